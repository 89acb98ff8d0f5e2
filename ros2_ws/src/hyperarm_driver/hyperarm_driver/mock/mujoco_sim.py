"""The simulated robot on MuJoCo: the servos' firmware models on MuJoCo's actuators (no ROS).

The servo side (commands, modes, profiles, current limits, the current model, the
repeatability offset, watchdog, overload, homing, latency, noise) is the mock's own model of
the Dynamixel and PMAC firmware; everything physical (the arm's dynamics, the fingers, the
block, the pegs, the table, the poles, contacts and friction) is MuJoCo stepping the model
generated from the description and the work cell (:mod:`hyperarm_description.mjcf`).

Per joint, by its mode:

- position class: a PD on MuJoCo's actuator, force = kp·(goal + offset - q) + kv·(goal_v -
  q̇) + feed-forward within ±the true current limit; goal, goal_v from the
  velocity/acceleration-limited profile; the feed-forward is the static and inertial load
  of the arm and of a held block (the servo's integral and feed-forward action: no steady
  droop), so contacts deflect a joint by torque / kp until its limit, where it gives way;
- current: the commanded torque through the true torque constant, in whole current units,
  on the motor's torque-speed line (back-EMF: stall / velocity limit);
- off (and a mode switch's gap): no force.

Units: rad, rad/s, N·m for the arm and gripper; m, m/s, N for the rail; s.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from hyperarm_description import mjcf
from hyperarm_description.model import RobotDescription

from .cell import Cell
from .config import MockConfig, load_mock_config
from .joint_sim import ControlMode, JointSim
from .physics import Physics
from .world import BlockState, WorldEvent

__all__ = ["MujocoSim", "physics_options"]

_HOLDING = (ControlMode.POSITION, ControlMode.CURRENT_POSITION)


def physics_options(cfg: MockConfig) -> mjcf.PhysicsOptions:
    """The model's physics options from the mock's configuration."""
    s = cfg.servo
    return mjcf.PhysicsOptions(friction=cfg.world.friction, joint_damping=s.damping,
                               joint_frictionloss=cfg.current.friction if cfg.current.enabled
                               else 0.0, arm_kp=s.stiffness, gripper_kp=s.gripper_stiffness,
                               rail_kp=s.rail_stiffness)


class MujocoSim(JointSim):
    """:class:`JointSim`'s interface with MuJoCo's physics."""

    def __init__(self, desc: RobotDescription, cfg: MockConfig | None = None,
                 initial: Mapping[str, float] | None = None, effort_timeout: float = 0.5,
                 require_homing: bool = True, *, mount: mjcf.Mount | None = None,
                 host: bool = False) -> None:
        cfg = cfg if cfg is not None else load_mock_config()
        super().__init__(desc, cfg, initial, effort_timeout, require_homing)
        self.options = physics_options(cfg)
        self.physics = Physics(desc, cfg.world.spec, self.options, host=host, mount=mount)
        ph = self.physics
        damping = np.full(self.n, cfg.servo.damping)
        if self.rail:
            damping[self._index[self.rail]] = 0.0
        ph.set_friction(self.coulomb, damping)
        o = self.options
        self._kp = np.array([o.rail_kp if n == self.rail else
                             o.gripper_kp if i == self.g else o.arm_kp
                             for i, n in enumerate(self.names)])
        self._kv = np.array([o.rail_kv if n == self.rail else
                             o.gripper_kv if i == self.g else o.arm_kv
                             for i, n in enumerate(self.names)])
        self._emf = self.stall / self.vmax
        self._act_key: list[tuple] = [()] * self.n
        self._act_sig: tuple = ()
        ph.set_positions(self.position + self.offset)
        self.world = Cell(cfg.world, ph)
        self._debt = 0.0
        self.penetration = 0.0            # m, deepest contact of the last step
        self._sync_actuators()
        self._update_tool()
        self._history.clear()
        self._record()

    # -- actuators ------------------------------------------------------------------------
    def _sync_actuators(self) -> None:
        """Each servo's actuator as its mode, gap and limit make it (only when one
        changed)."""
        sig = (tuple(self.mode), self._gap.astype(bool).tobytes(), self.limit.tobytes())
        if sig == self._act_sig:
            return
        self._act_sig = sig
        ph = self.physics
        for i in range(self.n):
            mode = self.mode[i]
            if mode is ControlMode.OFF or self._gap[i] > 0.0:
                key = ("off",)
            elif mode is ControlMode.TORQUE:
                key = ("current", self.stall[i] * self.kt_ratio[i])
            else:
                key = ("position", float(self.limit[i]))
            if key != self._act_key[i]:
                self._act_key[i] = key
                if key[0] == "off":
                    ph.set_servo(i, "off", 0.0)
                elif key[0] == "current":
                    ph.set_servo(i, "current", key[1], back_emf=self._emf[i])
                else:
                    ph.set_servo(i, "position", key[1], self._kp[i], self._kv[i])
        self._is_current = np.array([k == "current" for k in ph.kind])
        self._is_position = np.array([k == "position" for k in ph.kind])

    def _feedforward(self) -> np.ndarray:
        """The load a position servo holds without a steady error: gravity and velocity
        products of the arm (and the held block's weight), its inertia along the profile."""
        ph = self.physics
        ff = ph.bias().copy()
        acc = self._ref_v - self._prev_ref_v
        if np.count_nonzero(acc):
            ff += ph.inertia_times(np.where(self._is_position, acc / ph.timestep, 0.0))
        if self.world.state is BlockState.HELD:
            b = self.cfg.world.block
            pose = ph.block_pose()
            ff += ph.body_load(ph.tool_body, pose[:3, 3], np.array([0.0, 0.0, -9.81 * b.mass]))
        return ff

    # -- simulation -----------------------------------------------------------------------
    def step(self, dt: float) -> None:
        """Advance the simulation by ``dt`` seconds (in MuJoCo steps of its timestep; a
        remainder carries over to the next call)."""
        if not dt > 0.0:
            return
        ph = self.physics
        h = ph.timestep
        self._debt += dt
        steps = int(math.floor(self._debt / h + 1e-9))
        self._debt -= steps * h
        for _ in range(steps):
            self._substep(h)
        contacts = ph.contacts(everything=self.world.state is BlockState.HELD)
        self.penetration = ph.max_penetration()
        g = self.g
        self.world.update(contacts, opening=self.goal[g] >= self.position[g] - 1e-3)
        self._truth(contacts)
        self._report_efforts(self._gap > 0.0 if np.any(self._gap) else None)
        self.events.extend(self.world.take_events())
        self._update_tool()
        self._record()

    def _substep(self, h: float) -> None:
        self.time += h
        while self._pending and self._pending[0][0] <= self.time + 1e-12:
            self._pending.popleft()[1]()
        gapped = self._gap > 0.0
        self._settle_offset(h)
        self._watchdog()
        held = self._modes().holding & ~gapped
        self._profile(h, held)
        self._sync_actuators()
        ph = self.physics
        pos = ph.position_ctrl(self._ref + self.offset, self._ref_v, self._feedforward())
        if self._is_current.any():
            torque = self.kt_ratio * self._quantize(self.tau_cmd, None)
            pos = np.where(self._is_current, torque, pos)
        ctrl = pos
        ph.step(ctrl)
        self.position = ph.q - self.offset
        self.velocity = ph.qd.copy()
        self.effort = ph.force.copy()
        if self.homing:
            i = self._index[self.rail]
            if self.mode[i] is ControlMode.OFF:
                self.homing = False
            elif abs(self._ref[i]) < 1e-9 and self._prof_v[i] == 0.0 \
                    and abs(self.position[i]) < 1e-4:
                self.homing, self.homed = False, True
                self.events.append(WorldEvent("homed", f"{self.rail} homed at 0 m"))
        self._overload(h, held)
        if np.any(gapped):
            self._gap = np.maximum(self._gap - h, 0.0)
            for i in np.flatnonzero(gapped & (self._gap <= 1e-12)):
                self._gap[i] = 0.0
                if self.mode[i] in _HOLDING:
                    self._restart_profile(int(i), keep_goal=not self._gap_hold[i])
                self._gap_hold[i] = False

    def _profile(self, dt: float, held: np.ndarray) -> None:
        """The servo's profile (its goal filter, the trapezoid), without the old first-order
        lag: MuJoCo's PD and inertia lag the joint behind it."""
        super()._profile(dt, held)
        self._ref_v = np.where(held, self._prof_v, 0.0)
        self._ref = np.where(held, self._prof_p, self._ref)

    def _report_efforts(self, gapped: np.ndarray | None) -> None:
        """The efforts the servos report: the actuator's force through the true torque
        constant, in whole current units, converted back with the nominal one (current
        mode: the commanded current)."""
        if not self.cfg.current.enabled:
            self.reported_effort = self.effort.copy()
            return
        self._set_reported(self._quantize(self.effort / self.kt_ratio, None), gapped)

    def _truth(self, contacts) -> None:
        """Ground truth from MuJoCo's contacts: the work cell's wrench on the held block (at
        tool0, tool0's axes) and its force (root frame), the links touching poles, and
        every cell contact on the robot (:meth:`contact_wrench`)."""
        tool = self.physics.tool_pose()
        tx, ty, tz = tool[:3, 3].tolist()
        fb = [0.0] * 3
        mb = [0.0] * 3
        total = [0.0] * 6
        links = []
        m = self.physics.model
        for c in contacts:
            for own, other, sign in ((c.a, c.b, 1.0), (c.b, c.a, -1.0)):
                if not (other == "table" or other.startswith(("peg_", "pole_"))):
                    continue
                block = own.startswith("block_piece")
                link = own.startswith("capsule_") and other.startswith("pole_")
                if not (block or link):
                    continue
                fx, fy, fz = (sign * c.force).tolist()
                px, py, pz = c.point.tolist()
                total[0] += fx; total[1] += fy; total[2] += fz
                total[3] += py * fz - pz * fy
                total[4] += pz * fx - px * fz
                total[5] += px * fy - py * fx
                if block:
                    rx, ry, rz = px - tx, py - ty, pz - tz
                    fb[0] += fx; fb[1] += fy; fb[2] += fz
                    mb[0] += ry * fz - rz * fy
                    mb[1] += rz * fx - rx * fz
                    mb[2] += rx * fy - ry * fx
                else:
                    body = m.body(m.geom_bodyid[m.geom(own).id]).name
                    links.append((body, other[5:], max(0.0, -c.dist), np.array([fx, fy, fz])))
        held = self.world.state is BlockState.HELD
        force = np.array(fb)
        self.contact_force = force if held else np.zeros(3)
        self.tool_wrench = np.r_[tool[:3, :3].T @ force, tool[:3, :3].T @ np.array(mb)] \
            if held else np.zeros(6)
        self.link_contacts = links
        self._wrench = np.array(total)

    def _held_by_contact(self) -> bool:
        return bool(self.link_contacts) or bool(np.any(self.contact_force))

    # -- outputs --------------------------------------------------------------------------
    def _update_tool(self) -> None:
        if hasattr(self, "physics"):
            self._tool = self.physics.tool_pose()
        else:
            super()._update_tool()

    def truth(self) -> dict[str, np.ndarray]:
        out = {} if self.world.state is BlockState.ABSENT else \
            {"block": self.physics.block_pose()}
        for name in self.world.peg_names:
            out[f"{name}_peg"] = self.world.peg_top(name)
        return out

    def contact_wrench(self) -> np.ndarray:
        return getattr(self, "_wrench", np.zeros(6)).copy()
