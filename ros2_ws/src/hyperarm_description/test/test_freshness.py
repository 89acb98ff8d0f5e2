"""Core: the stamped-stream gate (late, out-of-order, future and unstamped messages)."""
from __future__ import annotations

import random

import pytest

from hyperarm_description.freshness import REJECT_REASONS, StampGate

pytestmark = pytest.mark.core


def test_a_message_two_seconds_late_is_rejected_as_stale_and_named():
    gate = StampGate("host_pose", max_age=0.2)
    assert gate.check(100.0, now=100.01) is None
    late = gate.check(98.0, now=100.02)
    assert late is not None and late.reason == "stale"
    assert "host_pose" in late.text and "2.020 s ago" in late.text
    assert gate.counts["stale"] == 1 and gate.accepted == 1


def test_out_of_order_is_rejected_per_source_and_equal_stamps_pass():
    gate = StampGate("joint_states", max_age=1.0)
    assert gate.check(10.00, 10.05, source="arm") is None
    assert gate.check(9.99, 10.05, source="rail") is None       # another source: own order
    r = gate.check(9.98, 10.05, source="arm")
    assert r is not None and r.reason == "out_of_order" and "arm" in r.text
    assert gate.check(10.00, 10.06, source="arm") is None       # same stamp again: fine
    assert gate.newest("arm") == 10.00 and gate.counts["out_of_order"] == 1


def test_future_and_unstamped_and_non_finite():
    gate = StampGate("detections", max_age=1.0, max_future=0.1)
    assert gate.check(12.0, now=10.0).reason == "future"
    assert gate.newest() is None                     # a future stamp does not block the stream
    assert gate.check(0.0, now=10.0).reason == "unstamped"
    assert gate.check(float("nan"), now=10.0).reason == "stale"
    lenient = StampGate("hybrid_goal", max_age=1.0, allow_unstamped=True)
    assert lenient.check(0.0, now=10.0) is None and lenient.newest() == 10.0


def test_random_streams_never_use_an_older_or_stale_message():
    for seed in range(20):
        rng = random.Random(seed)
        gate = StampGate("s", max_age=0.3, max_future=0.05)
        used: list[float] = []
        now = 1000.0
        for _ in range(500):
            now += rng.uniform(0.0, 0.02)
            stamp = now - rng.choice([0.0, 0.01, 0.1, 0.5, 2.0, -0.2]) * rng.random()
            if gate.check(stamp, now) is None:
                assert not used or stamp >= used[-1]
                assert now - stamp <= 0.3 and stamp - now <= 0.05
                used.append(stamp)
        assert used and sum(gate.counts.values()) + gate.accepted == 500
        assert set(gate.counts) == set(REJECT_REASONS)


@pytest.mark.parametrize("kwargs", [dict(max_age=0.0), dict(max_age=float("inf")),
                                    dict(max_age=1.0, max_future=-1.0)])
def test_bad_limits_are_refused(kwargs):
    with pytest.raises(ValueError):
        StampGate("x", **kwargs)
