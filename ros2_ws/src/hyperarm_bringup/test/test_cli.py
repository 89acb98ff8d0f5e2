"""The `hyperarm` command line: every subcommand's --help, clear errors (no node running, a
timeout, a refusal), the bus tools against dxl_emulator and the ROS commands against the
mock driver, ik_service and task_node (installed executables, own ROS domain)."""
from __future__ import annotations

import math
import os
import subprocess

import pytest
import yaml

from hyperarm_bringup.cli import build_parser, parse_assignments
from hyperarm_description.model import load_description

SUBCOMMANDS = ("state", "diag", "torque", "hold", "reboot", "home", "move", "ik", "run",
               "traj", "scan", "set-id", "set-baud", "calibrate")


def hyperarm(executable, *args: str, timeout: float = 60.0, stdin: str | None = None):
    return subprocess.run([executable("hyperarm_bringup", "hyperarm"), *args],
                          capture_output=True, text=True, timeout=timeout,
                          input=stdin if stdin is not None else "", env=dict(os.environ))


@pytest.mark.core
def test_every_subcommand_has_help():
    parser = build_parser()
    for name in SUBCOMMANDS:
        with pytest.raises(SystemExit) as exc:
            parser.parse_args([name, "--help"])
        assert exc.value.code == 0, name


@pytest.mark.core
def test_ik_counts_its_numbers_and_q_is_optional(capsys):
    """`hyperarm ik 1 2` names what is missing (X Y Z), not the optional quaternion; 3 or 7
    numbers only (checked before any ROS)."""
    from hyperarm_bringup.cli import main

    for argv in (["ik", "1", "2"], ["ik", "1", "2", "3", "4"], ["ik", *"12345678"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "give X Y Z (m), and optionally QX QY QZ QW" in err, err
        assert f"got {len(argv) - 1} numbers" in err and "required" not in err
    usage = build_parser()._subparsers._group_actions[0].choices["ik"].format_usage()
    assert "X Y Z [QX QY QZ QW]" in usage and " Q " not in usage


@pytest.mark.core
def test_state_names_an_unknown_joint_before_any_ros(capsys):
    from hyperarm_bringup.cli import main

    assert main(["state", "--once", "--joints", "rail", "joint10"]) == 2
    err = capsys.readouterr().err
    assert "no such joint: joint10" in err and "rail" not in err.split("(")[0]


@pytest.mark.core
def test_move_rejects_the_whole_command_and_names_every_problem():
    limits = load_description(None, "arm").limits_by_name()
    assert parse_assignments(["joint1=0.5", "gripper=0.2"], limits) == {"joint1": 0.5,
                                                                      "gripper": 0.2}
    with pytest.raises(ValueError) as exc:
        parse_assignments(["joint1=0.5", "joint2=9", "nojoint=1", "joint3=abc", "joint4",
                           "joint5=nan"], limits)
    text = str(exc.value)
    for part in ("joint2=9 outside", "nojoint: no such joint", "'abc' is not a number",
                 "expected JOINT=VALUE", "joint5=nan outside"):
        assert part in text


@pytest.mark.e2e
def test_ros_commands_say_no_node_is_running(executable, ros_domain):
    r = hyperarm(executable, "state", "--once", "--timeout", "1")
    assert r.returncode == 1 and "is a driver running" in r.stderr and "Traceback" not in r.stderr
    r = hyperarm(executable, "torque", "on", "--timeout", "1")
    assert r.returncode == 1 and "no node serves /hyperarm/set_torque" in r.stderr
    # a short --timeout and no task_node: said so, not blamed on the task's name
    r = hyperarm(executable, "run", "ready", "--timeout", "1")
    assert r.returncode == 1 and "no task_node serves /hyperarm/run_task within 1 s" in r.stderr
    assert "task name" not in r.stderr
    r = hyperarm(executable, "move", "joint1=0.1", "--timeout", "1")
    assert r.returncode == 1 and "no joint_states for joint1" in r.stderr, r.stderr
    assert "nothing sent" in r.stderr and "sent:" not in r.stdout


@pytest.mark.emulator
def test_scan_set_id_set_baud_against_the_emulator(executable):
    from hyperarm_driver.dynamixel.testing import EmulatorProcess

    with EmulatorProcess("--servos", "1:XM430-W350@57600,2:MX-64@57600") as emu:
        r = hyperarm(executable, "scan", "--port", emu.link, "--baud", "57600",
                     "--baud", "1000000")
        assert r.returncode == 0, r.stderr
        rows = [line.split() for line in r.stdout.splitlines()[1:]]
        assert [(x[0], x[1], x[2]) for x in rows] == [("1", "57600", "XM430-W350"),
                                                      ("2", "57600", "MX-64")]
        # no terminal to confirm on: refused, nothing written
        r = hyperarm(executable, "set-id", "--port", emu.link, "--baud", "57600", "2", "5")
        assert r.returncode == 1 and "--yes" in r.stderr
        r = hyperarm(executable, "set-id", "--port", emu.link, "--baud", "57600", "2", "1",
                     "--yes")
        assert r.returncode == 1 and "already taken" in r.stderr
        r = hyperarm(executable, "set-id", "--port", emu.link, "--baud", "57600", "2", "5",
                     "--yes")
        assert r.returncode == 0, r.stderr
        r = hyperarm(executable, "set-baud", "--port", emu.link, "--baud", "57600", "5",
                     "1000000", "--yes")
        assert r.returncode == 0, r.stderr
        units = {(u["id"], u["baud"]) for u in emu.ctl("units")["units"]}
        assert units == {(1, 57600), (5, 1_000_000)}
        r = hyperarm(executable, "set-baud", "--port", emu.link, "--baud", "57600", "1",
                     "12345", "--yes")
        assert r.returncode == 1 and "not a Dynamixel baud rate" in r.stderr
        r = hyperarm(executable, "scan", "--port", emu.link + ".missing", "--baud", "57600")
        assert r.returncode == 1 and "cannot open" in r.stderr


@pytest.mark.emulator
def test_calibrate_writes_zero_offsets_into_a_copy(executable, tmp_path):
    from hyperarm_driver.dynamixel.testing import EmulatorProcess

    with EmulatorProcess() as emu:
        emu.ctl("set", id=3, position=2148.0)   # joint3 sits 100 ticks off centre
        out = tmp_path / "calibrated.yaml"
        r = hyperarm(executable, "calibrate", "--port", emu.link, "--output", str(out),
                     "--pose", "joint1=0.1")
        assert r.returncode == 0, r.stderr
    desc = load_description(out, "arm")
    by_name = {j.name: j.servo for j in desc.joints}
    assert by_name["joint3"].zero_offset == pytest.approx(100 * 2 * math.pi / 4096, abs=1e-6)
    assert by_name["joint1"].zero_offset == pytest.approx(-by_name["joint1"].direction * 0.1,
                                                          abs=1e-6)
    assert by_name["joint2"].zero_offset == 0.0
    assert yaml.safe_load(out.read_text())["arm"]["joints"][2]["servo"]["zero_offset"] != 0


@pytest.mark.e2e
@pytest.mark.slow
def test_ros_commands_against_the_mock(executable, launch, wait_for, rclpy_context, executor):
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sensor_msgs.msg import JointState

    launch("hyperarm_driver", "mock_driver")
    # a reader of joint_command our volatile writer can never match (transient local, QoS
    # incompatible): `move` must not wait for it
    reader = rclpy.create_node("latched_reader", namespace="/hyperarm", context=rclpy_context)
    reader.create_subscription(JointState, "joint_command", lambda m: None,
                               QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    executor.add_node(reader)
    launch("hyperarm_ik", "ik_service")
    launch("hyperarm_tasks", "task_node")
    r = hyperarm(executable, "state", "--once", "--timeout", "30")
    assert r.returncode == 0, r.stderr
    names = [line.split()[0] for line in r.stdout.splitlines()[1:]]
    assert names[:9] == [f"joint{i}" for i in range(1, 10)] and "gripper" in names
    # the arm mock has no rail: waiting for the rail_arm variant names it, exit 1, and the
    # table of what was heard is still printed
    r = hyperarm(executable, "state", "--once", "--variant", "rail_arm", "--timeout", "3")
    assert r.returncode == 1 and "no joint_states for rail within 3 s" in r.stderr, r.stderr
    assert [line.split()[0] for line in r.stdout.splitlines()[1:]] == names
    r = hyperarm(executable, "diag", "--timeout", "3")
    assert r.returncode == 0 and "mock_driver" in r.stdout, r.stdout + r.stderr
    for args in (("torque", "off"), ("torque", "on"), ("hold",), ("reboot",)):
        r = hyperarm(executable, *args, "--timeout", "20")
        assert r.returncode == 0, (args, r.stderr)
    r = hyperarm(executable, "home", "--timeout", "2")      # arm variant: no rail
    assert r.returncode == 1 and "rail/home" in r.stderr
    r = hyperarm(executable, "move", "joint1=0.3", "joint2=9")
    assert r.returncode == 1 and "nothing sent" in r.stderr
    r = hyperarm(executable, "move", "joint1=0.3", "--timeout", "20")
    assert r.returncode == 0 and r.stdout.startswith("taken: joint1=0.3"), r.stderr

    def joint1():
        out = hyperarm(executable, "state", "--once", "--timeout", "5").stdout
        row = [line.split() for line in out.splitlines() if line.startswith("joint1 ")]
        return row and abs(float(row[0][1]) - 0.3) < 1e-3
    assert wait_for(joint1, timeout=30)
    r = hyperarm(executable, "ik", "0.4", "0.1", "0.2", "-0.7071068", "0", "0", "0.7071068",
                 "--timeout", "20")
    assert r.returncode == 0 and "position error" in r.stdout, r.stderr
    assert len([line for line in r.stdout.splitlines() if line.startswith("joint")]) == 9
    r = hyperarm(executable, "ik", "0.4", "0.1", "0.2", "--timeout", "20")  # position only
    assert r.returncode == 0 and "orientation free (position only)" in r.stdout, r.stderr
    assert "orientation error" not in r.stdout
    r = hyperarm(executable, "ik", "5", "0", "0", "--timeout", "20")  # out of reach
    assert r.returncode == 1 and "no solution" in r.stderr
    r = hyperarm(executable, "run", "nosuch", "--timeout", "30")
    assert r.returncode == 1 and "nosuch" in r.stderr
    r = hyperarm(executable, "run", "ready", "--timeout", "60")
    assert r.returncode == 0 and "done" in r.stdout, r.stderr
