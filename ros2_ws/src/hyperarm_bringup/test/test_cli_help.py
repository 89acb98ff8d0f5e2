"""Every installed executable answers --help and -h with its own usage (the same text for
both) and exit 0, without starting ROS (issue 25 item 6: `ready.sh --help` printed run_task's usage, `run_sequence.sh --help`
took --help for a task name). A probe node on this test's own ROS domain watches the graph
meanwhile: no executable may bring a node up to print its help."""
from __future__ import annotations

import os
import re
import subprocess
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

PACKAGES = ("hyperarm_bringup", "hyperarm_description", "hyperarm_driver", "hyperarm_ik",
            "hyperarm_perception", "hyperarm_tasks", "hyperarm_control")


#: hyperarm_tasks' executables, each with the start of its own usage text
TASKS_USAGE = {
    "run_task": "usage: run_task",
    "task_node": "usage: ros2 run <package> task_node",
    "task_recorder": "usage: ros2 run <package> task_recorder",
    "plot_task": "usage: plot_task",
    "soak_block_transfer": "usage: soak_block_transfer",
    "host_plots": "usage: host_plots",
    "run_task.sh": "run_task.sh: start the hyperarm stack",
    "ready.sh": "ready.sh: move the arm to the ready pose",
    "run_sequence.sh": "run_sequence.sh: run several tasks in order",
}


def installed_executables() -> list[Path]:
    from ament_index_python.packages import get_package_prefix

    out = []
    for pkg in PACKAGES:
        lib = Path(get_package_prefix(pkg)) / "lib" / pkg
        out += sorted(p for p in lib.iterdir() if p.is_file() and os.access(p, os.X_OK))
    return out


def test_every_installed_executable_answers_help_with_its_own_usage(rclpy_context, executor,
                                                                     ros_domain):
    import rclpy

    exes = installed_executables()
    names = {p.name for p in exes}
    assert {"hyperarm", "viewer", "mock_driver", "dynamixel_driver", "pmac_rail_driver",
            "ready.sh", "run_sequence.sh", "run_task.sh", "run_task"} <= names, names

    probe = rclpy.create_node("help_probe", context=rclpy_context)
    executor.add_node(probe)
    seen: set[str] = set()
    stop = threading.Event()
    # nodes already on the domain before any --help runs are not theirs: an earlier test's
    # in-process nodes on a reused domain whose participant the graph still lists (seen:
    # test_client_in_executor's 'in_executor_client'/'in_executor_server')
    time.sleep(1.0)
    before = set(probe.get_node_names())

    def watch() -> None:
        while not stop.wait(0.05):
            seen.update(n for n in probe.get_node_names()
                        if n != "help_probe" and n not in before)
    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()

    def run(exe: Path, flag: str) -> tuple[Path, subprocess.CompletedProcess]:
        return exe, subprocess.run([str(exe), flag], capture_output=True, text=True,
                                   timeout=60, stdin=subprocess.DEVNULL,
                                   env=dict(os.environ, ROS_DOMAIN_ID=str(ros_domain)))
    try:
        with ThreadPoolExecutor(max_workers=4) as pool:
            results = list(pool.map(run, exes, ["--help"] * len(exes)))
            short = list(pool.map(run, exes, ["-h"] * len(exes)))
    finally:
        stop.set()
        watcher.join(timeout=5)
    problems = []
    for exe, r in results:
        text = r.stdout.strip()
        first = text.splitlines()[0] if text else ""
        if r.returncode != 0:
            problems.append(f"{exe.name}: exit {r.returncode}: {r.stderr.strip()[-300:]}")
        elif exe.name not in first:   # its own usage, not another program's
            problems.append(f"{exe.name}: first line of --help is {first!r}")
        elif not re.search(rf"(^|\s){re.escape(exe.name)} [\[A-Z-]", text, re.M):
            problems.append(f"{exe.name}: --help has no synopsis ('{exe.name} [OPTIONS|ARG]"
                            f"...'): {text[:200]!r}")
    for (exe, r), (_, h) in zip(results, short):
        if (h.returncode, h.stdout, h.stderr) != (r.returncode, r.stdout, r.stderr):
            problems.append(f"{exe.name}: -h (exit {h.returncode}) differs from --help: "
                            f"{(h.stdout + h.stderr)[:300]!r}")
        if exe.parent.name == "hyperarm_tasks":
            if not r.stdout.lstrip().startswith(TASKS_USAGE.get(exe.name, "(unknown)")):
                problems.append(f"{exe.name}: --help does not start with "
                                f"{TASKS_USAGE.get(exe.name)!r}: {r.stdout[:200]!r}")
    tasks = {e.name for e in exes if e.parent.name == "hyperarm_tasks"}
    assert tasks == set(TASKS_USAGE), f"hyperarm_tasks installs {sorted(tasks)}"
    assert not problems, "\n".join(problems)
    assert not seen, f"--help started ROS nodes: {sorted(seen)}"
