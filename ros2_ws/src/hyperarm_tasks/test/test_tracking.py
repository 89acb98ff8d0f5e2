"""Core tests of path tracking (no rclpy): the closest-approach figures, the time scaling,
and the shipped figure8 task on the mock's simulation (simulated time, ~2 s each)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from hyperarm_driver.mock.config import load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_description.world import PoleSpec
from hyperarm_ik.collision import CollisionModel
from hyperarm_ik.paths import FIGURE8, Figure8, hold_orientation
from hyperarm_tasks.runner import Runner
from hyperarm_tasks.sequence import load_task, load_task_file
from hyperarm_tasks.steps.track_path import windows
from hyperarm_tasks.testing import SimRobot, stall_driver
from hyperarm_tasks.tracking import (PathClock, arc_length, closest_approach, tracking_report,
                                     trapezoid_time_scaling)

pytestmark = pytest.mark.core


def test_closest_approach_is_to_the_segments_not_the_samples():
    path = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])      # one 1 m segment
    w = np.array([[0.5, 0.002, 0.0], [1.5, 0.0, 0.0], [-0.1, 0.0, 0.1]])
    d, where = closest_approach(w, path)
    assert d == pytest.approx([0.002, 0.5, math.hypot(0.1, 0.1)])
    assert where == pytest.approx([0.5, 1.0, 0.0])
    d1, _ = closest_approach(w, path[:1])                      # a single sample: a point
    assert d1[0] == pytest.approx(math.hypot(0.5, 0.002))
    with pytest.raises(ValueError, match="no path samples"):
        closest_approach(w, np.empty((0, 3)))


def test_windows_do_not_credit_a_crossing_path_with_its_other_pass():
    # the path goes out along x and comes back 3 mm off: waypoints on the way back are
    # 0 mm from the way out, but only the way back was measured while they were targets
    out = np.c_[np.linspace(0, 0.1, 101), np.zeros(101), np.zeros(101)]
    back = out[::-1] + [0.0, 0.003, 0.0]
    path = np.vstack([out, back])
    w_back = out[::-1][::10]                                   # 11 waypoints of the return
    d_all, _ = closest_approach(w_back, path)
    assert d_all.max() == pytest.approx(0.0, abs=1e-12)
    win = np.array([[101, 201]] * len(w_back))
    d_win, where = closest_approach(w_back, path, win)
    assert d_win == pytest.approx(np.full(len(w_back), 0.003))
    assert where.min() >= 101
    with pytest.raises(ValueError, match="window"):
        closest_approach(w_back, path, np.array([[5, 1]] * len(w_back)))


def test_windows_of_a_stream():
    stamps = np.arange(0.0, 3.0, 0.5)                          # samples every 0.5 s
    commanded = np.array([0.0, 0.5, 1.2, 2.0, 2.0, 2.0])       # waypoints 0..2
    win = windows(stamps, commanded, 3)
    # waypoint 1 first commanded at sample 2 (t = 1.0 s): samples within 1 s, 0.0..2.0 s
    assert win.tolist() == [[0, 2], [0, 4], [1, 5]]


def test_tracking_report_counts_and_statistics():
    wp = np.c_[np.linspace(0, 0.1, 11), np.zeros(11), np.zeros(11)]
    meas = wp + [0.0, 0.0, 0.0]
    meas[4:7, 1] = 0.002                                        # 2 mm off at waypoints 4..6
    q_plan = np.c_[np.linspace(0, 0.5, 11), np.zeros(11)]
    q_meas = q_plan.copy()
    q_meas[5, 1] = 0.2                                          # one measured joint jump
    rep = tracking_report(wp, q_plan, meas, q_meas, 1e-3)
    assert rep.waypoints == 11 and rep.reached == 8
    assert rep.reached_fraction == pytest.approx(8 / 11)
    assert rep.error_max == pytest.approx(0.002) and rep.worst_waypoint == 5
    # waypoints 4 and 6 are closer to the segments that join the path's two levels
    side = 0.01 * 0.002 / math.hypot(0.01, 0.002)
    assert rep.error_mean == pytest.approx((0.002 + 2 * side) / 11, rel=1e-9)
    assert rep.error_median == pytest.approx(0.0, abs=1e-12)
    assert rep.max_joint_step == pytest.approx(0.05)
    assert rep.max_joint_step_measured == pytest.approx(0.2)
    m = rep.metrics()
    assert m["track_reached"] == 8.0 and m["track_error_max"] == pytest.approx(0.002)
    assert "8/11 waypoints (72.7 %) within 1 mm" in rep.summary()
    with pytest.raises(ValueError, match="threshold"):
        tracking_report(wp, q_plan, meas, q_meas, 0.0)


@pytest.mark.parametrize("length,speed,accel", [(0.73, 0.05, 0.1), (0.001, 0.05, 0.1)])
def test_trapezoid_time_scaling(length, speed, accel):
    s_of, total = trapezoid_time_scaling(length, speed, accel)
    t = np.linspace(0.0, total, 4001)
    s = np.array([s_of(x) for x in t])
    assert s[0] == 0.0 and s[-1] == pytest.approx(length)
    v = np.diff(s) / np.diff(t)
    assert v.min() >= -1e-12 and v.max() <= speed + 1e-9
    assert np.abs(np.diff(v) / np.diff(t)[1:]).max() <= accel * 1.01
    if length > speed * speed / accel:                          # it cruises at ``speed``
        assert total == pytest.approx(length / speed + speed / accel)


def test_figure8_geometry():
    p = FIGURE8.points(1000)
    assert p.shape == (1000, 3) and np.allclose(p[0], FIGURE8.center)
    assert p[:, 1].max() == pytest.approx(FIGURE8.center[1] + 0.12, abs=1e-6)
    assert np.ptp(p[:, 2]) == pytest.approx(0.12, abs=1e-5) and np.all(p[:, 0] == 0.40)
    assert arc_length(p)[-1] == pytest.approx(0.7306, abs=1e-3)
    with pytest.raises(ValueError, match="half_width"):
        Figure8(half_width=0.0)


def _cell(seed, **imperfections):
    base = load_mock_config()
    return dataclasses.replace(base, imperfections=dataclasses.replace(
        base.imperfections, seed=seed, **imperfections))


def test_figure8_on_the_mock_reaches_the_waypoints(desc, kin):
    sim = JointSim(desc, _cell(31))
    robot = SimRobot(sim)
    # the work cell as run_task.sh gives it to the task node: the plan seeded from the end
    # of the line to the first waypoint sweeps link5 through the source peg
    world = CollisionModel(kin, sim.cfg.world.spec)
    chain = [sim.names.index(n) for n in kin.joint_names]
    visited = []
    step = sim.step
    sim.step = lambda dt: (step(dt), visited.append(sim.position[chain].copy()))
    result = Runner(robot, kin, load_task("figure8", desc), collisions=world).run()
    assert result.success, result.message
    moved = [msg for _, msg in robot.logs if "planned from another posture" in msg]
    assert len(moved) == 1 and "link5 with peg source" in moved[0]
    # the arm itself kept clear of the pegs and the table all the way
    hits = [k for k, q in enumerate(visited[::5]) if world.in_collision(q)]
    assert len(visited) > 1000 and not hits, (len(visited), hits[:5])
    m = result.metrics
    assert m["track_waypoints"] == 1000 and m["track_reached"] >= 999
    assert m["track_error_max"] < 1e-3 and 0 < m["track_error_mean"] <= m["track_error_p95"]
    assert 0.0 < m["track_max_joint_step"] < 0.05
    # 0.73 m at 5 cm/s, plus the ramps: ~15 s
    assert m["track_time"] == pytest.approx(0.7306 / 0.05 + 0.5, abs=0.3)
    assert any("1000/1000 waypoints" in msg or "999/1000" in msg for _, msg in robot.logs)
    # unhindered, it keeps to its plan, and says nothing is slow
    assert m["track_mean_speed"] == pytest.approx(m["track_planned_mean_speed"], rel=0.05)
    assert not any("slower than planned" in msg for _, msg in robot.logs)


def test_figure8_through_a_pole_fails_before_moving(desc, kin):
    # a short pole through the figure-8 at its far left: every posture's plan hits it, nothing
    # is sent along the path
    sim = JointSim(desc, _cell(31))
    robot = SimRobot(sim)
    pole = PoleSpec("centre", (0.40, -0.12), 0.01, 0.17, 0.23)
    world = CollisionModel(kin, dataclasses.replace(sim.cfg.world.spec, poles=(pole,)))
    sent = []
    runner = Runner(robot, kin, load_task("figure8", desc), collisions=world)
    runner.on_feedback = lambda fb: sent.append(fb.phase)
    result = runner.run()
    assert not result.success and result.failure_kind == "collision", result.message
    # the first plan's reason (it meets the source peg before the pole), and the others'
    assert "the planned joints collide at waypoint" in result.message
    assert "no other of 7 postures at the first waypoint gave a clean plan" in result.message
    assert "tracking" not in sent and "reconfiguring" not in sent


def _run_file(desc, kin, tmp_path, step: str, hook=None, on_feedback=None, **imperfections):
    path = tmp_path / "track.yaml"
    path.write_text(f"schema_version: 1\nsteps:\n  - {step}\n")
    robot = SimRobot(JointSim(desc, _cell(32, **imperfections)))
    if hook:
        hook(robot)
    runner = Runner(robot, kin, load_task_file(path, desc), on_feedback=on_feedback,
                    collisions=CollisionModel(kin, robot.sim.cfg.world.spec))
    return runner.run(), robot


def test_figure8_judges_the_measured_path(desc, kin, tmp_path):
    # joint_states with 3 mrad of noise: the measured path is no longer within 1 mm
    result, robot = _run_file(desc, kin, tmp_path, "{name: f8, type: track_path, path: "
                              "figure8, waypoints: 200, speed: 10 cm/s, min_reached: 0.999}",
                              position_noise=0.003)
    assert not result.success and result.failure_kind == "tracking"
    assert "step 'f8' (track_path) failed: " in result.message
    assert "fewer than the required 99.9 %" in result.message
    assert result.metrics["track_reached"] < 0.999 * 200
    assert robot.held == 1


def test_too_fast_is_refused_before_tracking(desc, kin, tmp_path):
    result, _ = _run_file(desc, kin, tmp_path, "{name: f8, type: track_path, path: figure8, "
                          "waypoints: 100, speed: 5 m/s}")
    assert not result.success and result.failure_kind == "tracking"
    assert "more than half its velocity limit" in result.message and "at most" in result.message
    assert "track_reached" not in result.metrics


def test_a_stalled_tick_slows_the_path_instead_of_jumping(desc, kin, tmp_path):
    # every 20th tick the node "stalls" 0.3 s (a loaded machine): without a limit, the next
    # command would jump 3 cm along the path at 10 cm/s
    robots, phases = [], []

    def stall(robot):
        real, calls = robot.sleep, [0]

        def sleep(seconds):
            calls[0] += 1
            real(seconds + (0.3 if calls[0] % 20 == 0 else 0.0))
        robot.sleep = sleep
        robots.append(robot)

    result, robot = _run_file(
        desc, kin, tmp_path, "{name: f8, type: track_path, path: figure8, waypoints: 200, "
        "speed: 10 cm/s, min_reached: 0.999}", hook=stall,
        on_feedback=lambda fb: phases.append((robots[0].now(), fb.phase)))
    assert result.success, result.message
    t_track = [t for t, ph in phases if ph == "tracking"]
    cmds = [c for t, c, _ in robot.commands if t_track[0] <= t <= t_track[-1]]
    tool = np.array([kin.forward(np.array([c[n] for n in kin.joint_names]))[:3, 3]
                     for c in cmds])
    assert len(tool) > 100
    step = np.linalg.norm(np.diff(tool, axis=0), axis=1).max()
    assert step <= 1.5 * 0.02 * 0.10 * 1.01           # 1.5 periods at 10 cm/s: 3 mm
    nominal = 0.7306 / 0.10 + 0.10 / 0.1               # cruise + the two ramps
    assert result.metrics["track_time"] > nominal + 1.0   # it took longer instead
    assert result.metrics["track_reached"] >= 0.999 * 200
    # and says so (issue 24, item 6: figure8 ran at 3.2-3.9 cm/s of its stated 5 cm/s,
    # silently): the speed achieved beside the planned one, a warning
    m = result.metrics
    assert m["track_mean_speed"] == pytest.approx(m["track_length"] / m["track_time"])
    assert m["track_planned_mean_speed"] == pytest.approx(
        m["track_length"] / m["track_planned_time"])
    assert m["track_mean_speed"] < 0.9 * m["track_planned_mean_speed"]
    slow = [msg for lvl, msg in robot.logs if lvl == "warn" and "slower than planned" in msg]
    assert slow and "stated 10 cm/s" in slow[0] and \
        f"mean {m['track_mean_speed'] * 100:.2f} cm/s" in slow[0], robot.logs


def test_a_stalled_driver_holds_the_path(desc, kin, tmp_path):
    # the driver stalls 0.3 s in every 2 s (a loaded machine): it applies no command and
    # publishes no joint_states meanwhile, then takes the newest goal. Were the path to run
    # on, that goal would be 3 cm ahead at 10 cm/s and the servos would cut across.
    applied = []                       # (time, tool position) of the commands applied

    def stall(robot):
        stall_driver(robot, lambda positions: applied.append((robot.now(), kin.forward(
            np.array([positions[n] for n in kin.joint_names]))[:3, 3])))

    tracking = []                      # times of the tracking phase's feedback
    result, robot = _run_file(desc, kin, tmp_path, "{name: f8, type: track_path, path: "
                              "figure8, waypoints: 200, speed: 10 cm/s, min_reached: 0.999}",
                              hook=stall, on_feedback=lambda fb: tracking.append(
                                  applied[-1][0]) if fb.phase == "tracking" and applied
                              else None)
    assert result.success, result.message
    assert result.metrics["track_time"] > 0.7306 / 0.10 + 1.0 + 0.5   # it waited
    applied = [(t, p) for t, p in applied if tracking[0] <= t <= tracking[-1]]
    # across every stall the driver's next goal continues the path where its last one was
    # (the path is taken back to the last joint_states): no jump of the 50 ms it took to
    # see the stall (6 mm at 10 cm/s without the rewind); at most the period between the
    # last goal applied and the last joint_states, plus the resuming tick's 1.5 periods:
    # 2.5 periods of path, 2.5 mm
    gaps = [(t1, float(np.linalg.norm(p1 - p0))) for (t0, p0), (t1, p1)
            in zip(applied, applied[1:]) if t1 - t0 > 0.2]
    assert len(gaps) >= 4 and max(d for _, d in gaps) < 2.5 * 0.10 * 0.01, gaps


def test_path_clock_advances_slows_holds_and_rewinds():
    clock = PathClock(10.0, duration=1.0, period=0.01, stale=0.05, late_ticks=1.5)
    assert clock.tick(10.01, 0.0) == pytest.approx(0.01)
    assert clock.tick(10.05, 0.0) == pytest.approx(0.025)      # a late tick: 1.5 periods
    for k in range(1, 6):                                        # on time, 10 ms apart
        clock.tick(10.05 + 0.01 * k, 0.0)
    assert clock.t == pytest.approx(0.075)
    # the driver stalls after its state of 10.08: stale from 10.13 on (0.05 s)
    assert clock.tick(10.11, 0.03) == pytest.approx(0.085)      # not stale yet: runs on
    assert clock.tick(10.14, 0.06) == pytest.approx(0.055)      # taken back to 10.08's
    assert clock.stalled_for == pytest.approx(0.06)
    assert clock.tick(10.30, 0.22) == pytest.approx(0.055)      # held, no second rewind
    assert clock.tick(10.31, 0.0) == pytest.approx(0.065)       # fresh: on from there
    assert clock.stalled_for == 0.0
    for k in range(200):
        clock.tick(10.32 + 0.01 * k, 0.0)
    assert clock.t == 1.0                                        # never past the duration
    # a rewind before any tick old enough goes back to the start
    early = PathClock(0.0, duration=1.0, period=0.01, stale=0.05)
    early.tick(0.01, 0.0)
    assert early.tick(0.02, 0.5) == 0.0


def test_the_other_postures_tried_are_distinct_and_reach_the_first_waypoint(desc, kin):
    # (random IK seeds all gave the solver's one cold-start posture: 7 tries of one posture)
    from hyperarm_tasks.steps.track_path import other_starts
    runner = Runner(SimRobot(JointSim(desc, _cell(31))), kin, load_task("figure8", desc))
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = hold_orientation(kin), FIGURE8.points(1000)[0]
    here = runner.ik(pose, np.zeros(kin.nq)).q
    starts = list(other_starts(runner, pose, here, 7))
    assert len(starts) >= 5
    postures = [here] + starts
    for a in range(len(postures)):
        err = np.linalg.norm(kin.forward(postures[a])[:3, 3] - pose[:3, 3])
        assert err < 2e-4, err
        for b in range(a):
            assert np.abs(postures[a] - postures[b]).max() > 0.05, (a, b)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_a_figure8_anywhere_in_the_cell_never_drives_the_arm_into_it(desc, kin, tmp_path,
                                                                      seed):
    # the invariant beside the shipped placement: a random figure-8 (centre and size) in the
    # default work cell either runs with the measured arm clear of itself and the cell all
    # the way, or fails before tracking with the reason (collision, ik or tracking)
    rng = np.random.default_rng(seed)
    cx, cy, cz = rng.uniform(0.3, 0.45), rng.uniform(-0.1, 0.1), rng.uniform(0.0, 0.25)
    hw, hh = rng.uniform(0.05, 0.12), rng.uniform(0.03, 0.06)
    sim = JointSim(desc, _cell(40 + seed))
    world = CollisionModel(kin, sim.cfg.world.spec)
    chain = [sim.names.index(n) for n in kin.joint_names]
    visited = []
    step = sim.step
    sim.step = lambda dt: (step(dt), visited.append(sim.position[chain].copy()))
    path = tmp_path / "f8.yaml"
    path.write_text("schema_version: 1\nsteps:\n  - {name: ready, type: move_joints, arm: 0}\n"
                    f"  - {{name: f8, type: track_path, path: figure8, waypoints: 300, "
                    f"center: [{cx:.3f} m, {cy:.3f} m, {cz:.3f} m], half_width: {hw:.3f} m, "
                    f"half_height: {hh:.3f} m, speed: 5 cm/s}}\n")
    phases = []
    result = Runner(SimRobot(sim), kin, load_task_file(path, desc),
                    on_feedback=lambda fb: phases.append(fb.phase),
                    collisions=world).run()
    if result.success:
        hits = [k for k, q in enumerate(visited[::5]) if world.in_collision(q)]
        assert not hits, (seed, hits[:5])
    else:
        assert result.failure_kind in ("collision", "ik", "tracking"), result.message
        assert "tracking" not in phases, result.message
