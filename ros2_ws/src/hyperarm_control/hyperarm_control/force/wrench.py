"""Sensorless wrench estimate at tool0 from the joint efforts (no ROS).

    F = (J^T)^+ (tau_measured - tau_gravity - tau_bias),   (J^T)^+ = (J J^T + l^2 I)^-1 J

on the arm joints (the rail is position-controlled and left out), damped near singularities
(``l`` = ``singular_damping``), low-pass filtered (first order, ``filter`` per cycle), with a
covariance propagated from the effort noise and the friction left after calibration. F is the wrench the arm applies to its
environment at tool0's origin (the F_int of eq. 6): pressing down gives F_z < 0 in the
root frame. ``tare`` takes the present residual as the bias (a known wrench, e.g. zero,
being applied). Torques can first be corrected by a :class:`~.calibration.TorqueCalibration`.
Units: N, N·m, root axes unless stated.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import ForceConfigError

__all__ = ["EstimatorConfig", "WrenchEstimate", "WrenchEstimator", "to_tool"]


@dataclass(frozen=True)
class EstimatorConfig:
    """filter: 0..1 per cycle (1 = no filtering); effort_noise: std of one joint's
    measured effort (N·m, white: the filter reduces it); friction_noise: std of the
    friction left in one joint's effort after the calibration's compensation (N·m: a
    creeping or stuck joint's Coulomb friction is a slowly changing bias, which the filter
    does not reduce; it makes the estimate's error mostly tangential in a press);
    singular_damping: l (m)."""

    filter: float = 0.2
    effort_noise: float = 0.02
    friction_noise: float = 0.02
    singular_damping: float = 0.005

    def __post_init__(self) -> None:
        for name, lo, hi in (("filter", 1e-4, 1.0), ("effort_noise", 0.0, 10.0),
                             ("friction_noise", 0.0, 10.0),
                             ("singular_damping", 1e-6, 1.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or not lo <= v <= hi:
                raise ForceConfigError(f"estimator {name}: {v!r} not within {lo:g}..{hi:g}")


@dataclass(frozen=True)
class WrenchEstimate:
    """Filtered wrench (6,), root axes; ``raw`` is unfiltered. ``covariance`` (6, 6) is
    computed when asked for: (J^T)^+ sigma^2 ((J^T)^+)^T, sigma^2 the effort noise's
    variance times the filter's variance gain plus the friction's (not filtered)."""

    wrench: np.ndarray
    raw: np.ndarray
    pinv_t: np.ndarray              # (J^T)^+, 6 x n
    sigma2: float                   # N·m², per joint (noise x filter gain + friction)

    @property
    def covariance(self) -> np.ndarray:
        return self.sigma2 * (self.pinv_t @ self.pinv_t.T)


def to_tool(wrench: np.ndarray, rotation: np.ndarray,
            covariance: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """A wrench about tool0's origin from root axes to tool0 axes (R^T per 3-block)."""
    # rows of (2 x 3) @ R are (R^T f)^T and (R^T m)^T: both blocks in one product
    out = (wrench.reshape(2, 3) @ rotation).reshape(6)
    if covariance is None:
        return out, None
    rt = rotation.T
    big = np.zeros((6, 6))
    big[:3, :3] = big[3:, 3:] = rt
    return out, big @ covariance @ big.T


class WrenchEstimator:
    """Per-cycle estimate; :meth:`reset` clears the filter, :meth:`tare` sets the bias."""

    def __init__(self, n: int, config: EstimatorConfig | None = None) -> None:
        if n < 1:
            raise ForceConfigError(f"estimator: need at least one joint, got {n}")
        self.n = n
        self.config = config if config is not None else EstimatorConfig()
        self.bias = np.zeros(n)
        self._f: np.ndarray | None = None
        self._last_residual = np.zeros(n)
        self._started = False
        a = self.config.filter
        # variance of a first-order filter's output over its input's (white noise)
        self._var_gain = a / (2.0 - a)
        self._sigma2 = (self.config.effort_noise ** 2 * self._var_gain
                        + self.config.friction_noise ** 2)
        self._damp6 = self.config.singular_damping ** 2 * np.eye(6)

    def reset(self) -> None:
        self._f = None
        self._started = False

    def residual(self, tau_measured: np.ndarray, tau_gravity: np.ndarray) -> np.ndarray:
        return np.asarray(tau_measured, dtype=float) - tau_gravity - self.bias

    def update(self, j: np.ndarray, tau_measured: np.ndarray, tau_gravity: np.ndarray,
               jjt: np.ndarray | None = None) -> WrenchEstimate:
        """One cycle with the arm Jacobian ``j`` (6 x n, LWA) and efforts (n,) in N·m;
        ``jjt``: J J^T if known already (the law's)."""
        res = np.asarray(tau_measured, dtype=float) - tau_gravity
        a = self.config.filter
        # the residual low-passed like the estimate: what tare takes as the bias
        if self._started:
            self._last_residual += a * (res - self._last_residual)
        else:
            self._last_residual = res.copy()
            self._started = True
        m = (j @ j.T if jjt is None else jjt) + self._damp6
        p = np.linalg.solve(m, j)                                 # (J^T)^+, 6 x n
        raw = p @ (res - self.bias)
        if self._f is None:
            self._f = raw.copy()
        else:
            self._f += a * (raw - self._f)
        return WrenchEstimate(wrench=self._f.copy(), raw=raw, pinv_t=p, sigma2=self._sigma2)

    def tare(self, j: np.ndarray | None = None, known: np.ndarray | None = None) -> np.ndarray:
        """Take the (low-passed) residual as the bias, so that the estimate reads ``known``
        (default zero; needs ``j`` otherwise) from now on. Returns the bias (N·m)."""
        bias = self._last_residual.copy()
        if known is not None:
            if j is None:
                raise ForceConfigError("tare with a known wrench needs the Jacobian")
            bias = bias - j.T @ np.asarray(known, dtype=float)
        self.bias = bias
        self._f = None
        return bias.copy()
