#!/usr/bin/env python3
"""Check that every installed executable of the workspace runs with the venv's interpreter.

``ros2 run`` (and a launch file) starts ``install/<pkg>/lib/<pkg>/<exe>`` through its shebang.
colcon writes that shebang from the interpreter colcon runs under; apt's colcon runs under
/usr/bin/python3, which cannot import what ``requirements-robot.txt`` put into the venv
(viser, mcap), so ``viewer``, ``task_recorder`` and ``plot_task`` would fail on the robot.
scripts/setup.sh therefore builds with the venv's python (scripts/colcon_build.sh); this
script checks the result, for every executable:

- a Python script: its shebang is exactly ``--python`` (default: the venv of
  scripts/setup.sh, ``$HYPERARM_VENV`` or ``.venv``, ``bin/python``; not resolved, since
  a venv's python is a symlink to the system one), and its entry point (the module and
  function named by the script: ``EASY-INSTALL-ENTRY-SCRIPT`` / ``load_entry_point``, or a
  ``from MODULE import NAME`` line) imports under that interpreter in this environment
  (run it after ``source scripts/env.sh``);
- a shell script: a bash/sh shebang and ``bash -n`` finds no syntax error.

Exit 0 with a summary when all are fine, exit 1 listing every problem.
usage: check_executables.py [--install DIR] [--python PATH]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: Run under the checked interpreter: loads each entry point, prints {exe: error or ""}.
_LOADER = r"""
import importlib, importlib.metadata as md, json, sys
out = {}
for exe, kind, a, b, c in json.loads(sys.argv[1]):
    try:
        if kind == "dist":
            eps = [e for e in md.distribution(a).entry_points if e.group == b and e.name == c]
            if not eps:
                raise LookupError(f"distribution {a} has no {b} entry point {c}")
            eps[0].load()
        else:
            getattr(importlib.import_module(a), b)
        out[exe] = ""
    except BaseException as exc:
        out[exe] = f"{type(exc).__name__}: {exc}"
print(json.dumps(out))
"""
_EASY = re.compile(r"EASY-INSTALL-ENTRY-SCRIPT: '([^']+)','([^']+)','([^']+)'"
                   r"|load_entry_point\('([^']+)', '([^']+)', '([^']+)'\)")
_FROM = re.compile(r"^from ([A-Za-z_][\w.]*) import ([A-Za-z_]\w*)", re.M)


def default_python() -> str:
    venv = os.environ.get("HYPERARM_VENV") or str(ROOT / ".venv")
    return str(Path(venv) / "bin" / "python")


def executables(install: Path) -> list[Path]:
    """Every executable file under install/<pkg>/lib/<pkg>/ (what `ros2 run` starts)."""
    if not install.is_dir():
        return []
    return sorted(p for pkg in install.iterdir() if pkg.is_dir()
                  for p in (pkg / "lib" / pkg.name).glob("*")
                  if p.is_file() and os.access(p, os.X_OK))


def entry_point(text: str) -> tuple[str, str, str, str] | None:
    """("dist", dist, group, name) or ("module", module, attribute, "") of a Python script."""
    m = _EASY.search(text)
    if m:
        g = [x for x in m.groups() if x is not None]
        return ("dist", g[0], g[1], g[2])
    m = _FROM.search(text)
    if m:
        return ("module", m.group(1), m.group(2), "")
    return None


def check(install: Path, python: str) -> tuple[list[str], dict[str, int]]:
    """(problems, counts) for the executables under ``install``."""
    problems: list[str] = []
    counts = {"python": 0, "shell": 0}
    jobs = []
    found = executables(install)
    if not found:
        problems.append(f"{install}: no executables (is the workspace built? make setup)")
    for exe in found:
        rel = f"{exe.parent.parent.parent.name}/{exe.name}"
        text = exe.read_text(errors="replace")
        first = text.splitlines()[0] if text else ""
        if not first.startswith("#!"):
            problems.append(f"{rel}: no shebang")
            continue
        interp = first[2:].strip()
        if re.search(r"(^|/|\s)(ba)?sh$", interp):
            counts["shell"] += 1
            syntax = subprocess.run(["bash", "-n", str(exe)], capture_output=True, text=True)
            if syntax.returncode != 0:
                problems.append(f"{rel}: bash -n: {syntax.stderr.strip()}")
            continue
        counts["python"] += 1
        if interp != python:
            problems.append(f"{rel}: shebang '#!{interp}', not the venv's '#!{python}'")
            continue
        ep = entry_point(text)
        if ep is None:
            problems.append(f"{rel}: no entry point found in the script")
            continue
        jobs.append([rel, *ep])
    if jobs:
        proc = subprocess.run([python, "-c", _LOADER, json.dumps(jobs)], capture_output=True,
                              text=True)
        if proc.returncode != 0:
            problems.append(f"{python} could not run the import check: {proc.stderr[-2000:]}")
        else:
            for rel, error in json.loads(proc.stdout.splitlines()[-1]).items():
                if error:
                    problems.append(f"{rel}: does not import under {python}: {error}")
    return problems, counts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--install", type=Path, default=ROOT / "ros2_ws" / "install",
                    help="the colcon install directory (default: ros2_ws/install)")
    ap.add_argument("--python", default=default_python(),
                    help="the interpreter every Python executable must use "
                         "(default: the setup.sh venv's bin/python)")
    args = ap.parse_args(argv)
    problems, counts = check(args.install, args.python)
    if problems:
        print(f"FAIL: {len(problems)} installed executable(s) cannot run with {args.python}:")
        for p in problems:
            print(f"  {p}")
        return 1
    print(f"ok: {counts['python']} Python executables start with #!{args.python} and import "
          f"their entry points under it; {counts['shell']} shell scripts pass bash -n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
