"""`hyperarm traj FILE.yaml` (issue 26): a trajectory file through arm_controller's
FollowJointTrajectory, with the installed `hyperarm`, `mock_driver` and `arm_controller` on
the test's own ROS domain: the packaged wave succeeds and the arm ends at its last point; a
file that breaks the schema is refused before anything is sent; a point outside the limits
comes back INVALID_GOAL with the controller's sentence; Ctrl-C mid-way cancels (exit 130)
and the arm holds; no arm_controller: a clear error.

The mock and the controller run on simulated time (the mock's /clock at 1x): what is tested
is the CLI, judged apart from the machine's load. In real time a scheduling stall of the
mock under a loaded CI run (joint_states 0.276 s old, twice at the wave's start) rightly
aborts the trajectory; arm_controller's real-time behaviour is test_arm_controller_action_e2e's
and test_arm_controller_node's."""
from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

pytestmark = [pytest.mark.e2e]

NAMES = [f"joint{i}" for i in range(1, 10)]


def _run(executable, *args, timeout=60.0):
    return subprocess.run([executable("hyperarm_bringup", "hyperarm"), *args],
                          capture_output=True, text=True, timeout=timeout, env=dict(os.environ))


def _wave() -> Path:
    from ament_index_python.packages import get_package_share_directory

    return Path(get_package_share_directory("hyperarm_control")) / "config" / "wave.yaml"


def test_traj_sends_a_file_refuses_bad_ones_and_cancels_on_ctrl_c(
        executable, launch, wait_for, rclpy_context, executor, tmp_path):
    import rclpy
    from sensor_msgs.msg import JointState

    from hyperarm_description import contract
    from hyperarm_description.qos import observer_qos, qos_for

    # nothing serves the action: a clear error, exit 1
    r = _run(executable, "traj", str(_wave()), "--timeout", "2")
    assert r.returncode == 1 and "no arm_controller serves /hyperarm/arm_controller/" \
        "follow_joint_trajectory within 2 s" in r.stderr, r.stderr

    launch("hyperarm_driver", "mock_driver", params={"sim_speed": 1.0})
    launch("hyperarm_control", "arm_controller", params={"use_sim_time": True})
    probe = rclpy.create_node("traj_probe", namespace=contract.DEFAULT_NAMESPACE,
                              context=rclpy_context)
    states: dict[str, float] = {}
    commands: list = []
    probe.create_subscription(JointState, contract.JOINT_STATES,
                              lambda m: states.update(zip(m.name, m.position)),
                              qos_for(contract.JOINT_STATES))
    probe.create_subscription(JointState, contract.JOINT_COMMAND, commands.append,
                              observer_qos(contract.JOINT_COMMAND))
    executor.add_node(probe)

    def q():
        return np.array([states[n] for n in NAMES])

    # a schema error: refused, nothing sent
    bad = tmp_path / "bad.yaml"
    bad.write_text("joint_names: [joint1]\npoints: [{time: 1.0, position: [0.1]}]\n")
    r = _run(executable, "traj", str(bad))
    assert r.returncode == 1, r.stdout + r.stderr
    assert "refused, nothing sent" in r.stderr and "points/0" in r.stderr, r.stderr

    # not finite, too long, a YAML 1.1 exponent read as text: refused, saying where
    for text, said in (("time: .nan", "points/0/time: nan is not a finite number"),
                       ("time: .inf", "points/0/time"),
                       ("time: 3.0e+9", "points/0/time: 3000000000.0 is greater than"),
                       ("time: 1e12", "write the number with a dot")):
        bad.write_text(f"joint_names: [joint1]\npoints: [{{{text}, positions: [0.1]}}]\n")
        r = _run(executable, "traj", str(bad))
        assert r.returncode == 1 and "refused, nothing sent" in r.stderr, r.stderr
        assert said in r.stderr and "Traceback" not in r.stderr, (text, r.stderr)
    assert not commands

    # the wave: succeeded, ends at its last point (within the file's goal tolerance)
    r = _run(executable, "traj", str(_wave()), "--timeout", "30")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "trajectory succeeded: largest path error" in r.stdout
    assert "t =   0.00 s" in r.stdout or "t =" in r.stdout        # progress lines
    wave = yaml.safe_load(_wave().read_text())
    wait_for(lambda: all(n in states for n in NAMES), 10.0, what="joint_states")
    wait_for(lambda: np.abs(q() - wave["points"][-1]["positions"]).max() < 0.03, 5.0,
             what="the arm at the wave's last point")

    # a point outside joint2's limits: the controller's code and sentence, nothing moves
    n = len(commands)
    out = tmp_path / "out.yaml"
    out.write_text(yaml.safe_dump({"joint_names": NAMES, "points": [
        {"time": 2.0, "positions": [0.0, 4.0] + [0.0] * 7}]}))
    r = _run(executable, "traj", str(out))
    assert r.returncode == 1
    assert "trajectory aborted: INVALID_GOAL (-1)" in r.stderr and "joint2" in r.stderr, \
        r.stderr
    assert len(commands) == n

    # Ctrl-C 1.5 s into a 6 s move: cancelled, exit 130, the arm holds short of the goal
    far = tmp_path / "far.yaml"
    goal = [0.8, -0.6, 0.5, -0.4, 0.3, 0.0, 0.0, 0.0, 0.0]
    far.write_text(yaml.safe_dump({"joint_names": NAMES, "points": [
        {"time": 6.0, "positions": goal}]}))
    proc = subprocess.Popen([executable("hyperarm_bringup", "hyperarm"), "traj", str(far)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ))
    try:
        wait_for(lambda: len(commands) > n + 50, 20.0, what="the move under way")
    except AssertionError as exc:    # say why: what the client printed (a CI run: no move)
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"{exc}; {len(commands) - n} commands; hyperarm traj printed:\n"
                             f"{out[-1500:]}\n{err[-1500:]}") from None
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=10.0)
    assert proc.returncode == 130, stdout + stderr
    assert "Ctrl-C: cancelling the trajectory" in stderr
    assert "arm_controller: canceled" in stderr and "RCLError" not in stderr, stderr
    time.sleep(0.5)
    held, m = q(), len(commands)
    time.sleep(0.5)
    assert len(commands) == m and np.abs(q() - held).max() < 0.005
    assert np.abs(held - np.array(goal)).max() > 0.1          # stopped short of the goal
