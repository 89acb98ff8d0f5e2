"""The simulated robot: servo dynamics, arm dynamics, gripper and work-cell contact (no ROS).

Units: rad, rad/s, N·m for the arm and gripper joints; m, m/s, N for the rail; s.

Every servo is in one of four modes, chosen per joint by the last command it got (as the
real driver does: position only = position control, effort only = torque control, both =
current-based position with the effort as current limit), or OFF (torque disabled):

- POSITION / CURRENT_POSITION: the goal is followed through a velocity- and
  acceleration-limited profile (the description's limits) and a first-order lag. The
  position loop has a finite stiffness (``servo.stiffness``): external forces (the work
  cell's contacts) deflect the joint by torque/stiffness, and the servo's torque is limited
  to the stall torque (POSITION) or the commanded current limit (CURRENT_POSITION). When the
  limit is reached the joint yields further (a yield state, at most its velocity limit per
  step), so the contact force stays bounded by what it can exert. No position-class joint
  moves more than its velocity limit in a step. Gravity
  and inertia are assumed compensated by the servo's integral action (no steady droop), but
  their torques, from pinocchio's RNEA on the description's link masses, are reported as
  effort. A position-class servo held at its stall torque for ``OVERLOAD_TIME`` s raises an
  overload error and drops its torque, as a Dynamixel does.
- TORQUE: the commanded effort (clamped to the stall torque) drives the joint through the
  rigid-body dynamics (pinocchio CRBA/RNEA, semi-implicit Euler with viscous damping),
  against gravity and the contact forces (implicit contact springs, inelastic impacts, the
  motor's torque-speed line up to the velocity limit as no-load speed). Without a new effort command for
  ``effort_timeout`` s the watchdog switches the joint to holding its position.
- OFF: no torque; the joint moves under gravity and contacts with viscous friction.

Imperfections: a hidden joint offset drawn per move (repeatability: the encoders, hence
joint_states, do not see it, but the tool's true pose, the block and the camera do), noise
and latency on the reported states, latency on commands. Joint goals are clamped to the
limits before they are stored: no command outside the limits reaches the simulated servos.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from enum import Enum
from typing import Callable, Mapping, Sequence

import numpy as np
import pinocchio as pin

from hyperarm_description.joints import JointStateError, check_command
from hyperarm_description.model import RobotDescription
from hyperarm_description.pinocchio_model import build_model

from .config import MockConfig, MockError, load_mock_config
from .world import BlockState, World, WorldEvent

__all__ = ["ControlMode", "CommandReport", "StateSample", "MockCommandError", "JointSim",
           "OVERLOAD_TIME", "RAIL_FORCE_LIMIT"]

OVERLOAD_TIME = 2.0        # s at the stall torque before a POSITION servo's overload error
OVERLOAD_FRACTION = 0.98   # of the torque limit: "at the limit" for the overload count
RAIL_FORCE_LIMIT = 200.0   # N, the rail drive's force limit
FRICTION_VELOCITY = 0.02   # rad/s, below which Coulomb friction acts as a steep damper
CONTACT_DAMPING = 30.0     # N·s/m, against dynamic (torque-mode) joints
SUBSTEPS = 4               # dynamic sub-steps per step while any joint is dynamic
LINEARIZATIONS = 6         # quasi-static contact solves per step at most (stops when converged)
HARD_DEPTH = 0.001         # m: contacts deeper than this are on the stiff branch
HARD_FACTOR = 50.0         # the stiff branch's stiffness / contact_stiffness
RELINEARIZE = 1e-4         # rad: re-linearize when the solution is this far from the point
CONTACT_MARGIN = 0.02      # m: a remembered peg top or side this far apart is still a row
YIELD_ITERATIONS = 3       # contact solves per step at most while a servo gives way
JUMP_FACTOR = 2.0          # a position-class joint moving more than this x its velocity
                           # limit in one step: the contact solve failed (not taken)
OFFSET_RATE = 0.5          # rad/s: a new move's repeatability offset settles at most this
                           # fast per joint (its backlash takes up during the move, no jump)
GUARD_DEPTH = 0.002        # m: a step ending a link or the block deeper than this in a
                           # contact (unless the pose kept instead is deeper) is not taken


def _any(x) -> bool:
    """``x.any()`` for the step's small arrays (numpy's reduce costs ~3x more per call)."""
    return np.count_nonzero(x) != 0


def _clip(x, lo, hi):
    """``np.clip`` for the step's small arrays (np.clip's overhead is ~3x this)."""
    return np.minimum(np.maximum(x, lo), hi)


def _absmax(x: np.ndarray) -> float:
    """``np.abs(x).max()`` of a small non-empty array."""
    return max(np.abs(x).tolist())


class MockCommandError(MockError):
    """A command or request the simulated servos refuse (torque off, hardware error...)."""


class ControlMode(str, Enum):
    POSITION = "position"
    CURRENT_POSITION = "current_based_position"
    TORQUE = "current"
    OFF = "off"


_HOLDING = (ControlMode.POSITION, ControlMode.CURRENT_POSITION)


@dataclass(frozen=True)
class _ModeSets:
    """Which joints are in which mode (derived from ``JointSim.mode``)."""
    holding: np.ndarray           # (n,) bool: position-class
    torque: list[int]             # current (torque) mode
    off: list[int]                # torque off
    current_position: np.ndarray  # (nk,) bool: current-based position (chain joints)
    chain_held: bool              # every chain joint position-class


@dataclass(frozen=True)
class CommandReport:
    """What became of a command: joints applied, joints clamped to a limit, their mode."""

    applied: tuple[str, ...]
    clamped: tuple[str, ...]
    mode: ControlMode = ControlMode.POSITION
    rejected: str = ""       # why the rail's part was refused (the rest applied), or ""


@dataclass(frozen=True)
class StateSample:
    """Joint states as reported (noise and latency applied), in ``JointSim.names`` order."""

    stamp: float
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray


_AXES = np.eye(3)
_AXES.flags.writeable = False


def _skew(r: np.ndarray) -> np.ndarray:
    x, y, z = r.tolist()
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


class JointSim:
    """Every actuated joint of a description (rail, arm, gripper) plus the work cell.

    ``names`` lists the joints: the pinocchio chain (rail first, if any) then the gripper.
    ``position``/``velocity``/``effort`` are the encoder's noiseless values now; use
    :meth:`state` for what the driver reports.
    """

    def __init__(self, desc: RobotDescription, cfg: MockConfig | None = None,
                 initial: Mapping[str, float] | None = None, effort_timeout: float = 0.5,
                 require_homing: bool = True) -> None:
        if not (effort_timeout > 0.0 and math.isfinite(effort_timeout)):
            raise ValueError(f"effort_timeout must be > 0 s, got {effort_timeout}")
        self.desc = desc
        self.cfg = cfg if cfg is not None else load_mock_config()
        self.effort_timeout = float(effort_timeout)
        self.names = desc.all_joint_names
        self.n = len(self.names)
        self.nk = self.n - 1                       # chain joints; the gripper is last
        self.g = self.n - 1
        self._index = {n: i for i, n in enumerate(self.names)}
        limits = desc.limits_by_name()
        self.lower = np.array([limits[n][0] for n in self.names])
        self.upper = np.array([limits[n][1] for n in self.names])
        s = self.cfg.servo
        vel, acc, stall, stiff = [], [], [], []
        if desc.rail:
            vel.append(desc.rail.velocity); acc.append(desc.rail.acceleration)
            stall.append(RAIL_FORCE_LIMIT); stiff.append(s.rail_stiffness)
        for j in desc.joints:      # the driver writes j.acceleration; 0: unlimited (inf)
            vel.append(j.velocity)
            acc.append(j.acceleration if s.profile_acceleration is None else
                       (s.profile_acceleration if s.profile_acceleration > 0 else math.inf))
            stall.append(j.effort); stiff.append(s.stiffness)
        vel.append(desc.gripper.velocity); acc.append(s.gripper_acceleration)
        stall.append(desc.gripper.effort); stiff.append(s.gripper_stiffness)
        self.vmax, self.amax = np.array(vel), np.array(acc)
        self.stall, self.stiffness = np.array(stall), np.array(stiff)
        self.rail = desc.rail.name if desc.rail else None
        self._arm = np.zeros(self.n, dtype=bool)
        self._arm[[self._index[j.name] for j in desc.joints]] = True
        # the driver's default current limit of a position-class command (docs/dynamixel.md):
        # the stall torque for the arm joints, grip_effort for the gripper
        self.default_limit = self.stall.copy()
        self.default_limit[self.g] = min(desc.gripper.grip_effort, self.stall[self.g])
        self._current_model(desc)

        self.model = build_model(desc)
        self.data = self.model.createData()
        self.tool_id = self.model.getFrameId(desc.tool_frame)
        tool_frame = self.model.frames[self.tool_id]
        self._payload_joint = int(tool_frame.parentJoint)
        self._tool_in_joint = tool_frame.placement.homogeneous
        self._bare_inertia = pin.Inertia(self.model.inertias[self._payload_joint])
        self.payload = False                       # the held block's inertia is in the model
        # poles: the links' capsules (hyperarm_description) meet them
        self._poles = bool(self.cfg.world.poles)
        self._capsules = [(c.name, c.radius, self.model.getFrameId(c.frame), c.endpoints())
                          for c in desc.capsules] if self._poles else []
        self.link_contacts: list[tuple[str, str, float, np.ndarray]] = []
        self._pole_normals: dict[str, np.ndarray] = {}   # ongoing link contacts' sides
        self._link_rows: list = []
        self.world = World(self.cfg.world)
        imp = self.cfg.imperfections
        self._rng = np.random.default_rng(imp.seed)

        q0 = np.zeros(self.n)
        for name, value in (initial or {}).items():
            if name not in self._index:
                raise JointStateError(f"initial: unknown joint {name!r}")
            q0[self._index[name]] = value
        q0 = _clip(q0, self.lower, self.upper)
        self.time = 0.0
        self.mode = [self._hold_mode(i) for i in range(self.n)]
        self._mode_key: tuple = ()
        self._mode_sets: _ModeSets | None = None
        self.goal = q0.copy()
        self.limit_cmd = self.default_limit.copy()   # N·m (N rail), nominal, as commanded
        self.limit = self._true_limit(self.limit_cmd)  # what the servo really enforces
        self._gap = np.zeros(self.n)               # s of torque off left (mode switch)
        self.reported_effort = np.zeros(self.n)    # what the servos report (current model)
        self.tool_wrench = np.zeros(6)             # N, N·m: contacts on the block, at tool0
        self._last_rows = None                     # last contact rows and forces
        self._gap_hold = np.zeros(self.n, dtype=bool)  # after the gap: goal := present
        self.tau_cmd = np.zeros(self.n)
        self._effort_time = np.zeros(self.n)
        self._prof_p, self._prof_v = q0.copy(), np.zeros(self.n)
        self._yield = np.zeros(self.n)   # rad (m): how far a servo at its limit gave way
        self._yield_rate = np.zeros(self.n)   # rad/s (m/s), the yield's change last step
        self._ref, self._ref_v = q0.copy(), np.zeros(self.n)
        self.position, self.velocity, self.effort = q0.copy(), np.zeros(self.n), np.zeros(self.n)
        self.offset = np.zeros(self.n)             # hidden (repeatability), arm joints only
        self._offset_goal = np.zeros(self.n)       # the move's drawn offset (settling)
        self._settling = False                     # offset still on its way to the goal
        self._anchor = q0.copy()
        self._saturated_for = np.zeros(self.n)
        self.errors: dict[str, str] = {}
        self.events: list[WorldEvent] = []
        self.contact_force = np.zeros(3)           # N, on the held block, last step
        self._pending: deque[tuple[float, Callable[[], None]]] = deque()
        self._history: deque[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = deque()
        self._anchors: dict[str, np.ndarray] = {}   # friction anchors (xy, m) by contact
        self._contact_rows_used = None
        self._warm: np.ndarray | None = None       # last step's contact deflection (rad)
        self._underpowered: set[str] = set()       # joints whose current limit < their load
        self._redraw = False                       # a new move's offset waits for no contact
        self.guarded_steps = 0                     # steps the position guard refused
        self._blocked = False                      # the last step was refused
        self._blocked_at = -math.inf               # s, the last blocked event
        self.require_homing = bool(require_homing)
        self.homed = self.rail is None
        self.homing = False
        self.host = None   # a host_motion.HostMotion: moves the root in world (set by its user)
        self._tool = np.eye(4)
        self._fk_cache, self._fk_key, self._fk_pose = False, None, None
        self._travel: tuple = (None, None, None)   # _step_travel's dt and arrays
        self._update_tool()
        self._record()

    def _current_model(self, desc: RobotDescription) -> None:
        """Per-servo torque-constant ratio, Coulomb friction and current quantum (the rail:
        ideal), drawn once from the imperfections seed (its own stream)."""
        cur = self.cfg.current
        seed = self.cfg.imperfections.seed
        rng = np.random.default_rng(None if seed is None else [seed, 9])
        self.kt_ratio = np.ones(self.n)
        self.coulomb = np.zeros(self.n)
        self.quantum = np.zeros(self.n)
        servos = np.ones(self.n, dtype=bool)
        if self.rail:
            servos[self._index[self.rail]] = False
        if cur.enabled:
            m = int(servos.sum())
            e = cur.torque_constant_error
            self.kt_ratio[servos] = rng.uniform(1.0 - e, 1.0 + e, m)
            self.coulomb[servos] = cur.friction * rng.uniform(0.5, 1.5, m)
            self.quantum[servos] = cur.quantum
        self._quantized = self.quantum > 0.0           # (constant: _quantize's arrays)
        self._all_quantized = bool(self._quantized.all())
        self._quantum_safe = np.where(self._quantized, self.quantum, 1.0)

    def _quantize(self, tau: np.ndarray | float, idx=slice(None)) -> np.ndarray:
        """Nominal torque (N·m) rounded to whole current units of the servos ``idx``."""
        if idx is None:                  # every joint (no slicing: the step's hot path)
            rounded = np.round(tau / self._quantum_safe) * self.quantum
            return rounded if self._all_quantized else np.where(self._quantized, rounded, tau)
        q = self.quantum[idx]
        return np.where(self._quantized[idx], np.round(tau / self._quantum_safe[idx]) * q, tau)

    def _true_limit(self, nominal: np.ndarray) -> np.ndarray:
        """Torque limit (N·m) a servo really enforces for a nominal current limit."""
        return self.kt_ratio * np.abs(self._quantize(np.asarray(nominal, dtype=float)))

    def _hold_mode(self, i: int) -> ControlMode:
        """Position-class mode of joint ``i``: current-based position (arm, gripper; the
        driver's rule: no mode switch between position-class commands), position (rail)."""
        return ControlMode.POSITION if self.names[i] == self.rail else \
            ControlMode.CURRENT_POSITION

    def _set_limit(self, i: int, nominal: float) -> None:
        """Nominal current limit (N·m) of joint ``i``; ``limit`` gets what it enforces."""
        self.limit_cmd[i] = nominal
        self.limit[i] = float(self.kt_ratio[i] * abs(self._quantize(nominal, i)))

    def _switch(self, i: int, mode: ControlMode) -> None:
        """Set joint ``i``'s mode; changing between position-class and current (torque)
        control turns its torque off for ``servo.mode_switch_gap`` s first (:meth:`step`
        splits a step at the gap's end), as the real driver must (Operating Mode is written
        with torque off)."""
        old = self.mode[i]
        if old is not ControlMode.OFF and (old is ControlMode.TORQUE) != (mode is ControlMode.TORQUE):
            self._gap[i] = self.cfg.servo.mode_switch_gap
        self.mode[i] = mode

    def _modes(self) -> "_ModeSets":
        """The joints of each mode, recomputed only when a mode changed (``self.mode`` is a
        plain list, set in many places: compared as a tuple, ~0.3 µs)."""
        key = tuple(self.mode)
        if key != self._mode_key:
            self._mode_key = key
            self._mode_sets = _ModeSets(
                holding=np.array([m in _HOLDING for m in key]),
                torque=[i for i, m in enumerate(key) if m is ControlMode.TORQUE],
                off=[i for i, m in enumerate(key) if m is ControlMode.OFF],
                current_position=np.array([m is ControlMode.CURRENT_POSITION
                                           for m in key[:self.nk]]),
                chain_held=all(m in _HOLDING for m in key[:self.nk]))
        return self._mode_sets

    def _sync_payload(self) -> None:
        """The held block's mass and inertia in the model's last link while held."""
        held = self.world.state is BlockState.HELD
        if held == self.payload:
            return
        jid = self._payload_joint
        if held:
            b = self.cfg.world.block
            sx, sy, sz = b.size
            box = pin.Inertia(b.mass, np.zeros(3), np.diag(
                [b.mass * (sy**2 + sz**2) / 12.0, b.mass * (sx**2 + sz**2) / 12.0,
                 b.mass * (sx**2 + sy**2) / 12.0]))
            placement = pin.SE3(self._tool_in_joint @ self.world.grasp_transform())
            self.model.inertias[jid] = self._bare_inertia + placement.act(box)
        else:
            self.model.inertias[jid] = pin.Inertia(self._bare_inertia)
        self.payload = held

    # -- commands -----------------------------------------------------------------------
    def command(self, names: Sequence[str], positions: Sequence[float] = (),
                efforts: Sequence[float] = ()) -> CommandReport:
        """Command joints by name (see the module doc for the modes). Validates everything
        first and raises :class:`JointStateError` / :class:`MockCommandError` with nothing
        applied. Arm and gripper goals clamp to the limits, efforts to the stall torque; a
        rail setpoint outside its range, or before homing (``require_homing``), is rejected
        (as the PMAC driver does). Joints with torque off accept goals but do not move (and
        ``set_torque(True)`` resets the goals to the present position). Takes effect after
        the command latency."""
        if len(positions) == 0 and len(efforts) == 0:
            raise JointStateError("command has neither positions nor efforts")
        goals = check_command(names, positions, self.names) if len(positions) else {}
        torques = check_command(names, efforts, self.names, "effort") if len(efforts) else {}
        rejected = self._rail_problem(goals, torques)
        if rejected:
            # the real pair on rail_arm: the PMAC driver refuses the rail's part, the
            # Dynamixel driver still applies its own joints (nothing at all if only the rail)
            names = [n for n in names if n != self.rail]
            if not names:
                raise MockCommandError(rejected)
            goals.pop(self.rail, None)
        torques.pop(self.rail, None)       # 0 (no extra limit) or refused above
        idx = [self._index[n] for n in names]
        clamped = []
        values = {}
        for n, i in zip(names, idx):
            if n in goals:
                g = float(_clip(goals[n], self.lower[i], self.upper[i]))
                if g != goals[n]:
                    clamped.append(n)
                goals[n] = g
            if n in torques:
                t = torques[n]
                if n in goals:   # a current limit: > 0 limits, 0 = the default limit
                    lim = min(abs(t), self.stall[i]) if t != 0.0 else self.default_limit[i]
                    if abs(t) > self.stall[i]:
                        clamped.append(n)
                else:            # a torque
                    lim = float(_clip(t, -self.stall[i], self.stall[i]))
                    if lim != t:
                        clamped.append(n)
                values[n] = lim
        mode = ControlMode.CURRENT_POSITION if goals else ControlMode.TORQUE

        def apply() -> None:
            imp = self.cfg.imperfections
            new_move = False
            for n, i in zip(names, idx):
                if self.mode[i] is ControlMode.OFF:
                    continue  # torque went off while the command was in flight
                if mode is ControlMode.TORQUE:
                    self._switch(i, mode)
                    self.tau_cmd[i] = values[n]
                    self._effort_time[i] = self.time
                    continue
                if self.mode[i] not in _HOLDING:
                    self._restart_profile(i)
                elif (i == self.g and goals[n] > self.position[i]
                      and self._ref[i] < self.position[i] - 1e-3):
                    # fingers stopped on the block short of their profile: an opening goal
                    # starts from where they are, not from the old goal inside the block
                    self._prof_p[i] = self._ref[i] = self.position[i]
                    self._prof_v[i] = self._ref_v[i] = 0.0
                self._switch(i, self._hold_mode(i))
                self._gap_hold[i] = False
                self._set_limit(i, values.get(n, self.default_limit[i]))
                self.goal[i] = goals[n]
                if self._arm[i] and abs(goals[n] - self._anchor[i]) > imp.move_threshold:
                    new_move = True
                self._anchor[i] = goals[n]
            if new_move and imp.repeatability > 0.0:
                # one draw per move, for every arm joint (the backlash of the whole arm
                # settles anew); streamed small setpoints continue the same move. An arm
                # touching the cell (a link on a pole, the held block on a peg or the
                # table) is held by the contact: its backlash settles anew once it is free
                self._redraw = True
                self._draw_offset()

        self._schedule(apply)
        return CommandReport(applied=tuple(names), clamped=tuple(clamped), mode=mode,
                             rejected=rejected)

    def _held_by_contact(self) -> bool:
        """A link or the held block touches the work cell, or the block is threaded on a
        peg: the arm's backlash cannot settle anew."""
        threaded = self.world.state is BlockState.HELD and self.world.peg is not None
        return bool(self.link_contacts) or _any(self.contact_force) or threaded

    def _draw_offset(self) -> None:
        """Draw the pending new move's repeatability offset, unless the arm is held by a
        contact (then at the first step free of it, off the peg). The drawn offset is the
        goal the true joints settle to (:meth:`_settle_offset`), not a jump."""
        if not self._redraw or self._held_by_contact():
            return
        self._redraw = False
        arm = np.flatnonzero(self._arm)
        self._offset_goal[arm] = self._rng.normal(0.0, self.cfg.imperfections.repeatability,
                                                  len(arm))
        self._settling = True

    def _settle_offset(self, dt: float) -> None:
        """The offset moves towards the move's drawn one at OFFSET_RATE per joint, while no
        contact holds the arm: drawn at once, it moved the true arm by up to ~1 cm in one
        step (a block next to a peg ended 6-8 mm in its top); settling, the contact solve
        and the step's guard see it come as they see a commanded motion."""
        if not self._settling or self._held_by_contact():
            return
        gap = self._offset_goal - self.offset
        limit = OFFSET_RATE * dt
        self.offset = self.offset + _clip(gap, -limit, limit)
        if not _absmax(self._offset_goal - self.offset) > 0.0:
            self._settling = False

    def _rail_problem(self, goals: dict, torques: dict) -> str:
        """Why the PMAC rail driver would refuse the rail's part of a command, or "": an
        effort other than 0 (0 = no extra limit, as for every joint), or an effort without
        a position; a setpoint outside its range; before homing (``require_homing``)."""
        if self.rail is None or (self.rail not in goals and self.rail not in torques):
            return ""
        if self.host is not None and self.host.drives_rail:
            return (f"{self.rail} follows the scripted host motion: host_motion/enable false "
                    "first")
        if self.rail in torques and (self.rail not in goals or torques[self.rail] != 0.0):
            return (f"effort {torques[self.rail]:g} for {self.rail!r} refused: the rail is "
                    "position-controlled (send 0 or no effort)")
        i = self._index[self.rail]
        if not self.lower[i] <= goals[self.rail] <= self.upper[i]:
            return (f"{self.rail} setpoint {goals[self.rail]:g} m outside "
                    f"[{self.lower[i]:g}, {self.upper[i]:g}] m: command rejected")
        if self.require_homing and not self.homed:
            return f"{self.rail} is not homed: call rail/home first"
        return ""

    def _schedule(self, fn: Callable[[], None]) -> None:
        if self.cfg.imperfections.command_latency > 0.0:
            self._pending.append((self.time + self.cfg.imperfections.command_latency, fn))
        else:
            fn()

    def _restart_profile(self, i: int, keep_goal: bool = False) -> None:
        self._yield[i] = self._yield_rate[i] = 0.0   # the reference restarts where it is
        self._prof_p[i] = self._ref[i] = self.position[i]
        self._prof_v[i] = self._ref_v[i] = 0.0
        if not keep_goal:
            self.goal[i] = self.position[i]
            self._set_limit(i, self.default_limit[i])

    def _which(self, names: Sequence[str] | None) -> list[int]:
        if names is None:
            return list(range(self.n))
        unknown = [n for n in names if n not in self._index]
        if unknown:
            raise JointStateError(f"unknown joint(s) {unknown}; known: {self.names}")
        return [self._index[n] for n in names]

    def hold(self, names: Sequence[str] | None = None) -> list[str]:
        """Stop the powered joints among ``names`` (None = all) where they are
        (position-class mode at the default limit, effort commands dropped; torque
        unchanged). Returns the joints held."""
        powered = [i for i in self._which(names) if self.mode[i] is not ControlMode.OFF]
        for i in powered:
            self._restart_profile(i)
            self._switch(i, self._hold_mode(i))
            self._gap_hold[i] = self._gap[i] > 0.0
        return [self.names[i] for i in powered]

    def hold_keeping_grip(self, names: Sequence[str]) -> list[str]:
        """The drivers' ``hold`` service rule (as the Dynamixel driver's): the joints among
        ``names`` stop where they are, but a position-controlled gripper keeps its goal and
        limit (held where it is, a gripper squeezing a block would stop squeezing and drop
        it); an effort-controlled gripper is held like a joint. Returns the joints held."""
        g = self.desc.gripper.name
        torque = self.mode[self._index[g]] is ControlMode.TORQUE
        return self.hold([n for n in names if n != g or torque])

    def set_torque(self, enable: bool, names: Sequence[str] | None = None) -> None:
        """Torque on (the joints among ``names``, None = all, hold where they are in their
        position-class mode) or off (limp)."""
        which = self._which(names)
        if enable:
            errors = sorted(n for n in self.errors if self._index[n] in which)
            if errors:
                raise MockCommandError(f"hardware error on {errors}: reboot first")
            for i in which:
                self._restart_profile(i)
                self.mode[i] = self._hold_mode(i)
                self._gap[i] = 0.0
        else:
            for i in which:
                self.mode[i] = ControlMode.OFF
                self.tau_cmd[i] = 0.0

    def torque_enabled(self) -> list[bool]:
        return [m is not ControlMode.OFF for m in self.mode]

    def inject_error(self, name: str, error: str = "overload") -> None:
        """Fault injection: joint ``name`` reports a hardware error and drops its torque."""
        i = self._index[name]
        self.errors[name] = error
        self.mode[i] = ControlMode.OFF
        self.tau_cmd[i] = 0.0
        self.events.append(WorldEvent("hardware_error", f"{name}: {error}"))

    def reboot(self, names: Sequence[str] = ()) -> list[str]:
        """Reboot servos (empty = those with a hardware error). They come back torque off."""
        unknown = [n for n in names if n not in self._index]
        if unknown:
            raise JointStateError(f"unknown joint(s) {unknown}; known: {self.names}")
        targets = list(names) if names else sorted(self.errors)
        for n in targets:
            self.errors.pop(n, None)
            self.mode[self._index[n]] = ControlMode.OFF
            self.tau_cmd[self._index[n]] = 0.0
        return targets

    def home_rail(self) -> None:
        """Start the rail's home search: it drives to 0 m (the home position) and is homed
        when it gets there (``homed``)."""
        if self.rail is None:
            raise MockCommandError("this variant has no rail")
        i = self._index[self.rail]
        if self.mode[i] is ControlMode.OFF:
            raise MockCommandError(f"{self.rail} amplifier not enabled: set_torque true first")
        if self.host is not None and self.host.drives_rail:
            raise MockCommandError(f"{self.rail} follows the scripted host motion: "
                                   "host_motion/enable false first")
        self._schedule(lambda: self._home(i))

    def _home(self, i: int) -> None:
        if self.mode[i] not in _HOLDING:
            self._restart_profile(i)
        self.mode[i] = self._hold_mode(i)
        self.goal[i] = 0.0
        self.homing = True

    # -- simulation ---------------------------------------------------------------------
    def step(self, dt: float) -> None:
        """Advance the simulation by ``dt`` seconds."""
        if not dt > 0.0:
            return
        self.time += dt
        while self._pending and self._pending[0][0] <= self.time + 1e-12:
            self._pending.popleft()[1]()
        # a mode switch's torque-off gap ends inside this step: step to its end first, then
        # the rest (the gap lasts servo.mode_switch_gap, not a whole step)
        rest = 0.0
        if _any(self._gap):
            self._gap[self._gap < 1e-6] = 0.0
            gaps = self._gap[self._gap > 0.0]
            if gaps.size and float(gaps.min()) < dt - 1e-6:
                rest = dt - float(gaps.min())
                dt -= rest
                self.time -= rest
        if self.host is not None:
            self.host.before_step(dt)
        self._settle_offset(dt)
        # a tool pose computed twice in the step (the guard's, the step's end) once: the
        # model's placements (host motion) are the step's from here on
        self._fk_cache, self._fk_key = not self._poles, None
        self._watchdog()
        any_gap = _any(self._gap)   # torque off during a mode switch (this step)
        sets = self._modes()
        held = sets.holding
        if any_gap:
            gapped = self._gap > 0.0
            held = held & ~gapped
        self._profile(dt, held)
        nk = self.nk
        P = held[:nk]
        D = ~P
        dynamic = _any(D) if any_gap else not sets.chain_held
        if dynamic:
            q = self.position[:nk].copy()
            self._yield[:nk][D] = 0.0
            q[P] = self._ref[:nk][P] + self._yield[:nk][P]
            v = self.velocity[:nk].copy()
            v[P] = self._ref_v[:nk][P]
            a = np.zeros(nk)
            a[P] = ((self._ref_v[:nk] - self._prev_ref_v[:nk]) / dt)[P]
        else:    # every chain joint position-class (the usual case): no masks needed
            q = self._ref[:nk] + self._yield[:nk]
            v = self._ref_v[:nk].copy()
            a = (self._ref_v[:nk] - self._prev_ref_v[:nk]) / dt
        if _any(self._yield_rate[:nk]):
            # a joint giving way moves at its reference's rate plus its yield's
            yielding = P & (self._yield_rate[:nk] != 0.0)
            v[yielding] += self._yield_rate[:nk][yielding]
            a[yielding] = 0.0
        y_before = self._yield[:nk].copy()
        # the contact memory the step starts from (restored if the guard refuses the step)
        memory = (dict(self._pole_normals),
                  {kind: xy.copy() for kind, xy in self._anchors.items()}, self._warm)
        if dynamic:
            q, v = self._dynamics(dt, q, v, a, P, D)
        lim = self.limit[:nk]
        if self.world.state is BlockState.HELD or self._poles or _any(self._yield[:nk]):
            dq, gen = self._contacts(q, P, v=None)
            tau_id = pin.rnea(self.model, self.data, q + dq + self.offset[:nk], v, a)
            tau = tau_id - gen
            q, dq, tau, tau_id = self._limit_efforts(dt, q, v, a, P, dq, gen, tau_id, tau)
        else:   # nothing to touch, nothing given way: no contact solve, no yield
            dq, gen = self._contacts(q, P, v=None)          # (clears the contact state)
            tau_id = pin.rnea(self.model, self.data, q + self.offset[:nk], v, a)
            tau = _clip(tau_id, -lim, lim)
        q, dq, tau, tau_id = self._rate_limit(dt, q, v, a, P, dq, tau, tau_id)
        if dynamic:
            effort = np.zeros(nk)
            effort[P] = tau[P]
            effort[D] = self._applied_torque(D)
        else:
            effort = tau.copy()
        qk = _clip(q + dq, self.lower[:nk], self.upper[:nk])
        qk, v, effort, tau_id = self._guard(dt, qk, v, effort, tau_id, P, D, memory, y_before)
        self._draw_offset()      # a pending new move's offset, once free of contact
        self._yield_rate[:nk] = (self._yield[:nk] - y_before) / dt
        self.velocity[:nk] = v
        self.position[:nk] = qk
        self.effort[:nk] = effort
        self._set_contact_wrench()
        self._check_underpowered(P, tau_id)
        if self.homing:
            i = self._index[self.rail]
            if self.mode[i] is ControlMode.OFF:
                self.homing = False
            elif abs(self.position[i]) < 1e-6 and self._prof_v[i] == 0.0:
                self.homing, self.homed = False, True
                self.events.append(WorldEvent("homed", f"{self.rail} homed at 0 m"))
        self._update_tool()
        self.world.update_held(self._tool)
        self._gripper(dt)
        self._overload(dt, held)
        self._sync_payload()
        if any_gap:   # after the gap: restart from where it is
            self._gap = np.maximum(self._gap - dt, 0.0)
            for i in np.flatnonzero(gapped & (self._gap == 0.0)):
                if self.mode[i] in _HOLDING:   # hold / watchdog: hold where it is now
                    self._restart_profile(int(i), keep_goal=not self._gap_hold[i])
                self._gap_hold[i] = False
        self._report_efforts(gapped if any_gap else None)
        self.events.extend(self.world.take_events())
        self._fk_cache, self._fk_key = False, None
        if self.host is not None:
            self.host.after_step(dt)
        self._record()
        if rest > 0.0:
            self.step(rest)

    def _report_efforts(self, gapped: np.ndarray | None) -> None:
        """The efforts the servos report: the true torque (plus the friction the motor also
        overcomes while moving) through the true torque constant, in whole current units,
        converted back with the nominal one; in current mode the present current follows
        the commanded one (``gapped``: the joints in a mode switch's gap, None if none)."""
        if not self.cfg.current.enabled:
            self.reported_effort = self.effort.copy()
            return
        moving = np.abs(self.velocity) > FRICTION_VELOCITY
        if _any(moving):
            motor = self.effort + np.where(moving, np.sign(self.velocity) * self.coulomb, 0.0)
        else:
            motor = self.effort + 0.0      # (as above: -0.0 + 0.0 is 0.0)
        self._set_reported(self._quantize(motor / self.kt_ratio, None), gapped)

    def _set_reported(self, out: np.ndarray, gapped: np.ndarray | None) -> None:
        """``reported_effort`` := ``out`` (the motors' efforts as the servos measure them),
        but the commanded current in current mode, 0 with torque off or in a mode switch's
        gap, the rail's force as it is."""
        sets = self._modes()
        torque = sets.torque
        if torque:
            out[torque] = self._quantize(self.tau_cmd[torque], torque)
        if sets.off:
            out[sets.off] = 0.0
        if gapped is not None:
            out[gapped] = 0.0
        if self.rail:
            r = self._index[self.rail]
            out[r] = self.effort[r]
        self.reported_effort = out

    def _set_contact_wrench(self) -> None:
        """Ground truth for tests: the wrench (N, N·m) the contacts exert on the held block,
        at tool0 in tool0's axes (``tool_wrench``: force then torque)."""
        rows = getattr(self, "_last_rows", None)
        if rows is None or self.world.state is not BlockState.HELD:
            self.tool_wrench = np.zeros(6)
            return
        dirs, points, _, f, block = rows
        fl, dl, pl = f.tolist(), dirs.tolist(), points.tolist()
        keep = [True] * len(fl) if block is None else block.tolist()
        tx, ty, tz = self._tool[:3, 3].tolist()
        fx = fy = fz = mx = my = mz = 0.0
        for r, fr in enumerate(fl):   # a few rows: plain floats beat numpy's overhead here
            if not keep[r]:           # a link on a pole: not on the block
                continue
            d, (px, py, pz) = dl[r], pl[r]
            ax, ay, az = fr * d[0], fr * d[1], fr * d[2]
            rx, ry, rz = px - tx, py - ty, pz - tz
            fx += ax; fy += ay; fz += az
            mx += ry * az - rz * ay; my += rz * ax - rx * az; mz += rx * ay - ry * ax
        # the world-frame force and moment, rotated into tool0's axes (rows: v^T R = (R^T v)^T)
        self.tool_wrench = (np.array([[fx, fy, fz], [mx, my, mz]]) @ self._tool[:3, :3]).ravel()

    def _watchdog(self) -> None:
        torque = self._modes().torque
        if not torque:
            return
        late = [i for i in torque if self.time - self._effort_time[i] > self.effort_timeout]
        for i in late:
            self._restart_profile(i)
            self._switch(i, self._hold_mode(i))
            self._gap_hold[i] = self._gap[i] > 0.0
        if late:
            self.events.append(WorldEvent(
                "watchdog", f"no effort command for {self.effort_timeout:g} s: holding "
                + ", ".join(self.names[i] for i in late)))

    def _profile(self, dt: float, held: np.ndarray) -> None:
        """Velocity/acceleration-limited profile towards the goal, then the lag."""
        self._prev_ref_v = self._ref_v.copy()
        if (not _any(self._prof_v) and not _any(self._ref_v)
                and not _any(self._prof_p != self.goal)
                and not _any(self._ref != self._prof_p)):
            return                                  # every joint settled on its goal
        e = self.goal - self._prof_p
        # Fastest speed v = m·a·dt from which braking at amax in steps of dt (v, v - a·dt,
        # ..., while > 0) covers exactly |e|: with n = floor(m), |e| = dt·(v(n+1) - a·dt·T_n)
        # where T_n = n(n+1)/2; n follows from T_n <= |e|/(a·dt²) < T_(n+1).
        # an unlimited acceleration (inf) moves at up to vmax straight to the goal
        limited = np.isfinite(self.amax)
        adt = np.where(limited, self.amax, 1.0) * dt
        big_e = np.abs(e) / (adt * dt)
        n = np.floor((np.sqrt(1.0 + 8.0 * big_e) - 1.0) / 2.0)
        v_stop = adt * (big_e + n * (n + 1.0) / 2.0) / (n + 1.0)
        v_stop = np.where(limited, v_stop, np.abs(e) / dt)
        v_des = np.minimum(np.maximum(np.sign(e) * v_stop, -self.vmax), self.vmax)
        v_new = np.where(limited, np.minimum(np.maximum(v_des, self._prof_v - adt),
                                             self._prof_v + adt), v_des)
        # on the braking curve: follow it exactly (it decelerates at amax, step by step)
        braking = limited & (v_new * e > 0.0) & (np.abs(v_des) < np.abs(v_new))
        v_new = np.where(braking, v_des, v_new)
        p_new = self._prof_p + v_new * dt
        done = (self.goal - p_new) * e <= 0.0
        p_new = np.where(done, self.goal, p_new)
        v_new = np.where(done, e / dt, v_new)
        self._prof_p = np.where(held, p_new, self._prof_p)
        self._prof_v = np.where(held, v_new, 0.0)
        lag = self.cfg.servo.lag
        alpha = 1.0 if lag <= 0.0 else 1.0 - math.exp(-dt / lag)
        ref = self._ref + alpha * (self._prof_p - self._ref)
        ref = np.where(np.abs(self._prof_p - ref) < 1e-12, self._prof_p, ref)
        self._ref_v = np.where(held, (ref - self._ref) / dt, 0.0)
        self._ref = np.where(held, ref, self._ref)

    def _applied_torque(self, D: np.ndarray) -> np.ndarray:
        """Torque (N·m) the motors of the dynamic joints ``D`` exert: a commanded torque in
        whole current units through the true torque constant (friction: in the dynamics);
        0 with torque off or during a mode switch."""
        idx = np.flatnonzero(D)
        return np.array([self.kt_ratio[i] * float(self._quantize(self.tau_cmd[i], i))
                         if self.mode[i] is ControlMode.TORQUE and self._gap[i] == 0.0
                         else 0.0 for i in idx])

    def _dynamics(self, dt: float, q: np.ndarray, v: np.ndarray, a: np.ndarray,
                  P: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Integrate the torque-mode / limp joints ``D`` (others follow their reference).

        Sub-steps of semi-implicit Euler with implicit viscous damping; the mass matrix and
        the contact rows are evaluated once per step (their interferences follow the
        sub-steps' motion linearly), the bias forces (RNEA) every sub-step."""
        h = dt / SUBSTEPS
        nk = self.nk
        tau_d = self._applied_torque(D)
        damping = self.cfg.servo.damping
        q, v = q.copy(), v.copy()
        lo, hi = self.lower[:nk][D], self.upper[:nk][D]
        m = pin.crba(self.model, self.data, q + self.offset[:nk])
        m = np.triu(m) + np.triu(m, 1).T
        # viscous damping plus Coulomb friction, both implicit (the friction as a viscous
        # term c = F_c / max(|v|, FRICTION_VELOCITY), steep near rest: static friction)
        c_d = damping + self.coulomb[:nk][D] / np.maximum(np.abs(v[D]), FRICTION_VELOCITY)
        m_dd = m[np.ix_(D, D)]
        mdd = m_dd + h * np.diag(c_d)
        rows = self._contact_rows(q) if self.world.state is BlockState.HELD or self._poles \
            else None
        kinv = np.where(P, 1.0 / self.stiffness[:nk], 0.0)
        q0 = q.copy()
        # the motor's torque-speed line (back-EMF): a current-mode servo exerts at most
        # stall·(1 - v/v_max) along its motion (v_max, the joint's velocity limit, taken as
        # its no-load speed), braking beyond it; on the line the torque is implicit in v
        driven = np.array([self.mode[i] is ControlMode.TORQUE and self._gap[i] == 0.0
                           for i in np.flatnonzero(D)])
        stall = self.stall[:nk][D]
        c_emf = stall / self.vmax[:nk][D]
        for _ in range(SUBSTEPS):
            gen = np.zeros(nk)
            lhs, tau_s = mdd, tau_d
            if _any(driven):
                up, down = tau_d > stall - c_emf * v[D], tau_d < -stall - c_emf * v[D]
                line = driven & (up | down)
                if _any(line):
                    tau_s = np.where(line, np.where(up, stall, -stall) - c_emf * v[D], tau_d)
                    lhs = lhs + h * np.diag(np.where(line, c_emf, 0.0))
            if rows is not None:
                _, jr, p0, owner, tangential, _ = rows
                f = self._solve_contacts(jr, p0 - jr @ (q - q0), owner, tangential, kinv, v)
                gen = jr.T @ f
                on = f != 0.0
                if _any(on):   # the contact springs implicit too (stiff branch: 250 kN/m)
                    jd = jr[on][:, D]
                    k_q = (jd.T * (1.0 / self._row_comp[on])) @ jd
                    lhs = lhs + (h * h) * k_q
                    tau_s = tau_s - h * (k_q @ v[D])
            b = pin.rnea(self.model, self.data, q + self.offset[:nk], v, a)
            rhs = tau_s + gen[D] - b[D] - c_d * v[D]
            vd = v[D] + h * np.linalg.solve(lhs, rhs)
            if rows is not None:
                vd = self._impact(jr, p0 - jr @ (q - q0), tangential, D, m_dd, vd, h)
            qd = q[D] + h * vd
            at_limit = (qd <= lo) | (qd >= hi)
            v[D] = np.where(at_limit, 0.0, vd)
            q[D] = _clip(qd, lo, hi)
        return q, v

    @staticmethod
    def _impact(jr: np.ndarray, p0: np.ndarray, tangential: np.ndarray, D: np.ndarray,
                m_dd: np.ndarray, vd: np.ndarray, h: float) -> np.ndarray:
        """Inelastic impact of the dynamic joints: a normal contact that would end this
        sub-step deeper than HARD_DEPTH while still approaching loses its approach speed
        (the impulse of least kinetic energy that stops it, M⁻¹Jᵀλ, λ >= 0), as a block
        meeting a rigid surface does; a penalty spring alone would let a fast block sink
        v·sqrt(m/k) deep before pushing it out."""
        jd = jr[:, D]
        rate = jd @ vd                              # d(depth)/dt = -rate
        hit = [i for i in range(len(p0)) if not tangential[i] and rate[i] < 0.0
               and p0[i] - h * rate[i] > HARD_DEPTH]
        if not hit:
            return vd
        ja = jd[hit]
        minv_jt = np.linalg.solve(m_dd, ja.T)
        lam = np.linalg.lstsq(ja @ minv_jt, -rate[hit], rcond=None)[0]
        lam = np.maximum(lam, 0.0)
        return vd + minv_jt @ lam

    def _contacts(self, q: np.ndarray, P: np.ndarray,
                  v: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Contact forces on the held block at chain positions ``q`` (encoder values).

        Returns the deflection of the compliant (position-mode) joints and the generalized
        force of the contacts on every chain joint. Each contact is a penalty spring of the
        world's stiffness in series with the servos' stiffness (and, with ``v`` given, a
        damper against dynamic joints); on horizontal surfaces (peg top, table) tangential
        springs anchored where the block touched down give Coulomb friction (``friction``):
        the block sticks while the tangential force is inside the cone, else slides."""
        nk = self.nk
        zero = np.zeros(nk)
        self._contact_rows_used = None
        warm, self._warm = self._warm, None
        if self.world.state is not BlockState.HELD and not self._poles:
            self.contact_force = np.zeros(3)
            self._last_rows = None
            self._anchors.clear()
            return zero, zero
        kinv = np.where(P, 1.0 / self.stiffness[:nk], 0.0)
        # Quasi-static: linearize, solve, and re-linearize once at the deflected joints if
        # the linearization point was more than RELINEARIZE from them. Which contacts there
        # are is decided at the undeflected q. The first linearization point is q, or, when
        # every contact there is on a horizontal surface (a constant normal: no geometry to
        # re-linearize but the arm's) and the block was in contact at the last step, the
        # last step's deflected joints: in a sustained press one solve is then enough.
        if warm is not None:
            at_q = self.world.contacts(self._tool_at(q))
            # (links on a pole: linearized where they are, near the pole's surface)
            if (not at_q and not self.link_contacts) or not all(c.frictional for c in at_q) \
                    or (self.world.peg is not None and self.world.state is BlockState.HELD):
                # (threaded: the hole's wall is curved)
                warm = None
        q_lin, solved = (q, None) if warm is None else (q + warm, None)
        # threaded: the wall's normal where the arm's compliance really puts the block
        side = self._wall_normal(q, q, kinv)
        # (a warm start that missed gets the cold start's number of re-linearizations)
        for _ in range((LINEARIZATIONS + (warm is not None)) if v is None else 1):
            # re-linearizing, the threaded peg's side is the plane of its normal at q (a
            # linear solution may overshoot the curved side, even past the axis)
            rows = self._contact_rows(q_lin, side)
            if rows is None and q_lin is not q:   # contact lost where it was: try q itself
                q_lin = q
                rows = self._contact_rows(q)
            if rows is None:
                break
            contacts, jr, p0, owner, tangential, points = rows
            if q_lin is q and side is None:
                side = next((c.normal for c in contacts if c.kind.startswith("peg_side:")
                             and self.world.peg and c.kind.endswith(":" + self.world.peg)),
                            None)
            p0 = p0 + jr @ (q_lin - q)             # the interference at the undeflected q
            f = self._solve_contacts(jr, p0, owner, tangential, kinv, v)
            jtf = jr.T @ f
            deflection = kinv * jtf
            solved = contacts, jr, p0, f, owner, tangential, points, q_lin, jtf, deflection
            if _absmax(q + deflection - q_lin) < RELINEARIZE:  # rad: re-linearizing
                break                                                # would change ~nothing
            q_lin = q + deflection
            if side is not None:     # the wall's normal seen from the new linearization
                side = self._wall_normal(q_lin, q, kinv, side)
        if solved is None:
            self.contact_force = np.zeros(3)
            self._last_rows = None
            self.link_contacts = []
            if v is None:
                self._pole_normals = {}
            self._anchors.clear()
            return zero, zero
        contacts, jr, p0, f, owner, tangential, points, q_used, jtf, dq = solved
        lo, hi = self.lower[:nk], self.upper[:nk]
        qd = q + dq
        stopped = ((qd < lo) & (dq < 0.0)) | ((qd > hi) & (dq > 0.0))
        if _any(stopped):   # joints pushed onto their mechanical stops are rigid there
            kinv = np.where(stopped, 0.0, kinv)
            f = self._solve_contacts(jr, p0, owner, tangential, kinv, v)
            jtf = jr.T @ f
            dq = kinv * jtf
        self._contact_rows_used = jr, p0, f, self._rows_map
        if v is None:   # move friction anchors of sliding contacts along with the block
            anchors = self._anchors
            kinds = set()
            moved = None
            first = self._row_first        # each contact's first (normal) row
            for ci, c in enumerate(contacts):
                kinds.add(c.kind)
                if c.kind in anchors:      # frictional: its two tangential rows follow
                    if moved is None:
                        moved = jr @ (q + dq - q_used)        # points were taken at q_used
                    t = [first[ci] + 1, first[ci] + 2]
                    point = self._slides[ci][:2] + moved[t]
                    anchors[c.kind] = point + f[t] / self.cfg.world.contact_stiffness
            if not kinds.issuperset(anchors):
                for kind in list(anchors):
                    if kind not in kinds:
                        del anchors[kind]
            self._warm = dq
        dirs = self._row_dirs_array
        if self._poles:
            block = np.array([not contacts[o].kind.startswith("pole:") for o in owner])
            self.contact_force = dirs[block].T @ f[block] if _any(block) else np.zeros(3)
            self._link_rows = [(c, self._row_first[ci])
                               for ci, c in enumerate(contacts) if c.kind.startswith("pole:")]
            self._set_link_contacts(f)
        else:
            block = None          # every row is on the block
            self.contact_force = dirs.T @ f
        if v is None and self._poles:
            self._pole_normals = {c.kind: c.normal for ci, c in enumerate(contacts)
                                  if c.kind.startswith("pole:")
                                  and f[self._row_first[ci]] > 0.0}
        self._last_rows = (dirs, self._row_points, owner, f, block)
        return dq, jtf

    def _wall_normal(self, q_lin: np.ndarray, q: np.ndarray, kinv: np.ndarray,
                     previous: np.ndarray | None = None) -> np.ndarray | None:
        """The normal (3,, horizontal, unit) of the threaded hole's wall against the held
        block, for the contact solve linearized at ``q_lin`` from the undeflected joints
        ``q`` (servo compliances ``kinv``: rad/N·m, m/N for the rail): None when the
        block at ``q`` is within
        the clearance (no wall contact), ``previous`` when there is no better one.

        The wall is a circle of radius r (the clearance) about the peg's axis, far more
        curved than the arm's deflections: the plane of its normal at ``q`` lets the block
        slide tangentially (the arm's compliance C at the block is not isotropic) and end
        centimetres deep in the curved wall. Solved in the horizontal plane instead: the
        block's offset from the axis at ``q``, b0, moves by C F under the wall's force
        F = -lam u, and ends on the ray u at the distance r + lam / k_env:
        (rho I + lam C) u = b0, rho = r + lam / k_env, |u| = 1; |u(lam)| falls with lam,
        so lam is found by bisection. The normal is -u."""
        at = self.world.hole_offset(self._tool_at(q_lin))
        if at is None:
            return previous
        point, b_lin = at
        qt = q_lin + self.offset[:self.nk]
        j6 = pin.computeFrameJacobian(self.model, self.data, qt, self.tool_id,
                                      pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        jp = (j6[:3] - _skew(point - self.data.oMf[self.tool_id].translation) @ j6[3:])[:2]
        b0 = b_lin + jp @ (q - q_lin)
        r = self.cfg.world.clearance(self.world.peg)
        e0 = math.hypot(b0[0], b0[1])
        if e0 <= r:
            return previous
        c = (jp * kinv) @ jp.T
        c00, c01, c11 = float(c[0, 0]), float(0.5 * (c[0, 1] + c[1, 0])), float(c[1, 1])
        bx, by = float(b0[0]), float(b0[1])
        k_env = self.cfg.world.contact_stiffness

        f_hard, k_hard = k_env * HARD_DEPTH, HARD_FACTOR * k_env

        def u_of(lam: float) -> tuple[float, float]:
            # the wall's spring as the solve has it: stiff beyond HARD_DEPTH
            rho = r + (lam / k_env if lam <= f_hard else HARD_DEPTH + (lam - f_hard) / k_hard)
            a, b, d = rho + lam * c00, lam * c01, rho + lam * c11
            det = a * d - b * b
            return (d * bx - b * by) / det, (a * by - b * bx) / det
        # at hi the spring alone reaches e0: rho(hi) = e0, so |u| <= 1 (C >= 0)
        hi = k_env * (e0 - r) if e0 - r <= HARD_DEPTH else \
            f_hard + k_hard * (e0 - r - HARD_DEPTH)
        lo = 0.0
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            ux, uy = u_of(mid)
            if ux * ux + uy * uy > 1.0:
                lo = mid
            else:
                hi = mid
        ux, uy = u_of(hi)
        norm = math.hypot(ux, uy)
        if not norm > 0.0:
            return previous
        return np.array([-ux / norm, -uy / norm, 0.0])

    def _contact_rows(self, q: np.ndarray, side_normal: np.ndarray | None = None):
        """Contact rows of the held block at chain positions ``q``: the contacts, the
        Jacobian rows (m/rad) of each constrained direction, their interferences (m), the
        contact each row belongs to, which rows are tangential, and the contact points."""
        qt = q + self.offset[:self.nk]
        tool = self._tool_at(q)
        contacts = self.world.contacts(tool, side_normal, CONTACT_MARGIN)
        if self._poles:
            contacts = contacts + self._pole_contacts()
        if not contacts:
            return None
        j6 = pin.computeFrameJacobian(self.model, self.data, qt, self.tool_id,
                                      pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        rows, p0, owner, tangential, dirs, points = [], [], [], [], [], []
        first, row_points, slides = [], [], []
        for ci, c in enumerate(contacts):
            first.append(len(rows))
            if c.kind.startswith("pole:"):     # on a link: that link's frame Jacobian
                fid = self._capsule_frame[c.kind.rsplit(":", 1)[1]]
                jf = pin.computeFrameJacobian(self.model, self.data, qt, fid,
                                              pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
                jp = jf[:3] - _skew(c.point - self.data.oMf[fid].translation) @ jf[3:]
            else:
                jp = j6[:3] - _skew(c.point - tool[:3, 3]) @ j6[3:]
            rows.append(c.normal @ jp); p0.append(c.depth); owner.append(ci)
            tangential.append(False); dirs.append(c.normal); points.append(c.point)
            row_points.append(c.point)
            if c.frictional:
                anchor = self._anchors.get(c.kind)
                if anchor is None:   # touch-down: where the block actually is, not where
                    # the linearization point (e.g. the commanded joints) would put it
                    anchor = self._anchors[c.kind] = \
                        self.world.block_pose(self._tool)[:2, 3].copy()
                slide = c.point if c.slide is None else c.slide   # friction's material point
                if slide is not c.point:
                    jp = j6[:3] - _skew(slide - tool[:3, 3]) @ j6[3:]
                for axis in (0, 1):
                    rows.append(jp[axis]); p0.append(anchor[axis] - slide[axis])
                    owner.append(ci); tangential.append(True); dirs.append(_AXES[axis])
                    row_points.append(slide)
            slides.append(c.point if c.slide is None else c.slide)
        self._row_dirs_array = np.array(dirs)      # (rows, 3): each row's direction
        self._row_points = np.array(row_points)    # (rows, 3): where each row's force acts
        self._row_first = first                    # each contact's first row
        self._slides = slides                      # each contact's friction point
        return (contacts, np.array(rows), np.array(p0), np.array(owner),
                np.array(tangential), points)

    def _set_link_contacts(self, f: np.ndarray) -> None:
        """``link_contacts``: (capsule, pole, depth m at the commanded joints, force N on
        the link) of every link touching a pole, from the contact rows' forces ``f``."""
        self.link_contacts = [(c.kind.split(":")[2], c.kind.split(":")[1], c.depth,
                               c.normal * f[row]) for c, row in self._link_rows]

    def _pole_contacts(self) -> list:
        """Capsule-pole contacts at the configuration last put in ``self.data``."""
        segments = []
        self._capsule_frame = {}
        for name, radius, fid, (a, b) in self._capsules:
            m = self.data.oMf[fid]
            rot, pos = m.rotation, m.translation
            segments.append((name, radius, rot @ a + pos, rot @ b + pos))
            self._capsule_frame[name] = fid
        return self.world.pole_contacts(segments, self._pole_normals)

    def _solve_contacts(self, jr: np.ndarray, p0: np.ndarray, owner: np.ndarray,
                        tangential: np.ndarray, kinv: np.ndarray,
                        v: np.ndarray | None) -> np.ndarray:
        """Forces (N) of the contact rows: penalty springs in series with the servo springs,
        (I/k_env + J K⁻¹ Jᵀ) f = p0 over the active rows; a contact whose normal force would
        pull is dropped; a contact whose tangential force leaves the friction cone slides:
        its friction, mu x its normal force along that direction, is substituted into the
        system (its tangential rows dropped) and everything re-solved.

        The rows come as built by :meth:`_contact_rows`: per contact its normal row, then its
        tangential rows if any. The systems are tiny (3-6 rows), so the bookkeeping is done
        on Python lists: numpy's per-call overhead would dominate."""
        k_env = self.cfg.world.contact_stiffness
        m = len(p0)
        base = (jr * kinv) @ jr.T
        a_full = base.copy()
        a_full.flat[::m + 1] += 1.0 / k_env
        damp = CONTACT_DAMPING * (jr @ v) if v is not None else None
        f = self._solve_rows(a_full, p0, tangential, damp)
        # Beyond HARD_DEPTH the surface stiffens (HARD_FACTOR x): normal rows pressed deeper
        # are solved again on the stiff branch, f = k d0 + k_hard (d - d0), so no servo can
        # push the block more than ~HARD_DEPTH into a surface.
        fl, tl = f.tolist(), tangential.tolist()
        deep = [i for i in range(m) if not tl[i] and fl[i] > k_env * HARD_DEPTH]
        self._row_deep = (m, deep)
        if deep:
            a_full = base.copy()
            a_full.flat[::m + 1] += self._row_comp
            f = self._solve_rows(a_full, p0 - self._row_shift, tangential, damp)
        return f

    @property
    def _row_comp(self) -> np.ndarray:
        """Compliance (m/N) of each row of the last contact solve: 1/k_env, or the stiff
        branch's 1/(HARD_FACTOR k_env) for a normal row pressed beyond HARD_DEPTH."""
        m, deep = self._row_deep
        k_env = self.cfg.world.contact_stiffness
        out = np.full(m, 1.0 / k_env)
        out[deep] = 1.0 / (HARD_FACTOR * k_env)
        return out

    @property
    def _row_shift(self) -> np.ndarray:
        """Interference offset (m) of each row of the last contact solve: the stiff
        branch's force is k_env d0 + k_hard (d - d0), a spring k_hard shifted by this."""
        m, deep = self._row_deep
        out = np.zeros(m)
        k_env = self.cfg.world.contact_stiffness
        out[deep] = HARD_DEPTH * (1.0 - k_env / (HARD_FACTOR * k_env))
        return out

    def _solve_rows(self, a_full: np.ndarray, p0: np.ndarray, tangential: np.ndarray,
                    damp: np.ndarray | None) -> np.ndarray:
        """The active-set solve of :meth:`_solve_contacts` for one compliance matrix."""
        mu = self.cfg.world.friction
        m = len(p0)
        # per contact: its normal row and its tangential rows
        groups: list[tuple[int, list[int]]] = []
        for i in range(m):
            if tangential[i]:
                groups[-1][1].append(i)
            else:
                groups.append((i, []))
        active = list(range(len(groups)))
        # sliding contacts: their tangential force is mu x their normal force along a
        # direction u (from the trial force that left the cone); substituted into the
        # system, so the normal rows are solved with the friction they really get
        sliding: dict[int, np.ndarray] = {}
        f = np.zeros(m)
        for _ in range(4 * len(groups) + 4):
            free = [i for c in active for i in
                    ((groups[c][0],) if c in sliding else (groups[c][0], *groups[c][1]))]
            if not free:
                f = np.zeros(m)                         # rows of dropped contacts: 0
                break
            if len(free) == m:                          # every row (the usual case)
                a = a_full.copy() if sliding else a_full
            else:
                a = a_full[free][:, free]
            for c, u in sliding.items():
                if c in active:
                    n, t = groups[c]
                    col = free.index(n)
                    a[:, col] = a[:, col] + mu * (a_full[free][:, t] @ u)
            if len(free) == m:
                f = np.linalg.solve(a, p0)
            else:
                f = np.zeros(m)                         # rows of dropped contacts: 0
                f[free] = np.linalg.solve(a, p0[free])
            for c, u in sliding.items():
                if c in active:
                    n, t = groups[c]
                    f[t] = mu * u * f[n]
            if damp is not None:
                f[free] -= damp[free]
            # friction first: a tangential force beyond the cone (none if the normal force
            # pulls) makes its contact slide, then the normal forces are judged: a far
            # friction anchor must not make a real contact look pulling
            changed = False
            fl = f.tolist()
            for c in active:
                n, t = groups[c]
                if not t or c in sliding:
                    continue
                cap = mu * max(fl[n], 0.0)
                norm = math.hypot(*(fl[i] for i in t))
                if norm > cap * (1.0 + 1e-9):
                    sliding[c] = np.array([fl[i] for i in t]) / norm if norm > 0.0 \
                        else np.zeros(len(t))
                    changed = True
            if changed:
                continue
            pulling = [c for c in active if f[groups[c][0]] < 0.0]
            if not pulling:
                break
            # drop the one pulling most only: with it gone the others may push
            worst = min(pulling, key=lambda c: f[groups[c][0]])
            active = [c for c in active if c != worst]
        self._rows_map = self._unknowns_map(m, groups, active, sliding, mu)
        return f

    @staticmethod
    def _unknowns_map(m: int, groups: list, active: list[int], sliding: dict, mu: float
                      ) -> tuple[list[int], np.ndarray]:
        """The rows solved for in an active-set solve's outcome and the map S (m x k) from
        their forces to every row's: f = S f_free. A dropped contact's rows get nothing; a
        sliding contact's tangential rows get mu u x its normal force."""
        free = [i for c in active for i in
                ((groups[c][0],) if c in sliding else (groups[c][0], *groups[c][1]))]
        smap = np.zeros((m, len(free)))
        col = {row: k for k, row in enumerate(free)}
        for row, k in col.items():
            smap[row, k] = 1.0
        for c, u in sliding.items():
            if c in active:
                n, t = groups[c]
                smap[t, col[n]] = mu * u
        return free, smap

    def _limit_efforts(self, dt: float, q: np.ndarray, v: np.ndarray, a: np.ndarray,
                       P: np.ndarray, dq: np.ndarray, gen: np.ndarray, tau_id: np.ndarray,
                       tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Servos that would exceed their torque limit against a contact give way.

        A position-class servo's spring rests at its reference plus its yield ``_yield``
        (a state: where a servo at its limit was pushed back to). A joint whose torque would
        exceed its limit yields: the linear solve of the contact rows with the saturated
        joints free (their generalized contact force fixed at tau_id - limit),

            (I/k_env + J_u K_u⁻¹ J_uᵀ) f + J_s dq_s = p0,   J_sᵀ f = tau_id_s - tau_limit_s,

        over the rows the last contact solve solved for, with f = S f_free (its dropped
        contacts' rows 0, its sliding contacts' tangential rows mu u times their normal
        force: the contact as the step has it, not held stuck), gives how far they must
        move; a joint with a yield and torque to spare moves back
        towards its reference (half its slack per iteration). The yield moves at most
        ``vmax·dt`` per step (the servo's speed: no fling), and after every change of it the
        full contact solve (geometry, friction cone, stiff branch) runs again at the new
        joints, so the forces are the contact's at the position reached: what the limited
        joints exert, up to the residual of the last iteration (a few iterations per step,
        converging over the steps; the reported efforts are clipped to the limits).

        Returns the (yielded) undeflected joints, their deflection, the efforts and tau_id."""
        nk = self.nk
        lim = self.limit[:nk]
        y = self._yield[:nk]
        if self._contact_rows_used is None and not _any(y):   # no contact, no yield
            return q, dq, _clip(tau, -lim, lim), tau_id
        can = P & (np.abs(tau_id) <= lim)          # an under-powered joint is held (not sagging)
        over = can & (np.abs(tau) > lim) & (gen != 0.0)
        if not _any(over) and not _any(y[P]):
            return q, dq, _clip(tau, -lim, lim), tau_id
        ref = q - y
        budget = self.vmax[:nk] * dt                 # the yield's travel left this step
        stiff = self.stiffness[:nk]
        for _ in range(YIELD_ITERATIONS):
            target = y.copy()
            slack = np.maximum(lim - np.abs(tau), 0.0)
            back = P & ~over & (y != 0.0)
            target[back] -= np.sign(y[back]) * np.minimum(np.abs(y[back]),
                                                         0.5 * slack[back] / stiff[back])
            if _any(over) and self._contact_rows_used is not None:
                f, dq_s, over = self._yield_solve(P, over, can, tau_id, tau, lim)
                # the saturated joints end at q + dq_s, their spring at the limit torque
                target[over] = y[over] + dq_s - (tau_id[over] - np.sign(tau[over])
                                                 * lim[over]) / stiff[over]
            change = _clip(target - y, -budget, budget)
            change[~P] = 0.0
            if not _absmax(change) > 1e-12:
                break
            budget = budget - np.abs(change)
            y += change
            q = ref + y
            dq, gen = self._contacts(q, P, v=None)
            tau_id = pin.rnea(self.model, self.data, q + dq + self.offset[:nk], v, a)
            tau = tau_id - gen
            can = P & (np.abs(tau_id) <= lim)
            over = can & (np.abs(tau) > lim) & (gen != 0.0)
        return q, dq, _clip(tau, -lim, lim), tau_id

    def _yield_solve(self, P: np.ndarray, over: np.ndarray, can: np.ndarray,
                     tau_id: np.ndarray, tau: np.ndarray, lim: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The linear solve of :meth:`_limit_efforts` on the last contact rows (adding
        joints that saturate in turn): the contact forces, the saturated joints' motion
        and which joints are saturated."""
        nk = self.nk
        jr, p0, _, (free, smap) = self._contact_rows_used
        m, k = len(p0), len(free)
        sign = np.sign(tau)
        f, dq_s = np.zeros(m), np.zeros(int(over.sum()))
        if not k:
            return f, dq_s, over
        comp, shift = self._row_comp, self._row_shift
        for _ in range(nk):
            kinv_u = np.where(P & ~over, 1.0 / self.stiffness[:nk], 0.0)
            js = jr[:, over]
            ns = js.shape[1]
            # the contact solve's own rows: its dropped contacts' rows get no force, its
            # sliding contacts' friction is mu x their normal force (f = S f_free), so the
            # yield is solved against the contact the step really has, not a stuck one
            a_s = ((np.diag(comp) + (jr * kinv_u) @ jr.T) @ smap)[free]
            lhs = np.block([[a_s, js[free]], [js.T @ smap, np.zeros((ns, ns))]])
            rhs = np.r_[(p0 - shift)[free], tau_id[over] - sign[over] * lim[over]]
            sol = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
            f, dq_s = smap @ sol[:k], sol[k:]
            tau_new = tau_id - jr.T @ f
            newly = can & ~over & (np.abs(tau_new) > lim)
            if not _any(newly):
                break
            sign = np.where(newly, np.sign(tau_new), sign)
            over = over | newly
        return f, dq_s, over

    def _rate_limit(self, dt: float, q: np.ndarray, v: np.ndarray, a: np.ndarray,
                    P: np.ndarray, dq: np.ndarray, tau: np.ndarray, tau_id: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """No jump: the position-class joints move at most their velocity limit per step
        (a spring released from a contact, a yield: at the servo's speed). A faster motion
        is scaled down along its joint-space direction, the rest kept in the yields
        (recovered in the next steps), and the contact solved again there, so the pose
        reached is a contact equilibrium (no unchecked pose in between)."""
        nk = self.nk
        if not _any(P):
            return q, dq, tau, tau_id
        prev = self.position[:nk]
        move = _clip(q + dq, self.lower[:nk], self.upper[:nk]) - prev
        if _any(~P):
            ratio = max((np.abs(move[P]) / (self.vmax[:nk][P] * dt)).tolist())
        else:
            ratio = max((np.abs(move) / self._step_travel(dt)).tolist())
        if not ratio > 1.0:
            return q, dq, tau, tau_id
        shift = np.where(P, move * (1.0 / ratio - 1.0), 0.0)
        self._yield[:nk] += shift
        q = q + shift
        dq, gen = self._contacts(q, P, v=None)
        tau_id = pin.rnea(self.model, self.data, q + dq + self.offset[:nk], v, a)
        lim = self.limit[:nk]
        return q, dq, _clip(tau_id - gen, -lim, lim), tau_id

    def _step_travel(self, dt: float) -> np.ndarray:
        """vmax·dt (rad, m) of the chain joints: the most a joint moves in a step of dt."""
        if self._travel[0] != dt:
            self._travel = (dt, self.vmax[:self.nk] * dt,
                            JUMP_FACTOR * self.vmax[:self.nk] * dt)
        return self._travel[1]

    def _jump_travel(self, dt: float) -> np.ndarray:
        """JUMP_FACTOR·vmax·dt: a position-class joint moving more in a step jumped."""
        self._step_travel(dt)
        return self._travel[2]

    def _deepest(self, q: np.ndarray) -> float:
        """Deepest interference (m) of the block (held) and the links' capsules (poles) in
        the work cell at chain positions ``q``; 0 without contact. The wall of a threaded
        block's hole counts (its excess over the clearance): the contact solve puts the
        wall's normal where the arm's compliance really takes the block (``_wall_normal``),
        so a sideways pull ends within ~1-2 mm of it and the guard rarely has to act."""
        tool = self._tool_at(q)
        depths = [c.depth for c in self.world.contacts(tool)]
        depths.append(self.world.penetration(tool))   # the geometry alone
        if self._poles:
            depths += [c.depth for c in self._pole_contacts()]
        return max(depths, default=0.0)

    def _blocked_by(self, qk: np.ndarray, jump: np.ndarray) -> str:
        """The ``blocked`` event's text: the contacts at the refused pose, the joints."""
        tool = self._tool_at(qk)
        found = [f"{c.kind} {c.depth * 1e3:.1f} mm" for c in self.world.contacts(tool)
                 if c.depth > 0.0]
        if self._poles:
            found += [f"{c.kind} {c.depth * 1e3:.1f} mm" for c in self._pole_contacts()
                      if c.depth > 0.0]
        names = [self.names[i] for i in np.flatnonzero(jump)]
        what = ", ".join(found) or "a contact"
        tail = f" (the contact solve would throw {', '.join(names)})" if names else ""
        return (f"the arm is blocked: {what} at the commanded motion{tail}; the joints stay "
                "where they are, their servos at most at their limits")

    def _guard(self, dt: float, qk: np.ndarray, v: np.ndarray, effort: np.ndarray,
               tau_id: np.ndarray, P: np.ndarray, D: np.ndarray, memory: tuple,
               y_before: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The last check of a step: the position-class joints ``P`` may not jump (move more
        than JUMP_FACTOR times their velocity limit in the step), and no joint may end the
        step with a link or the block more than GUARD_DEPTH into a pole, a peg or the table,
        unless the pose it would keep instead (the last one, as it is now: host motion, a
        new offset or a grasp may have moved it) is deeper still. The contact solve is a linearization (once per
        step for the torque-mode joints ``D``); where it fails (a link caught edge-on, a
        near-singular yield solve, a torque-driven block hitting the table fast) its pose is
        not taken: the joints stay where they were, as against a rigid obstacle (the
        torque-mode ones stopped: an inelastic impact), and each position-class servo's
        spring is held at most at its torque limit there by its yield, so a servo the
        obstacle blocks stays at its limit and overloads (OVERLOAD_TIME), as the real one
        does. ``memory``: the contact memory (link contacts' sides, friction anchors,
        warm start) at the step's start, restored with the pose; ``y_before``: the yields
        at the step's start (the spring is held from there). Returns the positions,
        velocities, efforts and inverse-dynamics torques of the step."""
        nk = self.nk
        prev = self.position[:nk]
        jump = P & (np.abs(qk - prev) > self._jump_travel(dt))
        deep = False
        depth = 0.0
        if self.world.state is BlockState.HELD or self._poles:
            depth = self._deepest(qk)
            if depth > GUARD_DEPTH:   # against the pose that would be kept, measured now
                now, self._pole_normals = self._pole_normals, memory[0]
                before = self._deepest(prev)
                self._pole_normals = now
                deep = depth > max(GUARD_DEPTH, before) + 1e-9
        if not _any(jump) and not deep:
            self._blocked = False
            return qk, v, effort, tau_id
        self.guarded_steps += 1
        if not self._blocked and self.time - self._blocked_at >= 1.0:
            # once per streak of refused steps (at most once a second): what blocks the arm
            self._blocked_at = self.time
            self.events.append(WorldEvent("blocked", self._blocked_by(qk, jump)))
        self._blocked = True
        qk = prev.copy()
        v = np.zeros(nk)
        zero = np.zeros(nk)
        tau_g = pin.rnea(self.model, self.data, qk + self.offset[:nk], zero, zero)
        k, lim = self.stiffness[:nk], self.limit[:nk]
        rest = self._ref[:nk] + y_before - qk      # the springs' stretch
        held = _clip(rest, (-lim - tau_g) / k, (lim - tau_g) / k)
        self._yield[:nk] = np.where(P, y_before + held - rest, self._yield[:nk])
        effort = np.where(P, _clip(tau_g + k * held, -lim, lim), effort)
        # the contact state (forces, link contacts, friction anchors) of the pose kept
        self._pole_normals, self._anchors, self._warm = memory
        self._contacts(qk, np.zeros(nk, dtype=bool), v=None)
        return qk, v, effort, tau_g

    def _check_underpowered(self, P: np.ndarray, tau_id: np.ndarray) -> None:
        """A current-limited (CURRENT_POSITION) servo whose limit is below its own gravity
        and inertia load would sag on the robot; the mock holds it (not modelled), so it
        reports an ``underpowered`` event when a joint becomes so (once, until it recovers)
        and the node logs it as a warning: a task relying on it would fail on the robot."""
        nk = self.nk
        sagging = self._modes().current_position & P & (np.abs(tau_id) > self.limit[:nk])
        if not _any(sagging) and not self._underpowered:
            return                                  # the usual case: none under-powered
        now = {self.names[i] for i in np.flatnonzero(sagging).tolist()}
        for name in sorted(now - self._underpowered):
            i = self._index[name]
            self.events.append(WorldEvent(
                "underpowered", f"{name}: current limit {self.limit[i]:.3g} N·m below its load "
                f"{abs(tau_id[i]):.3g} N·m: the real servo would sag (the mock holds it)"))
        self._underpowered = now

    def _overload(self, dt: float, held: np.ndarray) -> None:
        """A position-class servo (arm, gripper; rail) whose limit is its stall torque, at it
        for OVERLOAD_TIME s: overload error, torque off (e.g. an arm joint pushing a link on
        a pole; the gripper on the block does not get there: its spring gives ~3.5 N·m at
        most, below its stall torque). The time at the limit is a leaky count (+dt at >= 98 % of the limit,
        -dt below), as a servo's thermal load: a servo that yields step after step against
        a contact, touching its limit every other step, overloads too."""
        stalled = held & (self.limit_cmd >= self.stall * (1.0 - 1e-9))   # at its stall torque
        stalled &= np.abs(self.effort) >= self.limit * OVERLOAD_FRACTION
        if not _any(stalled) and not _any(self._saturated_for):
            return
        self._saturated_for = np.where(stalled, self._saturated_for + dt,
                                       np.maximum(self._saturated_for - dt, 0.0))
        for i in np.flatnonzero(self._saturated_for >= OVERLOAD_TIME):
            self.inject_error(self.names[i], "overload")
            self._saturated_for[i] = 0.0

    def _tool_at(self, q: np.ndarray) -> np.ndarray:
        """True pose of tool0 (offsets included) at chain positions ``q`` (encoder values);
        leaves ``self.data`` at that configuration (but for a repeated ``q`` within a
        step's cache, which is off with poles: their contacts read ``self.data``)."""
        qt = q + self.offset[:self.nk]
        if self._fk_cache:
            key = qt.tobytes()
            if key == self._fk_key:
                return self._fk_pose
        pin.framesForwardKinematics(self.model, self.data, qt)
        pose = self.data.oMf[self.tool_id].homogeneous
        if self._fk_cache:
            self._fk_key, self._fk_pose = key, pose
        return pose

    def _update_tool(self) -> None:
        self._tool = self._tool_at(self.position[:self.nk])

    def _contact_angle(self) -> float:
        """Gripper angle (rad) at which the fingers touch the block."""
        gr = self.desc.gripper
        width = self.world.width_between_fingers(self._tool)
        return gr.lower + min(width / gr.max_opening, 1.0) * (gr.upper - gr.lower)

    def _gripper(self, dt: float) -> None:
        """The gripper's servo, its contact with the block, and grasp/release/drop."""
        g = self.g
        mode = self.mode[g]
        prev = self.position[g]
        present = self.world.block_between_fingers(self._tool)
        qc = self._contact_angle() if present else -math.inf
        reachable = prev >= qc - 1e-3          # fingers open enough to get around the block
        effort, contact = 0.0, False
        gap = self._gap[g] > 0.0
        if mode in _HOLDING and not gap:
            q = self._ref[g]
            if present and reachable and q <= qc:
                contact = True
                q = qc
                effort = float(_clip(self.stiffness[g] * (self._ref[g] - qc),
                                       -self.limit[g], self.limit[g]))
            vel = (q - prev) / dt
        elif mode is ControlMode.TORQUE and not gap:
            effort = self.kt_ratio[g] * float(self._quantize(self.tau_cmd[g], g))
            drive = math.copysign(max(abs(effort) - self.coulomb[g], 0.0), effort)
            vel = float(_clip(drive / self.cfg.servo.damping, -self.vmax[g], self.vmax[g]))
            q = float(_clip(prev + vel * dt, self.lower[g], self.upper[g]))
            if present and reachable and q <= qc and effort < 0.0:
                contact, q, vel = True, qc, 0.0
        else:
            q, vel = prev, 0.0
            contact = present and reachable and abs(prev - qc) < 1e-3
        self.position[g], self.velocity[g], self.effort[g] = q, vel, effort
        grip = abs(effort) if contact else 0.0
        min_effort = self.cfg.world.grasp.min_effort
        if self.world.state is BlockState.HELD:
            if not contact:
                self.world.release(self._tool, "released")
            elif grip < min_effort:   # slipped: let go on purpose if it is opening
                self.world.release(self._tool, "released" if self.goal[g] >= qc else "dropped")
        elif contact and grip >= min_effort:
            self.world.grasp(self._tool)

    def _record(self) -> None:
        self._history.append((self.time, self.position.copy(), self.velocity.copy(),
                              self.reported_effort.copy()))
        keep = self.cfg.imperfections.state_latency
        while len(self._history) > 1 and self._history[1][0] <= self.time - keep + 1e-12:
            self._history.popleft()

    # -- outputs ------------------------------------------------------------------------
    def state(self) -> StateSample:
        """Joint states as the driver reports them: ``state_latency`` old, with noise."""
        t, p, v, e = self._history[0]
        imp = self.cfg.imperfections
        if imp.position_noise > 0.0:
            p = p + self._rng.normal(0.0, imp.position_noise, self.n)
        if imp.velocity_noise > 0.0:
            v = v + self._rng.normal(0.0, imp.velocity_noise, self.n)
        if imp.effort_noise > 0.0:
            e = e + self._rng.normal(0.0, imp.effort_noise, self.n)
        return StateSample(t, p.copy(), v.copy(), e.copy())

    def tool_pose(self) -> np.ndarray:
        """True pose of tool0 (repeatability offsets included) in the root frame (in world,
        the root frame at rest, when a host motion moves the root)."""
        return self._tool.copy()

    def truth(self) -> dict[str, np.ndarray]:
        """True poses of what the camera sees: the block and each peg's top, root frame."""
        out = {} if self.world.state is BlockState.ABSENT else \
            {"block": self.world.block_pose(self._tool)}
        for name in self.world.peg_names:
            out[f"{name}_peg"] = self.world.peg_top(name)
        return out

    def take_events(self) -> list[WorldEvent]:
        out, self.events = self.events, []
        return out

    def contact_wrench(self) -> np.ndarray:
        """Wrench (N, N·m) the work cell's contacts (block and poles) exert on the robot in
        the last step, at the root's origin in its axes: force then moment."""
        rows = self._last_rows
        if rows is None:
            return np.zeros(6)
        dirs, points, _, f, _ = rows
        d = dirs * f[:, None]
        p = points
        return np.r_[d.sum(axis=0), np.cross(p, d).sum(axis=0)]
