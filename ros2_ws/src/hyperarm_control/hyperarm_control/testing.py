"""Test support for the controllers, without ROS: geometry and set-ups shared by the core
and end-to-end tests of hyperarm_control (and of the packages above it).

- :func:`wrap_postures`: the open and closed whole-arm wrap postures around a pole, for the
  force controller's whole-arm compliance tests (docs/force.md).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hyperarm_description.world import PoleSpec

if TYPE_CHECKING:
    from hyperarm_driver.mock.joint_sim import JointSim

__all__ = ["wrap_postures"]


def wrap_postures(sim: JointSim, pole: PoleSpec, open_bend: float = 0.5,
                  closed_bend: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Arm joint angles (rad, joint1..9) of an open and a closed wrap around the vertical
    ``pole`` (a :class:`~hyperarm_description.world.PoleSpec`; the scene of
    ``workcell_post.yaml`` and of the whole-arm compliance tests).

    The flat arm (pitch joints 2, 4, 6, 8 at 0) bent by 90° at the yaw joints 5 and 7 is a U:
    link3-link4, then link5-link6 (17 cm between joints 5 and 7), then link7 and the
    upright link9. The U's inside, 8.3 cm from either side and 7.5 cm back from joint 5,
    holds a post of about 55 mm radius. joint1 aims that point at the pole (its distance
    from the base must match the pole's, within 3 mm: else ValueError). The open posture
    bends joints 5 and 7 by ``open_bend``, the closed one by ``closed_bend`` (inside the
    pole). Arm variant only (ValueError on rail_arm)."""
    import pinocchio as pin

    def bent(bend: float, joint1: float) -> np.ndarray:
        q = np.zeros(9)
        q[0], q[4], q[6] = joint1, bend, bend
        return q
    if sim.rail:
        raise ValueError("wrap_postures: the arm variant only")
    m = sim.model
    d = m.createData()
    pin.forwardKinematics(m, d, np.r_[bent(np.pi / 2, 0.0), np.zeros(m.nq - 9)])
    at = {m.names[i]: d.oMi[i].translation for i in range(1, m.njoints)}
    d4 = at["joint5"] - at["joint4"]
    d56 = at["joint7"] - at["joint5"]
    p = at["joint5"] + 0.083 * d56 / np.linalg.norm(d56) - 0.075 * d4 / np.linalg.norm(d4)
    xy = np.asarray(pole.xy, dtype=float)
    if abs(np.linalg.norm(p[:2]) - np.linalg.norm(xy)) > 0.003:
        raise ValueError(f"the U's inside is {np.linalg.norm(p[:2]):.3f} m from the base, "
                         f"the pole {np.linalg.norm(xy):.3f} m")
    joint1 = float(np.arctan2(xy[1], xy[0]) - np.arctan2(p[1], p[0]))
    return bent(open_bend, joint1), bent(closed_bend, joint1)
