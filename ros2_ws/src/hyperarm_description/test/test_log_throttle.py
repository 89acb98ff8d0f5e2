"""Core: throttling per reason (a new kind of message is never hidden behind another)."""
from __future__ import annotations

import pytest

from hyperarm_description.log_throttle import ReasonThrottle, reason_key

pytestmark = pytest.mark.core


def test_each_reason_has_its_own_clock():
    t = ReasonThrottle(1.0)
    assert t.allow("duplicate name", now=0.0)
    assert not t.allow("duplicate name", now=0.4)
    assert t.allow("unknown joint", now=0.4)        # another reason: not hidden
    assert t.allow("duplicate name", now=1.0)
    assert t.suppressed("duplicate name") == 1 and t.suppressed("duplicate name") == 0


def test_message_counts_what_it_suppressed_and_numbers_do_not_make_new_reasons():
    t = ReasonThrottle(10.0)
    assert t.message("error 0.012 m at joint3") == "error 0.012 m at joint3"
    assert t.message("error 0.013 m at joint3") is None      # same reason, other figures
    assert t.message("joint9 in fault") == "joint9 in fault"
    t._last[reason_key("error 0.012 m at joint3")] = -100.0  # let time pass
    assert t.message("error 0.5 m at joint3") == \
        "error 0.5 m at joint3 (1 more like this suppressed)"


def test_reason_key_and_validation():
    assert reason_key("x=1.5e-3, y=-2, id 7") == "x=#, y=#, id #"
    with pytest.raises(ValueError):
        ReasonThrottle(-1.0)
