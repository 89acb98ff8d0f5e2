"""The viewer's scene in-process (no ROS, no browser): a real viser server on a free port;
link nodes posed by forward kinematics (checked against hyperarm_ik's Kinematics), joint
states merged by name and rejected whole when bad, tool path, objects from detections in
camera_link, the wrench arrow."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_bringup.viewer_scene import (ROBOT, RobotScene, SceneConfig, SceneInputError,
                                           ViewerError)
from hyperarm_description.model import load_description
from hyperarm_description.world import load_world
from hyperarm_driver.mock.config import default_workcell_path
from hyperarm_ik.kinematics import Kinematics

pytestmark = pytest.mark.core

ARM = [f"joint{i}" for i in range(1, 10)]


@pytest.fixture(scope="module")
def server():
    import viser

    srv = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def arm_kin():
    return Kinematics(variant="arm")


def _pose_of(handle) -> np.ndarray:
    w, x, y, z = np.asarray(handle.wxyz, dtype=float)
    out = np.eye(4)
    out[:3, :3] = pin.Quaternion(w, x, y, z).toRotationMatrix()
    out[:3, 3] = handle.position
    return out


def test_scene_has_a_node_per_link_with_its_visuals(server):
    scene = RobotScene(server.scene, load_description(None, "arm"))
    assert {"base_link", *(f"link{i}" for i in range(1, 10)), "gripper_finger"} <= set(
        scene.links)
    for name, handle in scene.links.items():
        assert handle.name == f"{ROBOT}/{name}"
    # the visuals of each link are its children: boxes (servos) and cylinders (brackets)
    names = set(server.scene._handle_from_node_name)
    assert f"{ROBOT}/link1/link1_0" in names and f"{ROBOT}/base_link/base_link_0" in names


def test_link_poses_match_forward_kinematics(server, arm_kin):
    scene = RobotScene(server.scene, load_description(None, "arm"))
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = arm_kin.random_configuration(rng)
        scene.set_joints(ARM, q.tolist())
        arm_kin.forward(q)   # updates arm_kin.data for every frame
        pin.updateFramePlacements(arm_kin.model, arm_kin.data)
        for name, handle in scene.links.items():
            if name == "gripper_finger":
                continue  # the gripper is locked out of the IK model
            want = arm_kin.data.oMf[arm_kin.model.getFrameId(name)].homogeneous
            np.testing.assert_allclose(_pose_of(handle), want, atol=1e-9, err_msg=name)
        np.testing.assert_allclose(scene.tool_position(), arm_kin.forward(q)[:3, 3],
                                   atol=1e-12)


def test_rail_and_arm_states_merge_by_name():
    """rail_arm: the rail driver and the arm driver publish their own joints."""
    import viser

    srv = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        kin = Kinematics(variant="rail_arm")
        scene = RobotScene(srv.scene, load_description(None, "rail_arm"))
        q = np.array([0.2, 0.3, -0.2, 0.1, 0.4, 0.0, -0.3, 0.2, 0.1, 0.0])
        scene.set_joints(["rail"], [q[0]])
        scene.set_joints(ARM + ["other_robot_joint"], q[1:].tolist() + [5.0])
        np.testing.assert_allclose(scene.tool_position(), kin.forward(q)[:3, 3], atol=1e-12)
        assert "other_robot_joint" not in scene.joint_positions()
    finally:
        srv.stop()


@pytest.mark.parametrize("names,positions", [
    (ARM, [0.1] * 8 + [float("nan")]),
    (ARM, [0.1] * 8),
    (["joint1", "joint1"], [0.1, 0.2]),
])
def test_a_bad_joint_state_is_rejected_whole(server, names, positions):
    scene = RobotScene(server.scene, load_description(None, "arm"))
    scene.set_joints(ARM, [0.05] * 9)
    before = scene.joint_positions()
    link = _pose_of(scene.links["link5"])
    with pytest.raises(SceneInputError):
        scene.set_joints(names, positions)
    assert scene.joint_positions() == before
    np.testing.assert_array_equal(_pose_of(scene.links["link5"]), link)


def test_tool_path_keeps_recent_positions_spaced_by_min_step(server, arm_kin):
    scene = RobotScene(server.scene, load_description(None, "arm"),
                       config=SceneConfig(path_length=5, path_min_step=0.01))
    for a in np.linspace(0.0, 0.2, 41):  # tool0 moves ~3 mm per step
        scene.set_joints(["joint1"], [a])
    path = scene.tool_path
    assert path.shape == (5, 3)
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert np.all(steps >= 0.01)
    q = np.zeros(9)
    q[0] = 0.2
    assert np.linalg.norm(path[-1] - arm_kin.forward(q)[:3, 3]) < 0.01


def test_detections_in_camera_link_are_drawn_in_the_root_frame(server):
    desc = load_description(None, "arm")
    world = load_world(default_workcell_path())
    scene = RobotScene(server.scene, desc, world, SceneConfig(object_max_age=0.5))
    block = np.eye(4)
    block[:3, 3] = (0.05, -0.02, 0.7)
    scene.set_detections("camera_link", ["block", "source_peg"], [block, np.eye(4)], now=10.0)
    shown = scene.visible_objects()
    np.testing.assert_allclose(shown["block"], (scene.camera_pose @ block)[:3, 3], atol=1e-12)
    assert set(shown) == {"block", "source_peg"}
    scene.set_detections("camera_link", ["block"], [block], now=10.3)
    assert set(scene.visible_objects()) == {"block", "source_peg"}   # peg 0.3 s old: kept
    scene.set_detections("camera_link", ["block"], [block], now=10.6)
    assert set(scene.visible_objects()) == {"block"}                 # peg 0.6 s old: hidden
    scene.expire(11.2)
    assert scene.visible_objects() == {}
    with pytest.raises(SceneInputError, match="frame"):
        scene.set_detections("map", ["block"], [block], now=12.0)
    skew = block.copy()
    skew[0, 0] = 3.0
    with pytest.raises(SceneInputError, match="rigid"):
        scene.set_detections("camera_link", ["block"], [skew], now=12.0)
    assert scene.visible_objects() == {}


def test_wrench_arrow_starts_at_tool0_along_the_force_in_the_root_frame(server):
    desc = load_description(None, "arm")
    scene = RobotScene(server.scene, desc, config=SceneConfig(wrench_scale=0.01))
    scene.set_joints(ARM, [0.3] * 9)
    scene.set_wrench("base_link", [0.0, 0.0, -5.0])
    np.testing.assert_allclose(scene.wrench_force, [0.0, 0.0, -5.0])
    scene.set_wrench("tool0", [1.0, 0.0, 0.0])   # tool0's x axis, in the root frame
    np.testing.assert_allclose(scene.wrench_force, scene.frame_pose("tool0")[:3, 0],
                               atol=1e-12)
    with pytest.raises(SceneInputError):
        scene.set_wrench("camera_link", [1.0, 0.0, 0.0])
    with pytest.raises(SceneInputError):
        scene.set_wrench("base_link", [1.0, float("inf"), 0.0])


def test_config_is_validated():
    with pytest.raises(ViewerError, match="path_length"):
        SceneConfig(path_length=1)
    with pytest.raises(ViewerError, match="wrench_scale"):
        SceneConfig(wrench_scale=float("nan"))


# -- the first view (issue 25 item 6: the control panel hid the outer half of the arm) ----
OLD_CAMERA = ((0.45, -0.85, 0.55), (0.25, 0.0, 0.05))   # the fixed first view before


@pytest.mark.parametrize("variant,cell", [("arm", "workcell.yaml"),
                                          ("rail_arm", "workcell_rail.yaml")])
def test_first_view_shows_arm_and_work_cell_left_of_the_panel(server, variant, cell):
    from hyperarm_bringup.viewer_scene import frame_view, project, visible_box

    world = load_world(default_workcell_path().with_name(cell))
    scene = RobotScene(server.scene, load_description(None, variant), world)
    pts = scene.view_points()
    assert len(pts) >= 12 + 4           # links, tool0, the pegs' feet and tops at least
    position, look_at = frame_view(pts)
    x_lo, x_hi, y_lo, y_hi = visible_box()
    xy = project(pts, position, look_at)
    assert ((xy[:, 0] >= x_lo - 1e-9) & (xy[:, 0] <= x_hi + 1e-9)
            & (xy[:, 1] >= y_lo - 1e-9) & (xy[:, 1] <= y_hi + 1e-9)).all(), xy
    # framed, not merely far away: the points span most of the visible box
    assert np.ptp(xy[:, 0]) > 0.8 * (x_hi - x_lo) or np.ptp(xy[:, 1]) > 0.8 * (y_hi - y_lo)
    if variant == "arm":    # the fixed view before put the outstretched arm under the panel
        old = project(pts, *OLD_CAMERA)
        assert (old[:, 0] > x_hi).any()


@pytest.mark.parametrize("seed", range(4))
def test_frame_view_fits_random_point_clouds(seed):
    from hyperarm_bringup.viewer_scene import frame_view, project, visible_box

    rng = np.random.default_rng(seed)
    x_lo, x_hi, y_lo, y_hi = visible_box()
    for _ in range(10):
        pts = rng.normal(size=(rng.integers(1, 30), 3)) * rng.uniform(0.01, 2.0, size=3)
        direction = rng.normal(size=3)
        direction[2] = -abs(direction[2]) - 0.1          # from above, never straight down
        position, look_at = frame_view(pts, direction=direction)
        xy = project(pts, position, look_at)
        assert np.isfinite(xy).all()
        assert (xy[:, 0] >= x_lo - 1e-6).all() and (xy[:, 0] <= x_hi + 1e-6).all()
        assert (xy[:, 1] >= y_lo - 1e-6).all() and (xy[:, 1] <= y_hi + 1e-6).all()
    with pytest.raises(ViewerError):
        frame_view(np.array([[0.0, 0.0, np.nan]]))


def test_the_viewer_draws_the_packaged_work_cell_by_default(server):
    """workcell_file '' = the cell the mock simulates: table and both pegs are drawn."""
    scene = RobotScene(server.scene, load_description(None, "arm"),
                       load_world(default_workcell_path()))
    names = set(server.scene._handle_from_node_name)
    assert {"/workcell/table", "/workcell/pegs/source", "/workcell/pegs/destination"} <= names
    assert scene.view_points().shape[1] == 3
