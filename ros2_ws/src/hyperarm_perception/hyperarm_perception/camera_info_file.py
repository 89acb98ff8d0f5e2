"""The standard camera calibration file (no ROS): the YAML ROS' ``camera_calibration`` writes
and ``camera_info_manager`` reads.

Its fields: ``image_width``, ``image_height``, ``camera_name``, ``camera_matrix`` (3x3),
``distortion_model``, ``distortion_coefficients`` (1xN), ``rectification_matrix`` (3x3) and
``projection_matrix`` (3x4), each matrix as ``{rows, cols, data}`` in row-major order. The
file is checked with a JSON schema (jsonschema) and then for consistency (the matrix sizes,
a camera matrix, the number of coefficients the model takes); each problem raises
:class:`CameraInfoFileError` naming the file and the field. Units: pixels.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import yaml

from .markers import CameraModel, CameraModelError, PerceptionError, read_yaml_file

__all__ = ["CameraInfoFileError", "CameraCalibration", "parse_camera_info",
           "load_camera_info", "dump_camera_info", "COEFFICIENTS"]


class CameraInfoFileError(PerceptionError):
    """A camera calibration file that cannot be used (the message names the field)."""


#: distortion model -> the numbers of coefficients it takes (as CameraInfo.d)
COEFFICIENTS = {"plumb_bob": (5,), "rational_polynomial": (8,), "equidistant": (4,)}


def _matrix(rows: int | None, cols: int | None) -> dict:
    return {"type": "object", "required": ["rows", "cols", "data"],
            "additionalProperties": False,
            "properties": {"rows": {"type": "integer", "minimum": 1} if rows is None
                           else {"const": rows},
                           "cols": {"type": "integer", "minimum": 0} if cols is None
                           else {"const": cols},
                           "data": {"type": "array", "items": {"type": "number"}}}}


SCHEMA: dict[str, Any] = {
    "type": "object",
    "required": ["image_width", "image_height", "camera_matrix", "distortion_model",
                 "distortion_coefficients"],
    "additionalProperties": False,
    "properties": {
        "image_width": {"type": "integer", "minimum": 1},
        "image_height": {"type": "integer", "minimum": 1},
        "camera_name": {"type": "string"},
        "camera_matrix": _matrix(3, 3),
        "distortion_model": {"enum": sorted(COEFFICIENTS)},
        "distortion_coefficients": _matrix(1, None),
        "rectification_matrix": _matrix(3, 3),
        "projection_matrix": _matrix(3, 4),
    },
}


@dataclass(frozen=True)
class CameraCalibration:
    """One camera's calibration: ``K`` 3x3, ``D`` the coefficients of ``distortion_model``,
    ``R`` 3x3 (rectification; identity for a monocular camera), ``P`` 3x4 (projection), for
    images of ``width`` x ``height`` pixels."""

    camera_name: str
    width: int
    height: int
    K: np.ndarray
    D: np.ndarray
    distortion_model: str
    R: np.ndarray
    P: np.ndarray

    @classmethod
    def ideal(cls, K: np.ndarray, width: int, height: int,
              name: str = "camera") -> "CameraCalibration":
        """A distortion-free monocular camera of intrinsics ``K`` (px): R = I, P = [K | 0]
        (the mock's rendered camera)."""
        k = np.asarray(K, dtype=float).reshape(3, 3)
        return cls(name, int(width), int(height), k, np.zeros(5), "plumb_bob", np.eye(3),
                   np.c_[k, np.zeros(3)])

    def info_fields(self) -> dict[str, Any]:
        """sensor_msgs/CameraInfo's calibration fields (distortion_model, d, k, r, p) as
        plain values: ``for name, v in cal.info_fields().items(): setattr(info, name, v)``."""
        return {"distortion_model": self.distortion_model,
                "d": [float(x) for x in self.D.reshape(-1)],
                "k": [float(x) for x in self.K.reshape(-1)],
                "r": [float(x) for x in self.R.reshape(-1)],
                "p": [float(x) for x in self.P.reshape(-1)]}

    def camera_model(self) -> CameraModel:
        """The detector's pinhole model (OpenCV's distortion: plumb_bob or
        rational_polynomial)."""
        if self.distortion_model == "equidistant":
            raise CameraInfoFileError("distortion_model 'equidistant' (fisheye) is not a "
                                      "pinhole model the marker detector takes")
        return CameraModel(self.K, self.D, self.width, self.height)


def _data(raw: dict, where: str, n: int) -> np.ndarray:
    values = np.asarray(raw["data"], dtype=float)
    if values.size != n:
        raise CameraInfoFileError(f"{where}.data: {values.size} values for "
                                  f"{raw['rows']}x{raw['cols']} (expected {n})")
    if not np.all(np.isfinite(values)):
        raise CameraInfoFileError(f"{where}.data: must be finite")
    return values


def parse_camera_info(data: Any, source: str = "<data>") -> CameraCalibration:
    """A :class:`CameraCalibration` from a calibration file's parsed YAML."""
    errors = sorted(jsonschema.Draft202012Validator(SCHEMA).iter_errors(data),
                    key=lambda e: -len(e.absolute_path))
    if errors:
        err = errors[0]
        path = ".".join(str(p) for p in err.absolute_path) or "file"
        text = err.message.replace("is a required property", "is missing (required)")
        raise CameraInfoFileError(f"{source}: {path}: {text}")
    model = data["distortion_model"]
    dist = data["distortion_coefficients"]
    D = _data(dist, f"{source}: distortion_coefficients", dist["rows"] * dist["cols"])
    if D.size not in COEFFICIENTS[model]:
        raise CameraInfoFileError(f"{source}: distortion_coefficients: {model} takes "
                                  f"{' or '.join(map(str, COEFFICIENTS[model]))} "
                                  f"coefficients, got {D.size}")
    K = _data(data["camera_matrix"], f"{source}: camera_matrix", 9).reshape(3, 3)
    width, height = int(data["image_width"]), int(data["image_height"])
    try:
        CameraModel(K, np.zeros(0), width, height)
    except CameraModelError as exc:
        raise CameraInfoFileError(f"{source}: camera_matrix: {exc}") from None
    R = (_data(data["rectification_matrix"], f"{source}: rectification_matrix", 9)
         .reshape(3, 3) if "rectification_matrix" in data else np.eye(3))
    if "projection_matrix" in data:
        P = _data(data["projection_matrix"], f"{source}: projection_matrix", 12).reshape(3, 4)
    else:   # a monocular camera's: K beside a zero column
        P = np.hstack([K, np.zeros((3, 1))])
    return CameraCalibration(str(data.get("camera_name", "")), width, height, K, D, model,
                             R, P)


def load_camera_info(path: str | Path) -> CameraCalibration:
    """Read and check a calibration file."""
    path = Path(path)
    return parse_camera_info(read_yaml_file(path, CameraInfoFileError), path.name)


def dump_camera_info(cal: CameraCalibration) -> str:
    """The calibration as the YAML text ``camera_calibration`` writes."""
    def matrix(m: np.ndarray) -> dict:
        m = np.atleast_2d(m)
        return {"rows": int(m.shape[0]), "cols": int(m.shape[1]),
                "data": [float(x) for x in m.reshape(-1)]}

    return yaml.safe_dump({
        "image_width": cal.width, "image_height": cal.height, "camera_name": cal.camera_name,
        "camera_matrix": matrix(cal.K), "distortion_model": cal.distortion_model,
        "distortion_coefficients": matrix(cal.D.reshape(1, -1)),
        "rectification_matrix": matrix(cal.R), "projection_matrix": matrix(cal.P),
    }, sort_keys=False)
