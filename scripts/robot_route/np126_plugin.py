"""pytest plugin for scripts/robot_route/core_tests.sh: a test module (or test) that cannot import
because it needs a package PyPI has no numpy-1.26 build of (pinocchio: every `pin` wheel
needs cmeel-boost, hence numpy>=2) or ROS (rclpy) is reported as *skipped, with the missing
module named*, instead of as a collection error. Any other import error still fails."""
from __future__ import annotations

import re

import pytest

#: modules the numpy-1.26 venv cannot have from PyPI (see docs/robot-install.md)
UNAVAILABLE = {"pinocchio", "rclpy", "coal", "hpp"}
#: ROS message packages (built by ROS, not on PyPI for numpy 1.26 / cp312)
ROS_SUFFIXES = ("_msgs", "_srvs", "_interfaces")
_MISSING = re.compile(r"No module named '([A-Za-z0-9_]+)")


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    report = outcome.get_result()
    if report.failed and isinstance(collector, pytest.Module):
        found = _MISSING.search(str(report.longrepr))
        name = found.group(1) if found else ""
        if name in UNAVAILABLE or name.endswith(ROS_SUFFIXES):
            report.outcome = "skipped"
            report.longrepr = (str(collector.path), 0,
                               f"Skipped: needs {name} (no numpy-1.26 build on PyPI)")
            report.result = []


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """The same for a test that imports such a module in its body (e.g. the generated
    hyperarm_interfaces, which only a colcon build against ROS makes)."""
    outcome = yield
    report = outcome.get_result()
    exc = call.excinfo.value if call.excinfo is not None else None
    if report.failed and isinstance(exc, ModuleNotFoundError):
        name = (exc.name or "").split(".")[0]
        if name in UNAVAILABLE or name.endswith(ROS_SUFFIXES):
            report.outcome = "skipped"
            report.longrepr = (str(item.path), 0,
                               f"Skipped: needs {name} (no numpy-1.26 build on PyPI)")
