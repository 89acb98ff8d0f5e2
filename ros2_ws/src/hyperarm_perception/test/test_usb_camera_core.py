"""Core tier (no ROS): the standard calibration file (camera_info_file) and frame capture
through OpenCV's VideoCapture (capture), on image sequences written to disk."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import yaml

from hyperarm_perception.camera_info_file import (CameraCalibration, CameraInfoFileError,
                                                  dump_camera_info, load_camera_info,
                                                  parse_camera_info)
from hyperarm_perception.capture import CaptureConfig, CaptureError, FrameSource
from hyperarm_perception.markers import CameraModel

pytestmark = pytest.mark.core

#: a file as ROS' camera_calibration writes it (ost.yaml of a 640x480 USB camera)
OST = """\
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [ 597.96,    0.  ,  312.95,
            0.  ,  598.61,  243.52,
            0.  ,    0.  ,    1.  ]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.096, -0.235, 0.0021, -0.0009, 0.000000]
rectification_matrix:
  rows: 3
  cols: 3
  data: [ 1.,  0.,  0.,
          0.,  1.,  0.,
          0.,  0.,  1.]
projection_matrix:
  rows: 3
  cols: 4
  data: [ 603.18,    0.  ,  312.21,    0.  ,
            0.  ,  606.35,  243.88,    0.  ,
            0.  ,    0.  ,    1.  ,    0.  ]
"""


def test_camera_calibrations_file_is_read_as_written():
    cal = parse_camera_info(yaml.safe_load(OST), "ost.yaml")
    assert (cal.width, cal.height, cal.camera_name) == (640, 480, "narrow_stereo")
    assert cal.K[0, 0] == 597.96 and cal.K[1, 2] == 243.52 and cal.K[2, 2] == 1.0
    assert cal.D.tolist() == [0.096, -0.235, 0.0021, -0.0009, 0.0]
    assert cal.P[0, 0] == 603.18 and cal.P.shape == (3, 4)
    model = cal.camera_model()
    assert isinstance(model, CameraModel) and model.width == 640


def test_camera_info_fields_of_a_file_and_of_an_ideal_camera():
    """The CameraInfo fields usb_camera (a calibration file) and mock_camera (an ideal
    pinhole) publish: K, R, P row-major, D as given; the ideal camera has D = 0, R = I and
    P = [K | 0]."""
    k = np.array([[600.0, 0.0, 320.5], [0.0, 601.0, 240.5], [0.0, 0.0, 1.0]])
    ideal = CameraCalibration.ideal(k, 640, 480, "mock")
    f = ideal.info_fields()
    assert f["distortion_model"] == "plumb_bob" and f["d"] == [0.0] * 5
    assert f["k"] == k.reshape(-1).tolist()
    assert f["r"] == np.eye(3).reshape(-1).tolist()
    assert f["p"] == [600.0, 0.0, 320.5, 0.0, 0.0, 601.0, 240.5, 0.0, 0.0, 0.0, 1.0, 0.0]
    assert (ideal.width, ideal.height) == (640, 480)
    g = parse_camera_info(yaml.safe_load(OST), "ost.yaml").info_fields()
    assert g["d"] == [0.096, -0.235, 0.0021, -0.0009, 0.0]
    assert g["p"][:3] == [603.18, 0.0, 312.21] and len(g["p"]) == 12
    assert g["k"][0] == 597.96 and g["distortion_model"] == "plumb_bob"


def test_dump_and_load_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    for _ in range(5):
        K = np.array([[rng.uniform(300, 900), 0, rng.uniform(300, 340)],
                      [0, rng.uniform(300, 900), rng.uniform(220, 260)], [0, 0, 1]])
        model = "rational_polynomial" if rng.random() < 0.5 else "plumb_bob"
        D = rng.normal(0, 0.1, 8 if model == "rational_polynomial" else 5)
        cal = CameraCalibration("cam", 640, 480, K, D, model, np.eye(3),
                                np.hstack([K, np.zeros((3, 1))]))
        path = tmp_path / "cal.yaml"
        path.write_text(dump_camera_info(cal))
        back = load_camera_info(path)
        assert back.distortion_model == model
        for a, b in ((back.K, K), (back.D, D), (back.R, cal.R), (back.P, cal.P)):
            assert np.array_equal(a, b)


@pytest.mark.parametrize("edit,field", [
    (lambda d: d.pop("camera_matrix"), "camera_matrix' is missing"),
    (lambda d: d["camera_matrix"].update(data=[1.0] * 8), "camera_matrix.data: 8 values"),
    (lambda d: d["camera_matrix"].update(rows=2), "camera_matrix.rows"),
    (lambda d: d.update(distortion_model="fisheye"), "distortion_model"),
    (lambda d: d["distortion_coefficients"].update(cols=4, data=[0.0] * 4),
     "distortion_coefficients: plumb_bob takes 5"),
    (lambda d: d["camera_matrix"].update(data=[0.0] * 9), "camera_matrix: K is not"),
    (lambda d: d.update(image_width=0), "image_width"),
    (lambda d: d.update(focal=1.0), "focal"),
    (lambda d: d["projection_matrix"].update(data=[float("nan")] * 12),
     "projection_matrix.data: must be finite"),
])
def test_each_bad_field_is_named(edit, field):
    data = yaml.safe_load(OST)
    edit(data)
    with pytest.raises(CameraInfoFileError, match=r"ost\.yaml: ") as err:
        parse_camera_info(data, "ost.yaml")
    assert field in str(err.value)


def test_unreadable_and_invalid_files(tmp_path):
    with pytest.raises(CameraInfoFileError, match="cannot read"):
        load_camera_info(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("image_width: [640\n")
    with pytest.raises(CameraInfoFileError, match="bad.yaml: line .*not valid YAML"):
        load_camera_info(bad)
    fish = yaml.safe_load(OST)
    fish.update(distortion_model="equidistant")
    fish["distortion_coefficients"].update(cols=4, data=[0.0] * 4)
    with pytest.raises(CameraInfoFileError, match="equidistant"):
        parse_camera_info(fish).camera_model()


def _sequence(tmp_path, n: int, size=(64, 48)) -> str:
    folder = tmp_path / "frames"
    folder.mkdir(exist_ok=True)
    for i in range(n):
        img = np.full((size[1], size[0], 3), 10 * i, np.uint8)   # frame i: grey 10 i
        cv2.imwrite(str(folder / f"{i:03d}.png"), img)
    return str(folder / "%03d.png")


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_a_sequence_is_read_in_order_then_ends(tmp_path):
    src = FrameSource(CaptureConfig(_sequence(tmp_path, 4), width=64, height=48))
    grey = []
    for _ in range(10):
        frame = src.read()
        if frame is None:
            break
        grey.append(int(frame[0, 0, 0]))
    assert grey == [0, 10, 20, 30]
    assert src.state == "ended" and "end of the recording" in src.problem
    assert src.read() is None and src.counts["frames"] == 4


def test_a_looped_sequence_starts_again(tmp_path):
    src = FrameSource(CaptureConfig(_sequence(tmp_path, 3), loop=True, width=0, height=0))
    grey = [int(src.read()[0, 0, 0]) for _ in range(7)]
    assert grey == [0, 10, 20, 0, 10, 20, 0]


def test_a_missing_camera_is_retried_each_period_and_opened_once_there(tmp_path):
    clock = _Clock()
    pattern = str(tmp_path / "frames" / "%03d.png")
    src = FrameSource(CaptureConfig(pattern, reopen_period=0.5), clock=clock)
    assert src.read() is None and src.state == "closed"
    assert "cannot open" in src.problem and src.counts["open_failures"] == 1
    for _ in range(3):                  # within the period: no new attempt
        clock.t += 0.1
        assert src.read() is None
    assert src.counts["open_failures"] == 1
    clock.t += 0.3
    assert src.read() is None and src.counts["open_failures"] == 2
    _sequence(tmp_path, 2)              # the camera appears
    clock.t += 0.5
    frame = src.read()
    assert frame is not None and src.state == "open" and src.problem == ""
    assert src.counts["reopened"] == 0   # the first opening is not a reopening


def test_a_camera_that_stops_delivering_is_lost_and_reopened(tmp_path):
    """A source that opens but yields nothing (an unreadable file: what a stalled device
    looks like to VideoCapture) is closed, counted and reopened after the period."""
    clock = _Clock()
    (tmp_path / "broken.png").write_bytes(b"not a png")
    src = FrameSource(CaptureConfig(str(tmp_path / "broken.png"), reopen_period=1.0),
                      clock=clock)
    assert src.read() is None
    assert src.state == "closed"
    fails = src.counts["read_failures"] + src.counts["open_failures"]
    assert fails == 1
    clock.t += 0.5
    assert src.read() is None
    assert src.counts["read_failures"] + src.counts["open_failures"] == 1
    clock.t += 0.6
    assert src.read() is None
    assert src.counts["read_failures"] + src.counts["open_failures"] == 2


def test_size_mismatch_is_a_sentence(tmp_path):
    src = FrameSource(CaptureConfig(_sequence(tmp_path, 1, size=(64, 48)), width=640,
                                    height=480))
    frame = src.read()
    assert src.size_mismatch(frame) == (f"{src.config.source} delivers 64x48, not the "
                                        "requested 640x480")
    src2 = FrameSource(CaptureConfig(src.config.source, width=64, height=48))
    assert src2.size_mismatch(frame) == ""


@pytest.mark.parametrize("kwargs,field", [
    ({"source": ""}, "device"), ({"width": -1}, "width"), ({"fps": math.nan}, "fps"),
    ({"pixel_format": "H264"}, "pixel_format"), ({"reopen_period": 0.0}, "reopen_period")])
def test_bad_capture_settings_name_the_parameter(kwargs, field):
    with pytest.raises(CaptureError, match=field):
        CaptureConfig(**kwargs)
