"""End-to-end (issue 24, item 2): a Ctrl-C at any instant of the installed run_task.sh's
start-up stops it: no task step starts after it, the script exits non-zero within 2 s, and
no process it started is SIGKILLed or left running.

Before the fix a Ctrl-C 0.6 or 1.0 s after the "logs in" line was lost (the client, a
background job, ignored SIGINT until rclpy was up) and the whole task ran; one 0.4 s in
SIGKILLed hybrid_force and task_node after 10 s each (they ignored the cleanup's SIGINT).
The checks are hyperarm_tasks.benchmarks.stop_cycles' (its 50-cycle run: docs/benchmarks.md).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from hyperarm_tasks.benchmarks.stop_cycles import check_stopped, interrupt_at

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

#: 20 instants from 0 to 3 s after the "logs in" line
INSTANTS = np.linspace(0.0, 3.0, 20)


def _script(executable) -> str:
    return os.path.join(os.path.dirname(executable("hyperarm_tasks", "run_task")), "run_task.sh")


def test_ctrl_c_at_20_instants_of_start_up(executable, ros_domain, tmp_path):
    script = _script(executable)
    report = []
    for i, delay in enumerate(INSTANTS):
        logs = tmp_path / f"run{i}"
        # in turn to the process group (a terminal's Ctrl-C) and to the script alone (kill)
        group = i % 2 == 0
        code, took, out, wall = interrupt_at([script, "--logs", str(logs), "block_transfer"],
                                             float(delay), group=group)
        problems = check_stopped(code, took, out, logs, wall)
        if problems:
            report.append(f"Ctrl-C {delay:.2f} s after 'logs in' ({'group' if group else 'script'})"
                          f": {'; '.join(problems)}\n" + out[-1500:])
    assert not report, "\n\n".join(report)


def test_ctrl_c_as_the_task_runs_stops_it_within_2_s(executable, ros_domain, tmp_path):
    """As the task begins (its first step's line: the goal just accepted; later instants
    are test_block_transfer_e2e's SIGINT mid-step and stop_cycles'): cancelled, no further
    step, exit within 2 s."""
    script = _script(executable)
    report = []
    for i, delay in enumerate((0.0,)):
        logs = tmp_path / f"run{i}"
        code, took, out, wall = interrupt_at([script, "--logs", str(logs), "block_transfer"],
                                             delay, after="[1/13]", group=True)
        problems = check_stopped(code, took, out, logs, wall)
        if "canceled: cancelled" not in out:
            problems.append("no 'canceled' result")
        if problems:
            report.append(f"Ctrl-C {delay:.1f} s into the task: {'; '.join(problems)}\n"
                          + out[-1500:])
    assert not report, "\n\n".join(report)


def test_ctrl_c_stops_make_demo_within_2_s(tmp_path, ros_domain):
    """`make demo`'s script (scripts/demo.sh), a terminal's Ctrl-C (its process group) in the
    stack's start-up and once the task runs: exit 130 within 2 s, nothing plotted, no node
    SIGKILLed or left running (it plotted a partial recording for seconds before)."""
    demo = Path(__file__).resolve().parents[4] / "scripts" / "demo.sh"
    report = []
    for i, (after, delay) in enumerate((("logs in", 0.5), ("[1/13]", 0.3))):
        out_dir = tmp_path / f"demo{i}"
        env = dict(os.environ, HYPERARM_DEMO_OUT=str(out_dir))
        code, took, out, wall = interrupt_at(["bash", str(demo)], delay, after=after,
                                             group=True, env=env)
        problems = check_stopped(code, took, out, out_dir / "logs", wall)
        if code != 130:
            problems.append(f"exit code {code}, not 130")
        if "plotting" in out:
            problems.append("plotted after the Ctrl-C")
        if problems:
            report.append(f"Ctrl-C {delay} s after {after!r}: {'; '.join(problems)}\n"
                          + out[-1500:])
    assert not report, "\n\n".join(report)


def test_ctrl_c_stops_the_cli_run_within_2_s(launch, executable, wait_for, tmp_path):
    """`hyperarm run`: a Ctrl-C while it starts, as the task begins and mid-step cancels the
    task (confirmed), exit 130 within 2 s, no traceback, no step after the cancel. Before,
    rclpy's own SIGINT handler shut the context down under the cancel: RCLError traceback,
    exit 1, the cancel never confirmed."""
    from hyperarm_tasks.benchmarks.stop_cycles import late_steps, task_node_lines

    launch("hyperarm_driver", "mock_driver")
    task = launch("hyperarm_tasks", "task_node")
    wait_for(lambda: "task_node ready" in task.output(), 60.0, what="task_node")
    cli = [executable("hyperarm_bringup", "hyperarm"), "run", "block_transfer"]
    report = []
    for after, delay in ((None, 0.3), ("[1/13]", 0.0), ("[2/13]", 0.3)):
        code, took, out, wall = interrupt_at(cli, delay, after=after, group=True)
        problems = late_steps(task_node_lines(task.log), wall, out)
        # 0.3 s after the start it may still be in Python's start-up and setuptools'
        # console-script wrapper (no code of ours yet: a KeyboardInterrupt there ends it
        # with -2 and a traceback, nothing sent; docs/architecture.md)
        if code not in ((130,) if after is not None else (130, -2)):
            problems.append(f"exit code {code}, not 130")
        if took > 2.0:
            problems.append(f"exited {took:.2f} s after the Ctrl-C")
        if "Traceback" in out and after is not None:
            problems.append("traceback")
        if after is not None and "canceled: cancelled" not in out:
            problems.append("no confirmed cancel")
        if problems:
            report.append(f"Ctrl-C {delay} s after {after or 'the start'}: "
                          f"{'; '.join(problems)}\n{out[-2000:]}")
        # the next run starts once the node has finished this one
        wait_for(lambda: "(force control off, holding)" in task.output()
                 or after is None, 10.0, what="the cancel's end")
    assert not report, "\n\n".join(report)
