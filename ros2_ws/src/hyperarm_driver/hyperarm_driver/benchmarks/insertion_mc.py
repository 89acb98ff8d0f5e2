"""insertion_mc: Monte-Carlo of the mock's insertion against the prediction from geometry.

Over ``--seeds`` seeds of the packaged work cell (each seed draws the hidden repeatability
offsets and the servos' current model), the simulation core (no ROS) picks the block from
the source peg and brings it down onto the destination peg:

- **blind**: a straight descent (streamed 2 mm setpoints) from above the peg to its base;
- **dither**: the same descent, and if the block did not thread (it stopped on the peg's
  top, or slid off its edge: pressed down this hard, the arm's springs push it sideways
  more than friction holds), back up (streamed) and a pressing x-y spiral (4 mm below the
  top, out to 15 mm, streamed) until the block threads.

The script (one joint-space move to above the source, streamed descent, grasp, streamed
lift, one joint-space move to above the destination, streamed descent) makes two moves, so
two offsets are drawn (the move rule, docs/mock.md): one at the grasp, one at the
insertion. The **prediction** samples the same two offsets (N(0, repeatability²) per arm
joint) and computes, by forward kinematics only, where the block's hole axis meets the
block's top and bottom faces at the peg's top: the blind rate predicted is the probability
that both are within the radial clearance of the peg's axis (a tilted hole is a tilted
cylinder, docs/mock.md). The blind rate measured must match it (binomial standard error shown).

    python -m hyperarm_driver.benchmarks.insertion_mc [--seeds 200] [--samples 100000]
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time

import numpy as np
import pinocchio as pin

from hyperarm_description.model import load_description
from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_driver.mock.scenario import tool_down_ik

DT = 0.01
ARM = [f"joint{i}" for i in range(1, 10)]


def _plan(sim: JointSim) -> dict:
    """Joint goals of the script (IK on the nominal model, computed once)."""
    w = sim.cfg.world
    half = w.block.size[2] / 2.0
    src, dst = w.peg(w.block.start), next(p for p in w.pegs if p.name != w.block.start)
    top = w.table_height + dst.height
    q = np.zeros(9)

    def ik(xyz):
        nonlocal q
        q = tool_down_ik(sim, np.asarray(xyz, dtype=float), q)
        return q.copy()

    def line(a, b, step=0.002):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        n = max(1, int(math.ceil(np.linalg.norm(b - a) / step)))
        return [ik(a + (b - a) * k / n) for k in range(1, n + 1)]

    s_block = np.array([*src.xy, w.table_height + half])
    s_above = s_block + [0.0, 0.0, src.height + 0.02]
    d_above = np.array([*dst.xy, top + half + 0.02])
    d_base = np.array([*dst.xy, w.table_height + half])
    plan = {"s_above": ik(s_above)}
    plan["down"] = line(s_above, s_block)
    plan["grasp"] = plan["down"][-1]
    plan["up"] = line(s_block, s_above)
    plan["d_above"] = ik(d_above)
    plan["descent"] = line(d_above, d_base)
    plan["ascent"] = plan["descent"][-2::-1] + [plan["d_above"]]
    # the descent's setpoint where the block's bottom reaches the peg's top
    z = [d_above[2] - (d_above[2] - d_base[2]) * k / len(plan["descent"])
         for k in range(1, len(plan["descent"]) + 1)]
    plan["at_top"] = plan["descent"][int(np.argmin(np.abs(np.array(z) - half - top)))]
    press = np.array([*dst.xy, top + half - 0.004])
    spiral = []
    for k in range(1, 400):
        r, a = 0.015 * k / 400, 2.0 * math.pi * 6.0 * k / 400
        spiral.append(press + [r * math.cos(a), r * math.sin(a), 0.0])
    plan["dither"] = line(d_above, press)[-1:] + [ik(p) for p in spiral]
    plan["block_start"] = sim.world.block_pose()
    plan["peg"] = dst
    return plan


def _goto(sim, q, seconds):
    sim.command(ARM, q.tolist())
    for _ in range(int(round(seconds / DT))):
        sim.step(DT)


def _stream(sim, qs, seconds):
    per = max(int(round(seconds / len(qs) / DT)), 1)
    for q in qs:
        sim.command(ARM, q.tolist())
        for _ in range(per):
            sim.step(DT)


def trial(desc, cfg, plan) -> tuple[bool, bool]:
    """One seeded pick and insertion: whether the block threads on the destination peg
    after the blind descent, and after the dither that follows it if it did not (the
    dither's run starts with the blind one: the same seed gives the same simulation)."""
    sim = JointSim(desc, cfg)
    g = ["gripper"]
    sim.command(g, [1.2], [0.6])
    _goto(sim, plan["s_above"], 2.5)
    _stream(sim, plan["down"], 1.0)
    sim.command(g, [0.0], [0.6])
    for _ in range(80):
        sim.step(DT)
    if sim.world.state.value != "held":
        raise RuntimeError("the grasp failed")
    _stream(sim, plan["up"], 1.0)
    _goto(sim, plan["d_above"], 2.5)
    _stream(sim, plan["descent"], 1.5)
    for _ in range(30):
        sim.step(DT)
    if sim.world.peg == plan["peg"].name:
        return True, True
    # not threaded: back up, streamed (the block may have slid off the top's edge), then
    # the pressing spiral
    _stream(sim, plan["ascent"], 1.5)
    for q in plan["dither"]:
        sim.command(ARM, q.tolist())
        for _ in range(2):
            sim.step(DT)
        if sim.world.peg == plan["peg"].name:
            return False, True
    return False, False


def predict(desc, cfg, plan, samples: int, rng: np.random.Generator) -> float:
    """Blind success probability from the clearance and the repeatability alone."""
    model = JointSim(desc, dataclasses.replace(cfg)).model
    data = model.createData()
    fid = model.getFrameId(desc.tool_frame)
    sigma = cfg.imperfections.repeatability

    def tool(q):
        pin.framesForwardKinematics(model, data, q)
        return data.oMf[fid].homogeneous.copy()

    peg = plan["peg"]
    clearance = cfg.world.clearance(peg.name)
    block0 = plan["block_start"]
    half = cfg.world.block.size[2] / 2.0
    ok = 0
    for _ in range(samples):
        d1, d2 = rng.normal(0.0, sigma, 9), rng.normal(0.0, sigma, 9)
        grasp = np.linalg.inv(tool(plan["grasp"] + d1)) @ block0
        b = tool(plan["at_top"] + d2) @ grasp
        rims = (b[:3, 3] + sign * half * b[:3, 2] for sign in (1.0, -1.0))
        ok += all(math.hypot(r[0] - peg.xy[0], r[1] - peg.xy[1]) <= clearance for r in rims)
    return ok / samples


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=200)
    ap.add_argument("--samples", type=int, default=100_000, help="prediction samples")
    args = ap.parse_args(argv)
    desc = load_description()
    base = load_mock_config()
    plan = _plan(JointSim(desc, dataclasses.replace(base, imperfections=dataclasses.replace(
        base.imperfections, repeatability=0.0))))
    t0 = time.monotonic()
    pred = predict(desc, base, plan, args.samples, np.random.default_rng(12345))
    wins = np.zeros(2)
    for seed in range(args.seeds):
        cfg = dataclasses.replace(base, imperfections=dataclasses.replace(
            base.imperfections, seed=seed))
        wins += trial(desc, cfg, plan)
    rates = {"blind": wins[0] / args.seeds, "dither": wins[1] / args.seeds}
    n = args.seeds
    se = math.sqrt(max(pred * (1.0 - pred), 1e-12) / n)
    z = (rates["blind"] - pred) / se
    print(f"repeatability {base.imperfections.repeatability:g} rad, clearance "
          f"{1e3 * base.world.clearance(plan['peg'].name):.1f} mm, {n} seeds, "
          f"{time.monotonic() - t0:.0f} s")
    print(f"blind straight descent: {rates['blind']:.3f} inserted; predicted {pred:.3f} "
          f"({args.samples} samples); difference {z:+.2f} standard errors "
          f"(binomial, {se:.3f})")
    print(f"pressing dither:        {rates['dither']:.3f} inserted")
    return 0 if abs(z) <= 3.0 else 1


if __name__ == "__main__":
    sys.exit(main())
