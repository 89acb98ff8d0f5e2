"""The robot route (Ubuntu 24.04 + ROS 2 Jazzy from apt) installs without breaking ROS:
pip's plan never replaces apt's numpy 1.26 nor adds a second pinocchio, every third-party
import has an apt (rosdep) key or a line in requirements-robot.txt, the installed
executables start with the venv's interpreter (colcon is run by it, whatever `colcon` is on
PATH), `make check-robot-route` sets up first, and the ROS-free core tests pass under
numpy 1.26 (docs/robot-install.md). The checks that need a build: test_robot_route_build.py."""
from __future__ import annotations

import ast
import importlib.util
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

pytestmark = pytest.mark.core

ROOT = Path(__file__).resolve().parents[4]
SRC = ROOT / "ros2_ws" / "src"
CHECK = ROOT / "scripts" / "robot_route" / "check_plan.py"
CHECK_EXES = ROOT / "scripts" / "robot_route" / "check_executables.py"


def _check_module(path: Path = CHECK):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_violations_name_numpy_2_a_second_pinocchio_and_ros_wheels():
    cp = _check_module()
    apt = cp.read_pins(cp.APT_CONSTRAINTS)
    assert apt["numpy"] == "1.26.4"
    plan = [("pyserial", "3.5"), ("numpy", "2.4.6"), ("pin", "4.1.0"), ("cmeel-boost", "1.90.0"),
            ("ros-rclpy", "7.1.6"), ("paramiko", "5.1.0")]
    bad = cp.violations(plan, apt, installed=False)
    assert len(bad) == 4 and all(n in " ".join(bad) for n in ("numpy", "pin", "cmeel", "ros-"))
    # with the apt set installed, even the same pyserial is a replacement
    assert any("pyserial" in b for b in cp.violations(plan, apt, installed=True))
    assert cp.violations([("paramiko", "5.1.0")], apt, installed=True) == []


@pytest.mark.slow
def test_robot_pip_plan_resolves_against_apt_numpy_and_adds_no_pinocchio():
    """pip --dry-run --report for CPython 3.12 manylinux with the apt versions as
    constraints (needs PyPI, as `make setup` does)."""
    proc = subprocess.run([sys.executable, str(CHECK)], capture_output=True, text=True,
                          timeout=170)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "ok [cp312" in proc.stdout and "dls-pmaclib" in proc.stdout


@pytest.mark.slow
def test_plan_check_fails_on_a_requirement_that_needs_numpy_2(tmp_path):
    req = tmp_path / "req.txt"
    req.write_text("pin==4.1.0\n")
    proc = subprocess.run([sys.executable, str(CHECK), "--requirements", str(req)],
                          capture_output=True, text=True, timeout=170)
    assert proc.returncode == 1 and "FAIL" in proc.stdout, proc.stdout


# import name -> rosdep key (apt on the robot); pip-only ones are in requirements-robot.txt
ROSDEP_OF = {"numpy": "python3-numpy", "yaml": "python3-yaml", "pinocchio": "pinocchio",
             "eigenpy": "pinocchio", "coal": "coal", "dynamixel_sdk": "dynamixel_sdk",
             "serial": "python3-serial", "pytest": "python3-pytest",
             "hypothesis": "python3-hypothesis", "launch": "launch",
             "launch_ros": "launch_ros", "jsonschema": "python3-jsonschema",
             "matplotlib": "python3-matplotlib", "PIL": "python3-pil",
             "lark": "python3-lark-parser", "scipy": "python3-scipy"}
PIP_OF = {"dls_pmaclib": "dls-pmaclib", "mcap": "mcap", "mcap_ros2": "mcap-ros2-support",
          "viser": "viser", "selenium": "selenium", "mujoco": "mujoco",
          "cv2": "opencv-python-headless"}
BENCH_ONLY = {"ikpy", "pytracik"}  # requirements-bench.txt, never at run time


def _imports(source: Path) -> set[str]:
    """Top-level names of the absolute imports of a module (anywhere in it)."""
    names = set()
    for node in ast.walk(ast.parse(source.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def _python_packages() -> list[Path]:
    return sorted(p.parent for p in SRC.glob("*/package.xml") if (p.parent / "setup.py").exists())


def test_every_third_party_import_has_an_apt_key_or_a_robot_pip_line():
    robot_pip = {re.split(r"[=<>]", line)[0].strip().lower()
                 for line in (ROOT / "requirements-robot.txt").read_text().splitlines()
                 if line.strip() and not line.startswith("#")}
    local = {p.name for p in SRC.iterdir() if p.is_dir()} | {"conftest"}
    missing = []
    for pkg in _python_packages():
        keys = {e.text for e in ET.parse(pkg / "package.xml").getroot()
                if e.tag.endswith("depend")}
        own = {p.stem for p in pkg.rglob("*.py")} | {p.name for p in pkg.rglob("*") if p.is_dir()}
        for source in pkg.rglob("*.py"):
            if "benchmark" in source.parts or source.name == "setup.py":
                continue
            for name in _imports(source):
                if (name in sys.stdlib_module_names or name in local or name in own
                        or name in BENCH_ONLY or name == "setuptools"):
                    continue
                if name in PIP_OF:
                    ok = PIP_OF[name] in robot_pip
                elif name in ROSDEP_OF:
                    ok = ROSDEP_OF[name] in keys
                else:  # a ROS package: its key is its name (rclpy, sensor_msgs, ...)
                    ok = name in keys or name in ("rcl_interfaces", "builtin_interfaces",
                                                  "action_msgs", "rosgraph_msgs")
                if not ok:
                    missing.append(f"{source.relative_to(SRC)}: import {name}")
    assert not missing, "no rosdep key / robot pip line for:\n" + "\n".join(sorted(set(missing)))


@pytest.mark.slow
@pytest.mark.timeout(600)   # on a fresh machine it first builds its venv from PyPI (minutes)
def test_core_tests_pass_under_numpy_1_26():
    """scripts/robot_route/core_tests.sh: pytest -m core in a venv with the apt versions
    (numpy 1.26.4); modules needing pinocchio/rclpy are skipped by name, nothing fails."""
    proc = subprocess.run(["bash", str(ROOT / "scripts/robot_route/core_tests.sh"),
                           "--ignore", str(Path(__file__))],
                          capture_output=True, text=True, timeout=600)
    tail = proc.stdout[-3000:] + proc.stderr[-2000:]
    assert proc.returncode == 0, tail
    assert "[np126] numpy 1.26.4" in proc.stdout
    passed = int(re.search(r"(\d+) passed", proc.stdout).group(1))
    assert passed >= 100, tail


# --- the installed executables' interpreter (issue 25.2) and the make target (25.3) --------

def _exe(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    path.chmod(0o755)


def test_check_executables_names_each_foreign_shebang_failing_import_and_bad_script(tmp_path):
    """A fake install tree: what apt's colcon wrote (#!/usr/bin/python3), an entry point that
    does not import, a shell script with a syntax error; the good ones pass."""
    ce = _check_module(CHECK_EXES)
    lib = tmp_path / "install" / "pkg_a" / "lib" / "pkg_a"
    py = sys.executable
    _exe(lib / "good", f"#!{py}\nimport sys\nfrom json import dumps\nsys.exit(0)\n")
    _exe(lib / "easy", f"#!{py}\n# EASY-INSTALL-ENTRY-SCRIPT: 'pytest','console_scripts',"
                       "'pytest'\nimport re\n")
    _exe(lib / "apt_colcon", "#!/usr/bin/python3\nfrom json import dumps\n")
    _exe(lib / "no_module", f"#!{py}\nfrom no_such_module_xyz import main\n")
    _exe(lib / "no_entry", f"#!{py}\n# EASY-INSTALL-ENTRY-SCRIPT: 'pytest','console_scripts',"
                           "'no_such_entry'\n")
    _exe(lib / "ok.sh", "#!/usr/bin/env bash\necho ok\n")
    _exe(lib / "bad.sh", "#!/usr/bin/env bash\nif then fi (\n")
    (lib / "not_executable").write_text("#!/usr/bin/python3\n")
    problems, counts = ce.check(tmp_path / "install", py)
    text = "\n".join(problems)
    assert len(problems) == 4, text
    assert "pkg_a/apt_colcon: shebang '#!/usr/bin/python3'" in text
    assert "pkg_a/no_module: does not import" in text and "no_such_module_xyz" in text
    assert "pkg_a/no_entry: does not import" in text and "no_such_entry" in text
    assert "pkg_a/bad.sh: bash -n" in text
    assert counts == {"python": 5, "shell": 2}
    assert ce.check(tmp_path / "nothing_built", py)[0]  # an empty install is no pass
    (tmp_path / "nothing_built").mkdir()
    assert "no executables" in ce.check(tmp_path / "nothing_built", py)[0][0]


def test_setup_builds_through_colcon_build_sh_only():
    """setup.sh runs colcon only through scripts/colcon_build.sh (the venv's interpreter),
    never the `colcon` on PATH, which is apt's /usr/bin/python3 one on the robot."""
    setup = (ROOT / "scripts" / "setup.sh").read_text()
    commands = [line.split("#")[0] for line in setup.splitlines()]
    assert any('scripts/colcon_build.sh" "$VENV" "$WS"' in c for c in commands)
    bare = re.compile(r"(^\s*|[;&|]\s*|\bif\s+!?\s*|\$\(\s*|\bexec\s+)colcon\s")
    assert not [c for c in commands if bare.search(c)], "setup.sh calls a bare colcon"
    assert bare.search("  if ! colcon --log-base log build") and bare.search("x && colcon b")
    build = (ROOT / "scripts" / "colcon_build.sh").read_text()
    assert '"$VENV/bin/python" -c' in build and "colcon_core.command import main" in build


def test_check_robot_route_sets_up_first_and_checks_the_executables():
    out = subprocess.run(["make", "-n", "-C", str(ROOT), "check-robot-route"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    order = [next(i for i, line in enumerate(lines) if key in line)
             for key in ("scripts/setup.sh", "check_plan.py", "check_executables.py",
                         "core_tests.sh")]
    assert order == sorted(order), out.stdout


def test_robot_install_doc_suggests_no_pip_install_the_plan_check_refuses():
    """docs/robot-install.md and check_plan.py agree: no `pip install` of a distribution the
    plan check forbids (the old fallback `pip install dynamixel-sdk` was one)."""
    cp = _check_module()
    doc = (ROOT / "docs" / "robot-install.md").read_text()
    named = [canonical for m in re.finditer(r"pip install ((?:[-\w.=<>\[\]]+ ?)+)", doc)
             for word in m.group(1).split() if not word.startswith("-")
             for canonical in [cp.canonical(re.split(r"[=<>\[]", word)[0])]]
    bad = [n for n in named if n in cp.FORBIDDEN or n.startswith(cp.FORBIDDEN_PREFIXES)]
    assert not bad, f"docs/robot-install.md suggests pip install {bad}: check_plan.py forbids it"
