"""The hybrid position/force control law of Danko & Oh (eqs. 6-8), as a lab would run it.

No ROS. Units: m, rad, s, kg, N, N·m. Vectors of 6 are [x, y, z, rx, ry, rz]: linear
rows first, in the axes of the goal's frame (the model's root frame, ``base_link`` or
``world``), about tool0's origin (pinocchio's LOCAL_WORLD_ALIGNED). Joint vectors are in
the description's ``kinematic_joint_names`` order (rail first on ``rail_arm``); the rail is
position-controlled and never gets a torque: every torque vector here has one entry per
*arm* joint (``HybridLaw.arm_names``).

Per cycle, with e = [p0 - p; log3(R0 R^T)] and the tool twist v = J dq (goal axes):

    F      = K e - D v + S F_d                 (eq. 6 plus feed-forward and damping)
    F      <- F * min(1, f_max/|F_lin|, m_max/|F_ang|)   (scaled: direction kept)
    tau    = g(q) + J^T F + N tau_0 - d_j dq   (eqs. 7-8 read as T = J^T F_int, docs/force.md)

with S the diagonal selection of force-controlled axes, K the goal's diagonal stiffness,
g the gravity torque of every link plus the payload (pinocchio), N = I - J^+ J the null-space
projector (damped J^+), tau_0 a posture spring towards ``posture`` plus a barrier away
from the joint limits that dominates it near them (:func:`null_space_torque`). The non-gravity part is then scaled (one factor, direction kept) into the
per-joint limits (stall torque x ``torque_margin``), and the change per cycle is limited to
``torque_rate`` x dt.

Two outputs of the same law:

- ``torque``: the torques themselves (effort-only joint_command: current mode);
- ``position``: the paper's pseudo-goal for position servos of known stiffness k_s:
  q_cmd moves so that the servo torques k_s (q_cmd - q) make the law's wrench at the
  tool (:meth:`HybridLaw._pseudo_goal`), sent with a current limit
  |g| + |k_s (q_cmd - q)| + ``effort_headroom`` (current-based position). Servos whose
  integral action does not hold gravity (``servo_holds_gravity`` false) get g / k_s added
  to q_cmd.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pinocchio as pin

from hyperarm_description.limits import limit_step
from hyperarm_description.model import RobotDescription

from hyperarm_ik.kinematics import Kinematics
from .errors import ForceConfigError, InvalidGoalError, StateError

__all__ = ["Payload", "LawConfig", "HybridGoal", "Command", "GravityModel", "HybridLaw",
           "OUTPUTS", "make_goal", "pose_error", "scale_wrench", "scale_into_limits",
           "rate_limit", "null_space_torque", "QUATERNION_TOLERANCE"]

OUTPUTS = ("torque", "position")
QUATERNION_TOLERANCE = 1e-3    # |norm - 1| accepted for a goal's quaternion
GRAVITY = 9.81                 # m/s², pinocchio's default model gravity (-z)


def _finite(value, where: str, shape: tuple[int, ...] | None = None,
            error: type[Exception] = ForceConfigError) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if shape is not None and a.shape != shape:
        raise error(f"{where}: expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise error(f"{where}: must be finite, got {a.tolist()}")
    return a


def _check(value: float, where: str, lo: float, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ForceConfigError(f"{where}: expected a number, got {value!r}")
    v = float(value)
    if not (math.isfinite(v) or v == math.inf == hi) or not lo <= v <= hi:
        raise ForceConfigError(f"{where}: {v!r} not within {lo:g}..{hi:g}")
    return v


@dataclass(frozen=True)
class Payload:
    """A held payload: mass (kg) at ``com`` (m, in tool0)."""

    mass: float = 0.0
    com: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        _check(self.mass, "payload.mass", 0.0, 10.0)
        object.__setattr__(self, "com", tuple(_finite(self.com, "payload.com", (3,)).tolist()))


@dataclass(frozen=True)
class LawConfig:
    """Gains and limits of :class:`HybridLaw` (SI). Validated on construction.

    damping: Cartesian damping on the tool twist [N·s/m x3, N·m·s/rad x3].
    position_stiffness: the least stiffness of position-controlled axes in the
      ``position`` output [N/m x3, N·m/rad x3] (tracking, not a force: see docs/force.md).
    joint_damping: N·m·s/rad on every arm joint's velocity.
    posture: preferred arm joint angles (rad) of the null-space term (None: all 0).
    posture_stiffness: N·m/rad of the null-space posture spring.
    limit_margin / limit_stiffness: within ``limit_margin`` rad of a limit a barrier
      (scaled by ``limit_stiffness`` N·m/rad, in the null space) pushes away from it, and
      the posture spring fades out (:func:`null_space_torque`).
    torque_margin: fraction of each servo's stall torque the controller may command.
    torque_rate: N·m/s, the largest change of a joint torque (per cycle: x dt); in the
      ``position`` output the pseudo-goal moves by at most torque_rate x dt / k_s.
    max_force / max_moment: Cartesian wrench limits (N, N·m), applied by scaling.
    singular_damping: lambda of the damped pseudo-inverses (m).
    servo_stiffness: N·m/rad of the servos' position loop (``position`` output).
    servo_holds_gravity: the servos' integral action holds gravity in position mode.
    effort_headroom: N·m above |tau| for the ``position`` output's current limit.
    position_filter / force_filter: 0..1, per-cycle gain of the pseudo-goal's update on
      the position / force-controlled axes (``position`` output).
    compliance_stiffness / compliance_effort: whole-arm compliance: every joint a spring of
      this stiffness (N·m/rad) towards the posture at its start, non-gravity torque at most
      ``compliance_effort`` N·m per joint.
    max_linear_stiffness / max_angular_stiffness: goals with a larger K are refused.
    workspace_margin: m beyond the arm's reach bound a goal may lie (else refused).
    max_speed / max_angular_speed: m/s, rad/s at which the law's reference follows the
      goal's X0 (a goal step is tracked as a ramp).
    force_rate: N/s, the fastest change of the force axes' wrench in the ``position``
      output (moments: x max_moment / max_force, N·m/s): presses build and release at
      most this fast, so the position axes keep up in contact.
    posture_speed: rad/s at which the null-space posture spring's reference moves from the
      posture at :meth:`HybridLaw.reset` to ``posture`` (no null-space lurch at enable).
    transition_time: s over which whole-arm compliance fades in or out (its springs and
      its effort cap), instead of a torque step.
    """

    damping: tuple[float, ...] = (8.0, 8.0, 8.0, 0.05, 0.05, 0.05)
    position_stiffness: tuple[float, ...] = (3000.0, 3000.0, 3000.0, 100.0, 100.0, 100.0)
    joint_damping: float = 0.02
    posture: tuple[float, ...] | None = None
    posture_stiffness: float = 0.3
    limit_margin: float = 0.2
    limit_stiffness: float = 3.0
    torque_margin: float = 0.8
    torque_rate: float = 100.0
    max_force: float = 30.0
    max_moment: float = 3.0
    singular_damping: float = 0.02
    servo_stiffness: float = 20.0
    servo_holds_gravity: bool = True
    effort_headroom: float = 1.0
    position_filter: float = 0.2
    force_filter: float = 0.5
    compliance_stiffness: float = 0.2
    compliance_effort: float = 0.4
    max_linear_stiffness: float = 5000.0
    max_angular_stiffness: float = 100.0
    workspace_margin: float = 0.02
    max_speed: float = 0.1
    max_angular_speed: float = 0.5
    force_rate: float = 5.0
    posture_speed: float = 0.5
    transition_time: float = 0.5

    def __post_init__(self) -> None:
        d = _finite(self.damping, "damping", (6,))
        if np.any(d < 0.0):
            raise ForceConfigError(f"damping: must be >= 0, got {d.tolist()}")
        object.__setattr__(self, "damping", tuple(d.tolist()))
        k = _finite(self.position_stiffness, "position_stiffness", (6,))
        if np.any(k <= 0.0):
            raise ForceConfigError(f"position_stiffness: must be > 0, got {k.tolist()}")
        object.__setattr__(self, "position_stiffness", tuple(k.tolist()))
        if self.posture is not None:
            object.__setattr__(self, "posture",
                               tuple(_finite(self.posture, "posture").reshape(-1).tolist()))
        for name, lo, hi in (("joint_damping", 0.0, 10.0), ("posture_stiffness", 0.0, 100.0),
                             ("limit_margin", 0.0, 1.0), ("limit_stiffness", 0.0, 1000.0),
                             ("torque_margin", 0.05, 1.0), ("torque_rate", 1e-3, 1e6),
                             ("max_force", 0.0, 1000.0), ("max_moment", 0.0, 100.0),
                             ("singular_damping", 1e-6, 1.0),
                             ("servo_stiffness", 0.1, 1e5), ("effort_headroom", 0.0, 10.0),
                             ("position_filter", 1e-3, 1.0), ("force_filter", 1e-3, 1.0),
                             ("compliance_stiffness", 0.0, 100.0),
                             ("compliance_effort", 0.0, 100.0),
                             ("max_linear_stiffness", 0.0, 1e6),
                             ("max_angular_stiffness", 0.0, 1e4),
                             ("workspace_margin", 0.0, 10.0), ("max_speed", 1e-3, 2.0),
                             ("max_angular_speed", 1e-3, 10.0), ("force_rate", 0.1, 1e4),
                             ("posture_speed", 1e-3, 10.0), ("transition_time", 0.0, 10.0)):
            _check(getattr(self, name), name, lo, hi)
        if not isinstance(self.servo_holds_gravity, bool):
            raise ForceConfigError(f"servo_holds_gravity: expected a bool, got "
                                   f"{self.servo_holds_gravity!r}")


@dataclass(frozen=True)
class HybridGoal:
    """A validated goal (see :func:`make_goal`). Root frame, m, rad, N, N·m."""

    position: np.ndarray            # (3,) X0 position
    rotation: np.ndarray            # (3, 3) X0 orientation
    stiffness: np.ndarray           # (6,) K, goal axes
    force_axes: np.ndarray          # (6,) bool, S
    wrench: np.ndarray              # (6,) F_d, goal axes (zero on position axes)
    frame: str = ""


def make_goal(kin: Kinematics, config: LawConfig, frame: str, position: Sequence[float],
              quaternion_xyzw: Sequence[float], stiffness: Sequence[float],
              force_axes: Sequence[bool], wrench: Sequence[float]) -> HybridGoal:
    """Check a goal whole and build it; raises :class:`InvalidGoalError` saying why.

    Refused: a frame other than the root frame, non-finite numbers, a quaternion whose norm
    is not 1 (+-QUATERNION_TOLERANCE), a negative stiffness or one above the configured
    maxima, a pose beyond the reach bound by more than ``workspace_margin``, a feed-forward
    wrench beyond the wrench limits.
    """
    if frame != kin.root_frame:
        shown = repr(frame) if frame else "empty"
        raise InvalidGoalError(f"goal frame is {shown}; goals are taken in {kin.root_frame!r}")
    p = _finite(position, "goal position", (3,), InvalidGoalError)
    quat = _finite(quaternion_xyzw, "goal orientation", (4,), InvalidGoalError)
    norm = float(np.linalg.norm(quat))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise InvalidGoalError(f"goal quaternion norm is {norm:.6g}, not 1 "
                               f"(+-{QUATERNION_TOLERANCE:g})")
    x, y, z, w = quat / norm
    rot = pin.Quaternion(w, x, y, z).toRotationMatrix()
    k = _finite(stiffness, "goal stiffness", (6,), InvalidGoalError)
    if np.any(k < 0.0):
        raise InvalidGoalError(f"goal stiffness must be >= 0, got {k.tolist()}")
    if np.any(k[:3] > config.max_linear_stiffness) or np.any(k[3:] > config.max_angular_stiffness):
        raise InvalidGoalError(
            f"goal stiffness {k.tolist()} above the maxima {config.max_linear_stiffness:g} N/m, "
            f"{config.max_angular_stiffness:g} N·m/rad")
    s = np.asarray(force_axes)
    if s.shape != (6,):
        raise InvalidGoalError(f"force_controlled: expected 6 flags, got {s.shape}")
    s = s.astype(bool)
    f = _finite(wrench, "goal wrench", (6,), InvalidGoalError)
    f = np.where(s, f, 0.0)
    if np.linalg.norm(f[:3]) > config.max_force or np.linalg.norm(f[3:]) > config.max_moment:
        raise InvalidGoalError(f"goal wrench {f.tolist()} beyond the limits "
                               f"{config.max_force:g} N, {config.max_moment:g} N·m")
    excess = kin.reach_excess(p)
    if excess > config.workspace_margin:
        raise InvalidGoalError(f"goal position {p.tolist()} is {excess:.3f} m beyond the arm's "
                               f"reach")
    return HybridGoal(position=p, rotation=rot, stiffness=k, force_axes=s, wrench=f,
                      frame=frame)


def pose_error(p0: np.ndarray, r0: np.ndarray, p: np.ndarray, r: np.ndarray) -> np.ndarray:
    """[p0 - p; log3(R0 R^T)] (m, rad; root axes): X0 - X of eq. 6."""
    return np.concatenate((p0 - p, pin.log3(r0 @ r.T)))


def scale_wrench(f: np.ndarray, max_force: float, max_moment: float) -> tuple[np.ndarray, float]:
    """``f`` scaled by one factor so that |force| <= max_force and |moment| <= max_moment
    (the direction of the 6-D wrench is kept). Returns (wrench, factor in [0, 1])."""
    s = 1.0
    fl, fa = f[:3], f[3:]
    nf, nm = math.sqrt(float(fl @ fl)), math.sqrt(float(fa @ fa))
    if nf > max_force:
        s = min(s, max_force / nf)
    if nm > max_moment:
        s = min(s, max_moment / nm)
    return f * s, s


def scale_into_limits(base: np.ndarray, delta: np.ndarray,
                      limit: np.ndarray) -> tuple[np.ndarray, float]:
    """base + s * delta with the largest s in [0, 1] keeping every |entry| <= limit.

    ``base`` (gravity) is clipped into the limits first if it alone exceeds them. Returns
    (torques, s)."""
    b = np.minimum(np.maximum(base, -limit), limit)
    t = b + delta
    over = np.abs(t) > limit
    if not over.any():
        return t, 1.0
    d = delta[over]
    bound = np.sign(d) * limit[over]
    s = float(np.clip(np.min((bound - b[over]) / d), 0.0, 1.0))
    return np.clip(b + s * delta, -limit, limit), s


def null_space_torque(q: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                      posture: np.ndarray, posture_stiffness: float, margin: float,
                      limit_stiffness: float) -> np.ndarray:
    """The null-space term's torque tau_0 (N·m per joint) at joint angles ``q`` (rad).

    Within ``margin`` (m, rad) of a limit, at a distance d, a push away from it of
    k_l (m - d) m / max(d, m/4) (k_l = ``limit_stiffness``, N·m/rad): 0 at d = m, growing
    like 1/d (a barrier) to 4 k_l (m - d) inside m/4, where it turns linear again (its
    slope k_l m²/d² capped at 4 k_l: the per-cycle null-space iteration stays stable).
    The posture spring k_p (posture - q) is faded by min(1, d_min / m)², d_min the smallest
    distance of any joint to its limit: near a limit the push dominates, so the posture
    spring cannot drive one joint into its limit through the null space's coupling (a
    posture spring pulling without bound against a push capped at k_l m did: issue 24)."""
    d_lo = q - lower
    d_hi = upper - q
    spring = posture_stiffness * (posture - q)
    if margin <= 0.0:
        return spring
    d_min = float(min(d_lo.min(), d_hi.min()))
    if d_min >= margin:
        return spring
    floor = 0.25 * margin
    push = limit_stiffness * margin * (
        np.maximum(margin - d_lo, 0.0) / np.maximum(d_lo, floor)
        - np.maximum(margin - d_hi, 0.0) / np.maximum(d_hi, floor))
    fade = max(d_min, 0.0) / margin
    return (fade * fade) * spring + push


def rate_limit(target: np.ndarray, previous: np.ndarray,
               max_step: float) -> tuple[np.ndarray, bool]:
    """``target`` with each entry at most ``max_step`` from ``previous``; and whether any
    entry was limited."""
    step = target - previous
    limited = bool((np.abs(step) > max_step).any())
    return previous + np.minimum(np.maximum(step, -max_step), max_step), limited


class GravityModel:
    """Gravity torques of every link (pinocchio, the description's masses) + a payload."""

    def __init__(self, kin: Kinematics) -> None:
        self.kin = kin
        self.model = kin.model
        self.data = self.model.createData()
        self.g = -np.asarray(self.model.gravity.linear, dtype=float)   # (0, 0, 9.81) up
        self.tool_id = kin.tool_id

    def torques(self, q: np.ndarray, payload: Payload, j_tool: np.ndarray | None = None,
                rotation: np.ndarray | None = None) -> np.ndarray:
        """Torques (N·m; N on the rail) that hold the chain still at ``q``: links and payload.

        ``j_tool`` / ``rotation``: tool0's Jacobian (LWA) and rotation at q, if known."""
        tau = pin.computeGeneralizedGravity(self.model, self.data, q).copy()
        if payload.mass > 0.0:
            if j_tool is None or rotation is None:
                j_tool = pin.computeFrameJacobian(self.model, self.data, q, self.tool_id,
                                                  pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
                rotation = self.data.oMf[self.tool_id].rotation
            tau += payload_jacobian(j_tool, rotation, payload.com).T @ (payload.mass * self.g)
        return tau


    def inverse_dynamics(self, q: np.ndarray, v: np.ndarray, a: np.ndarray,
                         payload: Payload) -> np.ndarray:
        """Torques (N·m; N on the rail) of the chain moving with velocity ``v`` and
        acceleration ``a`` at ``q`` (pinocchio RNEA: inertia, Coriolis, gravity), plus the
        payload's gravity (its inertia is neglected)."""
        tau = pin.rnea(self.model, self.data, q, v, a).copy()
        if payload.mass > 0.0:
            j_tool = pin.computeFrameJacobian(self.model, self.data, q, self.tool_id,
                                              pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            rotation = self.data.oMf[self.tool_id].rotation
            tau += payload_jacobian(j_tool, rotation, payload.com).T @ (payload.mass * self.g)
        return tau


def payload_jacobian(j_tool: np.ndarray, rotation: np.ndarray, com) -> np.ndarray:
    """3 x n linear Jacobian of the point ``com`` (m, tool0) from tool0's LWA Jacobian:
    v_point = v + w x r = J_v - [r]x J_w, r = R com."""
    r = rotation @ np.asarray(com, dtype=float)
    skew = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    return j_tool[:3] - skew @ j_tool[3:]


@dataclass
class Command:
    """One cycle's output. Torques/positions per arm joint (``HybridLaw.arm_names``)."""

    tau: np.ndarray                 # N·m, total (gravity included): the 'torque' output
    gravity: np.ndarray             # N·m, gravity part
    q_cmd: np.ndarray               # rad, the 'position' output's pseudo-goal
    effort_limit: np.ndarray        # N·m (> 0), the 'position' output's current limit
    wrench: np.ndarray              # (6,) commanded wrench after the limit, root axes
    error: np.ndarray               # (6,) X0 - X, root axes
    wrench_scale: float = 1.0       # < 1: the Cartesian wrench limit acted
    joint_scale: float = 1.0        # < 1: the joint torque limits acted
    rate_limited: bool = False
    step_limited: bool = False      # the position command's step limit acted
    jacobian: np.ndarray | None = None   # (6, na) arm Jacobian at q (LWA)
    rotation: np.ndarray | None = None   # tool0's rotation at q
    jjt: np.ndarray | None = None        # (6, 6) J J^T (undamped), for the estimate


class HybridLaw:
    """The controller's state and per-cycle law. Build once; :meth:`reset` at enable.

    The cycle is the controller's hot path (target: well under 0.3 ms in Python): it does
    one pinocchio pass for pose and Jacobian and one for gravity, one 6 x 6 inverse and
    one 6 x 6 solve, works on views (the arm joints are a slice of the chain), caches what
    depends only on the goal or the configuration, and never forms the 9 x 9 null-space
    projector (N v = v - J^T (J J^T + l^2 I)^-1 J v)."""

    def __init__(self, kin: Kinematics | None = None, config: LawConfig | None = None,
                 desc: RobotDescription | None = None) -> None:
        self.kin = kin if kin is not None else Kinematics(desc)
        self.config = config if config is not None else LawConfig()
        self.gravity = GravityModel(self.kin)
        desc = self.kin.desc
        self.arm_names = list(desc.arm_joint_names)
        mask = np.array([n in self.arm_names for n in self.kin.joint_names])
        idx = np.flatnonzero(mask)
        contiguous = len(idx) > 0 and idx[-1] - idx[0] + 1 == len(idx)
        # a slice (views, no copies) when the arm joints are contiguous in the chain
        self.arm = slice(int(idx[0]), int(idx[-1]) + 1) if contiguous else mask
        self.na = int(mask.sum())
        self.limit = np.array([j.effort for j in desc.joints]) * self.config.torque_margin
        self.v_max = np.array([j.velocity for j in desc.joints])     # rad/s
        self.lower = self.kin.lower[self.arm]
        self.upper = self.kin.upper[self.arm]
        if self.config.posture is None:
            self.posture = np.zeros(self.na)
        else:
            self.posture = np.asarray(self.config.posture, dtype=float)
            if self.posture.shape != (self.na,):
                raise ForceConfigError(f"posture: expected {self.na} arm joint angles, got "
                                       f"{self.posture.shape[0]}")
            if np.any(self.posture < self.lower) or np.any(self.posture > self.upper):
                raise ForceConfigError("posture: outside the joint limits")
        self.payload = Payload()
        self._ref_p: np.ndarray | None = None
        self._ref_r: np.ndarray | None = None
        self._ref_at: HybridGoal | None = None     # the reference has reached this goal
        self._tau_prev = np.zeros(self.na)
        self._q_cmd = np.zeros(self.na)
        self._q_out: np.ndarray | None = None        # the last position command sent
        self._f_prev: np.ndarray | None = None       # the force axes' last wrench (rate)
        self._f_prev_axes: np.ndarray | None = None  # ... and which axes they were
        self._compliance_posture = self.posture.copy()
        self._posture_ref = self.posture.copy()      # moves to posture at posture_speed
        self._compliance_w = 0.0                     # 0 off .. 1 on (fades)
        cfg = self.config
        self._d = np.asarray(cfg.damping)
        self._k_pos = np.asarray(cfg.position_stiffness)
        self._damp6 = cfg.singular_damping ** 2 * np.eye(6)
        self._gains_for: HybridGoal | None = None
        self._gains: tuple = ()
        # the limit spring of the null-space term: k_l (clamp(q, lo + m, hi - m) - q)
        self._push_lo = self.lower + cfg.limit_margin
        self._push_hi = self.upper - cfg.limit_margin
        if np.any(self._push_lo > self._push_hi):
            raise ForceConfigError(f"limit_margin {cfg.limit_margin:g} rad: more than half "
                                   "of a joint's range")
        self._guard: tuple[float, np.ndarray, np.ndarray] | None = None

    # -- state ---------------------------------------------------------------------------
    def _state(self, q, dq) -> tuple[np.ndarray, np.ndarray]:
        q = np.asarray(q, dtype=float).reshape(-1)
        dq = np.asarray(dq, dtype=float).reshape(-1)
        if q.shape != (self.kin.nq,) or dq.shape != (self.kin.nq,):
            raise StateError(f"expected {self.kin.nq} joint positions and velocities "
                             f"({', '.join(self.kin.joint_names)}), got {q.shape[0]} and "
                             f"{dq.shape[0]}")
        if not math.isfinite(float(q.sum() + dq.sum())):   # NaN/inf anywhere
            raise StateError("non-finite joint positions or velocities")
        return q, dq

    def hold_goal(self, q, stiffness: Sequence[float]) -> HybridGoal:
        """A goal at the present pose of ``q``: every axis position-controlled with
        ``stiffness`` (6 values, N/m and N·m/rad)."""
        q = np.asarray(q, dtype=float)
        p, r = self.kin.pose_view(self._state(q, np.zeros_like(q))[0])
        k = _finite(stiffness, "stiffness", (6,))
        return HybridGoal(position=p.copy(), rotation=r.copy(), stiffness=k,
                          force_axes=np.zeros(6, dtype=bool), wrench=np.zeros(6),
                          frame=self.kin.root_frame)

    def reset(self, q) -> None:
        """Start from the present pose: the previous torque is the gravity torque at ``q``
        (no drop, no jump), the pseudo-goal is ``q`` itself, the compliance posture too."""
        q, _ = self._state(q, np.zeros_like(np.asarray(q, dtype=float)))
        self._tau_prev = self.gravity.torques(q, self.payload)[self.arm].copy()
        self._q_cmd = q[self.arm].copy()
        self._q_out = None
        self._f_prev = None
        self._compliance_posture = q[self.arm].copy()
        self._posture_ref = q[self.arm].copy()
        self._compliance_w = 0.0
        self._ref_p = self._ref_r = None
        self._ref_at = None

    def set_compliance_posture(self, q) -> None:
        """Joint angles (chain order) the compliance springs pull towards."""
        q, _ = self._state(q, np.zeros_like(np.asarray(q, dtype=float)))
        self._compliance_posture = q[self.arm].copy()

    # -- the law -------------------------------------------------------------------------
    def step(self, q, dq, goal: HybridGoal, dt: float, compliance: bool = False,
             output: str = "torque") -> Command:
        """One control cycle at joint state (``q`` rad/m, ``dq``) with period ``dt`` (s)."""
        q, dq = self._state(q, dq)
        return self.step_checked(q, dq, goal, dt, compliance, output)

    def step_checked(self, q: np.ndarray, dq: np.ndarray, goal: HybridGoal, dt: float,
                     compliance: bool = False, output: str = "torque") -> Command:
        """:meth:`step` on states the caller has checked already (float arrays of the
        chain's length, finite)."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise StateError(f"dt must be > 0 s, got {dt!r}")
        cfg = self.config
        arm = self.arm
        p, r, j_full = self.kin.pose_jacobian_view(q)
        p, r = p.copy(), r.copy()
        j = j_full[:, arm]
        g = self.gravity.torques(q, self.payload, j_full, r)[arm]
        qa, dqa = q[arm], dq[arm]
        ref_p, ref_r = self._reference(goal, p, r, dt)
        err = pose_error(ref_p, ref_r, p, r)
        twist = j @ dqa
        jjt = j @ j.T
        jjt_inv = np.linalg.inv(jjt + self._damp6)      # damped: (J J^T + l^2 I)^-1
        self._advance(compliance, dt)
        w = self._compliance_w
        limit = self.limit
        if w > 0.0:       # the cap fades from the stall limits to |g| + compliance_effort
            limit = np.minimum(limit, w * (np.abs(g) + cfg.compliance_effort)
                               + (1.0 - w) * limit)
        if output == "position":
            return self._pseudo_goal(goal, qa, j, r, jjt, jjt_inv, g, err, twist, limit,
                                     compliance, dt)
        tau0 = self._posture_torque(qa, 1.0)
        f = goal.stiffness * err - self._d * twist + goal.wrench
        f, wscale = scale_wrench(f, cfg.max_force, cfg.max_moment)
        # J^T F + N tau0 - d_j dq, N tau0 = tau0 - J^T (J J^T + l^2)^-1 J tau0
        delta = j.T @ (f - jjt_inv @ (j @ tau0)) + tau0 - cfg.joint_damping * dqa
        if w > 0.0:
            delta += (w * cfg.compliance_stiffness) * (self._compliance_posture - qa)
        tau, jscale = scale_into_limits(g, delta, limit)
        tau, limited = rate_limit(tau, self._tau_prev, cfg.torque_rate * dt)
        tau = np.minimum(np.maximum(tau, -limit), limit)
        self._tau_prev = tau
        return Command(tau=tau, gravity=g, q_cmd=qa.copy(), effort_limit=np.abs(tau),
                       wrench=f, error=err, wrench_scale=wscale, joint_scale=jscale,
                       rate_limited=limited, jacobian=j, rotation=r, jjt=jjt)

    def _posture_torque(self, qa: np.ndarray, scale: float) -> np.ndarray:
        """``scale`` x the null-space term's torque tau_0 (N·m x scale): see
        :func:`null_space_torque`."""
        cfg = self.config
        return scale * null_space_torque(qa, self.lower, self.upper, self._posture_ref,
                                         cfg.posture_stiffness, cfg.limit_margin,
                                         cfg.limit_stiffness)

    def _goal_gains(self, goal: HybridGoal) -> tuple:
        """Per axis, for the pseudo-goal, cached per goal: the tracking stiffness k
        (position axes at least ``position_stiffness``, force axes the goal's K), K - k,
        the update gain, the selection, whether any axis is force-controlled, diag(k)."""
        if self._gains_for is not goal:
            s = goal.force_axes
            k = np.where(s, np.maximum(goal.stiffness, 1e-3),
                         np.maximum(goal.stiffness, self._k_pos))
            gain = np.where(s, self.config.force_filter, self.config.position_filter)
            dk = np.where(s, 0.0, goal.stiffness - k)
            kk = np.where(s, goal.stiffness, k)
            self._gains_for = goal
            self._gains = (k, kk, dk, gain, s, bool(s.any()), np.diag(k))
        return self._gains

    def _pseudo_goal(self, goal, qa, j, r, jjt, jjt_inv, g, err, twist, limit,
                     compliance, dt) -> Command:
        """The 'position' output: pseudo-goal q_cmd and current limit (see docs/force.md).

        The servos exert tau_s = k_s (q_cmd - q) above gravity, i.e. the wrench
        F_s = (J J^T)^-1 J tau_s at the tool. Each cycle the pseudo-goal moves by
        J^+ gamma (K + K_arm)^-1 (F - F_s), K_arm = k_s (J J^T)^-1 the arm's own stiffness
        at the tool: in free space (F_s ~ 0) the tool approaches X0 at the rate
        gamma K/(K + K_arm), in contact the servo force approaches F at the rate
        gamma K_arm/(K + K_arm): stable for any K, and at rest F_s = F exactly (the
        paper's pseudo-goal, eqs. 6-8). Position axes use at least ``position_stiffness``
        (they track X0)."""
        cfg = self.config
        ks = cfg.servo_stiffness
        k, kk, dk, gain, s, any_force, diag_k = self._goal_gains(goal)
        # position axes: tracking, k err - D v (their force is bounded by the joints'
        # current limits, not by the wrench limit); force axes: the law's wrench
        # K err - D v + F_d, scaled into the wrench limit as a whole 6-D wrench
        dtw = self._d * twist
        f = kk * err - dtw
        wscale = jscale = 1.0
        if any_force:
            f_law, wscale = scale_wrench(f + dk * err + goal.wrench, cfg.max_force,
                                         cfg.max_moment)
            # the joints' torque limits: the force axes' wrench is scaled (its direction
            # kept) so that gravity, the position axes' wrench and it fit every joint's
            # limit at rest. Clipped per joint instead, a saturated joint bent the wrench
            # the others made: the press fell to 5-7 N of 30 and the tool slid sideways
            # on the axes meant to hold (issue 24, item 7)
            f_pos = np.where(s, 0.0, f)
            f_frc = np.where(s, f_law, 0.0)
            _, jscale = scale_into_limits(g + j.T @ f_pos, j.T @ f_frc, limit)
            f = f_pos + self._rate_limited_force(jscale * f_frc, s, j, jjt_inv, qa, dt)
        f_s = self._servo_wrench(j, jjt_inv, qa)
        dx = gain * np.linalg.solve(ks * jjt_inv + diag_k, f - f_s)
        # the pseudo-goal moves at max_speed / max_angular_speed at most (a force axis
        # with K = 0 and F_d would otherwise accelerate the tool in free space); the force
        # axes and the position axes each have that budget: a soft arm presses by sending
        # its pseudo-goal far along the force axis, and one shared cap then starved the
        # position axes' correction (issue 24: the tool slid 3 mm sideways while z pressed)
        lin, ang = cfg.max_speed * dt, cfg.max_angular_speed * dt
        if any_force:
            _cap_apart(dx, s, lin, ang)
        else:
            _cap_into(dx, 0, lin)
            _cap_into(dx, 3, ang)
        # J^+ dx + N v with v = (position_filter / k_s) tau_0: v + J^T M^-1 (dx - J v)
        v = self._posture_torque(qa, cfg.position_filter / ks)
        step = v + j.T @ (jjt_inv @ (dx - j @ v))
        if self._compliance_w > 0.0:
            step += (self._compliance_w * cfg.position_filter * cfg.compliance_stiffness
                     / ks) * (self._compliance_posture - self._q_cmd)
        # torque-rate limit: at a given q the servo torque changes by k_s * step
        max_step = cfg.torque_rate * dt / ks
        step = np.minimum(np.maximum(step, -max_step), max_step)
        q_cmd = self._q_cmd + step
        np.maximum(q_cmd, self.lower, out=q_cmd)
        np.minimum(q_cmd, self.upper, out=q_cmd)
        if cfg.servo_holds_gravity:
            q_out = q_cmd.copy()
        else:
            q_out = np.minimum(np.maximum(q_cmd + g / ks, self.lower), self.upper)
        # last, after every other term: no joint steps further than its velocity limit x dt
        # from the last command (from the measured position at the first), inside the limits
        q_out, step_limited = self._limit_step(q_out, qa, dt)
        if step_limited:             # the pseudo-goal follows what the servos were told
            q_cmd = q_out.copy() if cfg.servo_holds_gravity else q_out - g / ks
        self._q_cmd = q_cmd
        # the current limit covers gravity and the pressing torque without letting one
        # cancel the other: if a contact vanishes the joint still holds its own weight
        push = ks * (q_cmd - qa)
        effort = np.abs(g)
        effort += np.abs(push)
        effort += cfg.effort_headroom
        np.maximum(effort, 0.05, out=effort)
        np.minimum(effort, limit, out=effort)
        tau = g + push                                  # what the servos exert
        np.maximum(tau, -limit, out=tau)
        np.minimum(tau, limit, out=tau)
        self._tau_prev = tau
        return Command(tau=tau, gravity=g, q_cmd=q_out, effort_limit=effort, wrench=f,
                       error=err, wrench_scale=wscale, joint_scale=jscale, jacobian=j,
                       rotation=r, jjt=jjt, step_limited=step_limited)

    def _servo_wrench(self, j: np.ndarray, jjt_inv: np.ndarray, qa: np.ndarray) -> np.ndarray:
        """F_s (N, N·m): the wrench the servos' springs k_s (q_cmd - q) make at the tool."""
        return jjt_inv @ (j @ (self.config.servo_stiffness * (self._q_cmd - qa)))

    def _rate_limited_force(self, f_frc: np.ndarray, s: np.ndarray, j: np.ndarray,
                            jjt_inv: np.ndarray, qa: np.ndarray, dt: float) -> np.ndarray:
        """The force axes' wrench ``f_frc`` (0 on position axes), its change since the
        last cycle limited to ``force_rate`` x dt (N, linear part) and ``force_rate`` x
        max_moment / max_force x dt (N·m, angular part), each part's direction kept. An
        axis that was not force-controlled starts from the servos' present wrench on it.

        In contact the position axes' forces converge only through the arm's own stiffness
        (in about 1 s at the defaults): a press built or released faster left the servos
        pushing sideways against friction, and the tool slipped when the normal force
        fell (11-27 mm at 28 N -> 1.5 N, issue 24)."""
        cfg = self.config
        prev = self._f_prev
        if prev is None or self._f_prev_axes is not s:
            start = self._servo_wrench(j, jjt_inv, qa)
            prev = np.where(s, start if prev is None else np.where(self._f_prev_axes, prev,
                                                                  start), 0.0)
        d = f_frc - prev
        lin = cfg.force_rate * dt
        ang = lin * (cfg.max_moment / cfg.max_force if cfg.max_force > 0.0 else 1.0)
        _cap_into(d, 0, lin)
        _cap_into(d, 3, ang)
        out = prev + d
        self._f_prev, self._f_prev_axes = out, s
        return out

    def _limit_step(self, q_out: np.ndarray, qa: np.ndarray,
                    dt: float) -> tuple[np.ndarray, bool]:
        """``q_out`` (rad) through hyperarm_description.limits.limit_step from the last
        position command (the measured ``qa`` at the first after :meth:`reset`); and
        whether it changed anything."""
        prev = qa if self._q_out is None else self._q_out
        limited = limit_step(q_out, prev, self.v_max, dt, self.lower, self.upper)
        changed = bool(np.any(limited != q_out))
        self._q_out = limited
        return limited, changed

    def _advance(self, compliance: bool, dt: float) -> None:
        """Move the posture spring's reference towards ``posture`` by posture_speed x dt
        per joint, and the compliance weight towards 1 (on) or 0 (off) by
        dt / transition_time."""
        cfg = self.config
        d = self.posture - self._posture_ref
        if d.any():
            step = cfg.posture_speed * dt
            self._posture_ref += np.minimum(np.maximum(d, -step), step)
        target = 1.0 if compliance else 0.0
        if self._compliance_w != target:
            rate = dt / cfg.transition_time if cfg.transition_time > 0.0 else 1.0
            self._compliance_w = min(max(target, self._compliance_w - rate),
                                     self._compliance_w + rate)

    def _reference(self, goal: HybridGoal, p: np.ndarray, r: np.ndarray,
                   dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The pose the law pulls towards: it follows the goal's X0 at ``max_speed`` m/s and
        ``max_angular_speed`` rad/s at most (a goal step becomes a ramp), starting from the
        present pose at :meth:`reset`. Once it has reached a goal it stays there (the
        goal's own arrays, not copied) until the goal changes."""
        if self._ref_at is goal:
            return goal.position, goal.rotation
        if self._ref_p is None:
            self._ref_p, self._ref_r = p.copy(), r.copy()
        d = goal.position - self._ref_p
        n = math.sqrt(float(d @ d))
        step = self.config.max_speed * dt
        at_p = n <= step
        self._ref_p = goal.position.copy() if at_p else self._ref_p + d * (step / n)
        w = pin.log3(goal.rotation @ self._ref_r.T)
        a = math.sqrt(float(w @ w))
        step = self.config.max_angular_speed * dt
        at_r = a <= step
        self._ref_r = goal.rotation.copy() if at_r else pin.exp3(w * (step / a)) @ self._ref_r
        if at_p and at_r:
            self._ref_at = goal
        return self._ref_p, self._ref_r

    def near_limit(self, q, margin: float) -> list[str]:
        """Arm joints within ``margin`` rad of a limit at chain positions ``q``."""
        if self._guard is None or self._guard[0] != margin:
            self._guard = (margin, self.lower + margin, self.upper - margin)
        _, lo, hi = self._guard
        qa = np.asarray(q, dtype=float)[self.arm]
        near = (qa < lo) | (qa > hi)
        if not near.any():
            return []
        return [n for n, b in zip(self.arm_names, near) if b]


def _cap_apart(v: np.ndarray, mask: np.ndarray, lin: float, ang: float) -> None:
    """Scale, in place, the masked and the unmasked entries of ``v``'s linear part (0:3)
    each down to norm ``lin`` if longer, and those of its angular part (3:6) to ``ang``."""
    for part, bound in ((slice(0, 3), lin), (slice(3, 6), ang)):
        seg, m = v[part], mask[part]
        for sel in (m, ~m):
            n = math.sqrt(float(seg[sel] @ seg[sel]))
            if n > bound:
                seg[sel] *= bound / n


def _cap_into(v: np.ndarray, i: int, bound: float) -> None:
    """Scale ``v[i:i+3]`` in place down to norm ``bound`` if it is longer."""
    x, y, z = v[i], v[i + 1], v[i + 2]
    n = math.sqrt(x * x + y * y + z * z)
    if n > bound:
        v[i:i + 3] *= bound / n
