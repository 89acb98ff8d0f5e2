"""The force node's logic without ROS: modes, passive rules, goals, the per-cycle output.

:class:`ForceController` owns the law, the wrench estimator and the calibration. The node
feeds it joint states, goals and service calls, and turns what it returns into messages:

- ``DISABLED`` (start): nothing is published on joint_command;
- ``ACTIVE``: every joint state gives one arm command (``torque`` or ``position`` output);
- ``PASSIVE``: a fault made it stop (stale joint states, a bad goal, a joint near its
  limit); latched until ``enable(True)`` again.

Entering DISABLED or PASSIVE from ACTIVE returns an :class:`Event` with ``hold=True``: the
node then calls the driver's ``hold`` once, so the arm is never left limp and no stale
effort keeps pushing. Each event is logged once and shown in the diagnostics.
Units: SI; time stamps in s (the node's clock).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import Sequence

import numpy as np
import pinocchio as pin

from hyperarm_description.freshness import StampGate, StampRejection

from ..own_gap import OwnGap
from .calibration import TorqueCalibration
from .errors import ForceConfigError, InvalidGoalError, StateError
from .law import OUTPUTS, Command, HybridGoal, HybridLaw, Payload, make_goal
from .wrench import WrenchEstimate, WrenchEstimator, to_tool

__all__ = ["Mode", "Event", "Output", "ControllerConfig", "ForceController",
           "joint_state_problem", "MALFORMED_KINDS"]

#: kinds of malformed joint_states, each its own log-throttle reason and diagnostics count
MALFORMED_KINDS = ("length", "nan", "inf", "duplicate")


def joint_state_problem(names: Sequence[str], position: Sequence[float],
                        velocity: Sequence[float],
                        effort: Sequence[float]) -> tuple[str, str] | None:
    """What is wrong with one joint_states message, judged whole, or None: (kind, text),
    kind one of :data:`MALFORMED_KINDS`, the text naming the field and the joint (rad,
    rad/s, N·m are not checked against ranges here: the law's guards do that)."""
    n = len(names)
    if len(set(names)) != n:
        dup = sorted({x for x in names if list(names).count(x) > 1})
        return "duplicate", f"joint_states ignored: joint name(s) {dup} appear twice"
    for label, arr in (("position", position), ("velocity", velocity), ("effort", effort)):
        if len(arr) not in (0, n):
            return "length", (f"joint_states ignored: {label} has {len(arr)} values for {n} "
                              "names")
    for label, arr in (("position", position), ("velocity", velocity), ("effort", effort)):
        for name, v in zip(names, arr):
            v = float(v)
            if math.isnan(v):
                return "nan", f"joint_states ignored: {label} of {name} is NaN"
            if math.isinf(v):
                return "inf", f"joint_states ignored: {label} of {name} is {v}"
    return None


class Mode(str, Enum):
    DISABLED = "disabled"
    ACTIVE = "active"
    PASSIVE = "passive"


@dataclass(frozen=True)
class Event:
    """Something to log once (``level`` 'info' or 'warn') and show in the diagnostics."""

    kind: str          # enabled, disabled, stale, bad_goal, near_limit, compliance, tare
    level: str
    message: str
    hold: bool = False  # the node calls the driver's hold service once


@dataclass
class Output:
    """One cycle: the arm command (None unless ACTIVE) and the wrench estimate (None until
    :meth:`ForceController.estimate` ran on it; :meth:`ForceController.step` runs both)."""

    names: list[str]
    positions: list[float] | None
    efforts: list[float] | None
    wrench_root: np.ndarray | None = None
    wrench_tool: np.ndarray | None = None
    command: Command | None = None
    q: np.ndarray | None = None          # the joint state the cycle ran on (chain order)
    dq: np.ndarray | None = None         # its velocities (chain order)
    effort: object = None                # its arm efforts (N·m), for the estimate


@dataclass(frozen=True)
class ControllerConfig:
    """output: 'torque' or 'position'; stale_timeout: s without joint states before going
    passive; limit_guard: rad from a joint limit at which it goes passive;
    default_stiffness: K of the hold goal at enable and of position axes a goal leaves at 0
    [N/m x3, N·m/rad x3]; state_max_age / goal_max_age: s, a joint state / goal stamped
    longer ago is not used (nor one older than the newest used: :class:`StampGate`);
    switch_gap: s the servos' torque is off when the first effort-only command after enable
    switches them into current mode (the 'torque' output): the impulse lost in it is added
    back (0: no compensation), spread over the first ``switch_spread`` commands, so that a
    first command overtaken by the next one (a loaded machine; a driver that writes the
    latest command of each cycle) still leaves most of it."""

    output: str = "position"
    stale_timeout: float = 0.1
    limit_guard: float = 0.02
    default_stiffness: tuple[float, ...] = (800.0, 800.0, 800.0, 20.0, 20.0, 20.0)
    max_dt: float = 0.05
    state_max_age: float = 0.2
    goal_max_age: float = 1.0
    switch_gap: float = 0.005
    switch_spread: int = 3

    def __post_init__(self) -> None:
        if self.output not in OUTPUTS:
            raise ForceConfigError(f"output {self.output!r}: one of {', '.join(OUTPUTS)}")
        for name, lo, hi in (("stale_timeout", 0.01, 10.0), ("limit_guard", 0.0, 0.5),
                             ("max_dt", 1e-3, 1.0), ("state_max_age", 0.01, 10.0),
                             ("goal_max_age", 0.01, 60.0), ("switch_gap", 0.0, 0.05)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
                raise ForceConfigError(f"{name}: {v!r} not within {lo:g}..{hi:g}")
        if isinstance(self.switch_spread, bool) or not isinstance(self.switch_spread, int) \
                or not 1 <= self.switch_spread <= 10:
            raise ForceConfigError(f"switch_spread: {self.switch_spread!r} not an integer "
                                   "within 1..10")
        k = np.asarray(self.default_stiffness, dtype=float)
        if k.shape != (6,) or not np.all(np.isfinite(k)) or np.any(k <= 0.0):
            raise ForceConfigError(f"default_stiffness: 6 values > 0, got {k.tolist()}")


@dataclass
class _Stats:
    cycles: int = 0
    last_event: str = "none"
    wrench_limited: int = 0
    joint_limited: int = 0
    rate_limited: int = 0
    step_limited: int = 0


class ForceController:
    """See the module doc. ``names``: the chain's joints (``law.kin.joint_names``)."""

    def __init__(self, law: HybridLaw, estimator: WrenchEstimator | None = None,
                 calibration: TorqueCalibration | None = None,
                 config: ControllerConfig | None = None) -> None:
        self.law = law
        self.kin = law.kin
        self.config = config if config is not None else ControllerConfig()
        self.estimator = estimator if estimator is not None else WrenchEstimator(law.na)
        self.calibration = calibration if calibration is not None else TorqueCalibration({})
        self.names = list(self.kin.joint_names)
        self.arm_names = list(law.arm_names)
        self.mode = Mode.DISABLED
        self.reason = "not enabled yet"
        self.compliance = False
        self.goal: HybridGoal | None = None
        self.stats = _Stats()
        self._last_state: float | None = None
        self._own_gap = OwnGap(self.config.stale_timeout)    # between check_stale calls
        self._last_cycle: float | None = None
        self._last_now: float | None = None
        self._period = 0.01                # s, the joint states' period (running estimate)
        self._switch_left = 0              # torque commands still carrying the gap's impulse
        self._q: np.ndarray | None = None
        self.last_estimate: WrenchEstimate | None = None
        self._last_rotation = np.eye(3)
        self._default_k = np.asarray(self.config.default_stiffness, dtype=float)
        self._base_id = self.kin.model.getFrameId(self.kin.desc.base_frame)
        self.state_gate = StampGate("joint_states", self.config.state_max_age)
        self.goal_gate = StampGate("hybrid_goal", self.config.goal_max_age)
        self.malformed = {k: 0 for k in MALFORMED_KINDS}   # joint_states dropped, per kind

    # -- modes ----------------------------------------------------------------------------
    def enable(self, on: bool, now: float) -> Event:
        """Enable from the present pose (hold goal there), or disable. Raises ForceError
        when it cannot enable (no or stale joint states, a joint near its limit)."""
        if not on:
            return self._stop(Mode.DISABLED, "disabled", "info", "disabled on request")
        if self._q is None or self._last_state is None:
            raise StateError("no joint_states received yet")
        if now - self._last_state > self.config.stale_timeout:
            raise StateError(f"joint_states are stale ({now - self._last_state:.3f} s old)")
        near = self.law.near_limit(self._q, self.config.limit_guard)
        if near:
            raise StateError(f"joints near their limits: {', '.join(near)}")
        self.law.reset(self._q)
        self.estimator.reset()
        self.goal = self.law.hold_goal(self._q, self._default_k)
        self.mode, self.reason = Mode.ACTIVE, "enabled"
        self._last_cycle = None
        self._switch_left = self.config.switch_spread if self.config.output == "torque" else 0
        return self._event(Event("enabled", "info", f"enabled ({self.config.output} output), "
                                 "holding the present pose"))

    def set_compliance(self, on: bool) -> Event:
        self.compliance = bool(on)
        if on and self._q is not None:
            self.law.set_compliance_posture(self._q)
        return self._event(Event("compliance", "info",
                                 f"whole-arm compliance {'on' if on else 'off'}"))

    def _stop(self, mode: Mode, kind: str, level: str, message: str) -> Event:
        was_active = self.mode is Mode.ACTIVE
        self.mode, self.reason = mode, message
        return self._event(Event(kind, level, message, hold=was_active))

    def _event(self, e: Event) -> Event:
        self.stats.last_event = f"{e.kind}: {e.message}"
        return e

    # -- inputs ---------------------------------------------------------------------------
    def check_state(self, stamp: float, now: float, names: Sequence[str], position,
                    velocity, effort) -> tuple[str, str] | None:
        """Whether one joint_states message (stamped ``stamp`` s, received at ``now`` s) may
        be used: None, or (throttle reason, text) when it is dropped whole: malformed (its
        own reason per kind, the text names the field and joint) or late / out of order /
        unstamped / from the future (:class:`StampGate`, per driver: the message's joint
        names are its source). Counted for the diagnostics."""
        problem = joint_state_problem(names, position, velocity, effort)
        if problem is not None:
            self.malformed[problem[0]] += 1
            return f"joint_states {problem[0]}", problem[1]
        return _gate_reason(self.state_gate, self.state_gate.check(stamp, now, tuple(names)))

    def check_goal(self, stamp: float, now: float) -> tuple[str, str] | None:
        """Whether a hybrid goal stamped ``stamp`` (s) may be used at ``now`` (s): None, or
        (throttle reason, text) when it is late, out of order, unstamped or from the
        future (the goal is ignored, the previous one stays). Judged only while ACTIVE (a
        goal is ignored otherwise anyway)."""
        if self.mode is not Mode.ACTIVE:
            return None
        return _gate_reason(self.goal_gate, self.goal_gate.check(stamp, now))

    def input_counts(self) -> dict[str, int]:
        """Dropped inputs per stream and reason, for the diagnostics."""
        out = {f"joint_states_{k}": v for k, v in self.malformed.items()}
        for gate in (self.state_gate, self.goal_gate):
            out.update({f"{gate.stream}_{k}": v for k, v in gate.counts.items()})
        return out

    def set_payload(self, mass: float, com: Sequence[float]) -> None:
        self.law.payload = Payload(float(mass), tuple(float(c) for c in com))  # type: ignore

    def on_goal(self, frame: str, position, quaternion_xyzw, stiffness, force_axes,
                wrench) -> tuple[HybridGoal | None, Event | None]:
        """A goal: accepted while ACTIVE (the law follows it from now on). A bad one is
        refused whole and, while ACTIVE, makes the controller passive (the arm holds).
        While not active a goal is ignored (returns None, None)."""
        if self.mode is not Mode.ACTIVE:
            return None, None
        try:
            k = np.asarray(stiffness, dtype=float)
            s = np.asarray(force_axes, dtype=bool)
            if k.shape == (6,) and s.shape == (6,):
                k = np.where(~s & (k == 0.0), self._default_k, k)
            goal = make_goal(self.kin, self.law.config, frame, position, quaternion_xyzw, k, s,
                             wrench)
        except InvalidGoalError as exc:
            return None, self._stop(Mode.PASSIVE, "bad_goal", "warn",
                                    f"goal refused, holding: {exc}")
        self.goal = goal
        return goal, None

    def check_stale(self, now: float) -> Event | None:
        """Passive when ACTIVE and no joint state came for ``stale_timeout`` s. Not judged
        right after this process itself did not run for ``stale_timeout`` s (no check since:
        a loaded machine's scheduling, not the states' silence): the states queued
        meanwhile are read first, and the next check judges."""
        if self._own_gap.after_gap(now):
            return None
        if self.mode is not Mode.ACTIVE or self._last_state is None:
            return None
        age = now - self._last_state
        if age > self.config.stale_timeout:
            return self._stop(Mode.PASSIVE, "stale", "warn",
                              f"joint_states stale ({age:.3f} s > "
                              f"{self.config.stale_timeout:g} s): passive, holding")
        return None

    def tare(self) -> str:
        """Capture the estimator's bias at the present state (no contact expected)."""
        if self._q is None:
            raise StateError("no joint_states received yet")
        bias = self.estimator.tare()
        self._event(Event("tare", "info", "tared"))
        return "tared: bias " + ", ".join(f"{b:+.3f}" for b in bias) + " N·m"

    def step(self, now: float, q, dq, effort,
             stamp: float = 0.0) -> tuple[Output, Event | None]:
        """One cycle on a full joint state (chain order; efforts of the arm joints used by
        the estimate) received at ``now``, measured at ``stamp`` (0: unknown). Staleness
        counts from the older of the two, so a backlog of old states is stale too. Returns
        the output (a command only while ACTIVE) and an event when a joint near its limit
        made it passive. :meth:`control` then :meth:`estimate`."""
        out, event = self.control(now, q, dq, effort, stamp)
        return self.estimate(out), event

    def control(self, now: float, q, dq, effort,
                stamp: float = 0.0) -> tuple[Output, Event | None]:
        """The command part of :meth:`step` (the node publishes it at once, then calls
        :meth:`estimate`: the wrench estimate is not on the command's latency path)."""
        q = np.asarray(q, dtype=float)
        dq = np.asarray(dq, dtype=float) if len(dq) else np.zeros_like(q)
        if q.shape != (len(self.names),) or dq.shape != q.shape or not \
                math.isfinite(float(q.sum() + dq.sum())):
            raise StateError("joint state: wrong length or non-finite values")
        self._q = q
        self._last_state = stamp if stamp > 0.0 else now
        if self._last_now is not None and 0.0 < now - self._last_now < 0.1:
            self._period += 0.1 * (now - self._last_now - self._period)
        self._last_now = now
        event = None
        cmd = None
        if self.mode is Mode.ACTIVE:
            near = self.law.near_limit(q, self.config.limit_guard)
            if near:
                event = self._stop(Mode.PASSIVE, "near_limit", "warn",
                                   f"{', '.join(near)} within {self.config.limit_guard:g} rad "
                                   "of a limit: passive, holding")
            else:
                dt = self.config.max_dt if self._last_cycle is None else \
                    min(max(now - self._last_cycle, 1e-3), self.config.max_dt)
                self._last_cycle = now
                assert self.goal is not None
                cmd = self.law.step_checked(q, dq, self.goal, dt, self.compliance,
                                            self.config.output)
                self._count(cmd)
        positions = efforts = None
        if cmd is not None:
            cal = self.calibration
            exact = not cal.joints
            # the torque margin applies to what is commanded, after the calibration's
            # division by each servo's scale (a scale < 1 once took efforts to 0.88 of stall)
            limit = self.law.limit
            if self.config.output == "torque":
                tau = self._switch_impulse(cmd.tau) if self._switch_left else cmd.tau
                tau = tau if exact else cal.command(self.arm_names, tau)
                efforts = np.minimum(np.maximum(tau, -limit), limit).tolist()
            else:
                positions = cmd.q_cmd.tolist()
                current = cmd.effort_limit if exact else cal.command(self.arm_names,
                                                                     cmd.effort_limit)
                efforts = np.minimum(current, limit).tolist()
        return Output(self.arm_names, positions, efforts, command=cmd, q=q, dq=dq,
                      effort=effort), event

    def _switch_impulse(self, tau: np.ndarray) -> np.ndarray:
        """The first effort-only command after enable switches the servos into current
        mode, their torque off for ``switch_gap`` s (Operating Mode is written with torque
        off): a gravity-loaded joint falls meanwhile (about 1 mm at the tool on the mock).
        Each of the first ``switch_spread`` commands (n) holds for about one state period T
        and carries tau x gap / n of extra impulse: the switching one over the T - gap it
        acts, tau x (1 + gap / (n (T - gap))), the others tau x (1 + gap / (n T)). A first
        command overtaken by the next is never applied; the next then switches and the
        loss is the overtaken one's share (N·m, within the torque limits)."""
        n = self.config.switch_spread
        first = self._switch_left == n
        self._switch_left -= 1
        gap = self.config.switch_gap
        if gap <= 0.0:
            return tau
        acting = max(self._period - gap, gap) if first else max(self._period, gap)
        factor = min(gap / (n * acting), 1.0)
        limit = self.law.limit
        return np.minimum(np.maximum(tau * (1.0 + factor), -limit), limit)

    def estimate(self, out: Output) -> Output:
        """Fill ``out``'s wrench estimate (root and tool0 axes) from its joint state."""
        est, r = self._estimate(out.q, out.effort, out.command, out.dq)
        self.last_estimate, self._last_rotation = est, r
        out.wrench_root = est.wrench
        out.wrench_tool = to_tool(est.wrench, r)[0]
        return out

    def _estimate(self, q: np.ndarray, effort, cmd: Command | None,
                  dq: np.ndarray | None = None) -> tuple[WrenchEstimate, np.ndarray]:
        if cmd is not None:            # the law's kinematics and gravity at this q
            j, r, g, jjt = cmd.jacobian, cmd.rotation, cmd.gravity, cmd.jjt
        else:
            arm = self.law.arm
            _, r, j_full = self.kin.pose_jacobian_view(q)
            r = r.copy()
            j = j_full[:, arm]
            g = self.law.gravity.torques(q, self.law.payload, j_full, r)[arm]
            jjt = None
        e = np.asarray(effort, dtype=float)
        if e.shape != g.shape:
            tau = g
        else:
            tau = e if not self.calibration.joints else self.calibration.correct(
                self.arm_names, e, None if dq is None else dq[self.law.arm])
        return self.estimator.update(j, tau, g, jjt), r

    def covariance_tool(self) -> np.ndarray | None:
        """Covariance (6, 6) of the last estimate in tool0 axes (N², N²·m², N²·m²)."""
        if self.last_estimate is None:
            return None
        return to_tool(self.last_estimate.wrench, self._last_rotation,
                       self.last_estimate.covariance)[1]

    def base_rotation(self) -> np.ndarray:
        """Rotation of base_link in the root frame at the last joint state."""
        pin.framesForwardKinematics(self.kin.model, self.kin.data, self._q)
        return self.kin.data.oMf[self._base_id].rotation.copy()

    def _count(self, cmd: Command) -> None:
        s = self.stats
        s.cycles += 1
        s.wrench_limited += cmd.wrench_scale < 1.0
        s.joint_limited += cmd.joint_scale < 1.0
        s.rate_limited += bool(cmd.rate_limited)
        s.step_limited += bool(cmd.step_limited)


def _gate_reason(gate: StampGate,
                 rejection: StampRejection | None) -> tuple[str, str] | None:
    """(throttle reason, text) of a gate's rejection: one reason per stream and kind."""
    if rejection is None:
        return None
    return f"{gate.stream} {rejection.reason}", rejection.text
