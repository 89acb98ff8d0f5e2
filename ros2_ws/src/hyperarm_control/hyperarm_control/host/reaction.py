"""The wrench the arm exerts on its mount (base_link), from pinocchio's RNEA (no ROS).

RNEA on the fixed-arm model with the measured q, dq, ddq gives ``f[1]``, the spatial force
that the mount transmits into the first link (joint1's frame). The arm exerts its opposite
on the mount; it is returned at base_link's origin in base_link axes, [force N; moment N·m].

- Gravity is given in base_link axes (``gravity_base``, m/s^2: world -z seen from a tilted
  host). A linearly accelerating mount (the rail carriage, a UAV) enters as the fictitious
  acceleration: RNEA runs with gravity - base_acceleration (both base_link axes, m/s^2).
  The mount's angular velocity and acceleration are not included.
- An estimated contact wrench (``contact_wrench_base``: the wrench the TOOL APPLIES to the
  environment, [N; N·m] at tool0's origin in base_link axes, as on ``ee_wrench_base``)
  enters as the external force -w on the last link. RNEA propagates it to the base, the
  same as mapping it through the Jacobian transpose (tau = J^T w) and the chain's statics.
- At rest without contact the result is the weight of the links, m g, with moment
  c x m g (pinocchio's total mass and centre of mass of the links).
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from hyperarm_ik.kinematics import Kinematics
from .errors import HostConfigError, HostStateError

__all__ = ["ReactionModel", "AccelerationEstimator", "HostAccelerationEstimator", "LatestWrench",
           "STANDARD_GRAVITY"]

STANDARD_GRAVITY = np.array([0.0, 0.0, -9.81])   # m/s^2, world -z


def _vec(v, n: int, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise HostStateError(f"{what} must be {n} finite numbers, got {a.tolist()}")
    return a


class ReactionModel:
    """Mount reaction of the nine-joint arm (fixed-arm :class:`Kinematics`, own data)."""

    def __init__(self, kin: Kinematics) -> None:
        if kin.variant != "arm":
            raise HostConfigError("ReactionModel needs the fixed-arm kinematics (variant "
                                  f"'arm'), got {kin.variant!r}")
        if list(kin.model.parents)[1] != 0 or 0 in list(kin.model.parents)[2:]:
            raise HostConfigError("the arm must be one chain from base_link")
        self.kin = kin
        self.model = kin.model.copy()      # own gravity setting; kinematics stay shared
        self.data = self.model.createData()
        self.nq = self.model.nq
        self._last = self.model.njoints - 1
        self._tool = kin.tool_id

    def wrench(self, q, dq=None, ddq=None, gravity_base=STANDARD_GRAVITY,
               base_acceleration=None, contact_wrench_base=None) -> np.ndarray:
        """[force (3) N; moment (3) N·m] the arm exerts on the mount, at base_link's origin
        in base_link axes. q rad, dq rad/s, ddq rad/s^2 (None: zero); gravity and base
        acceleration m/s^2 in base_link axes; contact wrench as in the module doc."""
        n = self.nq
        q = _vec(q, n, "q")
        dq = np.zeros(n) if dq is None else _vec(dq, n, "dq")
        ddq = np.zeros(n) if ddq is None else _vec(ddq, n, "ddq")
        g = _vec(gravity_base, 3, "gravity")
        if base_acceleration is not None:
            g = g - _vec(base_acceleration, 3, "base acceleration")
        self.model.gravity = pin.Motion(g, np.zeros(3))
        fext = None
        if contact_wrench_base is not None:
            w = _vec(contact_wrench_base, 6, "contact wrench")
            pin.framesForwardKinematics(self.model, self.data, q)
            p_tool = self.data.oMf[self._tool].translation
            f_on_tool = -w[:3]
            m_origin = -w[3:] + np.cross(p_tool, f_on_tool)   # about base_link's origin
            f_base = pin.Force(f_on_tool, m_origin)
            fext = [pin.Force.Zero() for _ in range(self.model.njoints)]
            fext[self._last] = self.data.oMi[self._last].actInv(f_base)  # local frame
        if fext is None:
            pin.rnea(self.model, self.data, q, dq, ddq)
        else:
            pin.rnea(self.model, self.data, q, dq, ddq, fext)
        # mount -> link1 in base axes (joint1's parent is base_link: liMi[1] = oMi[1]; rnea
        # updates liMi, not oMi)
        into_arm = self.data.liMi[1].act(self.data.f[1])
        return -np.concatenate((into_arm.linear, into_arm.angular))

    def mass_and_com(self, q) -> tuple[float, np.ndarray]:
        """Total mass (kg) of the links and their centre of mass (m, base_link)."""
        q = _vec(q, self.nq, "q")
        pin.centerOfMass(self.model, self.data, q)   # com[0]: base_link axes (com[i]: local)
        return float(self.data.mass[0] - self.model.inertias[0].mass), self.data.com[0].copy()


class AccelerationEstimator:
    """Joint accelerations (rad/s^2) by finite difference of measured velocities at their
    times (s); None until two samples more than ``min_dt`` s apart have been seen."""

    def __init__(self, min_dt: float = 1e-4) -> None:
        self.min_dt = float(min_dt)
        self._prev: tuple[float, np.ndarray] | None = None

    def update(self, t: float, dq: np.ndarray) -> np.ndarray | None:
        prev, self._prev = self._prev, (t, np.array(dq, dtype=float))
        if prev is None or t - prev[0] <= self.min_dt:
            return None
        return (self._prev[1] - prev[1]) / (t - prev[0])


class LatestWrench:
    """The newest estimated contact wrench ([force N; moment N·m], 6 numbers, e.g. the
    force node's ``ee_wrench_base``) and its arrival time (s): :meth:`get` returns it while
    it is at most ``timeout`` s old, else None (``timeout`` 0: never)."""

    def __init__(self, timeout: float) -> None:
        if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) \
                or not 0.0 <= timeout < float("inf"):
            raise HostConfigError(f"contact wrench timeout must be >= 0 s, got {timeout!r}")
        self.timeout = float(timeout)
        self._wrench: np.ndarray | None = None
        self._time = 0.0

    def update(self, now: float, wrench) -> None:
        """Take ``wrench`` arrived at ``now``; raises :class:`HostStateError` for one that
        is not 6 finite numbers (the last good one stays)."""
        self._wrench, self._time = _vec(wrench, 6, "contact wrench"), float(now)

    def get(self, now: float) -> np.ndarray | None:
        if self._wrench is None or self.timeout == 0.0 or now - self._time > self.timeout:
            return None
        return self._wrench


class HostAccelerationEstimator:
    """The host's linear acceleration (m/s², the velocities' axes) from its velocities at
    their stamps (s): the newest velocity minus the newest one at least ``baseline`` s
    older, over their stamps' difference. A velocity that is itself a difference over a
    short baseline is so not differenced again over one stamp (no spikes, noise divided by
    the baseline once more). None until such a pair exists; a repeated or older stamp
    returns the last estimate; :meth:`reset` after a gap or an untrusted velocity."""

    def __init__(self, baseline: float = 0.05) -> None:
        if isinstance(baseline, bool) or not isinstance(baseline, (int, float)) \
                or not 1e-3 <= baseline <= 1.0:
            raise HostConfigError(f"host acceleration baseline must be in 0.001..1 s, got "
                                  f"{baseline!r}")
        self.baseline = float(baseline)
        self._history: list[tuple[float, np.ndarray]] = []
        self._last: np.ndarray | None = None

    def reset(self) -> None:
        self._history.clear()
        self._last = None

    def update(self, stamp: float, velocity) -> np.ndarray | None:
        h = self._history
        if h and stamp <= h[-1][0]:
            return self._last
        h.append((float(stamp), _vec(velocity, 3, "host velocity")))
        while len(h) > 2 and h[1][0] <= stamp - self.baseline:
            h.pop(0)
        t0, v0 = h[0]
        if t0 <= stamp - self.baseline:
            self._last = (h[-1][1] - v0) / (stamp - t0)
        return self._last
