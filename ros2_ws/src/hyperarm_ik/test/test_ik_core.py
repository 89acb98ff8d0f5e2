"""The IK service's ROS-free logic: frames, quaternions, seeds, options, solver choice."""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from hyperarm_ik.errors import (FrameError, InvalidOptionError, InvalidSeedError,
                                InvalidTargetError, UnknownSolverError,
                                UnsupportedVariantError)
from hyperarm_ik.ik_core import IKCore, IKDefaults, IKPool, IKRequest
from hyperarm_ik.kinematics import Kinematics

pytestmark = pytest.mark.core

ARM = Kinematics()


def _request(q=None, kin=ARM, frame=None, **kw) -> IKRequest:
    q = np.full(kin.nq, 0.25) if q is None else q
    t = kin.forward(q)
    quat = pin.Quaternion(t[:3, :3])
    return IKRequest(frame_id=frame if frame is not None else kin.root_frame,
                     position=tuple(t[:3, 3]), orientation=(quat.x, quat.y, quat.z, quat.w),
                     **kw)


@pytest.fixture
def core():
    return IKCore(ARM)


def test_good_request_is_solved_with_defaults(core):
    result, source = core.solve(_request())
    assert result.success, result.message
    assert source == "ready pose q = 0"
    assert result.position_error <= core.defaults.position_tolerance
    assert result.orientation_error <= core.defaults.orientation_tolerance


def test_seed_from_request_then_joint_states_then_zero(core):
    q = np.linspace(-0.5, 0.5, 9)
    req = _request(seed_names=list(reversed(ARM.joint_names)) + ["gripper"],
                   seed_positions=list(reversed(q)) + [0.3])
    seed, source = core.seed(req)
    np.testing.assert_allclose(seed, q)
    assert source == "request"
    core.joint_states.update(ARM.joint_names[:5], q[:5])
    assert core.seed(_request())[1] == "ready pose q = 0"  # joints missing: not used
    core.joint_states.update(ARM.joint_names[5:], q[5:])
    seed, source = core.seed(_request())
    np.testing.assert_allclose(seed, q)
    assert source == "joint_states"


@pytest.mark.parametrize("names,values,match", [
    (["joint1"], [0.0, 1.0], "2 positions for 1 names"),
    (["joint1", "joint1"], [0.0, 1.0], "repeated: joint1"),
    (["jointX"] + [f"joint{i}" for i in range(2, 10)], [0.0] * 9, "unknown joints jointX"),
    ([f"joint{i}" for i in range(1, 9)], [0.0] * 8, "lacks joint9"),
    ([f"joint{i}" for i in range(1, 10)], [0.0] * 8 + [math.nan], "not finite for joint9"),
])
def test_bad_seeds_are_refused(core, names, values, match):
    with pytest.raises(InvalidSeedError, match=match):
        core.solve(_request(seed_names=names, seed_positions=values))


def test_frames_other_than_the_root_are_refused(core):
    with pytest.raises(FrameError, match="takes targets in 'base_link'"):
        core.solve(_request(frame="tool0"))
    with pytest.raises(FrameError, match="empty"):
        core.solve(_request(frame=""))
    rail = IKCore(Kinematics(variant="rail_arm"))
    with pytest.raises(FrameError, match="'world'"):
        rail.solve(_request(kin=rail.kin, frame="base_link"))
    result, _ = rail.solve(_request(kin=rail.kin))
    assert result.success, result.message


def test_quaternion_and_position_are_checked(core):
    req = _request()
    req.orientation = (0.0, 0.0, 0.0, 0.5)
    with pytest.raises(InvalidTargetError, match="quaternion norm is 0.5"):
        core.solve(req)
    req.orientation = (0.0, 0.0, math.nan, 1.0)
    with pytest.raises(InvalidTargetError, match="orientation is not 4 finite"):
        core.solve(req)
    req = _request()
    req.position = (0.1, math.inf, 0.0)
    with pytest.raises(InvalidTargetError, match="position is not 3 finite"):
        core.solve(req)
    req = _request(position_only=True)  # zero quaternion accepted when orientation is free
    req.orientation = (0.0, 0.0, 0.0, 0.0)
    result, _ = core.solve(req)
    assert result.success, result.message


def test_quaternion_within_tolerance_is_normalised(core):
    req = _request()
    req.orientation = tuple(1.0005 * v for v in req.orientation)
    result, _ = core.solve(req)
    assert result.success, result.message


def test_options_defaults_and_limits(core):
    assert core.options(_request()) == (core.defaults.position_tolerance,
                                        core.defaults.orientation_tolerance,
                                        core.defaults.timeout)
    assert core.options(_request(position_tolerance=1e-6, timeout=0.02))[::2] == (1e-6, 0.02)
    for kw, match in (({"position_tolerance": -1.0}, "position_tolerance"),
                      ({"orientation_tolerance": math.nan}, "orientation_tolerance"),
                      ({"timeout": 11.0}, "max_timeout")):
        with pytest.raises(InvalidOptionError, match=match):
            core.solve(_request(**kw))
    with pytest.raises(InvalidOptionError, match="timeout"):
        IKDefaults(timeout=0.0)


def test_solver_choice(core):
    result, _ = core.solve(_request(solver="wln", seed_names=ARM.joint_names,
                                    seed_positions=[0.2] * 9))
    assert result.message.startswith("wln:")
    with pytest.raises(UnknownSolverError, match="valid: default, pinv, weighted_pinv"):
        core.solve(_request(solver="fast"))
    with pytest.raises(UnsupportedVariantError):
        core.solve(_request(solver="augmented"))
    with pytest.raises(UnknownSolverError):
        IKCore(ARM, IKDefaults(solver="nope"))


def test_pool_serves_requests_concurrently_on_separate_solvers():
    import threading

    pool = IKPool(Kinematics, size=2)
    assert pool.cores[0].kin is not pool.cores[1].kin  # pinocchio data is per thread
    kin = pool.kin
    t = kin.forward(np.array([0.2, 0.5, -0.3, 0.4, 0.1, -0.5, 0.3, 0.2, -0.1]))
    quat = pin.Quaternion(t[:3, :3])
    base = dict(frame_id="base_link", position=t[:3, 3].tolist(),
                orientation=[quat.x, quat.y, quat.z, quat.w])
    slow_done = threading.Event()

    def slow():
        pool.solve(IKRequest(**base, solver="heuristic", timeout=5.0,
                             position_tolerance=1e-300, orientation_tolerance=1e-300))
        slow_done.set()

    th = threading.Thread(target=slow)
    th.start()
    try:
        while pool.busy == 0:  # the slow request holds a core
            threading.Event().wait(0.001)
        res, _ = pool.solve(IKRequest(**base))
        assert res.success and not slow_done.is_set()
        assert pool.peak_busy == 2
    finally:
        th.join()
    with pytest.raises(InvalidOptionError):
        IKPool(Kinematics, size=0)
