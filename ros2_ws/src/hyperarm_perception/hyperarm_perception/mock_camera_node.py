"""mock_camera: the mock's camera as pictures, rendered by MuJoCo in a process of its own
(issue 27).

Subscribes the mock's ``joint_states`` (the arm, gripper and rail as they are) and
``debug/detections_truth`` (hyperarm_interfaces/Detections: the true object poses in
camera_link, stamped at the mock camera's exposure), renders the description's camera view
of the work cell with the marker map's markers
(:class:`hyperarm_perception.rendered_camera.RenderedCamera`) and publishes it as a camera
driver does: ``camera/image_raw`` (sensor_msgs/Image, mono8 or rgb8) and ``camera/camera_info``
(the ideal pinhole of the description's field of view), sensor-data QoS, both stamped with
the truth's exposure stamp and framed in ``frame_id``. ``marker_detector`` turns them into
``detections``, as on the robot. At most ``rate`` pictures a second, each of the newest
truth not yet drawn, with the joint states nearest its stamp; rendering never delays the
mock's physics (another process) nor this node's subscriptions (a thread of its own, which
owns the OpenGL context). Needs EGL or OSMesa without a display (``MUJOCO_GL``, default egl
here; scripts/setup.sh installs EGL).
"""
from __future__ import annotations

import os
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, JointState

from hyperarm_description import contract
from hyperarm_description.freshness import stamp_seconds
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.model import DescriptionError
from hyperarm_description.params import OneOf, ParamSpec, Range, declare_parameters
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node
from hyperarm_description.world import load_world
from hyperarm_ik.ros_conversions import pose_to_matrix
from hyperarm_interfaces.msg import Detections

from .calibration_postures import NOMINAL_TARGET, parse_pose
from .camera_info_file import CameraCalibration
from .markers import PerceptionError, load_marker_map
from .marker_detector_node import CAMERA_INFO, IMAGE

PARAMETERS: ParamSpec = {
    "workcell_file": ("", "the mock's work-cell YAML ('' = hyperarm_driver's packaged "
                      "config/workcell.yaml): the table, pegs and block drawn", None),
    "marker_map": ("", "marker map YAML: the markers drawn on the objects ('' = the packaged "
                   "config/markers.yaml)", None),
    "rate": (10.0, "Hz, most pictures per second", Range(0.1, 100.0)),
    "width": (640, "pixels", Range(16, 4096)),
    "height": (480, "pixels", Range(16, 4096)),
    "blur_sigma": (0.5, "pixels, Gaussian blur of the optics (0 = none)", Range(0.0, 10.0)),
    "noise_sigma": (2.0, "grey levels, Gaussian noise per pixel (0 = none)",
                    Range(0.0, 50.0)),
    "seed": (-1, "seed of the pixel noise (-1 = fresh each start)", Range(-1, 2**31 - 1)),
    "encoding": ("mono8", "encoding of the pictures: mono8 (307 kB at 640x480: within Fast "
                 "DDS's 512 kB shared-memory segment, so no picture is lost between "
                 "processes) or rgb8 (921 kB: sent as UDP fragments, which a best-effort "
                 "subscriber loses at times)", OneOf(("mono8", "rgb8"))),
    "calibration_target": ("", "the gripper holds the calibration target (the marker map's "
                           "calibration_target) at 'x y z roll pitch yaw' (m, rad) in tool0, "
                           "drawn where the joints put it (e.g. '" + NOMINAL_TARGET + "', "
                           "docs/perception.md); '' = none held", None),
    "frame_id": ("camera_optical_frame", "frame of the images (the optical frame of the "
                 "description's camera)", None),
    "diagnostics_period": (1.0, "s between diagnostics messages", Range(0.1, 60.0)),
}

#: s the renderer may take to start (MuJoCo's model and OpenGL context) before the node gives up
_START_TIMEOUT = 60.0
_JOIN_TIMEOUT = 0.5   # s: the render thread's time to end at the node's stop

#: joint states kept to pick the one nearest a truth's stamp (at 100 Hz: 0.5 s)
_JOINT_HISTORY = 50


def _default_workcell() -> Path:
    from ament_index_python.packages import get_package_share_directory

    return Path(get_package_share_directory("hyperarm_driver")) / "config" / "workcell.yaml"


class MockCameraNode(Node):
    """Thin wrapper around :class:`RenderedCamera`: a render thread publishes each picture."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("mock_camera", **kwargs)
        desc = declare_robot_description(self)
        p = declare_parameters(self, PARAMETERS)
        try:
            cell = Path(p["workcell_file"]) if p["workcell_file"] else _default_workcell()
            world = load_world(cell)
            markers = load_marker_map(p["marker_map"] or None)
            held = ({"calibration_target": parse_pose(p["calibration_target"],
                                                      "calibration_target")}
                    if p["calibration_target"].strip() else {})
        except (DescriptionError, PerceptionError, ValueError, OSError) as exc:
            raise SystemExit(f"mock_camera: {exc}") from None
        self._frame_id = p["frame_id"]
        self._encoding = p["encoding"]
        self._period = 1.0 / p["rate"]
        self._lock = threading.Lock()
        self._joints: deque[tuple[float, dict[str, float]]] = deque(maxlen=_JOINT_HISTORY)
        self._truth: tuple[float, object, dict[str, np.ndarray]] | None = None
        self._drawn_stamp: float | None = None
        self.counts = {"pictures": 0, "truths": 0, "joint_states": 0, "no_joint_states": 0,
                       "bad_joint_states": 0, "bad_truth": 0, "render_failures": 0}
        self._render_ms = 0.0
        self._throttle = ReasonThrottle(5.0)      # one line per kind of bad truth
        self._image_pub = self.create_publisher(Image, IMAGE, qos_profile_sensor_data)
        self._info_pub = self.create_publisher(CameraInfo, CAMERA_INFO, qos_profile_sensor_data)
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS))
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_joints,
                                 qos_for(contract.JOINT_STATES))
        self.create_subscription(Detections, contract.DETECTIONS_TRUTH, self._on_truth,
                                 qos_for(contract.DETECTIONS_TRUTH))
        self.create_timer(p["diagnostics_period"], self._publish_diagnostics)
        # The render thread owns the OpenGL context (EGL refuses it to any other thread).
        os.environ.setdefault("MUJOCO_GL", "egl")
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._failure: str | None = None
        self._thread = threading.Thread(
            target=self._run, args=(desc, world, markers, held, p), name="mock_camera-render",
            daemon=True)
        self._thread.start()
        try:
            if not self._ready.wait(_START_TIMEOUT):
                self._failure = (f"the renderer was not ready within {_START_TIMEOUT:g} s "
                                 "(MuJoCo's OpenGL context: MUJOCO_GL)")
        except BaseException:      # a signal during the wait: the thread must not go on
            self._stop.set()
            raise
        if self._failure:
            self._stop.set()
            raise SystemExit(f"mock_camera: {self._failure}")
        cam = self._camera
        self.get_logger().info(
            f"mock_camera: {cell.name} with {len(markers.markers)} markers, "
            f"{cam.width}x{cam.height} at {p['rate']:g} Hz (f = {cam.K[0, 0]:.1f} px) -> "
            f"{IMAGE} + {CAMERA_INFO}")

    # -- inputs (executor thread) ------------------------------------------------------------
    def _on_joints(self, msg: JointState) -> None:
        if len(msg.name) != len(msg.position) or not np.all(np.isfinite(msg.position)):
            self.counts["bad_joint_states"] += 1   # a bad message is not drawn
            return
        self.counts["joint_states"] += 1
        with self._lock:
            self._joints.append((stamp_seconds(msg.header.stamp),
                                 dict(zip(msg.name, (float(v) for v in msg.position)))))

    def _on_truth(self, msg: Detections) -> None:
        try:
            if len(msg.names) != len(msg.poses):
                raise ValueError(f"{len(msg.names)} names, {len(msg.poses)} poses")
            poses = {}
            for name, pose in zip(msg.names, msg.poses):
                o = pose.orientation
                norm = float(np.linalg.norm([o.x, o.y, o.z, o.w]))
                if not np.isfinite(norm) or abs(norm - 1.0) > 1e-3:
                    raise ValueError(f"orientation of {name!r} is not a unit quaternion "
                                     f"(norm {norm:.6g})")
                t = pose_to_matrix(pose)
                if not np.all(np.isfinite(t)):
                    raise ValueError(f"pose of {name!r} not finite")
                poses[name] = t
        except ValueError as exc:
            self.counts["bad_truth"] += 1
            text = str(exc)
            kind = ("lengths" if "names" in text else "quaternion" if "quaternion" in text
                    else "non_finite")
            if (line := self._throttle.message(
                    f"mock_camera: {contract.DETECTIONS_TRUTH} dropped: {exc}", kind)):
                self.get_logger().warn(line)
            return
        self.counts["truths"] += 1
        with self._lock:
            self._truth = (stamp_seconds(msg.header.stamp), msg.header.stamp, poses)

    # -- the render thread -------------------------------------------------------------------
    def _run(self, desc, world, markers, held, p) -> None:
        try:
            from .rendered_camera import RenderedCamera, RenderOptions

            renderer = RenderedCamera(desc, world, markers, RenderOptions(
                width=p["width"], height=p["height"], blur_sigma=p["blur_sigma"],
                noise_sigma=p["noise_sigma"], seed=None if p["seed"] < 0 else p["seed"]),
                held=held)
        except BaseException as exc:   # mujoco's import (a bad MUJOCO_GL), the model, OpenGL
            self._failure = f"cannot render: {exc}"
            self._ready.set()
            return
        self._camera = renderer.camera
        cam = self._camera
        self._info_fields = CameraCalibration.ideal(cam.K, cam.width, cam.height,
                                                    "mock_camera").info_fields()
        link_in_root = renderer.camera_pose
        self._ready.set()
        try:
            next_at = time.monotonic()
            while not self._stop.wait(max(0.0, next_at - time.monotonic())):
                next_at = max(next_at + self._period, time.monotonic())
                job = self._next_job()
                if job is None:
                    continue
                t0 = time.perf_counter()
                stamp, joints, objects = job
                try:
                    image = renderer.render(joints,
                                            {n: link_in_root @ t for n, t in objects.items()})
                except Exception as exc:     # mujoco's or OpenGL's: said, counted, go on
                    self.counts["render_failures"] += 1
                    self.get_logger().error(f"mock_camera: rendering failed: {exc!r}",
                                            throttle_duration_sec=5.0)
                    continue
                self._render_ms = 1e3 * (time.perf_counter() - t0)
                if self._stop.is_set():
                    break
                self._publish(image, stamp)
        except Exception as exc:       # the loop itself failed: said, and ERROR from now on
            self._failure = f"the render thread stopped: {exc!r}"
            self.get_logger().error(f"mock_camera: {self._failure}")
        finally:
            renderer.close()

    def _next_job(self):
        """The newest truth not drawn yet with the joint states nearest its stamp, or None."""
        with self._lock:
            if self._truth is None or self._truth[0] == self._drawn_stamp:
                return None
            t, stamp, objects = self._truth
            if not self._joints:
                self.counts["no_joint_states"] += 1
                return None
            _, joints = min(self._joints, key=lambda item: abs(item[0] - t))
            self._drawn_stamp = t
        return stamp, joints, objects

    def _publish(self, image: np.ndarray, stamp) -> None:
        if self._encoding == "mono8":
            import cv2

            image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        img = Image()
        img.header.stamp = stamp
        img.header.frame_id = self._frame_id
        img.height, img.width = image.shape[:2]
        img.encoding = self._encoding
        img.step = int(image.strides[0])
        img.data = image.tobytes()
        cam = self._camera
        info = CameraInfo()
        info.header = img.header
        info.width, info.height = cam.width, cam.height
        for name, value in self._info_fields.items():
            setattr(info, name, value)
        try:
            self._image_pub.publish(img)
            self._info_pub.publish(info)
        except Exception:       # the node destroyed under a publish: the stop, not a bug
            if not self._stop.is_set():
                raise
        self.counts["pictures"] += 1

    def destroy_node(self) -> None:
        self._stop.set()               # the render thread ends its picture and frees OpenGL
        if self._thread.is_alive():
            # a picture takes ~30 ms; a thread held longer (a loaded machine's software
            # OpenGL) does not hold up the stop: it publishes nothing once stopped, and the
            # process ends with it (it held a lifecycle test's SIGINT stop 2.0 s once)
            self._thread.join(timeout=_JOIN_TIMEOUT)
        super().destroy_node()

    def _publish_diagnostics(self) -> None:
        with self._lock:
            waiting = self._truth is None or not self._joints
        if self._failure:
            level, message = DiagnosticStatus.ERROR, self._failure
        elif waiting:
            level, message = (DiagnosticStatus.WARN,
                              "waiting for the mock's joint_states and debug/detections_truth")
        else:
            level, message = DiagnosticStatus.OK, "rendering"
        status = DiagnosticStatus(
            name=f"{self.get_name()}: camera", hardware_id="mujoco", level=level,
            message=message,
            values=[KeyValue(key=k, value=str(v)) for k, v in self.counts.items()]
            + [KeyValue(key="render_ms", value=f"{self._render_ms:.1f}")])
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag.publish(arr)


def main(args: list[str] | None = None) -> None:
    run_node(MockCameraNode, args, parameters=PARAMETERS)


if __name__ == "__main__":
    main()
