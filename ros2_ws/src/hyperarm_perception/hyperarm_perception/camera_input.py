"""sensor_msgs/Image and CameraInfo fields -> the detector's inputs (no ROS: plain values in).

:func:`image_gray` turns an Image's fields (encoding, height, width, step, data) into a mono
uint8 array, :func:`camera_model` a CameraInfo's (k, d, distortion_model, width, height)
into a :class:`CameraModel`. Each problem raises :class:`ImageError` or
:class:`CameraModelError` with a sentence naming the field, for a log line throttled per kind.
"""
from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from .markers import CameraModel, CameraModelError, ImageError

__all__ = ["ENCODINGS", "DISTORTION_MODELS", "image_gray", "camera_model"]

#: encoding -> (channels, cv2 conversion to mono or None)
ENCODINGS = {"mono8": (1, None), "bgr8": (3, cv2.COLOR_BGR2GRAY),
             "rgb8": (3, cv2.COLOR_RGB2GRAY), "bgra8": (4, cv2.COLOR_BGRA2GRAY),
             "rgba8": (4, cv2.COLOR_RGBA2GRAY)}
#: CameraInfo distortion models OpenCV's pinhole functions take as they are
DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "")


def image_gray(encoding: str, height: int, width: int, step: int, data) -> np.ndarray:
    """A HxW uint8 mono image from an Image's fields (``data``: bytes-like, ``step`` bytes
    per row, rows padded beyond width x channels allowed)."""
    if encoding not in ENCODINGS:
        raise ImageError(f"image: encoding {encoding!r} not handled (use one of "
                         f"{', '.join(ENCODINGS)})")
    channels, conversion = ENCODINGS[encoding]
    if height <= 0 or width <= 0:
        raise ImageError(f"image: size {width}x{height} is empty")
    if step < width * channels:
        raise ImageError(f"image: step {step} bytes < width {width} x {channels} channel(s)")
    buf = np.frombuffer(data, dtype=np.uint8)
    if buf.size < step * height:
        raise ImageError(f"image: data has {buf.size} bytes, step x height needs "
                         f"{step * height}")
    rows = buf[:step * height].reshape(height, step)[:, :width * channels]
    if conversion is None:
        return np.ascontiguousarray(rows)
    return cv2.cvtColor(rows.reshape(height, width, channels), conversion)


def camera_model(k: Sequence[float], d: Sequence[float], distortion_model: str, width: int,
                 height: int) -> CameraModel:
    """A :class:`CameraModel` from a CameraInfo's fields; refuses an uncalibrated one (K all
    zeros, as drivers publish without a calibration) and models OpenCV's pinhole functions
    do not take (e.g. ``equidistant``)."""
    if distortion_model not in DISTORTION_MODELS:
        raise CameraModelError(f"camera_info: distortion_model {distortion_model!r} not "
                               f"handled (use {', '.join(m for m in DISTORTION_MODELS if m)})")
    K = np.asarray(k, dtype=float)
    if K.size != 9:
        raise CameraModelError(f"camera_info: k has {K.size} values, expected 9")
    if not np.any(K):
        raise CameraModelError("camera_info: k is all zeros (the camera is not calibrated)")
    return CameraModel(K.reshape(3, 3), np.asarray(d, dtype=float), int(width), int(height))
