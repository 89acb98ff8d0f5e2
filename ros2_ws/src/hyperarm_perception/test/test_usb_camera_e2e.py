"""e2e: the installed usb_camera replays an image sequence (OpenCV's VideoCapture, as it
opens a device) with a calibration file as camera_calibration writes it; the installed
marker_detector turns its images into the block's pose. A camera that is missing at the
start is said in the diagnostics (error) and opened once it is there; a calibration for
another image size is an error and CameraInfo says uncalibrated; SIGTERM ends it with 0."""
from __future__ import annotations

import math
import signal

import cv2
import numpy as np
import pytest

from hyperarm_perception.camera_info_file import CameraCalibration, dump_camera_info
from hyperarm_perception.markers import (T_LINK_OPTICAL, CameraModel, load_marker_map,
                                         rotation_angle)
from hyperarm_perception.synthetic import MarkerPlacement, look_at_pose, render

pytestmark = [pytest.mark.e2e]

CAM = CameraModel.from_fovy(640, 480, math.radians(45.0))


def _calibration(tmp_path, cam: CameraModel):
    cal = CameraCalibration("test", cam.width, cam.height, cam.K, np.zeros(5), "plumb_bob",
                            np.eye(3), np.hstack([cam.K, np.zeros((3, 1))]))
    path = tmp_path / "camera_info.yaml"
    path.write_text(dump_camera_info(cal))
    return path


def _frames(folder, marker: np.ndarray, n: int = 5) -> None:
    mm = load_marker_map()
    rng = np.random.default_rng(7)
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        img = render(CAM, mm.dictionary, [MarkerPlacement(0, mm.markers[0].size, marker)],
                     rng=rng)
        cv2.imwrite(str(folder / f"{i:04d}.png"), img)


def _probe(rclpy_context, executor):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo

    from hyperarm_description import contract
    from hyperarm_description.qos import qos_for
    from hyperarm_interfaces.msg import Detections

    probe = rclpy.create_node("usb_camera_probe", namespace=contract.DEFAULT_NAMESPACE,
                              context=rclpy_context)
    executor.add_node(probe)
    got = {"det": [], "info": [], "diag": []}
    probe.create_subscription(Detections, contract.DETECTIONS, got["det"].append,
                              qos_for(contract.DETECTIONS))
    probe.create_subscription(CameraInfo, "camera/camera_info", got["info"].append,
                              qos_profile_sensor_data)
    probe.create_subscription(DiagnosticArray, contract.DIAGNOSTICS,
                              lambda m: got["diag"].extend(s for s in m.status
                                                           if s.name == "usb_camera"),
                              qos_for(contract.DIAGNOSTICS))
    return got


def test_replayed_images_become_the_blocks_pose(launch, rclpy_context, executor, wait_for,
                                                 tmp_path):
    marker = look_at_pose([0.02, -0.03, 0.45], 0.35, 0.8, 0.4)
    frames = tmp_path / "frames"
    got = _probe(rclpy_context, executor)
    cam = launch("hyperarm_perception", "usb_camera",
                 params={"device": str(frames / "%04d.png"), "loop": True, "fps": 10.0,
                         "camera_info_file": str(_calibration(tmp_path, CAM)),
                         "reopen_period": 0.2, "diagnostics_period": 0.2})
    launch("hyperarm_perception", "marker_detector", params={"diagnostics_period": 0.5})
    # 1. no camera yet: an error in the diagnostics, naming the source
    wait_for(lambda: got["diag"], 30.0, what=lambda: f"diagnostics\n{cam.output()}")
    assert got["diag"][-1].level == bytes([2]), got["diag"][-1]
    assert "cannot open" in got["diag"][-1].message and "frames" in got["diag"][-1].message
    assert not got["info"]
    # 2. the camera appears: images and the calibration flow, the block is detected
    _frames(frames, marker)
    wait_for(lambda: got["det"] and list(got["det"][-1].names) == ["block"], 30.0,
             what=lambda: f"the block detected\n{cam.output()}")
    info = got["info"][-1]
    assert (info.width, info.height) == (640, 480) and info.distortion_model == "plumb_bob"
    assert np.allclose(np.array(info.k).reshape(3, 3), CAM.K)
    assert info.header.frame_id == "camera_optical_frame"
    mm = load_marker_map()
    truth = T_LINK_OPTICAL @ marker @ np.linalg.inv(mm.markers[0].offset)
    p, q = got["det"][-1].poses[0].position, got["det"][-1].poses[0].orientation
    assert np.linalg.norm([p.x - truth[0, 3], p.y - truth[1, 3], p.z - truth[2, 3]]) < 0.008
    import pinocchio as pin
    R = pin.Quaternion(q.w, q.x, q.y, q.z).toRotationMatrix()
    assert rotation_angle(R @ truth[:3, :3].T) < math.radians(3)
    wait_for(lambda: got["diag"][-1].level == bytes([0]), 10.0, what="streaming status")
    values = {kv.key: kv.value for kv in got["diag"][-1].values}
    assert values["state"] == "open" and values["size"] == "640x480"
    assert int(values["frames"]) >= 1 and int(values["open_failures"]) >= 1
    # 3. SIGTERM: exit 0
    cam.proc.send_signal(signal.SIGTERM)
    assert cam.proc.wait(timeout=10.0) == 0, cam.output()


def test_a_calibration_for_another_size_is_an_error_and_not_published(
        launch, rclpy_context, executor, wait_for, tmp_path):
    small = CameraModel.from_fovy(320, 240, math.radians(45.0))
    _frames(tmp_path / "frames", look_at_pose([0.0, 0.0, 0.4], 0.2, 0.0, 0.0), n=2)
    got = _probe(rclpy_context, executor)
    cam = launch("hyperarm_perception", "usb_camera",
                 params={"device": str(tmp_path / "frames" / "%04d.png"), "loop": True,
                         "camera_info_file": str(_calibration(tmp_path, small)),
                         "diagnostics_period": 0.2})
    wait_for(lambda: got["info"] and got["diag"] and got["diag"][-1].level == bytes([2]),
             30.0, what=lambda: f"camera_info and an error\n{cam.output()}")
    assert not any(got["info"][-1].k), "a calibration for 320x240 published for 640x480"
    assert "calibration is for 320x240" in got["diag"][-1].message
    wait_for(lambda: "calibration is for 320x240" in cam.output(), 10.0, what="log line")


def test_bad_parameters_exit_1_naming_them(launch, tmp_path):
    import time

    for params, text in (({"pixel_format": "H264"}, "pixel_format"),
                         ({"camera_info_file": str(tmp_path / "none.yaml")}, "cannot read")):
        proc = launch("hyperarm_perception", "usb_camera", params=params)
        deadline = time.monotonic() + 30.0
        while proc.proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert proc.proc.returncode == 1, proc.output()
        assert text in proc.output()


def test_a_missing_device_is_one_clear_line_and_an_error(launch, rclpy_context, executor,
                                                         wait_for):
    """The robot's case: no camera at /dev/...: one throttled warning of ours (OpenCV's own
    line per reopening is silenced), an error in the diagnostics, retried each period."""
    import time

    got = _probe(rclpy_context, executor)
    cam = launch("hyperarm_perception", "usb_camera",
                 params={"device": "/dev/hyperarm-no-camera", "reopen_period": 0.2,
                         "diagnostics_period": 0.2})
    wait_for(lambda: got["diag"], 30.0, what=lambda: f"diagnostics\n{cam.output()}")
    time.sleep(1.5)
    last = got["diag"][-1]
    assert last.level == bytes([2]) and "cannot open /dev/hyperarm-no-camera" in last.message
    assert "'video' group" in last.message
    values = {kv.key: kv.value for kv in last.values}
    assert int(values["open_failures"]) >= 5, values      # reopened every 0.2 s
    out = cam.output()
    assert out.count("cannot open /dev/hyperarm-no-camera") == 1, out
    assert "VIDEOIO" not in out, out
