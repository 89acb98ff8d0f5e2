"""What every IK solver shares: the request checks, the result, the honest success test.

Units: m, rad (rail m), s. A target is a position (3,) and a rotation matrix (3, 3) of tool0
in the model's root frame. ``success`` is always computed from the returned joints by forward
kinematics: position error <= position_tolerance, orientation error <= orientation_tolerance
(unless position_only) and every joint within its limits.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ..errors import (InvalidOptionError, InvalidSeedError, InvalidTargetError,
                      UnsupportedVariantError)
from ..kinematics import Kinematics, rotation_angle

__all__ = ["IKResult", "Solver", "task_error", "DEFAULT_POSITION_TOLERANCE",
           "DEFAULT_ORIENTATION_TOLERANCE", "DEFAULT_TIMEOUT", "OUT_OF_REACH",
           "ORIENTATION_OUT_OF_REACH", "COLLISION_MODES"]

DEFAULT_POSITION_TOLERANCE = 1e-4   # m
DEFAULT_ORIENTATION_TOLERANCE = 1e-3  # rad
DEFAULT_TIMEOUT = 0.1               # s
OUT_OF_REACH = "out of reach"       # note prefix of a proven-unreachable position
ORIENTATION_OUT_OF_REACH = "orientation out of reach"  # ... of a proven-unreachable pose
_EYE3 = np.eye(3)
COLLISION_MODES = ("ignore", "check", "avoid")


@dataclass
class IKResult:
    """Outcome of one solve. ``q`` is the best configuration found (also on failure)."""

    q: np.ndarray
    success: bool
    position_error: float        # m, |p_target - p(q)|
    orientation_error: float     # rad, angle between R_target and R(q)
    iterations: int
    solve_time: float            # s
    message: str
    violations: list[str] = field(default_factory=list)  # joints outside their limits
    reachable: bool | None = None  # False: proven out of reach; None: unknown
    contacts: list[str] = field(default_factory=list)  # "link4 with table" (if checked)


#: what a solve's timeout counts (:meth:`Solver.solve`'s ``clock``): the ``time`` function
CLOCKS = {"wall": "perf_counter", "cpu": "thread_time"}


class Solver:
    """Base class: validates requests, times the solve and builds honest results.

    Subclasses implement ``_solve(p, R, q0, ...) -> (q, iterations, note)``.

    Collisions: after :meth:`use_collision_model`, ``solve(..., collisions=...)`` checks the
    returned joints ("check": a collision makes the result a failure naming the pair) or
    also lets the solver avoid them ("avoid": the default solver's restarts and null-space
    push; the other solvers only check). "ignore" (the default) does neither.
    """

    collision = None  # a hyperarm_ik.collision.CollisionModel, or None
    _mode = "ignore"
    _held = False

    name = "base"
    #: the variants the solver applies to
    variants: tuple[str, ...] = ("arm", "rail_arm")

    def __init__(self, kin: Kinematics, max_iterations: int = 1000) -> None:
        if not isinstance(max_iterations, int) or max_iterations < 1:
            raise InvalidOptionError(f"max_iterations must be a positive integer, "
                                     f"got {max_iterations!r}")
        if kin.variant not in self.variants:
            raise UnsupportedVariantError(
                f"solver {self.name!r} applies to the {' or '.join(self.variants)} variant, "
                f"not {kin.variant!r}")
        self.kin = kin
        self.max_iterations = max_iterations
        self._now = time.perf_counter   # the clock of the solve in progress (solve's clock)

    # --- public entry point --------------------------------------------------------------
    def solve(self, position: np.ndarray, rotation: np.ndarray | None = None,
              seed: np.ndarray | None = None, *, position_only: bool = False,
              position_tolerance: float = DEFAULT_POSITION_TOLERANCE,
              orientation_tolerance: float = DEFAULT_ORIENTATION_TOLERANCE,
              timeout: float = DEFAULT_TIMEOUT, collisions: str = "ignore",
              held: bool = False, clock: str = "wall") -> IKResult:
        """Solve for tool0 at (position, rotation). ``seed`` defaults to q = 0.

        ``rotation`` may be None only with ``position_only``. ``collisions``: "ignore",
        "check" or "avoid" (needs :meth:`use_collision_model`); ``held``: the block is in
        the gripper. ``clock``: what ``timeout`` (s) counts, "wall" (elapsed time) or
        "cpu" (this thread's CPU time: a solve that other processes preempt is not cut
        short, so the answer does not depend on the machine's load; a planner's choice,
        e.g. the task runner's). Raises IKError subclasses on malformed input; an
        unreachable target is a result with success False, not an error.
        """
        t0 = time.perf_counter()
        p, r = self._check_target(position, rotation, position_only)
        q0 = self._check_seed(seed)
        _check_positive("position_tolerance", position_tolerance)
        _check_positive("orientation_tolerance", orientation_tolerance)
        _check_positive("timeout", timeout)
        if collisions not in COLLISION_MODES:
            raise InvalidOptionError(f"collisions must be one of {', '.join(COLLISION_MODES)}, "
                                     f"got {collisions!r}")
        if collisions != "ignore" and self.collision is None:
            raise InvalidOptionError(f"collisions={collisions!r} needs a collision model "
                                     f"(use_collision_model)")
        if clock not in CLOCKS:
            raise InvalidOptionError(f"clock must be one of {', '.join(CLOCKS)}, got {clock!r}")
        self._now = getattr(time, CLOCKS[clock])
        deadline = self._now() + timeout
        self._mode, self._held = collisions, bool(held)
        try:
            out = self._solve(p, r, q0, position_only, position_tolerance,
                              orientation_tolerance, deadline)
            return self._result(out[0], p, r, position_only, position_tolerance,
                                orientation_tolerance, out[1], t0, out[2],
                                out[3] if len(out) > 3 else None)
        finally:
            self._mode, self._held = "ignore", False
            self._now = time.perf_counter   # (a direct _solve call's deadline is wall time)

    def use_collision_model(self, model) -> None:
        """Check (and, for the default solver, avoid) collisions with ``model`` (a
        :class:`hyperarm_ik.collision.CollisionModel` on the same kinematics) in the
        requests that ask for it; None switches it off."""
        if model is not None and model.model.nq != self.kin.nq:
            raise InvalidOptionError("the collision model is of another robot variant")
        self.collision = model

    def _solve(self, p: np.ndarray, r: np.ndarray, q0: np.ndarray, position_only: bool,
               ptol: float, otol: float, deadline: float) -> tuple:
        """Return (q, iterations, note) or (q, iterations, note, (perr, oerr)) where the
        errors were evaluated by FK at exactly the returned q."""
        raise NotImplementedError

    # --- checks ---------------------------------------------------------------------------
    def _check_target(self, position, rotation, position_only: bool):
        p = np.asarray(position, dtype=float).reshape(-1)
        if p.shape != (3,):
            raise InvalidTargetError(f"target position needs 3 values, got {p.shape[0]}")
        if rotation is None:
            if not position_only:
                raise InvalidTargetError("a target rotation is required unless position_only")
            r = _EYE3
        else:
            r = np.asarray(rotation, dtype=float)
            if r.shape != (3, 3):
                raise InvalidTargetError(f"target rotation must be 3x3, got shape {r.shape}")
        v = r.ravel().tolist()
        if not math.isfinite(sum(p.tolist()) + sum(v)):  # nan/inf propagate through sums
            if not np.all(np.isfinite(p)):
                raise InvalidTargetError(f"target position is not finite: {p.tolist()}")
            raise InvalidTargetError("target rotation is not finite")
        # proper rotation: orthonormal rows and det = +1 (row0 x row1 = row2)
        a, b, c, d, e, f, g, h, i = v
        if (abs(a * a + b * b + c * c - 1.0) > 1e-6 or abs(d * d + e * e + f * f - 1.0) > 1e-6
                or abs(a * d + b * e + c * f) > 1e-6
                or abs(b * f - c * e - g) > 1e-6 or abs(c * d - a * f - h) > 1e-6
                or abs(a * e - b * d - i) > 1e-6):
            raise InvalidTargetError("target rotation is not a proper rotation matrix "
                                     "(orthonormal, det +1)")
        return p, r

    def _check_seed(self, seed) -> np.ndarray:
        if seed is None:
            return np.zeros(self.kin.nq)
        q = np.array(seed, dtype=float).reshape(-1)
        if q.shape != (self.kin.nq,):
            raise InvalidSeedError(
                f"seed needs {self.kin.nq} values ({', '.join(self.kin.joint_names)}), "
                f"got {q.shape[0]}")
        if not math.isfinite(sum(q.tolist())):
            bad = [n for n, v in zip(self.kin.joint_names, q) if not math.isfinite(v)]
            raise InvalidSeedError(f"seed is not finite for {', '.join(bad)}")
        return q

    # --- result ----------------------------------------------------------------------------
    def errors(self, q: np.ndarray, p: np.ndarray, r: np.ndarray) -> tuple[float, float]:
        """(position error m, orientation error rad) of tool0 at q."""
        pq, rq = self.kin.pose_view(q)
        return float(np.linalg.norm(p - pq)), rotation_angle(r, rq)

    def _result(self, q, p, r, position_only, ptol, otol, iterations, t0, note,
                errs=None) -> IKResult:
        """Build the result. ``errs`` may carry (position, orientation) errors that the
        solver evaluated by FK at exactly this q; otherwise they are computed here."""
        q = np.asarray(q, dtype=float)
        kin = self.kin
        lst = q.tolist()
        if not math.isfinite(sum(lst)):
            q = np.zeros(kin.nq)
            lst = q.tolist()
            errs = None
            note = (note + "; " if note else "") + "solver diverged to non-finite joints"
        qmin, qmax = min(lst), max(lst)
        if not (qmin >= -math.pi and qmax <= math.pi):
            q = kin.wrap(q)
            lst = q.tolist()
            qmin, qmax = min(lst), max(lst)
            errs = None
        if errs is None:
            perr, oerr = self.errors(q, p, r)
        else:
            perr, oerr = errs
        if qmin >= -kin.safe_range and qmax <= kin.safe_range:
            violations = []
        else:
            violations = kin.limit_violations(q)
        ok_p = perr <= ptol
        ok_o = position_only or oerr <= otol
        contacts = [] if self._mode == "ignore" else [
            str(c) for c in self.collision.check(q, self._held)]
        success = ok_p and ok_o and not violations and not contacts
        if success:
            msg = f"{self.name}: solved in {iterations} iterations"
        else:
            why = []
            if not ok_p:
                why.append(f"position error {perr:.3g} m > {ptol:.3g} m")
            if not ok_o:
                why.append(f"orientation error {oerr:.3g} rad > {otol:.3g} rad")
            if violations:
                why.append(f"outside joint limits: {', '.join(violations)}")
            if contacts:
                why.append(f"in collision: {', '.join(contacts)}")
            msg = f"{self.name}: not solved ({'; '.join(why)})"
        if note:
            msg += f"; {note}"
        return IKResult(q=q, success=success, position_error=perr, orientation_error=oerr,
                        iterations=iterations, solve_time=time.perf_counter() - t0,
                        message=msg, violations=violations, contacts=contacts,
                        reachable=False if note.startswith(
                            (OUT_OF_REACH, ORIENTATION_OUT_OF_REACH)) else None)


def _check_positive(name: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or value <= 0.0:
        raise InvalidOptionError(f"{name} must be a finite number > 0, got {value!r}")


def task_error(p: np.ndarray, r: np.ndarray, pq: np.ndarray, rq: np.ndarray,
               position_only: bool) -> np.ndarray:
    """Task-space error [p_t - p; log3(R_t R^T)] (6,), or the position part (3,)."""
    if position_only:
        return p - pq
    return np.concatenate((p - pq, pin.log3(r @ rq.T)))
