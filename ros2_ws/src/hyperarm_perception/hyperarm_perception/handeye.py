"""Eye-to-hand calibration of the fixed camera (no ROS): where camera_link is in the root frame.

This arm's set-up (hyperarm_description: ``camera:``): the camera is fixed in the root frame
(``camera_link``) and the gripper holds a marker (the target). For each of N arm postures
the FK gives ``G_i`` (tool0 in the root frame) and the detector gives ``C_i`` (the target in
camera_link). Both unknowns are constant: ``X`` (camera_link in the root frame) and ``Y``
(the target in tool0), with ``X C_i = G_i Y`` for every i.

:func:`calibrate_eye_to_hand` solves it with ``cv2.calibrateHandEye`` in its eye-to-hand form
(OpenCV's documentation: pass the base-to-gripper transforms, the inverses of G_i, where the
eye-in-hand form takes gripper-to-base; the result is then the camera in the base frame),
estimates Y from every pair, refines both (maximum likelihood, weighted by the detections'
covariances), reports each posture's residual (the target's predicted pose ``X^-1 G_i Y``
against the detected ``C_i``: distance in m, angle in rad) and drops outliers one by one
(the worst, while its Mahalanobis distance exceeds ``outlier_factor`` times the median and
chi-square's 99.9 % point), solving again each time.

How many postures: the rotation of X is determined by the relative motions
``G_i^-1 G_j``, which need rotations about at least two non-parallel axes (Tsai & Lenz): so
at least 3 postures whose relative rotations are large (>= ``min_angle``) and whose axes
span more than a line. :func:`check_pose_diversity` checks that before solving and says
what is missing. Noise averages out as more postures are used; docs/perception.md gives the
figures. Units: m, rad.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from .markers import PerceptionError, rotation_angle

__all__ = ["HandEyeError", "Diversity", "HandEyeResult", "check_pose_diversity",
           "calibrate_eye_to_hand", "METHODS"]


class HandEyeError(PerceptionError):
    """The postures or detections cannot give a calibration (too few, degenerate, bad data,
    too many outliers)."""


#: sqrt of chi-square's 99.9 % point for 6 degrees of freedom (22.46)
CHI2_6_999_SQRT = math.sqrt(22.458)

#: the names accepted for ``method`` -> OpenCV's flags
METHODS = {"tsai": cv2.CALIB_HAND_EYE_TSAI, "park": cv2.CALIB_HAND_EYE_PARK,
           "horaud": cv2.CALIB_HAND_EYE_HORAUD, "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
           "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS}


@dataclass(frozen=True)
class Diversity:
    """How well N postures constrain the calibration: ``poses``; ``motions``: the number of
    posture pairs whose relative rotation is >= min_angle; ``axis_spread``: the second
    singular value of those motions' unit rotation axes over sqrt(motions) (0 when all the
    axes are parallel, up to 1/sqrt(2) when they spread evenly in a plane or more)."""

    poses: int
    motions: int
    axis_spread: float


@dataclass(frozen=True)
class HandEyeResult:
    """``camera_pose``: 4x4 camera_link in the root frame (m); ``target_in_tool``: 4x4 the
    held target in tool0; per posture given, ``position_residuals`` (m) and
    ``angle_residuals`` (rad) of the target's predicted pose against the detection, and
    ``inliers`` (False: dropped as an outlier); ``method`` used."""

    camera_pose: np.ndarray
    target_in_tool: np.ndarray
    position_residuals: np.ndarray
    angle_residuals: np.ndarray
    inliers: np.ndarray
    method: str

    def summary(self) -> dict[str, float]:
        """Residual statistics of the inliers: RMS, median and max (position in m, angle in
        rad), and the counts."""
        p = self.position_residuals[self.inliers]
        a = self.angle_residuals[self.inliers]
        return {"poses": int(self.inliers.size), "inliers": int(self.inliers.sum()),
                "position_rms": float(np.sqrt(np.mean(p ** 2))),
                "position_median": float(np.median(p)), "position_max": float(p.max()),
                "angle_rms": float(np.sqrt(np.mean(a ** 2))),
                "angle_median": float(np.median(a)), "angle_max": float(a.max())}


def _check_poses(poses: Sequence[np.ndarray], what: str) -> list[np.ndarray]:
    out = []
    for i, T in enumerate(poses):
        T = np.asarray(T, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise HandEyeError(f"{what}[{i}]: expected a finite 4x4 pose")
        R = T[:3, :3]
        if (np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0
                or np.any(T[3] != (0, 0, 0, 1))):
            raise HandEyeError(f"{what}[{i}]: not a rigid transform (rotation not orthonormal "
                               "or last row not 0 0 0 1)")
        out.append(T)
    return out


def _axis_angle(R: np.ndarray) -> tuple[np.ndarray, float]:
    rvec = cv2.Rodrigues(R)[0].ravel()
    angle = float(np.linalg.norm(rvec))
    return (rvec / angle if angle > 0 else np.zeros(3)), angle


def check_pose_diversity(tool_poses: Sequence[np.ndarray], *, min_poses: int = 3,
                         min_angle: float = math.radians(10.0),
                         min_spread: float = 0.15) -> Diversity:
    """Check that the tool0 poses (4x4, root frame) can determine the calibration: at least
    ``min_poses`` postures, relative rotations of at least ``min_angle`` (rad) between some
    pairs, about axes that are not all parallel (``axis_spread`` >= ``min_spread``; 0.15 is
    about 9 deg between two axes). Raises :class:`HandEyeError` saying what is missing."""
    poses = _check_poses(tool_poses, "tool_poses")
    if len(poses) < min_poses:
        raise HandEyeError(f"{len(poses)} postures: at least {min_poses} are needed (the "
                           "rotation needs two relative motions about non-parallel axes)")
    axes = []
    for i in range(len(poses)):
        for j in range(i + 1, len(poses)):
            axis, angle = _axis_angle(poses[i][:3, :3].T @ poses[j][:3, :3])
            if angle >= min_angle:
                axes.append(axis * (1 if axis @ [1, 2, 3] >= 0 else -1))
    if len(axes) < 2:
        raise HandEyeError(f"only {len(axes)} pair(s) of postures differ by a rotation of "
                           f">= {math.degrees(min_angle):.0f} deg: turn the held target more "
                           "between postures")
    s = np.linalg.svd(np.array(axes), compute_uv=False)
    spread = float(s[1] / math.sqrt(len(axes)))
    if spread < min_spread:
        raise HandEyeError(f"the postures' relative rotations are all about nearly one axis "
                           f"(spread {spread:.3f} < {min_spread}): turn the target about "
                           "another axis too")
    return Diversity(len(poses), len(axes), spread)


def _average_pose(poses: list[np.ndarray]) -> np.ndarray:
    """Mean translation; rotation: the mean matrix projected onto SO(3) (SVD)."""
    M = np.mean([T[:3, :3] for T in poses], axis=0)
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = np.mean([T[:3, 3] for T in poses], axis=0)
    return out


def _residuals(X: np.ndarray, Y: np.ndarray, G: list[np.ndarray], C: list[np.ndarray]
               ) -> tuple[np.ndarray, np.ndarray]:
    """Per posture: distance (m) and angle (rad) of the target's predicted pose X^-1 G Y
    from the detected C."""
    inv_X = np.linalg.inv(X)
    pos, ang = [], []
    for Gi, Ci in zip(G, C):
        P = inv_X @ Gi @ Y
        pos.append(float(np.linalg.norm(P[:3, 3] - Ci[:3, 3])))
        ang.append(rotation_angle(P[:3, :3] @ Ci[:3, :3].T))
    return np.array(pos), np.array(ang)


def _perturbed(T: np.ndarray, d: np.ndarray) -> np.ndarray:
    """T with the left perturbation d = (dt [m], dtheta [rad]): t + dt, exp([dtheta]x) R."""
    out = T.copy()
    out[:3, :3] = cv2.Rodrigues(d[3:])[0] @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + d[:3]
    return out


def _log_rotation(R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of R, accurate for small angles too (cv2.Rodrigues returns 0
    below ~1e-5 rad, which zeroes a finite-difference Jacobian near a perfect fit)."""
    v = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = float(np.linalg.norm(v))
    angle = math.atan2(s, 0.5 * (np.trace(R) - 1.0))
    if s < 1e-12:
        return v
    if angle > 3.0:  # near pi the skew part loses the axis: OpenCV's is fine there
        return cv2.Rodrigues(R)[0].ravel()
    return v * (angle / s)


def _whitened(X: np.ndarray, Y: np.ndarray, G: list[np.ndarray], C: list[np.ndarray],
              W: list[np.ndarray]) -> np.ndarray:
    """Stacked residuals W_i (dt_i, dtheta_i): the detected C_i against the predicted
    X^-1 G_i Y, as a left perturbation in camera_link (the detector's covariance frame)."""
    inv_X = np.linalg.inv(X)
    out = []
    for Gi, Ci, Wi in zip(G, C, W):
        P = inv_X @ Gi @ Y
        r = np.r_[Ci[:3, 3] - P[:3, 3], _log_rotation(Ci[:3, :3] @ P[:3, :3].T)]
        out.append(Wi @ r)
    return np.concatenate(out)


def _refine(X: np.ndarray, Y: np.ndarray, G: list[np.ndarray], C: list[np.ndarray],
            W: list[np.ndarray], iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Maximum-likelihood X, Y: Levenberg-Marquardt on the whitened residuals (numerical
    Jacobian over the 12 perturbation parameters), from the linear solution."""
    lam = 1e-3
    r = _whitened(X, Y, G, C, W)
    cost = float(r @ r)
    for _ in range(iterations):
        J = np.empty((r.size, 12))
        h = 1e-7
        for k in range(12):
            d = np.zeros(12)
            d[k] = h
            J[:, k] = (_whitened(_perturbed(X, d[:6]), _perturbed(Y, d[6:]), G, C, W) - r) / h
        A, b = J.T @ J, J.T @ r
        while True:
            step = np.linalg.solve(A + lam * np.diag(np.diag(A)), -b)
            X2, Y2 = _perturbed(X, step[:6]), _perturbed(Y, step[6:])
            r2 = _whitened(X2, Y2, G, C, W)
            if float(r2 @ r2) <= cost:
                X, Y, r, lam = X2, Y2, r2, lam * 0.3
                converged = cost - float(r2 @ r2) < 1e-12 * max(cost, 1.0)
                cost = float(r2 @ r2)
                break
            lam *= 10.0
            if lam > 1e8:
                return X, Y
        if converged:
            break
    return X, Y


def _solve(G: list[np.ndarray], C: list[np.ndarray], method: str
           ) -> tuple[np.ndarray, np.ndarray]:
    inv_G = [np.linalg.inv(T) for T in G]
    R, t = cv2.calibrateHandEye([T[:3, :3] for T in inv_G], [T[:3, 3] for T in inv_G],
                                [T[:3, :3] for T in C], [T[:3, 3] for T in C],
                                method=METHODS[method])
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = np.asarray(t).ravel()
    if not np.all(np.isfinite(X)):
        raise HandEyeError(f"cv2.calibrateHandEye ({method}) found no solution")
    return X, _average_pose([iG @ X @ Ci for iG, Ci in zip(inv_G, C)])


def calibrate_eye_to_hand(tool_poses: Sequence[np.ndarray],
                          target_poses: Sequence[np.ndarray],
                          target_covariances: Sequence[np.ndarray] | None = None, *,
                          method: str = "park", refine: bool = True,
                          position_sigma: float = 0.001,
                          angle_sigma: float = math.radians(0.5),
                          outlier_factor: float = 3.0, min_poses: int = 3) -> HandEyeResult:
    """Camera_link in the root frame from ``tool_poses`` (G_i: tool0 in the root frame, FK)
    and ``target_poses`` (C_i: the held target in camera_link, the detector's), one pair
    per posture. ``method``: one of :data:`METHODS`, the linear solution. ``refine``: then
    the maximum-likelihood X and Y (Levenberg-Marquardt on the residuals whitened by
    ``target_covariances``, the detector's 6x6 covariances in camera_link, or else by
    ``position_sigma`` m and ``angle_sigma`` rad per axis); the linear methods alone leave
    several mm (their rotation error leaks into the translation: docs/perception.md).
    Outliers: each posture's Mahalanobis distance m_i = |W_i r_i| (r_i: the residual
    (dt, dtheta) in camera_link, W_i: the whitening above); while the worst inlier's
    exceeds both ``outlier_factor`` x the inliers' median and 4.74 (sqrt of chi-square's
    99.9 % point for 6 dof), it is dropped and the problem solved again; at least
    ``min_poses`` diverse postures (:func:`check_pose_diversity`) must remain. Judging in
    the whitened metric keeps postures whose error lies along the line of sight, where the
    detector's depth is known to be weak. :class:`HandEyeError` when the data cannot give a
    calibration."""
    if method not in METHODS:
        raise HandEyeError(f"method {method!r}: expected one of {', '.join(METHODS)}")
    G = _check_poses(tool_poses, "tool_poses")
    C = _check_poses(target_poses, "target_poses")
    if len(G) != len(C):
        raise HandEyeError(f"{len(G)} tool poses but {len(C)} target poses: one of each per "
                           "posture")
    if target_covariances is None:
        W = [np.diag([1.0 / position_sigma] * 3 + [1.0 / angle_sigma] * 3)] * len(C)
    else:
        if len(target_covariances) != len(C):
            raise HandEyeError(f"{len(target_covariances)} covariances for {len(C)} target "
                               "poses")
        W = []
        for i, cov in enumerate(target_covariances):
            cov = np.asarray(cov, dtype=float)
            try:
                if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
                    raise np.linalg.LinAlgError
                W.append(np.linalg.inv(np.linalg.cholesky(cov)))
            except np.linalg.LinAlgError:
                raise HandEyeError(f"target_covariances[{i}]: expected a finite symmetric "
                                   "positive definite 6x6 matrix") from None
    inliers = np.ones(len(G), dtype=bool)
    while True:
        idx = np.flatnonzero(inliers)
        check_pose_diversity([G[i] for i in idx], min_poses=min_poses)
        X, Y = _solve([G[i] for i in idx], [C[i] for i in idx], method)
        if refine:
            X, Y = _refine(X, Y, [G[i] for i in idx], [C[i] for i in idx],
                           [W[i] for i in idx])
        pos, ang = _residuals(X, Y, G, C)    # every posture's, dropped ones too
        m = np.linalg.norm(_whitened(X, Y, [G[i] for i in idx], [C[i] for i in idx],
                                     [W[i] for i in idx]).reshape(-1, 6), axis=1)
        over = (m > outlier_factor * np.median(m)) & (m > CHI2_6_999_SQRT)
        if not over.any():
            return HandEyeResult(X, Y, pos, ang, inliers, method)
        worst = idx[int(np.argmax(np.where(over, m, -1.0)))]
        inliers[worst] = False
        if inliers.sum() < min_poses:
            raise HandEyeError(f"too many outliers: {int((~inliers).sum())} of {len(G)} "
                               f"postures dropped, fewer than {min_poses} left")
