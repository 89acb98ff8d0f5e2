"""End-to-end tier of hybrid_force: the installed executable, driven by a scripted driver
(the probe publishes joint_states and serves hold) for the passive rules, and against the
mock for the physics (pressing, holding, tracking, limits)."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from hyperarm_description import contract
from hyperarm_description.model import load_description
from hyperarm_description.qos import qos_for
from hyperarm_control.benchmark.force_probe import (ForceProbe, MockArm, excursion, mean_force,
                                               step_response)
from hyperarm_ik.kinematics import Kinematics

pytestmark = [pytest.mark.e2e]

STIFF = [800.0, 800.0, 800.0, 20.0, 20.0, 20.0]
# a comfortable pose: tool pointing down in front of the base, far from every limit
Q_SAFE = np.array([0.0, 0.5, 0.0, 0.6, 0.0, 0.5, 0.0, -1.0, 0.0])


@pytest.fixture(scope="module")
def kin() -> Kinematics:
    return Kinematics(load_description())


def _commands_since(probe: ForceProbe, t: float) -> list:
    with probe.lock:
        return [m for (tt, m) in probe.commands if tt > t]


def _held_here(probe, since: float) -> list[tuple[float, object]]:
    """The node's arm-only holds after ``since``: position commands without efforts, at the
    present (measured) positions; not the driver's hold service, which would end the
    gripper's squeeze on a held block."""
    with probe.lock:
        return [(t, m) for (t, m) in probe.commands if t > since and not list(m.effort)
                and np.abs(np.array(m.position) - probe.q).max() < 1e-9]


def _wait_mode(probe, wait_for, mode: str, timeout: float = 5.0):
    return wait_for(lambda: probe.mode() == mode, timeout, what=f"mode {mode}")


def _enable(probe, wait_for) -> None:
    """Enable while the probe drives joint_states. A refusal for stale states is asked
    again for up to 5 s: the probe's publishing thread, starved on a loaded machine, sent
    late (a CI run: 'joint_states are stale (0.199 s old)'). Any other refusal fails."""
    def once() -> bool:
        res = probe.enable(True)
        assert res.success or "stale" in res.message, res.message
        return res.success
    wait_for(once, 5.0, period=0.05, what="enabled (joint_states fresh)")


def test_passive_rules_with_a_scripted_driver(launch, rclpy_context, executor, wait_for, kin):
    """Enable from the present pose; each bad goal refused (passive, the arm held once where
    it is, no more commands); stale joint_states passive within 0.2 s (the driver's hold
    called once); a joint near its limit passive; disable holds the arm once; goals while
    disabled ignored."""
    proc = launch("hyperarm_control", "hybrid_force", params={"diagnostics_period": 0.2})
    probe = ForceProbe(rclpy_context, executor, wait_for, driver=True)
    try:
        _passive_rules(probe, proc, wait_for, kin)
    finally:
        probe.close()


def _passive_rules(probe, proc, wait_for, kin) -> None:
    probe.q = Q_SAFE.copy()
    probe.driving = True
    wait_for(lambda: probe.mode() == "disabled", 20.0, what="hybrid_force diagnostics")
    # and reading the probe's joint_states (an ee_wrench on each): enable can work
    wait_for(lambda: probe.wrench, 20.0, what="ee_wrench (hybrid_force's joint_states)")
    assert not probe.commands                                    # silent while disabled
    t = kin.forward(Q_SAFE)
    p, r = t[:3, 3], t[:3, :3]
    probe.send_goal(p, r, STIFF)                                  # ignored: not enabled
    time.sleep(0.2)
    assert not probe.commands and probe.mode() == "disabled"

    _enable(probe, wait_for)
    wait_for(lambda: len(probe.commands) > 5, 5.0, what="joint_command while enabled")
    t_disable = time.monotonic()
    assert probe.enable(False).success
    wait_for(lambda: _held_here(probe, t_disable), 5.0, what="disable holds the arm where it is")
    first = probe.commands[0][1]
    assert list(first.name) == list(contract.ARM_JOINTS)          # arm joints only
    # position output from the present pose: no jump
    assert np.abs(np.array(first.position) - Q_SAFE).max() < 0.01
    assert all(0.0 < e <= j.effort for e, j in zip(first.effort, kin.desc.joints))

    bad_goals = [
        dict(position=p, rotation=r, stiffness=STIFF, frame="tool0"),
        dict(position=p, rotation=r, stiffness=STIFF, frame=""),
        dict(position=[math.nan, 0.0, 0.0], rotation=r, stiffness=STIFF),
        dict(position=p, rotation=None, stiffness=STIFF, quat=(0.0, 0.0, 0.0, 0.5)),
        dict(position=p, rotation=r, stiffness=[-5.0] + STIFF[1:]),
        dict(position=p, rotation=r, stiffness=[1e6] + STIFF[1:]),
        dict(position=[2.0, 0.0, 0.0], rotation=r, stiffness=STIFF),
    ]
    def refused(goal) -> bool:
        """Send a bad goal: passive with the refusal, the arm held once where it is,
        silence. False if the probe itself was too starved to keep joint_states fresh (the
        node then rightly went passive as stale first): the caller retries."""
        _enable(probe, wait_for)
        wait_for(lambda: probe.mode() == "active", 5.0, what="active")
        holds, t_goal = len(probe.hold_calls), time.monotonic()
        probe.send_goal(**goal)
        _wait_mode(probe, wait_for, "passive")
        reason = probe.statuses[-1][1]["reason"]
        if "stale" in reason:
            return False
        assert "goal refused" in reason, reason
        wait_for(lambda: _held_here(probe, t_goal), 5.0, what="the arm held where it is")
        t_held = _held_here(probe, t_goal)[0][0]
        time.sleep(0.15)
        assert _commands_since(probe, t_held) == [], goal         # then stopped publishing
        assert len(_held_here(probe, t_goal)) == 1, goal          # held once
        assert len(probe.hold_calls) == holds, goal                # not the driver's hold
        return True

    for goal in bad_goals:
        assert any(refused(goal) for _ in range(3)), f"probe starved 3 times: {goal}"

    # a good goal is followed: commands keep coming
    _enable(probe, wait_for)
    probe.send_goal(p + [0.0, 0.0, 0.005], r, STIFF)
    t0 = time.monotonic()
    wait_for(lambda: len(_commands_since(probe, t0)) > 10, 5.0, what="commands")
    assert probe.mode() == "active"

    # stale joint_states: passive within 0.2 s, one hold
    def stale_once() -> bool:
        """Stop the states: passive within 0.2 s of the last one's arrival, one hold.
        False if the node had not taken in the probe's last states (an overloaded machine
        delayed its executor or the probe: the measurement is void): the caller retries."""
        holds = len(probe.hold_calls)
        probe.driving = False
        time.sleep(0.02)
        t_stop = probe.last_published              # stamp (ROS time) of the last joint state
        wait_for(lambda: len(probe.hold_calls) > holds, 2.0,
                 what="hold after stale joint_states")
        _wait_mode(probe, wait_for, "passive", 2.0)
        # the node's diagnostics at the event carry its time of going passive and when the
        # last joint state reached it (delivery delays of an overloaded machine excluded)
        st = next(st for st in probe.statuses if st[3] > t_stop and st[1]["mode"] == "passive")
        t_passive, t_last = st[3], float(st[1]["last_state_s"])
        print(f"stale joint_states: passive {t_passive - t_last:.3f} s after the last one "
              f"arrived ({t_passive - t_stop:.3f} s after it was sent)")
        if t_last < t_stop - 1e-3:                 # not the last one the probe sent
            probe.driving = True
            wait_for(lambda: probe.enable(True).success, 5.0, what="re-enabled")
            return False
        assert t_passive - t_last < 0.2, f"passive after {t_passive - t_last:.3f} s"
        assert len(probe.hold_calls) == holds + 1
        assert "stale" in probe.statuses[-1][1]["reason"]
        return True

    assert any(stale_once() for _ in range(3)), "the node missed the last states 3 times"
    # enable refused while joint_states are stale
    res = probe.enable(True)
    assert not res.success and "stale" in res.message

    # a joint near its limit
    probe.driving = True
    time.sleep(0.1)
    _enable(probe, wait_for)
    holds, t_near = len(probe.hold_calls), time.monotonic()
    q = Q_SAFE.copy()
    q[4] = kin.upper[4] - 0.01
    probe.q = q
    _wait_mode(probe, wait_for, "passive")
    wait_for(lambda: _held_here(probe, t_near), 5.0, what="the arm held at the limit")
    assert len(probe.hold_calls) == holds
    assert "joint5" in probe.statuses[-1][1]["reason"]
    res = probe.enable(True)                                  # refused there
    assert not res.success and "joint5" in res.message

    # disable: hold once, silence
    probe.q = Q_SAFE.copy()
    time.sleep(0.1)
    _enable(probe, wait_for)
    holds, t_disable = len(probe.hold_calls), time.monotonic()
    assert probe.enable(False).success
    wait_for(lambda: _held_here(probe, t_disable), 5.0, what="the arm held at disable")
    t_off = _held_here(probe, t_disable)[0][0]
    time.sleep(0.2)
    assert not _commands_since(probe, t_off) and len(probe.hold_calls) == holds
    assert "Traceback" not in proc.output()


# --- against the mock ------------------------------------------------------------------

# The mock's loop can fall 0.1 s behind on a loaded 2-core machine; the stale rule itself
# is tested with its default (0.1 s) against the scripted driver above.
MOCK_PARAMS = {"stale_timeout": 0.5, "diagnostics_period": 0.2}


def _workcell(tmp_path, **imperfections) -> str:
    """The packaged work cell with repeatability 0 (the press must not thread the block by
    a random offset) and a seed."""
    import yaml
    from ament_index_python.packages import get_package_share_directory

    src = f"{get_package_share_directory('hyperarm_driver')}/config/workcell.yaml"
    data = yaml.safe_load(open(src, encoding="utf-8"))
    data["imperfections"].update({"repeatability": 0.0, "seed": 1, **imperfections})
    out = tmp_path / "workcell.yaml"
    out.write_text(yaml.safe_dump(data), encoding="utf-8")
    return str(out)


def _mock_session(launch, rclpy_context, executor, wait_for, tmp_path, mock_params=None,
                  **force_params):
    """mock_driver (repeatability 0) + hybrid_force started, a probe and an arm mover
    ready (joint_states seen, the mock subscribed to joint_command)."""
    launch("hyperarm_driver", "mock_driver",
           params={"workcell_file": _workcell(tmp_path), **(mock_params or {})})
    hf = launch("hyperarm_control", "hybrid_force", params=dict(MOCK_PARAMS, **force_params))
    probe = ForceProbe(rclpy_context, executor, wait_for)
    arm = MockArm(probe, wait_for)
    arm.q_now()
    wait_for(lambda: probe.cmd_pub.get_subscription_count() > 0, 10.0, what="mock subscribed")
    _wait_node_reads_states(probe, wait_for)
    return probe, arm, hf


def _wait_node_reads_states(probe: ForceProbe, wait_for) -> None:
    """Until hybrid_force has taken in joint_states (it publishes ee_wrench on each): its
    services answer as soon as it is up, and an enable before its first joint state is
    refused ("no joint_states received yet": seen on a loaded machine)."""
    wait_for(lambda: probe.wrench, 30.0, what="ee_wrench (hybrid_force reading joint_states)")


def _window(probe: ForceProbe, arm: MockArm, since: float):
    """Contact forces (N, (k, 3)) and tool positions (m, FK of the measured joints) received
    after ``since`` (monotonic s)."""
    with probe.lock:
        forces = np.array([f for (t, f) in probe.contact_force if t > since])
        states = [m for (t, m) in probe.states if t > since]
    if not states:
        return forces, np.zeros((0, 3))
    idx = [list(states[0].name).index(n) for n in arm.arm]
    xs = np.array([arm.kin.forward(np.array(m.position)[idx])[:3, 3] for m in states])
    return forces, xs


def _passive_since(probe: ForceProbe, t: float) -> str | None:
    """The hybrid_force node's reason for going passive since ``t`` (monotonic s), or None:
    its diagnostics since then, and its mode now."""
    with probe.lock:
        rows = [st for st in probe.statuses if st[0] >= t]
    passive = [st[1].get("reason", "") for st in rows if st[1].get("mode") == "passive"]
    if passive:
        return passive[0]
    return None if probe.mode() != "passive" else "passive (no reason seen)"


def _settled(probe: ForceProbe, arm: MockArm, wait_for, timeout: float, window: float = 0.6):
    """Wait (at most ``timeout`` s) until, over the last ``window`` s, the true contact
    force varies by less than 2 % (or 0.02 N) and the tool's z by less than 0.1 mm.
    Returns the mean contact force (N, 3), the tool positions of that window and the
    seconds waited."""
    t0 = time.monotonic()
    box = []

    def still() -> bool:
        now = time.monotonic()
        if now - t0 < window:
            return False
        forces, xs = _window(probe, arm, now - window)
        if len(forces) < 3 or len(xs) < 10:
            return False
        box[:] = [forces.mean(axis=0), xs]
        spread = float(np.ptp(forces, axis=0).max())
        return spread < max(0.02 * float(np.linalg.norm(box[0])), 0.02) \
            and float(np.ptp(xs[:, 2])) < 1e-4

    wait_for(still, timeout, what="contact force and tool at rest", period=0.05)
    return box[0], box[1], time.monotonic() - t0


@pytest.mark.slow
def test_pressing_on_a_peg_top_with_the_mock(launch, rclpy_context, executor, wait_for,
                                             tmp_path):
    """Calibrated first (hybrid_force_calibrate on the mock), the held block pressed on the
    destination peg's top with z force-controlled: the true contact force settles within
    10 % or 0.2 N of |K (X0 - X) + F_d| for K 200 and 1000 N/m (and 400 N/m with F_d; and
    4000 N/m, capped at the 30 N wrench limit), x and y hold within 2 mm through each whole
    press, the calibrated ee_wrench agrees with the truth within 15 %
    (an uncalibrated node beside it gives the figure before calibration; the calibration
    includes each servo's Coulomb friction, which the creeping joints of a pressing arm
    otherwise add to the estimate), and no commanded effort exceeds a servo's limit."""
    launch("hyperarm_driver", "mock_driver", params={
        "workcell_file": _workcell(tmp_path), "diagnostics_period": 0.1})
    probe = ForceProbe(rclpy_context, executor, wait_for)
    before, _ = _launch_uncalibrated(launch, probe, payload_mass=0.05)
    path, _ = _calibrate(launch, wait_for, tmp_path)
    launch("hyperarm_control", "hybrid_force",
           params=dict(MOCK_PARAMS, payload_mass=0.05, calibration_file=path))
    arm = MockArm(probe, wait_for)
    arm.q_now()
    # the calibrated node reads joint_states (its estimate comes on each): enable can work
    wait_for(lambda: probe.wrench_base, 20.0, what="ee_wrench_base of the calibrated node")
    wait_for(lambda: probe.block_state, 20.0, what="mock diagnostics")
    block = np.array([0.35, 0.12, -0.185])           # on the source peg (docs/mock.md)
    arm.grip(1.2)
    arm.move(block + [0.0, 0.0, 0.06])
    arm.move(block)
    arm.grip(0.0, 0.6, wait=False)
    wait_for(lambda: probe.block_state == "held", 5.0, what="block held")
    # off the peg (8 cm high; the block's bottom 1.5 cm above its top), in 2 cm joint moves
    # (nearly straight up: a threaded block dragged sideways jams against the peg)
    for dz in (0.02, 0.04, 0.06, 0.08, 0.10):
        arm.move(block + [0.0, 0.0, dz])
    top = -0.12                                       # destination peg top (z)
    # 13 mm off the peg's axis: the peg's top meets the block's bottom beside the hole
    over = np.array([0.35 + 0.013, -0.12, top + 0.015 + 0.01])
    arm.move(over)
    res = probe.enable(True)
    assert res.success, (res.message, probe.statuses[-1:])
    # in the air and at rest, the filtered estimates settled: the estimates' bias
    def tool_still() -> bool:   # over 0.5 s the tool (FK of the measured joints) moved < 0.2 mm
        xs = _window(probe, arm, time.monotonic() - 0.5)[1]
        return len(xs) >= 10 and float(np.ptp(xs, axis=0).max()) < 2e-4
    wait_for(tool_still, 10.0, what="at rest")
    t_rest = time.monotonic() + 0.5
    wait_for(lambda: probe.wrench_base and before
             and min(probe.wrench_base[-1][0], before[-1][0]) > t_rest, 5.0,
             what="estimates settled")
    assert probe.tare().success
    tare_before = probe.node.create_client(probe._trigger,
                                           f"{UNCALIBRATED}/{contract.HYBRID_TARE}")
    assert probe.call(tare_before, probe._trigger.Request()).success
    rot = arm.tool()[:3, :3]
    depth = 0.008
    x0 = over.copy()
    x0[2] = top + 0.015 - depth                        # X0: `depth` below the peg's top
    t_start = time.monotonic()
    results = []
    # the last: 28 N released to 1.5 N (issue 24: the tool slipped sideways, 11-26 mm in
    # the core simulation, before force_rate)
    for k, fd in ((200.0, 0.0), (1000.0, 0.0), (400.0, -1.0), (4000.0, 0.0), (200.0, 0.0)):
        # a press during which the node went passive on stale joint_states (a loaded
        # machine: documented, the task's insert step enables it again) held the arm where it
        # was and says nothing of the law: enabled again and pressed again, at most twice;
        # any other passivity fails the test
        for again in range(3):
            t_goal = time.monotonic()
            probe.send_goal(x0, rot, [800.0, 800.0, k, 20.0, 20.0, 20.0],
                            (False, False, True, False, False, False), (0, 0, fd, 0, 0, 0))
            f, xs, waited = _settled(probe, arm, wait_for, 8.0)
            passive = _passive_since(probe, t_goal)
            if passive is None:
                break
            assert passive.startswith("joint_states stale") and again < 2, (k, fd, passive)
            _enable(probe, wait_for)
        xy_all = _window(probe, arm, t_goal)[1][:, :2]     # the whole press, contact included
        f_true = abs(float(f[2]))        # the force-controlled axis: the normal force
        since = time.monotonic() - 0.6
        with probe.lock:
            est = mean_force(probe.wrench_base, since)
            est_before = mean_force(before, since)
        # the estimates (what the tool applies) against the truth (-(force on the block))
        est_error = float(np.linalg.norm(est + f) / np.linalg.norm(f))
        # its parts normal to the peg's top (z) and tangential (x, y: mostly friction)
        est_normal = float(abs(est[2] + f[2]) / np.linalg.norm(f))
        est_tangential = float(np.linalg.norm(est[:2] + f[:2]) / np.linalg.norm(f))
        with probe.lock:
            std = probe.statuses[-1][1].get("wrench_std_tool", "") if probe.statuses else ""
        before_error = float(np.linalg.norm(est_before + f) / np.linalg.norm(f))
        # at 4000 N/m the law asks 34 N: the wrench limit (max_force, 30 N) caps it
        expected = min(abs(k * (x0[2] - xs[:, 2].mean()) + fd), 30.0)
        results.append(dict(K=k, F_d=fd, true=round(f_true, 3), expected=round(expected, 3),
                            est_error=round(est_error, 3),
                            est_normal=round(est_normal, 3),
                            est_tangential=round(est_tangential, 3), est_std_tool=std,
                            xy_max_mm=round(float(np.abs(xy_all - x0[:2]).max()) * 1e3, 2),
                            uncalibrated_error=round(before_error, 3),
                            settled_s=round(waited, 1)))
        assert probe.block_state == "held"
        assert abs(f_true - expected) <= max(0.1 * expected, 0.2), results
        # x and y hold (FK of the measured joints) while z presses: through the whole
        # press, contact and its build-up included (issue 24 item 7: 2.7 mm at 4000 N/m
        # before the pseudo-goal's position axes got their own speed budget)
        assert np.abs(xy_all - x0[:2]).max() < 0.002, results
    print("pressing:", results)
    lim = np.array([j.effort for j in arm.desc.joints])
    with probe.lock:
        cmds = [m for (t, m) in probe.commands if t > t_start]
    assert cmds
    assert max(float(np.max(np.abs(np.array(m.effort)) / lim)) for m in cmds) <= 1.0
    assert probe.enable(False).success
    # the calibrated estimate (scale, offset and Coulomb friction of each servo fitted by
    # hybrid_force_calibrate): within 15 % of the truth at every force, 1.6 N included
    worst = max(r["est_error"] for r in results)
    assert worst <= 0.15, f"calibrated ee_wrench {worst:.0%} off the truth: {results}"


def overshoot(xs: np.ndarray, start: np.ndarray, goal: np.ndarray) -> float:
    """Largest excursion beyond the goal along the step, as a fraction of the step."""
    d = goal - start
    progress = (xs - start) @ d / float(d @ d)
    return float(max(progress.max() - 1.0, 0.0))


@pytest.mark.slow
def test_step_tracking_and_no_sag(launch, rclpy_context, executor, wait_for, tmp_path):
    """The tool (FK of the measured joints) moves less than 1 mm around the controller's
    start, a compliance on/off (mode change) and its stop; a 2 cm step of the goal on the
    position axes is tracked (within 1 mm after 2 s) with under 10 % overshoot, the other
    axes held within 3 mm. (Today's mock has no torque-off gap at a servo's operating-mode
    switch; the 'position' output causes none: every command is current-based position.)"""
    probe, arm, _ = _mock_session(launch, rclpy_context, executor, wait_for, tmp_path)
    arm.move([0.35, -0.05, -0.05])
    time.sleep(0.3)
    p0 = arm.tool()[:3, 3].copy()
    sag = {"start": excursion(probe, arm, p0, lambda: probe.enable(True))}
    ts, xs, goal = step_response(probe, arm)
    start = goal - np.array([0.0, 0.02, 0.0])
    ov = overshoot(xs, start, goal)
    print(f"step 2 cm in y: overshoot {ov * 100:.1f} %, final error "
          f"{np.linalg.norm(xs[-1] - goal) * 1000:.2f} mm")
    assert ov < 0.10
    assert np.linalg.norm(xs[-1] - goal) < 0.001
    assert np.abs(xs[:, [0, 2]] - start[[0, 2]]).max() < 0.003   # the other axes held
    p1 = arm.tool()[:3, 3].copy()
    sag["compliance on"] = excursion(probe, arm, p1, lambda: probe.compliance(True))
    sag["compliance off"] = excursion(probe, arm, p1, lambda: probe.compliance(False))
    sag["stop"] = excursion(probe, arm, p1, lambda: probe.enable(False))
    print("tool excursion (mm):", {k: round(v * 1e3, 3) for k, v in sag.items()})
    assert all(v < 0.001 for v in sag.values()), sag


def _post_cell(tmp_path) -> str:
    """The shipped ``workcell_post.yaml`` (a 55 mm-radius post 0.30 m out at 45°) with
    repeatability 0 and a seed."""
    import yaml
    from ament_index_python.packages import get_package_share_directory

    src = f"{get_package_share_directory('hyperarm_driver')}/config/workcell_post.yaml"
    data = yaml.safe_load(open(src, encoding="utf-8"))
    data["imperfections"].update({"repeatability": 0.0, "seed": 2})
    out = tmp_path / "workcell_post.yaml"
    out.write_text(yaml.safe_dump(data), encoding="utf-8")
    return str(out)


# the wrap (docs/force.md, "Whole-arm compliance"): the torque output (every joint soft),
# a null-space posture spring of 1 N·m/rad, a soft goal leading the tool (N/m, N·m/rad)
WRAP_PARAMS = {"output": "torque", "posture_stiffness": 1.0}
WRAP_STIFFNESS = [200.0, 200.0, 200.0, 2.0, 2.0, 2.0]


@pytest.mark.slow
def test_whole_arm_compliance_closes_around_a_pole(launch, rclpy_context, executor, wait_for,
                                                   tmp_path):
    """Whole-arm compliance through the node in the shipped post cell: from an open wrap
    posture (hyperarm_control.testing.wrap_postures: the post inside the arm's open U,
    nothing touching), force control in the torque output, compliance on, the goal leads
    the tool (tool pose of the closed posture, in 4 steps) and the null-space posture is
    that closed posture, which lies inside the post: the arm ends with at least 3 links on
    the post (debug/contacts, the mock's ground truth; the gripper's capsule not counted)
    and bounded contact forces (every link's below 25 N, not growing)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from hyperarm_driver.mock.config import load_mock_config
    from hyperarm_driver.mock.joint_sim import JointSim
    from hyperarm_control.testing import wrap_postures

    cell = _post_cell(tmp_path)
    sim = JointSim(load_description(), load_mock_config(cell))
    (post,) = sim.cfg.world.poles
    q_open, q_closed = wrap_postures(sim, post)
    launch("hyperarm_driver", "mock_driver", params={"workcell_file": cell})
    posture = "[" + ",".join(f"{v:.4f}" for v in q_closed) + "]"
    launch("hyperarm_control", "hybrid_force", params=dict(MOCK_PARAMS, posture=posture,
                                                      **WRAP_PARAMS))
    probe = ForceProbe(rclpy_context, executor, wait_for)
    contacts: list = []
    probe.node.create_subscription(DiagnosticArray, contract.CONTACTS_TRUTH,
                                   probe._rec(contacts), qos_for(contract.CONTACTS_TRUTH))
    arm = MockArm(probe, wait_for)
    arm.q_now()
    wait_for(lambda: probe.cmd_pub.get_subscription_count() > 0, 10.0, what="mock subscribed")
    # (sent again while waiting: a first command can be lost while discovery completes on
    # the mock's side, which once left the arm where it started in a whole-suite run)
    wait_for(lambda: (probe.command(arm.arm, q_open),
                      np.abs(arm.q_now() - q_open).max() < 2e-3)[1], 10.0, period=0.2,
             what="open posture")
    assert not any(m.status for _, m in contacts[-1:]), "touching in the open posture"
    _wait_node_reads_states(probe, wait_for)
    res = probe.enable(True)
    assert res.success, res.message
    assert probe.compliance(True).success
    kin = arm.kin
    for s in (0.25, 0.5, 0.75, 1.0):
        t = kin.forward(q_open + s * (q_closed - q_open))
        probe.send_goal(t[:3, 3], t[:3, :3], WRAP_STIFFNESS)
        time.sleep(1.0)                 # the goal's pace (it leads the tool), not a wait

    def links(msg) -> dict:
        return {kv.value: float(np.linalg.norm([float(v) for v in dict(
            (k.key, k.value) for k in st.values)["force_N"].split()]))
            for st in msg.status for kv in st.values if kv.key == "link"}

    def closed() -> bool:
        with probe.lock:
            recent = [(t, links(m)) for t, m in contacts if t > time.monotonic() - 2.0]
        if len(recent) < 20 or len([k for k in recent[-1][1] if k.startswith("link")]) < 3:
            return False
        half = recent[-1][0] - 1.0
        old = [max(ls.values(), default=0.0) for t, ls in recent if t <= half]
        new = [max(ls.values(), default=0.0) for t, ls in recent if t > half]
        if not old or not new:     # less than a second of contacts yet
            return False
        f_old, f_new = max(old), max(new)
        return f_new <= 1.05 * f_old + 0.1
    try:
        wait_for(closed, 10.0, what=">= 3 links on the pole, forces steady")
    except AssertionError as exc:     # say what the pole had instead
        with probe.lock:
            seen = [links(m) for _t, m in contacts[-200::20]]
        raise AssertionError(f"{exc}; last contacts (link: N): {seen}") from None
    with probe.lock:
        last = links(contacts[-1][1])
        peak = max(max(links(m).values(), default=0.0) for _, m in contacts)
    print(f"compliance around the pole: links in contact {sorted(last)}, forces (N) "
          f"{ {k: round(v, 2) for k, v in sorted(last.items())} }, peak {peak:.2f} N, "
          f"mode {probe.mode()}")
    assert len([k for k in last if k.startswith("link")]) >= 3, last   # arm links, not the gripper
    assert max(last.values()) < 25.0, last
    assert probe.mode() == "active"
    assert probe.enable(False).success


def _calibrate(launch, wait_for, tmp_path, poses: int = 3) -> tuple[str, str]:
    """hybrid_force_calibrate on the running mock (hybrid_force disabled or not started):
    exits 0; returns (the calibration file, its log)."""
    out = tmp_path / "calibration.yaml"
    cal_proc = launch("hyperarm_control", "hybrid_force_calibrate", params={
        "output_file": str(out), "poses": poses, "approach": 0.02, "settle": 0.2,
        "average": 0.2})
    wait_for(lambda: cal_proc.proc.poll() is not None, 60.0, what="calibration finished")
    assert cal_proc.proc.returncode == 0, cal_proc.output()[-2000:]
    assert "torque RMS error" in cal_proc.output()
    return str(out), cal_proc.output()


UNCALIBRATED = "/hyperarm/uncalibrated"


def _launch_uncalibrated(launch, probe: ForceProbe, **params):
    """A second hybrid_force without calibration, only estimating (never enabled): every
    name under UNCALIBRATED but the joint_states it reads. Returns its ee_wrench_base
    record (the probe's [(t, msg)]) and launched process: the 'before calibration' figure
    beside the calibrated node."""
    from geometry_msgs.msg import WrenchStamped

    proc = launch("hyperarm_control", "hybrid_force", "--ros-args", "-r",
                  f"joint_states:={contract.DEFAULT_NAMESPACE}/{contract.JOINT_STATES}", "-r",
                  f"{contract.DIAGNOSTICS}:={UNCALIBRATED}/diagnostics",
                  params=dict(MOCK_PARAMS, **params), namespace=UNCALIBRATED)
    store: list = []
    probe.node.create_subscription(WrenchStamped, f"{UNCALIBRATED}/{contract.EE_WRENCH_BASE}",
                                   probe._rec(store), qos_for(contract.EE_WRENCH_BASE))
    return store, proc


def _rms_error(est: list, truth: list, since: float) -> float:
    """RMS over the samples after ``since`` of |estimated force - true force| (N): the
    estimate is what the tool applies, the truth what the contacts exert on the block
    (its opposite), in base_link and tool0 axes (zero without a contact in either)."""
    e = mean_force(est, since)
    t = mean_force(truth, since)
    return float(np.linalg.norm(e + t)) if np.linalg.norm(t) > 1e-9 else float(np.linalg.norm(e))


@pytest.mark.slow
def test_calibration_executable_writes_the_file_the_node_loads(launch, rclpy_context, executor,
                                                               wait_for, tmp_path):
    """hybrid_force_calibrate drives the mock (its current model: per-servo torque constants
    1 +- 10 %, friction, quantized currents) through static poses, exits 0 and writes a
    calibration that hybrid_force loads. At held-out poses (tool down over the work cell,
    nothing touching: the truth debug/tool_wrench_truth is zero), the RMS error of the
    wrench estimate of the calibrated node is at most half that of an uncalibrated one."""
    t_start = time.monotonic()
    from hyperarm_control.force.calibration import load_calibration

    launch("hyperarm_driver", "mock_driver", params={"workcell_file": _workcell(tmp_path)})
    probe = ForceProbe(rclpy_context, executor, wait_for)
    before, _ = _launch_uncalibrated(launch, probe)      # starts while the calibration runs
    path, log = _calibrate(launch, wait_for, tmp_path)
    t = time.monotonic()
    cal = load_calibration(path, list(contract.ARM_JOINTS))
    assert not cal.joints["joint1"].identified and cal.joints["joint2"].identified
    hf = launch("hyperarm_control", "hybrid_force", params=dict(MOCK_PARAMS, calibration_file=path))
    wait_for(lambda: f"calibration {path}" in hf.output(), 20.0, what="hybrid_force started")
    arm = MockArm(probe, wait_for)
    arm.q_now()
    wait_for(lambda: probe.cmd_pub.get_subscription_count() > 0, 10.0, what="mock subscribed")
    errors = []
    for xyz in ([0.35, 0.0, -0.05], [0.25, -0.15, -0.10]):
        arm.move(xyz)
        wait_for(lambda: np.abs(probe.last_state().velocity[:9]).max() < 0.01, 10.0,
                 what="at rest")
        t0 = time.monotonic() + 0.5                 # the estimates' low-pass settled
        wait_for(lambda: all(s and s[-1][0] > t0 + 0.2 for s in
                             (before, probe.wrench_base, probe.truth)), 5.0, what="estimates")
        with probe.lock:
            errors.append((_rms_error(before, probe.truth, t0),
                           _rms_error(probe.wrench_base, probe.truth, t0)))
    rms_before, rms_after = (float(np.sqrt(np.mean(np.square(e)))) for e in zip(*errors))
    print(f"calibration: {log.splitlines()[-1] if log else ''} "
          f"({t - t_start:.1f} s, then {time.monotonic() - t:.1f} s of checks)")
    print(f"wrench estimate RMS error at 2 held-out poses (no contact, no tare): "
          f"{rms_before:.3f} N uncalibrated -> {rms_after:.3f} N calibrated")
    assert rms_after <= 0.5 * rms_before, errors
