"""The servos' firmware, as the mock models it (no physics, no ROS): what the Dynamixel and
PMAC controllers do with the commands they get, whatever moves the joints.

Units: rad, rad/s, N·m for the arm and gripper joints; m, m/s, N for the rail; s.

Every servo is in one of four modes, chosen per joint by the last command it got (as the
real driver does: position only = position control, effort only = torque control, both =
current-based position with the effort as current limit), or OFF (torque disabled):

- POSITION / CURRENT_POSITION: the goal is followed through a velocity- and
  acceleration-limited profile (the description's limits), exact in discrete time; the
  servo's force is limited to its current limit (the stall torque, the gripper's
  ``grip_effort``, or the commanded one). A position-class servo held at its stall torque
  (98 % or more, a leaky count) for ``OVERLOAD_TIME`` s raises an overload error and drops
  its torque, as a Dynamixel does.
- TORQUE (current): the commanded effort (clamped to the stall torque). Without a new
  effort command for ``effort_timeout`` s the watchdog switches the joint to holding its
  position.
- OFF: no torque.

Mode switches between position-class and current control turn the torque off for
``servo.mode_switch_gap`` s (the real driver writes Operating Mode with torque off).

The current model (per servo, drawn once from the seed): a torque-constant ratio, a Coulomb
friction, currents in whole units: a commanded torque or limit is exerted as
quantized(nominal) x true/nominal; the reported effort goes back through the true constant.

Imperfections: a hidden joint offset drawn per move (repeatability: the encoders, hence
joint_states, do not see it, but the tool's true pose, the block and the camera do), noise
and latency on the reported states, latency on commands. Joint goals are clamped to the
limits before they are stored: no command outside the limits reaches the servos.

:class:`ServoBank` holds this state; :class:`~hyperarm_driver.mock.joint_sim.JointSim`
puts it on MuJoCo's actuators.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from enum import Enum
from typing import Callable, Mapping, Sequence

import numpy as np

from hyperarm_description.joints import JointStateError, check_command
from hyperarm_description.model import RobotDescription

from .config import MockConfig, MockError, load_mock_config
from .world import WorldEvent

__all__ = ["ControlMode", "CommandReport", "StateSample", "MockCommandError", "ServoBank",
           "OVERLOAD_TIME", "RAIL_FORCE_LIMIT"]

OVERLOAD_TIME = 2.0        # s at the stall torque before a POSITION servo's overload error
OVERLOAD_FRACTION = 0.98   # of the torque limit: "at the limit" for the overload count
RAIL_FORCE_LIMIT = 200.0   # N, the rail drive's force limit
OFFSET_RATE = 0.5          # rad/s: a new move's repeatability offset settles at most this
                           # fast per joint (its backlash takes up during the move, no jump)

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


class ServoBank:
    """Every actuated joint's servo (rail, arm, gripper): modes, goals, profiles, limits,
    the current model, the hidden offsets, errors; the physics that moves the joints is a
    subclass's (:class:`~hyperarm_driver.mock.joint_sim.JointSim`), which sets
    ``position``/``velocity``/``effort`` (the encoders' noiseless values, the motors' true
    efforts) and calls :meth:`_record` after each step.

    ``names`` lists the joints: the chain (rail first, if any) then the gripper.
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
        self._gap_hold = np.zeros(self.n, dtype=bool)  # after the gap: goal := present
        self.tau_cmd = np.zeros(self.n)
        self._effort_time = np.zeros(self.n)
        self._prof_p, self._prof_v = q0.copy(), np.zeros(self.n)
        self._ref, self._ref_v = q0.copy(), np.zeros(self.n)
        self.position, self.velocity, self.effort = q0.copy(), np.zeros(self.n), np.zeros(self.n)
        self.offset = np.zeros(self.n)             # hidden (repeatability), arm joints only
        self._offset_goal = np.zeros(self.n)       # the move's drawn offset (settling)
        self._settling = False                     # offset still on its way to the goal
        self._anchor = q0.copy()
        self._saturated_for = np.zeros(self.n)
        self.errors: dict[str, str] = {}
        self.events: list[WorldEvent] = []
        self._pending: deque[tuple[float, Callable[[], None]]] = deque()
        self._history: deque[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = deque()
        self._redraw = False                       # a new move's offset waits for no contact
        self.require_homing = bool(require_homing)
        self.homed = self.rail is None
        self.homing = False
        self.link_contacts: list = []    # the physics' (links touching poles)
        self.contact_force = np.zeros(3)

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
        """Whether a contact holds the arm (its backlash cannot settle anew): a link on a
        pole, the held block touching the cell or threaded on a peg (the physics' say)."""
        return bool(self.link_contacts) or bool(np.any(self.contact_force))

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

    def set_profile_position(self, i: int, value: float) -> None:
        """Joint ``i``'s goal and profile at ``value`` (rad, m) now: a trajectory run by the
        controller itself (the PMAC's, for a scripted rail sweep)."""
        self.goal[i] = value
        self._prof_p[i] = value

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
        """Velocity/acceleration-limited profile towards the goal: the servo's reference."""
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
        # the reference is the profile (no lag of its own: the physics lags the joint); its
        # velocity the difference (the profile's own, or a trajectory's the controller runs
        # itself: set_profile_position)
        ref = np.where(held, self._prof_p, self._ref)
        self._ref_v = np.where(held, (ref - self._ref) / dt, 0.0)
        self._ref = ref

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

    def _record(self) -> None:
        self._history.append((self.time, self.position.copy(), self.velocity.copy(),
                              self.reported_effort.copy()))
        keep = self.cfg.imperfections.state_latency
        while len(self._history) > 1 and self._history[1][0] <= self.time - keep + 1e-12:
            self._history.popleft()

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

    def take_events(self) -> list[WorldEvent]:
        out, self.events = self.events, []
        return out
