"""Core tests of objects the arm hides from the camera (issue 27: a fixed camera above the
cell cannot see the block or a peg's tile once the hand is over it): the ``locate`` step,
the runner's located poses (:meth:`Runner.object_pose`), what forgets them (a gripper
closing or opening near the object, ``located_max_age``) and what overrides them (fresh
sightings). ``SimRobot.hand_hides`` models the occlusion: an object is not detected while
tool0 is over it."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_tasks.errors import StepFailed
from hyperarm_tasks.perception import camera_pose
from hyperarm_tasks.runner import Located, Runner, RunnerParams
from hyperarm_tasks.errors import TaskError
from hyperarm_tasks.sequence import load_task, load_task_file
from hyperarm_tasks.testing import ForceSimRobot, SimRobot
from hyperarm_tasks.testing import work_cell as cell

pytestmark = [pytest.mark.core]

HAND = 0.06     # m: the hand hides what lies within 6 cm of tool0 (horizontally), below it


def _markers() -> dict[str, list[np.ndarray]]:
    """The packaged marker map's marker centres per object (what the camera must see)."""
    from hyperarm_perception.markers import load_marker_map
    out: dict[str, list[np.ndarray]] = {}
    for m in load_marker_map().markers.values():
        out.setdefault(m.object, []).append(m.offset[:3, 3].copy())
    return out


def _transfer(desc, kin, seed: int, **params):
    sim = JointSim(desc, cell(seed))
    robot = ForceSimRobot(sim, kin)
    robot.hand_hides = HAND
    robot.hide_points = _markers()
    runner = Runner(robot, kin, load_task("block_transfer", desc), RunnerParams(**params))
    return runner.run(), sim, robot, runner


@pytest.mark.slow
def test_a_grasp_lost_mid_lift_clears_straight_up_from_where_the_arm_is(desc, kin):
    """The grasp judged lost partway up the lift (its effort ratio raised mid-stream): the
    clearing rises 10 cm from where the arm is, never back down towards the block (the
    last finished move's target, down_to_block's, was behind the arm)."""
    import dataclasses
    sim = JointSim(desc, cell(3))
    robot = ForceSimRobot(sim, kin)
    runner = Runner(robot, kin, load_task("block_transfer", desc))
    zs: list[tuple[float, float]] = []
    robot.at_time = [(t, lambda s: zs.append((s.time, s.tool_pose()[2, 3])))
                     for t in np.arange(0.5, 40, 0.02)]
    lifting = {}
    real_tick = runner.tick

    def tick(joints=()):
        if runner.step is not None and runner.step.name == "lift" and "at" not in lifting \
                and sim.tool_pose()[2, 3] > -0.16:            # 2.5 cm up the lift
            lifting["at"] = sim.time
            runner.params = dataclasses.replace(runner.params, grasp_min_effort_ratio=50.0)
        return real_tick(joints)

    runner.tick = tick
    clears = []
    real_clear = runner.clear_for_retry

    def clear(distance):
        t0, z0 = sim.time, sim.tool_pose()[2, 3]
        runner.params = dataclasses.replace(runner.params, grasp_min_effort_ratio=0.5)
        real_clear(distance)
        clears.append((t0, z0, sim.time, sim.tool_pose()[2, 3]))

    runner.clear_for_retry = clear
    result = runner.run()
    assert "at" in lifting, "the lift never got 2.5 cm up"
    assert any("grasp lost" in t for _, t in robot.logs), robot.logs
    assert len(clears) == 1, (clears, result.message)
    t0, z0, t1, z1 = clears[0]
    during = [z for t, z in zs if t0 <= t <= t1]
    assert during and min(during) > z0 - 0.003, (z0, min(during))     # never back down
    assert z1 > z0 + 0.095, (z0, z1)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 17])
def test_block_transfer_with_a_camera_the_hand_hides_uses_the_located_poses(desc, kin, seed):
    result, sim, robot, runner = _transfer(desc, kin, seed)
    assert result.success, result.message
    assert sim.world.on_peg("destination")
    assert robot.hidden_frames > 20            # the hand did hide things from the camera
    assert result.metrics["located_used"] >= 1     # down_to_block: the tab under the hand
    used = [t for lvl, t in robot.logs if "not in view now" in t]
    assert any(t.startswith("block not in view now") for t in used), used
    # the close forgot the block's located pose: it is never used after the close
    texts = [t for _, t in robot.logs]
    closed = texts.index("close: block may move now; only fresh sightings place it again")
    assert not any(t.startswith("block not in view now") for t in texts[closed:]), texts
    assert "block" not in runner.located and runner.held_objects == set()
    # nothing else was forgotten: the open above the source peg touches nothing
    assert not any("peg may move now" in t for t in texts), texts


@pytest.mark.slow
def test_a_grasp_judged_missed_clears_the_peg_before_the_retry_goes_back(desc, kin):
    """The fingers around the block, the grasp judged missed (here: an effort ratio no grasp
    reaches): the retry opens the gripper, moves the tool straight up 10 cm (the fingers
    clear the peg's top) before the joint-space move to ready, locates the block again and
    fails the second close the same way; the block never leaves its place on the peg (the
    task's failure then holds the fingers closed on it, as any failure keeps a grip)."""
    sim = JointSim(desc, cell(3))
    robot = ForceSimRobot(sim, kin)
    robot.hand_hides = HAND
    robot.hide_points = _markers()
    start = sim.truth()["block"][:3, 3].copy()
    where = []
    robot.at_time = [(t, lambda s: where.append(s.truth()["block"][:3, 3].copy()))
                     for t in np.arange(1, 40, 0.25)]
    runner = Runner(robot, kin, load_task("block_transfer", desc),
                    RunnerParams(grasp_min_effort_ratio=50.0))
    closes = []
    orig = runner.move_joint_goal

    def spy(goal, *args, **kw):     # where the tool is at every gripper goal
        if desc.gripper.name in goal:
            closes.append((goal[desc.gripper.name], runner.tool_measured()[2, 3]))
        return orig(goal, *args, **kw)

    runner.move_joint_goal = spy
    result = runner.run()
    assert not result.success and result.failure_kind == "grasp", result.message
    assert "step 'close' (gripper) failed: grasp missed" in result.message
    assert result.step_names.count("close") == 2 and result.step_names.count("locate") == 2
    assert any("the gripper opened and the tool 10 cm up first" in t for _, t in robot.logs)
    assert len(where) > 60                        # 1-21 s of the run, every 0.25 s
    drift = np.abs(np.array(where) - start).max(axis=0)
    assert drift.max() < 0.003, drift             # never dragged off or up the peg
    # the tool rose 10 cm from where the first close left it before ready's joint move
    k = [g for g, _ in closes].index(desc.gripper.lower)      # the first close
    first_close_z = closes[k][1]
    opened, z_open = closes[k + 1]                             # the open to clear
    assert opened == desc.gripper.upper and abs(z_open - first_close_z) < 0.005, closes
    z_after = [z for _, z in closes[k + 2:]]                   # ready's goal, then the rest
    assert z_after and z_after[0] > first_close_z + 0.095, (first_close_z, closes)


@pytest.mark.slow
def test_without_located_poses_the_hidden_block_is_not_seen(desc, kin):
    """located_max_age 0 (fresh sightings only): the step that reaches for the hidden block
    fails, naming it (what the rendered camera did before the locate step)."""
    result, _, robot, _ = _transfer(desc, kin, 3, located_max_age=0.0)
    assert not result.success and result.failure_kind == "detection", result.message
    assert "'down_to_block'" in result.message, result.message
    assert "detections of 'block' are stale" in result.message, result.message


def parse_task(data: dict, desc, name: str, tmp_path):
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return load_task_file(path, desc)


def _hide(robot, *names: str) -> None:
    """The camera goes on seeing everything but ``names`` (the arm over them)."""
    real = robot.detections.add
    robot.detections.add = lambda stamp, seen, poses: real(
        stamp, *(zip(*kept) if (kept := [(n, p) for n, p in zip(seen, poses)
                                          if n not in names]) else ([], [])))


def _still(desc, kin, tmp_path, **params):
    """A runner whose arm stays at rest (the camera sees everything unless turned off)."""
    sim = JointSim(desc, cell(5))
    robot = SimRobot(sim)
    task = parse_task({"schema_version": 1, "objects": ["block", "source_peg"],
                       "steps": [{"name": "look", "type": "locate"}]}, desc, "look", tmp_path)
    return Runner(robot, kin, task, RunnerParams(**params)), robot, sim


def test_locate_keeps_each_objects_pose_and_a_hidden_object_uses_it(desc, kin, tmp_path):
    runner, robot, sim = _still(desc, kin, tmp_path, located_max_age=2.0)
    result = runner.run()
    assert result.success, result.message
    truth = sim.truth()
    for name in ("block", "source_peg"):
        np.testing.assert_allclose(runner.located[name].pose[:3, 3], truth[name][:3, 3],
                                   atol=0.005)
    assert any("look: block located at" in t for _, t in robot.logs)
    _hide(robot, "block")
    robot.sleep(1.5)            # the sightings go stale, the located pose is 1.5 s old
    pose = runner.object_pose("block")
    np.testing.assert_allclose(pose, runner.located["block"].pose)
    assert runner.metrics["located_used"] == 1.0
    robot.sleep(0.6)            # now older than located_max_age: only fresh sightings count
    runner.params = RunnerParams(located_max_age=2.0, detection_timeout=0.3)
    with pytest.raises(StepFailed) as exc:
        runner.object_pose("block")
    assert exc.value.kind == "detection" and "'block'" in str(exc.value)


def test_locate_skips_objects_given_with_the_goal(desc, kin, tmp_path):
    """An object whose pose comes with the goal is not looked for (the camera need not see
    it: here it sees nothing of it) and the given pose is what the runner uses."""
    runner, robot, sim = _still(desc, kin, tmp_path)
    given = np.eye(4)
    given[:3, 3] = [0.3, 0.2, -0.185]
    robot.given["block"] = given
    real = robot.detections.add
    robot.detections.add = lambda stamp, names, poses: real(
        stamp, *zip(*[(n, p) for n, p in zip(names, poses) if n != "block"]))
    result = runner.run()
    assert result.success, result.message
    assert sorted(runner.located) == ["source_peg"]
    assert not any("block located" in t for _, t in robot.logs)
    np.testing.assert_allclose(runner.object_pose("block"), given)


def test_fresh_sightings_override_a_located_pose(desc, kin, tmp_path):
    """An object moved since it was located (by hand, or bumped) is where the camera sees
    it now, not where it was located."""
    runner, robot, sim = _still(desc, kin, tmp_path)
    wrong = np.eye(4)
    wrong[:3, 3] = [0.1, 0.3, -0.1]
    runner.located["block"] = Located(robot.now(), wrong)
    robot.sleep(1.0)            # fresh frames of the block where it really is
    pose = runner.object_pose("block")
    np.testing.assert_allclose(pose[:3, 3], sim.truth()["block"][:3, 3], atol=0.005)
    np.testing.assert_allclose(runner.located["block"].pose, pose)   # and located anew
    assert "located_used" not in runner.metrics


def test_a_held_object_is_never_located(desc, kin, tmp_path):
    """While held, fresh sightings of the object are used but not kept as its located pose,
    and an old located pose is not used: it moves with the hand."""
    runner, robot, sim = _still(desc, kin, tmp_path, detection_timeout=0.3)
    robot.sleep(1.0)
    runner.held_objects = {"block"}
    pose = runner.object_pose("block")
    np.testing.assert_allclose(pose[:3, 3], sim.truth()["block"][:3, 3], atol=0.005)
    assert "block" not in runner.located
    runner.located["block"] = Located(robot.now(), pose)     # (as if located before)
    _hide(robot, "block")
    robot.sleep(1.5)
    with pytest.raises(StepFailed, match="detections of 'block' are stale"):
        runner.object_pose("block")
    assert "located_used" not in runner.metrics


def test_newer_sightings_away_from_the_located_pose_are_waited_for(desc, kin, tmp_path):
    """Two frames (fewer than detection_frames) show the block 2 cm from where it was
    located: it moved, so its located pose is not used; the runner waits for enough fresh
    sightings and takes them."""
    runner, robot, sim = _still(desc, kin, tmp_path)
    robot.sleep(1.0)
    robot.detections.clear()
    where = sim.truth()["block"].copy()
    where[0, 3] += 0.02
    runner.located["block"] = Located(robot.now(), where)
    robot.sleep(0.25)                    # 2-3 frames of the block where it really is
    assert len(robot.detections.since("block", runner.located["block"].stamp)) < 5
    pose = runner.object_pose("block")
    np.testing.assert_allclose(pose[:3, 3], sim.truth()["block"][:3, 3], atol=0.005)
    assert "located_used" not in runner.metrics
    said = [t for _, t in robot.logs if t.startswith("block: seen ")]
    assert len(said) == 1 and said[0].endswith("waiting for fresh sightings"), robot.logs
    assert 15 <= int(said[0].split(" mm from there")[0].split()[-1]) <= 25, said  # 2 cm


def test_one_stray_sighting_does_not_say_the_object_moved(desc, kin, tmp_path):
    """One sighting 2 cm off since the object was located (a marker half under the hand
    gives such; it failed a rendered soak cycle when it counted), then none: the located
    pose is used."""
    runner, robot, sim = _still(desc, kin, tmp_path)
    robot.sleep(1.0)
    runner.object_pose("block")              # located from fresh sightings
    loc = runner.located["block"]
    _hide(robot, "block")
    robot.sleep(1.5)
    stray = loc.pose.copy()
    stray[0, 3] += 0.02
    robot.detections.add(robot.now() - 0.1, ["block"],
                         [np.linalg.inv(camera_pose(desc)) @ stray])
    np.testing.assert_allclose(runner.object_pose("block"), loc.pose)
    assert runner.metrics["located_used"] == 1.0


def test_a_camera_that_sees_nothing_is_failing_not_hidden(desc, kin, tmp_path):
    """No object in any frame for more than detection_max_age (a dead or covered camera,
    the mock's camera dropout): located poses are not used, said in a warning, and the
    step fails on stale detections (before this rule a whole block transfer ran on them)."""
    runner, robot, sim = _still(desc, kin, tmp_path, detection_timeout=0.3)
    assert runner.run().success
    robot.camera_on = False
    robot.sleep(1.2)
    with pytest.raises(StepFailed, match="detections of 'block' are stale"):
        runner.object_pose("block")
    assert any(lvl == "warn" and "the camera has seen no object" in t
               for lvl, t in robot.logs), robot.logs
    assert "located_used" not in runner.metrics


def test_located_max_age_zero_never_uses_a_located_pose(desc, kin, tmp_path):
    runner, robot, sim = _still(desc, kin, tmp_path, located_max_age=0.0,
                                detection_timeout=0.3)
    runner.located["block"] = Located(robot.now(), sim.truth()["block"])
    _hide(robot, "block")
    with pytest.raises(StepFailed):
        runner.object_pose("block")


def test_touch_forgets_only_what_lies_within_the_radius(desc, kin, tmp_path):
    runner, robot, _ = _still(desc, kin, tmp_path)
    for name, xyz in (("block", [0.35, 0.12, -0.185]), ("source_peg", [0.35, 0.12, -0.12]),
                      ("destination_peg", [0.35, -0.12, -0.12])):
        pose = np.eye(4)
        pose[:3, 3] = xyz
        runner.located[name] = Located(0.0, pose)
    # the fingers around the block's centre: the block, not its peg's top 6.5 cm above it
    assert runner.touch(np.array([0.35, 0.12, -0.185])) == ["block"]
    assert sorted(runner.located) == ["destination_peg", "source_peg"]
    assert runner.touch(np.array([0.0, 0.0, 0.3])) == []
    assert runner.touched_at == {"block": robot.now()}
    # the tool's position unknown (no joint_states): everything located is forgotten
    assert sorted(runner.touch(None)) == ["destination_peg", "source_peg"]
    assert runner.located == {}


def test_locate_step_fields_are_checked(desc, tmp_path):
    def bad(step):
        with pytest.raises(TaskError) as exc:
            parse_task({"schema_version": 1, "objects": ["block"], "steps": [step]}, desc,
                       "t", tmp_path)
        return str(exc.value)

    assert "unknown object 'peg'" in bad({"name": "l", "type": "locate", "objects": ["peg"]})
    assert "objects" in bad({"name": "l", "type": "locate", "objects": []})
    assert "objects" in bad({"name": "l", "type": "locate", "objects": "block"})
    with pytest.raises(TaskError) as exc:
        parse_task({"schema_version": 1, "steps": [{"name": "l", "type": "locate"}]}, desc,
                   "t", tmp_path)
    assert "the task declares none" in str(exc.value)


def test_an_extending_task_renames_the_objects_it_locates(desc):
    there = load_task("block_transfer", desc)
    back = load_task("block_transfer_back", desc)
    look = [s for s in there.steps if s.type == "locate"]
    look_back = [s for s in back.steps if s.type == "locate"]
    assert look[0].objects == ("block", "source_peg", "destination_peg")
    assert look_back[0].objects == ("block", "destination_peg", "source_peg")


def test_located_max_age_must_not_be_negative():
    with pytest.raises(ValueError, match="located_max_age"):
        RunnerParams(located_max_age=-1.0)
