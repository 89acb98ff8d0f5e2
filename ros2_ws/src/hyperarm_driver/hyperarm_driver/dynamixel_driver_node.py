"""dynamixel_driver: the arm's Dynamixel bus as a ROS 2 node (thin; logic in .dynamixel).

See docs/dynamixel.md for the parameters, topics, services and diagnostics.
"""
from __future__ import annotations

import logging

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from hyperarm_description import contract
from hyperarm_description.joints import velocity_problem
from hyperarm_description.model import DescriptionError, load_description
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import run_node
from hyperarm_interfaces.srv import Reboot

from .common import (NonEmpty, OneOf, ParamSpec, Range, answer_reboot, answer_set_torque,
                     declare_parameters, diagnostic_status)
from .dynamixel.bus import DynamixelBus, ftdi_latency_timer
from .dynamixel.config import bus_config_from_description
from .dynamixel.driver import DynamixelDriver
from .dynamixel.errors import CommandError, DynamixelError, StartupError
from .log_throttle import ReasonThrottle

_SDK_BAUDS = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600,
              1000000, 1152000, 2000000, 2500000, 3000000, 3500000, 4000000)

PARAMETERS: ParamSpec = {
    "port": ("/dev/ttyUSB0", "serial device of the Dynamixel bus", NonEmpty()),
    "baud": (1000000, "bus baud rate", OneOf(_SDK_BAUDS)),
    "rate": (100.0, "control cycle and joint_states rate, Hz", Range(1.0, 1000.0)),
    "description_file": ("", "robot description YAML ('' = the packaged one)", None),
    "command_timeout": (0.5, "effort watchdog: current-controlled joints hold their position "
                             "when no effort command came for this long, s", Range(0.05, 10.0)),
    "torque_on_start": (False, "enable torque after the start-up check", None),
    "shutdown_torque": ("hold", "on shutdown: 'hold' (torque on, hold position) or 'release' "
                                "(torque off)", OneOf(("hold", "release"))),
    "fast_sync_read": (True, "use Fast Sync Read when available", None),
    "reconnect_period": (0.5, "delay between reopening attempts of a lost port, s",
                         Range(0.05, 60.0)),
    "diagnostics_period": (1.0, "/diagnostics period, s", Range(0.1, 10.0)),
}


class DynamixelDriverNode(Node):
    """Publishes ``joint_states``, applies ``joint_command``; services and diagnostics."""

    def __init__(self, **kwargs) -> None:  # kwargs: rclpy Node options (context, overrides)
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("dynamixel_driver", **kwargs)
        p = self._declare_parameters()
        try:
            desc = load_description(p["description_file"] or None)
            config = bus_config_from_description(desc)
            bus = DynamixelBus(config, p["port"], p["baud"], fast_sync_read=p["fast_sync_read"])
            self._drv = DynamixelDriver(bus, command_timeout=p["command_timeout"],
                                        reconnect_period=p["reconnect_period"],
                                        other_joints=(contract.RAIL_JOINT,))
        except (DescriptionError, DynamixelError, ValueError) as exc:
            raise SystemExit(f"dynamixel_driver: {exc}") from exc
        self._shutdown_torque = p["shutdown_torque"]
        self._period = 1.0 / p["rate"]
        self._diag_period = p["diagnostics_period"]
        self.rejected_commands = 0   # joint_command messages rejected whole (NaN, ...)
        self._throttle = ReasonThrottle(1.0)   # command logs: once a second per reason
        self._pub = self.create_publisher(JointState, contract.JOINT_STATES,
                                          qos_for(contract.JOINT_STATES))
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS))
        self.create_subscription(JointState, contract.JOINT_COMMAND, self._on_command,
                                 qos_for(contract.JOINT_COMMAND))
        self.create_service(SetBool, contract.SET_TORQUE, self._on_set_torque)
        self.create_service(Reboot, contract.REBOOT, self._on_reboot)
        self.create_service(Trigger, contract.HOLD, self._on_hold)
        latency = ftdi_latency_timer(p["port"])
        if latency is not None and latency > 1:
            self.get_logger().warn(
                f"{p['port']}: FTDI latency_timer is {latency} ms, each bus transaction will "
                "wait that long; set it to 1 (docs/dynamixel.md, udev rule)")
        #: torque_on_start still to apply: at the first connection, even one that comes only
        #: after retries (servos powered after the driver started); never at a reconnection
        #: after a lost link, which leaves torque off until someone turns it on
        self._torque_on_start = bool(p["torque_on_start"])
        try:
            self._drv.connect()
        except StartupError as exc:
            raise SystemExit(f"dynamixel_driver: {exc}") from exc
        except DynamixelError as exc:
            self.get_logger().error(f"{exc}; retrying every {p['reconnect_period']:g} s")
        else:
            self.get_logger().info(
                f"{len(config.joints)} servos on {p['port']} at {p['baud']} baud, "
                f"{'fast' if bus.fast else 'plain'} sync read, {p['rate']:g} Hz; torque off")
            self._apply_torque_on_start()
        self.create_timer(self._period, self._tick)
        self.create_timer(self._diag_period, self._publish_diagnostics)

    def _declare_parameters(self) -> dict:
        return declare_parameters(self, PARAMETERS)

    def _apply_torque_on_start(self) -> None:
        if not self._torque_on_start:
            return
        self._torque_on_start = False
        try:
            self._drv.set_torque(True)
            self.get_logger().info("torque on (torque_on_start)")
        except DynamixelError as exc:
            self.get_logger().error(f"torque_on_start: {exc}; torque stays off")

    # -- cycle -------------------------------------------------------------------------------
    def _tick(self) -> None:
        was_up = self._drv.connected
        state = self._drv.cycle()
        if not was_up and self._drv.connected:
            self._apply_torque_on_start()      # the first connection came only now
        for level, event in self._drv.pop_events():
            if level >= logging.ERROR:
                self.get_logger().error(event)
            elif level >= logging.WARNING:
                self.get_logger().warn(event)
            elif level >= logging.INFO:
                self.get_logger().info(event)
            else:
                self.get_logger().debug(event)
        if was_up and not self._drv.connected:
            self.get_logger().error(f"Dynamixel port lost: {self._drv.last_error}")
        if state is None:
            if not self._drv.connected:
                self.get_logger().warn(f"port down: {self._drv.last_error}",
                                       throttle_duration_sec=5.0)
            else:
                self.get_logger().warn(f"bus read failed: {self._drv.last_error}",
                                       throttle_duration_sec=2.0)
            return
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = self._drv.names
        msg.position = state.position.tolist()
        msg.velocity = state.velocity.tolist()
        msg.effort = state.effort.tolist()
        self._pub.publish(msg)
        errs = self._drv.hardware_errors()
        if errs:
            self.get_logger().error(
                "hardware error: " + "; ".join(f"{n}: {', '.join(b)}" for n, b in errs.items()),
                throttle_duration_sec=2.0)

    def _throttled(self, reason: str) -> str | None:
        """None if ``reason`` was logged less than a second ago, else a suffix counting the
        messages of that reason suppressed meanwhile (throttling is per reason)."""
        if not self._throttle.allow(reason):
            return None
        n = self._throttle.suppressed(reason)
        return f" ({n} more since the last report)" if n else ""

    def _on_command(self, msg: JointState) -> None:
        try:
            if (problem := velocity_problem(msg.name, msg.velocity)):
                raise CommandError(problem, "velocity")
            report = self._drv.command(list(msg.name), list(msg.position), list(msg.effort))
        except CommandError as exc:
            self.rejected_commands += 1
            more = self._throttled(f"rejected:{exc.reason}")
            if more is not None:
                self.get_logger().error(f"joint_command rejected: {exc}{more}")
            return
        warnings = []
        if report.clamped:
            warnings.append(("clamped", f"joint_command clamped to joint limits: "
                                        f"{report.clamped}"))
        if report.effort_clamped:
            warnings.append(("effort_clamped", "joint_command effort clamped to the servo "
                                               f"limit: {report.effort_clamped}"))
        if report.port_down:
            warnings.append(("port_down", "joint_command dropped: the Dynamixel port is down "
                                          f"({self._drv.last_error})"))
        elif report.torque_off:
            warnings.append(("torque_off", f"joint_command for {report.torque_off} dropped: "
                                           "torque is off (set_torque true first)"))
        for reason, text in warnings:
            more = self._throttled(reason)
            if more is not None:
                self.get_logger().warn(text + more)

    # -- services ----------------------------------------------------------------------------
    def _on_set_torque(self, req: SetBool.Request, res: SetBool.Response) -> SetBool.Response:
        return answer_set_torque(self, req.data, self._drv.set_torque, (DynamixelError,), res)

    def _on_reboot(self, req: Reboot.Request, res: Reboot.Response) -> Reboot.Response:
        return answer_reboot(self, req.joints, self._drv.reboot, (DynamixelError,), res)

    def _on_hold(self, req: Trigger.Request, res: Trigger.Response) -> Trigger.Response:
        try:
            self._drv.hold()
        except DynamixelError as exc:
            res.success, res.message = False, f"hold: {exc}"
            return res
        res.success, res.message = True, "holding the present position"
        return res

    # -- diagnostics -------------------------------------------------------------------------
    def _publish_diagnostics(self) -> None:
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [diagnostic_status(st.name, st.hardware_id, st.level, st.message, st.values)
                      for st in self._drv.diagnostics("dynamixel_driver", self._diag_period)]
        self._diag.publish(arr)

    def destroy_node(self) -> None:
        try:
            self._drv.shutdown(self._shutdown_torque)
        except AttributeError:
            pass  # failed in __init__ before the driver existed
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(DynamixelDriverNode, args, parameters=PARAMETERS, robot_description=False)


if __name__ == "__main__":
    main()
