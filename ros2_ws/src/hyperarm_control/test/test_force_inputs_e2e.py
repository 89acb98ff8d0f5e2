"""End-to-end tier of hybrid_force's inputs (issue 24 item 3): the installed executable,
driven by a scripted driver (the probe publishes joint_states at 100 Hz and serves hold),
gets late, out-of-order and malformed joint_states and hybrid goals."""
from __future__ import annotations

import math
import re
import time

import numpy as np
import pytest

from hyperarm_description.model import load_description
from hyperarm_control.benchmark.force_probe import ForceProbe
from hyperarm_ik.kinematics import Kinematics

pytestmark = [pytest.mark.e2e]

STIFF = [800.0, 800.0, 800.0, 20.0, 20.0, 20.0]
Q_SAFE = np.array([0.0, 0.5, 0.0, 0.6, 0.0, 0.5, 0.0, -1.0, 0.0])


def _stamp(msg) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def _counts(probe: ForceProbe) -> dict[str, int]:
    with probe.lock:
        values = probe.statuses[-1][1] if probe.statuses else {}
    return {k: int(v) for k, v in values.items()
            if k.startswith(("joint_states_", "hybrid_goal_"))}


def _until_counted(probe: ForceProbe, wait_for, key: str, send, tries: int = 5) -> bool:
    """``send()`` until the diagnostics' count ``key`` grows (a loaded machine may not take
    a message in: each try waits 1 s)."""
    for _ in range(tries):
        before = _counts(probe).get(key, 0)
        send()
        try:
            wait_for(lambda: _counts(probe).get(key, 0) > before, 1.0, what=key)
            return True
        except AssertionError:
            continue
    return False


def _tool_moves(probe: ForceProbe, kin: Kinematics, since: float, p0: np.ndarray) -> float:
    """Largest distance (m) of the tool at the commanded positions after ``since``
    (monotonic s) from ``p0``."""
    with probe.lock:
        cmds = [m for t, m in probe.commands if t > since]
    assert cmds, "no joint_command"
    return max(float(np.linalg.norm(kin.forward(np.array(m.position))[:3, 3] - p0))
               for m in cmds)


def test_late_out_of_order_and_malformed_inputs_are_dropped(launch, rclpy_context, executor,
                                                            wait_for):
    """While enabled and holding on a 100 Hz state stream: one state stamped now - 2 s with
    joint2 0.06 rad off (the tool about 3 cm), one 50 ms older than the newest (out of
    order), and states with a NaN position, an inf velocity and a short effort array are
    not used (no joint_command carries their stamps, the commands stay where they were),
    each counted in the diagnostics and each kind logged (naming the field); a goal 3 cm
    up stamped now - 2 s, and one stamped before the newest goal used, are ignored (the
    commanded tool stays within 1 mm); a fresh goal there is followed (the commanded tool
    moves > 5 mm: the measurement sees a goal that is used). On the old node the late
    state and the late goal were used."""
    kin = Kinematics(load_description())
    # stale_timeout 0.5 s: the probe's 100 Hz stream may stall 0.1 s on a loaded machine
    # (the stale rule is test_force_e2e.py's); state_max_age stays at its default
    proc = launch("hyperarm_control", "hybrid_force", params={"diagnostics_period": 0.2,
                                                          "stale_timeout": 0.5})
    probe = ForceProbe(rclpy_context, executor, wait_for, driver=True)
    try:
        probe.q = Q_SAFE.copy()
        probe.driving = True
        wait_for(lambda: probe.mode() == "disabled", 20.0, what="hybrid_force diagnostics")
        # and reading the probe's joint_states (an ee_wrench on each): enable can work
        wait_for(lambda: probe.wrench, 20.0, what="ee_wrench (hybrid_force's joint_states)")
        assert probe.enable(True).success
        wait_for(lambda: len(probe.commands) > 10, 5.0, what="joint_command while enabled")
        t = kin.forward(Q_SAFE)
        p0, r0 = t[:3, 3].copy(), t[:3, :3].copy()

        # joint states: late (2 s), out of order (50 ms), malformed
        q_off = Q_SAFE.copy()
        q_off[1] += 0.06
        nan_q = Q_SAFE.copy()
        nan_q[2] = math.nan
        inf_v = np.zeros(9)
        inf_v[3] = math.inf
        bad_stamps = []

        def dropped(key: str, publish) -> bool:
            """One bad state in a 30 ms pause of the stream (the node's subscription has
            depth 1: the next good state would replace it)."""
            def paused():
                probe.driving = False
                time.sleep(0.012)
                publish()
                bad_stamps.append(probe.last_published)
                time.sleep(0.02)
                probe.driving = True
            return _until_counted(probe, wait_for, key, paused)

        t_bad = time.monotonic()
        assert dropped("joint_states_stale", lambda: probe.publish_state(q_off, age=2.0))
        assert dropped("joint_states_out_of_order",
                       lambda: probe.publish_state(q_off, age=0.05))
        assert dropped("joint_states_nan", lambda: probe.publish_state(nan_q))
        assert dropped("joint_states_inf", lambda: probe.publish_state(Q_SAFE, dq=inf_v))
        assert dropped("joint_states_length",
                       lambda: probe.publish_state(Q_SAFE, effort=np.zeros(8)))
        with probe.lock:
            stamps = [_stamp(m) for tt, m in probe.commands if tt > t_bad]
        assert stamps and not set(bad_stamps) & set(stamps)
        assert _tool_moves(probe, kin, t_bad, p0) < 0.001
        assert probe.mode() == "active"
        out = proc.output()
        # the late state's age as the node saw it: 2.0xx s, more on a loaded machine (a CI
        # run: the line was there with another age)
        assert re.search(r"joint_states from .* ignored: stamped [2-9]\.\d{3} s ago, older "
                         r"than max_age", out), out[-2000:]
        for text in ("before the newest one used", "position of joint3 is NaN",
                     "velocity of joint4 is inf", "effort has 8 values for 9 names"):
            assert text in out, text

        # goals: late (2 s) and out of order are ignored; a fresh one is followed
        up = p0 + np.array([0.0, 0.0, 0.03])
        t_goal = time.monotonic()

        def ignored(key: str, send) -> bool:
            # the goal subscription has depth 1: goals sent back to back replace each other
            return _until_counted(probe, wait_for, key, send)

        assert ignored("hybrid_goal_stale", lambda: probe.send_goal(up, r0, STIFF, age=2.0))
        probe.send_goal(p0, r0, STIFF)                   # the newest goal used: here
        time.sleep(0.2)
        assert ignored("hybrid_goal_out_of_order",
                       lambda: probe.send_goal(up, r0, STIFF, age=0.6))
        time.sleep(0.5)
        assert _tool_moves(probe, kin, t_goal, p0) < 0.001
        assert probe.mode() == "active"
        t_fresh = time.monotonic()
        probe.send_goal(up, r0, STIFF)
        time.sleep(0.6)
        assert _tool_moves(probe, kin, t_fresh, p0) > 0.005
        assert "Traceback" not in proc.output()
    finally:
        probe.close()
