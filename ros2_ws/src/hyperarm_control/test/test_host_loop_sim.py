"""Core tier: the compensation loop on the mock's simulated servos (no rclpy).

``hyperarm_control.benchmark.host_sim.rail_sweep``: :class:`CompensationLoop` (what
host_compensation runs per joint state) drives the arm of the mock's ``JointSim`` (rail_arm:
acceleration-limited servo profiles and their first-order lag, repeatability 0) while the
rail sweeps 0 -> +0.2 -> -0.2 -> 0 m at 0.2 m/s; each command reaches the simulation one
step (10 ms) after the joint state it answers. Judged as the e2e test is, by FK of the
measured joint states, rail included: the issue's 3 mm RMS, 8 mm max and 2 deg, every state
answered. Without the profile lead the same loop lags: it must be clearly worse, so the
lead is what this test shows (the e2e test adds the machine's jitter).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from hyperarm_control.benchmark.host_sim import rail_sweep

pytestmark = pytest.mark.core


def _figures(run) -> tuple[float, float, float]:
    p = run["position_error"]
    return (float(np.sqrt(np.mean(p ** 2))), float(p.max()),
            math.degrees(float(run["orientation_error"].max())))


@pytest.mark.slow
def test_rail_sweep_on_the_simulated_servos_meets_the_issue_bounds_with_the_lead():
    run = rail_sweep(lead=True)
    rms, worst, deg = _figures(run)
    summary = f"with lead: RMS {rms * 1e3:.2f} mm, max {worst * 1e3:.2f} mm, {deg:.2f} deg"
    print(summary)
    assert run["rail"].max() > 0.199 and run["rail"].min() < -0.199
    assert float(run["answered"]) == 1.0
    assert rms < 3e-3 and worst < 8e-3 and deg < 2.0, summary
    # the first 1.5 s (speeding up to 0.2 m/s, then steady) with and without the lead
    n = int(1.5 / 0.01)
    first = {k: v[:n] for k, v in run.items() if k != "answered"}
    rms1, _w1, deg1 = _figures(first)
    rms0, worst0, deg0 = _figures(rail_sweep(lead=False, duration=1.5))
    print(f"first 1.5 s with: RMS {rms1 * 1e3:.2f} mm, {deg1:.2f} deg; without: RMS "
          f"{rms0 * 1e3:.2f} mm, max {worst0 * 1e3:.2f} mm, {deg0:.2f} deg")
    assert rms1 < 0.5 * rms0 and deg1 < 0.5 * deg0, (summary, rms0, deg0)


@pytest.mark.slow
def test_uav_sway_on_the_simulated_robot_meets_the_bounds_both_ways():
    """The mock's ``uav_sway`` (2 cm, 1 cm heave, 5 deg tilt at 0.5 Hz) over its ramp and one
    period: judged by FK of the joint states on the mock's host pose and by its truth."""
    from hyperarm_control.benchmark.host_sim import sway

    run = sway("uav_sway")
    for kind in ("", "truth_"):
        p = run[f"{kind}position_error"]
        rms, worst = float(np.sqrt(np.mean(p ** 2))), float(p.max())
        deg = math.degrees(float(run[f"{kind}orientation_error"].max()))
        assert rms < 3e-3 and worst < 8e-3 and deg < 2.0, (kind, rms, worst, deg)
    tilt = max(math.degrees(math.acos(min(1.0, h[2, 2]))) for h in run["host"])
    assert tilt > 4.9, tilt                                       # the whole sway ran


@pytest.mark.slow
def test_uav_sway_on_the_passive_mount_meets_the_bounds_and_does_not_grow():
    """``uav_sway_passive`` (the sway on the shipped 8 kg, ~4 / 8 Hz, damping ratio ~0.1
    spring-damper mount: the arm's reactions move its base) for 20 s, ten sway periods:
    the bounds hold both ways, the mount does move (more than 1 mm), and its motion over
    the last 5 s is no larger than over the 5 s before (a compensation that feeds the
    mount's modes grows them: on a 0.5 kg mount it reached 40 mm; docs/host.md)."""
    from hyperarm_control.benchmark.host_sim import sway

    run = sway("uav_sway_passive", duration=20.0)
    for kind in ("", "truth_"):
        p = run[f"{kind}position_error"]
        rms, worst = float(np.sqrt(np.mean(p ** 2))), float(p.max())
        deg = math.degrees(float(run[f"{kind}orientation_error"].max()))
        assert rms < 3e-3 and worst < 8e-3 and deg < 2.0, (kind, rms, worst, deg)
    mount, t = run["mount"], run["t"]
    assert np.abs(mount[:, :3]).max() > 1e-3
    late, before = t > t[-1] - 5.0, (t > t[-1] - 10.0) & (t <= t[-1] - 5.0)
    for axis in range(6):
        swing = np.ptp(mount[late, axis]), np.ptp(mount[before, axis])
        assert swing[0] <= 1.1 * swing[1] + 1e-5, (axis, swing)


@pytest.mark.slow
def test_the_passive_mount_holds_from_other_postures():
    """Issue 24 item 4: ``uav_sway_passive`` from the random ordinary postures (seed 0) that
    the previous node did not hold, the first and third, 8 s (the mount's oscillation grew
    for about 6 s, then saturated): each within 3 mm RMS, 8 mm max, 2 deg by the mock's
    truth, the mount's motion not growing over the last 2 s. Without the mount-mode filter
    of the host pose they went 3.76 / 4.76 mm RMS, 15.9 / 15.8 mm max, growing 1.5 x (the
    second held at 0.22 mm either way; left out for time). The issue asks for 10 postures x 3 seeds: that
    takes minutes here: ``host_benchmark --only mount``; docs/host.md gives its figures."""
    from hyperarm_control.benchmark.host_sim import ordinary_postures, sway

    for q0 in ordinary_postures(0, 3)[::2]:
        run = sway("uav_sway_passive", duration=8.0, q0=q0)
        p = run["truth_position_error"]
        rms, worst = float(np.sqrt(np.mean(p ** 2))), float(p.max())
        deg = math.degrees(float(run["truth_orientation_error"].max()))
        mount, t = run["mount"], run["t"]
        late, before = t > t[-1] - 2.0, (t > t[-1] - 4.0) & (t <= t[-1] - 2.0)
        grow = max(np.ptp(mount[late, a]) / max(np.ptp(mount[before, a]), 1e-6)
                   for a in range(3))
        summary = (f"q0 {np.round(q0, 2).tolist()}: RMS {rms * 1e3:.2f} mm, max "
                   f"{worst * 1e3:.2f} mm, {deg:.2f} deg, mount swing last/previous 2 s "
                   f"{grow:.2f}")
        print(summary)
        assert rms < 3e-3 and worst < 8e-3 and deg < 2.0, summary
        assert grow < 1.25, summary


def test_the_mount_mode_filter_passes_a_ramp_and_attenuates_the_mounts_modes():
    """HostPoseTracker's mount-mode filter (3 / 2 Hz): a host moving at constant velocity
    is followed without lag (the advance undoes the low-pass's), a 0.5 Hz sway within 4 %
    of its amplitude, while at 6 Hz (between the mount's 4 and 8 Hz modes) the twist that
    carries the prediction over the horizon comes out below 40 % of the raw one (the pose
    itself at ~88 %, 19 deg behind); unfiltered (cutoff 0) everything passes whole."""
    from hyperarm_control.host import HostPoseTracker

    def run(signal, cutoff, seconds=4.0, dt=0.01):
        tracker = HostPoseTracker(pose_cutoff=cutoff, twist_cutoff=2.0 if cutoff else 0.0)
        out = []
        for k in range(int(seconds / dt)):
            pose = np.eye(4)
            pose[0, 3] = signal(k * dt)
            state = tracker.update(k * dt, pose)
            out.append((signal(k * dt), state.pose[0, 3], tracker.raw.linear[0],
                        state.linear[0]))
        return np.array(out[len(out) // 2:])          # after the transient

    ramp = run(lambda t: 0.05 * t, 3.0)
    assert np.abs(ramp[:, 1] - ramp[:, 0]).max() < 2e-4, np.abs(ramp[:, 1] - ramp[:, 0]).max()
    slow = run(lambda t: 0.02 * math.sin(2 * math.pi * 0.5 * t), 3.0, seconds=8.0)
    assert np.abs(slow[:, 1] - slow[:, 0]).max() < 0.04 * 0.02
    fast = run(lambda t: 0.001 * math.sin(2 * math.pi * 6.0 * t), 3.0)
    assert np.ptp(fast[:, 3]) < 0.4 * np.ptp(fast[:, 2]), (np.ptp(fast[:, 3]), np.ptp(fast[:, 2]))
    whole = run(lambda t: 0.001 * math.sin(2 * math.pi * 6.0 * t), 0.0)
    np.testing.assert_allclose(whole[:, 1], whole[:, 0])
    np.testing.assert_allclose(whole[:, 3], whole[:, 2])


def test_host_pose_tracker_twist_ignores_bursts_of_equal_stamps():
    """Poses published in a burst (a driver catching up: 10 ms of motion apart, stamps
    microseconds apart) do not make the twist spike; it is the motion over the baseline."""
    from hyperarm_control.host import HostPoseTracker

    tracker = HostPoseTracker(baseline=0.02)
    v = 0.05                                                      # m/s along x
    for k in range(30):
        stamp = k * 0.01 if k % 3 else k * 0.01 - 0.0099          # every third one early
        pose = np.eye(4)
        pose[0, 3] = v * k * 0.01
        state = tracker.update(stamp, pose)
        if k > 5:
            assert abs(state.linear[0] - v) < 0.5 * v, (k, state.linear)
    assert tracker.stamp == pytest.approx(0.29)
