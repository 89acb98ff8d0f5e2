"""Node tier: dynamixel_driver in-process (executor) against dxl_emulator on a pty; plus one
end-to-end run of the installed executables (clean Ctrl-C with the release policy)."""
from __future__ import annotations

import signal
import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from hyperarm_description import contract
from hyperarm_description.qos import qos_for
from hyperarm_driver.dynamixel.emulator import EmulatorControl
from hyperarm_driver.dynamixel.testing import EmulatorProcess
from hyperarm_driver.dynamixel_driver_node import DynamixelDriverNode
from hyperarm_interfaces.srv import Reboot

NAMES = [f"joint{i}" for i in range(1, 10)] + ["gripper"]


class Probe:
    """A client node: latest joint_states and diagnostics, command publisher, services."""

    def __init__(self, executor, context):
        from rclpy.node import Node

        self.node = Node("dxl_probe", namespace=contract.DEFAULT_NAMESPACE, context=context)
        self.states: list[JointState] = []
        self.diag: dict[str, dict] = {}
        self.node.create_subscription(JointState, contract.JOINT_STATES, self.states.append,
                                      qos_for(contract.JOINT_STATES))
        self.node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, self._on_diag,
                                      qos_for(contract.DIAGNOSTICS))
        self.cmd = self.node.create_publisher(JointState, contract.JOINT_COMMAND,
                                              qos_for(contract.JOINT_COMMAND))
        self.clients = {
            "torque": self.node.create_client(SetBool, contract.SET_TORQUE),
            "reboot": self.node.create_client(Reboot, contract.REBOOT),
            "hold": self.node.create_client(Trigger, contract.HOLD),
        }
        executor.add_node(self.node)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            self.diag[st.name] = {"level": ord(st.level), "message": st.message,
                                  **{kv.key: kv.value for kv in st.values}}

    def call(self, which: str, request, wait_for, timeout: float = 10.0):
        client = self.clients[which]
        wait_for(lambda: client.service_is_ready(), timeout, what=f"{which} service")
        fut = client.call_async(request)
        wait_for(fut.done, timeout, what=f"{which} response")
        return fut.result()

    def position(self, name: str) -> float | None:
        if not self.states:
            return None
        msg = self.states[-1]
        return msg.position[list(msg.name).index(name)]

    def command(self, names, position=(), effort=()):
        self.cmd.publish(JointState(name=list(names), position=list(position),
                                    effort=list(effort)))


@pytest.fixture
def emu(tmp_path):
    with EmulatorProcess(workdir=tmp_path) as e:
        yield e


def start_node(executor, rclpy_context, emu, **params):
    overrides = [Parameter("port", value=emu.link), Parameter("diagnostics_period", value=0.2),
                 Parameter("reconnect_period", value=0.1)]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    node = DynamixelDriverNode(context=rclpy_context, parameter_overrides=overrides)
    executor.add_node(node)
    return node


@pytest.mark.node
def test_node_states_commands_torque_hold(executor, rclpy_context, emu, wait_for):
    node = start_node(executor, rclpy_context, emu)
    probe = Probe(executor, rclpy_context)
    wait_for(lambda: probe.states, 10.0, what="joint_states")
    assert list(probe.states[-1].name) == NAMES
    res = probe.call("torque", SetBool.Request(data=True), wait_for)
    assert res.success, res.message
    wait_for(lambda: all(emu.ctl("state")["servos"][str(i)]["torque_enable"] == 1
                         for i in range(1, 11)), 5.0, what="torque on in the servos")

    def send_until(cond, what, names, position=(), effort=()):
        def go():
            probe.command(names, position, effort)
            return cond()
        wait_for(go, 10.0, period=0.05, what=what)

    send_until(lambda: abs(probe.position("joint1") - 0.3) < 3e-3, "joint1 at 0.3",
               ["joint1"], [0.3])
    # a NaN or unknown-joint command is rejected whole: joint2 does not move to 0.5
    for k, (names, pos) in enumerate(((["joint2", "joint3"], [0.5, float("nan")]),
                                      (["joint2", "elbow"], [0.5, 0.1])), start=1):
        probe.command(names, pos)   # (one at a time: joint_command keeps only the newest)
        wait_for(lambda: node.rejected_commands == k, 5.0, what=f"rejection of {names} {pos}")
    n = len(probe.states)
    wait_for(lambda: len(probe.states) > n + 3, 5.0, what="cycles after the rejections")
    assert abs(probe.position("joint2")) < 3e-3
    # effort only -> current mode on the servo; hold -> back to position mode
    send_until(lambda: emu.ctl("state")["servos"]["5"]["operating_mode"] == 0,
               "joint5 in current mode", ["joint5"], effort=[0.2])
    res = probe.call("hold", Trigger.Request(), wait_for)
    assert res.success
    wait_for(lambda: emu.ctl("state")["servos"]["5"]["operating_mode"] == 5, 5.0,
             what="joint5 back in current-based position mode")
    res = probe.call("torque", SetBool.Request(data=False), wait_for)
    assert res.success
    assert all(emu.ctl("state")["servos"][str(i)]["torque_enable"] == 0 for i in range(1, 11))


@pytest.mark.node
@pytest.mark.parametrize("name,value,problem", [
    ("baud", 1e6, "must be an integer"), ("port", 5, "must be a string"),
    ("rate", 2000.0, "not within 1..1000"), ("shutdown_torque", "drop", "not one of hold"),
    ("torque_on_start", "yes", "must be a bool"), ("port", "", "must not be empty"),
    ("command_timeout", float("nan"), "must be finite")])
def test_node_rejects_bad_parameters_with_a_clear_error(rclpy_context, name, value, problem):
    with pytest.raises(SystemExit) as info:
        DynamixelDriverNode(context=rclpy_context,
                            parameter_overrides=[Parameter(name, value=value)])
    text = str(info.value)
    assert text.startswith(f"dynamixel_driver: parameter {name}") and problem in text, text


@pytest.mark.node
def test_node_takes_an_integer_rate_and_waits_for_a_missing_port(rclpy_context, tmp_path):
    node = DynamixelDriverNode(context=rclpy_context, parameter_overrides=[
        Parameter("port", value=str(tmp_path / "ttyNONE")), Parameter("rate", value=50)])
    try:
        assert node._period == pytest.approx(0.02) and not node._drv.connected
        assert "ttyNONE" in node._drv.last_error
    finally:
        node.destroy_node()


@pytest.mark.node
def test_node_hardware_error_diagnostics_and_smart_reboot(executor, rclpy_context, emu,
                                                          wait_for):
    start_node(executor, rclpy_context, emu)
    probe = Probe(executor, rclpy_context)
    wait_for(lambda: probe.diag.get("dynamixel_driver: bus", {}).get("connected") == "True",
             10.0, what="bus diagnostics")
    emu.ctl("fault", id=8, bits=0x04)
    d = wait_for(lambda: probe.diag.get("dynamixel_driver: joint8", {}).get(
        "hardware_error") == "overheating" and probe.diag["dynamixel_driver: joint8"],
        5.0, what="joint8 overheating in diagnostics")
    assert d["level"] == 2 and d["temperature_C"] == "85" and d["model"] == "XM430-W350"
    assert probe.diag["dynamixel_driver: joint7"]["hardware_error"] == "none"
    res = probe.call("torque", SetBool.Request(data=True), wait_for)
    assert not res.success and "joint8: overheating" in res.message
    res = probe.call("reboot", Reboot.Request(joints=[]), wait_for)
    assert res.success and list(res.rebooted) == ["joint8"]
    wait_for(lambda: probe.diag["dynamixel_driver: joint8"]["hardware_error"] == "none", 5.0,
             what="error cleared")
    res = probe.call("reboot", Reboot.Request(joints=["nope"]), wait_for)
    assert not res.success and "unknown joint" in res.message


@pytest.mark.node
def test_node_port_loss_reported_and_reconnects_torque_off(executor, rclpy_context, emu,
                                                           wait_for):
    start_node(executor, rclpy_context, emu, torque_on_start=True)
    probe = Probe(executor, rclpy_context)
    wait_for(lambda: probe.diag.get("dynamixel_driver: bus", {}).get("connected") == "True",
             10.0, what="bus diagnostics")
    assert emu.ctl("state")["servos"]["1"]["torque_enable"] == 1
    emu.ctl("disappear", seconds=1.0)
    bus = wait_for(lambda: probe.diag["dynamixel_driver: bus"]["connected"] == "False"
                   and probe.diag["dynamixel_driver: bus"], 5.0, what="port down reported")
    assert bus["level"] == 2 and bus["message"].startswith("port down")
    assert emu.link in bus["last_error"]  # lost, or cannot be reopened yet: names the port
    assert probe.diag["dynamixel_driver: joint1"]["level"] == 3  # STALE
    res = probe.call("torque", SetBool.Request(data=True), wait_for)
    assert not res.success and "down" in res.message
    wait_for(lambda: probe.diag["dynamixel_driver: bus"]["connected"] == "True", 10.0,
             what="reconnected")
    assert probe.diag["dynamixel_driver: bus"]["reconnects"] == "1"
    assert all(emu.ctl("state")["servos"][str(i)]["torque_enable"] == 0 for i in range(1, 11))
    n = len(probe.states)
    wait_for(lambda: len(probe.states) > n + 5, 5.0, what="joint_states again")


@pytest.mark.e2e
@pytest.mark.slow
def test_e2e_installed_executables_and_release_on_ctrl_c(launch, tmp_path, wait_for,
                                                         executor, rclpy_context):
    link, ctl = str(tmp_path / "ttyDXL"), str(tmp_path / "ctl")
    emu = launch("hyperarm_driver", "dxl_emulator", "--link", link, "--control", ctl)
    wait_for(lambda: (tmp_path / "ctl").exists(), 20.0, what="emulator control socket")
    control = EmulatorControl(ctl)
    drv = launch("hyperarm_driver", "dynamixel_driver",
                 params={"port": link, "torque_on_start": True, "shutdown_torque": "release"})
    probe = Probe(executor, rclpy_context)
    wait_for(lambda: len(probe.states) > 10, 30.0, what="joint_states from the driver process")
    assert list(probe.states[-1].name) == NAMES
    assert control("state")["servos"]["3"]["torque_enable"] == 1
    drv.proc.send_signal(signal.SIGINT)
    assert drv.proc.wait(timeout=15.0) in (0, -signal.SIGINT), drv.output()[-2000:]
    servos = control("state")["servos"]
    assert all(servos[str(i)]["torque_enable"] == 0 for i in range(1, 11)), drv.output()[-2000:]
    control.close()
    assert "10 servos" in emu.output()
