"""stop_cycles: start run_task.sh and stop it with a Ctrl-C at a random instant, N times.

    python -m hyperarm_tasks.benchmarks.stop_cycles [--cycles 50] [--seed 1] [--max-delay 12]
                                                    [--task block_transfer] [--logs DIR]

Each cycle starts the installed run_task.sh (the mock, hybrid_force and task_node as separate
processes) and sends SIGINT a uniformly drawn 0..max-delay s after its "logs in" line, either
to its process group (a terminal's Ctrl-C) or to the script alone (``kill -INT``), in turn.
A cycle passes when the script exits non-zero within :data:`EXIT_WITHIN` s, no process it
started was SIGKILLed or is left running, and no task step started after the Ctrl-C reached
the task node (issue 24, item 2). Prints a line per cycle and the worst exit time; exit code
0 only if every cycle passed. The e2e tests (test_interrupt_e2e.py) use the same checks.
"""
from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

EXIT_WITHIN = 2.0   # s from the Ctrl-C to run_task.sh's exit (issue 24, item 2)
_STAMP = re.compile(r"^\[\w+\] \[(\d+\.\d+)\] \[hyperarm\.task_node\]: (.*)$")


def run_task_sh() -> str:
    """The installed run_task.sh."""
    from ament_index_python.packages import get_package_prefix
    return str(Path(get_package_prefix("hyperarm_tasks")) / "lib" / "hyperarm_tasks"
               / "run_task.sh")


def interrupt_at(cmd: list[str], delay: float, after: str | None = "logs in",
                 group: bool = False, env: dict | None = None
                 ) -> tuple[int, float, str, float]:
    """Run ``cmd`` (e.g. ``run_task.sh --logs LOGS TASK``; SIGINT not ignored, as from a
    terminal) and send it SIGINT ``delay`` s after its first output line containing
    ``after`` (None: after its start) (to its whole process group with ``group``, as a
    terminal's Ctrl-C). Returns (exit code, s from the signal to the exit, output, the
    signal's wall-clock time)."""
    proc = subprocess.Popen(cmd,
                            env=dict(env or os.environ, PYTHONUNBUFFERED="1"),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = []
    try:
        for line in (proc.stdout if after is not None else ()):
            lines.append(line)
            if after in line:
                break
        time.sleep(delay)
        sent, wall = time.monotonic(), time.time()
        if group:
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGINT)
        try:
            rest, _ = proc.communicate(timeout=15.0)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)     # the script and every node it started
            rest, _ = proc.communicate()
            rest += "\n(still running 15 s after the signal: its process group killed)"
        return proc.returncode, time.monotonic() - sent, "".join(lines) + rest, wall
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()


def left_running(logs: Path) -> list[str]:
    """The processes of run_task.sh's ``pids`` file that still run, as "name (pid)"."""
    out = []
    path = logs / "pids"
    for line in (path.read_text().splitlines() if path.exists() else []):
        if len(line.split()) == 2:
            name, pid = line.split()
            try:
                os.kill(int(pid), 0)
                out.append(f"{name} ({pid})")
            except ProcessLookupError:
                pass
    return out


def task_node_lines(logs: Path) -> list[tuple[float, str]]:
    """(wall-clock time, message) of the task node's log lines (``logs``: run_task.sh's
    logs directory, or the task node's log file)."""
    path = logs if logs.is_file() else logs / "task_node.log"
    out = []
    for line in (path.read_text(errors="replace").splitlines() if path.exists() else []):
        m = _STAMP.match(line)
        if m:
            out.append((float(m.group(1)), m.group(2)))
    return out


def check_stopped(code: int, took: float, out: str, logs: Path, wall: float) -> list[str]:
    """What went wrong with one interrupted run of run_task.sh ([] if nothing)."""
    problems = []
    if code == 0:
        problems.append("exit code 0 after a Ctrl-C")
    if took > EXIT_WITHIN:
        problems.append(f"exited {took:.2f} s after the Ctrl-C (> {EXIT_WITHIN:g} s)")
    if "killing it" in out:
        problems.append("a process was SIGKILLed")
    left = left_running(logs)
    if left:
        problems.append(f"left running: {left}")
    problems += late_steps(task_node_lines(logs), wall, out)
    return problems


def late_steps(lines: list[tuple[float, str]], wall: float, out: str) -> list[str]:
    """Steps the task node started after a Ctrl-C at ``wall`` (``lines``: its log from
    :func:`task_node_lines`, ``out``: the client's output)."""
    problems = []
    lines = [(t, msg) for t, msg in lines if t > wall - 60.0]
    cancel = [t for t, msg in lines if msg.startswith("cancel requested") and t > wall]
    # no step may start after the cancel reached the node (or, without a cancel: nothing
    # was sent, no step at all after the Ctrl-C)
    since = cancel[0] if cancel else wall
    late = [msg for t, msg in lines if t > since and re.match(r"step \d+/\d+ ", msg)]
    if late:
        problems.append(f"steps started after the Ctrl-C: {late}")
    if "no task sent" in out and any(re.match(r"task '[^']+': \d+ steps", msg)
                                     for _t, msg in lines):
        problems.append("the client said 'no task sent' but the task node got the task")
    return problems


def main(argv: list[str] | None = None) -> int:
    import numpy as np

    ap = argparse.ArgumentParser(prog="stop_cycles", description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=50)
    ap.add_argument("--seed", type=int, default=1, help="seed of the drawn instants")
    ap.add_argument("--max-delay", type=float, default=12.0, metavar="S",
                    help="instants drawn from 0..S s after 'logs in'")
    ap.add_argument("--task", default="block_transfer")
    ap.add_argument("--logs", default=None, help="keep every cycle's logs here")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    logs = Path(args.logs) if args.logs else Path(tempfile.mkdtemp(prefix="hyperarm-stops."))
    script, failed, worst = run_task_sh(), 0, 0.0
    for k in range(args.cycles):
        delay, group = float(rng.uniform(0.0, args.max_delay)), k % 2 == 0
        where = logs / f"cycle{k + 1}"
        code, took, out, wall = interrupt_at([script, "--logs", str(where), args.task], delay,
                                             group=group)
        problems = check_stopped(code, took, out, where, wall)
        worst = max(worst, took)
        stage = ("no task sent" if "no task sent" in out else
                 (re.findall(r"canceled: (.*)", out) or ["?"])[-1])
        print(f"cycle {k + 1:2d}: Ctrl-C {delay:5.2f} s after 'logs in' "
              f"({'group' if group else 'script'}): exit {code} after {took:.2f} s, {stage}"
              + ("" if not problems else f": FAIL {'; '.join(problems)}"), flush=True)
        failed += bool(problems)
    print(f"\n{args.cycles - failed}/{args.cycles} stopped cleanly; slowest exit {worst:.2f} s; "
          f"logs: {logs}")
    return 0 if not failed else 1


if __name__ == "__main__":
    sys.exit(main())
