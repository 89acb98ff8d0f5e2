"""docker/: what can be checked without Docker (which cannot run on the development
machines): every file the Dockerfile copies exists and is not excluded by .dockerignore,
every repository command it runs exists, the package.xml files it copies for rosdep are all
the workspace's packages, the robot route's requirements are in the image, and the compose
files start executables and launch files that exist."""
from __future__ import annotations

import fnmatch
import re
import shlex
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.core

ROOT = Path(__file__).resolve().parents[4]
SRC = ROOT / "ros2_ws" / "src"
DOCKERFILE = ROOT / "docker" / "Dockerfile"


def instructions() -> list[tuple[str, str]]:
    text = DOCKERFILE.read_text().replace("\\\n", " ")
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            word, _, rest = line.partition(" ")
            out.append((word.upper(), rest.strip()))
    return out


def ignored(rel: str) -> bool:
    """Whether .dockerignore keeps ``rel`` out of the build context: a pattern matches the
    path or one of its parent directories (``**/`` also matches at the top)."""
    patterns = [p.strip().rstrip("/") for p in (ROOT / ".dockerignore").read_text().splitlines()
                if p.strip() and not p.startswith("#")]
    patterns += [p[3:] for p in patterns if p.startswith("**/")]
    parts = rel.strip("/").split("/")
    paths = ["/".join(parts[:i]) for i in range(1, len(parts) + 1)]
    return any(fnmatch.fnmatch(path, p) for path in paths for p in patterns)


def test_history_builds_and_outputs_stay_out_of_the_build_context():
    """.git and every path .gitignore names (builds, venvs, demo_output, caches) are not sent
    to Docker; the sources are."""
    assert ignored(".git/HEAD") and ignored("demo_output/task.mcap")
    for line in (ROOT / ".gitignore").read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        name = line.strip("/")
        if name.startswith("*."):
            samples = [f"x{name[1:]}/f", f"ros2_ws/src/pkg/x{name[1:]}"]
        elif "/" in name or line.startswith("/"):
            samples = [f"{name}/f"]
        else:  # a bare name matches at any depth
            samples = [f"{name}/f", f"ros2_ws/src/pkg/{name}/f"]
        for sample in samples:
            assert ignored(sample), f".dockerignore lets {sample} in (.gitignore: {line})"
    for kept in ("ros2_ws/src/hyperarm_ik/setup.py", "scripts/setup.sh", "Makefile"):
        assert not ignored(kept), kept


def test_base_image_and_entrypoint():
    ins = instructions()
    assert ins[0] == ("FROM", "ros:jazzy-ros-base")
    entry = [r for w, r in ins if w == "ENTRYPOINT"]
    assert entry == ['["/entrypoint.sh"]']
    script = ROOT / "docker" / "entrypoint.sh"
    assert script.exists() and script.stat().st_mode & 0o111


def test_every_copied_file_exists_and_is_in_the_build_context():
    copies = [shlex.split(r)[:-1] for w, r in instructions() if w == "COPY"]
    assert copies
    for sources in copies:
        for src in sources:
            if src == ".":
                continue
            assert (ROOT / src).exists(), f"COPY {src}: no such file"
            assert not ignored(src), f"COPY {src}: excluded by .dockerignore"
    for needed in ("requirements-robot.txt", "scripts/setup.sh", "scripts/env.sh",
                   "scripts/robot_route/ubuntu-24.04-apt.txt"):
        assert not ignored(needed), needed


def test_rosdep_sees_every_package_of_the_workspace():
    copied = {Path(shlex.split(r)[0]).parent.name for w, r in instructions()
              if w == "COPY" and r.split()[0].endswith("package.xml")}
    packages = {p.parent.name for p in SRC.glob("*/package.xml")}
    assert copied == packages, f"COPY package.xml for {sorted(packages - copied)} missing"
    runs = " ".join(r for w, r in instructions() if w == "RUN")
    assert "rosdep install --from-paths ros2_ws/src --ignore-src" in runs


def test_every_repository_command_it_runs_exists():
    runs = [r for w, r in instructions() if w == "RUN"]
    named = [tok for r in runs for tok in shlex.split(r.replace("&&", " ").replace("||", " ")
                                                      .replace("(", " ").replace(")", " "))
             if tok.startswith(("scripts/", "docker/"))]
    assert "scripts/setup.sh" in named
    for path in named:
        assert (ROOT / path).exists(), f"RUN uses {path}: not in the repository"
    # the robot route of setup.sh pip-installs exactly requirements-robot.txt
    setup = (ROOT / "scripts" / "setup.sh").read_text()
    assert "requirements-robot.txt" in setup and "--system-site-packages" in setup


def installed_executables(pkg: str) -> set[str]:
    """What colcon installs into lib/<pkg>/ (what `ros2 run pkg` finds), read from the
    package's setup.py, so this core test needs no build: its console_scripts and the
    scripts/*.sh it lists as data files."""
    setup = (SRC / pkg / "setup.py").read_text()
    names = set(re.findall(r'"\s*([\w.-]+)\s*=\s*[\w.]+:\w+\s*"', setup))
    if 'glob("scripts/*.sh")' in setup:
        names |= {p.name for p in (SRC / pkg / "scripts").glob("*.sh")}
    return names


def test_installed_executables_are_read_from_setup_py():
    assert {"task_node", "run_task.sh", "task_recorder"} <= installed_executables("hyperarm_tasks")
    assert {"mock_driver", "dynamixel_driver"} <= installed_executables("hyperarm_driver")
    assert "mock_driver" not in installed_executables("hyperarm_ik")


def _exists_in_workspace(cmd: list[str]) -> None:
    if cmd[:2] == ["ros2", "run"]:
        pkg, exe = cmd[2], cmd[3]
        assert exe in installed_executables(pkg), cmd
    elif cmd[:2] == ["ros2", "launch"]:
        assert (SRC / cmd[2] / "launch" / cmd[3]).exists(), cmd
    else:
        raise AssertionError(f"unchecked command {cmd}")
    for arg in cmd:
        if "/share/" in arg:
            pkg, rel = arg.split("/share/", 1)[1].split("/", 1)
            assert (SRC / pkg / rel).exists(), arg


@pytest.mark.parametrize("name", ["compose.mock.yaml", "compose.hardware.yaml"])
def test_compose_files(name):
    data = yaml.safe_load((ROOT / "docker" / name).read_text())
    assert data["services"]
    for svc in data["services"].values():
        assert svc["network_mode"] == "host" and not svc.get("privileged")
        build = svc["build"]
        assert (ROOT / "docker" / build["context"] / build["dockerfile"]).resolve() == DOCKERFILE
        _exists_in_workspace(svc["command"])
    if name == "compose.mock.yaml":  # issue 24.8: the IK avoids the cell the mock simulates
        # the controllers, as the launch files start them (issue 26)
        assert {"arm_controller", "gripper_controller"} <= set(data["services"])
        ik = data["services"]["ik_service"]["command"]
        assert "world_file:=/opt/hyperarm/ros2_ws/install/hyperarm_driver/share/" \
               "hyperarm_driver/config/workcell.yaml" in ik, ik
    if name == "compose.hardware.yaml":
        svc = data["services"]["hyperarm"]
        assert "/dev:/dev" in svc["volumes"]
        assert any(re.fullmatch(r"c 188:\* rmw", r) for r in svc["device_cgroup_rules"])
