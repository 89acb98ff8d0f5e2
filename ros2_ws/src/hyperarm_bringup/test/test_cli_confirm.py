"""The CLI's confirmation core (hyperarm_bringup.confirm, no ROS): when a joint has taken its
goal, which driver log lines are refusals, which joints a table lacks; and the ik/run
messages of the CLI (issue 25 items 4 and 6)."""
from __future__ import annotations

import random

import numpy as np
import pytest

from hyperarm_bringup.confirm import REACHED, STEP, GoalWatch, is_refusal, missing_joints
from hyperarm_description import contract
from hyperarm_description.model import load_description

pytestmark = pytest.mark.core

LIMITS = load_description(None, "rail_arm").limits_by_name()


def _kind(name: str) -> str:
    return "rail" if name == contract.RAIL_JOINT else "revolute"


@pytest.mark.parametrize("seed", range(5))
def test_a_joint_moving_to_its_goal_is_taken_one_standing_still_is_not(seed):
    rng = np.random.default_rng(seed)
    for _ in range(40):
        names = list(rng.choice(list(LIMITS), size=rng.integers(1, 5), replace=False))
        start = {n: rng.uniform(*LIMITS[n]) for n in LIMITS}
        goal = {n: rng.uniform(*LIMITS[n]) for n in names}
        far = [n for n in names if abs(goal[n] - start[n]) > 2 * STEP[_kind(n)]]
        watch = GoalWatch(goal, start)
        watch.update(start)                          # nothing moved yet
        assert watch.pending() == [n for n in names if n in far or
                                   abs(goal[n] - start[n]) > REACHED[_kind(n)]]
        # noise smaller than REACHED/2 around the start never counts as taking the goal
        noisy = {n: start[n] + rng.uniform(-1, 1) * REACHED[_kind(n)] / 2 for n in LIMITS}
        watch.update(noisy)
        assert set(far) <= set(watch.pending())
        # half way there: a step closer than the start, for every far joint
        half = dict(start, **{n: (start[n] + goal[n]) / 2 for n in names})
        watch.update(half)
        assert not set(far) & set(watch.pending())
        # moving away never confirms
        away = GoalWatch(goal, start)
        away.update({n: start[n] - np.sign(goal[n] - start[n]) * 0.1 for n in names})
        assert set(far) <= set(away.pending())


def test_reaching_the_goal_confirms_and_nan_is_ignored():
    watch = GoalWatch({"joint1": 0.5, "rail": 0.2}, {"joint1": 0.496, "rail": 0.0})
    watch.update({"joint1": float("nan"), "rail": float("nan")})
    assert watch.pending() == ["joint1", "rail"]
    watch.update({"joint1": 0.4999, "rail": 0.0009})     # joint1 within REACHED; rail 0.9 mm
    assert watch.pending() == ["rail"]
    watch.update({"rail": 0.0011})                        # the rail STEP (1 mm) closer
    assert watch.done() and watch.taken == {"joint1": 0.4999, "rail": 0.0011}
    with pytest.raises(ValueError, match="no start position"):
        GoalWatch({"joint1": 0.1}, {})


def test_refusals_as_the_drivers_log_them():
    refusals = [
        "joint_command for ['joint1'] dropped: torque is off (set_torque true first)",
        "joint_command rejected: joint2 position nan is not finite",
        "joint_command dropped: the Dynamixel port is down (no such device)",
        "rail setpoint rejected, nothing sent: rail not homed; call rail/home first",
        "rail fault latched: watchdog PLC tripped (heartbeat lost): the card stopped the rail;"
        " motor killed, setpoints refused until set_torque true",
    ]
    others = ["joint_command clamped to joint limits: ['joint3']", "home complete",
              "FTDI latency_timer is 16 ms", "rail/home refused: torque is off"]
    assert all(is_refusal(t) for t in refusals)
    assert not any(is_refusal(t) for t in others)


def test_missing_joints_in_order():
    required = tuple(LIMITS)
    rng = random.Random(3)
    for _ in range(20):
        seen = rng.sample(required, rng.randint(0, len(required)))
        assert missing_joints(required, seen) == [n for n in required if n not in seen]
    assert missing_joints(required, ["rail"]) == list(required[:-1])


def _fails_as_a_library_does(interrupt: bool):
    """A command that, like rclpy's import during a Ctrl-C, turns the KeyboardInterrupt it
    gets inside C code into an error of its own (ImportError "initialization failed")."""
    import os
    import signal

    def cmd(_args) -> int:
        try:
            if interrupt:
                os.kill(os.getpid(), signal.SIGINT)
            raise ImportError("initialization failed")
        except KeyboardInterrupt:
            raise ImportError("initialization failed") from None
    return cmd


def test_a_ctrl_c_that_a_library_turned_into_its_error_ends_with_130(monkeypatch, capsys):
    """`hyperarm run` interrupted while rclpy's C extension loads: exit 130 (it was a
    traceback and exit 1); the same error without a Ctrl-C is still raised (a real bug)."""
    from hyperarm_bringup import cli

    monkeypatch.setattr(cli, "cmd_run", _fails_as_a_library_does(True))
    assert cli.main(["run", "block_transfer"]) == 130
    assert "hyperarm run: interrupted (ImportError: initialization failed)" in \
        capsys.readouterr().err
    monkeypatch.setattr(cli, "cmd_run", _fails_as_a_library_does(False))
    with pytest.raises(ImportError, match="initialization failed"):
        cli.main(["run", "block_transfer"])
