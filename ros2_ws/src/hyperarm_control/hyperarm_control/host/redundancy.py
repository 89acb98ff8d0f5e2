"""Use the arm's redundancy to lower the moment it exerts on its mount (no ROS).

The nine-joint arm has three joints more than a 6-D tool pose needs. :class:`ReactionMinimizer`
solves the tool pose (primary task, damped least squares) and, in the task's null space,
descends a secondary objective: the component of the arm's centre of mass off the gravity
line through the mount, ``h(q) = 1/2 |P c(q)|^2`` with ``P = I - u u^T`` (``u`` the unit
gravity direction in base_link axes, ``c`` the links' centre of mass, pinocchio). The static
moment the links' weight exerts on the mount is ``m c x g``, whose norm is ``m |g| |P c|``:
minimising ``h`` keeps the centre of mass over the mount, which is the same as minimising the
gravity part of the base moment (the dynamic part is small at task speeds; it is not in ``h``).

- :meth:`ReactionMinimizer.solve`: one pose, warm-started, a fixed number of null-space
  steps (each at most ``max_null_step`` rad) while the pose is met;
- :meth:`ReactionMinimizer.plan`: a path of poses, each seeded with the previous solution
  (the posture keeps improving along the path, never jumping);
- :meth:`ReactionMinimizer.reconfigure`: at one pose, the joint path of small null-space
  steps from the present posture to the minimising one (the tool stays where it is), to
  stream before a path starts.

Joints stay ``limit_margin`` inside their limits and are pushed away from them within
``limit_band`` (a joint at a limit would block the null-space motion). Units: m, rad, N·m.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import pinocchio as pin

from hyperarm_ik.kinematics import Kinematics
from .errors import HostConfigError, HostGoalError, HostStateError
from .reaction import STANDARD_GRAVITY

__all__ = ["RedundancyConfig", "ReactionMinimizer", "OBJECTIVES"]

#: the secondary objectives (``none`` = plain IK, for comparisons)
OBJECTIVES = ("none", "min_reaction")


@dataclass(frozen=True)
class RedundancyConfig:
    """Settings of :class:`ReactionMinimizer` (validated on construction).

    gain: 1/m^2, null-space step = -gain x gradient of h (rad per step, before the cap).
    max_null_step: rad, largest null-space step per iteration (the posture changes slowly).
    null_steps: null-space steps per pose in :meth:`~ReactionMinimizer.solve`.
    max_iterations: task iterations per pose before it is reported unreachable.
    position_tolerance / orientation_tolerance: m / rad, the pose counts as met within them.
    orientation_scale: m/rad, weight of orientation errors against position errors.
    damping: lambda of the damped least squares (m^2).
    limit_margin / limit_band: rad kept from every limit / within which joints are pushed away.
    """

    gain: float = 50.0
    max_null_step: float = 0.01
    null_steps: int = 1
    max_iterations: int = 50
    position_tolerance: float = 1e-4
    orientation_tolerance: float = 1e-3
    orientation_scale: float = 0.2
    damping: float = 1e-6
    limit_margin: float = 0.02
    limit_band: float = 0.15

    def __post_init__(self) -> None:
        for name in ("null_steps", "max_iterations"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 1000:
                raise HostConfigError(f"{name} must be an integer in 0..1000, got {v!r}")
        for name, lo, hi in (("gain", 0.0, 1e4), ("max_null_step", 1e-6, 0.5),
                             ("position_tolerance", 1e-7, 0.1),
                             ("orientation_tolerance", 1e-6, 1.0),
                             ("orientation_scale", 1e-3, 10.0), ("damping", 0.0, 1.0),
                             ("limit_margin", 0.0, 0.5), ("limit_band", 0.0, 1.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or not lo <= v <= hi:
                raise HostConfigError(f"{name} must be a number in {lo:g}..{hi:g}, got {v!r}")


class ReactionMinimizer:
    """Tool-pose IK of the fixed arm with the centre of mass kept over the mount in the null
    space. ``kin``: the fixed-arm :class:`Kinematics`; ``gravity``: m/s^2 in base_link axes."""

    def __init__(self, kin: Kinematics, config: RedundancyConfig | None = None,
                 gravity=STANDARD_GRAVITY) -> None:
        if kin.variant != "arm":
            raise HostConfigError("ReactionMinimizer needs the fixed-arm kinematics (variant "
                                  f"'arm'), got {kin.variant!r}")
        self.kin = kin
        self.config = config if config is not None else RedundancyConfig()
        c = self.config
        g = np.asarray(gravity, dtype=float).reshape(-1)
        if g.shape != (3,) or not np.all(np.isfinite(g)) or np.linalg.norm(g) < 1e-6:
            raise HostConfigError(f"gravity must be 3 finite numbers, not zero, got {g.tolist()}")
        self.gravity = g
        u = g / np.linalg.norm(g)
        self._proj = np.eye(3) - np.outer(u, u)
        self._model = kin.model
        self._data = kin.model.createData()     # own data: the kinematics' stays untouched
        self.mass = float(sum(i.mass for i in kin.model.inertias[1:]))
        self.lower = kin.lower + c.limit_margin
        self.upper = kin.upper - c.limit_margin
        if np.any(self.lower >= self.upper):
            raise HostConfigError(f"limit_margin {c.limit_margin} rad leaves no joint range")
        self._s2 = np.array([1.0, 1.0, 1.0] + [c.orientation_scale ** 2] * 3)
        self._winv = np.diag(1.0 / self._s2)

    # -- the objective --------------------------------------------------------------------
    def static_moment(self, q) -> float:
        """N·m, the norm of the moment the links' weight exerts on the mount at q."""
        q = self._q(q)
        com = pin.centerOfMass(self._model, self._data, q)
        return self.mass * float(np.linalg.norm(self.gravity)) * float(
            np.linalg.norm(self._proj @ com))

    def _gradient(self, q: np.ndarray) -> np.ndarray:
        """Gradient of h = 1/2 |P c|^2 (m^2/rad) plus the push away from the limits."""
        jc = pin.jacobianCenterOfMass(self._model, self._data, q)   # also sets data.com[0]
        pc = self._proj @ self._data.com[0]
        grad = (self._proj @ jc).T @ pc
        band = self.config.limit_band
        if band > 0.0:   # quadratic wall inside the band: gradient of 1/2 (band - d)^2 * w
            w = 4.0 * float(np.abs(grad).max() + 1e-3) / band
            lo, hi = q - self.lower, self.upper - q
            grad = grad - w * np.clip(band - lo, 0.0, None) + w * np.clip(band - hi, 0.0, None)
        return grad

    # -- solving --------------------------------------------------------------------------
    def solve(self, pose, seed, null_steps: int | None = None) -> np.ndarray:
        """Arm joints (rad) that put tool0 at ``pose`` (4x4, base_link), from ``seed``, with
        ``null_steps`` (default: the config's) null-space steps lowering the objective.
        Raises :class:`HostGoalError` when the pose is not met within the tolerances."""
        target = self._pose(pose)
        q = np.clip(self._q(seed), self.lower, self.upper)
        c = self.config
        steps = c.null_steps if null_steps is None else int(null_steps)
        done_null = 0
        for _ in range(c.max_iterations + steps):
            e = self._error(q, target)
            met = self._met(e)
            if met and done_null >= steps:
                return q
            z = None
            if met or done_null < steps:
                z = self._null_step(q)
                done_null += 1
            q = self._iterate(q, target, z)
        e = self._error(q, target)
        if self._met(e) and done_null >= steps:
            return q
        raise HostGoalError(f"pose not met after {c.max_iterations} iterations: misses by "
                            f"{np.linalg.norm(e[:3]) * 1e3:.2f} mm, "
                            f"{math.degrees(float(np.linalg.norm(e[3:]))):.3f} deg")

    def plan(self, poses, seed, on_waypoint: Callable[[int], object] | None = None
             ) -> np.ndarray:
        """(n, 9) joints for the (n, 4, 4) poses, each seeded with the previous solution
        (``on_waypoint(k)`` is called before pose k: progress, cancel checks). Raises
        :class:`HostGoalError` naming the first pose that is not met."""
        out = []
        q = self._q(seed)
        for k, pose in enumerate(poses):
            if on_waypoint is not None:
                on_waypoint(k)
            try:
                q = self.solve(pose, q)
            except HostGoalError as exc:
                raise HostGoalError(f"waypoint {k + 1}/{len(poses)}: {exc}") from None
            out.append(q)
        return np.array(out)

    def reconfigure(self, pose, q_start, starts: int = 16, max_steps: int = 2000,
                    tolerance: float = 1e-4) -> np.ndarray:
        """(m, 9) joint path at the fixed tool ``pose`` from ``q_start`` (included) to a
        posture that minimises the static moment; consecutive rows differ by a few
        ``max_null_step`` at most (streamed over time, no jump) and every row but the first
        meets the pose.

        The objective has several local minima over the arm's self-motion (e.g. a posture
        in one vertical plane is a minimum among planar postures, far above the best
        non-planar ones), so besides the descent from ``q_start`` it tries ``starts``
        postures from fixed pseudo-random seeds (deterministic) and keeps the lowest
        (coarse descents of 5 x ``max_null_step``, the final one of 2 x). To
        get there it walks in joint space from the present posture to that one, re-solving
        the pose at every small step (the tool stays put); if that walk breaks (a pose not
        met, a jump), the local descent is used. The path then descends (null-space steps)
        until the moment improves by less than ``tolerance`` (fraction) over 20 steps."""
        q0 = self.solve(pose, q_start, null_steps=0)
        path = [self._q(q_start), q0]
        far = self._best_start(pose, starts)
        if far is not None and self._descend(pose, q0, 150, scale=5.0)[-1][1] > 1.02 * far[1]:
            walk = self._walk(pose, q0, far[0])
            if walk is not None:
                path += walk
        for q, _m in self._descend(pose, path[-1], max_steps, tolerance, scale=2.0):
            path.append(q)
        return np.array(path)

    def _descend(self, pose, q, steps: int, tolerance: float = 0.0, scale: float = 1.0):
        """[(q, static moment)] of up to ``steps`` null-space steps (``scale`` x the cap)
        from ``q``; stops early when the moment improves by less than ``tolerance`` over 20
        steps (0: never)."""
        out = []
        target = self._pose(pose)
        for _ in range(steps):
            q = self.solve(target, self._iterate(q, target, scale * self._null_step(q)),
                           null_steps=0)
            out.append((q, self.static_moment(q)))
            if tolerance > 0.0 and len(out) > 20 \
                    and out[-21][1] - out[-1][1] < tolerance * out[-21][1]:
                break
        return out

    def _best_start(self, pose, starts: int):
        """(q, moment) of the lowest of ``starts`` descents from seeded postures, or None."""
        rng = np.random.default_rng(15)
        best = None
        for _ in range(starts):
            seed = rng.uniform(0.8 * self.lower, 0.8 * self.upper)
            try:
                q = self.solve(pose, seed, null_steps=0)
            except HostGoalError:
                continue
            q, m = self._descend(pose, q, 150, scale=5.0)[-1]    # coarse, fast
            if best is None or m < best[1]:
                best = (q, m)
        return best

    def _walk(self, pose, qa: np.ndarray, qb: np.ndarray) -> list[np.ndarray] | None:
        """Joint-space walk qa -> qb with the pose re-solved at every step (max_null_step
        apart), or None if a step does not meet the pose or jumps."""
        cap = self.config.max_null_step
        n = max(1, int(math.ceil(2.0 * float(np.abs(qb - qa).max()) / cap)))
        out, prev = [], qa
        for k in range(1, n + 1):
            s = k / n
            try:
                q = self.solve(pose, (1.0 - s) * qa + s * qb, null_steps=0)
            except HostGoalError:
                return None
            if float(np.abs(q - prev).max()) > 5.0 * cap:
                return None
            out.append(q)
            prev = q
        return out

    # -- internals ------------------------------------------------------------------------
    def _null_step(self, q: np.ndarray) -> np.ndarray:
        z = -self.config.gain * self._gradient(q)
        n = float(np.abs(z).max())
        if n > self.config.max_null_step:
            z *= self.config.max_null_step / n
        return z

    def _iterate(self, q: np.ndarray, target: np.ndarray, z: np.ndarray | None) -> np.ndarray:
        """One damped least-squares step on the task, with ``z`` projected into its null
        space; joints that would pass a limit leave the step (once)."""
        e = self._error(q, target)
        j = self._jac
        lam = self.config.damping + float(e @ (self._s2 * e))
        dq = self._dls(j, e, lam, z)
        out = ((q + dq < self.lower) & (dq < 0)) | ((q + dq > self.upper) & (dq > 0))
        if out.any():
            j = j.copy()
            j[:, out] = 0.0
            dq = self._dls(j, e, lam, None if z is None else np.where(out, 0.0, z))
        return np.clip(q + dq, self.lower, self.upper)

    def _dls(self, j, e, lam, z):
        a = j @ j.T + lam * self._winv
        if z is None:
            return j.T @ np.linalg.solve(a, e)
        return z + j.T @ np.linalg.solve(a, e - j @ z)

    def _error(self, q: np.ndarray, target: np.ndarray) -> np.ndarray:
        p, r, j = self.kin.pose_jacobian_view(q)
        self._jac = j
        return np.concatenate((target[:3, 3] - p, pin.log3(target[:3, :3] @ r.T)))

    def _met(self, e: np.ndarray) -> bool:
        c = self.config
        return (float(np.linalg.norm(e[:3])) <= c.position_tolerance
                and float(np.linalg.norm(e[3:])) <= c.orientation_tolerance)

    def _q(self, q) -> np.ndarray:
        a = np.asarray(q, dtype=float).reshape(-1)
        if a.shape != (self.kin.nq,) or not np.all(np.isfinite(a)):
            raise HostStateError(f"q must be {self.kin.nq} finite numbers, got {a.tolist()}")
        return a

    @staticmethod
    def _pose(pose) -> np.ndarray:
        from .compensation import check_pose
        return check_pose(pose, "tool pose", HostGoalError)
