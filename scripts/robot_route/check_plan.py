#!/usr/bin/env python3
"""Check the robot route's pip install plan against Ubuntu 24.04's apt Python packages.

On the robot (Ubuntu 24.04, ROS 2 Jazzy from apt) scripts/setup.sh pip-installs only
requirements-robot.txt into a ``--system-site-packages`` venv; numpy 1.26, pinocchio, the
Dynamixel SDK & co. come from apt. This script resolves that plan here, without the robot:

1. ``cp312``: ``pip install --dry-run --report`` for CPython 3.12 on manylinux x86_64 (the
   robot's interpreter and platform), constrained to the apt versions listed in
   ubuntu-24.04-apt.txt (numpy==1.26.4, ...). It fails when the plan cannot be resolved with
   those versions (something needs numpy>=2), or when it would install a distribution that
   apt/ROS already provides in another form (a second pinocchio: ``pin``, ``libpinocchio``,
   ``cmeel-*``, ``eigenpy``, ``coal``; ``dynamixel-sdk``; ``ros-*`` wheels).
2. ``--venv DIR`` (optional): a venv of this interpreter holding exactly the apt versions
   plays the robot's system site; the plan resolved in it must install none of them, i.e.
   pip would replace nothing (numpy above all).

Exit 0 and the plan on stdout when it is clean, exit 1 with every violation otherwise.
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
APT_CONSTRAINTS = HERE / "ubuntu-24.04-apt.txt"
ROBOT_REQUIREMENTS = ROOT / "requirements-robot.txt"

#: Distributions that would be a second copy of something apt/ROS installs without pip
#: metadata (so pip cannot see it is there): pinocchio and its stack, the SDK, ROS itself.
FORBIDDEN = {"pin", "libpinocchio", "eigenpy", "coal", "libcoal", "hpp-fcl", "cmeel",
             "dynamixel-sdk", "numpy"}
FORBIDDEN_PREFIXES = ("cmeel-", "ros-")

#: CPython 3.12 on Ubuntu 24.04 x86_64 (glibc 2.39): pip does not widen a --platform to the
#: older manylinux tags the interpreter accepts, so every one is listed.
PLATFORM = ["--python-version", "3.12", "--implementation", "cp", "--only-binary=:all:",
            *(f"--abi={abi}" for abi in ("cp312", "abi3", "none")),
            *(f"--platform=manylinux_2_{minor}_x86_64" for minor in range(5, 40)),
            *(f"--platform={tag}_x86_64" for tag in ("manylinux1", "manylinux2010",
                                                      "manylinux2014", "linux"))]


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def read_pins(path: Path) -> dict[str, str]:
    """``name==version`` lines of a constraints file (comments skipped)."""
    pins = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            pins[canonical(name)] = version.strip()
    return pins


def plan(python: str, requirements: Path, extra: list[str]) -> list[tuple[str, str]]:
    """(name, version) pip would install, from its --dry-run --report; raises
    RuntimeError with pip's message when the requirements cannot be resolved."""
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "report.json"
        cmd = [python, "-m", "pip", "install", "--dry-run", "--quiet", "--report", str(report),
               "--disable-pip-version-check", "-c", str(APT_CONSTRAINTS),
               "-r", str(requirements), *extra]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            message = "\n".join(line for line in proc.stderr.splitlines()
                                 if "is ignored: it is neither" not in line)
            raise RuntimeError(f"pip cannot resolve {requirements.name} against the apt "
                               f"versions:\n{message.strip()}")
        data = json.loads(report.read_text())
    return [(canonical(item["metadata"]["name"]), item["metadata"]["version"])
            for item in data["install"]]


def violations(items: list[tuple[str, str]], apt: dict[str, str],
               installed: bool) -> list[str]:
    """What is wrong with a plan: a forbidden distribution, an apt one at another version,
    or (``installed``: the apt set is in the environment) any apt one at all."""
    bad = []
    for name, version in items:
        if name in apt:
            if installed:
                bad.append(f"{name} {version} would replace the apt {name} {apt[name]}")
            elif version != apt[name]:
                bad.append(f"{name} {version} differs from the apt {name} {apt[name]}")
        elif name in FORBIDDEN or name.startswith(FORBIDDEN_PREFIXES):
            bad.append(f"{name} {version} duplicates a package apt/ROS provides "
                       "(pinocchio stack, Dynamixel SDK or ROS)")
    return bad


def make_apt_venv(venv: Path) -> str:
    """A venv holding exactly the apt versions (idempotent); returns its python."""
    python = venv / "bin" / "python"
    if not python.exists():
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    subprocess.run([str(python), "-m", "pip", "install", "--quiet",
                    "--disable-pip-version-check", "-r", str(APT_CONSTRAINTS)], check=True)
    return str(python)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--requirements", type=Path, default=ROBOT_REQUIREMENTS)
    parser.add_argument("--venv", type=Path, help="also resolve in a venv holding the apt "
                        "versions (created if missing)")
    args = parser.parse_args(argv)
    apt = read_pins(APT_CONSTRAINTS)
    failed = False
    checks = [("cp312 manylinux, apt versions as constraints", sys.executable,
               ["--ignore-installed", "--target", "/nonexistent-dry-run", *PLATFORM], False)]
    if args.venv:
        checks.append((f"venv {args.venv.name} holding the apt versions",
                       make_apt_venv(args.venv), [], True))
    for title, python, extra, installed in checks:
        try:
            items = plan(python, args.requirements, extra)
        except RuntimeError as exc:
            print(f"FAIL [{title}]: {exc}")
            failed = True
            continue
        bad = violations(items, apt, installed)
        shown = ", ".join(f"{n}=={v}" + (" (apt)" if n in apt and not installed else "")
                          for n, v in items) or "(nothing)"
        print(f"{'FAIL' if bad else 'ok'} [{title}]: pip would install {shown}")
        for line in bad:
            print(f"  - {line}")
        failed |= bool(bad)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
