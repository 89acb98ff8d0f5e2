"""Image / CameraInfo fields -> detector inputs: every encoding handled gives the same mono
image, row padding is skipped, and each bad kind raises its own error naming the field."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from hyperarm_perception.camera_input import camera_model, image_gray
from hyperarm_perception.markers import CameraModel, CameraModelError, ImageError

pytestmark = pytest.mark.core


def test_every_encoding_gives_the_same_mono_image():
    rng = np.random.default_rng(0)
    bgr = rng.integers(0, 256, (6, 5, 3), dtype=np.uint8)
    mono = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    cases = {"mono8": mono, "bgr8": bgr, "rgb8": bgr[:, :, ::-1],
             "bgra8": cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA),
             "rgba8": cv2.cvtColor(bgr, cv2.COLOR_BGR2RGBA)}
    for encoding, arr in cases.items():
        arr = np.ascontiguousarray(arr)
        ch = 1 if arr.ndim == 2 else arr.shape[2]
        out = image_gray(encoding, 6, 5, 5 * ch, arr.tobytes())
        np.testing.assert_array_equal(out, mono, err_msg=encoding)
        # rows padded to a step of 5 * ch + 3 bytes
        padded = np.zeros((6, 5 * ch + 3), np.uint8)
        padded[:, :5 * ch] = arr.reshape(6, -1)
        np.testing.assert_array_equal(image_gray(encoding, 6, 5, 5 * ch + 3,
                                                 padded.tobytes()), mono, err_msg=encoding)


@pytest.mark.parametrize("args, text", [
    (("16UC1", 4, 4, 8, bytes(32)), "encoding '16UC1' not handled"),
    (("mono8", 0, 4, 4, b""), "size 4x0 is empty"),
    (("bgr8", 4, 4, 8, bytes(32)), "step 8 bytes < width 4 x 3 channel(s)"),
    (("mono8", 4, 4, 4, bytes(10)), "data has 10 bytes, step x height needs 16"),
])
def test_bad_images(args, text):
    with pytest.raises(ImageError) as info:
        image_gray(*args)
    assert text in str(info.value)


def test_camera_info_to_model():
    K = [579.4, 0, 319.5, 0, 579.4, 239.5, 0, 0, 1]
    cam = camera_model(K, [0.1, -0.2, 0, 0, 0.05], "plumb_bob", 640, 480)
    assert isinstance(cam, CameraModel) and cam.K[0, 0] == 579.4 and cam.D.size == 5
    assert camera_model(K, [], "", 640, 480).D.size == 0


@pytest.mark.parametrize("args, text", [
    (([0.0] * 9, [], "plumb_bob", 640, 480), "k is all zeros (the camera is not calibrated)"),
    (([1.0] * 4, [], "plumb_bob", 640, 480), "k has 4 values, expected 9"),
    (([579.4, 0, 319.5, 0, 579.4, 239.5, 0, 0, 1], [0.1] * 4, "equidistant", 640, 480),
     "distortion_model 'equidistant' not handled"),
    (([579.4, 0, 319.5, 0, 579.4, 239.5, 0, 0, 1], [0.1] * 3, "plumb_bob", 640, 480),
     "0, 4, 5, 8, 12 or 14"),
    (([math.nan, 0, 319.5, 0, 579.4, 239.5, 0, 0, 1], [], "plumb_bob", 640, 480),
     "finite 3x3"),
])
def test_bad_camera_info(args, text):
    with pytest.raises(CameraModelError) as info:
        camera_model(*args)
    assert text in str(info.value)
