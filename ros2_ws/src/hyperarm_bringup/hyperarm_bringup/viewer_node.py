"""viewer: a live 3-D view of the robot in the browser (viser), from joint_states, the
camera detections, and the wrench estimate.

Open the URL it logs (default http://localhost:8080) in a browser: the robot (from the URDF
of hyperarm_description) posed from ``joint_states``, the work-cell objects from
``detections`` (or the mock's ``debug/detections_truth``), the table, pegs and poles of the
work-cell file (by default the one the mock and ik_service use), the recent tool path,
and the force of ``ee_wrench_base`` as an arrow at tool0; the first view frames the arm
and the work cell left of the control panel (viewer_scene.frame_view). The scene lives in
hyperarm_bringup.viewer_scene (no ROS); this node only converts messages and refreshes the
scene at ``update_rate``.
"""
from __future__ import annotations

import socket
import threading

from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.params import NonEmpty, Range, declare_parameters
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node
from hyperarm_description.world import WorldSpecError, load_world
from hyperarm_driver.mock.config import default_workcell_path
from hyperarm_ik.ros_conversions import pose_to_matrix
from hyperarm_interfaces.msg import Detections

from .viewer_scene import RobotScene, SceneConfig, SceneInputError, ViewerError, frame_view

PARAMETERS = {
    "host": ("0.0.0.0", "address the web server listens on (0.0.0.0: every interface; "
             "127.0.0.1: this computer only)", NonEmpty()),
    "port": (8080, "TCP port of the web page (0: any free port, logged)", Range(0, 65535)),
    "objects_topic": (contract.DETECTIONS, "Detections topic of the work-cell objects "
                      f"(on the mock, {contract.DETECTIONS_TRUTH} shows the true poses)",
                      NonEmpty()),
    "workcell_file": ("", "work-cell YAML whose table, pegs and poles are drawn ('' = the "
                      "packaged config/workcell.yaml of hyperarm_driver, as the mock and "
                      "ik_service use; 'none' = no work cell)", None),
    "update_rate": (20.0, "scene refreshes per second (Hz)", Range(1.0, 60.0)),
    "path_length": (500, "tool positions kept in the tool path", Range(2, 100000)),
    "path_min_step": (0.002, "distance tool0 moves before a new tool-path point (m)",
                      Range(1e-5, 1.0)),
    "wrench_scale": (0.02, "length of the wrench arrow per newton (m/N)", Range(1e-5, 10.0)),
    "object_max_age": (1.0, "an object not detected for this long is hidden (s)",
                       Range(0.01, 3600.0)),
    "shadows": (False, "draw shadows (costly without a GPU)", None),
}


class ViewerNode(Node):
    """Subscribes ``joint_states``, ``objects_topic`` and ``ee_wrench_base``; serves the
    viser page on ``host``:``port``."""

    def __init__(self) -> None:
        super().__init__("viewer", namespace=contract.DEFAULT_NAMESPACE)
        import viser  # the web server starts here, after the parameters are valid

        desc = declare_robot_description(self)
        p = declare_parameters(self, PARAMETERS)
        world = None
        if p["workcell_file"] != "none":
            # '' = the work cell the mock simulates and ik_service avoids by default
            path = p["workcell_file"] or str(default_workcell_path())
            try:
                world = load_world(path)
            except (WorldSpecError, OSError) as exc:
                raise SystemExit(f"viewer: workcell_file: {exc}") from exc
        try:
            config = SceneConfig(path_length=p["path_length"],
                                 path_min_step=p["path_min_step"],
                                 wrench_scale=p["wrench_scale"],
                                 object_max_age=p["object_max_age"])
            self.server = viser.ViserServer(host=p["host"], port=p["port"], verbose=False,
                                            label="hyperarm")
        except (ViewerError, OSError) as exc:
            raise SystemExit(f"viewer: {exc}") from exc
        self.server.scene.configure_default_lights(cast_shadow=p["shadows"])
        self.server.gui.configure_theme(show_logo=False, show_share_button=False)
        self.scene = RobotScene(self.server.scene, desc, world, config)
        # the first view: the arm at rest and the work cell, left of the control panel
        position, look_at = frame_view(self.scene.view_points())
        self.server.initial_camera.up = (0.0, 0.0, 1.0)
        self.server.initial_camera.position = tuple(position)
        self.server.initial_camera.look_at = tuple(look_at)
        self._lock = threading.Lock()
        self._joints: JointState | None = None
        self._wrench: WrenchStamped | None = None
        self._detections: Detections | None = None
        self._throttle = ReasonThrottle(5.0)
        self.create_subscription(JointState, contract.JOINT_STATES, self._keep("_joints"),
                                 qos_for(contract.JOINT_STATES))
        self.create_subscription(WrenchStamped, contract.EE_WRENCH_BASE,
                                 self._keep("_wrench"), qos_for(contract.EE_WRENCH_BASE))
        qos_key = (p["objects_topic"] if p["objects_topic"] in contract.QOS
                   else contract.DETECTIONS)
        self.create_subscription(Detections, p["objects_topic"], self._keep("_detections"),
                                 qos_for(qos_key))
        self.create_timer(1.0 / p["update_rate"], self._refresh)
        self.port = self.server.get_port()
        shown = socket.gethostname() if p["host"] == "0.0.0.0" else p["host"]
        self.get_logger().info(
            f"viewer: open http://{shown}:{self.port} (or http://localhost:{self.port} on "
            f"this computer); {desc.variant} variant, objects from {p['objects_topic']}")

    def _keep(self, attr: str):
        def store(msg) -> None:
            with self._lock:
                setattr(self, attr, msg)
        return store

    def _refresh(self) -> None:
        with self._lock:
            joints, wrench, det = self._joints, self._wrench, self._detections
            self._joints = self._wrench = self._detections = None
        now = self.get_clock().now().nanoseconds * 1e-9
        if joints is not None:
            self._apply("joint_states", self.scene.set_joints, list(joints.name),
                        list(joints.position))
        if det is not None:
            poses = [pose_to_matrix(p) for p in det.poses]
            self._apply("detections", self.scene.set_detections, det.header.frame_id,
                        list(det.names), poses, now)
        else:
            self.scene.expire(now)
        if wrench is not None:
            f = wrench.wrench.force
            self._apply("ee_wrench_base", self.scene.set_wrench, wrench.header.frame_id,
                        [f.x, f.y, f.z])

    def _apply(self, what: str, fn, *args) -> None:
        try:
            fn(*args)
        except (SceneInputError, ValueError) as exc:
            if (text := self._throttle.message(f"{what}: {exc}")):
                self.get_logger().warn(text)

    def destroy_node(self) -> None:
        server = getattr(self, "server", None)
        if server is not None:
            server.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(ViewerNode, args, parameters=PARAMETERS)


if __name__ == "__main__":
    main()
