"""hybrid_force: Danko & Oh's hybrid position/force control of the arm (docs/force.md).

Subscribes ``hybrid_goal`` and ``joint_states``; publishes ``joint_command`` (arm joints
only, while enabled), ``ee_wrench`` (tool0) and ``ee_wrench_base`` (base_link); serves
``hybrid_force/enable``, ``hybrid_force/tare``, ``hybrid_force/compliance``. The logic is
in ``hyperarm_control.force`` (no ROS); this node converts messages and keeps time.
"""
from __future__ import annotations

import time
from array import array

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from hyperarm_description.freshness import stamp_seconds
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description import contract
from hyperarm_description.params import Range
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node
from hyperarm_interfaces.msg import HybridGoal

from .force.calibration import load_calibration
from .force.controller import Event, ForceController, Mode, Output
from .force.errors import ForceError
from .force.law import HybridLaw
from .force.parameters import DYNAMIC, PARAMETERS, build
from .force.wrench import WrenchEstimator
from hyperarm_ik.kinematics import Kinematics
from hyperarm_ik.ros_conversions import JointStateInput

_LEVEL = {Mode.DISABLED: 0, Mode.ACTIVE: 0, Mode.PASSIVE: 1}   # OK, OK, WARN


class HybridForceNode(Node):
    """Thin ROS wrapper around :class:`ForceController`."""

    def __init__(self, **kwargs) -> None:   # kwargs: rclpy Node options (context, overrides)
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("hybrid_force", **kwargs)
        self._log_throttle = ReasonThrottle(5.0)  # per reason, not per call site
        desc = declare_robot_description(self)
        p = self._declare()
        try:
            law_cfg, est_cfg, ctl_cfg = build(p)
            kin = Kinematics(desc)
            law = HybridLaw(kin, law_cfg)
            cal = load_calibration(p["calibration_file"], law.arm_names) \
                if p["calibration_file"] else None
            self._ctl = ForceController(law, WrenchEstimator(law.na, est_cfg), cal, ctl_cfg)
            self._ctl.set_payload(p["payload_mass"], p["payload_com"])
        except (ForceError, ValueError) as exc:
            raise SystemExit(f"hybrid_force: {exc}") from exc
        self._kin = kin
        self._input = JointStateInput(self.get_logger(), self._log_throttle)
        self._cache = self._input.cache
        self._root, self._base = kin.root_frame, desc.base_frame
        self._timer_trigger = p["trigger"] == "timer"
        self._compute_time = 0.0
        self._state_time: float | None = None     # s, when the newest joint state came
        self._stamp = None
        self.add_on_set_parameters_callback(self._on_parameters)
        self._cmd = self.create_publisher(JointState, contract.JOINT_COMMAND,
                                          qos_for(contract.JOINT_COMMAND))
        self._cmd_msg = JointState(name=list(self._ctl.arm_names))
        self._w_tool = self.create_publisher(WrenchStamped, contract.EE_WRENCH,
                                             qos_for(contract.EE_WRENCH))
        self._w_base = self.create_publisher(WrenchStamped, contract.EE_WRENCH_BASE,
                                             qos_for(contract.EE_WRENCH_BASE))
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS))
        # depth 1: on a loaded machine a backlog of old states would each move the
        # pseudo-goal on stale measurements (a delay in the loop); the newest one is enough
        states_qos = qos_for(contract.JOINT_STATES)
        states_qos.depth = 1
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_joint_states,
                                 states_qos)
        self.create_subscription(HybridGoal, contract.HYBRID_GOAL, self._on_goal,
                                 qos_for(contract.HYBRID_GOAL))
        self.create_service(SetBool, contract.HYBRID_ENABLE, self._on_enable)
        self.create_service(Trigger, contract.HYBRID_TARE, self._on_tare)
        self.create_service(SetBool, contract.HYBRID_COMPLIANCE, self._on_compliance)
        self._hold = self.create_client(Trigger, contract.HOLD)
        self.create_timer(min(0.01, ctl_cfg.stale_timeout / 4.0), self._check_stale)
        if self._timer_trigger:
            self.create_timer(1.0 / p["rate"], self._cycle)
        self.create_timer(p["diagnostics_period"], self._publish_diagnostics)
        self.get_logger().info(
            f"hybrid_force: {desc.variant}, {ctl_cfg.output} output, trigger {p['trigger']}, "
            f"calibration {p['calibration_file'] or 'none'}; disabled until "
            f"{contract.HYBRID_ENABLE} true")

    # -- parameters -------------------------------------------------------------------------
    def _declare(self) -> dict:
        """Declare the table's parameters (read-only but the payload's), with descriptions
        and ranges; a wrong type or value ends the node with a message naming it."""
        out = {}
        for name, (default, text, check) in PARAMETERS.items():
            d = ParameterDescriptor(description=text + (check.text() if check else ""),
                                    read_only=name not in DYNAMIC,
                                    dynamic_typing=isinstance(default, float))
            if isinstance(check, Range):
                d.floating_point_range = [FloatingPointRange(from_value=float(check.lo),
                                                             to_value=float(check.hi))]
            try:
                value = self.declare_parameter(name, default, d).value
            except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
                raise SystemExit(f"hybrid_force: parameter {name}: {exc}") from None
            if isinstance(default, float) and isinstance(value, int) \
                    and not isinstance(value, bool):
                value = float(value)          # -p rate:=200 is fine for a double
            if type(value) is not type(default) and not isinstance(default, list):
                raise SystemExit(f"hybrid_force: parameter {name} must be of the type of "
                                 f"{default!r}, got {value!r}")
            problem = check.check(value) if check is not None else None
            if problem:
                raise SystemExit(f"hybrid_force: parameter {name}={value!r} {problem}")
            out[name] = list(value) if isinstance(default, list) else value
        return out

    def _on_parameters(self, params) -> SetParametersResult:
        values = {p.name: p.value for p in params}
        if not set(values) & set(DYNAMIC):
            return SetParametersResult(successful=True)
        mass = values.get("payload_mass", self.get_parameter("payload_mass").value)
        com = values.get("payload_com", self.get_parameter("payload_com").value)
        try:
            self._ctl.set_payload(mass, list(com))
        except (ForceError, TypeError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self.get_logger().info(f"payload {mass:g} kg at {list(com)} m (tool0)")
        return SetParametersResult(successful=True)

    # -- inputs -----------------------------------------------------------------------------
    def _on_joint_states(self, msg: JointState) -> None:
        dropped = self._ctl.check_state(stamp_seconds(msg.header.stamp), self._now(), msg.name,
                                        msg.position, msg.velocity, msg.effort)
        if dropped is not None:
            self._warn_dropped(*dropped)
            return
        if not self._input.merge(msg):
            return
        if any(n in self._ctl.arm_names for n in msg.name):
            self._state_time = now = self._now()    # staleness counts from the arrival
            self._stamp = msg.header.stamp
            if not self._timer_trigger:
                self._cycle(now)

    def _cycle(self, now: float | None = None) -> None:
        names = self._ctl.names
        if self._state_time is None or not self._cache.has(names):
            return
        c = self._cache
        q = [c.position[n] for n in names]
        dq = [c.velocity.get(n, 0.0) for n in names]
        effort = [c.effort[n] for n in self._ctl.arm_names if n in c.effort]
        t0 = time.perf_counter()
        try:
            out, event = self._ctl.control(self._now() if now is None else now, q, dq,
                                           effort, self._state_time)
        except ForceError as exc:
            if (text := self._log_throttle.message(f"control cycle skipped: {exc}")):
                self.get_logger().warn(text)
            return
        if out.positions is not None or out.efforts is not None:
            cmd = self._cmd_msg       # one message (names set once), stamped with the state;
            # array('d'): rclpy's setters skip their per-element checks
            cmd.header.stamp = self._stamp or self.get_clock().now().to_msg()
            cmd.position = array("d", out.positions or ())
            cmd.effort = array("d", out.efforts or ())
            self._cmd.publish(cmd)
        self._ctl.estimate(out)       # after the command: not on its latency path
        self._compute_time = time.perf_counter() - t0
        self._handle(event)
        self._publish_wrench(out, self._stamp)

    def _warn_dropped(self, reason: str, text: str) -> None:
        """A dropped input, logged throttled per reason (stream and kind)."""
        if (line := self._log_throttle.message(text, reason)):
            self.get_logger().warn(line)

    def _on_goal(self, msg: HybridGoal) -> None:
        dropped = self._ctl.check_goal(stamp_seconds(msg.header.stamp), self._now())
        if dropped is not None:
            self._warn_dropped(*dropped)
            return
        p, o, w = msg.pose.position, msg.pose.orientation, msg.wrench
        goal, event = self._ctl.on_goal(
            msg.header.frame_id, [p.x, p.y, p.z], [o.x, o.y, o.z, o.w], list(msg.stiffness),
            list(msg.force_controlled),
            [w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z])
        if goal is None and event is None:
            if (text := self._log_throttle.message("hybrid_goal ignored: not enabled")):
                self.get_logger().warn(text)
        self._handle(event)

    def _check_stale(self) -> None:
        self._handle(self._ctl.check_stale(self._now()))

    # -- services ---------------------------------------------------------------------------
    def _on_enable(self, req: SetBool.Request, res: SetBool.Response) -> SetBool.Response:
        try:
            event = self._ctl.enable(bool(req.data), self._now())
        except ForceError as exc:
            res.success, res.message = False, f"cannot enable: {exc}"
            self.get_logger().error(res.message)
            return res
        self._handle(event)
        res.success, res.message = True, event.message
        return res

    def _on_tare(self, req: Trigger.Request, res: Trigger.Response) -> Trigger.Response:
        try:
            res.message = self._ctl.tare()
            res.success = True
        except ForceError as exc:
            res.success, res.message = False, f"tare: {exc}"
        self.get_logger().info(res.message)
        return res

    def _on_compliance(self, req: SetBool.Request, res: SetBool.Response) -> SetBool.Response:
        event = self._ctl.set_compliance(bool(req.data))
        self._handle(event)
        res.success, res.message = True, event.message
        return res

    # -- outputs ----------------------------------------------------------------------------
    def _handle(self, event: Event | None) -> None:
        """Log an event once (one call site per severity) and call hold once if asked."""
        if event is None:
            return
        if event.level == "warn":
            self.get_logger().warn(event.message)
        else:
            self.get_logger().info(event.message)
        if event.hold and event.kind != "stale" and self._hold_arm_here():
            pass
        elif event.hold:
            if self._hold.service_is_ready():
                self._hold.call_async(Trigger.Request())
            else:
                self.get_logger().error(f"driver's {contract.HOLD} service not available: "
                                        "the arm keeps its last command")
        self._publish_diagnostics()

    def _hold_arm_here(self) -> bool:
        """Hold the ARM joints where they are (one position command) from fresh joint
        states; False if they are not fresh. Not the driver's hold service: that holds every
        joint where it is, the gripper too, whose fingers then stop squeezing a held block
        (and, called asynchronously, it landed after the task's next commands)."""
        names, c = self._ctl.arm_names, self._cache
        fresh = (self._state_time is not None and c.has(names)
                 and self._now() - self._state_time <= self._ctl.config.stale_timeout)
        if not fresh:
            return False
        cmd = JointState()
        cmd.header.stamp = self.get_clock().now().to_msg()
        cmd.name = list(names)
        cmd.position = [float(c.position[n]) for n in names]
        self._cmd.publish(cmd)
        return True

    def _publish_wrench(self, out: Output, stamp) -> None:
        msg = WrenchStamped()
        msg.header.stamp = stamp if stamp is not None else self.get_clock().now().to_msg()
        for pub, frame, w in ((self._w_tool, self._kin.desc.tool_frame, out.wrench_tool),
                              (self._w_base, self._base, self._in_base(out.wrench_root))):
            msg.header.frame_id = frame
            f, t = msg.wrench.force, msg.wrench.torque
            f.x, f.y, f.z, t.x, t.y, t.z = (float(v) for v in w)
            pub.publish(msg)

    def _in_base(self, w_root: np.ndarray) -> np.ndarray:
        if self._root == self._base:
            return w_root
        rt = self._ctl.base_rotation().T
        return np.concatenate((rt @ w_root[:3], rt @ w_root[3:]))

    def _publish_diagnostics(self) -> None:
        ctl, s = self._ctl, self._ctl.stats
        values = {"mode": ctl.mode.value, "reason": ctl.reason, "output": ctl.config.output,
                  "compliance": ctl.compliance, "cycles": s.cycles,
                  "compute_ms": f"{self._compute_time * 1e3:.3f}",
                  "wrench_limited": s.wrench_limited, "joint_limited": s.joint_limited,
                  "rate_limited": s.rate_limited, "step_limited": s.step_limited,
                  "last_event": s.last_event,
                  "payload_kg": ctl.law.payload.mass,
                  "last_state_s": f"{self._state_time or 0.0:.6f}",
                  **ctl.input_counts()}
        cov = ctl.covariance_tool()
        if cov is not None:    # 1-sigma of the estimate from the effort noise (tool0 axes)
            sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
            values["wrench_std_tool"] = " ".join(f"{v:.3g}" for v in sd)
        st = DiagnosticStatus(level=bytes([_LEVEL[ctl.mode]]), name="hybrid_force",
                              hardware_id="hybrid_force", message=f"{ctl.mode.value}: "
                              f"{ctl.reason}",
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag.publish(arr)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9


def main(args: list[str] | None = None) -> None:
    run_node(HybridForceNode, args, executor="events", parameters=PARAMETERS)


if __name__ == "__main__":
    main()
