"""Forward kinematics, Jacobians and limit helpers (core, no rclpy)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from hyperarm_ik.errors import IKError, InvalidSeedError
from hyperarm_ik.kinematics import Kinematics, rotation_angle

pytestmark = pytest.mark.core


@pytest.fixture(scope="module", params=["arm", "rail_arm"])
def kin(request):
    return Kinematics(variant=request.param)


def test_ready_pose_is_stretched_along_x():
    k = Kinematics()
    t = k.forward(np.zeros(9))
    np.testing.assert_allclose(t[:3, 3], [0.6034, 0.0, 0.1902], atol=1e-12)


def test_fk_matches_the_dh_table(kin):
    import pinocchio as pin
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(kin.lower, kin.upper)
        if kin.variant == "rail_arm":  # world -> carriage (rail) -> mount -> DH chain
            rail = kin.desc.rail
            base = np.eye(4)
            base[:3, :3] = pin.rpy.rpyToMatrix(*rail.mount_rpy)
            base[:3, 3] = np.asarray(rail.axis) * q[0] + np.asarray(rail.mount_xyz)
            expected = base @ kin.desc.dh_forward(q[1:])
        else:
            expected = kin.desc.dh_forward(q)
        np.testing.assert_allclose(kin.forward(q), expected, atol=1e-12)


def test_jacobian_matches_finite_differences(kin):
    rng = np.random.default_rng(1)
    h = 1e-7
    for _ in range(3):
        q = rng.uniform(kin.lower, kin.upper) * 0.9
        j = kin.jacobian(q)
        t0 = kin.forward(q)
        fd = np.zeros((6, kin.nq))
        for i in range(kin.nq):
            dq = q.copy()
            dq[i] += h
            t1 = kin.forward(dq)
            fd[:3, i] = (t1[:3, 3] - t0[:3, 3]) / h
            # angular velocity in the root frame: vee(R1 R0^T - I) / h
            w = t1[:3, :3] @ t0[:3, :3].T
            fd[3:, i] = np.array([w[2, 1] - w[1, 2], w[0, 2] - w[2, 0],
                                  w[1, 0] - w[0, 1]]) / (2 * h)
        np.testing.assert_allclose(j, fd, atol=1e-5)


def test_views_agree_with_copies(kin):
    q = np.linspace(-1.0, 1.0, kin.nq)
    p, r, j = kin.pose_jacobian_view(q)
    t = kin.forward(q)
    np.testing.assert_allclose(p, t[:3, 3])
    np.testing.assert_allclose(r, t[:3, :3])
    np.testing.assert_allclose(j, kin.jacobian(q))


def test_bad_joint_vectors_are_refused():
    k = Kinematics()
    with pytest.raises(InvalidSeedError, match="expected 9 joint values"):
        k.forward(np.zeros(8))
    q = np.zeros(9)
    q[4] = np.nan
    with pytest.raises(IKError, match="joint5"):
        k.jacobian(q)


def test_limits_wrap_and_violations():
    k = Kinematics()
    q = np.zeros(9)
    q[2] = math.radians(151)
    q[7] = -math.radians(170)
    assert k.limit_violations(q) == ["joint3", "joint8"]
    assert not k.within_limits(q)
    assert k.within_limits(k.clip(q))
    w = k.wrap(np.full(9, 2 * math.pi + 0.5))
    np.testing.assert_allclose(w, 0.5)
    np.testing.assert_allclose(k.forward(w), k.forward(np.full(9, 2 * math.pi + 0.5)), atol=1e-12)


def test_reach_bound_is_sound_and_tight(kin):
    rng = np.random.default_rng(2)
    worst = -np.inf
    for _ in range(300):
        p = kin.forward(rng.uniform(kin.lower, kin.upper))[:3, 3]
        worst = max(worst, kin.reach_excess(p))
    assert worst <= 0.0  # reachable points are never declared out of reach
    far = kin.shoulder_origin + np.array([0.0, 0.0, kin.reach + 0.05])
    assert kin.reach_excess(far) == pytest.approx(0.05, abs=1e-9)


def test_rail_extends_the_reach_along_x():
    k = Kinematics(variant="rail_arm")
    p = np.array([1.5 + 0.7, 0.0, 0.05])  # beyond the fixed arm, within rail + arm
    assert k.reach_excess(p) < 0.0
    assert Kinematics().reach_excess(p - np.array([0, 0, 0.05])) > 0.0


def test_rotation_angle_is_accurate_for_small_and_large_angles():
    import pinocchio as pin
    for ang in (1e-9, 1e-5, 0.3, 3.0):
        r = pin.exp3(np.array([0.0, ang, 0.0]))
        assert rotation_angle(np.eye(3), r) == pytest.approx(ang, rel=1e-6)
