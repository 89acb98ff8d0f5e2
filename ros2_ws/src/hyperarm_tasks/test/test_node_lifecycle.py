"""E2E: every node of the suite through ``--help``, SIGINT, a double SIGINT and SIGTERM.

Each installed executable must print its usage and parameters for ``--help`` / ``-h`` and
exit 0 without starting (no port opened, no ROS node created). Started for real (the
drivers on their emulators), every node must exit within 2 s of one SIGINT, of two SIGINTs
50 ms apart, or of SIGTERM, with exit code 0, no traceback, no segfault and none of rclpy's
shutdown-race messages, and it must still apply its shutdown policy: the Dynamixel driver
with ``shutdown_torque:=release`` leaves every servo torque-off on the emulator.
"""
from __future__ import annotations

import re
import signal
import subprocess
import time

import pytest

from hyperarm_driver.dynamixel.emulator import EmulatorControl

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

#: (package, executable, ROS node name) of every node of the suite.
NODES = [
    ("hyperarm_driver", "mock_driver", "mock_driver"),
    ("hyperarm_driver", "dynamixel_driver", "dynamixel_driver"),
    ("hyperarm_driver", "pmac_rail_driver", "pmac_rail_driver"),
    ("hyperarm_ik", "fk_node", "fk_node"),
    ("hyperarm_ik", "tf_publisher", "tf_publisher"),
    ("hyperarm_ik", "ik_service", "ik_service"),
    ("hyperarm_control", "hybrid_force", "hybrid_force"),
    ("hyperarm_control", "host_compensation", "host_compensation"),
    ("hyperarm_tasks", "task_node", "task_node"),
    ("hyperarm_tasks", "task_recorder", "task_recorder"),
    ("hyperarm_bringup", "viewer", "viewer"),
    ("hyperarm_perception", "marker_detector", "marker_detector"),
    ("hyperarm_perception", "usb_camera", "usb_camera"),
    ("hyperarm_perception", "mock_camera", "mock_camera"),
    ("hyperarm_control", "arm_controller", "arm_controller"),
    ("hyperarm_control", "gripper_controller", "gripper_controller"),
]

BAD_OUTPUT = ("Traceback", "Segmentation fault", "Failed to publish log message",
              "exception never retrieved", "cannot use Destroyable", "core dumped")
EXIT_WITHIN = 2.0  # s, from the (last) signal to the process' exit


#: parameters each node's --help must list (with the rest of its table)
HELP_PARAMETERS = {
    "mock_driver": ["variant", "rate", "workcell_file", "sim_speed"],
    "dynamixel_driver": ["port", "baud", "shutdown_torque"],
    "pmac_rail_driver": ["host", "port", "require_homing"],
    "fk_node": ["variant", "description_file"],
    "tf_publisher": ["variant", "max_state_age", "diagnostics_period"],
    "ik_service": ["default_solver", "max_timeout"],
    "task_node": ["command_rate", "tasks_dir", "detection_max_age", "collision_check"],
    "task_recorder": ["output"],
    "hybrid_force": ["output", "stale_timeout", "payload_mass"],
    "viewer": ["port", "host", "objects_topic", "workcell_file"],
    "host_compensation": ["host_source", "initial_delay", "speed_scale"],
    "marker_detector": ["marker_map", "max_age"],
    "usb_camera": ["device", "camera_info_file", "reopen_period"],
    "mock_camera": ["workcell_file", "marker_map", "rate", "noise_sigma"],
    "arm_controller": ["rate", "path_tolerance", "max_state_age"],
    "gripper_controller": ["goal_tolerance", "stall_timeout", "allow_stalling"]}


def test_help_of_every_node(executable, tmp_path):
    """(-h gives the same text: test_cli_help)"""
    flag = "--help"
    for package, name, _node in NODES:
        # A port that does not exist: --help must not try to open it (or loop retrying).
        t0 = time.monotonic()
        out = subprocess.run([executable(package, name), flag, "--ros-args", "-p",
                              "port:=/dev/does-not-exist"], capture_output=True, text=True,
                             timeout=30.0)
        took = time.monotonic() - t0
        text = out.stdout + out.stderr
        assert out.returncode == 0, f"{name} {flag}: exit {out.returncode}\n{text}"
        assert text.startswith(f"usage: ros2 run <package> {name}"), f"{name}: {text[:300]}"
        assert "parameters (read-only" in text, text
        assert not any(bad in text for bad in BAD_OUTPUT), text
        assert took < 15.0, f"{name} {flag} took {took:.1f} s"
        for param in HELP_PARAMETERS[name]:      # the same usage text for both flags
            assert re.search(rf"^  {param} \(", out.stdout, re.M), \
                f"{name} {flag}: {param} missing\n{text}"


def _frames(tmp_path) -> str:
    """A 3-frame image sequence for usb_camera to replay."""
    import cv2
    import numpy as np

    folder = tmp_path / "frames"
    folder.mkdir(exist_ok=True)
    for i in range(3):
        cv2.imwrite(str(folder / f"{i:02d}.png"), np.full((480, 640, 3), 40 * i, np.uint8))
    return str(folder / "%02d.png")


def _start_all(launch, tmp_path, wait_for):
    """The emulators, then every node; returns ({exe: Launched}, emulator control)."""
    link, ctl = str(tmp_path / "ttyDXL"), str(tmp_path / "dxl.ctl")
    launch("hyperarm_driver", "dxl_emulator", "--link", link, "--control", ctl)
    pmac = launch("hyperarm_driver", "pmac_emulator", "--port", "0")
    wait_for(lambda: (tmp_path / "dxl.ctl").exists(), 20.0, what="dxl emulator socket")
    port = wait_for(lambda: re.search(r"127\.0\.0\.1:(\d+)", pmac.output()), 20.0,
                    what="pmac emulator port").group(1)
    procs = {
        # The mock in a namespace of its own: it would otherwise serve the same services
        # as the Dynamixel driver.
        "mock_driver": launch("hyperarm_driver", "mock_driver", namespace="/mock"),
        "dynamixel_driver": launch("hyperarm_driver", "dynamixel_driver", params={
            "port": link, "torque_on_start": True, "shutdown_torque": "release"}),
        "pmac_rail_driver": launch("hyperarm_driver", "pmac_rail_driver",
                                   params={"port": int(port)}),
        "fk_node": launch("hyperarm_ik", "fk_node"),
        "tf_publisher": launch("hyperarm_ik", "tf_publisher"),
        "ik_service": launch("hyperarm_ik", "ik_service"),
        "hybrid_force": launch("hyperarm_control", "hybrid_force"),
        "host_compensation": launch("hyperarm_control", "host_compensation"),
        "task_node": launch("hyperarm_tasks", "task_node"),
        "task_recorder": launch("hyperarm_tasks", "task_recorder",
                                params={"output": str(tmp_path / "rec.mcap")}),
        "viewer": launch("hyperarm_bringup", "viewer", params={"port": 0,
                                                               "host": "127.0.0.1"}),
        "marker_detector": launch("hyperarm_perception", "marker_detector"),
        # streaming (a looped recording at 30 fps): its capture thread publishes while the
        # signals arrive
        "usb_camera": launch("hyperarm_perception", "usb_camera", params={
            "device": _frames(tmp_path), "loop": True}),
        # beside the mock (its namespace): rendering while the signals arrive
        "mock_camera": launch("hyperarm_perception", "mock_camera", namespace="/mock"),
        "arm_controller": launch("hyperarm_control", "arm_controller"),
        "gripper_controller": launch("hyperarm_control", "gripper_controller"),
    }
    return procs, EmulatorControl(ctl)


def _wait_ready(rclpy_context, wait_for, procs) -> None:
    from rclpy.node import Node

    probe = Node("lifecycle_probe", context=rclpy_context)
    try:
        want = {node for _p, _e, node in NODES}

        def up():
            for name, item in procs.items():
                assert item.proc.poll() is None, f"{name} died:\n{item.output()[-3000:]}"
            return want <= {n for n, _ns in probe.get_node_names_and_namespaces()}

        wait_for(up, 60.0, period=0.1, what="every node in the ROS graph")
    finally:
        probe.destroy_node()


@pytest.mark.alone   # 16 processes stopping at once: our shutdown, not the other worker's load
@pytest.mark.timeout(420)   # the wait at the gate (the other worker's test) included
@pytest.mark.parametrize("signals", [(signal.SIGINT,), (signal.SIGINT, signal.SIGINT),
                                     (signal.SIGTERM,)], ids=["sigint", "double-sigint",
                                                              "sigterm"])
def test_every_node_exits_cleanly_on_signals(launch, tmp_path, wait_for, rclpy_context,
                                             signals):
    procs, control = _start_all(launch, tmp_path, wait_for)
    try:
        _wait_ready(rclpy_context, wait_for, procs)
        try:
            wait_for(lambda: control("state")["servos"]["3"]["torque_enable"] == 1, 20.0,
                     what="Dynamixel torque on")
        except AssertionError as exc:   # say why: the driver's own account
            raise AssertionError(f"{exc}; dynamixel_driver said:\n"
                                 f"{procs['dynamixel_driver'].output()[-3000:]}") from None
        time.sleep(0.5)  # let every node run its loops for a while
        for i, sig in enumerate(signals):
            if i:
                time.sleep(0.05)
            for item in procs.values():
                item.proc.send_signal(sig)
        sent = time.monotonic()
        problems = []
        late = []
        for name, item in procs.items():
            try:
                code = item.proc.wait(timeout=max(0.1, sent + EXIT_WITHIN - time.monotonic()))
            except subprocess.TimeoutExpired:
                problems.append(f"{name}: still running {EXIT_WITHIN} s after the signal")
                late.append(name)
                continue
            out = item.output()
            if code != 0:
                problems.append(f"{name}: exit code {code}")
            for bad in BAD_OUTPUT:
                if bad in out:
                    problems.append(f"{name}: printed {bad!r}")
            if problems and problems[-1].startswith(name):
                problems.append(out[-2500:])
        for name in late:   # (not a pass) where each late node's time went, in its words
            item = procs[name]
            try:
                item.proc.wait(timeout=max(0.1, sent + 9.0 - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
            took = [line for line in item.output().splitlines() if "shutdown took" in line]
            problems.append(f"{name}: {took[-1] if took else 'no phases printed'} "
                            f"(exit code {item.proc.returncode})")
        servos = control("state")["servos"]
        off = [sid for sid, st in servos.items() if st["torque_enable"] != 0]
        if off:
            problems.append(f"dynamixel_driver: servos {off} still torque-on after shutdown "
                            f"(release policy)\n{procs['dynamixel_driver'].output()[-2000:]}")
        assert not problems, "\n".join(problems)
    finally:
        control.close()



@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["sigint", "sigterm"])
def test_signal_during_start_up_is_a_clean_exit(launch, sig):
    """A signal while the node is still importing its libraries or building itself (seconds
    on a loaded computer) ends it with 0 and no traceback: nothing had started."""
    procs = {name: launch(package, name, params={"port": "/dev/does-not-exist"}
                          if name == "dynamixel_driver" else {"port": 0}
                          if name == "viewer" else None)
             for package, name, _node in NODES}
    # Signal each one while it imports its node module: numpy is mapped (the node's imports
    # have begun) but the node has not said it is up yet. Before that, only Python itself
    # and setuptools' console-script wrapper run (a window we cannot cover).
    pending = dict(procs)
    deadline = time.monotonic() + 30.0
    while pending and time.monotonic() < deadline:
        for name, item in list(pending.items()):
            if item.proc.poll() is not None or _imports_numpy(item.proc.pid):
                item.proc.send_signal(sig)
                del pending[name]
        time.sleep(0.002)
    assert not pending, f"never saw these import numpy: {sorted(pending)}"
    problems = []
    for name, item in procs.items():
        try:
            code = item.proc.wait(timeout=EXIT_WITHIN + 3.0)
        except subprocess.TimeoutExpired:
            problems.append(f"{name}: still running after the signal")
            continue
        out = item.output()
        if code != 0 or any(bad in out for bad in BAD_OUTPUT):
            problems.append(f"{name}: exit code {code}\n{out[-2000:]}")
    assert not problems, "\n".join(problems)


def _imports_numpy(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/maps") as fh:
            return "numpy" in fh.read()
    except OSError:
        return False
