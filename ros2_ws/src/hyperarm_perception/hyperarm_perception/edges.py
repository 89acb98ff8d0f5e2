"""Marker corners from the marker's four outer edges (no ROS): an unbiased refinement.

OpenCV's corner refinements find a blurred convex corner inside the true one:
``CORNER_REFINE_SUBPIX`` (``cornerSubPix``) put the corners of the mock's rendered markers
0.27-0.30 px inward at any picture size, so a 25 px marker looked 1-1.3 % farther than it was
(10 mm at 0.8 m, docs/perception.md). A straight edge has no such bias: blurred by any
symmetric point-spread function, the level half way between the dark and the light side
still lies on the edge. So each outer edge of the black square is measured where it is
straight (away from the corners): at points along it, the intensity profile across it
(bilinear samples) gives the sub-pixel position of the mid-level crossing; a
line is fitted through them (``cv2.fitLine``, Huber weights against a stray profile); the
corners are the intersections of neighbouring lines.

It needs the black square's outer border (one module wide) inside the edge and a light
margin (at least one module, as printed markers have) outside, and straight edges: on a
real lens, run it on a rectified image or accept the distortion's curvature over one marker
(small for a marker that covers a few percent of the picture). The mid level must be the
mid level of light: a gamma-encoded picture (most USB cameras send sRGB) is linearised
first with its ``gamma`` (2.2 for sRGB; the mock's pictures are linear, 1.0); read as linear,
an sRGB picture put the corners 0.6 px inward. The picture is 8-bit grey levels (0-255).
Units: pixels.
"""
from __future__ import annotations

import cv2
import numpy as np

__all__ = ["refine_corners_on_edges", "EDGE_MIN_CONTRAST"]

#: grey levels (linear, 0-255): a profile with less between its dark and light ends is not
#: used
EDGE_MIN_CONTRAST = 20.0
_STEP = 0.25          # px between the samples of one profile
_END_MARGIN = 0.2     # fraction of a side left out at each end (the corners' own blur)
_MAX_REACH = 4.0      # px: the profiles' half-length at most (a close-up marker's cost)
_MAX_PROFILES = 40    # per side at most
_LEVEL_BAND = 0.2     # of the marker's contrast: a profile's levels farther from the
                      # marker's median levels are not the marker's
_HUBER = 0.15         # px: the line fit's Huber constant (crossings scatter ~0.05 px; a
                      # stray profile, e.g. a dark object in the margin, is down-weighted)


def _bilinear(img: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``img`` sampled at the float pixel coordinates ``xy`` (...x2), bilinear, in float64
    (``cv2.remap`` rounds coordinates to 1/32 px: it moved every corner 0.023 px towards
    +x, +y at a 1 px blur), clamped to the image."""
    h, w = img.shape
    x = np.clip(xy[..., 0], 0.0, w - 1.0)
    y = np.clip(xy[..., 1], 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(int), w - 2)
    y0 = np.minimum(np.floor(y).astype(int), h - 2)
    fx, fy = x - x0, y - y0
    top = img[y0, x0] * (1.0 - fx) + img[y0, x0 + 1] * fx
    bottom = img[y0 + 1, x0] * (1.0 - fx) + img[y0 + 1, x0 + 1] * fx
    return top * (1.0 - fy) + bottom * fy


def _crossings(img: np.ndarray, origin: np.ndarray, base: np.ndarray, normal: np.ndarray,
               centre: np.ndarray, offsets: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(rows, s, dark, light): for each point of ``base`` (Nx2) whose profile along its ``normal`` (Nx2,
    centred at ``centre`` px along it) has enough contrast, the offset s (px along the
    normal) where the profile crosses the level half way between its dark (first) and light
    (last) sample, and those two levels."""
    pos = centre[:, None] + offsets[None, :]              # N x samples, px along the normal
    prof = _bilinear(img, base[:, None, :] + pos[..., None] * normal[:, None, :] - origin)
    dark, light = prof[:, 0], prof[:, -1]
    mid = 0.5 * (dark + light)
    above = prof >= mid[:, None]
    first = np.argmax(above, axis=1)     # the first sample at or above mid, from the dark end
    ok = ((light - dark) > EDGE_MIN_CONTRAST) & above.any(axis=1) & (first > 0)
    rows = np.nonzero(ok)[0]
    j = first[rows]
    lo, hi = prof[rows, j - 1], prof[rows, j]
    frac = (mid[rows] - lo) / np.maximum(hi - lo, 1e-6)
    return rows, pos[rows, j - 1] + frac * _STEP, dark[rows], light[rows]


def _line_through(points: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(point, unit direction) of the line fitted through ``points`` (Nx2), or None."""
    if len(points) < 3:
        return None
    vx, vy, x0, y0 = cv2.fitLine(points.astype(np.float32), cv2.DIST_HUBER, _HUBER, 0.01,
                                 0.01).reshape(-1)
    return np.array([x0, y0], float), np.array([vx, vy], float)


def _intersect(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]
               ) -> np.ndarray | None:
    (p, u), (q, v) = a, b
    m = np.column_stack([u, -v])
    if abs(np.linalg.det(m)) < 1e-6:
        return None
    s, _ = np.linalg.solve(m, q - p)
    return p + s * u


def refine_corners_on_edges(gray: np.ndarray, quad: np.ndarray, modules: int,
                            gamma: float = 1.0) -> np.ndarray | None:
    """The 4 corners (4x2 px, the order of ``quad``) of a dark square marker whose corners
    are roughly ``quad`` (e.g. from ``cv2.aruco``), as the intersections of its four outer
    edges; None if an edge cannot be measured (too little contrast, too few points) or a
    corner would move more than 5 % of the shortest side (0.5-1.5 px: the edge is not where
    ``quad`` says, e.g. occluded).

    ``gray``: HxW image (any numeric type); ``modules``: the marker's width in modules,
    black border included (a dictionary's ``markerSize + 2``), which bounds the profiles to
    the border and the margin; ``gamma``: the picture's encoding (grey level = 255
    (light / full)^(1/gamma)), 1.0 for a linear one."""
    quad = np.asarray(quad, float).reshape(4, 2)
    centre = quad.mean(axis=0)
    sides = np.linalg.norm(np.roll(quad, -1, axis=0) - quad, axis=1)
    module = float(sides.min()) / max(int(modules), 1)
    max_move = min(1.5, max(0.5, 0.05 * float(sides.min())))
    # the marker's neighbourhood only, as float (bilinear samples must not be rounded)
    h, w = np.shape(gray)[:2]
    x0, y0 = (max(0, int(v) - 4) for v in np.floor(quad.min(axis=0) - module))
    x1, y1 = (int(v) + 5 for v in np.ceil(quad.max(axis=0) + module))
    x1, y1 = min(w, x1), min(h, y1)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    img = np.asarray(gray[y0:y1, x0:x1], np.float64)
    if gamma != 1.0:
        img = 255.0 * (np.clip(img, 0.0, 255.0) / 255.0) ** float(gamma)   # linear light
    origin = np.array([x0, y0], float)
    # px: profile half-length: the dark and light levels are read half a module inside and
    # outside the edge, in the middle of the black border and of the margin, as far as can
    # be from the inner cells and the margin's far side (their blur moved the levels: read
    # at 0.8 module, the corners came out 0.08-0.1 px outward at the mock's 0.5 px blur)
    reach = max(0.75, min(0.5 * module, _MAX_REACH))
    offsets = np.arange(-reach, reach + 1e-9, _STEP)
    # every side's profiles at once: points along the side (away from the corners), each
    # with the side's outward normal (dark inside, light outside)
    bases, normals, side_of = [], [], []
    for i in range(4):
        a, b = quad[i], quad[(i + 1) % 4]
        length = float(np.linalg.norm(b - a))
        if length < 4.0:
            return None
        d = (b - a) / length
        n = np.array([-d[1], d[0]])
        if n @ (0.5 * (a + b) - centre) < 0:
            n = -n
        count = min(_MAX_PROFILES, max(4, int(length * (1.0 - 2 * _END_MARGIN))))
        t = np.linspace(_END_MARGIN, 1.0 - _END_MARGIN, count) * length
        bases.append(a + t[:, None] * d)
        normals.append(np.repeat(n[None, :], count, axis=0))
        side_of.append(np.full(count, i))
    base, normal, side = np.vstack(bases), np.vstack(normals), np.concatenate(side_of)
    # three passes, each reading the levels at +-reach from the crossing the one before
    # found (from a start 0.4 px off the edge they were 2.1 and 2.9 px from it: 0.03 px
    # of error at a 1 px blur; two passes left 0.03 px at 1.5 px)
    centre_s = np.zeros(len(base))
    rows = np.arange(len(base))
    for _pass in range(3):
        sub, found, dark, light = _crossings(img, origin, base[rows], normal[rows],
                                             centre_s[rows], offsets)
        rows = rows[sub]
        centre_s[rows] = found
        # a profile whose levels are not the marker's (a dark object in the margin, a glint
        # on the border) has its crossing moved: dropped. The median over all four sides:
        # one side's majority may be the intruded one
        if len(rows):
            d0, l0 = np.median(dark), np.median(light)
            band = _LEVEL_BAND * (l0 - d0)
            rows = rows[(np.abs(dark - d0) <= band) & (np.abs(light - l0) <= band)]
    points = base + centre_s[:, None] * normal
    lines = []
    for i in range(4):
        mine = rows[side[rows] == i]
        line = _line_through(points[mine])
        if line is None:           # fewer than 3 profiles with contrast on this side
            return None
        lines.append(line)
    out = np.empty((4, 2))
    for i in range(4):                          # corner i joins side i-1 and side i
        c = _intersect(lines[i - 1], lines[i])
        if c is None or np.linalg.norm(c - quad[i]) > max_move:
            return None
        out[i] = c
    return out
