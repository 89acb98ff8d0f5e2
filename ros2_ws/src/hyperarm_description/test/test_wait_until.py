"""The suite's wait helper (ros2_ws/src/conftest.py, fixture ``wait_for``): a callable
``what`` is read at the timeout, so a process' log in the error is the log of the whole wait
(an f-string showed the log as it was when the wait began: a driver that "said nothing for
20 s" in one CI failure had said nothing yet)."""
from __future__ import annotations

import pytest

pytestmark = pytest.mark.core


def test_a_callable_what_is_read_at_the_timeout(wait_for):
    log = ["started"]

    def cond() -> bool:
        log.append("a line written while waiting")
        return False

    with pytest.raises(AssertionError, match="a line written while waiting"):
        wait_for(cond, 0.05, what=lambda: "\n".join(log))


def test_a_plain_what_and_a_success(wait_for):
    with pytest.raises(AssertionError, match=r"timed out after 0\.0 s waiting for the thing"):
        wait_for(lambda: False, 0.01, what="the thing")
    assert wait_for(lambda: 7, 1.0, what=lambda: "unused") == 7
