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
from hyperarm_ik.benchmark.force_probe import ForceProbe
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


def _wait_mode(probe, wait_for, mode: str, timeout: float = 5.0):
    return wait_for(lambda: probe.mode() == mode, timeout, what=f"mode {mode}")


def test_passive_rules_with_a_scripted_driver(launch, rclpy_context, executor, wait_for, kin):
    """Enable from the present pose; each bad goal refused (passive, hold called once, no
    more commands); stale joint_states passive within 0.2 s; a joint near its limit
    passive; disable holds once; goals while disabled ignored."""
    proc = launch("hyperarm_ik", "hybrid_force", params={"diagnostics_period": 0.2})
    probe = ForceProbe(rclpy_context, executor, wait_for, driver=True)
    probe.q = Q_SAFE.copy()
    probe.driving = True
    wait_for(lambda: probe.mode() == "disabled", 20.0, what="hybrid_force diagnostics")
    assert not probe.commands                                    # silent while disabled
    t = kin.forward(Q_SAFE)
    p, r = t[:3, 3], t[:3, :3]
    probe.send_goal(p, r, STIFF)                                  # ignored: not enabled
    time.sleep(0.2)
    assert not probe.commands and probe.mode() == "disabled"

    res = probe.enable(True)
    assert res.success, res.message
    wait_for(lambda: len(probe.commands) > 5, 5.0, what="joint_command while enabled")
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
    for k, goal in enumerate(bad_goals):
        if k:
            assert probe.enable(True).success
            wait_for(lambda: probe.mode() == "active", 5.0, what="active again")
        holds = len(probe.hold_calls)
        probe.send_goal(**goal)
        _wait_mode(probe, wait_for, "passive")
        wait_for(lambda: len(probe.hold_calls) == holds + 1, 5.0, what="one hold call")
        t_passive = time.monotonic()
        time.sleep(0.15)
        assert not _commands_since(probe, t_passive + 0.02), goal  # stopped publishing
        assert len(probe.hold_calls) == holds + 1                  # hold called once
        assert "goal refused" in probe.statuses[-1][1]["reason"]

    # a good goal is followed: commands keep coming
    assert probe.enable(True).success
    probe.send_goal(p + [0.0, 0.0, 0.005], r, STIFF)
    t0 = time.monotonic()
    wait_for(lambda: len(_commands_since(probe, t0)) > 10, 5.0, what="commands")
    assert probe.mode() == "active"

    # stale joint_states: passive within 0.2 s, one hold
    holds = len(probe.hold_calls)
    probe.driving = False
    t_stop = time.monotonic()
    _wait_mode(probe, wait_for, "passive", 2.0)
    t_seen = wait_for(lambda: probe.hold_calls[-1] if len(probe.hold_calls) > holds else None,
                      2.0, what="hold after stale joint_states")
    assert t_seen - t_stop < 0.2, f"passive after {t_seen - t_stop:.3f} s"
    assert "stale" in probe.statuses[-1][1]["reason"]
    # enable refused while joint_states are stale
    res = probe.enable(True)
    assert not res.success and "stale" in res.message

    # a joint near its limit
    probe.driving = True
    time.sleep(0.1)
    assert probe.enable(True).success
    holds = len(probe.hold_calls)
    q = Q_SAFE.copy()
    q[4] = kin.upper[4] - 0.01
    probe.q = q
    _wait_mode(probe, wait_for, "passive")
    wait_for(lambda: len(probe.hold_calls) == holds + 1, 5.0, what="hold at the limit")
    assert "joint5" in probe.statuses[-1][1]["reason"]
    res = probe.enable(True)                                  # refused there
    assert not res.success and "joint5" in res.message

    # disable: hold once, silence
    probe.q = Q_SAFE.copy()
    time.sleep(0.1)
    assert probe.enable(True).success
    holds = len(probe.hold_calls)
    assert probe.enable(False).success
    wait_for(lambda: len(probe.hold_calls) == holds + 1, 5.0, what="hold at disable")
    t_off = time.monotonic()
    time.sleep(0.2)
    assert not _commands_since(probe, t_off + 0.02)
    assert "Traceback" not in proc.output()
