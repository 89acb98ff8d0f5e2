"""insertion_mc: Monte-Carlo of the mock's insertion against the prediction from geometry.

Over ``--seeds`` seeds of the packaged work cell (each seed draws the hidden repeatability
offsets and the servos' current model), the simulation core on MuJoCo (no ROS) picks the
block from the source peg by the pads' friction and brings it down onto the destination
peg:

- **blind**: a straight descent (streamed 2 mm setpoints) from above the peg to 4 mm below
  its top, where a force limit would stop it (pushed on down to the base, a block on the
  top is pressed at the servos' stall torques and turns 50-60° in the pads' friction grasp:
  no dither could insert it then);
- **dither**: if the block did not thread (it stopped on the peg's top, or slid off its
  edge: pressed down, the arm's springs push it sideways), back up and down again
  (streamed: the same move, the same offset) and a pressing x-y spiral (4 mm below the top,
  out to 15 mm, 6 turns, streamed) until the block threads.

The script (one joint-space move to above the source, streamed descent, grasp, streamed
lift, one joint-space move to above the destination, streamed descent) makes two moves, so
two offsets are drawn (the move rule, docs/mock.md): one at the grasp, one at the
insertion. The **prediction** samples the same two offsets (N(0, repeatability²) per arm
joint) and computes, by forward kinematics only, where the block is at the peg's top: the
grasp takes the block where it stood, but the pads centre it between them along the
closing axis and clamp its faces flat against them (a friction grasp, not a weld: it does
not keep the tool's error along that axis; measured, the block also shifts ~1 mm along
tool0's x as the pads close, which the prediction leaves out). The blind rate predicted is
the probability that the hole's axis, at the block's top and bottom faces, is where the
peg passes the modelled hole: a regular polygon of ``hole_pieces`` edges circumscribed
about the hole's circle (docs/mujoco.md), so a round peg fits while its offset along each
edge's normal is at most the radial clearance (up to clearance / cos(π/12) towards a
corner of the 12-gon). The blind rate measured must match it (binomial standard error).

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
from hyperarm_driver.mock.joint_sim import JointSim, physics_options
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
    plan = {"s_above": ik(s_above)}
    plan["down"] = line(s_above, s_block)
    plan["grasp"] = plan["down"][-1]
    plan["up"] = line(s_block, s_above)
    plan["d_above"] = ik(d_above)
    press = np.array([*dst.xy, top + half - 0.004])
    plan["descent"] = line(d_above, press)
    plan["ascent"] = plan["descent"][-2::-1] + [plan["d_above"]]
    plan["at_top"] = ik([*dst.xy, top + half])     # the block's bottom at the peg's top
    spiral = []
    for k in range(1, 400):
        r, a = 0.015 * k / 400, 2.0 * math.pi * 6.0 * k / 400
        spiral.append(press + [r * math.cos(a), r * math.sin(a), 0.0])
    # back down streamed (the same move: the insertion's offset, not a new draw)
    plan["dither"] = line(d_above, press) + [ik(p) for p in spiral]
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
    _stream(sim, plan["descent"], 0.25)        # 2 mm per 20 ms, as before
    for _ in range(30):
        sim.step(DT)
    if sim.world.peg == plan["peg"].name:
        return True, True
    # not threaded: back up, streamed (the block may have slid off the top's edge), down
    # again streamed and the pressing spiral
    _stream(sim, plan["ascent"], 1.5)
    for q in plan["dither"]:
        sim.command(ARM, q.tolist())
        for _ in range(2):
            sim.step(DT)
        if sim.world.peg == plan["peg"].name:
            return False, True
    return False, False


def _pads_grasp(grasp: np.ndarray) -> np.ndarray:
    """The block's pose in tool0 (``grasp``: where it stood, in tool0) once the pads hold
    it: its faces flat against the pads (its y axis along tool0's z, the closing axis; the
    smallest rotation that does it) and centred between them along that axis."""
    out = grasp.copy()
    y = out[:3, 1]
    target = np.array([0.0, 0.0, 1.0 if y[2] >= 0.0 else -1.0])
    axis = np.cross(y, target)
    s, c = float(np.linalg.norm(axis)), float(y @ target)
    if s > 1e-15:
        k = axis / s
        kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        a = math.atan2(s, c)
        out[:3, :3] = (np.eye(3) + math.sin(a) * kx + (1.0 - math.cos(a)) * kx @ kx) @ out[:3, :3]
    out[2, 3] = 0.0
    return out


def passes(block: np.ndarray, peg_xy, half: float, clearance: float, edges: int) -> bool:
    """Whether a vertical round peg at ``peg_xy`` passes the block's modelled hole (a regular
    polygon of ``edges`` edges circumscribed about the hole's circle, an edge's normal at
    π/edges from the block's x axis) at the block's top and bottom faces, block pose
    ``block``: the offset of the hole's axis from the peg's, along every edge's normal (in
    the block's horizontal axes), at most the radial ``clearance``."""
    yaw = math.atan2(block[1, 0], block[0, 0])
    normals = [yaw + math.pi * (2 * k + 1) / edges for k in range(edges)]
    for sign in (1.0, -1.0):
        rim = block[:3, 3] + sign * half * block[:3, 2]
        ex, ey = float(rim[0]) - peg_xy[0], float(rim[1]) - peg_xy[1]
        if max(ex * math.cos(a) + ey * math.sin(a) for a in normals) > clearance:
            return False
    return True


def predict(desc, cfg, plan, samples: int, rng: np.random.Generator) -> float:
    """Blind success probability from the clearance, the repeatability and the grasp."""
    model = JointSim(desc, dataclasses.replace(cfg)).model
    data = model.createData()
    fid = model.getFrameId(desc.tool_frame)
    sigma = cfg.imperfections.repeatability
    edges = physics_options(cfg).hole_pieces

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
        grasp = _pads_grasp(np.linalg.inv(tool(plan["grasp"] + d1)) @ block0)
        ok += passes(tool(plan["at_top"] + d2) @ grasp, peg.xy, half, clearance, edges)
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
