"""Core test of whole-arm compliance (issue 10, the paper's Fig. 4) with the force node's
core in the loop (no rclpy): hyperarm_tasks.testing.ForceSimRobot runs hyperarm_control's
ForceController on the mock's simulation of the shipped ``workcell_post.yaml`` as
hybrid_force runs it. The same scene through the installed executables:
hyperarm_control/test/test_force_e2e.py::test_whole_arm_compliance_closes_around_a_pole."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hyperarm_driver.mock.config import default_workcell_path, load_mock_config
from hyperarm_driver.mock.joint_sim import JointSim
from hyperarm_tasks.perception import matrix_to_quat
from hyperarm_tasks.testing import ForceSimRobot, wrap_postures

pytestmark = [pytest.mark.core, pytest.mark.slow]

# the wrap's goal: soft, leading the tool to the closed posture's tool pose (N/m, N·m/rad)
WRAP_STIFFNESS = [200.0, 200.0, 200.0, 2.0, 2.0, 2.0]
# the node's parameters for the wrap (docs/force.md): every joint current-controlled
WRAP_PARAMS = {"output": "torque", "posture_stiffness": 1.0}


def post_cell(seed: int):
    """The shipped post cell with repeatability 0 (no hidden offsets) and ``seed`` (the
    servos' current model)."""
    cfg = load_mock_config(default_workcell_path().parent / "workcell_post.yaml")
    return dataclasses.replace(cfg, imperfections=dataclasses.replace(
        cfg.imperfections, repeatability=0.0, seed=seed))


def arm_links(sim) -> dict[str, float]:
    """Arm links (capsules link1..link9, not the gripper) touching a pole: force (N)."""
    return {link: float(np.linalg.norm(f)) for link, _, _, f in sim.link_contacts
            if link.startswith("link")}


@pytest.mark.parametrize("seed", [2, 5])
def test_soft_arm_closes_around_the_post_with_three_links(desc, kin, seed):
    """From the open wrap posture (the post inside the open U, nothing touching), force
    control in the torque output, compliance on, the null-space posture the closed wrap
    (inside the post) and the goal leading the tool there in 4 steps of 1 s: the arm ends
    with at least 3 links on the post, every force below 25 N and steady over the last
    second, the controller still active."""
    from hyperarm_control.force.controller import Mode

    cfg = post_cell(seed)
    (post,) = cfg.world.poles
    sim = JointSim(desc, cfg)
    q_open, q_closed = wrap_postures(sim, post)
    robot = ForceSimRobot(sim, kin, output=WRAP_PARAMS["output"],
                          params=dict(WRAP_PARAMS, posture=[float(v) for v in q_closed]))
    arm = list(robot.ctl.arm_names)
    sim.command(arm, [float(v) for v in q_open])
    robot.sleep(3.0)                              # disabled: the mock's position servos move
    idx = [sim.names.index(n) for n in arm]
    assert np.abs(sim.state().position[idx] - q_open).max() < 2e-3
    assert not sim.link_contacts, sim.link_contacts
    assert robot.set_force_control(True) is None
    robot._handle(robot.ctl.set_compliance(True))
    for s in (0.25, 0.5, 0.75, 1.0):
        t = kin.forward(q_open + s * (q_closed - q_open))
        _, event = robot.ctl.on_goal(kin.root_frame, t[:3, 3], matrix_to_quat(t[:3, :3]),
                                     WRAP_STIFFNESS, [False] * 6, [0.0] * 6)
        robot._handle(event)
        robot.sleep(1.0)
    robot.sleep(4.0)
    history = []
    for _ in range(10):
        robot.sleep(0.1)
        history.append(arm_links(sim))
    last = history[-1]
    assert len(last) >= 3, history
    assert max(last.values()) < 25.0, last
    peak_late = max(max(h.values(), default=0.0) for h in history)
    assert peak_late <= 1.05 * max(history[0].values(), default=0.0) + 0.1, history  # steady
    assert robot.ctl.mode is Mode.ACTIVE and robot.passive is None, robot.events
