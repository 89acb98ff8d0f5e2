"""soak_block_transfer: block_transfer N times in a row on the mock, a new seed each cycle.

    soak_block_transfer [--cycles 20] [--first-seed 1] [--logs DIR]

Each cycle is one run of run_task.sh (a fresh stack: mock_driver with the default work cell
and noise, its imperfection and camera seeds set to the cycle's seed; task_node), so every
cycle sees a different arm error and camera noise. Prints one line per cycle and the
figures recorded in docs/benchmarks.md: success rate, mean and p95 cycle time (the task's
own time, without the stack's start-up), insertion time, dither turns and insertion
attempts. Exit code 0 only if every cycle succeeded.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

_RESULT = re.compile(r"run_task: (\w+): (.*)")
_DONE = re.compile(r"done in ([0-9.]+) s \((.*)\)")


def _script() -> str:
    from ament_index_python.packages import get_package_prefix
    return str(Path(get_package_prefix("hyperarm_tasks")) / "lib" / "hyperarm_tasks" / "run_task.sh")


def run_cycle(seed: int, logs: Path, task: str = "block_transfer") -> dict:
    t0 = time.monotonic()
    done = subprocess.run([_script(), "--seed", str(seed), "--logs", str(logs / f"seed{seed}"),
                           task], capture_output=True, text=True, timeout=600,
                          env=dict(os.environ, PYTHONUNBUFFERED="1"))
    out = {"seed": seed, "ok": done.returncode == 0, "wall": time.monotonic() - t0,
           "message": "", "metrics": {}, "time": float("nan")}
    for line in (done.stdout + done.stderr).splitlines():
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
        out["message"] = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
    return out


def _stats(values) -> str:
    v = np.array([x for x in values if np.isfinite(x)])
    if not len(v):
        return "n/a"
    return f"mean {v.mean():.2f}, p95 {np.percentile(v, 95):.2f}, max {v.max():.2f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="soak_block_transfer", description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--logs", default=None, help="keep every cycle's logs here")
    args = ap.parse_args(argv)
    logs = Path(args.logs) if args.logs else Path(tempfile.mkdtemp(prefix="hyperarm-soak."))
    results = []
    for k in range(args.cycles):
        seed = args.first_seed + k
        r = run_cycle(seed, logs)
        results.append(r)
        m = r["metrics"]
        print(f"cycle {k + 1:2d} seed {seed:3d}: {'ok  ' if r['ok'] else 'FAIL'} "
              f"task {r['time']:.1f} s (wall {r['wall']:.0f} s), insertion "
              f"{m.get('insertion_time', float('nan')):.2f} s, dither turns "
              f"{m.get('dither_turns', float('nan')):.1f}, attempts "
              f"{m.get('insertion_attempts', float('nan')):.0f}"
              + ("" if r["ok"] else f": {r['message']}"), flush=True)
    ok = [r for r in results if r["ok"]]
    print(f"\nsuccess: {len(ok)}/{len(results)}")
    print(f"cycle time (s): {_stats([r['time'] for r in ok])}")
    print(f"insertion time (s): {_stats([r['metrics'].get('insertion_time', np.nan) for r in ok])}")
    print(f"dither turns: {_stats([r['metrics'].get('dither_turns', np.nan) for r in ok])}")
    print(f"insertion attempts: {_stats([r['metrics'].get('insertion_attempts', np.nan) for r in ok])}")
    print(f"logs: {logs}")
    return 0 if len(ok) == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
