"""Host-compensation scenarios on the mock's simulation, no ROS (core tests, figures).

- :func:`rail_sweep`: :class:`~hyperarm_control.host.CompensationLoop` (what host_compensation
  runs per joint state) drives the arm of the mock's ``JointSim`` (rail_arm: the servos'
  acceleration-limited profiles and first-order lag, repeatability 0) while the rail sweeps
  0 -> +0.2 -> -0.2 -> 0 m at 0.2 m/s; every command reaches the simulation one step after
  the joint state it answers. Tool error by FK of the measured joints, rail included, and
  the reaction the node publishes (:class:`~hyperarm_control.host.ReactionModel`).
- :func:`rail_reach`: issue 24's item 1 on the same simulation: tool0 held about 0.62 m
  ahead (:data:`Q_REACH`, 10 deg below forward, near the stretched singularity) while the
  rail is streamed 0.2 m away from it at 0.1 m/s and back: the arm reaches full stretch
  (the goal goes out of reach) and leaves it. Returns every command sent, for the step
  invariant.

The shipped figure-8 task on this simulation (the task runner, above this package) is
hyperarm_tasks.benchmarks.host_figure8, which uses :func:`_sim` and :data:`ARM`.

Needs hyperarm_driver, imported when called.
Units: s, m, rad, N, N·m.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hyperarm_description.model import load_description

from ..host import (AccelerationEstimator, CompensationConfig, CompensationLoop, Compensator,
                    DelayEstimator, RailHost, ReactionModel)
from ..host.reaction import STANDARD_GRAVITY as _GRAVITY
from hyperarm_ik.kinematics import Kinematics, rotation_angle

if TYPE_CHECKING:
    from hyperarm_driver.mock.host_motion import HostMotionSpec

__all__ = ["rail_sweep", "rail_reach", "sway", "ordinary_postures", "mount_study", "Q0",
           "Q_REACH", "DT"]

ARM = [f"joint{i}" for i in range(1, 10)]
#: tool0 pointing down 0.2 m in front of the base (reachable while the base moves)
Q0 = [1.367, 0.62, -1.871, 0.548, 1.726, -1.732, 1.335, -0.596, 0.726]
DT = 0.01
#: tool0 0.62 m ahead of the base, 0.1 m up, 10 deg below forward (IK, issue 24 item 1)
Q_REACH = [0.141, 0.134, -0.305, -0.071, 0.137, 0.3, 0.145, -0.19, -0.113]


def _rail_setpoint(t: float, speed: float = 0.2, dwell: float = 0.3) -> float:
    """0 -> +0.2 -> -0.2 -> 0 m at ``speed`` m/s, ``dwell`` s at each turning point."""
    for a, b in zip((0.0, 0.2, -0.2), (0.2, -0.2, 0.0)):
        d = abs(b - a) / speed
        if t <= d:
            return a + math.copysign(speed * t, b - a)
        t -= d
        if t <= dwell:
            return b
        t -= dwell
    return 0.0


def _sim(desc):
    from hyperarm_driver.mock.config import load_mock_config
    from hyperarm_driver.mock.joint_sim import JointSim

    cfg = load_mock_config()
    return JointSim(desc, dataclasses.replace(cfg, imperfections=dataclasses.replace(
        cfg.imperfections, repeatability=0.0)))


def _rail_reach_setpoint(t: float) -> float:
    """0 -> -0.2 m (away from a tool ahead in +x) at 0.1 m/s, then back to 0."""
    return -0.1 * t if t < 2.0 else (-0.2 + 0.1 * (t - 2.0) if t < 4.0 else 0.0)


def rail_reach(duration: float = 5.0, config: CompensationConfig | None = None,
               compensator=Compensator, loop_class=CompensationLoop
               ) -> dict[str, np.ndarray]:
    """Issue 24 item 1 (module doc): :func:`rail_sweep`'s arrays plus ``command`` ((n, 9)
    rad, every command sent), ``dt`` (s, the states' periods) and ``status``.
    ``compensator``/``loop_class``: the classes to run (a comparison with another core)."""
    return rail_sweep(duration=duration, q0=Q_REACH, setpoint=_rail_reach_setpoint,
                      config=config, compensator=compensator, loop_class=loop_class)


def rail_sweep(lead: bool = True, duration: float = 5.2,
               reaction: bool = False, q0=None, setpoint=None,
               config: CompensationConfig | None = None, compensator=Compensator,
               loop_class=CompensationLoop) -> dict[str, np.ndarray]:
    """The rail sweep (see the module doc) for ``duration`` s (5.2: the whole sweep): arrays
    ``t`` (s), ``rail`` (m), ``position_error`` (m), ``orientation_error`` (rad), with
    ``reaction`` also ``wrench`` ((n, 6) N, N·m at base_link), ``command`` ((n, 9) rad),
    ``status`` and ``answered`` (commands per joint state). ``q0``: the arm's start posture
    (default :data:`Q0`); ``setpoint``: the rail's setpoint (m) at t s (default: the sweep);
    ``config``: the compensation's (default: with ``lead``)."""
    desc = load_description(variant="rail_arm")
    sim = _sim(desc)
    sim.home_rail()
    sim.command(ARM, Q0 if q0 is None else q0)
    for _ in range(300):
        sim.step(DT)
    setpoint = _rail_setpoint if setpoint is None else setpoint
    kin, rail, arm = Kinematics(variant="rail_arm"), RailHost(desc), Kinematics(variant="arm")
    cfg = config if config is not None else CompensationConfig(profile_lead=lead)
    loop = loop_class(compensator(arm, cfg), DelayEstimator(0.04), 0.1, host_from_states=True)
    model, accel = ReactionModel(arm), AccelerationEstimator()
    idx = [sim.names.index(n) for n in ARM]
    chain = [sim.names.index(n) for n in kin.joint_names]
    ir = sim.names.index("rail")

    def measured():
        s = sim.state()
        return s, s.position[idx], rail.state(s.position[ir], s.velocity[ir])

    s, q, host = measured()
    loop.on_state(sim.time, s.stamp, q, host, None, None)
    ok, why, _goal = loop.enable(sim.time, q, host, "rail")
    if not ok:
        raise RuntimeError(why)
    goal = kin.forward(s.position[chain])
    out: dict[str, list] = {k: [] for k in ("t", "rail", "position_error",
                                            "orientation_error", "wrench", "command",
                                            "status", "dt")}
    pending, answered, n = None, 0, int(duration / DT)
    t0 = sim.time
    for k in range(n):
        sim.command(["rail"], [setpoint(k * DT)])
        if pending is not None:           # the previous answer arrives (one step later)
            sim.command(ARM, pending)
        sim.step(DT)
        s, q, host = measured()
        pending, _log = loop.on_state(sim.time, s.stamp, q, host, None, None)
        answered += pending is not None
        if pending is not None:
            out["command"].append(pending.copy())
            out["dt"].append(DT)
        out["status"].append(loop.status)
        tool = kin.forward(s.position[chain])
        dq = s.velocity[idx]
        out["t"].append(sim.time - t0)
        out["rail"].append(s.position[ir])
        out["position_error"].append(float(np.linalg.norm(tool[:3, 3] - goal[:3, 3])))
        out["orientation_error"].append(rotation_angle(goal[:3, :3], tool[:3, :3]))
        if reaction:
            out["wrench"].append(model.wrench(q, dq, accel.update(sim.time, dq)))
    res = {k: np.array(v) for k, v in out.items() if v}
    res["answered"] = np.array(answered / n)
    return res


def sway(motion: str | Path | HostMotionSpec = "uav_sway", duration: float = 4.2,
         lead: bool = True, delay_steps: int = 1, config: CompensationConfig | None = None,
         q0=None, cutoffs: tuple[float, float] | None = None) -> dict[str, np.ndarray]:
    """The mock's host motion ``motion`` (a shipped name such as ``uav_sway`` or
    ``uav_sway_passive``, a path, or a ``HostMotionSpec``) on the fixed
    arm, compensated by :class:`CompensationLoop` on the host pose the mock publishes
    (base_link in world, one per step): ``t``, the tool errors judged by FK of the joint
    states on the host pose (``position_error``, ``orientation_error``) and by the mock's
    truth (``truth_position_error``, ``truth_orientation_error``), ``wrench`` (the
    reaction the node publishes), ``host`` ((n, 4, 4) host poses). Commands reach the
    simulation ``delay_steps`` steps after the state they answer. ``q0``: the arm's start
    posture (default :data:`Q0`). ``cutoffs``: (pose, twist) Hz of the host pose's
    mount-mode filter (default host_compensation's; (0, 0): none)."""
    from hyperarm_driver.mock.host_motion import HostMotion, load_host_motion

    desc = load_description(variant="arm")
    sim = _sim(desc)
    spec = load_host_motion(motion) if isinstance(motion, (str, Path)) else motion
    sim.host = HostMotion(spec, sim)
    sim.command(ARM, Q0 if q0 is None else q0)
    for _ in range(200):
        sim.step(DT)
    arm = Kinematics(variant="arm")
    cfg = config if config is not None else CompensationConfig(profile_lead=lead)
    loop = CompensationLoop(Compensator(arm, cfg), DelayEstimator(0.04), 0.1,
                            host_from_states=False)
    from ..host import MOUNT_POSE_CUTOFF, MOUNT_TWIST_CUTOFF, HostPoseTracker

    pc, tc = (MOUNT_POSE_CUTOFF, MOUNT_TWIST_CUTOFF) if cutoffs is None else cutoffs
    tracker = HostPoseTracker(pose_cutoff=pc, twist_cutoff=tc)
    model, accel = ReactionModel(arm), AccelerationEstimator()
    idx = [sim.names.index(n) for n in ARM]

    def measured():
        s = sim.state()
        tracker.update(sim.time, sim.host.base_pose)
        return s, s.position[idx]

    s, q = measured()
    loop.on_state(sim.time, s.stamp, q, tracker.state, tracker.stamp, sim.time, tracker.raw)
    ok, why, goal = loop.enable(sim.time, q, tracker.raw, "host_pose")
    if not ok:
        raise RuntimeError(why)
    goal_truth = sim.tool_pose().copy()
    sim.host.enable()
    out: dict[str, list] = {k: [] for k in ("t", "position_error", "orientation_error",
                                            "truth_position_error",
                                            "truth_orientation_error", "wrench", "host",
                                            "mount")}
    pending: list[np.ndarray] = []
    t0 = sim.time
    for _ in range(int(duration / DT)):
        if len(pending) >= delay_steps and pending:
            sim.command(ARM, pending.pop(0))
        sim.step(DT)
        s, q = measured()
        command, _log = loop.on_state(sim.time, s.stamp, q, tracker.state, tracker.stamp,
                                      sim.time, tracker.raw)
        if command is None:
            raise RuntimeError(f"compensation stopped: {loop.reason}")
        pending.append(command)
        host = sim.host.base_pose            # the measured host pose (not the filtered one)
        tool = host @ arm.forward(q)
        truth = sim.tool_pose()
        dq = s.velocity[idx]
        out["t"].append(sim.time - t0)
        out["position_error"].append(float(np.linalg.norm(tool[:3, 3] - goal[:3, 3])))
        out["orientation_error"].append(rotation_angle(goal[:3, :3], tool[:3, :3]))
        out["truth_position_error"].append(float(np.linalg.norm(truth[:3, 3]
                                                                 - goal_truth[:3, 3])))
        out["truth_orientation_error"].append(rotation_angle(goal_truth[:3, :3],
                                                             truth[:3, :3]))
        out["wrench"].append(model.wrench(q, dq, accel.update(sim.time, dq),
                                          gravity_base=host[:3, :3].T @ _GRAVITY))
        out["host"].append(host.copy())
        mount = getattr(sim.host, "mount", None)
        out["mount"].append(np.zeros(6) if mount is None else mount.displacement.copy())
    return {k: np.array(v) for k, v in out.items()}


def ordinary_postures(seed: int, n: int) -> list[np.ndarray]:
    """``n`` random arm postures (rad, seeded: 0.7 x uniform within the limits) with tool0
    0.2-0.6 m from the base's vertical axis and above z = -0.1 m: ordinary working
    postures, not only the tests' :data:`Q0`."""
    arm, rng, out = Kinematics(variant="arm"), np.random.default_rng(seed), []
    while len(out) < n:
        q = arm.random_configuration(rng) * 0.7
        p = arm.forward(q)[:3, 3]
        if p[2] > -0.1 and 0.2 < float(np.linalg.norm(p[:2])) < 0.6:
            out.append(q)
    return out


def mount_study(seeds=(0, 1, 2), postures: int = 10, duration: float = 10.0,
                cutoffs: tuple[float, float] | None = None) -> list[dict[str, object]]:
    """``uav_sway_passive`` for ``duration`` s from :func:`ordinary_postures` of each seed
    (issue 24 item 4): per run the seed, posture, the truth's RMS and max position error
    (m), max orientation error (rad) and the mount's largest translation (m)."""
    out = []
    for seed in seeds:
        for q0 in ordinary_postures(seed, postures):
            run = sway("uav_sway_passive", duration=duration, q0=q0, cutoffs=cutoffs)
            p = run["truth_position_error"]
            out.append({"seed": seed, "q0": q0, "rms": float(np.sqrt(np.mean(p ** 2))),
                        "max": float(p.max()),
                        "deg": math.degrees(float(run["truth_orientation_error"].max())),
                        "mount": float(np.abs(run["mount"][:, :3]).max())})
    return out
