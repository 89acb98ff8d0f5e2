"""The suite's own scheduling (ros2_ws/src/conftest.py): a test of the pure-Python tiers runs
as low-priority batch work beside the other worker's node processes; other tests run at the
niceness the suite started with."""
from __future__ import annotations

import os

import pytest


def _conftest(request: pytest.FixtureRequest):
    for plugin in request.config.pluginmanager.get_plugins():
        if getattr(plugin, "BATCH_NICENESS", None) is not None:
            return plugin
    raise AssertionError("ros2_ws/src/conftest.py not loaded")


@pytest.mark.core
def test_a_core_test_runs_at_batch_niceness(request):
    conf = _conftest(request)
    if not conf._RENICE:
        pytest.skip("no root or CAP_SYS_NICE here: niceness is left alone")
    assert os.getpriority(os.PRIO_PROCESS, 0) >= conf.BATCH_NICENESS


@pytest.mark.node
@pytest.mark.core
def test_a_timed_tier_test_is_not_reniced(request):
    """(marked core too: a node, e2e or emulator marker wins) the suite's own niceness"""
    conf = _conftest(request)
    if not conf._RENICE:
        pytest.skip("no root or CAP_SYS_NICE here: niceness is left alone")
    assert os.getpriority(os.PRIO_PROCESS, 0) == conf._START_NICENESS
