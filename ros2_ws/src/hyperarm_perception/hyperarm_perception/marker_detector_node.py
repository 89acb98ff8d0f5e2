"""marker_detector: detects the marker map's markers in camera images and publishes the
objects' poses as Detections in camera_link (issue 27).

Subscribes ``camera/image_raw`` (sensor_msgs/Image: mono8, bgr8, rgb8, bgra8, rgba8) and
``camera/camera_info`` (sensor_msgs/CameraInfo; plumb_bob or rational_polynomial), both with
the sensor-data QoS (best effort, so it matches best-effort and reliable drivers); publishes
``detections`` (hyperarm_interfaces/Detections, header.stamp = the image's) and
``/diagnostics`` (counts of every rejection). The detection itself is
:mod:`hyperarm_perception.markers`; this node converts messages and wires them up. The robot
description (``variant``, ``description_file``) gives the camera's extrinsics, hence which
way is up in ``camera_link``: the prior of the map's ``upright`` objects.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from hyperarm_description import contract
from hyperarm_description.freshness import StampGate, stamp_seconds
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.params import ParamSpec, Range, declare_parameters
from hyperarm_description.qos import qos_for
from hyperarm_description.model import camera_link_pose
from hyperarm_description.ros_main import declare_robot_description, run_node
from hyperarm_ik.ros_conversions import matrix_to_pose
from hyperarm_interfaces.msg import Detections

from .camera_input import camera_model, image_gray
from .markers import (REASONS, CameraModelError, ImageError, MarkerDetector, MarkerMapError,
                      load_marker_map, up_in_camera_link)

IMAGE = "camera/image_raw"
CAMERA_INFO = "camera/camera_info"

PARAMETERS: ParamSpec = {
    "marker_map": ("", "marker map YAML (docs/perception.md); '' = the packaged "
                   "config/markers.yaml", None),
    "max_age": (1.0, "s, images stamped longer ago than this (or out of order, or from the "
                "future) are dropped", Range(0.01, 60.0)),
    "diagnostics_period": (1.0, "s between diagnostics messages", Range(0.1, 60.0)),
}


class MarkerDetectorNode(Node):
    """Thin wrapper around :class:`MarkerDetector`."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("marker_detector", **kwargs)
        desc = declare_robot_description(self)
        p = declare_parameters(self, PARAMETERS)
        try:
            self._map = load_marker_map(p["marker_map"] or None)
        except MarkerMapError as exc:
            raise SystemExit(f"marker_detector: {exc}") from None
        # up (against gravity) in camera_link, from the description's camera extrinsics
        self._up = up_in_camera_link(camera_link_pose(desc))
        self._detector: MarkerDetector | None = None
        self._gate = StampGate(IMAGE, p["max_age"])
        self._throttle = ReasonThrottle(5.0)
        #: drops before detection: no_camera_info, bad_camera_info, bad_image
        self._dropped = {"no_camera_info": 0, "bad_camera_info": 0, "bad_image": 0}
        self._info_key = None
        self._pub = self.create_publisher(Detections, contract.DETECTIONS,
                                          qos_for(contract.DETECTIONS))
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS))
        self.create_subscription(CameraInfo, CAMERA_INFO, self._on_info, qos_profile_sensor_data)
        self.create_subscription(Image, IMAGE, self._on_image, qos_profile_sensor_data)
        self.create_timer(p["diagnostics_period"], self._publish_diagnostics)
        self.get_logger().info(
            f"marker_detector: {len(self._map.markers)} markers of {self._map.dictionary} "
            f"({', '.join(self._map.objects)}); {IMAGE} + {CAMERA_INFO} -> "
            f"{contract.DETECTIONS} in {contract.CAMERA_FRAME}")

    def _warn(self, text: str, reason: str) -> None:
        if (line := self._throttle.message(text, reason)):
            self.get_logger().warn(line)

    def _on_info(self, msg: CameraInfo) -> None:
        key = (tuple(msg.k), tuple(msg.d), msg.distortion_model, msg.width, msg.height)
        if key == self._info_key:
            return
        try:
            cam = camera_model(msg.k, msg.d, msg.distortion_model, msg.width, msg.height)
        except CameraModelError as exc:
            self._dropped["bad_camera_info"] += 1
            self._warn(f"{CAMERA_INFO} ignored: {exc}", f"camera_info: {exc}")
            return
        self._info_key = key
        if self._detector is None:
            self._detector = MarkerDetector(self._map, cam, up=self._up)
        else:
            self._detector.set_camera(cam)

    def _on_image(self, msg: Image) -> None:
        rejection = self._gate.check(stamp_seconds(msg.header.stamp),
                                     self.get_clock().now().nanoseconds * 1e-9)
        if rejection is not None:
            self._warn(rejection.text, f"image_{rejection.reason}")
            return
        if self._detector is None:
            self._dropped["no_camera_info"] += 1
            self._warn(f"{IMAGE} dropped: no valid CameraInfo on {CAMERA_INFO} yet",
                       "no_camera_info")
            return
        try:
            gray = image_gray(msg.encoding, msg.height, msg.width, msg.step, msg.data)
            result = self._detector.detect(gray)
        except ImageError as exc:
            self._dropped["bad_image"] += 1
            self._warn(f"{IMAGE} dropped: {exc}", f"image: {exc}")
            return
        for rej in result.rejections:
            self._warn(rej.text, f"marker_{rej.reason}")
        out = Detections()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = contract.CAMERA_FRAME
        out.names = [d.object for d in result.detections]
        out.poses = [matrix_to_pose(d.pose) for d in result.detections]
        out.covariances = [float(v) for d in result.detections for v in d.covariance.reshape(-1)]
        self._pub.publish(out)

    def counts(self) -> dict[str, int]:
        """Every count the diagnostics carry."""
        out = dict(self._dropped)
        out.update({f"image_{r}": n for r, n in self._gate.counts.items()})
        if self._detector is not None:
            out.update({(f"rejected_{k}" if k in REASONS else k): v
                        for k, v in self._detector.counts.items()})
        return out

    def _publish_diagnostics(self) -> None:
        counts = self.counts()
        ok = self._detector is not None
        st = DiagnosticStatus(
            level=bytes([0 if ok else 1]), name="marker_detector", hardware_id="camera",
            message="detecting" if ok else f"waiting for a valid CameraInfo on {CAMERA_INFO}",
            values=[KeyValue(key=k, value=str(v)) for k, v in counts.items()])
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag.publish(arr)


def main(args: list[str] | None = None) -> None:
    run_node(MarkerDetectorNode, args, parameters=PARAMETERS, robot_description=True)


if __name__ == "__main__":
    main()
