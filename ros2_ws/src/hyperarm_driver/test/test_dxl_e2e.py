"""e2e tier: the installed ``dynamixel_driver`` on the installed ``dxl_emulator`` (issue 17,
Dynamixel driver): a NaN in another driver's joint, the effort-0 rule, the servo's own torque
state in /diagnostics, logs per reason and for commands dropped with torque off, the brake
before a limit in torque mode and the operating-mode switches, all over real DDS."""
from __future__ import annotations

import itertools
import math
import re
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool

from hyperarm_description import contract
from hyperarm_description.model import load_description
from hyperarm_description.qos import qos_for
from hyperarm_driver.dynamixel.config import bus_config_from_description
from hyperarm_driver.dynamixel.emulator import EmulatorControl

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

CFG = bus_config_from_description(load_description())


class Client:
    """joint_command publisher, /diagnostics and joint_states listener, set_torque client."""

    def __init__(self, executor, context):
        from rclpy.node import Node

        self.node = Node("dxl_e2e_client", namespace=contract.DEFAULT_NAMESPACE,
                         context=context)
        self.diag: dict[str, dict] = {}
        self.states: list[JointState] = []
        self.node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, self._on_diag,
                                      qos_for(contract.DIAGNOSTICS))
        self.node.create_subscription(JointState, contract.JOINT_STATES, self.states.append,
                                      qos_for(contract.JOINT_STATES))
        self.pub = self.node.create_publisher(JointState, contract.JOINT_COMMAND,
                                              qos_for(contract.JOINT_COMMAND))
        self.torque = self.node.create_client(SetBool, contract.SET_TORQUE)
        executor.add_node(self.node)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            self.diag[st.name] = {"level": ord(st.level), "message": st.message,
                                  **{kv.key: kv.value for kv in st.values}}

    def send(self, names, position=(), effort=()):
        self.pub.publish(JointState(name=list(names), position=[float(x) for x in position],
                                    effort=[float(x) for x in effort]))

    def set_torque(self, on: bool, wait_for) -> SetBool.Response:
        wait_for(self.torque.service_is_ready, 20.0, what="set_torque service")
        fut = self.torque.call_async(SetBool.Request(data=on))
        wait_for(fut.done, 10.0, what="set_torque response")
        return fut.result()


def _connect(path: str) -> EmulatorControl | None:
    try:
        return EmulatorControl(path)
    except (FileNotFoundError, ConnectionRefusedError):   # not bound / not listening yet
        return None


def start(launch, tmp_path, wait_for, executor, rclpy_context, **params):
    link, ctl = str(tmp_path / "ttyDXL"), str(tmp_path / "ctl")
    emu = launch("hyperarm_driver", "dxl_emulator", "--link", link, "--control", ctl)
    control = wait_for(lambda: _connect(ctl), 20.0, what="emulator control socket")
    drv = launch("hyperarm_driver", "dynamixel_driver",
                 params={"port": link, "diagnostics_period": 0.2, **params})
    client = Client(executor, rclpy_context)
    wait_for(lambda: client.diag.get("dynamixel_driver: bus", {}).get("connected") == "True"
             and len(client.states) > 3, 30.0, what="the driver process up")
    return emu, control, drv, client


def servo(control, sid: int) -> dict:
    return control("state")["servos"][str(sid)]


def test_e2e_command_rules_torque_state_and_logs(launch, tmp_path, wait_for, executor,
                                                 rclpy_context):
    emu, control, drv, client = start(launch, tmp_path, wait_for, executor, rclpy_context)
    # issue 16: the arm's MX(2.0) servos refuse Fast Sync Read; the node warns and falls back
    wait_for(lambda: re.search(r"\[WARN\].*Fast Sync Read \(0x8A\) failed at start-up.*"
                               r"using plain Sync Read", drv.output()), 10.0,
             what="fallback warning")
    assert client.diag["dynamixel_driver: bus"]["sync_read"] == "plain"
    # torque off: a command is dropped and logged (throttled), nothing moves
    client.send(["joint1"], [0.5])
    wait_for(lambda: "joint_command for ['joint1'] dropped: torque is off" in drv.output(),
             10.0, what="torque-off drop logged")
    assert client.set_torque(True, wait_for).success
    # NaN in the rail's slot (another driver's joint): the whole message is rejected
    control("write_log", clear=True)
    client.send(["joint1", "rail"], [0.9, math.nan])
    wait_for(lambda: "non-finite setpoint for ['rail']" in drv.output(), 10.0,
             what="NaN rejection logged")
    # duplicate, then unknown 0.2 s later: both logged (throttling is per reason)
    client.send(["joint2", "joint2"], [0.1, 0.1])
    wait_for(lambda: "duplicate joint names" in drv.output(), 10.0, what="duplicate logged")
    time.sleep(0.2)
    client.send(["joint2", "elbow"], [0.1, 0.1])
    wait_for(lambda: "unknown joint(s) ['elbow']" in drv.output(), 10.0,
             what="unknown joint logged 0.2 s after the duplicate")
    log = control("write_log")["log"]
    assert log and all(r["value"] == 2048 for r in log
                       if r["id"] == 1 and r["register"] == "goal_position")
    assert servo(control, 1)["present_position"] == 2048      # joint1 did not move
    # position + effort 0 (tools fill effort with zeros): the default limit, not limp
    client.send(["joint2"], [0.3], [0.0])
    s = wait_for(lambda: abs(servo(control, 2)["present_position"]
                             - CFG.joints[1].rad_to_ticks_float(0.3)) <= 2 and servo(control, 2),
                 10.0, what="joint2 at 0.3 rad")
    assert s["operating_mode"] == 5 and s["goal_current"] == CFG.joints[1].model.current_limit
    # position + effort 1 N·m: that limit; then position only: the default limit again, and
    # no operating-mode switch (no torque-off) on the way
    j2 = CFG.joints[1]
    limit = round(1.0 / j2.model.torque_constant / j2.model.current_unit)
    control("write_log", clear=True)
    client.send(["joint2"], [0.2], [1.0])
    wait_for(lambda: servo(control, 2)["goal_current"] == limit, 10.0, what="1 N·m limit")
    client.send(["joint2"], [0.25])
    s = wait_for(lambda: servo(control, 2)["goal_current"] == j2.model.current_limit
                 and servo(control, 2), 10.0, what="default limit after position only")
    assert s["operating_mode"] == 5 and s["torque_enable"] == 1
    assert not [r for r in control("write_log")["log"]
                if r["id"] == 2 and r["register"] in ("torque_enable", "operating_mode")]
    # overload: the servo turns its torque off by itself; /diagnostics says so
    control("fault", id=3, bits=0x20)
    d = wait_for(lambda: client.diag.get("dynamixel_driver: joint3", {}).get("torque") == "off"
                 and client.diag["dynamixel_driver: joint3"], 10.0, what="torque: off")
    assert d["hardware_error"] == "overload" and d["level"] == 2
    assert client.diag["dynamixel_driver: joint2"]["torque"] == "on"
    wait_for(lambda: "servo turned its torque off by itself: joint3 (overload)"
             in drv.output(), 10.0, what="torque drop logged")


def _torque_off_spans(log: list, sid: int) -> list[int]:
    """Cycles (goal SYNC WRITEs, instruction 0x83) each torque-off of servo ``sid`` lasted."""
    spans, open_cycles = [], None
    for r in log:
        if r["id"] != sid:
            continue
        if r["inst"] == 0x83 and r["register"] == "goal_position" and open_cycles is not None:
            open_cycles += 1
        if r["register"] == "torque_enable":
            if r["value"] == 0:
                open_cycles = 0
            elif open_cycles is not None:
                spans.append(open_cycles)
                open_cycles = None
    # (a torque-off still open at the end of the log is a switch in flight when the log
    # was read; the caller checks the servos' torque state itself)
    return spans


def test_e2e_torque_fuzz_near_limits_and_mode_switches(launch, tmp_path, wait_for, executor,
                                                       rclpy_context):
    emu, control, drv, client = start(launch, tmp_path, wait_for, executor, rclpy_context,
                                      torque_on_start=True)
    # joint5 starts 0.2 rad below its upper limit, joint8 0.2 rad above its lower one
    j5, j8 = CFG.joints[4], CFG.joints[7]
    client.send(["joint5", "joint8"], [j5.upper - 0.2, j8.lower + 0.2])
    wait_for(lambda: abs(servo(control, 5)["present_position"]
                         - j5.rad_to_ticks_float(j5.upper - 0.2)) <= 2
             and abs(servo(control, 8)["present_position"]
                     - j8.rad_to_ticks_float(j8.lower + 0.2)) <= 2, 10.0,
             what="joints near their limits")
    for sid in (5, 8):
        control("overshoot", id=sid)
    # lockstep: 10 ms of servo motion per driver cycle, whatever this machine's load does to
    # the scheduling of the three processes (the brake is under test, not the scheduler)
    control("lockstep", dt=0.01)
    control("write_log", clear=True)
    rng = np.random.default_rng(5)
    kinds = 0
    def writes() -> int:
        return control("stats")["instructions"].get("0x83", 0)
    first, t_end = writes(), time.monotonic() + 60.0
    effort = np.zeros(2)

    def limit_zone_reached() -> bool:    # the brake commanded joint5 near its upper limit
        return any(r["id"] == 5 and r["register"] == "goal_position" and r["inst"] == 0x83
                   and r["value"] >= j5.tick_limits[1] - 60
                   for r in control("write_log")["log"])

    # at least 300 driver cycles (3 s of servo time), and on until the random torques have
    # driven joint5 into its limit zone (so the brake is exercised, whatever the load did
    # to the pace of this command stream)
    for k in itertools.count():
        if k % 20 == 0 and writes() - first >= 300 and limit_zone_reached():
            break
        assert time.monotonic() < t_end, ("the driver did not cycle 300 times with joint5 "
                                          "driven into its limit zone in 60 s")
        if rng.random() < 0.1:       # random torques, three times in four toward the limit
            toward = np.where(rng.random(2) < 0.75, 1.0, -1.0) * np.array([1.0, -1.0])
            effort = toward * rng.uniform(0.1, 5.0, 2)
        if rng.random() < 0.05:      # now and then a position-class command in between
            client.send(["joint5", "joint8"], [j5.upper - 0.3, j8.lower + 0.3],
                        [0.0, 1.0] if kinds % 2 else [])
            kinds += 1
        else:
            client.send(["joint5", "joint8"], effort=effort)
        time.sleep(0.01)
    # back to position control, settled, before the write log is read (no switch in flight)
    client.send(["joint5", "joint8"], [j5.upper - 0.3, j8.lower + 0.3])
    wait_for(lambda: all(servo(control, i)["operating_mode"] == 5
                         and servo(control, i)["torque_enable"] == 1 for i in (5, 8)), 10.0,
             what="joints back in current-based position, torque on")
    control("lockstep", dt=None)
    for sid, j in ((5, j5), (8, j8)):
        over = control("overshoot", id=sid)["ticks"]
        assert over is not None and over <= 10.0, (j.name, over)
    log = control("write_log")["log"]
    for sid in (5, 8):
        spans = _torque_off_spans(log, sid)
        # torque-off never outlasts one cycle (normally 0: on again before that cycle's goals)
        assert spans and all(n <= 1 for n in spans), (sid, spans)
        modes = {r["value"] for r in log if r["id"] == sid and r["register"] == "operating_mode"}
        assert modes == {0, 5}
    # the joints did reach their limit zone (the brake was exercised, not only configured)
    ticks = [r["value"] for r in log if r["id"] == 5 and r["register"] == "goal_position"
             and r["inst"] == 0x83]
    assert max(ticks) >= j5.tick_limits[1] - 60, max(ticks)
    assert not re.search(r"Traceback", drv.output())


def test_torque_on_start_waits_for_servos_that_come_up_late_never_a_reconnection(
        launch, tmp_path, wait_for, executor, rclpy_context):
    """torque_on_start with the servos not there yet (the driver started before the bus was
    powered; a loaded start-up where the first transactions time out): torque comes on at
    the first connection, however late. After the link is lost and comes back, torque stays
    off until someone turns it on (a reconnection is not a start)."""
    import signal

    link, ctl = str(tmp_path / "ttyDXL"), str(tmp_path / "ctl")
    drv = launch("hyperarm_driver", "dynamixel_driver", params={
        "port": link, "torque_on_start": True, "reconnect_period": 0.2,
        "diagnostics_period": 0.2})
    wait_for(lambda: "retrying" in drv.output(), 30.0, what=lambda: f"the retries\n{drv.output()}")
    emu = launch("hyperarm_driver", "dxl_emulator", "--link", link, "--control", ctl)
    control = wait_for(lambda: _connect(ctl), 20.0, what="emulator control socket")
    wait_for(lambda: all(servo(control, j.id)["torque_enable"] == 1 for j in CFG.joints), 20.0,
             what=lambda: f"torque on at the late first connection\n{drv.output()}\n"
                          f"dxl_emulator said:\n{emu.output()}")
    # (the driver says so after the writes: its line may come a moment after the servos)
    wait_for(lambda: "torque on (torque_on_start)" in drv.output(), 5.0,
             what=lambda: f"the driver's torque-on line\n{drv.output()}")
    # the bus goes away and comes back (a new emulator: every servo's torque off)
    emu.proc.send_signal(signal.SIGINT)
    assert emu.proc.wait(timeout=10.0) == 0
    wait_for(lambda: "port lost" in drv.output(), 10.0, what=lambda: f"the loss\n{drv.output()}")
    launch("hyperarm_driver", "dxl_emulator", "--link", link, "--control", ctl)
    control = wait_for(lambda: _connect(ctl), 20.0, what="the new emulator's control socket")
    wait_for(lambda: drv.output().count("connected to") >= 2, 20.0,
             what=lambda: f"the reconnection\n{drv.output()}")
    time.sleep(1.0)
    assert all(servo(control, j.id)["torque_enable"] == 0 for j in CFG.joints)
    assert drv.output().count("torque on (torque_on_start)") == 1
