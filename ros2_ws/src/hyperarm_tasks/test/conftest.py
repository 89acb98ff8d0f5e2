"""Fixtures of the hyperarm_tasks tests (the shared ones are in ros2_ws/src/conftest.py):
the fixed arm's description and kinematics, and what run_task.sh left running."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path
from typing import Callable

import pytest

from hyperarm_tasks.process_group import run_stoppable


@pytest.fixture(scope="module")
def desc():
    from hyperarm_description import load_description
    return load_description()


@pytest.fixture(scope="module")
def kin(desc):
    # imported here: collecting this directory must not need pinocchio (the robot route's
    # numpy-1.26 core run has none: scripts/robot_route/core_tests.sh)
    from hyperarm_ik.kinematics import Kinematics
    return Kinematics(desc)


def _alive(logs: Path) -> list[str]:
    """The processes run_task.sh started (its ``--logs`` directory's ``pids`` file) that are
    still running, as "name (pid)"."""
    out = []
    for line in (logs / "pids").read_text().split("\n"):
        if line.strip():
            name, pid = line.split()
            try:
                os.kill(int(pid), 0)
                out.append(f"{name} ({pid})")
            except ProcessLookupError:
                pass
    return out


def _digest(logs: Path, tail: int = 25) -> str:
    """What the nodes of a failed run said: every WARN, ERROR or FATAL line of each node's
    log in ``logs`` and the last ``tail`` lines of the task node's (for a failure message:
    the CI keeps only the test's output)."""
    out = []
    for log in sorted(Path(logs).glob("*.log")):
        lines = log.read_text(errors="replace").splitlines()
        bad = [ln for ln in lines if any(f"[{w}]" in ln for w in ("WARN", "ERROR", "FATAL"))
               or "Traceback" in ln]
        out.append(f"--- {log.name}: {len(bad)} warnings/errors of {len(lines)} lines")
        out += bad[-40:]
        if log.name == "task_node.log":
            out.append(f"--- {log.name}: last {tail} lines")
            out += lines[-tail:]
    return "\n".join(out)


@pytest.fixture
def node_logs() -> Callable[[Path], str]:
    """``node_logs(logs)``: the warnings and errors of a run's node logs, for an assertion's
    message."""
    return _digest


@pytest.fixture
def still_running() -> Callable[[Path], list[str]]:
    """``still_running(logs)``: what run_task.sh left behind (expected: [])."""
    return _alive


@pytest.fixture
def run_task_sh(executable, ros_domain) -> Callable[..., subprocess.CompletedProcess]:
    """``run_task_sh(*args, timeout=s)``: the installed run_task.sh on the test's domain,
    output captured (text); at ``timeout`` stopped with its nodes
    (:func:`hyperarm_tasks.testing.run_stoppable`)."""
    script = os.path.join(os.path.dirname(executable("hyperarm_tasks", "run_task")),
                          "run_task.sh")

    def run(*args: str, timeout: float) -> subprocess.CompletedProcess:
        env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain), PYTHONUNBUFFERED="1")
        return run_stoppable([script, *args], env=env, timeout=timeout)
    return run
