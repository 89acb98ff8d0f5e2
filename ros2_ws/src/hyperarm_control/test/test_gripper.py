"""Core tier: the GripperCommand core (hyperarm_control.gripper, no rclpy): goal checks,
reached / stalled / stopped / stale judgements, cancel and preemption, over random inputs."""
from __future__ import annotations

import math

import numpy as np
import pytest

from hyperarm_control.gripper import (GripperError, GripperGoal, GripperJudge, GripperLimits,
                                      GripperParams, InvalidGripperGoal, check_goal)
from hyperarm_description.model import load_description

pytestmark = [pytest.mark.core]

DESC = load_description(None, "arm")
LIM = GripperLimits.from_description(DESC)
PAR = GripperParams()


def test_limits_from_the_description():
    g = DESC.gripper
    assert (LIM.name, LIM.lower, LIM.upper) == (g.name, g.lower, g.upper)
    assert LIM.stall_effort == g.effort and LIM.default_effort == g.grip_effort


@pytest.mark.parametrize("position,effort,match", [
    (math.nan, 0.5, "position nan"), (math.inf, 0.5, "position inf"),
    (0.5, math.nan, "max_effort nan"), (0.5, -math.inf, "max_effort -inf"),
    (0.5, -0.1, "negative"), (-0.01, 0.5, "outside gripper's limits"),
    (LIM.upper + 0.01, 0.0, "outside gripper's limits")])
def test_bad_goals_are_refused_with_a_reason(position, effort, match):
    with pytest.raises(InvalidGripperGoal, match=match):
        check_goal(position, effort, LIM, PAR)


def test_effort_zero_is_the_default_and_too_much_is_clamped():
    g = check_goal(0.0, 0.0, LIM, PAR)
    assert (g.effort_command, g.limit, g.clamped) == (0.0, LIM.default_effort, False)
    g = check_goal(0.0, 0.0, LIM, GripperParams(max_effort=0.3))
    assert (g.effort_command, g.limit) == (0.3, 0.3)
    g = check_goal(LIM.upper, 0.4, LIM, GripperParams(max_effort=0.3))
    assert (g.position, g.effort_command, g.limit) == (LIM.upper, 0.4, 0.4)
    g = check_goal(0.0, 100.0, LIM, PAR)
    assert g.clamped and g.limit == g.effort_command == LIM.stall_effort


def test_random_goals_accepted_inside_refused_outside():
    rng = np.random.default_rng(1)
    for _ in range(2000):
        pos = rng.uniform(LIM.lower - 0.5, LIM.upper + 0.5)
        eff = rng.uniform(-1.0, 6.0)
        inside = LIM.lower <= pos <= LIM.upper and eff >= 0
        if inside:
            g = check_goal(pos, eff, LIM, PAR)
            assert g.position == pos and 0 < g.limit <= LIM.stall_effort
        else:
            with pytest.raises(InvalidGripperGoal):
                check_goal(pos, eff, LIM, PAR)


@pytest.mark.parametrize("kwargs", [{"goal_tolerance": -1}, {"stall_timeout": 0},
                                    {"stall_effort_fraction": 1.5}, {"max_state_age": math.nan},
                                    {"max_effort": -0.1}])
def test_bad_params_are_refused(kwargs):
    with pytest.raises(GripperError):
        GripperParams(**kwargs)


def test_bad_limits_and_goal_types_are_refused():
    with pytest.raises(GripperError, match="lower limit"):
        GripperLimits("g", 1.0, 0.0, 1.0, 0.5)
    with pytest.raises(GripperError):
        GripperJudge(LIM, PAR).start((0.0, 0.0), 0.0)


class Servo:
    """A gripper servo in current-based position: moves at ``v`` towards its goal and stops
    on an object at ``obstacle`` (closing), where it pushes with its limit."""

    def __init__(self, q: float, v: float = 2.0, obstacle: float | None = None):
        self.q, self.v, self.obstacle = q, v, obstacle
        self.vel = self.effort = 0.0

    def step(self, goal: GripperGoal, dt: float, rng) -> None:
        err = goal.position - self.q
        step = float(np.clip(err, -self.v * dt, self.v * dt))
        new = self.q + step
        if self.obstacle is not None and self.q >= self.obstacle >= new:
            new = self.obstacle
        self.vel = (new - self.q) / dt
        self.q = new
        blocked = abs(goal.position - self.q) > 1e-6 and self.vel == 0.0
        self.effort = math.copysign(goal.limit, err) if blocked else 0.1 * step / dt
        self.effort += rng.normal(0, 0.01)


def run(judge, goal, servo, rng, dt=0.02, t0=0.0, horizon=10.0, latency=0.0):
    judge.start(goal, t0)
    t = t0
    while t < t0 + horizon:
        t += dt
        servo.step(goal, dt, rng)
        st = judge.step(t, servo.q, servo.vel + rng.normal(0, 0.005), servo.effort,
                        t - latency)
        if st.done:
            return st, t - t0
    raise AssertionError("no result")


@pytest.mark.parametrize("seed", range(5))
def test_open_reaches_and_close_on_an_object_stalls(seed):
    rng = np.random.default_rng(seed)
    judge = GripperJudge(LIM, PAR)
    obstacle = rng.uniform(0.2, 1.0)
    servo = Servo(rng.uniform(0.0, 0.1), obstacle=None)
    st, _ = run(judge, check_goal(LIM.upper, 0.0, LIM, PAR), servo, rng)
    assert st.status == "succeeded" and st.reached_goal and not st.stalled
    assert abs(st.position - LIM.upper) <= PAR.goal_tolerance
    servo.obstacle = obstacle
    st, took = run(judge, check_goal(0.0, rng.uniform(0.2, 1.0), LIM, PAR), servo, rng)
    assert st.status == "succeeded" and st.stalled and not st.reached_goal
    assert st.position == pytest.approx(obstacle) and st.effort < 0
    assert PAR.stall_timeout <= took < PAR.stall_timeout + 1.0
    assert "stalled" in st.reason and not judge.running


def test_stall_aborts_without_allow_stalling():
    rng = np.random.default_rng(7)
    judge = GripperJudge(LIM, GripperParams(allow_stalling=False))
    st, _ = run(judge, check_goal(0.0, 0.0, LIM, PAR), Servo(1.0, obstacle=0.5), rng)
    assert st.status == "aborted" and st.stalled and not st.reached_goal
    assert "allow_stalling is false" in st.reason


def test_not_moving_without_effort_is_not_a_stall():
    """Torque off (or a servo in error): still, short of the goal, no effort: aborted,
    stalled false; with stall_effort_fraction 0 it is a stall (velocity alone)."""
    judge = GripperJudge(LIM, PAR)
    judge.start(check_goal(0.0, 0.0, LIM, PAR), 0.0)
    for k in range(1, 200):
        st = judge.step(k * 0.02, 0.8, 0.0, 0.01, k * 0.02)
        if st.done:
            break
    assert st.status == "aborted" and not st.stalled and "not held by an object" in st.reason
    assert k * 0.02 == pytest.approx(PAR.stall_timeout, abs=0.03)
    judge = GripperJudge(LIM, GripperParams(stall_effort_fraction=0.0))
    judge.start(check_goal(0.0, 0.0, LIM, PAR), 0.0)
    st = judge.step(1.5, 0.8, 0.0, 0.0, 1.5)
    assert st.status == "succeeded" and st.stalled
    # effort pushing the wrong way (opening while asked to close) is no stall either
    judge = GripperJudge(LIM, PAR)
    judge.start(check_goal(0.0, 0.0, LIM, PAR), 0.0)
    assert judge.step(1.5, 0.8, 0.0, +0.6, 1.5).status == "aborted"
    # effort not reported: judged on the velocity alone
    judge.start(check_goal(0.0, 0.0, LIM, PAR), 0.0)
    st = judge.step(1.5, 0.8, 0.0, math.nan, 1.5)
    assert st.stalled and "not reported" in st.reason


def test_moving_slowly_is_not_a_stall_and_motion_restarts_the_timer():
    judge = GripperJudge(LIM, PAR)
    judge.start(check_goal(0.0, 0.0, LIM, PAR), 0.0)
    assert judge.step(0.9, 0.8, 0.0, -0.6, 0.9).status == "running"
    assert judge.step(0.95, 0.8, -0.2, -0.6, 0.95).status == "running"   # moved: restart
    assert judge.step(1.9, 0.8, 0.0, -0.6, 1.9).status == "running"
    assert judge.step(1.96, 0.8, 0.0, -0.6, 1.96).stalled


def test_stale_or_non_finite_state_aborts():
    judge = GripperJudge(LIM, PAR)
    judge.start(check_goal(0.0, 0.0, LIM, PAR), 0.0)
    assert judge.step(0.2, 1.0, -1.0, 0.0, 0.0).status == "running"
    st = judge.step(0.3, 1.0, -1.0, 0.0, 0.0)
    assert st.status == "aborted" and "older than max_state_age" in st.reason
    judge.start(check_goal(0.0, 0.0, LIM, PAR), 0.0)
    st = judge.step(0.1, math.nan, 0.0, 0.0, 0.1)
    assert st.status == "aborted" and "non-finite" in st.reason


def test_idle_cancel_and_preemption():
    judge = GripperJudge(LIM, PAR)
    assert judge.step(1.0, 0.5, 0.0, 0.0, 1.0).status == "idle"
    assert not judge.start(check_goal(0.0, 0.0, LIM, PAR), 0.0)
    assert judge.start(check_goal(1.0, 0.0, LIM, PAR), 0.1)      # preempts
    assert judge.goal.position == 1.0
    st = judge.cancel(0.7, -0.2)
    assert st.status == "canceled" and st.position == 0.7 and not judge.running
    assert "holding at 0.7000" in st.reason


def test_random_states_never_claim_both_and_reached_is_within_tolerance():
    rng = np.random.default_rng(3)
    for _ in range(300):
        params = GripperParams(goal_tolerance=rng.uniform(0.001, 0.05),
                               stall_timeout=rng.uniform(0.05, 0.5),
                               allow_stalling=bool(rng.integers(2)))
        judge = GripperJudge(LIM, params)
        goal = check_goal(rng.uniform(LIM.lower, LIM.upper), rng.uniform(0, 1), LIM, params)
        judge.start(goal, 0.0)
        t = 0.0
        for _ in range(200):
            t += 0.01
            q = rng.uniform(LIM.lower, LIM.upper)
            st = judge.step(t, q, rng.choice([0.0, rng.normal(0, 0.1)]),
                            rng.uniform(-1, 1), t - rng.uniform(0, 0.3))
            assert not (st.stalled and st.reached_goal)
            if st.reached_goal:
                assert abs(q - goal.position) <= params.goal_tolerance
            if st.stalled:
                assert abs(q - goal.position) > params.goal_tolerance
                assert st.status == ("succeeded" if params.allow_stalling else "aborted")
            if st.done:
                assert not judge.running
                break
