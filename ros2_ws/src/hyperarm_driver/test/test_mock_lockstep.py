"""Core tier: the mock's lockstep rule (``hyperarm_driver.mock.lockstep``, no ROS): it
waits only while a controller answers, for the answer to the last state only, and a
timeout disengages it until an answer comes; a controller answering every state from
another thread is never timed out."""
from __future__ import annotations

import threading
import time

import pytest

from hyperarm_driver.mock.lockstep import Lockstep

pytestmark = pytest.mark.core


def test_nobody_answering_it_never_waits():
    ls = Lockstep(0.5)
    ls.published(1)
    ls.answered(99)                       # a command for no published state: no answer
    t0 = time.monotonic()
    assert ls.wait() and time.monotonic() - t0 < 0.1
    assert not ls.engaged and ls.timeouts == 0


def test_waits_for_the_answer_to_the_last_state_and_disengages_on_a_timeout():
    ls = Lockstep(0.2)
    ls.published(1)
    ls.answered(1)                        # the controller is in the loop
    assert ls.engaged
    ls.published(2)
    threading.Timer(0.05, ls.answered, args=(2,)).start()
    t0 = time.monotonic()
    assert ls.wait()
    assert 0.04 < time.monotonic() - t0 < 0.19
    ls.published(3)
    ls.answered(2)                        # late: the answer to the state before
    t0 = time.monotonic()
    assert not ls.wait()                  # timed out after 0.2 s
    assert time.monotonic() - t0 >= 0.19
    assert ls.timeouts == 1 and not ls.engaged
    ls.published(4)
    t0 = time.monotonic()
    assert ls.wait() and time.monotonic() - t0 < 0.1     # disengaged: no wait
    ls.answered(4)                        # an answer again: engaged again
    assert ls.engaged


def test_a_controller_answering_every_state_from_another_thread_is_never_timed_out():
    """The simulation thread publishes and waits 300 times while another thread answers
    each state as it sees it (the race of a fast answer against the publish)."""
    ls = Lockstep(0.5)
    seen: list[int] = []
    cond = threading.Condition()
    stop = threading.Event()

    def controller() -> None:
        last = None
        while not stop.is_set():
            with cond:
                cond.wait_for(lambda: (seen and seen[-1] != last) or stop.is_set(), 0.1)
                stamp = seen[-1] if seen else None
            if stamp is not None and stamp != last:
                ls.answered(stamp)
                last = stamp
    t = threading.Thread(target=controller)
    t.start()
    try:
        for k in range(300):
            ls.published(k)
            with cond:
                seen.append(k)
                cond.notify_all()
            assert ls.wait(), k
            if k == 0:
                time.sleep(0.05)          # the first answer engages it
    finally:
        stop.set()
        t.join(2.0)
    assert ls.engaged and ls.timeouts == 0


@pytest.mark.parametrize("bad", [0.0, -1.0, 61.0, True, "0.2"])
def test_bad_timeouts_are_refused(bad):
    with pytest.raises(ValueError):
        Lockstep(bad)
