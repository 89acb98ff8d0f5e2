"""mock_driver: stands in for the Dynamixel driver and the PMAC rail driver, with no hardware.

Same topics, services, diagnostics keys and parameters as the real drivers where they apply
(docs/dynamixel.md, docs/pmac.md), plus a simulated work cell and camera. The simulation
lives in ``hyperarm_driver.mock`` (no ROS); this node converts messages and keeps time.
See docs/mock.md.

Time: with ``sim_speed`` 0 (default) the simulation runs in real time and messages carry
the node clock's time. With ``sim_speed`` > 0 it runs at that multiple of real time,
publishes ``/clock`` (simulated time, starting at 0) and stamps everything with it; run the
other nodes with ``use_sim_time:=true``.
"""
from __future__ import annotations

import threading
import time
import traceback
from dataclasses import replace

import numpy as np
import pinocchio as pin
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose, PoseStamped, WrenchStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from hyperarm_description import contract
from hyperarm_description.joints import JointStateError, velocity_problem
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.qos import NO_PUB_EVENTS, qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node
from hyperarm_interfaces.msg import Detections
from hyperarm_interfaces.srv import Reboot

from .common import (OneOf, ParamSpec, Range, answer_reboot, answer_set_torque,
                     declare_parameters, diagnostic_status)
from .mock.camera import Camera, Frame, pose_from_xyz_rpy
from .mock.config import MockError, load_mock_config
from .mock.diagnostics import BusStats, DiagStatus, mock_diagnostics
from .mock.host_motion import HostMotion, HostMotionError, load_host_motion
from .mock.joint_sim import JointSim
from .mock.lockstep import Lockstep

class _SimSpeed:
    """0 (real time) or a speed-up within 0.1..100."""

    def check(self, value: float) -> str | None:
        return None if value == 0.0 or 0.1 <= value <= 100.0 else \
            "must be 0 (real time) or within 0.1..100"

    def text(self) -> str:
        return " (0, or 0.1..100)"


class _Repeatability:
    """-1 (the work-cell file's value) or a standard deviation within 0..0.1 rad."""

    def check(self, value: float) -> str | None:
        return None if value == -1.0 or 0.0 <= value <= 0.1 else \
            "must be -1 (the work-cell file's) or within 0..0.1 rad"

    def text(self) -> str:
        return " (-1, or 0..0.1)"


PARAMETERS: ParamSpec = {
    "rate": (100.0, "simulation step and joint_states rate, Hz", Range(1.0, 1000.0)),
    "command_timeout": (0.5, "effort watchdog: torque-controlled joints hold their position "
                             "when no effort command came for this long, s",
                        Range(0.05, 10.0)),
    "torque_on_start": (True, "enable torque at start (the mock's default: true)", None),
    "shutdown_torque": ("hold", "on shutdown: 'hold' or 'release' (logged only)",
                        OneOf(("hold", "release"))),
    "require_homing": (True, "rail variant: refuse rail setpoints until rail/home completed",
                       None),
    "diagnostics_period": (1.0, "/diagnostics period, s", Range(0.1, 10.0)),
    "workcell_file": ("", "work-cell YAML ('' = the packaged config/workcell.yaml)", None),
    "detections": ("oracle", "what the mock publishes on detections: 'oracle' (the true poses "
                   "with the camera section's noise and latency), or 'none' (mock_camera renders "
                   "pictures and marker_detector publishes them, as on the robot); "
                   "debug/detections_truth is published either way", OneOf(("oracle", "none"))),
    "sim_speed": (0.0, "0 = real time; > 0 = run at this multiple of real time and publish "
                       "/clock", _SimSpeed()),  # type: ignore[dict-item]
    "lockstep_timeout": (0.0, "s of wall time, with sim_speed > 0: while a controller answers "
                         "each joint_states with a joint_command of the same header.stamp, "
                         "each tick waits for that answer, at most this long (then it steps "
                         "and waits again only once an answer comes), as a lockstep "
                         "simulator does: a controller's loop is judged apart from the "
                         "machine's load (a real robot never waits); 0 = off",
                         Range(0.0, 1.0)),
    "host_motion": ("", "scripted host motion: a host-motion YAML path or the name of a shipped "
                        "one (rail_sweep, uav_sway, uav_sway_passive); '' = none. Starts with "
                        "host_motion/enable true (docs/mock.md)", None),
    "repeatability": (-1.0, "hidden joint offset drawn per move, rad (std): overrides the work "
                            "cell's imperfections.repeatability; -1 = the file's value, 0 = the "
                            "tool truth is FK of joint_states", _Repeatability()),  # type: ignore[dict-item]
}

# Simulation events logged as warnings (a task relying on them would fail on the robot); the
# others (grasped, released, threaded, unthreaded, homed, ...) are logged as info.
WARNING_EVENTS = frozenset({"watchdog", "dropped", "hardware_error", "underpowered",
                            "blocked"})
_LEVELS = {"OK": 0, "WARN": 1, "ERROR": 2}  # diagnostic_msgs/DiagnosticStatus levels
_MAX_CATCH_UP = 5  # simulation steps per timer tick at most in real time


def _stamp(t: float) -> Time:
    sec = int(np.floor(t))
    return Time(sec=sec, nanosec=min(int(round((t - sec) * 1e9)), 999_999_999))


def _pose(m: np.ndarray) -> Pose:
    out = Pose()
    out.position.x, out.position.y, out.position.z = (float(v) for v in m[:3, 3])
    q = pin.Quaternion(m[:3, :3])
    out.orientation.x, out.orientation.y, out.orientation.z, out.orientation.w = (
        float(q.x), float(q.y), float(q.z), float(q.w))
    return out


class MockDriver(Node):
    """Simulated arm (+ rail) and work cell behind the drivers' ROS interface."""

    def __init__(self, **kwargs) -> None:  # kwargs: rclpy Node options (context, overrides)
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("mock_driver", **kwargs)
        self._throttle = ReasonThrottle(1.0)
        desc = declare_robot_description(self)
        p = self._declare_parameters()
        try:
            cfg = load_mock_config(p["workcell_file"] or None)
            if p["repeatability"] >= 0.0:
                cfg = replace(cfg, imperfections=replace(cfg.imperfections,
                                                         repeatability=p["repeatability"]))
            self._sim = JointSim(desc, cfg, effort_timeout=p["command_timeout"],
                                 require_homing=p["require_homing"])
            if p["host_motion"]:
                self._sim.host = HostMotion(load_host_motion(p["host_motion"]), self._sim)
        except (MockError, ValueError) as exc:
            raise SystemExit(f"mock_driver: {exc}") from exc
        self._camera = Camera(cfg.camera, pose_from_xyz_rpy(desc.camera.xyz, desc.camera.rpy))
        self._frame_id = desc.camera.frame
        self._oracle = p["detections"] == "oracle"
        self._dt = 1.0 / p["rate"]
        self._speed = p["sim_speed"]
        self._lockstep = Lockstep(p["lockstep_timeout"]) \
            if self._speed > 0.0 and p["lockstep_timeout"] > 0.0 else None
        self._diag_period = p["diagnostics_period"]
        self._shutdown_torque = p["shutdown_torque"]
        self._stats = BusStats()
        if not p["torque_on_start"]:
            self._sim.set_torque(False)
        self._pub = self.create_publisher(JointState, contract.JOINT_STATES,
                                          qos_for(contract.JOINT_STATES))
        # No QoS-event handlers on the low-rate outputs: each one costs every executor
        # wake-up (joint_states / joint_command keep them, for incompatible-QoS warnings).
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS),
                                           event_callbacks=NO_PUB_EVENTS)
        self._det = self.create_publisher(Detections, contract.DETECTIONS,
                                          qos_for(contract.DETECTIONS),
                                          event_callbacks=NO_PUB_EVENTS)
        self._truth = self.create_publisher(Detections, contract.DETECTIONS_TRUTH,
                                            qos_for(contract.DETECTIONS_TRUTH),
                                            event_callbacks=NO_PUB_EVENTS)
        self._wrench = self.create_publisher(WrenchStamped, contract.TOOL_WRENCH_TRUTH,
                                             qos_for(contract.TOOL_WRENCH_TRUTH),
                                             event_callbacks=NO_PUB_EVENTS)
        self._tool_frame = desc.tool_frame
        self._contacts = self.create_publisher(DiagnosticArray, contract.CONTACTS_TRUTH,
                                               qos_for(contract.CONTACTS_TRUTH),
                                               event_callbacks=NO_PUB_EVENTS)
        self._touching = False
        self._tool_truth = self.create_publisher(PoseStamped, contract.TOOL_POSE_TRUTH,
                                                 qos_for(contract.TOOL_POSE_TRUTH),
                                                 event_callbacks=NO_PUB_EVENTS)
        self._host_pub = None if self._sim.host is None else self.create_publisher(
            PoseStamped, contract.HOST_POSE, qos_for(contract.HOST_POSE),
            event_callbacks=NO_PUB_EVENTS)
        self.create_service(SetBool, contract.HOST_MOTION_ENABLE, self._on_host_motion)
        self._clock_pub = None
        if self._speed > 0.0:
            self._clock_pub = self.create_publisher(ClockMsg, contract.CLOCK, QoSProfile(
                depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                durability=DurabilityPolicy.VOLATILE), event_callbacks=NO_PUB_EVENTS)
        self.create_subscription(JointState, contract.JOINT_COMMAND, self._on_command,
                                 qos_for(contract.JOINT_COMMAND))
        # One owner per service (docs/architecture.md): set_torque, hold, reboot act on the
        # arm and the gripper; on rail_arm the rail has its own under rail/.
        self._servos = [n for n in self._sim.names if n != self._sim.rail]
        self.create_service(SetBool, contract.SET_TORQUE, self._on_set_torque)
        self.create_service(Reboot, contract.REBOOT, self._on_reboot)
        self.create_service(Trigger, contract.HOLD, self._on_hold)
        if self._sim.rail is not None:
            self.create_service(Trigger, contract.RAIL_HOME, self._on_home)
            self.create_service(SetBool, contract.RAIL_SET_TORQUE, self._on_rail_torque)
            self.create_service(Trigger, contract.RAIL_HOLD, self._on_rail_hold)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(self._diag_period / max(self._speed, 1.0), self._publish_diagnostics,
                          clock=steady)
        # The simulation loop runs in its own thread, paced by the monotonic clock: a
        # 200 Hz rclpy timer would cost more CPU in the executor than the simulation.
        # Callbacks (commands, services, diagnostics) share the simulation under _lock.
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._failure: BaseException | None = None
        self._failed = self.create_guard_condition(self._on_failure)
        self._loop = threading.Thread(target=self._run, name="mock_driver-sim", daemon=True)
        self._loop.start()
        if p["lockstep_timeout"] > 0.0 and self._speed == 0.0:
            self.get_logger().warn("lockstep_timeout needs sim_speed > 0 (simulated time): "
                                   "ignored, the simulation runs in real time")
        if self.get_parameter("use_sim_time").value and self._speed == 0.0:
            self.get_logger().warn(
                "use_sim_time is true but sim_speed is 0: nothing publishes /clock, so this "
                "node's clock stays at 0; set sim_speed > 0 to run on simulated time")
        timing = (f"sim time x{self._speed:g}, publishing {contract.CLOCK}" if self._speed > 0.0
                  else "real time")
        host = "" if self._sim.host is None else \
            f"; host motion {self._sim.host.spec.source} (host_motion/enable true to start)"
        self.get_logger().info(
            f"mock_driver: {desc.variant}, {len(self._sim.names)} joints at {p['rate']:g} Hz, "
            f"{timing}; work cell {cfg.source}; torque {'on' if p['torque_on_start'] else 'off'}"
            f"{host}")

    def _declare_parameters(self) -> dict:
        # the real drivers' helper: wrong types and values end the node with a clear message
        return declare_parameters(self, PARAMETERS)

    # -- time and the simulation loop -----------------------------------------------------
    def _run(self) -> None:
        """Tick every 1/rate s of wall time until stopped. In real time a tick simulates
        the wall time elapsed (at most _MAX_CATCH_UP steps); on sim time, sim_speed steps."""
        last = next_tick = time.monotonic()
        owed = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if self._speed > 0.0:
                owed += self._speed
            else:
                owed = min(owed + (now - last) / self._dt, _MAX_CATCH_UP)
            last = now
            steps = max(int(owed + 0.5), 0)
            owed -= steps
            if steps and self._lockstep is not None:
                self._lockstep.wait()    # no answer in time: steps anyway (docs/mock.md)
            try:
                with self._lock:
                    self._tick(steps)
            except Exception as exc:  # noqa: BLE001 - a bug, or the context gone at shutdown
                if self.context.ok() and not self._stop.is_set():
                    # a bug: log the traceback once, then end the node (non-zero exit) from
                    # the executor's thread: no half-alive node that answers but never moves
                    self.get_logger().fatal("simulation loop failed, the node exits:\n"
                                            + traceback.format_exc())
                    self._failure = exc
                    self._failed.trigger()
                return
            next_tick += self._dt
            delay = next_tick - time.monotonic()
            if delay < -self._dt:          # fell behind (loaded machine): do not burst
                next_tick = time.monotonic()
            self._stop.wait(max(delay, 0.0))

    def _tick(self, steps: int) -> None:
        start = time.monotonic()
        for _ in range(steps):
            self._sim.step(self._dt)
            for frame in self._camera.step(self._sim.time, self._sim.truth):
                self._publish_frame(frame)
            self._publish_poses()
        if steps == 0:
            return
        if self._clock_pub is not None:
            self._clock_pub.publish(ClockMsg(clock=_stamp(self._sim.time)))
        s = self._sim.state()
        msg = JointState()
        msg.header.stamp = self._time(s.stamp)
        msg.name = self._sim.names
        msg.position = s.position.tolist()
        msg.velocity = s.velocity.tolist()
        msg.effort = s.effort.tolist()
        if self._lockstep is not None:   # before publishing: a fast answer must not be missed
            self._lockstep.published((msg.header.stamp.sec, msg.header.stamp.nanosec))
        self._pub.publish(msg)
        w = self._sim.tool_wrench
        wrench = WrenchStamped()
        wrench.header.stamp = self._time(self._sim.time)   # the truth now (no latency)
        wrench.header.frame_id = self._tool_frame
        (wrench.wrench.force.x, wrench.wrench.force.y, wrench.wrench.force.z,
         wrench.wrench.torque.x, wrench.wrench.torque.y, wrench.wrench.torque.z) = \
            (float(v) for v in w)
        self._wrench.publish(wrench)
        touching = bool(self._sim.link_contacts)
        if touching or self._touching:   # while links touch a pole, and once when they stop
            self._publish_contacts(msg.header.stamp)
        self._touching = touching
        for event in self._sim.take_events():
            self._log_event(event.kind, event.detail)
        self._stats.cycles += 1
        self._stats.cycle_times.append(time.monotonic() - start)

    def _publish_poses(self) -> None:
        """Per step, in world: the true tool0 (debug/tool_pose_truth) and, with a host
        motion, base_link (host_pose)."""
        msg = PoseStamped()
        msg.header.stamp = self._time(self._sim.time)
        msg.header.frame_id = contract.WORLD_FRAME
        msg.pose = _pose(self._sim.tool_pose())
        self._tool_truth.publish(msg)
        if self._host_pub is not None:
            host = PoseStamped(header=msg.header, pose=_pose(self._sim.host.base_pose))
            self._host_pub.publish(host)

    def _log_event(self, kind: str, detail: str) -> None:
        """One call site per severity: rclpy raises if one call site logs at two."""
        if kind in WARNING_EVENTS:
            self.get_logger().warn(f"{kind}: {detail}")
        else:
            self.get_logger().info(f"{kind}: {detail}")

    def _time(self, t: float) -> Time:
        """Stamp of simulated time ``t`` (s): itself on sim time; in real time the node
        clock's now, less how long ago ``t`` was in the simulation (latencies)."""
        if self._speed > 0.0:
            return _stamp(t)
        now = self.get_clock().now().nanoseconds * 1e-9
        return _stamp(now - (self._sim.time - t))

    def _publish_contacts(self, stamp: Time) -> None:
        """debug/contacts: one status per link capsule touching a pole (none: empty)."""
        arr = DiagnosticArray()
        arr.header.stamp = stamp
        arr.status = [diagnostic_status(
            f"{self.get_name()}: contact {link}", pole, 0, f"{link} on {pole}",
            [("link", link), ("pole", pole), ("depth_mm", f"{1e3 * depth:.2f}"),
             ("force_N", " ".join(f"{v:.3f}" for v in force))])
            for link, pole, depth, force in self._sim.link_contacts]
        self._contacts.publish(arr)

    def _on_failure(self) -> None:
        """Executor thread: the simulation loop died (its traceback is logged): end."""
        raise SystemExit(f"mock_driver: simulation loop failed: {self._failure!r}")

    def _publish_frame(self, frame: Frame) -> None:
        detected = () if frame.dropped else frame.detected   # a camera dropout: no detections
        outputs = [(self._truth, frame.truth)]
        if self._oracle:
            outputs.append((self._det, detected))
        for pub, poses in outputs:
            msg = Detections()
            msg.header.stamp = self._time(frame.stamp)
            msg.header.frame_id = self._frame_id
            msg.names = list(frame.names) if poses else []
            msg.poses = [_pose(m) for m in poses]
            pub.publish(msg)

    # -- commands and services --------------------------------------------------------------
    def _on_command(self, msg: JointState) -> None:
        try:
            self._apply_command(msg)
        finally:     # lockstep: the answer to a state is in (applied, or refused)
            if self._lockstep is not None:
                self._lockstep.answered((msg.header.stamp.sec, msg.header.stamp.nanosec))

    def _apply_command(self, msg: JointState) -> None:
        try:
            if (problem := velocity_problem(msg.name, msg.velocity)):
                raise JointStateError(problem)
            with self._lock:
                report = self._sim.command(list(msg.name), list(msg.position),
                                           list(msg.effort))
        except (JointStateError, MockError) as exc:
            if self._sim.rail in msg.name:
                self._stats.rejected_setpoints += 1
                self._stats.last_rejection = str(exc)
            if (text := self._throttle.message(f"joint_command rejected: {exc}")):
                self.get_logger().error(text)    # per reason: a new kind is never hidden
            return
        if report.rejected:       # the rail's part only: the arm's was applied
            self._stats.rejected_setpoints += 1
            self._stats.last_rejection = str(report.rejected)
            if (text := self._throttle.message(
                    f"rail setpoint rejected, nothing sent: {report.rejected}")):
                self.get_logger().error(text)
        if report.clamped and (text := self._throttle.message(
                f"joint_command clamped to limits: {list(report.clamped)}")):
            self.get_logger().warn(text)

    def _on_set_torque(self, req: SetBool.Request, res: SetBool.Response) -> SetBool.Response:
        def action(enable: bool) -> None:
            with self._lock:
                self._sim.set_torque(enable, self._servos)
        return answer_set_torque(self, req.data, action, (MockError,), res)

    def _on_rail_torque(self, req: SetBool.Request, res: SetBool.Response) -> SetBool.Response:
        def action(enable: bool) -> None:
            with self._lock:
                self._sim.set_torque(enable, [self._sim.rail])
        return answer_set_torque(self, req.data, action, (MockError,), res)

    def _on_rail_hold(self, req: Trigger.Request, res: Trigger.Response) -> Trigger.Response:
        with self._lock:
            if self._sim.host is not None and self._sim.host.drives_rail:
                self._sim.host.abort("rail/hold: the rail sweep stopped")
            held = self._sim.hold([self._sim.rail])
        res.success = bool(held)
        res.message = "rail holding its present position" if held else \
            "rail amplifier not enabled: rail/set_torque true first"
        return res

    def _on_host_motion(self, req: SetBool.Request, res: SetBool.Response) -> SetBool.Response:
        host = self._sim.host
        if host is None:
            res.success, res.message = False, "no host motion configured (parameter host_motion)"
            self.get_logger().error(f"host_motion/enable: {res.message}")
            return res
        try:
            with self._lock:
                res.message = host.enable() if req.data else host.disable()
        except HostMotionError as exc:
            res.success, res.message = False, f"host_motion/enable: {exc}"
            self.get_logger().error(res.message)
            return res
        res.success = True
        self.get_logger().info(res.message)
        return res

    def _on_reboot(self, req: Reboot.Request, res: Reboot.Response) -> Reboot.Response:
        def action(joints: list[str]) -> list[str]:
            if self._sim.rail in joints:
                raise JointStateError(f"{self._sim.rail} is not a servo of this driver "
                                      "(the rail: rail/set_torque, rail/hold, rail/home)")
            with self._lock:
                return self._sim.reboot(joints)
        return answer_reboot(self, req.joints, action, (JointStateError, MockError), res)

    def _on_hold(self, req: Trigger.Request, res: Trigger.Response) -> Trigger.Response:
        with self._lock:
            self._sim.hold_keeping_grip(self._servos)   # the real driver's rule
        res.success, res.message = True, "holding the present position"
        return res

    def _on_home(self, req: Trigger.Request, res: Trigger.Response) -> Trigger.Response:
        try:
            with self._lock:
                self._sim.home_rail()
        except MockError as exc:
            res.success, res.message = False, f"rail/home: {exc}"
            self.get_logger().error(res.message)
            return res
        res.success, res.message = True, "home search started"
        return res

    # -- diagnostics ------------------------------------------------------------------------
    def _publish_diagnostics(self) -> None:
        arr = DiagnosticArray()
        with self._lock:   # the simulation thread steps the time: read it with the statuses
            arr.header.stamp = self._time(self._sim.time)
            statuses = mock_diagnostics(self._sim, self._stats, self._diag_period, self._speed)
        if (ls := self._lockstep) is not None:
            statuses.append(DiagStatus(
                name="mock_driver: lockstep", hardware_id="mock", level="OK",
                message=f"each step waits for the answering joint_command, at most "
                        f"{ls.timeout:g} s",
                values={"timeout_s": f"{ls.timeout:g}", "engaged": str(ls.engaged),
                        "timed_out": str(ls.timeouts)}))
        arr.status = [diagnostic_status(d.name, d.hardware_id, _LEVELS[d.level], d.message,
                                        d.values.items()) for d in statuses]
        self._diag.publish(arr)

    def destroy_node(self) -> None:
        if hasattr(self, "_loop"):
            self._stop.set()
            self._loop.join(timeout=5.0)
            self.get_logger().info(f"shutting down ({self._shutdown_torque})")
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(MockDriver, args, parameters=PARAMETERS)


if __name__ == "__main__":
    main()
