"""The last guard of every streaming controller (plain Python, no ROS).

Host compensation, hybrid force, the task runner and any trajectory follower send one joint
command per cycle. Whatever their goal, the host motion or a singularity computed, no command
may step a joint further in one cycle than its velocity limit times the period, nor leave its
position limits. :func:`limit_step` enforces both; a controller applies it LAST, after every
other term (profile leads, margins, null-space terms), to the exact vector it publishes.
"""
from __future__ import annotations

from typing import Optional

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["StepLimitError", "limit_step"]


class StepLimitError(ValueError):
    """The limiter's inputs are malformed (lengths, non-finite values, bad period/limits)."""


def _vector(x: ArrayLike, n: int, label: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape != (n,):
        raise StepLimitError(f"{label}: {a.size} values for {n} joints")
    return a


def limit_step(q_cmd: ArrayLike, q_prev: ArrayLike, v_max: ArrayLike, dt: float,
               lower: Optional[ArrayLike] = None,
               upper: Optional[ArrayLike] = None) -> np.ndarray:
    """Clip a joint command to one cycle's reach of the previous command, and to limits.

    Parameters (per joint, in the caller's order):
        q_cmd: the command the controller wants to send (rad, or m for a prismatic joint).
        q_prev: the command sent last cycle, or the measured position on the first cycle
            (rad or m).
        v_max: velocity limit (rad/s or m/s), > 0; a scalar applies to every joint.
        dt: the period of the controller (s), > 0 and finite.
        lower, upper: optional position limits (rad or m); the result is clipped into them
            after the step limit. Where ``q_prev`` lies outside them the result moves towards
            them by at most ``v_max * dt`` (it never jumps into range).

    Returns a new array ``q`` with ``|q - q_prev| <= v_max * dt`` for every joint (exactly,
    up to one rounding of the subtraction), and ``lower <= q <= upper`` wherever that is
    reachable within the step. The direction of each joint's motion is kept.

    Raises :class:`StepLimitError` on mismatched lengths, non-finite ``q_cmd``/``q_prev``,
    non-positive or non-finite ``v_max``/``dt``, or ``lower > upper``: a controller must
    drop such a command, never send it.
    """
    q_cmd_a = np.asarray(q_cmd, dtype=float)
    if q_cmd_a.ndim != 1:
        raise StepLimitError(f"q_cmd must be a vector, got shape {q_cmd_a.shape}")
    n = q_cmd_a.size
    q_prev_a = _vector(q_prev, n, "q_prev")
    v = _vector(v_max, n, "v_max")
    if not np.all(np.isfinite(q_cmd_a)):
        raise StepLimitError(f"non-finite q_cmd at index {np.flatnonzero(~np.isfinite(q_cmd_a)).tolist()}")
    if not np.all(np.isfinite(q_prev_a)):
        raise StepLimitError(f"non-finite q_prev at index {np.flatnonzero(~np.isfinite(q_prev_a)).tolist()}")
    if not np.all(np.isfinite(v)) or np.any(v <= 0.0):
        raise StepLimitError(f"v_max must be finite and > 0, got {v.tolist()}")
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0.0:
        raise StepLimitError(f"dt must be finite and > 0 s, got {dt}")
    step = v * dt
    lo_b = q_prev_a - step
    hi_b = q_prev_a + step
    if lower is not None or upper is not None:
        lo = _vector(lower, n, "lower") if lower is not None else np.full(n, -np.inf)
        hi = _vector(upper, n, "upper") if upper is not None else np.full(n, np.inf)
        if np.any(np.isnan(lo)) or np.any(np.isnan(hi)) or np.any(lo > hi):
            raise StepLimitError("position limits must satisfy lower <= upper")
        # Intersect the reachable band with the limits; where they do not overlap (q_prev
        # outside the limits by more than a step) stay at the band's edge nearest the limits.
        lo_b, hi_b = np.maximum(lo_b, np.minimum(lo, hi_b)), np.minimum(hi_b, np.maximum(hi, lo_b))
    return np.clip(q_cmd_a, lo_b, hi_b)
