"""Per-servo torque calibration from static poses under gravity (no ROS).

A servo reports ``tau_measured = scale * tau_true + offset`` (torque-constant error,
zero-current offset). At rest and without contact, tau_true is the gravity torque of the
model (links + payload), so poses with different gravity loads identify, joint by joint,
``scale`` and ``offset`` by regularised least squares (:func:`fit_calibration`). A joint
whose gravity torque the poses do not identify (joint1 turns about the vertical: none)
keeps ``scale`` 1 and gets its offset only (``identified: false`` in the file). Friction biases one static sample; the
calibration executable averages each pose approached from both sides.

Coulomb friction: while a joint turns faster than ``FRICTION_VELOCITY`` its servo's
current also overcomes the friction, ``friction * sign(velocity)`` (N·m), which no wrench
acts against. An arm held by the force controller is rarely still (the pseudo-goal and the
null-space posture term keep some joints creeping at a few 0.01 rad/s while it presses),
so an estimate that ignores this is biased by up to the friction of every creeping joint:
15-30 % of a 1.6 N press on the mock. The calibration run also records the efforts while
the joints move between poses; :func:`fit_friction` takes, per joint, the median of
``sign(v) (tau_measured - tau_model)`` over them, and :meth:`TorqueCalibration.correct`
subtracts ``friction * sign(v)`` from a moving joint's effort.

File (YAML, written by :func:`save_calibration`, read by :func:`load_calibration`)::

    schema_version: 1
    kind: hyperarm_torque_calibration
    joints:
      joint2: {scale: 1.08, offset: -0.012, identified: true, rms: 0.004, samples: 24,
               friction: 0.031}
``friction`` is optional (default 0: none compensated). Units: N·m.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import yaml

from .errors import CalibrationError

__all__ = ["JointCalibration", "TorqueCalibration", "fit_calibration", "fit_friction",
           "save_calibration", "load_calibration", "SCHEMA_VERSION", "KIND",
           "FRICTION_VELOCITY"]

SCHEMA_VERSION = 1
KIND = "hyperarm_torque_calibration"
NOISE = 0.005          # N·m: std of a static effort residual (the servos' current resolution)
SCALE_PRIOR = 0.2      # std of the scale's prior around 1
OFFSET_PRIOR = 0.02    # N·m: std of the offset's prior around 0
IDENTIFIED_SCALE_STD = 0.05   # posterior std of a scale below which the joint is identified
SCALE_RANGE = (0.5, 2.0)
FRICTION_VELOCITY = 0.02   # rad/s: a joint faster than this shows its Coulomb friction
FRICTION_MIN_SAMPLES = 20  # moving samples a joint needs for its friction to be fitted


@dataclass(frozen=True)
class JointCalibration:
    scale: float = 1.0
    offset: float = 0.0
    identified: bool = False
    rms: float = 0.0
    samples: int = 0
    friction: float = 0.0      # N·m, Coulomb friction compensated while moving

    def __post_init__(self) -> None:
        if not (SCALE_RANGE[0] <= self.scale <= SCALE_RANGE[1]):
            raise CalibrationError(f"scale {self.scale!r} outside {SCALE_RANGE}")
        if not math.isfinite(self.offset) or abs(self.offset) > 5.0:
            raise CalibrationError(f"offset {self.offset!r} N·m not finite or beyond 5 N·m")
        if not (math.isfinite(self.friction) and 0.0 <= self.friction <= 5.0):
            raise CalibrationError(f"friction {self.friction!r} N·m not within 0..5")


@dataclass(frozen=True)
class TorqueCalibration:
    """Calibration of named joints; joints not listed are taken as exact."""

    joints: Mapping[str, JointCalibration]

    def arrays(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(scale, offset, friction) in the order of ``names`` (cached per order)."""
        key = tuple(names)
        cache = self.__dict__.setdefault("_cache", {})
        if key not in cache:
            exact = JointCalibration()
            cal = [self.joints.get(n, exact) for n in names]
            cache[key] = (np.array([c.scale for c in cal]), np.array([c.offset for c in cal]),
                          np.array([c.friction for c in cal]))
        return cache[key]

    def correct(self, names: Sequence[str], tau_measured: np.ndarray,
                velocity: np.ndarray | None = None) -> np.ndarray:
        """True torques from measured ones: (tau_measured - offset) / scale, less the
        Coulomb friction ``friction * sign(v)`` of joints faster than FRICTION_VELOCITY
        (with ``velocity``, rad/s, in the order of ``names``)."""
        s, b, fc = self.arrays(names)
        tau = (np.asarray(tau_measured, dtype=float) - b) / s
        if velocity is not None:
            v = np.asarray(velocity, dtype=float)
            tau -= np.where(np.abs(v) > FRICTION_VELOCITY, np.sign(v) * fc, 0.0)
        return tau

    def command(self, names: Sequence[str], tau: np.ndarray) -> np.ndarray:
        """What to command for a true torque ``tau`` (the servo applies scale x command)."""
        s = self.arrays(names)[0]
        return np.asarray(tau, dtype=float) / s


def fit_calibration(names: Sequence[str], tau_model: np.ndarray, tau_measured: np.ndarray,
                    noise: float = NOISE, scale_prior: float = SCALE_PRIOR,
                    offset_prior: float = OFFSET_PRIOR) -> TorqueCalibration:
    """Fit scale/offset per joint from P static poses: ``tau_model`` and ``tau_measured``
    are (P, n) in N·m. Needs at least 3 poses.

    A regularised (maximum a posteriori) least-squares fit of ``measured = scale * model +
    offset``: residuals of std ``noise`` (N·m, the effort's resolution), priors scale ~ 1 +-
    ``scale_prior`` and offset ~ 0 +- ``offset_prior`` (N·m). A plain two-parameter fit
    trades scale against offset when a joint's gravity torque is large but varies little
    over the poses (joint2: ~3.3 N·m +- 0.07): a 2 % scale error then hides in a
    0.07 N·m offset. The priors keep the offset small unless the data demand it, and a
    scale the data do not inform stays at 1 (joint1: no gravity torque at all). A joint is
    ``identified`` when the posterior std of its scale is below ``IDENTIFIED_SCALE_STD``."""
    tm = np.asarray(tau_model, dtype=float)
    tr = np.asarray(tau_measured, dtype=float)
    if tm.ndim != 2 or tm.shape != tr.shape or tm.shape[1] != len(names):
        raise CalibrationError(f"expected two (poses, {len(names)}) arrays, got {tm.shape} "
                               f"and {tr.shape}")
    if tm.shape[0] < 3:
        raise CalibrationError(f"need at least 3 poses, got {tm.shape[0]}")
    if not (np.all(np.isfinite(tm)) and np.all(np.isfinite(tr))):
        raise CalibrationError("non-finite torques in the calibration data")
    if not (noise > 0.0 and scale_prior > 0.0 and offset_prior > 0.0):
        raise CalibrationError("noise, scale_prior and offset_prior must be > 0")
    prior = np.diag([1.0 / scale_prior ** 2, 1.0 / offset_prior ** 2])
    out = {}
    for i, name in enumerate(names):
        x, y = tm[:, i], tr[:, i]
        a = np.c_[x, np.ones_like(x)]
        normal = a.T @ a / noise ** 2 + prior
        rhs = a.T @ y / noise ** 2 + prior @ np.array([1.0, 0.0])
        scale, offset = np.linalg.solve(normal, rhs)
        cov = np.linalg.inv(normal)
        identified = bool(math.sqrt(cov[0, 0]) < IDENTIFIED_SCALE_STD)
        if not SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]:
            raise CalibrationError(f"{name}: fitted scale {scale:.3g} outside "
                                   f"{SCALE_RANGE}: wrong model or data")
        rms = float(np.sqrt(np.mean((scale * x + offset - y) ** 2)))
        out[name] = JointCalibration(scale=float(scale), offset=float(offset),
                                     identified=identified, rms=rms, samples=int(len(x)))
    return TorqueCalibration(out)


def fit_friction(cal: TorqueCalibration, names: Sequence[str], tau_model: np.ndarray,
                 tau_measured: np.ndarray, velocity: np.ndarray) -> TorqueCalibration:
    """``cal`` with each joint's Coulomb friction (N·m) fitted from samples taken while the
    arm moved without contact: ``tau_model`` (the model's torques at those states: gravity,
    and inertia if known), ``tau_measured`` and ``velocity`` (rad/s) are (S, n). Per
    joint, the median of ``sign(v) (corrected - model)`` over its samples faster than
    FRICTION_VELOCITY (inertia while speeding up and slowing down roughly cancels in the
    median), at least 0; a joint with fewer than FRICTION_MIN_SAMPLES such samples keeps
    friction 0 (none compensated)."""
    tm = np.asarray(tau_model, dtype=float)
    tr = np.asarray(tau_measured, dtype=float)
    v = np.asarray(velocity, dtype=float)
    if tm.ndim != 2 or tm.shape != tr.shape or tm.shape != v.shape or \
            tm.shape[1] != len(names):
        raise CalibrationError(f"friction: expected three (samples, {len(names)}) arrays, got "
                               f"{tm.shape}, {tr.shape} and {v.shape}")
    if not (np.all(np.isfinite(tm)) and np.all(np.isfinite(tr)) and np.all(np.isfinite(v))):
        raise CalibrationError("non-finite values in the friction data")
    corrected = cal.correct(names, tr) if len(tr) else tr
    out = dict(cal.joints)
    for i, name in enumerate(names):
        moving = np.abs(v[:, i]) > FRICTION_VELOCITY
        base = out.get(name, JointCalibration())
        fc = 0.0
        if int(moving.sum()) >= FRICTION_MIN_SAMPLES:
            d = np.sign(v[moving, i]) * (corrected[moving, i] - tm[moving, i])
            fc = float(min(max(np.median(d), 0.0), 5.0))
        out[name] = JointCalibration(scale=base.scale, offset=base.offset,
                                     identified=base.identified, rms=base.rms,
                                     samples=base.samples, friction=fc)
    return TorqueCalibration(out)


def save_calibration(cal: TorqueCalibration, path: str | Path) -> None:
    data = {"schema_version": SCHEMA_VERSION, "kind": KIND,
            "joints": {n: {"scale": round(c.scale, 6), "offset": round(c.offset, 6),
                           "identified": c.identified, "rms": round(c.rms, 6),
                           "samples": c.samples, "friction": round(c.friction, 6)}
                       for n, c in cal.joints.items()}}
    Path(path).write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")


def load_calibration(path: str | Path, known: Sequence[str] | None = None) -> TorqueCalibration:
    """Read and validate a calibration file; ``known`` = the joints it may name."""
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CalibrationError(f"cannot read calibration {p}: {exc.strerror}") from exc
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{p}: not valid YAML: {exc}") from exc
    if not isinstance(data, Mapping) or data.get("kind") != KIND:
        raise CalibrationError(f"{p}: not a torque calibration (kind: {KIND})")
    if data.get("schema_version") != SCHEMA_VERSION:
        raise CalibrationError(f"{p}: schema_version must be {SCHEMA_VERSION}")
    joints = data.get("joints")
    if not isinstance(joints, Mapping):
        raise CalibrationError(f"{p}: joints: expected a mapping")
    out = {}
    for name, raw in joints.items():
        if known is not None and name not in known:
            raise CalibrationError(f"{p}: joints.{name}: not an arm joint ({', '.join(known)})")
        if not isinstance(raw, Mapping):
            raise CalibrationError(f"{p}: joints.{name}: expected a mapping")
        try:
            vals = {k: raw[k] for k in ("scale", "offset")}
            vals["friction"] = raw.get("friction", 0.0)
            if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in vals.values()):
                raise CalibrationError("scale, offset and friction must be numbers")
            out[name] = JointCalibration(scale=float(vals["scale"]), offset=float(vals["offset"]),
                                         identified=bool(raw.get("identified", True)),
                                         rms=float(raw.get("rms", 0.0)),
                                         samples=int(raw.get("samples", 0)),
                                         friction=float(vals["friction"]))
        except KeyError as exc:
            raise CalibrationError(f"{p}: joints.{name}: missing {exc.args[0]}") from exc
        except CalibrationError as exc:
            raise CalibrationError(f"{p}: joints.{name}: {exc}") from exc
    return TorqueCalibration(out)


def calibration_poses(lower: np.ndarray, upper: np.ndarray, q0: np.ndarray, n: int,
                      spread: float = 0.6, seed: int = 0) -> np.ndarray:
    """``n`` arm postures around ``q0`` (rad): each joint but the first moved by up to
    ``spread`` rad (uniform, fixed ``seed``), kept 0.2 rad inside the limits. Joint1 (a
    vertical axis) stays: it changes no gravity torque. The caller checks them (e.g. the
    tool's height) before use."""
    if n < 3:
        raise CalibrationError(f"need at least 3 poses, got {n}")
    rng = np.random.default_rng(seed)
    q0 = np.asarray(q0, dtype=float)
    out = np.repeat(q0[None, :], n, axis=0)
    out[:, 1:] += rng.uniform(-spread, spread, (n, len(q0) - 1))
    return np.clip(out, lower + 0.2, upper - 0.2)


class CalibrationRun:
    """Sequencing of a calibration (no ROS): for each pose, approach it from above and
    from below (``approach`` rad, friction acts both ways), wait until still, average the
    efforts for ``average`` s, and use the mean of both approaches. ``step`` is called on
    every joint state and returns the arm goal to command (or None when done). Given the
    velocities, the states while some joint moves faster than FRICTION_VELOCITY are kept
    in ``moving`` (time, q, velocity, effort), for :func:`moving_samples` and
    :func:`fit_friction`."""

    def __init__(self, poses: np.ndarray, approach: float = 0.05, settle: float = 0.5,
                 average: float = 0.5, tolerance: float = 0.003, timeout: float = 10.0) -> None:
        self.poses = np.asarray(poses, dtype=float)
        self.approach, self.settle, self.average = approach, settle, average
        self.tolerance, self.timeout = tolerance, timeout
        self.samples: list[list[np.ndarray]] = [[] for _ in range(2 * len(self.poses))]
        self.q_at: list[np.ndarray] = []
        self.moving: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._k = 0            # index over (pose, side, phase)
        self._phase_start: float | None = None
        self._reached: float | None = None
        self.done = False

    def _target(self) -> np.ndarray:
        pose, side, phase = self._k // 4, (self._k // 2) % 2, self._k % 2
        q = self.poses[pose].copy()
        if phase == 0:     # the approach point, beyond the pose on this side
            q[1:] += self.approach if side == 0 else -self.approach
        return q

    def step(self, now: float, q: np.ndarray, effort: np.ndarray,
             velocity: np.ndarray | None = None) -> np.ndarray | None:
        if self.done:
            return None
        if velocity is not None and np.abs(velocity).max() > FRICTION_VELOCITY:
            self.moving.append((now, np.array(q, dtype=float), np.array(velocity, dtype=float),
                                np.array(effort, dtype=float)))
        target = self._target()
        if self._phase_start is None:
            self._phase_start = now
        if now - self._phase_start > self.timeout:
            raise CalibrationError(f"pose {self._k // 4 + 1} not reached within "
                                   f"{self.timeout:g} s (|error| "
                                   f"{np.abs(q - target).max():.4f} rad)")
        if np.abs(q - target).max() <= self.tolerance:
            if self._reached is None:
                self._reached = now
            if self._k % 2 == 1 and now - self._reached >= self.settle:
                self.samples[self._k // 2].append(np.asarray(effort, dtype=float))
            if self._k % 2 == 0 or now - self._reached >= self.settle + self.average:
                if self._k % 4 == 3:
                    self.q_at.append(np.asarray(q, dtype=float))
                self._k += 1
                self._phase_start, self._reached = None, None
                if self._k >= 4 * len(self.poses):
                    self.done = True
                    return None
                return self._target()
        return target

    def moving_samples(self, max_gap: float = 0.05
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(q, velocity, acceleration, effort), each (S, n), of the moving states; the
        accelerations by central differences of the velocities within runs of states at
        most ``max_gap`` s apart (a run's first and last state are dropped)."""
        out: list[list[np.ndarray]] = [[], [], [], []]
        m = self.moving
        for i in range(1, len(m) - 1):
            (t0, _, v0, _), (t1, q1, v1, e1), (t2, _, v2, _) = m[i - 1], m[i], m[i + 1]
            if 0.0 < t1 - t0 <= max_gap and 0.0 < t2 - t1 <= max_gap:
                for lst, x in zip(out, (q1, v1, (v2 - v0) / (t2 - t0), e1)):
                    lst.append(x)
        n = self.poses.shape[1]
        return tuple(np.array(x) if x else np.zeros((0, n)) for x in out)  # type: ignore

    def efforts(self) -> np.ndarray:
        """(P, n) mean efforts per pose, both approaches averaged."""
        means = [np.mean(s, axis=0) for s in self.samples]
        return np.array([(means[2 * i] + means[2 * i + 1]) / 2 for i in range(len(self.poses))])
