"""usb_camera: a USB (V4L2) camera's images and calibration on the standard camera topics
(issue 27).

Captures with OpenCV (:mod:`hyperarm_perception.capture`: a ``/dev/video*`` device, or a
video file or image sequence to replay) and publishes ``camera/image_raw``
(sensor_msgs/Image, bgr8 or mono8) and ``camera/camera_info`` (sensor_msgs/CameraInfo) with
the sensor-data QoS, both stamped when the frame was read and framed in ``frame_id`` (REP
103's optical frame). The calibration is the standard file ROS' camera_calibration writes
(``camera_info_file``); without one CameraInfo carries K = 0 (uncalibrated), as every ROS
camera driver does. A camera that is missing or lost is said in the log and in
``/diagnostics`` and reopened every ``reopen_period`` s; a calibration for another image
size is an error in both (CameraInfo then says uncalibrated).
"""
from __future__ import annotations

import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from hyperarm_description import contract
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.params import OneOf, ParamSpec, Range, declare_parameters
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import run_node

from .camera_info_file import CameraCalibration, CameraInfoFileError, load_camera_info
from .capture import PIXEL_FORMATS, CaptureConfig, CaptureError, FrameSource

IMAGE = "camera/image_raw"
CAMERA_INFO = "camera/camera_info"

PARAMETERS: ParamSpec = {
    "device": ("/dev/video0", "camera to open: a V4L2 device, or a video file or image "
               "sequence (e.g. frames/%04d.png) to replay", None),
    "width": (640, "pixels, requested image width (0 = the camera's default)",
              Range(0, 10000)),
    "height": (480, "pixels, requested image height (0 = the camera's default)",
               Range(0, 10000)),
    "fps": (30.0, "frames per second requested, and the most published (0 = as they come)",
            Range(0.0, 1000.0)),
    "pixel_format": ("", "FOURCC the device delivers: MJPG, YUYV, or '' for its default",
                     OneOf(PIXEL_FORMATS)),
    "encoding": ("bgr8", "encoding of the published images", OneOf(("bgr8", "mono8"))),
    "camera_info_file": ("", "calibration YAML as ROS' camera_calibration writes it; '' = "
                         "uncalibrated (K = 0)", None),
    "frame_id": ("camera_optical_frame", "frame of the images (the camera's optical frame: "
                 "x right, y down, z along the view)", None),
    "loop": (False, "replay a video file or image sequence from its start at its end", None),
    "reopen_period": (1.0, "s between attempts to open a missing or lost camera",
                      Range(0.05, 60.0)),
    "diagnostics_period": (1.0, "s between diagnostics messages", Range(0.1, 60.0)),
}


class UsbCameraNode(Node):
    """Thin wrapper around :class:`FrameSource`: a capture thread publishes each frame."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("usb_camera", **kwargs)
        p = declare_parameters(self, PARAMETERS)
        try:
            self._source = FrameSource(CaptureConfig(
                source=p["device"], width=p["width"], height=p["height"], fps=p["fps"],
                pixel_format=p["pixel_format"], loop=p["loop"],
                reopen_period=p["reopen_period"]))
            self._calibration: CameraCalibration | None = (
                load_camera_info(p["camera_info_file"]) if p["camera_info_file"] else None)
        except (CaptureError, CameraInfoFileError) as exc:
            raise SystemExit(f"usb_camera: {exc}") from None
        # OpenCV would log each failed reopening too; this node says it once, throttled
        import cv2
        cv2.setLogLevel(2)   # cv::utils::logging::LOG_LEVEL_ERROR
        self._encoding = p["encoding"]
        self._frame_id = p["frame_id"]
        self._period = 1.0 / p["fps"] if p["fps"] > 0 else 0.0
        from .capture import is_device
        self._pace = bool(self._period) and not is_device(p["device"])
        self._throttle = ReasonThrottle(5.0)
        self._mismatch = ""
        self._size = (0, 0)
        self._rate = 0.0           # Hz, smoothed publication rate
        self._last_t: float | None = None
        self._image_pub = self.create_publisher(Image, IMAGE, qos_profile_sensor_data)
        self._info_pub = self.create_publisher(CameraInfo, CAMERA_INFO, qos_profile_sensor_data)
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS))
        self.create_timer(p["diagnostics_period"], self._publish_diagnostics)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="usb_camera-capture",
                                        daemon=True)
        cal = (f"calibration {p['camera_info_file']} ({self._calibration.width}x"
               f"{self._calibration.height})" if self._calibration else
               "no calibration (CameraInfo K = 0: run camera_calibration, then set "
               "camera_info_file)")
        self.get_logger().info(f"usb_camera: {p['device']} -> {IMAGE} ({self._encoding}) + "
                               f"{CAMERA_INFO}, {cal}")
        self._thread.start()

    def _warn(self, text: str, reason: str) -> None:
        if (line := self._throttle.message(text, reason)):
            self.get_logger().warn(line)

    def _run(self) -> None:
        last_state = self._source.state
        next_at = time.monotonic()
        while not self._stop.is_set():
            frame = self._source.read()
            if self._stop.is_set():        # stopping while the read blocked: publish nothing
                break
            state = self._source.state
            if state != last_state:
                if state == "open":
                    self.get_logger().info(f"usb_camera: {self._source.config.source} open")
                elif state == "ended":
                    self.get_logger().info(f"usb_camera: {self._source.problem}")
                last_state = state
            if frame is None:
                if state == "closed":
                    self._warn(self._source.problem, "no_camera")
                self._stop.wait(min(0.1, self._source.config.reopen_period))
                continue
            try:
                self._publish(frame)
            except Exception:       # the node destroyed under a publish: the stop, not a bug
                if self._stop.is_set():
                    break
                raise
            if self._pace:          # a recording: at fps (a device delivers at its own rate)
                next_at = max(next_at + self._period, time.monotonic() - self._period)
                self._stop.wait(max(0.0, next_at - time.monotonic()))

    def _publish(self, frame: np.ndarray) -> None:
        import cv2

        stamp = self.get_clock().now().to_msg()
        if self._encoding == "mono8" and frame.ndim == 3:
            frame = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        elif self._encoding == "bgr8" and frame.ndim == 2:
            frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        frame = np.ascontiguousarray(frame)
        h, w = frame.shape[:2]
        now = time.monotonic()
        if self._last_t is not None and now > self._last_t:
            inst = 1.0 / (now - self._last_t)
            self._rate = inst if not self._rate else 0.9 * self._rate + 0.1 * inst
        self._last_t = now
        if self._size != (w, h):
            self._size = (w, h)
            if (off := self._source.size_mismatch(frame)):
                self.get_logger().warn(f"usb_camera: {off}")
        img = Image()
        img.header.stamp = stamp
        img.header.frame_id = self._frame_id
        img.height, img.width = h, w
        img.encoding = self._encoding
        img.is_bigendian = 0
        img.step = int(frame.strides[0])
        img.data = frame.tobytes()
        self._image_pub.publish(img)
        self._info_pub.publish(self._camera_info(w, h, stamp))

    def _camera_info(self, w: int, h: int, stamp) -> CameraInfo:
        info = CameraInfo()
        info.header.stamp = stamp
        info.header.frame_id = self._frame_id
        info.width, info.height = w, h
        cal = self._calibration
        self._mismatch = ""
        if cal is not None and (cal.width, cal.height) != (w, h):
            self._mismatch = (f"the calibration is for {cal.width}x{cal.height} images, the "
                              f"camera delivers {w}x{h}: set width/height or recalibrate")
            self._warn(f"usb_camera: {self._mismatch}; CameraInfo says uncalibrated",
                       "calibration_size")
            cal = None
        if cal is None:
            info.distortion_model = "plumb_bob"
            info.d = [0.0] * 5
            return info          # K, R, P all zero: uncalibrated
        for name, value in cal.info_fields().items():
            setattr(info, name, value)
        return info

    def _publish_diagnostics(self) -> None:
        src = self._source
        if src.state == "closed":
            level, message = 2, src.problem or f"opening {src.config.source}"
        elif self._mismatch:
            level, message = 2, self._mismatch
        elif src.state == "ended":
            level, message = 1, src.problem
        elif self._calibration is None:
            level, message = 1, "streaming, uncalibrated (no camera_info_file)"
        else:
            level, message = 0, "streaming"
        values = {**src.counts, "state": src.state, "size": "%dx%d" % self._size,
                  "rate_hz": f"{self._rate:.1f}"}
        st = DiagnosticStatus(level=bytes([level]), name="usb_camera",
                              hardware_id=src.config.source, message=message,
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag.publish(arr)

    def destroy_node(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        if self._thread.is_alive():
            # still inside a blocking read of a stalled device: releasing the capture under
            # it is undefined in OpenCV; the daemon thread ends with the process
            self.get_logger().warn(f"usb_camera: {self._source.config.source} still blocks "
                                   "a read; not released")
        else:
            self._source.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(UsbCameraNode, args, parameters=PARAMETERS, robot_description=False)


if __name__ == "__main__":
    main()
