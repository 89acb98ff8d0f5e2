"""Issue 24 (item 1's invariant, for the task runner): no joint_command the runner streams
steps a joint further in one cycle than its velocity limit × the period, nor leaves its
limits, whatever the goal; the limiter applies last, to the exact command sent. Property
tests: random far goals from random postures (direct), and whole tasks on the mock's
simulation over several seeds (every command recorded; figure8's commands are bounded by
its own joint-step check, test_tracking.py)."""
from __future__ import annotations

import numpy as np
import pytest

from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_tasks.runner import Runner
from hyperarm_tasks.sequence import load_task
from hyperarm_tasks.testing import SimRobot
from hyperarm_tasks.testing import work_cell as cell

pytestmark = [pytest.mark.core]


def _limits(desc) -> dict[str, tuple[float, float, float]]:
    """The arm's joints (the gripper's open/close goals are effort-limited squeezes the
    servo profiles: not limited, see Runner.command)."""
    return {j.name: (j.lower, j.upper, j.velocity) for j in desc.joints}


def _violations(commands, limits, period, resets=()):
    """Commands that step a joint more than velocity × period from that joint's previous
    command (pairs across a hold or a force-control switch in ``resets`` excepted), or
    leave its limits."""
    bad, last = [], {}
    resets = sorted(resets)
    for t, positions, _eff in commands:
        for name, q in positions.items():
            if name not in limits:
                continue
            lo, hi, v = limits[name]
            if not lo - 1e-12 <= q <= hi + 1e-12:
                bad.append((t, name, q, "outside limits"))
            if name in last:
                t0, q0 = last[name]
                if not any(t0 < r <= t for r in resets) and abs(q - q0) > v * period + 1e-9:
                    bad.append((t, name, q - q0, f"step > {v * period:.4f}"))
            last[name] = (t, q)
    return bad


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_far_goals_from_random_postures_are_step_limited(desc, kin, seed):
    rng = np.random.default_rng(seed)
    limits = _limits(desc)
    sim = JointSim(desc, cell(seed))
    robot = SimRobot(sim)
    runner = Runner(robot, kin, load_task("ready", desc))
    names = list(kin.joint_names)
    lo = np.array([limits[n][0] for n in names])
    hi = np.array([limits[n][1] for n in names])
    for _ in range(300):
        if rng.random() < 0.1:
            runner.last_sent.clear()          # as after a hold: from the measured posture
        # far and wild: anywhere within twice the range, NaN-free
        goal = lo - 0.5 * (hi - lo) + rng.random(len(names)) * 2.0 * (hi - lo)
        before = dict(runner.last_sent) or robot.joint_positions()
        sent = runner.command(dict(zip(names, goal.tolist())))
        for i, n in enumerate(names):
            v = limits[n][2]
            assert abs(sent[n] - before[n]) <= v * runner.period + 1e-12, (n, sent[n], before[n])
            assert lo[i] <= sent[n] <= hi[i]
            # and it moves towards the goal as far as it may
            want = np.clip(goal[i], lo[i], hi[i])
            assert abs(sent[n] - want) <= abs(before[n] - want) + 1e-12
        robot.sleep(runner.period)


@pytest.mark.slow
@pytest.mark.parametrize("task, seed", [("block_transfer", 21), ("block_transfer", 22),
                                        ("rest", 24)])
def test_every_command_of_a_task_is_step_limited(desc, kin, task, seed):
    sim = JointSim(desc, cell(seed))
    robot = SimRobot(sim)
    resets: list[float] = []
    hold, force = robot.hold, robot.set_force_control

    def hold_logged():
        resets.append(sim.time)
        return hold()

    def force_logged(enabled):
        resets.append(sim.time)
        return force(enabled)

    robot.hold, robot.set_force_control = hold_logged, force_logged
    runner = Runner(robot, kin, load_task(task, desc))
    result = runner.run()
    assert result.success, result.message
    assert len(robot.commands) > 20
    bad = _violations(robot.commands, _limits(desc), runner.period, resets)
    assert not bad, bad[:10]
