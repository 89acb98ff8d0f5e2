"""End-to-end through the installed executables: run_task.sh starts mock_driver, task_node
(and task_recorder) as processes over real DDS (the test's own ROS_DOMAIN_ID) and runs the
shipped block_transfer (and issue 13's figure8 and rail_transport); real time, so each test
takes tens of seconds."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.qos import qos_for
from hyperarm_tasks.process_group import run_stoppable

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


def _script(executable) -> str:
    return os.path.join(os.path.dirname(executable("hyperarm_tasks", "run_task")), "run_task.sh")


def _run(script, args, ros_domain, timeout):
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain), PYTHONUNBUFFERED="1")
    return run_stoppable([script, *args], env=env, timeout=timeout)


def test_two_cycles_there_and_back_recorded_and_plotted(executable, ros_domain, tmp_path,
                                                        still_running, node_logs):
    """`make demo`'s run: there and back on the mock's rendered pictures (issue 27: the
    demo sees), recorded and plotted. The camera cannot see the block once the hand is over
    it: each leg uses where `locate` found it (`located_used` in the result)."""
    logs, rec = tmp_path / "logs", tmp_path / "run.mcap"
    done = _run(_script(executable), ["--camera", "rendered", "--seed", "21", "--logs",
                                      str(logs), "--record", str(rec), "block_transfer",
                                      "block_transfer_back"], ros_domain, 200)
    out = done.stdout + done.stderr
    assert done.returncode == 0, out + node_logs(logs)
    assert out.count("run_task: succeeded") == 2, out
    assert len(re.findall(r"succeeded: .*located_used [1-9]", out)) == 2, out
    names = [line.split()[0] for line in (logs / "pids").read_text().splitlines()]
    assert "mock_camera" in names and "marker_detector" in names, names
    # and where the time went, step by step (issue 28: the soak's per-step table)
    assert out.count("run_task: time per step (s): ready ") == 2, out
    for step in ("[2/13] locate (locate)", "[9/13] insert (force_insert)", "[13/13] ready_end"):
        assert step in out
    assert still_running(logs) == []
    # every move_to a straight tool line, the first from the singular ready pose too (issue
    # 24 item 6: above_source fell back to a joint-space move in every leg)
    task_log = (logs / "task_node.log").read_text()
    assert "falling back to a joint-space move" not in task_log, node_logs(logs)
    # every channel decodes with mcap-ros2-support's stock decoder (issue 24, item 6: the
    # action's RunTask_FeedbackMessage channel was refused as 'an invalid message name')
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    topics, stages = set(), set()
    with open(rec, "rb") as fh:
        for schema, channel, _m, msg in make_reader(
                fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            topics.add(channel.topic)
            if channel.topic == "/hyperarm/task_feedback":
                assert schema.name == "hyperarm_interfaces/msg/TaskFeedback"
                stages.add((msg.task, msg.stage))
    assert {"/hyperarm/joint_states", "/hyperarm/joint_command", "/hyperarm/detections",
            "/hyperarm/task_feedback"} <= topics
    assert {("block_transfer", "insert"), ("block_transfer_back", "ready_end")} <= stages
    plots = subprocess.run([executable("hyperarm_tasks", "plot_task"), str(rec), "--out",
                            str(tmp_path / "png")], capture_output=True, text=True, timeout=120)
    assert plots.returncode == 0, plots.stderr
    for name in ("tool_path.png", "joints.png", "insertion.png"):
        assert (tmp_path / "png" / name).stat().st_size > 10_000


def test_unreachable_destination_is_refused_before_any_motion(executable, ros_domain, tmp_path,
                                                               still_running):
    from ament_index_python.packages import get_package_share_directory
    cell = yaml.safe_load(open(Path(get_package_share_directory("hyperarm_driver"))
                               / "config" / "workcell.yaml"))
    cell["world"]["pegs"]["destination"]["xy"] = [0.9, -0.6]
    cell["imperfections"]["seed"] = 3
    path = tmp_path / "far.yaml"
    path.write_text(yaml.safe_dump(cell))
    logs = tmp_path / "logs"
    done = _run(_script(executable), ["--workcell", str(path), "--logs", str(logs),
                                      "block_transfer"], ros_domain, 120)
    out = done.stdout + done.stderr
    assert done.returncode == 1, out
    # issue 24, item 6: found before the block is picked, named with its distance beyond
    # the peg as the camera sees it (noisy, unseeded): within 1 cm of where it was put (the
    # text prefix "(0.9" checked this before, one-sided: 0.899 failed it)
    found = re.search(r"run_task: failed: refused before any motion: target of step "
                      r"'above_destination' \(destination_peg \+ \(\+0\.000, \+0\.000, "
                      r"\+0\.035\) m\) at \((-?[0-9.]+), (-?[0-9.]+), ", out)
    assert found, out
    assert abs(float(found.group(1)) - 0.9) <= 0.01 and abs(float(found.group(2)) + 0.6) <= 0.01, out
    assert "m beyond the arm's workspace" in out
    assert "[2/13]" not in out and "[1/13]" not in out          # no step ran
    assert still_running(logs) == []


@pytest.mark.alone   # a 2 s bound on stopping the stack: our stop, not the other worker's load
@pytest.mark.timeout(420)   # the wait at the gate (the other worker's test) included
def test_sigint_twice_mid_task_cancels_and_leaves_no_process(executable, ros_domain, tmp_path,
                                                             still_running):
    logs = tmp_path / "logs"
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain), PYTHONUNBUFFERED="1")
    # As from a user's shell: SIGINT not ignored. A shell started with SIGINT ignored (e.g.
    # by a parent that ignores it) cannot trap it, so the Ctrl-C would never reach the task.
    proc = subprocess.Popen([_script(executable), "--logs", str(logs), "block_transfer"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = []
    deadline = time.monotonic() + 90
    for line in proc.stdout:
        lines.append(line)
        if "[3/13] above_source" in line or time.monotonic() > deadline:
            break
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    time.sleep(0.05)
    proc.send_signal(signal.SIGINT)         # a quick second Ctrl-C
    rest, _ = proc.communicate(timeout=60)
    took = time.monotonic() - sent
    out = "".join(lines) + rest
    assert proc.returncode == 130, out
    assert took < 2.0, f"exited {took:.2f} s after the Ctrl-C\n{out}"   # issue 24, item 2
    assert "cancelling the task" in out and "cancelled during above_source" in out, out
    assert "Traceback" not in out and "Segmentation" not in out
    assert still_running(logs) == []
    assert "cancel requested for task 'block_transfer' during above_source" in \
        (logs / "task_node.log").read_text()


def test_cancel_mid_insertion_holds_with_force_off(launch, rclpy_context, executor, wait_for,
                                                   ros_domain, executable, tmp_path):
    import rclpy
    from ament_index_python.packages import get_package_share_directory
    cell = yaml.safe_load(open(Path(get_package_share_directory("hyperarm_driver"))
                               / "config" / "workcell.yaml"))
    cell["world"]["block"]["hole_radius"] = 0.00805    # 0.05 mm: the insertion goes on
    cell["imperfections"]["seed"] = 5
    (tmp_path / "tight.yaml").write_text(yaml.safe_dump(cell))
    launch("hyperarm_driver", "mock_driver", params={"workcell_file": str(tmp_path / "tight.yaml")})
    force = launch("hyperarm_control", "hybrid_force")      # the insertion under force control
    task = launch("hyperarm_tasks", "task_node")
    node = rclpy.create_node("probe", namespace=contract.DEFAULT_NAMESPACE, context=rclpy_context)
    states, commands = [], []
    node.create_subscription(JointState, contract.JOINT_STATES,
                             lambda m: states.append((time.monotonic(), m)),
                             qos_for(contract.JOINT_STATES))
    # arrival and the command's own stamp (wall clock; the force node stamps its commands
    # with the state they answer): one published before the cancel ended may still be on
    # its way when the client exits (seen once at load ~4)
    node.create_subscription(JointState, contract.JOINT_COMMAND,
                             lambda m: commands.append((time.monotonic(), m.header.stamp.sec
                                                        + 1e-9 * m.header.stamp.nanosec)),
                             qos_for(contract.JOINT_COMMAND))
    executor.add_node(node)
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain), PYTHONUNBUFFERED="1")
    client = subprocess.Popen([executable("hyperarm_tasks", "run_task"), "block_transfer",
                               "--wait-ready", "60", "--wait-force"], env=env,
                              stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines = []
    for line in client.stdout:
        lines.append(line)
        if "dithering" in line:
            break
    time.sleep(1.0)                                   # well inside the insertion
    client.send_signal(signal.SIGINT)
    rest, _ = client.communicate(timeout=30)
    out = "".join(lines) + rest
    assert client.returncode == 1, out
    assert "canceled: cancelled during insert" in out, out
    t_done, wall_done = time.monotonic(), time.time()
    time.sleep(1.5)
    late = [(t - t_done, stamp) for t, stamp in commands
            if t > t_done and (stamp == 0.0 or stamp > wall_done)]
    assert not late, f"joint_command after the cancel (arrival after, stamp): {late}"
    recent = [m for t, m in states if t > t_done + 0.5]
    assert len(recent) > 10, (len(states), states[-1][0] - t_done, len(commands))
    q = np.array([m.position for m in recent])
    assert np.ptp(q, axis=0).max() < 2e-3, "the arm moved after the cancel: not holding"
    log = task.output()
    assert "cancel requested for task 'block_transfer' during insert" in log
    assert "cancelled during insert (force control off, holding)" in log
    # the insertion did run under force control, and the cancel switched it off
    flog = force.output()
    assert "enabled (position output)" in flog, flog[-2000:]
    modes = [ln for ln in flog.splitlines() if "enabled (" in ln or "disabled" in ln
             or ": passive" in ln]
    assert modes and modes[-1].endswith("disabled on request"), flog[-2000:]
    assert "Traceback" not in flog


def test_refused_rail_command_fails_with_the_drivers_reason(executable, ros_domain, tmp_path,
                                                            still_running):
    (tmp_path / "tasks").mkdir()
    (tmp_path / "tasks" / "rail_out.yaml").write_text(
        "schema_version: 1\nsteps:\n  - {name: rail_out, type: move_joints, "
        "joints: {rail: 0.3 m}, tolerance: 0.002, timeout: 5 s}\n")
    logs = tmp_path / "logs"
    done = _run(_script(executable), ["--variant", "rail_arm", "--tasks-dir",
                                      str(tmp_path / "tasks"), "--logs", str(logs), "rail_out"],
                ros_domain, 90)
    out = done.stdout + done.stderr
    assert done.returncode == 1, out
    assert "step 'rail_out' (move_joints) failed: driver refused: the rail is not homed" in out
    assert still_running(logs) == []


def test_description_option_goes_to_the_commanding_nodes_not_the_mock(
        executable, ros_domain, tmp_path, still_running, node_logs):
    """--description FILE: task_node and hybrid_force load FILE (task_node says so), the
    mock keeps its packaged description (the world); a missing file is exit 2 at once."""
    from hyperarm_description.model import default_description_path

    mine = tmp_path / "my_robot.yaml"
    mine.write_text(default_description_path().read_text())
    logs = tmp_path / "logs"
    done = _run(_script(executable), ["--description", str(mine), "--logs", str(logs),
                                      "ready"], ros_domain, 90)
    out = done.stdout + done.stderr
    assert done.returncode == 0, out + node_logs(logs)
    assert f"robot description {mine}" in (logs / "task_node.log").read_text()
    assert str(mine) not in (logs / "mock_driver.log").read_text()
    assert still_running(logs) == []
    bad = _run(_script(executable), ["--description", str(tmp_path / "nope.yaml"), "ready"],
               ros_domain, 30)
    assert bad.returncode == 2 and "--description: no file" in bad.stderr, bad.stderr


def test_rendered_camera_option_moves_on_markers_found_in_pictures(
        executable, ros_domain, tmp_path, still_running, node_logs):
    """--camera rendered: the mock publishes no detections; mock_camera renders its pictures
    and marker_detector finds the pegs' markers in them, and a task whose first step is
    relative to a peg moves on those detections (run_task waits for the camera's first
    detections: the renderer takes seconds to start); both stop with the stack. A bad
    --camera, or --camera rendered with --hardware, is exit 2 at once."""
    tasks = tmp_path / "tasks"
    tasks.mkdir()
    (tasks / "over_peg.yaml").write_text(
        "schema_version: 1\ndescription: above the source peg, seen in the pictures\n"
        "objects: [source_peg]\nsteps:\n"
        "  - name: above\n    type: move_to\n"
        "    target: {relative_to: source_peg, offset: [0, 0, 5 cm]}\n")
    logs = tmp_path / "logs"
    done = _run(_script(executable), ["--camera", "rendered", "--seed", "3", "--tasks-dir",
                                      str(tasks), "--logs", str(logs), "over_peg"],
                ros_domain, 120)
    out = done.stdout + done.stderr
    assert done.returncode == 0, out + node_logs(logs)
    assert "run_task: succeeded" in out, out
    names = [line.split()[0] for line in (logs / "pids").read_text().splitlines()]
    assert "mock_camera" in names and "marker_detector" in names, names
    assert still_running(logs) == []
    for bad, why in ((["--camera", "fisheye"], "--camera oracle or rendered"),
                     (["--camera", "rendered", "--hardware", str(tasks / "over_peg.yaml")],
                      "--camera rendered is the mock's")):
        refused = _run(_script(executable), [*bad, "ready"], ros_domain, 30)
        assert refused.returncode == 2 and why in refused.stderr, refused.stderr


def test_wait_detections_names_a_missing_camera(launch, ros_domain, executable):
    """run_task --wait-ready S --wait-detections with no camera (the mock's detections off):
    not ready after S s, saying the camera's detections are missing; nothing is sent."""
    launch("hyperarm_driver", "mock_driver", params={"detections": "none"})
    launch("hyperarm_tasks", "task_node")
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain), PYTHONUNBUFFERED="1")
    done = subprocess.run([executable("hyperarm_tasks", "run_task"), "ready", "--wait-ready",
                           "8", "--wait-detections"], env=env, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 1, done
    assert "not ready after 8 s: no detections from the camera on detections" in \
        done.stdout + done.stderr, done
    assert "[1/" not in done.stdout


def _block_transfer_under_way(launch, ros_domain, executable):
    """mock_driver and task_node launched, and run_task's block_transfer at its second step
    (above_source): (task_node, the run_task process, its lines so far, its environment,
    mock_driver)."""
    driver = launch("hyperarm_driver", "mock_driver")
    node = launch("hyperarm_tasks", "task_node")
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain), PYTHONUNBUFFERED="1")
    client = subprocess.Popen([executable("hyperarm_tasks", "run_task"), "block_transfer",
                               "--wait-ready", "60"], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, start_new_session=True)
    seen = []
    for line in client.stdout:
        seen.append(line)
        if "[3/13]" in line:
            break
    return node, client, seen, env, driver


def test_second_goal_is_rejected_with_a_reason(launch, ros_domain, executable):
    node, first, _, env, _ = _block_transfer_under_way(launch, ros_domain, executable)
    second = subprocess.run([executable("hyperarm_tasks", "run_task"), "ready"], env=env,
                            capture_output=True, text=True, timeout=60)
    assert second.returncode == 1
    # the node's reason, not a guess (issue 24, item 6)
    assert ("run_task: rejected: task 'ready' rejected: task 'block_transfer' is running "
            "(one goal at a time)") in second.stdout + second.stderr, second
    assert "another task running?" not in second.stdout + second.stderr
    assert "task 'ready' rejected: task 'block_transfer' is running (one goal at a time)" in \
        node.output()
    first.send_signal(signal.SIGINT)
    rest, _ = first.communicate(timeout=30)
    assert "cancelled during above_source" in rest


def _sigterm_task_node(node, client) -> tuple[int, float, str, str]:
    """SIGTERM to task_node: (its exit code, s to exit, the client's further output, the
    node's log)."""
    t0 = time.monotonic()
    node.proc.send_signal(signal.SIGTERM)
    code = node.proc.wait(timeout=10)
    took = time.monotonic() - t0
    try:
        rest, _ = client.communicate(timeout=30)
    finally:
        client.kill()
    return code, took, rest, node.output()


def test_task_node_stopped_mid_task_stops_it_holds_and_answers(launch, ros_domain, executable):
    """SIGTERM to task_node while a task moves the arm (a user's Ctrl-C to the node, or its
    launch file's stop): the task stops as a cancel stops it (force off, the driver told to
    hold), its client gets an aborted result naming the stop, and the node exits within 2 s.
    Before (the task in the executor's thread pool) the node was destroyed under the moving
    task and the client waited for a result that never came."""
    node, client, seen, _, _ = _block_transfer_under_way(launch, ros_domain, executable)
    time.sleep(0.5)                      # above_source is moving
    code, took, rest, out = _sigterm_task_node(node, client)
    assert code == 0 and took < 2.0, (code, took, out[-2000:])
    assert "stopping: task 'block_transfer' stops during above_source" in out, out[-2000:]
    assert "hold failed" not in out, out[-2000:]
    assert "run_task: failed: task_node stopped: cancelled during above_source" in rest, \
        "".join(seen) + rest
    assert "[4/13]" not in rest


def test_task_node_stopped_while_the_driver_hangs_still_answers(launch, ros_domain,
                                                                executable):
    """The driver frozen (SIGSTOP: no joint_states, no answer to hold) mid-task, then SIGTERM
    to task_node: the task cannot stop as a cancel does (its hold waits for the driver), so
    after STOP_WAIT (1 s) the node answers the client itself, aborted and saying so, and
    exits; no result is lost to the node's destruction."""
    node, client, seen, _, driver = _block_transfer_under_way(launch, ros_domain, executable)
    time.sleep(0.5)                      # above_source is moving
    driver.proc.send_signal(signal.SIGSTOP)
    try:
        time.sleep(0.3)
        code, took, rest, out = _sigterm_task_node(node, client)
    finally:
        driver.proc.send_signal(signal.SIGCONT)
    assert code == 0 and took < 2.0, (code, took, out[-2000:])
    assert "run_task: failed: task_node stopped: task 'block_transfer' did not stop within " \
        "1 s (during above_source)" in rest, "".join(seen) + rest + out[-2000:]
    assert "[4/13]" not in rest


def test_hardware_mode_runs_on_the_dynamixel_driver(launch, executable, ros_domain, tmp_path,
                                                    wait_for, still_running):
    """--hardware PARAMS: the real Dynamixel driver (on its bus emulator) instead of the mock."""
    link = tmp_path / "ttyDXL"
    launch("hyperarm_driver", "dxl_emulator", "--link", str(link))
    wait_for(link.exists, 20.0, what="the emulator's pty")
    params = tmp_path / "hw.yaml"
    params.write_text(f"/**:\n  ros__parameters:\n    port: {link}\n    torque_on_start: true\n")
    logs = tmp_path / "logs"
    done = _run(_script(executable), ["--hardware", str(params), "--logs", str(logs),
                                      "rest", "ready"], ros_domain, 120)
    out = done.stdout + done.stderr
    assert done.returncode == 0, out
    assert f"run_task.sh: rest ready on the hardware (drivers with {params}) (arm)" in out
    assert out.count("run_task: succeeded") == 2
    assert [line.split()[0] for line in (logs / "pids").read_text().splitlines()] == \
        ["dynamixel_driver", "hybrid_force", "task_node"]
    assert still_running(logs) == []
