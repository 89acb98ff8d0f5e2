"""Core tests of the runner on the mock's simulation (no rclpy): the block transfer and each
way it fails, cancel, retries. Simulated time, so each run takes a few seconds."""
from __future__ import annotations

import numpy as np
import pytest

from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_tasks.runner import Runner
from hyperarm_tasks.sequence import load_task
from hyperarm_tasks.testing import SimRobot, stall_driver
from hyperarm_tasks.testing import work_cell as cell

pytestmark = [pytest.mark.core, pytest.mark.slow]


def run(desc, kin, cfg, task="block_transfer", **robot_kw):
    sim = JointSim(desc, cfg)
    robot = SimRobot(sim, **robot_kw)
    return Runner(robot, kin, load_task(task, desc)).run(), sim, robot


@pytest.mark.parametrize("seed", [11, 12])
def test_block_transfer_moves_the_block_onto_the_destination(desc, kin, seed):
    result, sim, robot = run(desc, kin, cell(seed))
    assert result.success, result.message
    assert sim.world.on_peg("destination")
    names = [s.name for s in load_task("block_transfer", desc).steps]
    assert result.step_names[-5:] == names[-5:]          # a retry repeats a few steps
    assert set(result.step_names) == set(names)
    assert result.metrics["insertion_depth"] >= 0.005
    assert robot.held == 0
    # every move_to a straight line: the first one too, from the singular ready pose (it
    # fell back to joint space in every run, issue 24 item 6)
    fallbacks = [m for _level, m in robot.logs if "falling back" in m]
    assert not fallbacks, fallbacks


def test_block_absent_is_reported(desc, kin):
    sim = JointSim(desc, cell(3))
    robot = SimRobot(sim)
    real = robot.detections.add
    robot.detections.add = lambda stamp, names, poses: real(
        stamp, *zip(*[(n, p) for n, p in zip(names, poses) if n != "block"]))
    result = Runner(robot, kin, load_task("block_transfer", desc)).run()
    assert not result.success
    assert result.failure_kind == "detection"
    assert "object 'block' not seen by the camera" in result.message
    # found missing from the ready pose, before the arm reaches over the source peg
    assert result.message.startswith("step 'locate' (locate) failed"), result.message
    assert robot.held == 1          # safe stop: hold


def test_camera_dropout_is_stale_detections(desc, kin):
    sim = JointSim(desc, cell(4))
    robot = SimRobot(sim)
    robot.sleep(1.0)
    robot.camera_on = False
    result = Runner(robot, kin, load_task("block_transfer", desc)).run()
    assert not result.success and result.failure_kind == "detection"
    assert result.message.startswith("step 'locate' (locate) failed: detections of 'block' "
                                     "are stale"), result.message


@pytest.mark.parametrize("xy", [(0.9, -0.6), (-0.3, -1.0), (1.3, 0.1)])
def test_unreachable_destination_is_refused_before_any_motion(desc, kin, xy):
    """Issue 24, item 6: a destination beyond reach failed only after the block was picked,
    naming an intermediate waypoint. Now every target known at the start is checked first:
    the task fails before any command, naming the target and its distance beyond reach."""
    import re

    result, sim, robot = run(desc, kin, cell(5, destination=xy))
    assert not result.success and result.failure_kind == "unreachable", result.message
    assert result.message.startswith("refused before any motion: target of step "
                                     "'above_destination' (destination_peg + "), result.message
    assert robot.commands == [] and result.step_names == []
    m = re.search(r"at \(([-\d.]+), ([-\d.]+), ([-\d.]+)\) m is ([\d.]+) m beyond the arm's "
                  r"workspace", result.message)
    assert m, result.message
    p = np.array([float(v) for v in m.groups()[:3]])
    assert np.linalg.norm(p[:2] - np.array(xy)) < 0.02        # the peg the camera saw
    assert float(m.group(4)) == pytest.approx(kin.reach_excess(p), abs=1e-3)
    assert float(m.group(4)) > 0.0


def test_a_target_lost_mid_task_says_where_the_block_is_left(desc, kin):
    """The destination's detections jump out of reach after the block is grasped (the
    camera saw it move): the failing step says the block is left in the gripper, where."""
    sim = JointSim(desc, cell(9))
    robot = SimRobot(sim)
    real = robot.detections.add
    runner = Runner(robot, kin, load_task("block_transfer", desc))

    def add(stamp, names, poses):
        if runner.holding is not None:           # grasped: the peg "moves" 1.2 m away
            poses = [p.copy() for p in poses]
            for n, p in zip(names, poses):
                if n == "destination_peg":
                    p[:3, 3] += robot._inv_cam[:3, :3] @ np.array([1.2, 0.0, 0.0])
        real(stamp, names, poses)
    robot.detections.add = add
    result = runner.run()
    assert not result.success
    assert result.message.startswith("step 'above_destination' (move_to) failed"), result.message
    assert "the grasped object is left in the gripper, tool0 at (" in result.message
    assert robot.held >= 1


def test_tiny_clearance_fails_the_insertion_with_best_depth(desc, kin):
    """0.05 mm of clearance: the hole accepts the peg only within 3.3 mrad of tilt over the
    block's 3 cm (docs/mock.md), less than the arm's repeatability achieves."""
    result, sim, robot = run(desc, kin, cell(6, hole_radius=0.008 + 0.00005))
    assert not result.success and result.failure_kind == "insertion"
    assert "insertion not achieved in 30 s (best depth" in result.message
    assert result.step_names.count("insert") == 2      # retried once with a new pattern
    assert not sim.world.on_peg("destination")


def test_cancel_mid_insertion_holds(desc, kin):
    # the insertion starts ~13 s into the task (simulated) and cannot thread (0.05 mm of
    # clearance) for its 30 s: cancel inside it
    result, sim, robot = run(desc, kin, cell(7, hole_radius=0.008 + 0.00005), cancel_at=24.0)
    assert not result.success
    assert result.message == "cancelled during insert"
    assert robot.held == 1
    t_cancel = sim.time
    n = len(robot.commands)
    robot.sleep(0.5)
    assert len(robot.commands) == n and t_cancel >= 24.0   # nothing commanded after


@pytest.mark.parametrize("last", ["ready", "above_source", "open"])
def test_a_cancel_as_a_step_ends_starts_no_next_step(desc, kin, monkeypatch, last):
    """Issue 24, 2: a cancel that arrives after a step's last look at it (here: the moment
    the step returns) must not let the next step start (it did: 'cancelled during' the next
    one, after its log line and its first commands)."""
    from hyperarm_tasks import steps as steps_mod

    task = load_task("block_transfer", desc)
    names = [s.name for s in task.steps]
    after = names[names.index(last) + 1]
    sim = JointSim(desc, cell(13))
    robot = SimRobot(sim)
    ran = {}

    def wrap(kind):
        inner = steps_mod.STEP_TYPES[kind]

        class Wrapped:
            @staticmethod
            def run(step, ctx):
                inner.run(step, ctx)
                if step.name == last:        # the cancel comes just as it ends
                    robot.cancel_at = sim.time
                    ran["t"], ran["n"] = sim.time, len(robot.commands)
        return Wrapped

    for kind in list(steps_mod.STEP_TYPES):
        monkeypatch.setitem(steps_mod.STEP_TYPES, kind, wrap(kind))
    result = Runner(robot, kin, task).run()
    assert not result.success and result.failure_kind == "cancelled"
    assert result.message == f"cancelled before {after}"
    assert not [m for _lvl, m in robot.logs if f" {after} (" in m], robot.logs
    assert len(robot.commands) == ran["n"]        # nothing commanded after the cancel
    assert robot.held == 1                        # and the arm holds
    assert result.step_names[-1] == last


def test_ready_and_rest(desc, kin):
    result, sim, _ = run(desc, kin, cell(1), task="rest")
    assert result.success, result.message
    assert sim.position[1] == pytest.approx(np.pi / 2, abs=0.02)
    result, sim, _ = run(desc, kin, cell(1), task="ready")
    assert result.success, result.message


def test_grasp_missed_is_retried_then_reported(desc, kin):
    sim = JointSim(desc, cell(8))
    robot = SimRobot(sim)
    wrong = np.eye(4)
    wrong[:3, 3] = (0.35, 0.16, -0.185)          # 4 cm beside the block: nothing to grasp
    robot.given["block"] = wrong
    result = Runner(robot, kin, load_task("block_transfer", desc)).run()
    assert not result.success and result.failure_kind == "grasp"
    assert "step 'close' (gripper) failed: grasp missed" in result.message
    assert result.step_names.count("close") == 2             # re-grasped once
    assert sim.world.on_peg("source")


class _StallOnClose(SimRobot):
    """The joint_states stream stalls for ``stall`` s (the simulation goes on) from the
    first gripper close: positions and efforts stay those of its start, their age grows,
    as the runner sees it when a node is not scheduled or the driver stops publishing."""

    def __init__(self, sim, stall: float) -> None:
        super().__init__(sim)
        self.stall, self.frozen = stall, None      # (start, positions, efforts)
        self.stalled = False

    def command(self, positions, efforts=None):
        g = self.sim.desc.gripper
        if not self.stalled and list(positions) == [g.name] and positions[g.name] == g.lower:
            self.stalled = True
            self.frozen = (self.sim.time, super().joint_positions(), super().joint_efforts())
        return super().command(positions, efforts)

    def _live(self) -> bool:
        return self.frozen is None or self.sim.time >= self.frozen[0] + self.stall

    def joint_positions(self):
        return super().joint_positions() if self._live() else dict(self.frozen[1])

    def joint_efforts(self):
        return super().joint_efforts() if self._live() else dict(self.frozen[2])

    def joint_states_age(self) -> float:
        return 0.0 if self._live() else self.sim.time - self.frozen[0]


def test_a_state_stall_while_closing_is_not_a_stopped_gripper(desc, kin):
    """A close "settles" when the gripper stops moving; with no new joint_states the
    positions do not move either. Seen in a soak on a loaded machine: the close ended on
    1 s of frozen states with the gripper still open, reported "grasp missed" though the
    mock had grasped, and its retry carried the block off the peg and dropped it. States
    that do not arrive are no evidence that the gripper stopped: the close waits for them."""
    sim = JointSim(desc, cell(5))
    robot = _StallOnClose(sim, stall=0.8)
    result = Runner(robot, kin, load_task("block_transfer", desc)).run()
    assert robot.stalled
    assert result.success, result.message
    assert result.step_names.count("close") == 1           # no retry
    assert sim.world.on_peg("destination")


class _SometimesLate(SimRobot):
    """Every third look at the joint_states finds them 80 ms old (a loaded machine: the
    states come, late now and then), the positions still the present ones."""

    def __init__(self, sim) -> None:
        super().__init__(sim)
        self.looks = 0

    def joint_states_age(self) -> float:
        self.looks += 1
        return 0.08 if self.looks % 3 == 0 else 0.0


def test_late_states_now_and_then_do_not_keep_a_close_from_ending(desc, kin):
    """Stillness is counted over fresh states only, but a late one does not restart the
    count: restarted at each late look, a close never reached its 0.3 s and timed out
    with the block grasped (seen once through run_task.sh with a recording on)."""
    sim = JointSim(desc, cell(5))
    robot = _SometimesLate(sim)
    result = Runner(robot, kin, load_task("block_transfer", desc)).run()
    assert robot.looks > 0
    assert result.success, result.message
    assert result.step_names.count("close") == 1


def test_grasp_lost_while_carrying(desc, kin):
    sim = JointSim(desc, cell(9))
    robot = SimRobot(sim)
    # the gripper servo overloads during the lift (8.4-10.7 s in): it drops its torque
    robot.at_time.append((9.5, lambda s: s.inject_error("gripper", "overload")))
    result = Runner(robot, kin, load_task("block_transfer", desc)).run()
    assert not result.success
    assert any("grasp lost" in m for _lvl, m in robot.logs), robot.logs
    # the retry (open, clear the peg, back to ready, locate again, re-grasp) cannot open a
    # gripper in fault: the driver's reason, after the failure it was to recover from
    assert result.failure_kind == "driver"
    assert result.message.startswith("step 'lift' (move_to) failed: grasp lost: "), \
        result.message
    assert result.message.endswith("; clearing for the retry failed: driver refused: "
                                   "hardware error gripper: overload"), result.message


def test_torque_off_and_joint_fault_fail_with_the_drivers_reason(desc, kin):
    sim = JointSim(desc, cell(1))
    sim.set_torque(False)
    robot = SimRobot(sim)
    result = Runner(robot, kin, load_task("rest", desc)).run()
    assert not result.success and result.failure_kind == "driver"
    assert "driver refused: torque off on gripper" in result.message
    sim = JointSim(desc, cell(1))
    sim.inject_error("joint5", "overload")
    result = Runner(SimRobot(sim), kin, load_task("ready", desc)).run()
    assert not result.success and result.failure_kind == "driver"
    assert "hardware error joint5: overload" in result.message


def test_first_moves_from_the_ready_pose_are_mostly_straight(desc, kin):
    """Issue 24 item 6's neighbourhood: move_to lines from the singular ready pose to 12
    random "down" targets over the table (seeded). Slerped at a uniform rate along the
    whole line, 16 of 20 such lines fell back to joint space (the turn about the stretched
    arm's own axis is outside the Jacobian's range until the arm has bent); turned over the
    line's last 70 %, 2-4 of 20 in three seeds. At most a quarter may fall back here."""
    from hyperarm_tasks.perception import DOWN

    rng = np.random.default_rng(24)
    fallbacks = []
    for i in range(12):
        robot = SimRobot(JointSim(desc, cell(11)))
        runner = Runner(robot, kin, load_task("block_transfer", desc))
        target = np.eye(4)
        target[:3, :3] = DOWN
        target[:3, 3] = [rng.uniform(0.28, 0.5), rng.uniform(-0.2, 0.2), rng.uniform(-0.1, 0.05)]
        qs, _ = runner.plan_line(target, 0.005, True, f"line {i}")
        fallbacks += [m for _level, m in robot.logs if "falling back" in m]
        if not any("falling back" in m for _level, m in robot.logs):
            assert len(qs) > 2               # a straight line: IK at every point
    assert len(fallbacks) <= 3, "\n".join(fallbacks)


def test_a_plan_does_not_depend_on_a_preempted_wall_clock(desc, kin, monkeypatch):
    """The runner's IK counts its timeouts in CPU time: with every read of the wall clock a
    second later than the last (a process preempted again and again on a loaded machine),
    lines from the ready pose to random "down" targets are planned exactly as on a calm
    machine (with wall-clock deadlines every waypoint's solve was cut: joint space)."""
    import time

    from hyperarm_tasks.perception import DOWN

    rng = np.random.default_rng(5)
    targets = []
    for _ in range(4):
        target = np.eye(4)
        target[:3, :3] = DOWN
        target[:3, 3] = [rng.uniform(0.28, 0.5), rng.uniform(-0.2, 0.2), rng.uniform(-0.1, 0.05)]
        targets.append(target)

    def plans():
        out = []
        for i, target in enumerate(targets):
            robot = SimRobot(JointSim(desc, cell(11)))
            runner = Runner(robot, kin, load_task("block_transfer", desc))
            qs, _ = runner.plan_line(target, 0.005, True, f"line {i}")
            out.append((np.array(qs), [m for _lv, m in robot.logs if "falling back" in m]))
        return out

    calm = plans()
    real, jumps = time.perf_counter, iter(range(10 ** 9))
    monkeypatch.setattr(time, "perf_counter", lambda: real() + 1.0 * next(jumps))
    preempted = plans()
    monkeypatch.undo()
    for (qa, fa), (qb, fb) in zip(calm, preempted):
        assert fa == fb and qa.shape == qb.shape and np.array_equal(qa, qb), (fa, fb)
    assert any(len(qa) > 2 for qa, _ in calm)       # straight lines were planned at all


def _move_over_source(desc, tmp_path, extra: str = ""):
    """A task of one move_to from the ready pose to 5 cm above the source peg (~14 s)."""
    from hyperarm_tasks.sequence import load_task_file
    path = tmp_path / "move.yaml"
    path.write_text("schema_version: 1\nobjects: [source_peg]\nsteps:\n"
                    "  - {name: over, type: move_to, target: {relative_to: source_peg, "
                    f"offset: [0, 0, 5 cm]}}, speed: 5 cm/s{extra}}}\n")
    return load_task_file(path, desc)


def test_a_stalled_driver_holds_a_streamed_move(desc, kin, tmp_path):
    # a move_to through stalls of the driver: the goal it applies after each continues
    # where it stopped (the stream's clock is taken back to the driver's last
    # joint_states), not 0.05 s of the path further on
    robot = SimRobot(JointSim(desc, cell(11)))
    applied = []
    stall_driver(robot, lambda positions: applied.append(
        (robot.now(), np.array([positions[n] for n in sorted(positions)]))))
    result = Runner(robot, kin, _move_over_source(desc, tmp_path)).run()
    assert result.success, result.message
    steps = [(t1 - t0, float(np.abs(q1 - q0).max()))
             for (t0, q0), (t1, q1) in zip(applied, applied[1:])]
    # each first goal after a stall against the stream's steps just before it: no larger
    # than 2.5 of them (the tick before the driver's last joint_states and the resuming
    # tick's 1.5 periods); without the rewind, the 0.05 s it took to see the stall
    gaps = [(d, max(dd for _dt, dd in steps[k - 5:k])) for k, (dt, d) in enumerate(steps)
            if dt > 0.2 and k >= 5]
    assert len(gaps) >= 4, steps
    assert all(d <= 2.5 * before + 1e-6 for d, before in gaps), gaps


def test_joint_states_that_stop_fail_a_streamed_move(desc, kin, tmp_path):
    robot = SimRobot(JointSim(desc, cell(11)))
    stall_driver(robot, stop_at=2.0)
    result = Runner(robot, kin, _move_over_source(desc, tmp_path, ", timeout: 60 s")).run()
    assert not result.success and result.failure_kind == "driver", result.message
    assert "no joint_states for 5.0 s while moving" in result.message
    assert result.total_time < 2.0 + 5.0 + 1.0
