"""Core tier (no ROS): the joint trajectory core. Goals checked with the action's error
codes, splines through the points from the present state, and the follower's tolerances,
cancel, preemption and stale states; its invariant (no command step beyond velocity limit x
period, never outside the limits) over random goals, states and event sequences."""
from __future__ import annotations

import math

import numpy as np
import pytest

from hyperarm_control.trajectory import (Follower, GoalToleranceViolated, InvalidGoal,
                                         InvalidJoints, JointLimits, OldHeaderTimestamp,
                                         PathToleranceViolated, Tolerances, TrajectoryError,
                                         build_trajectory, resolve_tolerance, start_time)
from hyperarm_description.model import load_description

pytestmark = pytest.mark.core

LIM = JointLimits.from_description(load_description(None, "arm"))
N = len(LIM.names)
PERIOD = 0.01
#: path 0.1 rad, path velocity and goal velocity not checked (0), goal 0.01 rad, 0.5 s
DEFAULTS = Tolerances(np.full(N, 0.1), np.zeros(N), np.full(N, 0.01), np.zeros(N), 0.5)


def _random_goal(rng, q0, points=4, kind="cubic", slack=1.6):
    """A goal within the limits from q0: random waypoints, times slow enough for the limits
    (``slack`` x the fastest straight move)."""
    lo, hi = LIM.lower + 0.3, LIM.upper - 0.3
    p = rng.uniform(lo, hi, (points, N))
    t, prev, times = 0.0, q0, []
    for k in range(points):
        need = np.max(np.abs(p[k] - prev) / LIM.velocity)
        need = max(need, math.sqrt(np.max(np.abs(p[k] - prev) / LIM.acceleration)) * 2.5)
        t += slack * max(need, 0.2) + 0.3
        times.append(t)
        prev = p[k]
    v = a = None
    if kind in ("hermite", "quintic"):   # as a planner gives them: the neighbours' slopes
        knots = np.concatenate([[0.0], times])
        pts = np.vstack([q0, p])
        slope = np.diff(pts, axis=0) / np.diff(knots)[:, None]
        v = np.zeros((points, N))
        v[:-1] = 0.5 * (slope[:-1] + slope[1:])
    if kind == "quintic":
        a = np.zeros((points, N))
        a[:-1] = rng.uniform(-0.05, 0.05, (points - 1, N)) * LIM.acceleration
    return list(LIM.names), times, p, v, a


def _build(names, times, p, v=None, a=None, q0=None, v0=None, **kw):
    return build_trajectory(LIM, names, times, p.tolist(),
                            None if v is None else v.tolist(),
                            None if a is None else a.tolist(),
                            start_position=np.zeros(N) if q0 is None else q0,
                            start_velocity=v0, **kw)


def test_limits_from_the_description():
    assert LIM.names == tuple(f"joint{i}" for i in range(1, 10))
    rail = JointLimits.from_description(load_description(None, "rail_arm"))
    assert rail.names[0] == "rail" and rail.names[1:] == LIM.names
    assert rail.velocity[0] == load_description(None, "rail_arm").rail.velocity


@pytest.mark.parametrize("kind", ["cubic", "hermite", "quintic"])
@pytest.mark.parametrize("seed", range(3))
def test_the_spline_passes_every_point_from_the_present_state(kind, seed):
    rng = np.random.default_rng(seed)
    q0 = rng.uniform(LIM.lower + 0.5, LIM.upper - 0.5)
    names, times, p, v, a = _random_goal(rng, q0, kind=kind, slack=3.0)
    traj = _build(names, times, p, v, a, q0=q0)
    assert traj.kind == kind
    q, dq, _ = traj.sample(0.0)
    assert np.allclose(q, q0, atol=1e-12) and np.allclose(dq, 0.0, atol=1e-12)
    for k, t in enumerate(times):
        q, dq, ddq = traj.sample(t - 1e-12)
        assert np.allclose(q, p[k], atol=1e-9)
        if v is not None:
            assert np.allclose(dq, v[k], atol=1e-6)
        if a is not None:
            assert np.allclose(ddq, a[k], atol=1e-4)
    q, dq, ddq = traj.sample(times[-1] + 5.0)     # held after the end
    assert np.array_equal(q, p[-1]) and not dq.any() and not ddq.any()
    # continuity across the interior knots: position and velocity always; acceleration
    # for the C2 kinds (cubic spline, quintic)
    for t in times[:-1]:
        left, right = traj.sample(t - 1e-7), traj.sample(t + 1e-7)
        assert np.allclose(left[0], right[0], atol=1e-5)
        assert np.allclose(left[1], right[1], atol=1e-4)
        if kind != "hermite":
            assert np.allclose(left[2], right[2], atol=1e-3 * LIM.acceleration.max())


def test_the_messages_joint_order_is_mapped_onto_the_controllers():
    rng = np.random.default_rng(5)
    names, times, p, _, _ = _random_goal(rng, np.zeros(N), points=2)
    perm = rng.permutation(N)
    traj = _build([names[i] for i in perm], times, p[:, perm])
    assert np.allclose(traj.sample(times[-1])[0], p[-1])


def test_a_first_point_at_t0_is_the_start_state_and_causes_no_jump():
    q0 = np.full(N, 0.2)
    p = np.vstack([q0 + 0.01, np.full(N, 0.5)])
    traj = _build(list(LIM.names), [0.0, 2.0], p, q0=q0)
    assert np.allclose(traj.sample(0.0)[0], q0)          # from where the arm is
    with pytest.raises(InvalidGoal, match=r"point 0 at t = 0 puts joint1 at 0\.7000, "
                                          r"0\.5000 from where it is"):
        _build(list(LIM.names), [0.0, 2.0], np.vstack([q0 + 0.5, q0]), q0=q0)


def _bad(**change):
    names = list(LIM.names)
    times = [1.0, 2.0]
    p = np.array([np.full(N, 0.1), np.full(N, 0.2)])
    args = {"names": names, "times": times, "p": p, "v": None, "a": None}
    args.update(change)
    return args


@pytest.mark.parametrize("change,error,text", [
    ({"names": list(LIM.names[:-1])}, InvalidJoints, "missing joint9"),
    ({"names": list(LIM.names[:-1]) + ["elbow"]}, InvalidJoints, "unknown elbow"),
    ({"names": list(LIM.names[:-1]) + ["joint1"]}, InvalidJoints, "repeated joint1"),
    ({"times": [2.0, 1.0]}, InvalidGoal, "point 1 at 1 s is not after point 0"),
    ({"times": [1.0, 1.0]}, InvalidGoal, "times must increase strictly"),
    ({"times": [-1.0, 1.0]}, InvalidGoal, "before the start"),
    ({"times": [1.0, math.nan]}, InvalidGoal, "point 1 is not finite"),
    ({"times": [1.0]}, InvalidGoal, "1 times for 2 points"),
    ({"p": np.array([np.full(N, 0.1), [0.2] * (N - 1) + [math.nan]])}, InvalidGoal,
     "positions: point 1 has nan"),
    ({"p": np.array([np.full(N, 0.1), [9.0] + [0.2] * (N - 1)])}, InvalidGoal,
     "positions: point 1, joint1 = 9 is outside its limits"),
    ({"v": np.array([np.full(N, 99.0), np.zeros(N)])}, InvalidGoal,
     "velocities: point 0, joint1 = 99"),
    ({"v": np.zeros((2, N)), "a": np.array([np.zeros(N), np.full(N, 1e3)])}, InvalidGoal,
     "accelerations: point 1, joint1 = 1000"),
    ({"a": np.zeros((2, N))}, InvalidGoal, "accelerations without velocities"),
    ({"times": [0.05, 0.1], "p": np.array([np.full(N, 1.0), np.full(N, 1.0)])}, InvalidGoal,
     "the trajectory needs joint"),
])
def test_each_bad_goal_is_refused_with_its_code(change, error, text):
    args = _bad(**change)
    with pytest.raises(error, match=text.replace("(", r"\(")) as err:
        _build(args["names"], args["times"], args["p"], args["v"], args["a"])
    assert err.value.code == (-2 if error is InvalidJoints else -1)


def test_ragged_and_empty_points_are_refused():
    with pytest.raises(InvalidGoal, match="point 1 has 8 values, expected 9"):
        build_trajectory(LIM, LIM.names, [1.0, 2.0], [[0.1] * N, [0.1] * (N - 1)],
                         start_position=np.zeros(N))
    with pytest.raises(InvalidGoal, match="velocities: point 0 has 3 values"):
        build_trajectory(LIM, LIM.names, [1.0, 2.0], [[0.1] * N, [0.1] * N],
                         [[0.0] * 3, [0.0] * N], start_position=np.zeros(N))
    with pytest.raises(InvalidGoal, match="empty"):
        build_trajectory(LIM, LIM.names, [], [], start_position=np.zeros(N))


def test_a_spline_that_overshoots_a_limit_between_points_is_refused():
    """Points inside the limits, but the cubic between them swings past joint1's upper
    limit: refused before it runs."""
    hi = LIM.upper[0]
    p = np.zeros((3, N))
    p[:, 0] = [hi - 0.01, hi - 0.01, -1.0]
    with pytest.raises(InvalidGoal, match=r"joint1 position .* beyond its limit"):
        _build(list(LIM.names), [2.0, 2.2, 4.0], p, q0=np.zeros(N),
               v0=np.zeros(N))


def test_header_stamps_zero_future_late_and_old():
    assert start_time(0.0, 3.0, 100.0) == (100.0, 0.0)
    assert start_time(101.0, 3.0, 100.0) == (101.0, 0.0)       # starts then
    assert start_time(98.0, 3.0, 100.0) == (100.0, 2.0)        # late: 2 s already due
    with pytest.raises(OldHeaderTimestamp, match="would be over") as err:
        start_time(90.0, 3.0, 100.0)
    assert err.value.code == -3


def test_a_late_goal_starts_from_the_present_state_with_the_points_already_due_dropped():
    """A stamp 1 s old on a 2-point goal (1 s and 3 s): the first point is dropped, the
    spline runs from where the arm is now to the second point in the 2 s left; followed,
    it neither jumps nor aborts (it aborted at once on a 0.5 rad path error before)."""
    q0 = np.zeros(N)
    p = np.array([np.full(N, 0.5), np.full(N, 0.6)])
    start, elapsed = start_time(99.0, 3.0, 100.0)
    traj = _build(list(LIM.names), [1.0, 3.0], p, q0=q0, elapsed=elapsed)
    assert traj.duration == pytest.approx(2.0)
    assert np.allclose(traj.sample(0.0)[0], q0) and np.allclose(traj.sample(2.0)[0], 0.6)
    f = Follower(LIM, PERIOD)
    out = _run(f, traj, DEFAULTS, lambda t, out: out[-1].command if out else q0, 104.0,
               t0=start)
    assert out[-1].status == "succeeded", out[-1].failure
    with pytest.raises(OldHeaderTimestamp, match="every point was due"):
        _build(list(LIM.names), [1.0, 3.0], p, q0=q0, elapsed=3.5)


def test_a_goal_must_end_at_rest_and_not_last_for_hours():
    v = np.array([np.full(N, 0.1), np.full(N, 0.05)])
    p = np.array([np.full(N, 0.1), np.full(N, 0.2)])
    with pytest.raises(InvalidGoal, match="the last point gives joint1 0.05 rad/s"):
        _build(list(LIM.names), [1.0, 2.0], p, v)
    with pytest.raises(InvalidGoal, match="beyond 3600 s"):
        _build(list(LIM.names), [1.0, 1e7], p)
    # at rest as joint_trajectory_controller judges it (float32 epsilon): a velocity that
    # arithmetic made -6e-16 is rest, 1e-6 rad/s is not
    v[-1] = -5.9e-16
    assert _build(list(LIM.names), [1.0, 2.0], p, v).kind != "hold"
    v[-1] = 1e-6
    with pytest.raises(InvalidGoal, match="must end at rest"):
        _build(list(LIM.names), [1.0, 2.0], p, v)


def test_holding_here_while_moving_is_a_hold_not_a_refusal():
    """Only the start state (t = 0) while the arm still moves: hold where it is (was refused
    for needing -800 rad/s^2 to stop in 1 ms)."""
    q0 = np.full(N, 0.3)
    traj = _build(list(LIM.names), [0.0], q0[None, :], q0=q0, v0=np.full(N, 0.2))
    assert traj.kind == "hold" and np.array_equal(traj.sample(0.0)[0], q0)


def test_a_start_outside_the_limits_is_taken_as_the_nearest_limit():
    q0 = np.zeros(N)
    q0[0] = LIM.upper[0] + 0.3
    traj = _build(list(LIM.names), [2.0], np.full((1, N), 0.1), q0=q0)
    assert traj.sample(0.0)[0][0] == LIM.upper[0]


def test_tolerance_semantics_of_joint_trajectory_controller():
    assert resolve_tolerance(0.2, 0.1) == 0.2
    assert resolve_tolerance(0.0, 0.1) == 0.1
    assert resolve_tolerance(-1.0, 0.1) == math.inf
    with pytest.raises(InvalidGoal, match="-2"):
        resolve_tolerance(-2.0, 0.1)
    tol = Tolerances.resolve(LIM.names, DEFAULTS,
                             path={"joint3": (0.05, 0.5), "joint4": (-1.0, 0.0)},
                             goal_time=0.0)
    assert tol.path[2] == 0.05 and tol.path_velocity[2] == 0.5
    assert tol.path[3] == math.inf and tol.path[0] == 0.1
    assert tol.path_velocity[0] == math.inf          # a default of 0: not checked
    assert tol.goal_time == DEFAULTS.goal_time == 0.5
    assert Tolerances.resolve(LIM.names, DEFAULTS, goal_time=-1.0).goal_time == math.inf
    assert Tolerances(np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N), 0.0).goal_time \
        == math.inf                                  # 0: wait for the goal without limit
    with pytest.raises(InvalidGoal, match="'elbow': not a joint"):
        Tolerances.resolve(LIM.names, DEFAULTS, goal={"elbow": (0.1, 0.0)})
    with pytest.raises(InvalidGoal, match="goal_time_tolerance"):
        Tolerances.resolve(LIM.names, DEFAULTS, goal_time=-3.0)


def _run(follower, traj, tol, q_of, t_end, t0=0.0, stamp_lag=0.0):
    follower.start(traj, tol, t0)
    out = []
    t = t0
    while t <= t_end:
        cyc = follower.step(t, q_of(t, out), t - stamp_lag)
        out.append(cyc)
        if cyc.status != "running":
            break
        t += PERIOD
    return out


def test_a_tracked_trajectory_succeeds_and_holds_its_goal():
    rng = np.random.default_rng(2)
    f = Follower(LIM, PERIOD)
    names, times, p, v, a = _random_goal(rng, np.zeros(N), kind="quintic")
    traj = _build(names, times, p, v, a)
    out = _run(f, traj, DEFAULTS, lambda t, out: out[-1].command if out else np.zeros(N),
               times[-1] + 2.0)
    assert out[-1].status == "succeeded" and out[-1].failure is None
    assert np.allclose(out[-1].command, p[-1], atol=0.01)
    assert max(np.abs(c.error).max() for c in out) < DEFAULTS.path[0]


def test_a_joint_held_back_aborts_on_its_path_tolerance_and_the_arm_holds_there():
    f = Follower(LIM, PERIOD)
    traj = _build(list(LIM.names), [3.0], np.full((1, N), 0.6))

    def stuck(t, out):     # joint5 does not move; the others follow
        q = out[-1].command.copy() if out else np.zeros(N)
        q[4] = 0.0
        return q
    out = _run(f, traj, DEFAULTS, stuck, 5.0)
    assert out[-1].status == "aborted"
    assert isinstance(out[-1].failure, PathToleranceViolated)
    assert out[-1].failure.code == -4
    assert "joint5 is 0.1" in str(out[-1].failure) and "path tolerance 0.1" in str(
        out[-1].failure)
    at = out[-1].actual
    for k in range(200):     # held where the arm was at the abort
        cyc = f.step(10.0 + k * PERIOD, at, 10.0 + k * PERIOD)
    assert cyc.status == "aborted" and np.allclose(cyc.command, at)


def test_a_goal_not_reached_aborts_after_the_goal_time_tolerance():
    f = Follower(LIM, PERIOD)
    traj = _build(list(LIM.names), [1.0], np.full((1, N), 0.2))
    tol = Tolerances(np.zeros(N), np.zeros(N), np.full(N, 0.01), np.zeros(N), 0.3)

    def short(t, out):       # stops 0.05 rad short on joint2
        q = out[-1].command.copy() if out else np.zeros(N)
        q[1] = min(q[1], 0.15)
        return q
    out = _run(f, traj, tol, short, 3.0)
    assert out[-1].status == "aborted" and isinstance(out[-1].failure, GoalToleranceViolated)
    assert out[-1].failure.code == -5 and "joint2 is 0.0500 rad from its goal" in str(
        out[-1].failure)
    assert 1.3 <= out[-1].time <= 1.3 + 2 * PERIOD


def test_a_stale_state_aborts_and_holds_the_last_command():
    """States stop while joint1 moves fast: the goal aborts and the command stays where it
    was (it was sent back 0.23 rad at -3 rad/s towards the old state before)."""
    f = Follower(LIM, PERIOD, max_state_age=0.2)
    traj = _build(list(LIM.names), [2.0], np.full((1, N), 1.0))
    unchecked = Tolerances(np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N), 0.0)
    f.start(traj, unchecked, 0.0)
    q, last_stamp = np.zeros(N), 0.0
    for k in range(200):
        t = k * PERIOD
        if t < 1.0:                   # fresh states, then none after t = 1 s
            last_stamp = t
            q = f.step(t, q, last_stamp).command if k else f.step(t, q, t).command
            continue
        cyc = f.step(t, q, last_stamp)
        if cyc.status == "aborted":
            break
    assert "joint_states are 0.2" in str(cyc.failure) and cyc.failure.code == -4
    held = cyc.command
    for k in range(50):
        again = f.step(2.0 + k * PERIOD, q, last_stamp)
        assert np.array_equal(again.command, held)
    assert np.all(held >= q - 1e-12)          # not sent back towards the old state


def test_non_finite_inputs_are_refused_not_commanded():
    f = Follower(LIM, PERIOD)
    f.start(_build(list(LIM.names), [2.0], np.full((1, N), 0.3)), DEFAULTS, 0.0)
    f.step(0.0, np.zeros(N), 0.0)
    for now, stamp, v in ((math.nan, 0.01, None), (0.01, math.nan, None),
                          (0.01, 0.01, np.full(N, math.inf))):
        with pytest.raises(TrajectoryError, match="finite"):
            f.step(now, np.zeros(N), stamp, v)


def test_cancel_holds_the_last_command_and_a_preemption_starts_from_it():
    f = Follower(LIM, PERIOD)
    traj = _build(list(LIM.names), [2.0], np.full((1, N), 0.5))
    q = np.zeros(N)
    f.start(traj, DEFAULTS, 0.0)
    for k in range(100):
        q = f.step(k * PERIOD, q, k * PERIOD).command
    f.cancel()
    held = [f.step(1.0 + k * PERIOD, q, 1.0 + k * PERIOD) for k in range(20)]
    assert held[0].status == "cancelled"
    assert all(np.array_equal(c.command, q) for c in held)
    # a new goal from there: the first command is one step at most from the held one
    new = _build(list(LIM.names), [2.0], np.full((1, N), -0.2), q0=q)
    f.start(new, DEFAULTS, 2.0)
    first = f.step(2.0, q, 2.0)
    assert first.status == "running"
    assert np.allclose(first.desired, q)     # the new goal starts where the command was
    assert np.array_equal(first.command, first.desired)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_after_release_the_next_goal_starts_where_the_arm_was_moved(seed):
    # goal 1 ends at its hold; the controller releases the arm. A next goal from there
    # continues from the last command (the step invariant across goals); after another
    # commander moved the arm, reseed: goal 2's commands start at the measured position,
    # not at goal 1's hold
    rng = np.random.default_rng(seed)
    f = Follower(LIM, PERIOD)
    end1 = rng.uniform(-0.3, 0.3, N)
    out = _run(f, _build(list(LIM.names), [1.0], end1[None, :]), DEFAULTS,
               lambda t, out: out[-1].command if out else np.zeros(N), 3.0)
    assert out[-1].status == "succeeded"
    hold = f.step(3.0, end1, 3.0)
    assert np.array_equal(hold.command, hold.desired)
    for call in (lambda g: g.release(), lambda g: g.reseed(np.zeros(N))):
        g = Follower(LIM, PERIOD)                   # never while a goal runs
        g.start(_build(list(LIM.names), [1.0], end1[None, :]), DEFAULTS, 0.0)
        with pytest.raises(TrajectoryError):
            call(g)
    f.release()
    assert np.array_equal(f.last_command, hold.command)
    moved = end1 + rng.uniform(0.4, 0.8, N) * rng.choice([-1.0, 1.0], N)
    moved = np.clip(moved, LIM.lower, LIM.upper)
    end2 = moved + 0.05
    # without reseed: one velocity step from the hold (the old behaviour, heading back)
    g = Follower(LIM, PERIOD)
    g._last = hold.command.copy()
    g.start(_build(list(LIM.names), [1.0], end2[None, :], q0=moved), DEFAULTS, 5.0)
    assert np.all(np.abs(g.step(5.0, moved, 5.0).command - hold.command)
                  <= LIM.velocity * PERIOD + 1e-12)
    f.reseed(moved)
    f.start(_build(list(LIM.names), [1.0], end2[None, :], q0=moved), DEFAULTS, 5.0)
    first = f.step(5.0, moved, 5.0)
    # within one velocity-limit step of where the arm is (not heading back to end1)
    assert np.all(np.abs(first.command - moved) <= LIM.velocity * PERIOD + 1e-12)
    assert np.all(np.abs(first.command - end1) > 0.3)
    with pytest.raises(TrajectoryError):
        Follower(LIM, PERIOD).reseed(np.full(N, np.nan))



@pytest.mark.parametrize("seed", range(6))
def test_invariant_no_command_step_beyond_the_velocity_limit_whatever_happens(seed):
    """Random goals (all kinds), measured states that track, lag, jump or freeze, late
    stamps, preemptions mid-way, cancels and stale states, in random order: every command is
    inside the limits and within velocity limit x period of the previous one."""
    rng = np.random.default_rng(100 + seed)
    f = Follower(LIM, PERIOD, max_state_age=0.2)
    step = LIM.velocity * PERIOD
    q = rng.uniform(LIM.lower, LIM.upper)
    last = None
    t = 0.0
    events = 0
    for _ in range(3000):
        r = rng.random()
        if r < 0.01:
            kind = rng.choice(["cubic", "hermite", "quintic"])
            try:
                names, times, p, v, a = _random_goal(rng, q, points=int(rng.integers(1, 5)),
                                                     kind=kind, slack=rng.uniform(0.3, 3))
                traj = _build(names, times, p, v, a,
                              q0=np.clip(q, LIM.lower, LIM.upper))
                f.start(traj, DEFAULTS, t)
                events += 1
            except InvalidGoal:
                pass                 # too fast for the limits: refused, nothing changes
        elif r < 0.015:
            f.cancel()
        # the measured state: follows the command, lags, jumps or freezes
        mode = rng.random()
        if last is not None and mode < 0.7:
            q = last + rng.normal(0, 0.002, N)
        elif mode < 0.75:
            q = rng.uniform(LIM.lower, LIM.upper)
        stamp = t - (rng.uniform(0.0, 0.5) if rng.random() < 0.02 else 0.0)
        cyc = f.step(t, q, stamp)
        cmd = cyc.command
        assert np.all(cmd >= LIM.lower) and np.all(cmd <= LIM.upper)
        if last is not None:
            assert np.all(np.abs(cmd - last) <= step + 1e-12), (t, np.abs(cmd - last) / step)
        last = cmd
        t += PERIOD
    assert events >= 10


@pytest.mark.parametrize("seed", range(4))
def test_the_command_lead_makes_up_for_a_servo_that_lags(seed):
    """A servo that reaches each command ``lag`` s late: with command_lead = lag the path
    error is the spline's own curvature over a cycle (under 1 mrad); without a lead it is
    about velocity x lag, and every command stays within one velocity-limit step."""
    rng = np.random.default_rng(40 + seed)
    lag = 0.03
    names, times, p, v, a = _random_goal(rng, np.zeros(N), points=3, kind="quintic",
                                         slack=1.6)
    traj = _build(names, times, p, v, a)
    worst = {}
    for lead in (0.0, lag):
        f = Follower(LIM, PERIOD, command_lead=lead)
        f.start(traj, Tolerances(np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N), 0.0),
                0.0)
        sent: list[tuple[float, np.ndarray]] = []
        last = None
        errors = []
        for k in range(int(times[-1] / PERIOD)):
            t = k * PERIOD
            # the servo is where the command sent lag s ago asked it to be
            due = [c for tc, c in sent if tc <= t - lag + 1e-9]
            q = due[-1] if due else np.zeros(N)
            cyc = f.step(t, q, t)
            if last is not None:
                assert np.all(np.abs(cyc.command - last) <= LIM.velocity * PERIOD + 1e-12)
            last = cyc.command
            sent.append((t, cyc.command))
            if t > lag + PERIOD:
                errors.append(np.abs(cyc.error).max())
        worst[lead] = max(errors)
    speed = max(np.abs(traj.sample(t)[1]).max() for t in np.arange(0, times[-1], 0.01))
    assert worst[lag] < 1e-3, worst
    assert worst[0.0] > 0.5 * speed * lag, (worst, speed)


def test_a_state_is_judged_against_the_path_where_it_was_measured():
    """States that arrive 0.15 s after they were measured, on a fast move: judged at their
    stamp they are on the path (no abort); the feedback's time is the stamp's."""
    traj = _build(list(LIM.names), [1.5], np.full((1, N), 1.0))
    f = Follower(LIM, PERIOD, max_state_age=0.3)
    f.start(traj, DEFAULTS, 0.0)
    for k in range(int(2.5 / PERIOD)):
        t = k * PERIOD
        stamp = max(t - 0.15, 0.0)
        cyc = f.step(t, traj.sample(stamp)[0], stamp)
        assert cyc.status in ("running", "succeeded"), cyc.failure
        if cyc.status == "running":
            assert np.abs(cyc.error).max() < 1e-12
            assert cyc.time == pytest.approx(stamp)
    assert cyc.status == "succeeded"
    # the same late states judged at the cycle's time would have been beyond the path
    # tolerance (0.1 rad): it would have aborted
    assert max(np.abs(traj.sample(t)[0] - traj.sample(t - 0.15)[0]).max()
               for t in np.arange(0.15, 1.5, 0.01)) > DEFAULTS.path[0]


def test_commander_watch_tells_its_own_commands_from_another_commanders():
    from hyperarm_control.trajectory import CommanderWatch

    names = list(LIM.names)
    w = CommanderWatch(names, quiet=0.5, memory=4)
    mine = [np.full(N, 0.1 * k) for k in range(6)]
    for q in mine:
        w.sent(q)
    assert not w.observe(names, mine[-1], 1.0)             # its own, back bit for bit
    assert not w.observe(names, mine[2], 1.0)              # still remembered (4)
    assert w.busy(1.0) is None
    assert w.observe(names, mine[0], 2.0)                  # forgotten: another's
    assert not w.observe(["gripper"], [0.2], 2.5)          # another joint set
    assert w.observe(["joint3"], [0.0], 3.0)               # a part of its joints
    assert w.other_joints == ("joint3",) and w.heard == 2
    assert "joint3" in w.busy(3.2) and "0.200 s ago" in w.busy(3.2)
    assert w.busy(3.5) is None                             # quiet for 0.5 s
    assert w.observe(names, mine[-1] + 1e-12, 4.0)         # not exactly its own
    assert CommanderWatch(names, quiet=0.0).busy(0.0) is None
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError):
            CommanderWatch(names, quiet=bad)



def test_early_cycles_step_by_the_time_since_the_last_command():
    """Cycles closer together than the period (a driver's burst) step a joint by at most
    its velocity limit x the time since the last command: the arm is never told to move
    faster than its limits, whatever the cycle times."""
    rng = np.random.default_rng(5)
    f = Follower(LIM, PERIOD)
    f.start(_build(list(LIM.names), [0.8], np.full((1, N), 1.0)), DEFAULTS, 0.0)
    t, q, last = 0.0, np.zeros(N), None
    for _ in range(300):
        t += rng.choice([0.001, 0.004, 0.0075, 0.01, 0.02])
        cyc = f.step(t, q, t)
        if last is not None:
            lt, lq = last
            assert np.all(np.abs(cyc.command - lq)
                          <= LIM.velocity * min(t - lt, PERIOD) + 1e-12)
        last = (t, cyc.command)
        q = cyc.command


def test_state_check_refuses_states_that_are_not_the_arm():
    from hyperarm_control.trajectory import StateCheck

    names = list(LIM.names)
    c = StateCheck(names, LIM.velocity)                    # 3 rad/s, x2, + 0.02 rad
    q = np.zeros(N)
    assert c.check(names + ["gripper"], list(q) + [0.5], [], 1.00) is None
    assert c.check(names, list(q + 0.05), [], 1.01) is None     # 5 rad/s < 6 + slack
    # a jump of 0.9 rad in 10 ms: refused, naming the joint; the last state stays
    why = c.check(names, list(q + 0.95), [], 1.02)
    assert why is not None and why.startswith("joint1: 0.9500 is 0.9000 from its last")
    assert c.check(names, list(q + 0.06), [], 1.02) is None
    # a subset message stamped before the newest used for those joints: refused per joint
    why = c.check(names[:3], [0.06] * 3, [], 1.015)
    assert why is not None and "joint1: stamped 0.005 s before" in why
    # non-finite values: refused
    bad = list(q + 0.06)
    bad[4] = math.nan
    assert "joint5: non-finite" in c.check(names, bad, [], 1.03)
    assert "joint2: non-finite" in c.check(names, list(q + 0.06), [0.0, math.inf], 1.03)
    # other joints only (the rail's driver, the gripper): nothing to check
    assert c.check(["rail"], [5.0], [], 0.0) is None
    # a long gap allows a long move (a driver back after a pause)
    assert c.check(names, list(q + 1.0), [], 2.0) is None
    for bad_args in ((names, np.zeros(N)), (names, np.full(N, 3.0), 0.5),
                     (names, np.full(N, 3.0), 2.0, -1.0)):
        with pytest.raises(ValueError):
            StateCheck(*bad_args)
