"""Core: the step limiter every streaming controller applies last (issue 24 item 1)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hs

from hyperarm_description.limits import StepLimitError, limit_step

pytestmark = pytest.mark.core

_F = hs.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)


@hs.composite
def _case(draw):
    n = draw(hs.integers(1, 10))
    q_cmd = np.array(draw(hs.lists(hs.floats(-1e3, 1e3, allow_nan=False), min_size=n, max_size=n)))
    q_prev = np.array(draw(hs.lists(_F, min_size=n, max_size=n)))
    v = np.array(draw(hs.lists(hs.floats(1e-3, 10.0), min_size=n, max_size=n)))
    dt = draw(hs.floats(1e-4, 0.2))
    lo = np.array(draw(hs.lists(hs.floats(-4.0, 0.0), min_size=n, max_size=n)))
    hi = lo + np.array(draw(hs.lists(hs.floats(0.0, 6.0), min_size=n, max_size=n)))
    return q_cmd, q_prev, v, dt, lo, hi


@settings(max_examples=200, deadline=None)
@given(_case())
def test_no_joint_ever_steps_further_than_its_velocity_limit_times_the_period(case):
    q_cmd, q_prev, v, dt, lo, hi = case
    for limits in ((None, None), (lo, hi)):
        q = limit_step(q_cmd, q_prev, v, dt, *limits)
        assert q.shape == q_cmd.shape
        assert np.all(np.abs(q - q_prev) <= v * dt * (1 + 1e-12) + 1e-12)
        # the direction of motion is kept: never a step away from the command
        assert np.all((q - q_prev) * (q_cmd - q_prev) >= -1e-15) or limits[0] is not None
        within = (q_cmd >= q_prev - v * dt) & (q_cmd <= q_prev + v * dt)
        if limits[0] is None:
            np.testing.assert_array_equal(q[within], q_cmd[within])   # a reachable command passes
        else:
            inside = (q_prev >= lo) & (q_prev <= hi)
            assert np.all((q[inside] >= lo[inside]) & (q[inside] <= hi[inside]))
            # outside the limits by more than a step: a full step towards them, no jump
            below, above = q_prev < lo - v * dt, q_prev > hi + v * dt
            np.testing.assert_allclose(q[below], (q_prev + v * dt)[below])
            np.testing.assert_allclose(q[above], (q_prev - v * dt)[above])


def test_a_jump_of_two_point_six_rad_is_cut_to_one_cycle_of_velocity():
    q_prev = np.zeros(9)
    q_cmd = np.array([2.6, -2.6, 0.0, 0.001, 3.65, 0, 0, 0, -0.5])
    q = limit_step(q_cmd, q_prev, 3.0, 0.01)
    np.testing.assert_allclose(q, [0.03, -0.03, 0.0, 0.001, 0.03, 0, 0, 0, -0.03])


def test_position_limits_clip_after_the_step():
    q = limit_step([1.0, -1.0], [0.99, -0.99], [3.0, 3.0], 0.01, lower=[-0.995, -0.995],
                   upper=[0.995, 0.995])
    np.testing.assert_allclose(q, [0.995, -0.995])


@pytest.mark.parametrize("args, word", [
    (([0.0, np.nan], [0.0, 0.0], 1.0, 0.01), "q_cmd"),
    (([0.0, 0.0], [np.inf, 0.0], 1.0, 0.01), "q_prev"),
    (([0.0, 0.0], [0.0], 1.0, 0.01), "q_prev"),
    (([0.0, 0.0], [0.0, 0.0], [1.0, 0.0], 0.01), "v_max"),
    (([0.0, 0.0], [0.0, 0.0], 1.0, 0.0), "dt"),
    (([0.0, 0.0], [0.0, 0.0], 1.0, float("nan")), "dt"),
])
def test_malformed_inputs_raise_naming_the_field(args, word):
    with pytest.raises(StepLimitError, match=word):
        limit_step(*args)


def test_crossed_limits_raise():
    with pytest.raises(StepLimitError, match="lower <= upper"):
        limit_step([0.0], [0.0], 1.0, 0.01, lower=[1.0], upper=[0.0])
