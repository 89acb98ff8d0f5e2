"""Keep tool0 at a pose in the world while the arm's host (rail carriage, UAV) moves.

Every cycle, :meth:`Compensator.step` takes the host's state (the pose of ``base_link`` in
``world`` and its twist, :class:`HostState`), predicts the host pose ``horizon`` s ahead
(feed-forward of the host velocity over the measured latency plus the actuators' lag),
expresses the world goal in ``base_link`` and runs a few damped least-squares iterations on
the nine arm joints, warm-started from the previous command (the rail, or the UAV, is a
known input, not a variable); the first iteration also pulls the joints back towards the
posture at start in the task's null space (``posture_gain``), so the redundant joints do
not drift into a stretched, singular posture over a long motion, and pushes every joint
within ``limit_band`` of a limit away from it (``limit_gain``; the posture pull fades there,
so the push dominates): a joint does not run into its limit while the others can hold the
tool. The change from the previous command is then limited to
``speed_scale`` x each joint's velocity limit x dt (uniform scaling, so the tool's path
keeps its direction): the command never jumps. Joints stay ``limit_margin`` inside their
limits. The damped least squares is singularity-robust: below ``singular_threshold`` of the
weighted Jacobian's smallest singular value its damping grows towards ``singular_damping``
(manipulability-scaled, Nakamura & Hanafusa), so neither the iterations nor the feed-forward
speeds explode at the stretched singularity; the feed-forward speeds are capped at the step
limit's speeds. The command finally sent (``q`` plus the profile lead) passes LAST through
:func:`hyperarm_description.limits.limit_step`: no joint ever steps further from the
previous command than its velocity limit x dt, and none leaves the margins.

When the pose cannot be reached (the miss stays above the tolerances and stops shrinking
for ``stall_cycles`` cycles while the step limit is not what holds the motion back, or the
position is beyond the arm's reach bound), the step says so
(``Status.UNREACHABLE`` and a reason) and keeps commanding the closest configuration the
damped iterations find (least-squares closest, within the limits, step-limited); tracking
resumes by itself when the pose is reachable again.

Units: m, rad, s; twists in world axes (linear velocity of base_link's origin m/s, angular
velocity rad/s). Poses are 4x4 homogeneous matrices.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
import pinocchio as pin

from hyperarm_description.limits import limit_step
from hyperarm_description.model import RobotDescription
from hyperarm_description.pinocchio_model import build_model

from hyperarm_ik.kinematics import Kinematics, rotation_angle
from .errors import HostConfigError, HostGoalError, HostStateError, NotStartedError

__all__ = ["MOUNT_POSE_CUTOFF", "MOUNT_TWIST_CUTOFF", "HostState", "RailHost", "HostPoseTracker", "CompensationConfig", "Status",
           "CompensationStep", "Compensator", "DelayEstimator", "check_pose", "rigid_inverse"]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

#: Hz, host_compensation's default mount-mode filter of host_pose (:class:`HostPoseTracker`)
MOUNT_POSE_CUTOFF = 3.0
MOUNT_TWIST_CUTOFF = 2.0


def check_pose(t, what: str, error: type[Exception] = HostStateError) -> np.ndarray:
    """``t`` as a float 4x4 homogeneous matrix with a proper rotation, or raise ``error``."""
    m = np.asarray(t, dtype=float)
    if m.shape != (4, 4):
        raise error(f"{what} must be a 4x4 matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise error(f"{what} is not finite")
    r = m[:3, :3]
    if np.abs(r @ r.T - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(r) - 1.0) > 1e-6 \
            or np.abs(m[3] - (0.0, 0.0, 0.0, 1.0)).max() > 1e-9:
        raise error(f"{what} is not a rigid transform (orthonormal rotation, det +1, "
                    "last row 0 0 0 1)")
    return m


def rigid_inverse(t: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (4x4): [R^T, -R^T p]."""
    out = np.eye(4)
    rt = t[:3, :3].T
    out[:3, :3] = rt
    out[:3, 3] = -rt @ t[:3, 3]
    return out


def _vec3(v, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise HostStateError(f"{what} must be 3 finite numbers, got {a.tolist()}")
    return a


@dataclass(frozen=True)
class HostState:
    """Pose of base_link in world (4x4, m) and its twist in world axes: ``linear`` (m/s, of
    base_link's origin) and ``angular`` (rad/s). Validated on construction."""

    pose: np.ndarray
    linear: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "pose", check_pose(self.pose, "host pose"))
        object.__setattr__(self, "linear", _vec3(self.linear, "host linear velocity"))
        object.__setattr__(self, "angular", _vec3(self.angular, "host angular velocity"))

    @classmethod
    def trusted(cls, pose: np.ndarray, linear: np.ndarray, angular=None) -> "HostState":
        """A state from values already checked (a pose computed by pinocchio, a checked
        message): no re-validation, for the per-cycle path."""
        out = object.__new__(cls)
        object.__setattr__(out, "pose", pose)
        object.__setattr__(out, "linear", np.asarray(linear, dtype=float))
        object.__setattr__(out, "angular", np.zeros(3) if angular is None
                           else np.asarray(angular, dtype=float))
        return out

    def predict(self, horizon: float) -> np.ndarray:
        """The host pose (4x4) ``horizon`` s ahead at constant twist (first order)."""
        out = self.pose.copy()
        out[:3, 3] += self.linear * horizon
        if self.angular.any():
            out[:3, :3] = pin.exp3(self.angular * horizon) @ self.pose[:3, :3]
        return out


class RailHost:
    """The host state of the rail_arm variant from the rail joint (m, m/s)."""

    def __init__(self, desc: RobotDescription) -> None:
        if desc.rail is None:
            raise HostConfigError("RailHost needs the rail_arm description (it has no rail)")
        self._model = build_model(desc)
        self._data = self._model.createData()
        self._frame = self._model.getFrameId(desc.base_frame)
        self._q = np.zeros(self._model.nq)   # rail first, the arm joints do not matter
        self.lower, self.upper = float(desc.rail.lower), float(desc.rail.upper)
        self.axis = self.pose(1.0)[:3, 3] - self.pose(0.0)[:3, 3]   # world, per metre

    def pose(self, rail: float) -> np.ndarray:
        """4x4 pose of base_link in world at rail position ``rail`` (m)."""
        self._q[0] = rail
        pin.framesForwardKinematics(self._model, self._data, self._q)
        return self._data.oMf[self._frame].homogeneous.copy()

    def state(self, rail: float, rail_velocity: float = 0.0) -> HostState:
        """:class:`HostState` at rail position (m) and velocity (m/s)."""
        if not (math.isfinite(rail) and math.isfinite(rail_velocity)):
            raise HostStateError(f"rail state is not finite: {rail!r} m, {rail_velocity!r} m/s")
        return HostState.trusted(self.pose(rail), self.axis * rail_velocity)


class HostPoseTracker:
    """:class:`HostState` from a stream of stamped host poses (e.g. ``host_pose`` from
    motion capture or the mock). The twist is the difference between the newest pose and
    the newest one at least ``baseline`` s older (by stamp), over their stamps' difference:
    poses that come in bursts with nearly equal stamps (a driver catching up) do not make
    it spike, and noise is averaged over the baseline. A pose whose stamp is not after the
    previous one replaces it. :attr:`stamp` is the newest pose's stamp (s): the host state
    is that old, so a prediction's horizon counts from it; the twist is the one of
    ``baseline / 2`` s before it (a lag the prediction's horizon does not include).

    Mount-mode filter (``pose_cutoff`` Hz > 0, issue 24 item 4): :attr:`state` is then the
    pose low-passed (first order, cutoff ``pose_cutoff``) and advanced by its time constant
    T = 1 / (2 pi pose_cutoff) at the twist low-passed at ``twist_cutoff`` Hz, with that
    twist: p_f + T v_f, the rotation likewise (T: the sampled filter's lag on a ramp,
    dt (1 - a) / a for its last step, about T - dt / 2). Slow host motion passes (the advance
    undoes the low-pass's lag: a ramp exactly, a 0.5 Hz sway within about 1 %), while at a
    passive mount's 4-8 Hz modes the twist, which carries the prediction over the horizon,
    is cut to about a third and the pose lags 15-21 deg: the compensation no longer
    predicts the mount's own oscillation, which, with the loop's delay and the servos' lag,
    fed those modes (issue 24 item 4; a horizon shorter for every frequency helped too but
    cost accuracy on the slow sway). The unfiltered state stays in :attr:`raw` (for the
    reaction and for judging the measured tool)."""

    def __init__(self, baseline: float = 0.02, max_gap: float = 0.5, pose_cutoff: float = 0.0,
                 twist_cutoff: float = 0.0) -> None:
        for name, v, lo, hi in (("baseline", baseline, 1e-3, 1.0), ("max_gap", max_gap,
                                                                       1e-3, 10.0),
                                ("pose_cutoff", pose_cutoff, 0.0, 100.0),
                                ("twist_cutoff", twist_cutoff, 0.0, 100.0)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or not lo <= v <= hi:
                raise HostConfigError(f"host pose tracker {name} must be in {lo:g}..{hi:g}, "
                                      f"got {v!r}")
        self.baseline, self.max_gap = float(baseline), float(max_gap)
        if pose_cutoff > 0.0 and twist_cutoff <= 0.0:
            raise HostConfigError("host pose tracker: a pose_cutoff needs a twist_cutoff > 0")
        self.pose_cutoff, self.twist_cutoff = float(pose_cutoff), float(twist_cutoff)
        self._filtered: list | None = None      # [p, R, v, w, stamp] of the filter
        self._history: list[tuple[float, np.ndarray]] = []
        self.state: HostState | None = None
        self.raw: HostState | None = None       # the unfiltered state
        self.stamp: float | None = None
        self.twist_full = False      # the twist is a difference over a whole baseline

    def reset(self) -> None:
        self._history.clear()
        self.state = self.stamp = self.raw = self._filtered = None
        self.twist_full = False

    def update(self, stamp: float, pose) -> HostState:
        """Add the pose (4x4, base_link in world) taken at ``stamp`` (s); returns the state.
        Raises :class:`HostStateError` for a malformed pose or stamp."""
        pose = check_pose(pose, "host pose")
        if not math.isfinite(stamp):
            raise HostStateError(f"host pose stamp is not finite: {stamp!r}")
        h = self._history
        while h and h[-1][0] >= stamp:          # not newer: replaces what it overtakes
            h.pop()
        if h and stamp - h[-1][0] > self.max_gap:
            h.clear()                            # after a gap: no twist from unrelated poses
            self._filtered = None
        h.append((float(stamp), pose))
        while len(h) > 2 and h[1][0] <= stamp - self.baseline:
            h.pop(0)                             # keep one pose at least baseline s older
        lin, ang = np.zeros(3), np.zeros(3)
        t0, p0 = h[0]
        self.twist_full = t0 <= stamp - self.baseline   # the same test as the pruning above
        if self.twist_full:
            dt = stamp - t0
            lin = (pose[:3, 3] - p0[:3, 3]) / dt
            ang = pin.log3(pose[:3, :3] @ p0[:3, :3].T) / dt
        elif self.raw is not None and len(h) > 1:
            lin, ang = self.raw.linear, self.raw.angular   # too short yet: keep it
        self.raw = HostState.trusted(pose, lin, ang)
        self.state = self._filter(stamp, self.raw) if self.pose_cutoff > 0.0 else self.raw
        self.stamp = float(stamp)
        return self.state

    def _filter(self, stamp: float, raw: HostState) -> HostState:
        """The mount-mode filter (class doc) updated with ``raw`` at ``stamp`` (s)."""
        f = self._filtered
        if f is None or stamp <= f[4]:
            if f is None:
                f = self._filtered = [raw.pose[:3, 3].copy(), raw.pose[:3, :3].copy(),
                                      raw.linear.copy(), raw.angular.copy(), float(stamp),
                                      1.0 / (2.0 * math.pi * self.pose_cutoff)]
        else:
            dt = stamp - f[4]
            a1 = 1.0 - math.exp(-2.0 * math.pi * self.pose_cutoff * dt)
            f[5] = dt * (1.0 - a1) / a1      # the sampled filter's lag on a ramp (-> T)
            a2 = 1.0 - math.exp(-2.0 * math.pi * self.twist_cutoff * dt)
            f[0] = f[0] + a1 * (raw.pose[:3, 3] - f[0])
            f[1] = f[1] @ pin.exp3(a1 * pin.log3(f[1].T @ raw.pose[:3, :3]))
            f[2] = f[2] + a2 * (raw.linear - f[2])
            f[3] = f[3] + a2 * (raw.angular - f[3])
            f[4] = float(stamp)
        lead = f[5]
        pose = np.eye(4)
        pose[:3, 3] = f[0] + lead * f[2]
        pose[:3, :3] = pin.exp3(lead * f[3]) @ f[1]
        return HostState.trusted(pose, f[2].copy(), f[3].copy())


@dataclass(frozen=True)
class CompensationConfig:
    """Settings of :class:`Compensator` (validated on construction).

    iterations: damped least-squares iterations per cycle (warm-started).
    damping: lambda0 of the damping lambda = damping + |e|^2 (m^2).
    orientation_scale: m/rad, weight of orientation errors against position errors.
    position_tolerance / orientation_tolerance: m / rad; above them (after the iterations
    stall) the pose is reported unreachable.
    speed_scale: fraction of each joint's velocity limit allowed per cycle (step limit).
    limit_margin: rad kept from every joint limit.
    max_horizon: s, the prediction horizon is clamped to [0, max_horizon].
    posture_gain: fraction of the way back to the posture at start per cycle, in the
    task's null space (keeps the nine joints from drifting towards singular postures).
    profile_lead: add to each joint's command the distance its servo's acceleration-limited
    profile trails a goal moving at the joint's feed-forward speed v, v|v| / (2 a) (a: the
    joint's acceleration limit): a servo that brakes to stop at its goal lags a moving
    goal by that much, more for fast joints than for slow ones, which a single delay
    cannot compensate.
    stall_cycles: cycles in a row of a miss that does not shrink (not step-limited) after
    which the pose is reported unreachable.
    limit_band: rad from a joint's limit margin within which the null space pushes it away.
    limit_gain: the push per cycle (rad) is limit_gain x (limit_band - distance) inside the
    band, in the task's null space; the posture pull fades as (distance / limit_band)^2.
    track_position_tolerance / track_orientation_tolerance: m / rad, the MEASURED tool error
    (FK of the measured joints on the host pose) above which the loop reports ``off_track``
    (:class:`~hyperarm_control.host.CompensationLoop`).
    singular_threshold: m/rad, the weighted Jacobian's smallest singular value (position
    rows in m/rad, orientation rows x orientation_scale) below which the damping grows.
    singular_damping: m^2, the damping added at the singularity (smallest singular value
    0), fading as (1 - (sigma/threshold)^2): a least-squares gain of at most
    1 / (2 sqrt(singular_damping)) rad/m there.
    """

    iterations: int = 6
    damping: float = 1e-6
    orientation_scale: float = 0.2
    position_tolerance: float = 1e-3
    orientation_tolerance: float = 0.01
    speed_scale: float = 0.8
    limit_margin: float = 0.02
    max_horizon: float = 0.2
    stall_cycles: int = 10
    posture_gain: float = 0.05
    profile_lead: bool = True
    singular_threshold: float = 0.02
    singular_damping: float = 4e-4
    limit_band: float = 0.3
    limit_gain: float = 0.1
    track_position_tolerance: float = 5e-3
    track_orientation_tolerance: float = 0.035

    def __post_init__(self) -> None:
        if not isinstance(self.profile_lead, bool):
            raise HostConfigError(f"profile_lead must be true or false, got {self.profile_lead!r}")
        for name in ("iterations", "stall_cycles"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 100:
                raise HostConfigError(f"{name} must be an integer in 1..100, got {v!r}")
        for name, lo, hi in (("damping", 0.0, 1.0), ("orientation_scale", 1e-3, 10.0),
                             ("position_tolerance", 1e-6, 0.1),
                             ("orientation_tolerance", 1e-5, 1.0), ("speed_scale", 1e-3, 1.0),
                             ("limit_margin", 0.0, 0.5), ("max_horizon", 0.0, 1.0),
                             ("posture_gain", 0.0, 1.0), ("singular_threshold", 0.0, 1.0),
                             ("singular_damping", 0.0, 1.0), ("limit_band", 0.0, 1.0),
                             ("limit_gain", 0.0, 1.0),
                             ("track_position_tolerance", 1e-5, 1.0),
                             ("track_orientation_tolerance", 1e-4, 3.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or not lo <= v <= hi:
                raise HostConfigError(f"{name} must be a number in {lo:g}..{hi:g}, got {v!r}")


class Status(str, Enum):
    TRACKING = "tracking"          # the command holds tool0 at the goal (within tolerance)
    OFF_TRACK = "off_track"        # the measured tool is off the goal (loop's judgement)
    CONVERGING = "converging"      # moving there, limited by the step limit
    UNREACHABLE = "unreachable"    # holding the closest configuration; reason says why


@dataclass(frozen=True)
class CompensationStep:
    """One cycle's output: the arm joints ``q`` (rad, the arm's joint order) that put tool0
    at the goal on the predicted host pose, the ``command`` to send (``q`` plus the profile
    lead), the feed-forward joint speeds ``velocity`` (rad/s), status, reason (empty unless
    UNREACHABLE), tool errors of ``q`` against the predicted goal (m, rad) and whether the
    step limit scaled the motion."""

    q: np.ndarray
    status: Status
    reason: str
    position_error: float
    orientation_error: float
    step_limited: bool
    command: np.ndarray | None = None
    velocity: np.ndarray | None = None


class Compensator:
    """Per-cycle IK of the nine arm joints for a world-fixed tool0 goal on a moving host.

    ``kin`` is the fixed-arm :class:`Kinematics` (root base_link, nine joints).
    """

    def __init__(self, kin: Kinematics, config: CompensationConfig | None = None) -> None:
        if kin.variant != "arm" or kin.nq != len(kin.desc.joints):
            raise HostConfigError("Compensator needs the fixed-arm kinematics (variant 'arm', "
                                  f"root base_link), got {kin.variant!r}")
        self.kin = kin
        self.config = config if config is not None else CompensationConfig()
        c = self.config
        self.lower = kin.lower + c.limit_margin
        self.upper = kin.upper - c.limit_margin
        if np.any(self.lower >= self.upper):
            raise HostConfigError(f"limit_margin {c.limit_margin} rad leaves no joint range")
        self.velocity_limit = np.array([j.velocity for j in kin.desc.joints])      # rad/s
        self.speed = self.velocity_limit * c.speed_scale                              # rad/s
        self.acceleration = np.array([j.acceleration for j in kin.desc.joints])    # rad/s^2
        self._s2 = np.array([1.0, 1.0, 1.0] + [c.orientation_scale ** 2] * 3)  # error weights
        self._winv = np.diag(1.0 / self._s2)
        self._wsqrt = np.sqrt(self._s2)
        self._best, self._stuck = math.inf, 0
        self.q: np.ndarray | None = None        # the last solution (rad)
        self.sent: np.ndarray | None = None     # the last command sent, lead included (rad)
        self.goal: np.ndarray | None = None     # tool0 in world (4x4)

    @property
    def started(self) -> bool:
        return self.q is not None

    def tool_in_world(self, q: np.ndarray, host: HostState) -> np.ndarray:
        """4x4 pose of tool0 in world with arm joints ``q`` on ``host``."""
        return host.pose @ self.kin.forward(q)

    def start(self, q_measured, host: HostState, goal: np.ndarray | None = None) -> np.ndarray:
        """Begin from the measured arm joints (clipped into the margins); the goal is
        ``goal`` (tool0 in world) or, if None, where tool0 is now. Returns the goal."""
        q = self.kin._q(q_measured)     # raises InvalidSeedError (an IKError) when malformed
        self.q = np.clip(q, self.lower, self.upper)
        self.sent = self.q.copy()
        self._ref = self.q.copy()               # the posture the null space pulls towards
        self._best, self._stuck = math.inf, 0
        self.goal = (self.tool_in_world(q, host) if goal is None
                     else check_pose(goal, "goal", HostGoalError))
        return self.goal.copy()

    def set_goal(self, goal: np.ndarray) -> None:
        """New tool0 goal in world (4x4); reached at the step limit's pace."""
        if self.q is None:
            raise NotStartedError("set_goal before start")
        self.goal = check_pose(goal, "goal", HostGoalError)
        self._best, self._stuck = math.inf, 0

    def stop(self) -> None:
        self.q = self.goal = self.sent = None

    def step(self, host: HostState, horizon: float, dt: float) -> CompensationStep:
        """One cycle: the arm command for the host pose ``horizon`` s ahead (s, clamped to
        0..max_horizon), moving at most the step limit over ``dt`` s (> 0) from the last
        command."""
        if self.q is None or self.goal is None:
            raise NotStartedError("step before start")
        if not (math.isfinite(horizon) and math.isfinite(dt) and dt > 0.0):
            raise HostStateError(f"horizon {horizon!r} s and dt {dt!r} s must be finite, "
                                 "dt > 0")
        c, kin = self.config, self.kin
        h = min(max(horizon, 0.0), c.max_horizon)
        predicted = host.predict(h)
        target = rigid_inverse(predicted) @ self.goal      # tool0 goal in base_link
        pt, rt = target[:3, 3], target[:3, :3]
        excess = kin.reach_excess(pt)
        # no posture pull while unreachable: the command settles at the closest configuration
        pull = c.posture_gain if excess <= 0.0 and self._stuck < c.stall_cycles else 0.0
        q = self.q.copy()
        prev = math.inf
        stalled = False
        at_q = None                 # (position error, orientation error, J) evaluated at q
        for it in range(c.iterations):
            p, r, j = kin.pose_jacobian_view(q)
            e = np.concatenate((pt - p, pin.log3(rt @ r.T)))
            cost = float(e @ (self._s2 * e))
            if cost >= prev * 0.99:
                stalled = True
            prev = cost
            if math.sqrt(cost) < 1e-7:
                at_q = (float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:])), j)
                break
            if it == 0:     # the singularity's damping, once per cycle (J changes little)
                lam_s = self.singular_damping(j)
            lam = c.damping + cost + lam_s
            # first iteration: a pull towards the posture at start and a push away from the
            # limits, in the task's null space
            z = self._null_space(q, pull) if it == 0 and pull > 0.0 else None
            dq = self._dls(j, e, lam, z)
            if c.limit_band > 0.0 and pull > 0.0:   # reachable: spare joints near limits
                w = self._limit_weights(q, dq)
                if w is not None:
                    dq = self._dls(j, e, lam, z, w)
            out = ((q + dq < self.lower) & (dq < 0)) | ((q + dq > self.upper) & (dq > 0))
            if out.any():          # joints held at a limit leave the step (active set, once)
                j = j.copy()
                j[:, out] = 0.0
                dq = self._dls(j, e, lam, None if z is None else np.where(out, 0.0, z))
            q = np.clip(q + dq, self.lower, self.upper)
        if at_q is None:
            p, r, j = kin.pose_jacobian_view(q)
            at_q = (float(np.linalg.norm(pt - p)), rotation_angle(rt, r), j)
        perr_ik, oerr_ik, j_q = at_q
        delta = q - self.q
        ratio = float(np.max(np.abs(delta) / (self.speed * dt)))
        limited = ratio > 1.0
        if limited:
            delta /= ratio
            self.q = np.clip(self.q + delta, self.lower, self.upper)
            perr, oerr = self._errors(self.q, pt, rt)
        else:
            self.q, perr, oerr = q, perr_ik, oerr_ik
        ok = perr_ik <= c.position_tolerance and oerr_ik <= c.orientation_tolerance
        # a miss that no longer shrinks (1 %) for stall_cycles cycles, not step-limited
        residual = perr_ik + c.orientation_scale * oerr_ik
        if ok or limited or not stalled or residual < 0.99 * self._best:
            self._best, self._stuck = residual, 0
        else:
            self._stuck += 1
        unreachable = excess > 0.0 or self._stuck >= c.stall_cycles
        velocity = (np.zeros(kin.nq) if unreachable or limited
                    else self._feed_forward(host, predicted, j_q))
        command = self.q.copy()
        if c.profile_lead:
            command = command + velocity * np.abs(velocity) / (2.0 * self.acceleration)
        # LAST, after every other term: one cycle's reach of the previous command, limits
        command = limit_step(command, self.sent, self.velocity_limit, dt, self.lower,
                             self.upper)
        self.sent = command
        if unreachable:
            why = (f"beyond the arm's reach by {excess:.3f} m" if excess > 0.0 else
                   f"closest configuration misses by {perr_ik * 1e3:.1f} mm, "
                   f"{math.degrees(oerr_ik):.2f} deg")
            return CompensationStep(self.q.copy(), Status.UNREACHABLE,
                                    f"goal unreachable from the host's pose: {why}; holding "
                                    "the closest configuration", perr, oerr, limited,
                                    command, velocity)
        status = Status.TRACKING if (perr <= c.position_tolerance
                                     and oerr <= c.orientation_tolerance) else Status.CONVERGING
        return CompensationStep(self.q.copy(), status, "", perr, oerr, limited, command,
                                velocity)

    def _null_space(self, q: np.ndarray, pull: float) -> np.ndarray:
        """The null-space motion of one cycle (rad): ``pull`` of the way back to the posture
        at start, faded as (d / limit_band)^2 near a limit (d: rad to the nearer margin), plus
        limit_gain x (limit_band - d) away from a limit within the band."""
        c = self.config
        z = pull * (self._ref - q)
        if c.limit_band <= 0.0:
            return z
        lo, hi = q - self.lower, self.upper - q
        d = np.minimum(lo, hi)
        inside = d < c.limit_band
        if inside.any():
            fade = np.clip(d / c.limit_band, 0.0, 1.0) ** 2
            away = np.where(lo <= hi, 1.0, -1.0)
            z = np.where(inside, fade * z + away * c.limit_gain * (c.limit_band - d), z)
        return z

    def measured_error(self, q, host: HostState) -> tuple[float, float]:
        """(m, rad) tool0 of the MEASURED arm joints ``q`` on ``host`` against the goal."""
        if self.goal is None:
            raise NotStartedError("measured_error before start")
        tool = self.tool_in_world(self.kin._q(q), host)
        return (float(np.linalg.norm(tool[:3, 3] - self.goal[:3, 3])),
                rotation_angle(self.goal[:3, :3], tool[:3, :3]))

    def limit_joints(self, q, within: float = 1e-3) -> list[str]:
        """Names of the joints of ``q`` (rad) within ``within`` rad of the limit margins."""
        q = np.asarray(q, dtype=float)
        near = (q <= self.lower + within) | (q >= self.upper - within)
        return [self.kin.desc.joints[i].name for i in np.flatnonzero(near)]

    def _feed_forward(self, host: HostState, predicted: np.ndarray,
                      j: np.ndarray) -> np.ndarray:
        """Joint speeds (rad/s) that keep tool0 on the goal while the host moves at its
        twist: the goal's velocity in base_link (position -R^T (v + w x (p_goal - p_host)),
        angular -R^T w) through the weighted damped least squares with ``j``, the
        Jacobian at the command."""
        if not (host.linear.any() or host.angular.any()):
            return np.zeros(self.kin.nq)
        r = predicted[:3, :3]
        lever = self.goal[:3, 3] - predicted[:3, 3]
        twist = np.concatenate((-r.T @ (host.linear + np.cross(host.angular, lever)),
                                -r.T @ host.angular))
        j = j.copy()
        j[:, (self.q <= self.lower + 1e-9) | (self.q >= self.upper - 1e-9)] = 0.0
        lam = self.config.damping + self.singular_damping(j)
        v = self._dls(j, twist, lam)
        w = self._limit_weights(self.q, v) if self.config.limit_band > 0.0 else None
        if w is not None:
            v = self._dls(j, twist, lam, None, w)
        ratio = float(np.max(np.abs(v) / self.speed))
        return v / ratio if ratio > 1.0 else v      # at most the step limit's speeds

    def singular_damping(self, j: np.ndarray) -> float:
        """Damping (m^2) added near a singularity of ``j``: singular_damping x
        (1 - (sigma_min / singular_threshold)^2) below the threshold, else 0 (sigma_min: the
        smallest singular value of the weighted Jacobian, m/rad)."""
        c = self.config
        if c.singular_damping <= 0.0 or c.singular_threshold <= 0.0:
            return 0.0
        a = self._wsqrt[:, None] * j
        s2 = max(float(np.linalg.eigvalsh(a @ a.T)[0]), 0.0)
        t2 = c.singular_threshold ** 2
        return c.singular_damping * (1.0 - s2 / t2) if s2 < t2 else 0.0

    def _limit_weights(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray | None:
        """Weighted least norm (Chan & Dubey): each joint's share of the task motion, 1
        but (d / limit_band)^2 (at least 1e-3) for a joint within limit_band (d, rad) of a
        limit margin that ``dq`` moves towards it; None when every weight is 1."""
        band = self.config.limit_band
        lo, hi = q - self.lower, self.upper - q
        d = np.where(dq < 0.0, lo, hi)
        toward = (d < band) & (dq != 0.0)
        if not toward.any():
            return None
        return np.where(toward, np.clip(d / band, 0.0316, 1.0) ** 2, 1.0)

    def _dls(self, j: np.ndarray, e: np.ndarray, lam: float,
             z: np.ndarray | None = None, w: np.ndarray | None = None) -> np.ndarray:
        """Weighted damped least squares: argmin |J dq - e|^2_W + lam |dq - z|^2, with
        ``lam`` includes the singularity's damping (:meth:`singular_damping`, added by the
        caller). ``w``: per-joint weights of the motion (|dq - z|^2 weighted by 1/w; None:
        all 1)."""
        if w is not None:
            jw = j * w
            a = jw @ j.T + lam * self._winv
            return (jw.T @ np.linalg.solve(a, e) if z is None
                    else z + jw.T @ np.linalg.solve(a, e - j @ z))
        if z is None:
            return j.T @ np.linalg.solve(j @ j.T + lam * self._winv, e)
        return z + j.T @ np.linalg.solve(j @ j.T + lam * self._winv, e - j @ z)

    def _errors(self, q: np.ndarray, pt: np.ndarray, rt: np.ndarray) -> tuple[float, float]:
        p, r = self.kin.pose_view(q)
        return float(np.linalg.norm(pt - p)), rotation_angle(rt, r)


class DelayEstimator:
    """The loop's delay (s) from a command to the measured joints that match it.

    :meth:`commanded` records every command (time s, joints rad); :meth:`measured`, for a
    measured joint vector at its arrival time, finds the recorded command nearest to it
    (within ``window`` s) and, while the commands move (at least ``min_motion`` rad over
    the window), smooths arrival - command time into :attr:`delay` (exponential, ``gain``
    per sample). On a ramp, a first-order servo lag looks like a pure delay, so this is the
    horizon that makes the measured joints land on the host pose they were computed for.
    """

    def __init__(self, initial: float, window: float = 0.3, min_motion: float = 0.005,
                 gain: float = 0.05) -> None:
        for name, v, lo, hi in (("initial", initial, 0.0, 1.0), ("window", window, 0.01, 5.0),
                                ("min_motion", min_motion, 0.0, 1.0), ("gain", gain, 1e-4, 1.0)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or not lo <= v <= hi:
                raise HostConfigError(f"delay estimator {name} must be in {lo:g}..{hi:g}, "
                                      f"got {v!r}")
        self.delay = float(initial)
        self.window, self.min_motion, self.gain = window, min_motion, gain
        self._t: list[float] = []
        self._q: list[np.ndarray] = []
        self.samples = 0

    def reset(self) -> None:
        self._t.clear()
        self._q.clear()

    def commanded(self, t: float, q: np.ndarray) -> None:
        self._t.append(t)
        self._q.append(np.array(q, dtype=float))
        while self._t and self._t[0] < t - self.window:
            self._t.pop(0)
            self._q.pop(0)

    def measured(self, t: float, q: np.ndarray) -> float:
        """Update with joints measured (arriving) at ``t``; returns the delay (s). A sample
        counts only where the match is sharp: the commands around the nearest one move
        (between its neighbours) at least 3 times the miss, so a measured posture near a
        turning point, where commands before and after the turn look alike, is no sample."""
        if len(self._q) < 3:
            return self.delay
        hist = np.array(self._q)
        if float(np.abs(hist[-1] - hist[0]).max()) < self.min_motion:
            return self.delay
        miss = np.abs(hist - np.asarray(q, dtype=float)).max(axis=1)
        i = int(np.argmin(miss))
        # the oldest entry may be older still, the newest is the command just sent: no sample
        if 0 < i < len(hist) - 1 and \
                float(np.abs(hist[i + 1] - hist[i - 1]).max()) >= 3.0 * float(miss[i]):
            sample = t - self._t[i]
            self.delay += self.gain * (min(max(sample, 0.0), self.window) - self.delay)
            self.samples += 1
        return self.delay
