"""Every installed executable of hyperarm_tasks answers ``--help`` and ``-h`` with its own
usage, exit 0, starting nothing (issue 24: ``ready.sh --help`` printed run_task's usage and
``run_sequence.sh --help`` sent a task called "--help")."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

pytestmark = [pytest.mark.e2e]

#: the installed executables, each with a word of its own usage text
EXPECTED = {
    "run_task": "usage: run_task",
    "task_node": "usage: ros2 run <package> task_node",
    "task_recorder": "usage: ros2 run <package> task_recorder",
    "plot_task": "usage: plot_task",
    "soak_block_transfer": "usage: soak_block_transfer",
    "run_task.sh": "run_task.sh: start the hyperarm stack",
    "ready.sh": "ready.sh: move the arm to the ready pose",
    "run_sequence.sh": "run_sequence.sh: run several tasks in order",
}


def _installed(executable) -> dict[str, str]:
    lib = Path(executable("hyperarm_tasks", "run_task")).parent
    return {p.name: str(p) for p in sorted(lib.iterdir())
            if p.is_file() and os.access(p, os.X_OK)}


def test_every_executable_is_known_here(executable):
    assert set(_installed(executable)) == set(EXPECTED)


@pytest.mark.parametrize("flag", ["--help", "-h"])
def test_every_executable_answers_help_with_its_own_usage(executable, flag, ros_domain):
    problems = []
    for name, path in _installed(executable).items():
        done = subprocess.run([path, flag], capture_output=True, text=True, timeout=60,
                              env=dict(os.environ, ROS_DOMAIN_ID=str(ros_domain)))
        text = done.stdout + done.stderr
        if done.returncode != 0:
            problems.append(f"{name} {flag}: exit {done.returncode}\n{text[-800:]}")
        elif not text.lstrip().startswith(EXPECTED[name]):
            problems.append(f"{name} {flag}: not its own usage:\n{text[:400]}")
        elif "Traceback" in text:
            problems.append(f"{name} {flag}: traceback\n{text[-800:]}")
    assert not problems, "\n\n".join(problems)
