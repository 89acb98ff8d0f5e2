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
    patterns = [p.strip() for p in (ROOT / ".dockerignore").read_text().splitlines()
                if p.strip() and not p.startswith("#")]
    return any(fnmatch.fnmatch(rel, p) or rel.startswith(p.rstrip("/") + "/")
               for p in patterns)


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


def _exists_in_workspace(cmd: list[str]) -> None:
    if cmd[:2] == ["ros2", "run"]:
        pkg, exe = cmd[2], cmd[3]
        assert (ROOT / "ros2_ws" / "install" / pkg / "lib" / pkg / exe).exists(), cmd
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
    if name == "compose.hardware.yaml":
        svc = data["services"]["hyperarm"]
        assert "/dev:/dev" in svc["volumes"]
        assert any(re.fullmatch(r"c 188:\* rmw", r) for r in svc["device_cgroup_rules"])
