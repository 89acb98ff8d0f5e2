"""soak_block_transfer: block_transfer N times in a row on the mock, a new seed each cycle.

    soak_block_transfer [--cycles 20] [--first-seed 1] [--logs DIR]
                        [--task T] [--variant V] [--workcell FILE] [--camera C]

Each cycle is one run of run_task.sh (a fresh stack: mock_driver with the default work cell
and noise, its imperfection and camera seeds set to the cycle's seed; task_node), so every
cycle sees a different arm error and camera noise. Prints one line per cycle and the
figures recorded in docs/benchmarks.md: success rate, mean and p95 cycle time (the task's
own time, without the stack's start-up), insertion time, dither turns and insertion
attempts. Exit code 0 only if every cycle succeeded. ``--task`` soaks another task the same
way (e.g. ``figure8``; ``rail_transport --variant rail_arm --workcell .../workcell_rail.yaml``)
and prints the statistics of every metric its result reports. ``--camera rendered`` runs
every cycle on the mock's rendered pictures and the marker detector (run_task.sh
``--camera``; default ``oracle``, the mock's noisy true poses).
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

import numpy as np

_RESULT = re.compile(r"run_task: (\w+): (.*)")
STOP_WAIT = 60.0   # s for run_task.sh to stop its stack (its client, then each node)
_DONE = re.compile(r"done in ([0-9.]+) s \((.*)\)")
_STEPS = "run_task: time per step (s): "


def _script() -> str:
    from ament_index_python.packages import get_package_prefix
    return str(Path(get_package_prefix("hyperarm_tasks")) / "lib" / "hyperarm_tasks" / "run_task.sh")


_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


def _run(cmd: list[str], timeout: float, pids: Path) -> tuple[int, str, str]:
    """Run one run_task.sh (in its own session); on Ctrl-C, SIGTERM or the timeout, stop it
    (:func:`_stop`) before going on, with SIGINT and SIGTERM held off meanwhile, so no
    cycle's stack is left behind. ``pids``: its ``--logs`` directory's pids file."""
    held = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"),
                                start_new_session=True, preexec_fn=_unblock)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
        return proc.returncode, stdout, stderr
    except BaseException as exc:
        signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
        try:
            stdout, stderr = _stop(proc, pids)
        finally:   # a stop request that came meanwhile is delivered here
            signal.pthread_sigmask(signal.SIG_SETMASK, held)
        if isinstance(exc, subprocess.TimeoutExpired):
            return 124, stdout, stderr + f"\nsoak: the cycle took more than {timeout:g} s"
        for line in (stdout + stderr).splitlines():   # a node run_task.sh had to SIGKILL
            if "killing it" in line or "did not stop" in line:
                print(line, file=sys.stderr, flush=True)
        raise


def _unblock() -> None:
    """In the child before exec: the stop signals are blocked in the parent around the
    fork, and a child would inherit that (run_task.sh's traps would never run)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)


def _stop(proc: subprocess.Popen, pids: Path) -> tuple[str, str]:
    """SIGTERM run_task.sh (it stops every process it started: SIGTERM, since a shell started
    in the background ignores SIGINT), give it STOP_WAIT s, then SIGKILL what is left: its
    session and every node in its pids file (run_task.sh starts each in a session of its
    own)."""
    proc.terminate()
    try:
        stdout, stderr = proc.communicate(timeout=STOP_WAIT)
    except subprocess.TimeoutExpired:
        stdout, stderr = "", "soak: run_task.sh did not stop in time: killed\n"
    for pid in [proc.pid] + _listed(pids):
        try:
            os.killpg(pid, signal.SIGKILL) if pid == proc.pid else os.kill(pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
    if proc.returncode is None:
        proc.communicate()
    return stdout, stderr


def _listed(pids: Path) -> list[int]:
    """The pids in a run_task.sh pids file ("name pid" lines), [] without one."""
    try:
        lines = pids.read_text().splitlines()
    except OSError:
        return []
    return [int(line.split()[1]) for line in lines if len(line.split()) == 2
            and line.split()[1].isdigit()]


def _cycles(args, logs: Path, options: list[str], task: str, results: list[dict],
            line) -> None:
    """Run the cycles into ``results``, a line each (``line(k, seed, result)``); a stop
    request (Ctrl-C, SIGTERM) ends them after the cycle's stack is stopped. Further stop
    requests are ignored from then on: the summary is printed whole."""
    k, seed = 0, args.first_seed
    try:
        for k in range(args.cycles):
            seed = args.first_seed + k
            results.append(run_cycle(seed, logs, task, options))
            print(line(k, seed, results[-1]), flush=True)
    except KeyboardInterrupt:
        for sig in _STOP_SIGNALS:
            signal.signal(sig, signal.SIG_IGN)
        print(f"\ninterrupted in cycle {k + 1} (seed {seed}); its stack stopped", flush=True)
        return
    for sig in _STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)


def _terminate(signum, frame):   # SIGTERM: stop as Ctrl-C does (the cycle's stack first)
    raise KeyboardInterrupt


def _handle_signals() -> None:
    """SIGINT and SIGTERM stop the soak (the cycle's stack first), also when it was started
    in the background, where SIGINT is ignored on entry."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _terminate)


def run_cycle(seed: int, logs: Path, task: str = "block_transfer",
              options: list[str] | None = None) -> dict:
    t0 = time.monotonic()
    where = logs / f"seed{seed}"
    rc, stdout, stderr = _run([_script(), "--seed", str(seed), "--logs", str(where),
                               *(options or []), task], timeout=600, pids=where / "pids")
    out = {"seed": seed, "ok": rc == 0, "wall": time.monotonic() - t0,
           "message": "", "metrics": {}, "time": float("nan"), "steps": {}}
    for line in (stdout + stderr).splitlines():
        if line.startswith(_STEPS):     # a step run twice (a retry) counts both times
            for item in line[len(_STEPS):].split(", "):
                name, _, value = item.rpartition(" ")
                try:
                    out["steps"][name] = out["steps"].get(name, 0.0) + float(value)
                except ValueError:
                    pass
            continue
        m = _RESULT.search(line)
        if m:
            out["message"] = m.group(2)
            d = _DONE.search(m.group(2))
            if d:
                out["time"] = float(d.group(1))
                for item in d.group(2).split(", "):
                    name, _, value = item.rpartition(" ")
                    try:
                        out["metrics"][name] = float(value)
                    except ValueError:
                        pass
    if not out["message"]:
        out["message"] = (stderr or stdout).strip().splitlines()[-1:] or ["no output"]
    return out


def step_table(results: list[dict]) -> str:
    """Where the cycle time goes: per step (in the order the tasks ran them), its mean and
    max time over ``results`` (s; a retried step's runs summed per cycle) and share of the
    mean cycle, as a markdown table."""
    names: list[str] = []
    for r in results:
        names += [n for n in r.get("steps", {}) if n not in names]
    if not names:
        return "time per step: n/a (run_task printed none)"
    total = float(np.mean([r["time"] for r in results]))
    rows = ["| step | mean s | max s | share of the cycle |", "|---|---|---|---|"]
    for n in names:
        v = np.array([r["steps"].get(n, 0.0) for r in results])
        rows.append(f"| {n} | {v.mean():.2f} | {v.max():.2f} | {100 * v.mean() / total:.0f} % |")
    return "time per step:\n" + "\n".join(rows)


def _stats(values, fmt: str = ".2f") -> str:
    v = np.array([x for x in values if np.isfinite(x)])
    if not len(v):
        return "n/a"
    return (f"mean {v.mean():{fmt}}, p95 {np.percentile(v, 95):{fmt}}, "
            f"max {v.max():{fmt}}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="soak_block_transfer", description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--logs", default=None, help="keep every cycle's logs here")
    ap.add_argument("--task", default="block_transfer", help="the task to soak")
    ap.add_argument("--variant", default=None, help="run_task.sh --variant")
    ap.add_argument("--workcell", default=None, help="run_task.sh --workcell (the mock's cell)")
    ap.add_argument("--camera", choices=("oracle", "rendered"), default="oracle",
                    help="run_task.sh --camera: the mock's noisy true poses (oracle) or its "
                         "rendered pictures and marker_detector (rendered)")
    args = ap.parse_args(argv)
    logs = Path(args.logs) if args.logs else Path(tempfile.mkdtemp(prefix="hyperarm-soak."))
    options = [*(["--variant", args.variant] if args.variant else []),
               *(["--camera", args.camera] if args.camera != "oracle" else []),
               *(["--workcell", args.workcell] if args.workcell else [])]
    if args.task != "block_transfer":
        return _soak_task(args, logs, options)
    _handle_signals()
    results: list[dict] = []

    def line(k: int, seed: int, r: dict) -> str:
        m = r["metrics"]
        return (f"cycle {k + 1:2d} seed {seed:3d}: {'ok  ' if r['ok'] else 'FAIL'} "
                f"task {r['time']:.1f} s (wall {r['wall']:.0f} s), insertion "
                f"{m.get('insertion_time', float('nan')):.2f} s, dither turns "
                f"{m.get('dither_turns', float('nan')):.1f}, attempts "
                f"{m.get('insertion_attempts', float('nan')):.0f}, task_node CPU "
                f"{100 * m.get('task_node_cpu', float('nan')):.0f} %"
                + ("" if r["ok"] else f": {r['message']}"))

    _cycles(args, logs, options, "block_transfer", results, line)
    ok = [r for r in results if r["ok"]]
    print(f"\nsuccess: {len(ok)}/{len(results)}")
    print(f"cycle time (s): {_stats([r['time'] for r in ok])}")
    print(f"insertion time (s): {_stats([r['metrics'].get('insertion_time', np.nan) for r in ok])}")
    print(f"dither turns: {_stats([r['metrics'].get('dither_turns', np.nan) for r in ok])}")
    print(f"insertion attempts: {_stats([r['metrics'].get('insertion_attempts', np.nan) for r in ok])}")
    print(f"located poses used (an object the arm hid): "
          f"{_stats([r['metrics'].get('located_used', 0.0) for r in ok])}; held block unseen "
          f"at the insertion's check: {sum('camera_check_unseen' in r['metrics'] for r in ok)}"
          f"/{len(ok)} cycles")
    print(f"task_node CPU (fraction of one core over the task): "
          f"{_stats([r['metrics'].get('task_node_cpu', np.nan) for r in ok])}")
    print(step_table(ok))
    print(f"logs: {logs}")
    if len(results) < args.cycles:
        return 130
    return 0 if len(ok) == len(results) else 1


def _soak_task(args, logs: Path, options: list[str]) -> int:
    """Any other task: a line per cycle, then the statistics of every reported metric."""
    _handle_signals()
    results: list[dict] = []

    def line(k: int, seed: int, r: dict) -> str:
        figures = ", ".join(f"{n} {v:.4g}" for n, v in r["metrics"].items())
        return (f"cycle {k + 1:2d} seed {seed:3d}: {'ok  ' if r['ok'] else 'FAIL'} task "
                f"{r['time']:.1f} s (wall {r['wall']:.0f} s)"
                + (f": {figures}" if r["ok"] else f": {r['message']}"))

    _cycles(args, logs, options, args.task, results, line)
    ok = [r for r in results if r["ok"]]
    print(f"\n{args.task} success: {len(ok)}/{len(results)}")
    print(f"task time (s): {_stats([r['time'] for r in ok])}")
    for name in dict.fromkeys(n for r in ok for n in r["metrics"]):
        print(f"{name}: min {_min(ok, name)}, "
              f"{_stats([r['metrics'].get(name, np.nan) for r in ok], '.4g')}")
    print(step_table(ok))
    print(f"logs: {logs}")
    if len(results) < args.cycles:
        return 130
    return 0 if len(ok) == len(results) else 1


def _min(results: list[dict], name: str) -> str:
    v = [r["metrics"][name] for r in results if name in r["metrics"]]
    return f"{min(v):.4g}" if v else "n/a"


if __name__ == "__main__":
    sys.exit(main())
