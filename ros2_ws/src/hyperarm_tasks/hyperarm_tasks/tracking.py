"""Path-tracking figures (no ROS): how closely a measured tool path came to waypoints.

Danko & Oh's criterion (Table II): a waypoint is *reached* when the tool came within 1 mm
of it. Here the tool path is the measured one (FK of measured joint states), taken as the
polyline through its samples, and each waypoint's error is its closest approach to that
polyline (distance to the nearest segment, not just the nearest sample), searched in the
part of the path measured while that waypoint was the target. Units: m, rad, s.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["closest_approach", "TrackingReport", "tracking_report", "arc_length",
           "trapezoid_time_scaling", "PathClock"]

_CHUNK = 256   # waypoints per vectorised block (bounds the memory to ~chunk x samples x 3)


def closest_approach(waypoints: np.ndarray, path: np.ndarray,
                     windows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Distance (m) of each of the (n, 3) ``waypoints`` to the polyline through the (m, 3)
    ``path`` samples, and the fractional sample index where it is closest (k + t: on the
    segment k -> k+1 at fraction t). A single sample is a point.

    ``windows`` (n, 2), optional: sample indices [lo, hi] per waypoint; only the segments
    between them count (the path while that waypoint was the target, so that a path
    crossing itself, like a figure-8, is not credited with its other pass)."""
    w = np.asarray(waypoints, dtype=float).reshape(-1, 3)
    p = np.asarray(path, dtype=float).reshape(-1, 3)
    if len(p) == 0:
        raise ValueError("no path samples")
    if len(p) == 1:
        return np.linalg.norm(w - p[0], axis=1), np.zeros(len(w))
    if windows is not None:
        windows = np.asarray(windows, dtype=int).reshape(len(w), 2)
        if np.any(windows[:, 0] > windows[:, 1]) or windows.min() < 0:
            raise ValueError("each window must be 0 <= lo <= hi")
    a, d = p[:-1], np.diff(p, axis=0)                 # segments a + t d, t in [0, 1]
    dd = np.einsum("ij,ij->i", d, d)
    dd_safe = np.where(dd > 0.0, dd, 1.0)
    seg = np.arange(len(a))
    dist = np.empty(len(w))
    where = np.empty(len(w))
    for lo in range(0, len(w), _CHUNK):
        rel = w[lo:lo + _CHUNK, None, :] - a[None, :, :]          # (c, m-1, 3)
        t = np.clip(np.einsum("cmj,mj->cm", rel, d) / dd_safe, 0.0, 1.0)
        t = np.where(dd > 0.0, t, 0.0)
        off = rel - t[..., None] * d[None, :, :]
        sq = np.einsum("cmj,cmj->cm", off, off)
        if windows is not None:
            win = windows[lo:lo + _CHUNK]
            # segment k joins samples k and k+1: inside when both are in [lo, hi]
            # (a window of one sample keeps the segment that starts there)
            first = np.minimum(win[:, :1], len(a) - 1)
            last = np.maximum(np.minimum(win[:, 1:] - 1, len(a) - 1), first)
            sq = np.where((seg >= first) & (seg <= last), sq, np.inf)
        k = np.argmin(sq, axis=1)
        rows = np.arange(len(k))
        dist[lo:lo + _CHUNK] = np.sqrt(sq[rows, k])
        where[lo:lo + _CHUNK] = k + t[rows, k]
    return dist, where


@dataclass(frozen=True)
class TrackingReport:
    """Figures of one tracked path. Errors in m, joint steps in rad."""

    waypoints: int
    reached: int                  # waypoints whose closest approach <= threshold
    threshold: float              # m
    error_mean: float
    error_rms: float
    error_median: float
    error_p95: float
    error_max: float
    worst_waypoint: int           # index of error_max
    max_joint_step: float         # rad, largest |dq| of any joint between consecutive waypoints (planned)
    max_joint_step_measured: float  # rad, the same on the measured joints at each closest approach

    @property
    def reached_fraction(self) -> float:
        return self.reached / self.waypoints if self.waypoints else 0.0

    def metrics(self, prefix: str = "track_") -> dict[str, float]:
        """Flat float figures (a task result's ``metrics``)."""
        return {f"{prefix}{k}": float(v) for k, v in (
            ("waypoints", self.waypoints), ("reached", self.reached),
            ("reached_fraction", self.reached_fraction), ("threshold", self.threshold),
            ("error_mean", self.error_mean), ("error_rms", self.error_rms),
            ("error_median", self.error_median), ("error_p95", self.error_p95),
            ("error_max", self.error_max), ("worst_waypoint", self.worst_waypoint),
            ("max_joint_step", self.max_joint_step),
            ("max_joint_step_measured", self.max_joint_step_measured))}

    def summary(self) -> str:
        mm = 1000.0
        return (f"{self.reached}/{self.waypoints} waypoints ({100.0 * self.reached_fraction:.1f} %) "
                f"within {self.threshold * mm:g} mm of the measured path; path error mean "
                f"{self.error_mean * mm:.3f} mm, rms {self.error_rms * mm:.3f}, p95 "
                f"{self.error_p95 * mm:.3f}, max {self.error_max * mm:.3f} mm (waypoint "
                f"{self.worst_waypoint}); largest joint step between waypoints "
                f"{self.max_joint_step:.4f} rad planned, {self.max_joint_step_measured:.4f} "
                f"rad measured")


def tracking_report(waypoints: np.ndarray, planned_q: np.ndarray, measured_xyz: np.ndarray,
                    measured_q: np.ndarray, threshold: float = 1e-3,
                    windows: np.ndarray | None = None) -> TrackingReport:
    """Figures of a tracked path: ``waypoints`` (n, 3) m, their planned joints (n, nq),
    the measured tool positions (m, 3) (FK of the measured joints ``measured_q`` (m, nq),
    in time order), ``windows`` as for :func:`closest_approach`."""
    w = np.asarray(waypoints, dtype=float).reshape(-1, 3)
    qp = np.asarray(planned_q, dtype=float)
    qm = np.asarray(measured_q, dtype=float)
    if len(qp) != len(w) or len(qm) != len(measured_xyz):
        raise ValueError("planned_q must match waypoints and measured_q measured_xyz")
    if not threshold > 0.0:
        raise ValueError(f"threshold must be > 0 m, got {threshold!r}")
    err, where = closest_approach(w, measured_xyz, windows)
    # measured joints at each waypoint's closest approach (interpolated on its segment)
    k = np.minimum(where.astype(int), len(qm) - 1)
    t = (where - k)[:, None]
    q_at = qm[k] + t * (qm[np.minimum(k + 1, len(qm) - 1)] - qm[k])
    step = float(np.abs(np.diff(qp, axis=0)).max()) if len(qp) > 1 else 0.0
    step_m = float(np.abs(np.diff(q_at, axis=0)).max()) if len(q_at) > 1 else 0.0
    worst = int(np.argmax(err))
    return TrackingReport(
        waypoints=len(w), reached=int(np.count_nonzero(err <= threshold)),
        threshold=float(threshold), error_mean=float(err.mean()),
        error_rms=float(np.sqrt(np.mean(err * err))), error_median=float(np.median(err)),
        error_p95=float(np.percentile(err, 95)), error_max=float(err[worst]),
        worst_waypoint=worst, max_joint_step=step, max_joint_step_measured=step_m)


def arc_length(points: np.ndarray) -> np.ndarray:
    """Cumulative length (m) along the polyline through ``points``: (n,), starting at 0."""
    p = np.asarray(points, dtype=float)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def trapezoid_time_scaling(length: float, speed: float, acceleration: float):
    """Distance along a path of ``length`` (m) at time t (s): from rest to ``speed`` (m/s)
    at ``acceleration`` (m/s^2), cruise, back to rest (a triangle when too short).
    Returns (s(t) callable, total duration s)."""
    if not (speed > 0.0 and acceleration > 0.0 and length >= 0.0):
        raise ValueError("speed and acceleration must be > 0, length >= 0")
    t_a = speed / acceleration
    if acceleration * t_a * t_a > length:          # triangle: never reaches ``speed``
        t_a = float(np.sqrt(length / acceleration))
        v = acceleration * t_a
        total = 2.0 * t_a
    else:
        v = speed
        total = 2.0 * t_a + (length - acceleration * t_a * t_a) / speed

    def s_of(t: float) -> float:
        if t <= 0.0:
            return 0.0
        if t >= total:
            return length
        if t < t_a:
            return 0.5 * acceleration * t * t
        if t > total - t_a:
            r = total - t
            return length - 0.5 * acceleration * r * r
        return 0.5 * acceleration * t_a * t_a + v * (t - t_a)

    return s_of, total


class PathClock:
    """The time along a streamed path (s), from the wall clock of its ticks, such that a
    stall never makes the path jump:

    - a tick advances it by the wall time since the last tick, at most ``late_ticks``
      periods (a late tick of a loaded node slows the path down instead);
    - while the joint states are older than ``stale`` s (the driver lags or stalls) it does
      not advance, and it is taken back, once per stall, to where it was when the driver sent
      its last joint states: the driver applied no later goal as far as anyone knows, so the
      path resumes from there (without the rewind, from ``stale`` s of path further on);
    - it never passes ``duration``.
    """

    def __init__(self, now: float, duration: float, period: float, stale: float,
                 late_ticks: float = 1.5) -> None:
        self.t = 0.0
        self.duration = float(duration)
        self._max_step = late_ticks * period
        self._stale = float(stale)
        self._last = float(now)
        self._history: deque[tuple[float, float]] = deque(maxlen=256)
        self._rewound = False
        self.stalled_for = 0.0    # s the joint states have been stale at the last tick

    def tick(self, now: float, states_age: float) -> float:
        """The path time at wall time ``now`` (s), the joint states ``states_age`` s old."""
        self.stalled_for = 0.0 if states_age <= self._stale else states_age
        if states_age <= self._stale:
            self.t = min(self.t + min(max(now - self._last, 0.0), self._max_step),
                         self.duration)
            self._rewound = False
        elif not self._rewound:
            self._rewound = True
            back = [pt for wall, pt in self._history if wall <= now - states_age]
            self.t = min(self.t, back[-1] if back else 0.0)
        self._last = now
        self._history.append((now, self.t))
        return self.t
