"""pmac_rail_driver: the rail joint of the rail_arm variant, on a Delta Tau Turbo PMAC.

Thin ROS wrapper around :class:`hyperarm_driver.pmac.driver.RailDriver` (which owns the TCP
link in its own thread): publishes the ``rail`` joint on ``joint_states``, applies ``rail``
setpoints from ``joint_command``, serves ``rail/home``, ``rail/hold`` and ``rail/set_torque``
(the arm driver owns ``hold`` and ``set_torque``: one owner per service on rail_arm) and
reports on ``/diagnostics``. Parameters and behaviour: docs/pmac.md.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from hyperarm_description import contract
from hyperarm_description.joints import velocity_problem
from hyperarm_description.model import DescriptionError, load_description
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import run_node

from .common import NonEmpty, ParamSpec, Range, declare_parameters, diagnostic_status
from .pmac.axis import RailAxis, RailConfig
from .pmac.client import PmacClient
from .log_throttle import ReasonThrottle
from .pmac.driver import RailDriver, check_command, reason_key
from .pmac.errors import PmacError, RailError
from .pmac.watchdog import WatchdogConfig

NODE_NAME = "pmac_rail_driver"
_SERVICE_TIMEOUT = 1.0   # s, wait for the worker to run a service request

PARAMETERS: ParamSpec = {
    "variant": ("rail_arm", "robot variant; only rail_arm has a rail", None),
    "description_file": ("", "robot description YAML ('' = the packaged one)", None),
    "host": ("127.0.0.1", "PMAC IP address", NonEmpty()),
    "port": (1025, "PMAC TCP port", Range(1, 65535)),
    "motor": (0, "PMAC motor number 1..32; 0 = from the description (rail.pmac.motor)",
              Range(0, 32)),
    "counts_per_metre": (0.0, "encoder counts per metre; 0 = from the description "
                              "(rail.pmac.counts_per_metre); negative flips the direction", None),
    "rate": (50.0, "status poll and joint_states rate, Hz", Range(5.0, 500.0)),
    "timeout": (0.1, "reply timeout of one command, s (link loss detected within "
                     "timeout + 1/rate)", Range(0.005, 0.4)),
    "reconnect_period": (1.0, "delay between reconnection attempts, s", Range(0.05, 60.0)),
    "require_homing": (True, "refuse setpoints until the card reports home complete", None),
    "configure_card": (True, "on every (re)connect set I3=2 I6=1 I64=1, write jog "
                             "speed/acceleration (Ixx22, Ixx19, Ixx20, Ixx21) and soft limits "
                             "(Ixx13, Ixx14) and download the safety PLC; false: only check "
                             "I3/I6/I64", None),
    "watchdog_timeout": (0.5, "on-card watchdog: the safety PLC stops the rail when the "
                              "driver's heartbeat stops for this long, s; 0 = no safety PLC "
                              "(needs configure_card)", Range(0.0, 10.0)),
    "watchdog_plc": (10, "PLC program number of the safety PLC", Range(1, 31)),
    "watchdog_pvar": (8001, "first of the three P-variables of the safety PLC (heartbeat, "
                            "seen, armed)", Range(0, 8189)),
    "watchdog_mvar": (8140, "first of the three M-variables of the safety PLC (status bits: "
                            "fatal following error, amplifier fault, open loop)",
                      Range(0, 8189)),
    "log_period": (10.0, "the same problem (unreachable card, rejected setpoint reason) is "
                         "logged at most once per this period, s", Range(0.1, 3600.0)),
    "diagnostics_period": (0.5, "/diagnostics period, s", Range(0.1, 10.0)),
}


class PmacRailDriver(Node):
    """The PMAC rail driver node (see the module docstring and docs/pmac.md)."""

    def __init__(self, **node_kwargs: object) -> None:
        """``node_kwargs`` go to rclpy's Node (``context``, ``parameter_overrides``, ...)."""
        node_kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__(NODE_NAME, **node_kwargs)
        p = self._declare_parameters()
        if p["variant"] != "rail_arm":
            raise SystemExit(f"{NODE_NAME}: variant must be rail_arm (the only one with a "
                             f"rail), got {p['variant']!r}")
        try:
            desc = load_description(p["description_file"] or None, "rail_arm")
            if desc.rail is None:
                raise DescriptionError("the rail_arm variant has no rail")
            config = RailConfig.from_rail(desc.rail, int(p["motor"]),
                                          float(p["counts_per_metre"]))
        except (DescriptionError, RailError) as exc:
            raise SystemExit(f"{NODE_NAME}: {exc}") from exc
        self._joint = desc.rail.name
        client = PmacClient(p["host"], int(p["port"]), timeout=float(p["timeout"]),
                            connect_timeout=max(0.2, min(2.0, float(p["reconnect_period"]))))
        try:
            watchdog = None
            if p["watchdog_timeout"] > 0:
                if not p["configure_card"]:
                    raise ValueError("watchdog_timeout > 0 needs configure_card (the driver "
                                     "downloads the safety PLC); set watchdog_timeout:=0.0")
                pv = int(p["watchdog_pvar"])
                watchdog = WatchdogConfig(plc=int(p["watchdog_plc"]), heartbeat=pv, seen=pv + 1,
                                          armed=pv + 2, mvar=int(p["watchdog_mvar"]),
                                          timeout=float(p["watchdog_timeout"]))
            self._driver = RailDriver(RailAxis(client, config, watchdog=watchdog),
                                      rate=float(p["rate"]),
                                      reconnect_period=float(p["reconnect_period"]),
                                      require_homing=bool(p["require_homing"]),
                                      configure_card=bool(p["configure_card"]),
                                      log=self._on_event, log_period=float(p["log_period"]))
        except (ValueError, RailError) as exc:
            raise SystemExit(f"{NODE_NAME}: {exc}") from exc
        self._rejections = ReasonThrottle(float(p["log_period"]))
        self._last_stamp = 0.0
        self._reported: tuple[int, tuple[str, ...]] = (0, ())   # in the last /diagnostics
        self._js_pub = self.create_publisher(JointState, contract.JOINT_STATES,
                                             qos_for(contract.JOINT_STATES))
        self._diag_pub = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                               qos_for(contract.DIAGNOSTICS))
        self.create_subscription(JointState, contract.JOINT_COMMAND, self._on_command,
                                 qos_for(contract.JOINT_COMMAND))
        self.create_service(Trigger, contract.RAIL_HOME, self._on_home)
        self.create_service(Trigger, contract.RAIL_HOLD, self._on_hold)
        self.create_service(SetBool, contract.RAIL_SET_TORQUE, self._on_torque)
        self.create_timer(1.0 / float(p["rate"]), self._publish_state)
        self.create_timer(float(p["diagnostics_period"]), self._publish_diagnostics)
        self._driver.start()
        self.get_logger().info(
            f"{NODE_NAME}: PMAC {client.endpoint} motor {config.motor}, "
            f"{config.counts_per_metre:g} counts/m, limits [{config.lower:g}, {config.upper:g}] m,"
            f" {p['rate']:g} Hz, homing {'required' if p['require_homing'] else 'not required'}"
            + (f", watchdog {p['watchdog_timeout'] * 1e3:g} ms" if watchdog else ", no watchdog"))

    def _declare_parameters(self) -> dict[str, object]:
        return declare_parameters(self, PARAMETERS)

    def _on_event(self, level: str, message: str) -> None:
        # (rclpy fixes one severity per call site: one call per level)
        if level == "info":
            self.get_logger().info(message)
        elif level == "warn":
            self.get_logger().warning(message)
        else:
            self.get_logger().error(message)

    # -- topics ---------------------------------------------------------------------------
    def _on_command(self, msg: JointState) -> None:
        names = list(msg.name)
        if self._joint not in names:
            return                     # other drivers' joints
        try:
            problem = (check_command(names, msg.position, msg.effort, self._joint)
                       or velocity_problem(names, msg.velocity))
            if problem:
                self._driver.reject(problem)
            self._driver.set_target(msg.position[names.index(self._joint)])
        except RailError as exc:
            # throttled per reason (numbers aside), so that one problem never hides another
            if self._rejections.allow(reason_key(str(exc))):
                self.get_logger().error(f"rail setpoint rejected, nothing sent: {exc}")

    def _publish_state(self) -> None:
        snap = self._driver.snapshot()
        # a refused setpoint or a new latched fault (a watchdog trip) goes out on
        # /diagnostics at once, not at the next diagnostics_period: the commanding client
        # learns why its setpoints are not followed (docs/pmac.md, "Refusals")
        if (snap.rejected_setpoints, snap.latched) != self._reported:
            self._publish_diagnostics()
        if not snap.link_up or snap.state is None or snap.stamp == self._last_stamp:
            return
        self._last_stamp = snap.stamp
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = [self._joint]
        msg.position = [snap.state.position]
        msg.velocity = [snap.state.velocity]
        self._js_pub.publish(msg)

    def _publish_diagnostics(self) -> None:
        snap = self._driver.snapshot()
        self._reported = (snap.rejected_setpoints, snap.latched)
        level, message, kv = snap.diagnostic()
        status = diagnostic_status(f"{NODE_NAME}: {self._joint}",
                                   f"pmac@{snap.endpoint}#{snap.motor}", level, message, kv)
        out = DiagnosticArray()
        out.header.stamp = self.get_clock().now().to_msg()
        out.status = [status]
        self._diag_pub.publish(out)

    # -- services -------------------------------------------------------------------------
    def _run(self, kind: str, response):  # Trigger.Response | SetBool.Response
        try:
            response.message = self._driver.request(kind, timeout=_SERVICE_TIMEOUT)
            response.success = True
        except (PmacError, ValueError) as exc:
            response.success, response.message = False, f"{kind} refused: {exc}"
            self.get_logger().warning(response.message)
        return response

    def _on_home(self, request: Trigger.Request, response: Trigger.Response):
        return self._run("home", response)

    def _on_hold(self, request: Trigger.Request, response: Trigger.Response):
        return self._run("hold", response)

    def _on_torque(self, request: SetBool.Request, response: SetBool.Response):
        return self._run("enable" if request.data else "kill", response)

    def destroy_node(self) -> None:
        self._driver.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(PmacRailDriver, args, parameters=PARAMETERS, robot_description=False)


if __name__ == "__main__":
    main()
