"""The installed console script generate_moveit_config (what `ros2 run
hyperarm_moveit_config generate_moveit_config` runs): --help / -h, and --check passes on
the committed files and prints each variant's collision figures. No ROS involved."""
from __future__ import annotations

import subprocess

import pytest

pytestmark = pytest.mark.e2e


def test_help(executable):
    exe = executable("hyperarm_moveit_config", "generate_moveit_config")
    texts = []
    for flag in ("--help", "-h"):
        run = subprocess.run([exe, flag], capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, run.stderr
        texts.append(run.stdout)
    assert texts[0] == texts[1] and texts[0].startswith("usage: generate_moveit_config")
    assert "--check" in texts[0]


def test_check_passes_and_prints_the_figures(executable):
    exe = executable("hyperarm_moveit_config", "generate_moveit_config")
    run = subprocess.run([exe, "--check"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    lines = run.stdout.splitlines()
    assert [line.split(":")[0] for line in lines] == ["arm", "rail_arm"], run.stdout
    assert all("Never disabled" in line and "(10000 samples, seed 0)" in line for line in lines)
