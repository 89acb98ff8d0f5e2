"""The marker detector core: ArUco/AprilTag markers on a numpy image -> object poses (no ROS).

Pipeline for one image (:meth:`MarkerDetector.detect`):

1. ``cv2.aruco.ArucoDetector`` finds the markers of the map's dictionary, with sub-pixel corner
   refinement (``CORNER_REFINE_SUBPIX``); with ``corner_refinement: edges`` (the default)
   the corners are then taken as the intersections of the marker's four outer edges
   (:mod:`hyperarm_perception.edges`: no inward bias on a blurred picture), falling back to
   the sub-pixel corners where an edge cannot be measured (counted: ``edge_fallbacks``).
2. Each marker whose id is in the :class:`MarkerMap` and whose shortest side is at least
   ``min_side_px`` pixels gets IPPE's two poses (``cv2.solvePnPGeneric(...,
   SOLVEPNP_IPPE_SQUARE)``, ordered by IPPE's own reprojection error), each refined by
   ``cv2.solvePnPRefineLM``; the first is the marker's pose. For an object the map lists
   as ``upright`` (it rests with its z axis up, as the block and the pegs on the table) and
   a detector given the camera's ``up`` direction, the solution whose object z axis is
   nearer to up (by more than 1 deg) comes first instead when the corners cannot tell the
   two apart (its RMS reprojection error larger by at most ``corner_sigma_px``; counted:
   ``upright_choices``): a small marker's two solutions fit nearly as well, and noise picked
   the tilted one in a few frames in 100. An object that really is tilted has a clearly
   better solution, kept.
3. It is rejected when it is seen at a grazing angle (its normal more than
   ``max_view_angle`` from the line of sight to its centre) or when its RMS corner
   reprojection error exceeds ``max_reprojection_px``.
4. The markers of one object give each an object pose (through the marker's offset from the
   object frame); when they disagree by more than ``agree_position`` / ``agree_angle`` the
   object is rejected (``disagreement``), else its pose is refined on all their corners at
   once.
5. The object's 6x6 pose covariance comes from the corner reprojection error (see
   :func:`pose_covariance`).
6. An ``upright`` object whose z axis is within ``upright_snap`` (10 deg) of up is turned
   upright about its markers' centre (counted: ``upright_snaps``): the centre is measured
   well, the tilt of a small or partly covered marker is not, and an origin far from its
   marker (a peg's top, 144 mm from its tile) moved 2.5 mm with every degree.

Frames: OpenCV's optical frame (x right, y down, z along the view) is where the PnP works;
:data:`T_LINK_OPTICAL` turns it into ``camera_link`` (the ROS body frame of the robot
description: x along the view, y left, z up), the frame of the project's ``Detections``.
Every rejection is counted per reason in :attr:`MarkerDetector.counts` and comes back with a
sentence naming the marker (:class:`Rejection`). Units: m, rad, pixels.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import cv2
import jsonschema
import numpy as np
import yaml

from hyperarm_description.model import DescriptionError, _rpy_matrix, parse_angle

from .edges import refine_corners_on_edges

__all__ = ["PerceptionError", "MarkerMapError", "CameraModelError", "ImageError",
           "MarkerSpec", "DetectorConfig", "MarkerMap", "CameraModel", "Detection",
           "Rejection", "FrameResult", "MarkerDetector", "load_marker_map",
           "parse_marker_map", "pose_covariance", "marker_corners", "T_LINK_OPTICAL",
           "REASONS", "rotation_angle", "default_marker_map_path", "aruco_detector",
           "up_in_camera_link"]


class PerceptionError(ValueError):
    """Root of every error of hyperarm_perception (bad configuration, camera or image)."""


class MarkerMapError(PerceptionError):
    """The marker map YAML is unreadable, violates the schema or is inconsistent (the
    message names the field)."""


class CameraModelError(PerceptionError):
    """Intrinsics that cannot be a pinhole camera (size, focal lengths, distortion)."""


class ImageError(PerceptionError):
    """An image the detector does not handle (dtype, channels, size, emptiness)."""


#: Every reason a marker (or an object) is rejected; the keys of MarkerDetector.counts.
REASONS = ("unknown_id", "too_small", "pose_failed", "grazing", "reprojection",
           "disagreement")

#: rad: an upright object's pose candidate nearer to up by more than this goes first (two
#: solutions that LM refined into one pose differ by far less; a flip, by 5-17 deg)
UPRIGHT_MARGIN = math.radians(1.0)

#: camera_link <- optical frame: optical z (view) = link x, optical x (right) = link -y,
#: optical y (down) = link -z (REP 103/105's camera_optical_frame, rpy -pi/2, 0, -pi/2).
T_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0],
                           [-1.0, 0.0, 0.0, 0.0],
                           [0.0, -1.0, 0.0, 0.0],
                           [0.0, 0.0, 0.0, 1.0]])
T_LINK_OPTICAL.flags.writeable = False

SCHEMA_VERSION = 1

_POSE_SCHEMA = {
    "type": "object", "additionalProperties": False,
    "properties": {"xyz": {"type": "array", "items": {"type": "number"},
                           "minItems": 3, "maxItems": 3},
                   "rpy": {"type": "array", "items": {"type": ["number", "string"]},
                           "minItems": 3, "maxItems": 3}},
}

MARKER_MAP_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "type": "object", "additionalProperties": False,
    "required": ["schema_version", "dictionary", "markers"],
    "properties": {
        "schema_version": {"type": "integer"},
        "dictionary": {"type": "string"},
        "markers": {"type": "array", "minItems": 1, "items": {
            "type": "object", "additionalProperties": False,
            "required": ["id", "object", "size"],
            "properties": {
                "id": {"type": "integer", "minimum": 0},
                "object": {"type": "string", "minLength": 1},
                "size": {"type": "number", "exclusiveMinimum": 0},
                "offset": _POSE_SCHEMA,
            }}},
        "upright": {"type": "array", "uniqueItems": True,
                    "items": {"type": "string", "minLength": 1}},
        "detection": {
            "type": "object", "additionalProperties": False,
            "properties": {
                "min_side_px": {"type": "number", "exclusiveMinimum": 0},
                "max_view_angle": {"type": ["number", "string"]},
                "max_reprojection_px": {"type": "number", "exclusiveMinimum": 0},
                "corner_sigma_px": {"type": "number", "exclusiveMinimum": 0},
                "agree_position": {"type": "number", "exclusiveMinimum": 0},
                "agree_angle": {"type": ["number", "string"]},
                "corner_refinement": {"enum": ["edges", "subpix"]},
                "gamma": {"type": "number", "minimum": 0.2, "maximum": 5.0},
                "upright_snap": {"type": ["number", "string"]},
            }},
    },
}


def marker_corners(size: float) -> np.ndarray:
    """4x3 corners (m) of a square marker of edge ``size`` in its own frame (z out of the
    printed face, x right, y up), in ArUco's order (top-left, top-right, bottom-right,
    bottom-left) = the order SOLVEPNP_IPPE_SQUARE requires."""
    h = 0.5 * size
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


@dataclass(frozen=True)
class MarkerSpec:
    """One printed marker: ``id`` in the dictionary, the ``object`` it is on, ``size`` (m,
    edge of the black square) and ``offset``: 4x4 pose of the marker frame in the object frame."""

    id: int
    object: str
    size: float
    offset: np.ndarray

    def corners_in_object(self) -> np.ndarray:
        """4x3 corners (m) in the object frame."""
        c = marker_corners(self.size)
        return c @ self.offset[:3, :3].T + self.offset[:3, 3]


@dataclass(frozen=True)
class DetectorConfig:
    """Rejection thresholds and the noise model.

    ``min_side_px``: shortest marker side (pixels) accepted; ``max_view_angle`` (rad): the
    largest angle between the marker's normal and the line of sight to its centre;
    ``max_reprojection_px``: the largest RMS corner reprojection error (pixels) after the
    refinement; ``corner_sigma_px``: the prior standard deviation of a corner coordinate
    (pixels) used by the covariance (a floor on the one estimated from the residuals);
    ``agree_position`` (m) / ``agree_angle`` (rad): how far two markers' poses of one object
    may differ; ``corner_refinement``: ``edges`` (intersections of the outer edges, see
    :mod:`hyperarm_perception.edges`) or ``subpix`` (OpenCV's ``CORNER_REFINE_SUBPIX`` alone);
    ``gamma``: the pictures' encoding, which the edges undo (1.0: linear, as the mock's; about
    2.2 for the sRGB of most USB cameras); ``upright_snap`` (rad): an ``upright`` object
    whose estimated z axis is within this of up is turned upright about its markers'
    centre (0: never; see :class:`MarkerDetector`)."""

    min_side_px: float = 20.0
    max_view_angle: float = math.radians(60.0)
    max_reprojection_px: float = 1.0
    corner_sigma_px: float = 0.2
    agree_position: float = 0.01
    agree_angle: float = math.radians(10.0)
    corner_refinement: str = "edges"
    gamma: float = 1.0
    upright_snap: float = math.radians(10.0)


@dataclass(frozen=True)
class MarkerMap:
    """The markers of one dictionary (an OpenCV ``cv2.aruco.DICT_*`` name) by id;
    ``upright``: the objects that rest with their z axis up (the detector's prior against
    a flipped single-marker pose, :class:`MarkerDetector`)."""

    dictionary: str
    markers: Mapping[int, MarkerSpec]
    config: DetectorConfig = field(default_factory=DetectorConfig)
    upright: frozenset[str] = frozenset()

    @property
    def objects(self) -> list[str]:
        return sorted({m.object for m in self.markers.values()})


def _angle(value: Any, where: str) -> float:
    out = parse_angle_or_fail(value, where)
    if not 0.0 < out <= math.pi:
        raise MarkerMapError(f"{where}: must be in (0, 180 deg], got {value!r}")
    return out


def _schema_path(err: jsonschema.ValidationError, data: Any) -> str:
    out = ""
    node = data
    for part in err.absolute_path:
        if isinstance(part, int):
            label = ""
            if isinstance(node, list) and isinstance(node[part], dict) and "id" in node[part]:
                label = f" (id {node[part]['id']})"
            out += f"[{part}]{label}"
        else:
            out += f".{part}" if out else str(part)
        try:
            node = node[part]
        except (KeyError, IndexError, TypeError):
            node = None
    return out or "file"


def parse_marker_map(data: Any, source: str = "<data>") -> MarkerMap:
    """A :class:`MarkerMap` from the YAML's data; :class:`MarkerMapError` naming ``source``
    and the field for a schema violation, an unknown dictionary, an id outside it, a
    duplicated id or a bad angle."""
    validator = jsonschema.Draft202012Validator(MARKER_MAP_SCHEMA)
    errors = sorted(validator.iter_errors(data), key=lambda e: -len(e.absolute_path))
    if errors:
        err = errors[0]
        if err.validator == "additionalProperties":
            extra = sorted(set(err.instance) - set(err.schema.get("properties", {})))
            text = (f"unknown field {', '.join(map(repr, extra))}; allowed: "
                    f"{', '.join(sorted(err.schema.get('properties', {})))}")
        else:
            text = err.message.replace("is a required property", "is missing (required)")
        raise MarkerMapError(f"{source}: {_schema_path(err, data)}: {text}")
    if data["schema_version"] != SCHEMA_VERSION:
        raise MarkerMapError(f"{source}: schema_version {data['schema_version']} is not "
                             f"supported (this version reads {SCHEMA_VERSION})")
    name = data["dictionary"]
    if not name.startswith("DICT_") or not isinstance(getattr(cv2.aruco, name, None), int):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise MarkerMapError(f"{source}: dictionary: unknown {name!r}; known: "
                             f"{', '.join(known)}")
    n_ids = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList.shape[0]
    markers: dict[int, MarkerSpec] = {}
    for i, raw in enumerate(data["markers"]):
        where = f"{source}: markers[{i}] (id {raw['id']})"
        mid = int(raw["id"])
        if mid >= n_ids:
            raise MarkerMapError(f"{where}.id: {name} has ids 0..{n_ids - 1}")
        if mid in markers:
            raise MarkerMapError(f"{where}.id: id {mid} is already used by "
                                 f"{markers[mid].object!r}")
        offset = np.eye(4)
        raw_offset = raw.get("offset", {})
        offset[:3, 3] = raw_offset.get("xyz", (0.0, 0.0, 0.0))
        rpy = [parse_angle_or_fail(a, f"{where}.offset.rpy[{k}]")
               for k, a in enumerate(raw_offset.get("rpy", (0.0, 0.0, 0.0)))]
        offset[:3, :3] = _rpy_matrix(rpy)
        if not np.all(np.isfinite(offset)):
            raise MarkerMapError(f"{where}.offset: must be finite")
        size = float(raw["size"])
        if not math.isfinite(size):
            raise MarkerMapError(f"{where}.size: must be finite")
        markers[mid] = MarkerSpec(mid, raw["object"], size, offset)
    det = data.get("detection", {})
    defaults = DetectorConfig()
    config = DetectorConfig(
        min_side_px=float(det.get("min_side_px", defaults.min_side_px)),
        max_view_angle=(_angle(det["max_view_angle"], f"{source}: detection.max_view_angle")
                        if "max_view_angle" in det else defaults.max_view_angle),
        max_reprojection_px=float(det.get("max_reprojection_px",
                                          defaults.max_reprojection_px)),
        corner_sigma_px=float(det.get("corner_sigma_px", defaults.corner_sigma_px)),
        agree_position=float(det.get("agree_position", defaults.agree_position)),
        agree_angle=(_angle(det["agree_angle"], f"{source}: detection.agree_angle")
                     if "agree_angle" in det else defaults.agree_angle),
        corner_refinement=str(det.get("corner_refinement", defaults.corner_refinement)),
        gamma=float(det.get("gamma", defaults.gamma)),
        upright_snap=(_snap_angle(det["upright_snap"], f"{source}: detection.upright_snap")
                      if "upright_snap" in det else defaults.upright_snap))
    objects = {m.object for m in markers.values()}
    for k, obj in enumerate(data.get("upright", [])):
        if obj not in objects:
            raise MarkerMapError(f"{source}: upright[{k}]: {obj!r} is not an object of the "
                                 f"map; objects: {', '.join(sorted(objects))}")
    return MarkerMap(name, markers, config, frozenset(data.get("upright", [])))


def _snap_angle(value: Any, where: str) -> float:
    out = parse_angle_or_fail(value, where)
    if not 0.0 <= out <= math.radians(45.0):
        raise MarkerMapError(f"{where}: must be in [0, 45 deg], got {value!r}")
    return out


def parse_angle_or_fail(value: Any, where: str) -> float:
    """``parse_angle`` (rad, ``"k*pi/n"``, ``"x deg"``) raising :class:`MarkerMapError`."""
    try:
        return parse_angle(value, where)
    except DescriptionError as exc:
        raise MarkerMapError(str(exc)) from None


def up_in_camera_link(camera_in_root: np.ndarray) -> np.ndarray:
    """The root frame's +z (up, for a root frame with z up as the robot's base_link and
    world) in ``camera_link``, from ``camera_link``'s 4x4 pose in the root frame."""
    return np.asarray(camera_in_root, dtype=float)[:3, :3].T @ np.array([0.0, 0.0, 1.0])


def default_marker_map_path() -> Path:
    """The packaged marker map (config/markers.yaml)."""
    return Path(__file__).resolve().parent / "config" / "markers.yaml"


def read_yaml_file(path: Path, error: type[PerceptionError]) -> Any:
    """The parsed YAML of ``path``; ``error`` (a :class:`PerceptionError` subclass) naming
    the file, and the line of a syntax error, if it cannot be read or parsed."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise error(f"{path.name}: cannot read: {exc.strerror or exc}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" line {mark.line + 1}" if mark is not None else ""
        raise error(f"{path.name}:{at}: not valid YAML: "
                    f"{getattr(exc, 'problem', None) or exc}") from None


def load_marker_map(path: str | Path | None = None) -> MarkerMap:
    """Read and check a marker map YAML (default: the packaged one)."""
    path = Path(path) if path is not None else default_marker_map_path()
    return parse_marker_map(read_yaml_file(path, MarkerMapError), path.name)


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera with OpenCV's distortion: ``K`` 3x3 (pixels), ``D`` the coefficients
    (plumb_bob: k1 k2 p1 p2 k3; empty for none), image ``width`` x ``height`` (pixels)."""

    K: np.ndarray
    D: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        D = np.asarray(self.D, dtype=float).reshape(-1)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise CameraModelError(f"K must be a finite 3x3 matrix, got {np.asarray(self.K)!r}")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or K[2, 2] != 1.0 or np.any(K[1:, 0]) or K[2, 1]:
            raise CameraModelError(f"K is not a camera matrix (fx, fy > 0, last row 0 0 1): "
                                   f"{K.tolist()}")
        if D.size not in (0, 4, 5, 8, 12, 14) or not np.all(np.isfinite(D)):
            raise CameraModelError(f"D: expected 0, 4, 5, 8, 12 or 14 finite coefficients, "
                                   f"got {D.tolist()}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CameraModelError(f"image size must be positive, got {self.width}x"
                                   f"{self.height}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "D", D)

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy: float) -> "CameraModel":
        """An ideal camera (square pixels, centred principal point, no distortion) with a
        vertical field of view ``fovy`` (rad), like the description's camera."""
        if not 0.0 < fovy < math.pi:
            raise CameraModelError(f"fovy must be in (0, pi), got {fovy}")
        f = 0.5 * height / math.tan(0.5 * fovy)
        K = np.array([[f, 0.0, 0.5 * (width - 1)], [0.0, f, 0.5 * (height - 1)],
                      [0.0, 0.0, 1.0]])
        return cls(K, np.zeros(0), width, height)


@dataclass(frozen=True)
class Rejection:
    """A marker (or an object: ``marker_id`` None) left out: ``reason`` (one of
    :data:`REASONS`) and ``text``, a sentence naming it and the measured value."""

    reason: str
    marker_id: int | None
    object: str | None
    text: str


@dataclass(frozen=True)
class Detection:
    """An object seen: ``pose`` 4x4 of the object frame in camera_link (m),
    ``covariance`` 6x6 in camera_link (x, y, z in m, then rotations about camera_link's x, y, z
    in rad: ROS' PoseWithCovariance order; the rotation error is the left perturbation
    R = exp([dtheta]x) R_est), ``pose_optical`` the same pose in the optical frame,
    ``marker_ids`` used and ``rms_px`` their RMS corner reprojection error (pixels)."""

    object: str
    pose: np.ndarray
    covariance: np.ndarray
    pose_optical: np.ndarray
    marker_ids: tuple[int, ...]
    rms_px: float


@dataclass(frozen=True)
class FrameResult:
    """One image's :class:`Detection` s (one per object) and :class:`Rejection` s."""

    detections: list[Detection]
    rejections: list[Rejection]


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotation_angle(R: np.ndarray) -> float:
    """Angle (rad) of the rotation matrix ``R``."""
    return float(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))))


def _pose_matrix(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=float).reshape(3))[0]
    T[:3, 3] = np.asarray(tvec, dtype=float).reshape(3)
    return T


def _rms_px(obj: np.ndarray, img: np.ndarray, T: np.ndarray, cam: CameraModel) -> float:
    """RMS corner reprojection error (pixels, over both coordinates of each corner) of the
    pose T."""
    res, _ = _residuals(obj, img, T, cam)
    return float(np.sqrt(np.mean(res ** 2) * 2.0))


def _residuals(obj: np.ndarray, img: np.ndarray, T: np.ndarray, cam: CameraModel
               ) -> tuple[np.ndarray, np.ndarray]:
    """Reprojection residuals (2N, pixels) of the pose T (optical <- points' frame) and the
    Jacobian (2N x 6) of the projections w.r.t. the perturbation (dt, dtheta):
    R' = exp([dtheta]x) R, t' = t + dt, both in the optical frame."""
    rvec = cv2.Rodrigues(T[:3, :3])[0]
    proj, jac = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, T[:3, 3].reshape(3, 1),
                                  cam.K, cam.D)
    res = (proj.reshape(-1, 2) - img.reshape(-1, 2)).reshape(-1)
    # projectPoints' columns 3..5 are d(u, v)/d(tvec) = d(u, v)/dX for X = R P + t; the
    # rotation perturbation moves X by dtheta x (R P) = -[R P]x dtheta.
    j_t = jac[:, 3:6]
    rp = obj @ T[:3, :3].T
    j_r = np.vstack([j_t[2 * i:2 * i + 2] @ -_skew(rp[i]) for i in range(len(obj))])
    return res, np.hstack([j_t, j_r])


def pose_covariance(obj: np.ndarray, img: np.ndarray, T: np.ndarray, cam: CameraModel,
                    sigma_px: float) -> np.ndarray:
    """6x6 covariance of the pose ``T`` (optical frame <- points' frame) fitted to the N
    corners ``img`` (Nx2, pixels) of the points ``obj`` (Nx3, m).

    Model: each corner coordinate has independent Gaussian noise of standard deviation
    sigma (pixels); the least-squares pose then has, to first order, the covariance
    sigma^2 (J^T J)^-1, with J (2N x 6) the Jacobian of the projections w.r.t. the pose
    perturbation (dt [m], dtheta [rad]) about T (t' = t + dt, R' = exp([dtheta]x) R, both
    in the optical frame), built from ``cv2.projectPoints``' jacobian output (its d/dtvec
    block is d(u,v)/dX). sigma is the larger of ``sigma_px`` (the prior) and the residuals'
    estimate sqrt(RSS / (2N - 6)) when 2N > 6, so that a fit worse than the prior widens
    the covariance. Returns (dt, dtheta) order: m^2, m rad, rad^2."""
    res, J = _residuals(obj, img, T, cam)
    dof = res.size - 6
    sigma2 = float(sigma_px) ** 2
    if dof > 0:
        sigma2 = max(sigma2, float(res @ res) / dof)
    info = J.T @ J
    return sigma2 * np.linalg.inv(info)


def _gray(image: Any, cam: CameraModel) -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise ImageError(f"image: expected a numpy array, got {type(image).__name__}")
    if image.size == 0:
        raise ImageError("image: empty")
    if image.dtype != np.uint8:
        raise ImageError(f"image: dtype {image.dtype} not handled (uint8 mono8/bgr8/rgb8)")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] == 3:
        # BGR or RGB: the marker's black/white contrast is the same in either weighting
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    elif image.ndim != 2:
        raise ImageError(f"image: shape {image.shape} not handled (HxW or HxWx3)")
    if image.shape != (cam.height, cam.width):
        raise ImageError(f"image: {image.shape[1]}x{image.shape[0]} pixels, the camera "
                         f"model says {cam.width}x{cam.height}")
    return image


def aruco_detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    """OpenCV's marker finder for ``dictionary`` (a ``cv2.aruco.DICT_*`` name) with the
    detector's sub-pixel corner refinement."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    # a 5x5 window at most (OpenCV's default relative size 0.3 of a module shrinks it
    # to 3x3 on small markers, which left 0.4 px RMS corner errors on synthetic images;
    # a larger window reaches the inner cells' and the margin's edges: also worse)
    params.cornerRefinementWinSize = 2
    params.relativeCornerRefinmentWinSize = 1.0
    params.cornerRefinementMaxIterations = 50
    params.cornerRefinementMinAccuracy = 0.01
    return cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)), params)


class MarkerDetector:
    """Detects the markers of a :class:`MarkerMap` in images of a :class:`CameraModel`.

    :attr:`counts` holds the number of rejections per reason (:data:`REASONS`) and
    ``frames`` / ``detections`` / ``edge_fallbacks`` / ``upright_choices`` since
    construction (for diagnostics). ``up``: the direction opposite to gravity in
    ``camera_link`` (3 values, any length; e.g. from the description's camera extrinsics:
    :func:`up_in_camera_link`), for the map's ``upright`` objects; None: no such prior."""

    def __init__(self, marker_map: MarkerMap, camera: CameraModel,
                 up: np.ndarray | None = None) -> None:
        self.map = marker_map
        self.camera = camera
        self._up: np.ndarray | None = None
        if up is not None:
            u = np.asarray(up, dtype=float).reshape(-1)
            n = float(np.linalg.norm(u)) if u.shape == (3,) else float("nan")
            if not (math.isfinite(n) and n > 1e-9):
                raise PerceptionError(f"up must be 3 finite values, not all 0, got {up!r}")
            self._up = T_LINK_OPTICAL[:3, :3].T @ (u / n)     # in the optical frame
        self._aruco = aruco_detector(marker_map.dictionary)
        # the marker's width in modules, black border included (the edges' profiles stay
        # within the border and the margin)
        self._modules = int(self._aruco.getDictionary().markerSize) + 2
        self.counts: dict[str, int] = {r: 0 for r in REASONS}
        self.counts.update(frames=0, detections=0, edge_fallbacks=0, upright_choices=0,
                           upright_snaps=0)

    def set_camera(self, camera: CameraModel) -> None:
        """Use new intrinsics (e.g. a changed CameraInfo) from the next image on."""
        self.camera = camera

    def _reject(self, out: list[Rejection], reason: str, marker_id: int | None,
                obj: str | None, text: str) -> None:
        self.counts[reason] += 1
        out.append(Rejection(reason, marker_id, obj, text))

    def _marker_pose(self, spec: MarkerSpec, img: np.ndarray) -> np.ndarray | None:
        poses = self._marker_poses(spec, img)
        return poses[0] if poses else None

    def _marker_poses(self, spec: MarkerSpec, img: np.ndarray) -> list[np.ndarray]:
        """IPPE's solutions for one marker (at most two, each refined by LM), the one with
        the smaller reprojection error first; only those in front of the camera. On a small
        marker the two are close in error and noise can put the wrong one first (a tilt
        flipped by 5-16 degrees): an object of several markers then takes, for each, the
        one that agrees with the others (:meth:`_object`)."""
        obj = marker_corners(spec.size)
        cam = self.camera
        n, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img.reshape(-1, 1, 2), cam.K, cam.D,
                                                    flags=cv2.SOLVEPNP_IPPE_SQUARE)
        out = []
        for k in np.argsort(np.asarray(errs).reshape(-1))[:n]:
            rvec, tvec = cv2.solvePnPRefineLM(obj, img.reshape(-1, 1, 2), cam.K, cam.D,
                                              rvecs[k].copy(), tvecs[k].copy())
            T = _pose_matrix(rvec, tvec)
            if np.all(np.isfinite(T)) and T[2, 3] > 0:
                out.append(T)
        return out

    def _upright_first(self, spec: MarkerSpec, img: np.ndarray,
                       candidates: list[np.ndarray]) -> list[np.ndarray]:
        """``candidates`` with the one whose object z axis is nearest to up first, if it is
        nearer by more than :data:`UPRIGHT_MARGIN` and the corners cannot tell the two
        apart: its RMS reprojection error within ``max_reprojection_px`` and larger than
        the first's by at most ``corner_sigma_px`` (the corners' noise)."""
        inv = np.linalg.inv(spec.offset)
        tilts = [float(np.arccos(np.clip((T @ inv)[:3, 2] @ self._up, -1.0, 1.0)))
                 for T in candidates]
        k = int(np.argmin(tilts))
        if k == 0 or tilts[k] > tilts[0] - UPRIGHT_MARGIN:   # the same pose, refined twice
            return candidates
        rms = [_rms_px(marker_corners(spec.size), img, T, self.camera)
               for T in (candidates[0], candidates[k])]
        cfg = self.map.config
        if rms[1] > cfg.max_reprojection_px or rms[1] > rms[0] + cfg.corner_sigma_px:
            return candidates     # the corners tell them apart: the object is tilted
        self.counts["upright_choices"] += 1
        return [candidates[k], *candidates[:k], *candidates[k + 1:]]

    def _snap_upright(self, T: np.ndarray, specs: list[MarkerSpec]) -> np.ndarray:
        """An upright object's pose ``T`` (optical frame) turned so that its z axis is up,
        about its markers' centre (measured well; the tilt of a small or partly covered
        marker is not, and a marker 144 mm from the object's origin moves the origin 2.5 mm
        per degree), if its z axis is within ``upright_snap`` of up; else ``T``."""
        z = T[:3, 2]
        tilt = math.acos(max(-1.0, min(1.0, float(z @ self._up))))
        if tilt > self.map.config.upright_snap:
            return T
        self.counts["upright_snaps"] += 1
        if tilt < 1e-12:
            return T
        axis = np.cross(z, self._up)
        turn = cv2.Rodrigues((axis / np.linalg.norm(axis) * tilt).reshape(3, 1))[0]
        centre = np.mean([spec.offset[:3, 3] for spec in specs], axis=0)   # object frame
        out = T.copy()
        out[:3, :3] = turn @ T[:3, :3]
        out[:3, 3] = T[:3, :3] @ centre + T[:3, 3] - out[:3, :3] @ centre
        return out

    def detect(self, image: np.ndarray) -> FrameResult:
        """Detections and rejections of one image (uint8, HxW mono or HxWx3 colour, the
        camera model's size); :class:`ImageError` for an image it does not handle."""
        gray = _gray(image, self.camera)
        self.counts["frames"] += 1
        corners, ids, _ = self._aruco.detectMarkers(gray)
        cfg = self.map.config
        rejections: list[Rejection] = []
        # object -> [(spec, image corners 4x2, the marker's pose candidates in the optical
        # frame (the better first), rms)]
        seen: dict[str, list[tuple[MarkerSpec, np.ndarray, list[np.ndarray], float]]] = {}
        for quad, mid in zip(corners, ids.reshape(-1) if ids is not None else []):
            mid = int(mid)
            img = quad.reshape(4, 2).astype(float)
            spec = self.map.markers.get(mid)
            if spec is None:
                self._reject(rejections, "unknown_id", mid, None,
                             f"marker {mid} ({self.map.dictionary}) is not in the marker map")
                continue
            side = float(min(np.linalg.norm(img - np.roll(img, -1, axis=0), axis=1)))
            if side < cfg.min_side_px:
                self._reject(rejections, "too_small", mid, spec.object,
                             f"marker {mid} ({spec.object}): shortest side {side:.1f} px < "
                             f"min_side_px {cfg.min_side_px:g}")
                continue
            if cfg.corner_refinement == "edges":
                on_edges = refine_corners_on_edges(gray, img, self._modules, cfg.gamma)
                if on_edges is None:
                    self.counts["edge_fallbacks"] += 1
                else:
                    img = on_edges
            candidates = self._marker_poses(spec, img)
            if not candidates:
                self._reject(rejections, "pose_failed", mid, spec.object,
                             f"marker {mid} ({spec.object}): no pose in front of the camera")
                continue
            if self._up is not None and spec.object in self.map.upright:
                candidates = self._upright_first(spec, img, candidates)
            T = candidates[0]
            sight = T[:3, 3] / np.linalg.norm(T[:3, 3])
            view = math.acos(max(-1.0, min(1.0, float(-T[:3, 2] @ sight))))
            if view > cfg.max_view_angle:
                self._reject(rejections, "grazing", mid, spec.object,
                             f"marker {mid} ({spec.object}): seen at {math.degrees(view):.1f}"
                             f" deg from its normal > max_view_angle "
                             f"{math.degrees(cfg.max_view_angle):.1f} deg")
                continue
            rms = _rms_px(marker_corners(spec.size), img, T, self.camera)
            if rms > cfg.max_reprojection_px:
                self._reject(rejections, "reprojection", mid, spec.object,
                             f"marker {mid} ({spec.object}): RMS corner reprojection error "
                             f"{rms:.2f} px > max_reprojection_px {cfg.max_reprojection_px:g}")
                continue
            seen.setdefault(spec.object, []).append((spec, img, candidates, rms))
        detections = []
        for name in sorted(seen):
            det = self._object(name, seen[name], rejections)
            if det is not None:
                detections.append(det)
        self.counts["detections"] += len(detections)
        return FrameResult(detections, rejections)

    def _object(self, name: str, markers: list, rejections: list[Rejection]
                ) -> Detection | None:
        cfg = self.map.config
        markers = sorted(markers, key=lambda m: m[0].id)
        ids = [spec.id for spec, *_ in markers]
        # each marker's candidates as object poses; for each candidate of each marker in
        # turn (the first marker's first), every other marker takes its candidate nearest
        # in orientation, and the set must agree with it (a flipped small marker then does
        # not reject a good object, whichever marker it is)
        cands = [[T @ np.linalg.inv(spec.offset) for T in ts] for spec, _, ts, _ in markers]
        poses, failure = None, None
        for r, ref in ((r, ref) for r in range(len(cands)) for ref in cands[r]):
            pick = [ref if k == r else
                    min(c, key=lambda P: rotation_angle(P[:3, :3] @ ref[:3, :3].T))
                    for k, c in enumerate(cands)]
            for i in range(len(pick)):
                dp = float(np.linalg.norm(pick[i][:3, 3] - ref[:3, 3]))
                da = rotation_angle(pick[i][:3, :3] @ ref[:3, :3].T)
                if dp > cfg.agree_position or da > cfg.agree_angle:
                    failure = failure or (r, i, dp, da)
                    break
            else:
                poses = pick
                break
        if poses is None:
            r, i, dp, da = failure
            self._reject(rejections, "disagreement", None, name,
                         f"{name}: markers {ids[r]} and {ids[i]} disagree by "
                         f"{dp * 1000:.1f} mm / {math.degrees(da):.1f} deg (limits "
                         f"{cfg.agree_position * 1000:g} mm / "
                         f"{math.degrees(cfg.agree_angle):g} deg)")
            return None
        obj = np.vstack([spec.corners_in_object() for spec, *_ in markers])
        img = np.vstack([m[1] for m in markers])
        best = int(np.argmin([m[3] for m in markers]))
        T = poses[best]
        if len(markers) > 1:  # one pose from all the object's corners
            rvec, tvec = cv2.solvePnPRefineLM(obj, img.reshape(-1, 1, 2), self.camera.K,
                                              self.camera.D, cv2.Rodrigues(T[:3, :3])[0],
                                              T[:3, 3].reshape(3, 1).copy())
            T = _pose_matrix(rvec, tvec)
        rms = _rms_px(obj, img, T, self.camera)
        cov_opt = pose_covariance(obj, img, T, self.camera, cfg.corner_sigma_px)
        if self._up is not None and name in self.map.upright and cfg.upright_snap > 0.0:
            T = self._snap_upright(T, [spec for spec, *_ in markers])
        rot = np.zeros((6, 6))
        rot[:3, :3] = rot[3:, 3:] = T_LINK_OPTICAL[:3, :3]
        return Detection(name, T_LINK_OPTICAL @ T, rot @ cov_opt @ rot.T, T,
                         tuple(spec.id for spec, *_ in markers), rms)
