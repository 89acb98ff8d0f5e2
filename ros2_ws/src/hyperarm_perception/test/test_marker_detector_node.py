"""Node tier: marker_detector in-process, fed synthetic images (OpenCV-rendered markers) and
a CameraInfo by a probe node. The block's detection arrives in camera_link with the image's
stamp; an image before any CameraInfo, an uncalibrated CameraInfo, an unhandled encoding, an
unknown marker id and a stale image are each dropped, counted in the diagnostics and logged."""
from __future__ import annotations

import math

import numpy as np
import pytest

from hyperarm_description import contract
from hyperarm_description.qos import qos_for
from hyperarm_perception.markers import (T_LINK_OPTICAL, CameraModel, load_marker_map,
                                         rotation_angle)
from hyperarm_perception.synthetic import MarkerPlacement, look_at_pose, render

pytestmark = pytest.mark.node

CAM = CameraModel.from_fovy(640, 480, math.radians(45.0))


def _info(k=None):
    from sensor_msgs.msg import CameraInfo

    msg = CameraInfo()
    msg.width, msg.height = CAM.width, CAM.height
    msg.distortion_model = "plumb_bob"
    msg.k = [float(v) for v in (CAM.K.ravel() if k is None else k)]
    msg.d = [0.0] * 5
    return msg


def _image(probe, pixels, encoding="mono8", age=0.0):
    from rclpy.duration import Duration
    from sensor_msgs.msg import Image

    msg = Image()
    msg.header.stamp = (probe.get_clock().now() - Duration(seconds=age)).to_msg()
    msg.header.frame_id = contract.CAMERA_FRAME
    msg.height, msg.width = pixels.shape[:2]
    msg.encoding = encoding
    msg.step = pixels.shape[1] * (1 if pixels.ndim == 2 else pixels.shape[2])
    msg.data = pixels.tobytes()
    return msg


def test_detections_and_every_bad_input(rclpy_context, executor, wait_for):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import CameraInfo, Image

    from hyperarm_interfaces.msg import Detections
    from hyperarm_perception.marker_detector_node import (CAMERA_INFO, IMAGE,
                                                          MarkerDetectorNode)

    node = MarkerDetectorNode(context=rclpy_context, parameter_overrides=[
        Parameter("diagnostics_period", value=0.2)])
    probe = Node("marker_probe", namespace=contract.DEFAULT_NAMESPACE, context=rclpy_context)
    executor.add_node(node)
    executor.add_node(probe)
    got, diags = [], []
    probe.create_subscription(Detections, contract.DETECTIONS, got.append,
                              qos_for(contract.DETECTIONS))
    probe.create_subscription(DiagnosticArray, contract.DIAGNOSTICS,
                              lambda m: diags.extend(s for s in m.status
                                                     if s.name == "marker_detector"),
                              qos_for(contract.DIAGNOSTICS))
    images = probe.create_publisher(Image, IMAGE, 10)
    infos = probe.create_publisher(CameraInfo, CAMERA_INFO, 10)
    wait_for(lambda: images.get_subscription_count() and infos.get_subscription_count()
             and probe.count_publishers(contract.DETECTIONS), 10.0, what="matching")

    mm = load_marker_map()
    rng = np.random.default_rng(1)
    marker = look_at_pose([0.03, -0.02, 0.4], 0.4, 1.0, 0.7)
    block = render(CAM, mm.dictionary, [MarkerPlacement(0, mm.markers[0].size, marker)],
                   rng=rng)

    # 1. an image before any CameraInfo: dropped, counted, nothing published
    images.publish(_image(probe, block))
    wait_for(lambda: node.counts()["no_camera_info"] == 1, 10.0, what="no_camera_info")
    # 2. an uncalibrated CameraInfo (K all zeros): ignored, still waiting
    infos.publish(_info(k=[0.0] * 9))
    wait_for(lambda: node.counts()["bad_camera_info"] == 1, 10.0, what="bad_camera_info")
    images.publish(_image(probe, block))
    wait_for(lambda: node.counts()["no_camera_info"] == 2, 10.0, what="still no camera")
    assert got == []
    wait_for(lambda: diags and diags[-1].level == bytes([1]), 10.0, what="waiting status")
    assert "waiting for a valid CameraInfo" in diags[-1].message

    # 3. a valid CameraInfo, then the block as bgr8: one detection in camera_link
    infos.publish(_info())
    wait_for(lambda: node._detector is not None, 10.0, what="camera model")
    sent = _image(probe, np.repeat(block[:, :, None], 3, axis=2), "bgr8")
    images.publish(sent)
    wait_for(lambda: got, 10.0, what="detections")
    msg = got[-1]
    assert msg.header.frame_id == contract.CAMERA_FRAME and msg.header.stamp == sent.header.stamp
    assert list(msg.names) == ["block"]
    p, q = msg.poses[0].position, msg.poses[0].orientation
    truth = T_LINK_OPTICAL @ marker @ np.linalg.inv(mm.markers[0].offset)
    assert np.linalg.norm([p.x - truth[0, 3], p.y - truth[1, 3], p.z - truth[2, 3]]) < 0.008
    import pinocchio as pin
    R = pin.Quaternion(q.w, q.x, q.y, q.z).toRotationMatrix()
    assert rotation_angle(R @ truth[:3, :3].T) < math.radians(3)

    # 4. an unhandled encoding: dropped, counted, no detections message for it
    n = len(got)
    images.publish(_image(probe, np.zeros((480, 640 * 2), np.uint8), "16UC1"))
    wait_for(lambda: node.counts()["bad_image"] == 1, 10.0, what="bad encoding")
    # 5. a marker id not in the map: an empty Detections, counted
    other = render(CAM, mm.dictionary, [MarkerPlacement(33, 0.03, marker)], rng=rng)
    images.publish(_image(probe, other))
    wait_for(lambda: node.counts()["rejected_unknown_id"] == 1, 10.0, what="unknown id")
    wait_for(lambda: len(got) == n + 1, 10.0, what="empty detections")
    assert list(got[-1].names) == []
    # 6. a stale image (5 s old): dropped by the StampGate
    images.publish(_image(probe, block, age=5.0))
    wait_for(lambda: node.counts()["image_stale"] == 1, 10.0, what="stale")
    assert len(got) == n + 1

    # the diagnostics carry every count
    def latest():
        return {kv.key: kv.value for kv in diags[-1].values} if diags else {}
    wait_for(lambda: latest().get("rejected_unknown_id") == "1"
             and latest().get("image_stale") == "1", 10.0, what="diagnostics")
    values = latest()
    assert values["no_camera_info"] == "2" and values["bad_camera_info"] == "1"
    assert values["bad_image"] == "1" and values["frames"] == "2"
    assert values["detections"] == "1" and diags[-1].level == bytes([0])
    # corners from the markers' edges on every marker seen (none fell back to OpenCV's)
    assert values["edge_fallbacks"] == "0" and "rejected_edge_fallbacks" not in values
