"""Fixtures of hyperarm_tasks' tests (the shared ones are in ros2_ws/src/conftest.py)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

import pytest


def _alive(logs: Path) -> list[str]:
    """The processes run_task.sh started (its ``--logs`` directory's ``pids`` file) that are
    still running, as "name (pid)"."""
    out = []
    for line in (logs / "pids").read_text().split("\n"):
        if line.strip():
            name, pid = line.split()
            try:
                os.kill(int(pid), 0)
                out.append(f"{name} ({pid})")
            except ProcessLookupError:
                pass
    return out


@pytest.fixture
def still_running() -> Callable[[Path], list[str]]:
    """``still_running(logs)``: what run_task.sh left behind (expected: [])."""
    return _alive
