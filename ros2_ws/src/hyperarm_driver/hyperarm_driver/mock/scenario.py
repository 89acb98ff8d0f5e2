"""Scripted use of the simulated robot without ROS: move the tool, open/close the gripper.

For tests, benchmarks and experiments on the mock's core. ``tool_down_ik`` is a small
damped-least-squares IK (pinocchio) for tool0 at a position with the hand pointing down
(``DOWN``); it is not the project's IK service, only enough to drive the simulation to known
poses.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from .joint_sim import JointSim

__all__ = ["DOWN", "tool_down_ik", "Scenario"]

# tool0 orientation with the hand (which points along tool0's -y) pointing straight down:
# x along root x, y along root +z, z (the fingers' closing direction) along root -y.
DOWN = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


#: Seeds tried in turn when a solution from the given seed makes the arm touch itself
#: (simulations on MuJoCo model the links' capsules against each other): gentle arcs.
ARC_SEEDS = (np.array([0.0, 0.35, 0.0, 0.35, 0.0, 0.35, 0.0, 0.35, 0.0]),
             np.array([0.0, 0.5, 0.0, 0.5, 0.0, 0.5, 0.0, 0.3, 0.0]),
             np.array([0.0, 0.25, 0.0, 0.25, 0.0, 0.25, 0.0, 0.25, 0.0]))


def self_contacts(sim, q: np.ndarray) -> list[tuple[str, str]]:
    """Pairs of the arm's capsules that touch at arm joints ``q`` (rad) in a simulation on
    MuJoCo (``sim.physics``); [] for a simulation without one."""
    physics = getattr(sim, "physics", None)
    if physics is None:
        return []
    return physics.self_contacts(np.r_[sim.position[:sim.nk - len(q)], q])


def tool_down_ik(sim: JointSim, xyz, seed: np.ndarray | None = None,
                 rot: np.ndarray = DOWN, iterations: int = 2000) -> np.ndarray:
    """Arm joint angles (rad) putting tool0 at ``xyz`` (m, root frame) with orientation
    ``rot``, the arm not touching itself (on MuJoCo: else from :data:`ARC_SEEDS`); raises
    RuntimeError if it does not converge to 1e-6 (or only to postures touching
    themselves)."""
    seeds = [seed] + list(ARC_SEEDS)
    last = ""
    for s in seeds:
        try:
            q = _dls(sim, xyz, s, rot, iterations)
        except RuntimeError as e:
            last = str(e)
            continue
        hits = self_contacts(sim, q)
        if not hits:
            return q
        last = f"tool_down_ik: {xyz}: the arm touches itself ({hits})"
    raise RuntimeError(last)


def _dls(sim: JointSim, xyz, seed: np.ndarray | None, rot: np.ndarray,
         iterations: int) -> np.ndarray:
    model, data, fid = sim.model, sim.model.createData(), sim.tool_id
    lo, hi = sim.lower[:sim.nk] * 0.95, sim.upper[:sim.nk] * 0.95
    q = np.zeros(sim.nk) if seed is None else np.asarray(seed, dtype=float).copy()
    target = np.asarray(xyz, dtype=float)
    err = np.inf
    for _ in range(iterations):
        pin.framesForwardKinematics(model, data, q)
        m = data.oMf[fid]
        e = np.r_[target - m.translation, pin.log3(rot @ m.rotation.T)]
        err = float(np.linalg.norm(e))
        if err < 1e-8:
            break
        j = pin.computeFrameJacobian(model, data, q, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        dq = j.T @ np.linalg.solve(j @ j.T + 1e-4 * np.eye(6), e)
        biggest = float(np.abs(dq).max())
        if biggest > 0.2:
            dq *= 0.2 / biggest
        q = np.clip(q + dq, lo, hi)
    if err > 1e-6:
        raise RuntimeError(f"tool_down_ik: no solution for {target.tolist()} (error {err:.2e})")
    return q


class Scenario:
    """Drive a :class:`JointSim` step by step (``dt`` s) through tool moves and grips."""

    def __init__(self, sim: JointSim, dt: float = 0.005) -> None:
        self.sim, self.dt = sim, dt
        self.q = sim.position[:sim.nk].copy()
        self.arm = [n for n in sim.names[:sim.nk] if n != sim.rail]
        self.tool_target: np.ndarray | None = None

    def run(self, seconds: float) -> None:
        for _ in range(int(round(seconds / self.dt))):
            self.sim.step(self.dt)

    def move_tool(self, xyz, seconds: float = 2.0, effort=None,
                  step: float = 0.002) -> np.ndarray:
        """Move tool0 (pointing down) in a straight line to ``xyz`` by streaming joint goals
        (one IK waypoint every ``step`` m over 70 % of ``seconds``; the first move is one
        joint-space goal), then simulate until ``seconds`` have passed.
        With ``effort`` (N·m, one for all or one per arm joint) the arm joints run
        current-based position with that limit.
        Returns the final joint goals."""
        target = np.array(xyz, dtype=float)     # a copy: the caller may reuse its array
        start = self.tool_target if self.tool_target is not None else target
        n = max(1, int(np.ceil(np.linalg.norm(target - start) / step)))  # 1st move: joint space
        per = 0.7 * seconds / n if n > 1 else 0.0   # 70 % on the way, the rest settling
        if effort is None:
            eff = ()
        else:
            eff = np.broadcast_to(np.asarray(effort, dtype=float), (len(self.arm),)).tolist()
        for k in range(1, n + 1):
            self.q = tool_down_ik(self.sim, start + (target - start) * k / n, self.q)
            self.sim.command(self.arm, self.q[-len(self.arm):].tolist(), eff)
            self.run(per)
        self.tool_target = target
        self.run(max(seconds - n * per, 0.0))
        return self.q
    def grip(self, angle: float, effort: float | None = None, seconds: float = 1.0) -> None:
        """Command the gripper to ``angle`` (rad, 0 = closed), optionally with a current
        limit ``effort`` (N·m), and simulate ``seconds``."""
        g = self.sim.desc.gripper.name
        self.sim.command([g], [angle], [effort] if effort is not None else ())
        self.run(seconds)

    def block_xyz(self) -> np.ndarray:
        return self.sim.world.block_pose(self.sim.tool_pose())[:3, 3]
