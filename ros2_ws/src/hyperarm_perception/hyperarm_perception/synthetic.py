"""Synthetic camera images of printed markers, rendered with OpenCV itself (no simulator).

Used by the tests and the detector benchmark: ``cv2.aruco.generateImageMarker`` draws the
marker with a white margin, a homography (exact for a plane seen by a pinhole camera) warps
it into the image at a known pose, supersampled ``supersample`` times per axis and
area-averaged (anti-aliased edges); then a Gaussian blur and Gaussian pixel noise. Distortion
is not rendered: use a camera model without distortion. Units: m, pixels, grey levels.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from .markers import CameraModel, marker_corners

__all__ = ["MarkerPlacement", "render", "look_at_pose"]


@dataclass(frozen=True)
class MarkerPlacement:
    """Marker ``id`` of edge ``size`` (m) at ``pose``: 4x4 of the marker frame in the optical
    frame (x right, y down, z along the view)."""

    id: int
    size: float
    pose: np.ndarray


def render(camera: CameraModel, dictionary: str, markers: Sequence[MarkerPlacement], *,
           background: int = 110, blur_sigma: float = 0.6, noise_sigma: float = 2.0,
           rng: np.random.Generator | None = None, supersample: int = 4,
           marker_px: int = 240, margin_bits: float = 1.0,
           corner_shift: dict[int, tuple[int, tuple[float, float]]] | None = None
           ) -> np.ndarray:
    """A uint8 mono image (camera.height x camera.width) of ``markers`` (nearest last) on a
    uniform ``background``; ``blur_sigma`` (pixels) and ``noise_sigma`` (grey levels) model
    the optics and the sensor. ``corner_shift`` {marker id: (corner index, (du, dv) pixels)}
    moves one image corner of a marker (a non-planar / damaged marker) for tests."""
    if camera.D.size and np.any(camera.D):
        raise ValueError("render: distortion is not rendered; use D = 0")
    dictionary_ = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    s = int(supersample)
    # supersampled pixel centres: x_hi = s x + (s - 1) / 2
    up = np.array([[s, 0.0, 0.5 * (s - 1)], [0.0, s, 0.5 * (s - 1)], [0.0, 0.0, 1.0]])
    K_hi = up @ camera.K
    W, H = camera.width * s, camera.height * s
    canvas = np.full((H, W), background, dtype=np.uint8)
    for m in sorted(markers, key=lambda m: -float(m.pose[2, 3])):
        bits = dictionary_.markerSize + 2
        cell = max(1, marker_px // bits)
        side = cell * bits
        pad = int(round(margin_bits * cell))
        tile = np.full((side + 2 * pad, side + 2 * pad), 255, dtype=np.uint8)
        tile[pad:pad + side, pad:pad + side] = cv2.aruco.generateImageMarker(
            dictionary_, m.id, side, borderBits=1)
        # the black square's corners in the tile (pixel-centre coordinates)
        src = np.array([[pad - 0.5, pad - 0.5], [pad + side - 0.5, pad - 0.5],
                        [pad + side - 0.5, pad + side - 0.5], [pad - 0.5, pad + side - 0.5]])
        pts = marker_corners(m.size) @ m.pose[:3, :3].T + m.pose[:3, 3]
        if np.any(pts[:, 2] <= 0):
            raise ValueError(f"render: marker {m.id} is behind the camera")
        proj = pts @ K_hi.T
        dst = proj[:, :2] / proj[:, 2:3]
        if corner_shift and m.id in corner_shift:
            k, (du, dv) = corner_shift[m.id]
            dst[k] += (du * s, dv * s)
        Hm = cv2.getPerspectiveTransform(src.astype(np.float32), dst.astype(np.float32))
        warped = cv2.warpPerspective(tile, Hm, (W, H), flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        mask = cv2.warpPerspective(np.full(tile.shape, 255, np.uint8), Hm, (W, H),
                                   flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                                   borderValue=0)
        canvas[mask > 0] = warped[mask > 0]
    image = cv2.resize(canvas, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    out = image.astype(float)
    if blur_sigma > 0:
        out = cv2.GaussianBlur(out, (0, 0), blur_sigma)
    if noise_sigma > 0:
        rng = rng if rng is not None else np.random.default_rng()
        out = out + rng.normal(0.0, noise_sigma, out.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def look_at_pose(position: Sequence[float], tilt: float, tilt_axis_angle: float,
                 spin: float) -> np.ndarray:
    """4x4 marker pose in the optical frame at ``position`` (m), facing the camera (its z
    towards the camera's origin) and then tilted by ``tilt`` (rad) about an in-plane axis at
    ``tilt_axis_angle`` (rad) from its x axis, and spun by ``spin`` (rad) about its normal."""
    p = np.asarray(position, dtype=float)
    z = -p / np.linalg.norm(p)                  # marker normal towards the camera
    x0 = np.cross([0.0, 1.0, 0.0], z)
    if np.linalg.norm(x0) < 1e-6:
        x0 = np.cross([1.0, 0.0, 0.0], z)
    x0 /= np.linalg.norm(x0)
    y0 = np.cross(z, x0)
    R = np.column_stack([x0, y0, z])
    R = R @ cv2.Rodrigues(np.array([0.0, 0.0, spin]))[0]
    axis = np.array([np.cos(tilt_axis_angle), np.sin(tilt_axis_angle), 0.0])
    R = R @ cv2.Rodrigues(axis * tilt)[0]
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T
