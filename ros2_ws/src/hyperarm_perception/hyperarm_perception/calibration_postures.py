"""Arm postures for the eye-to-hand calibration (no ROS): the held target in view of the
fixed camera, facing it, the arm clear of itself and of the work cell, each reachable from
the one before on a collision-free straight joint path.

Drawn at random within the joint limits (seeded) and kept when every condition holds
(:class:`PostureRules`), three candidates per posture wanted; then chained greedily from
the start: next, the nearest (in joint travel) reachable on a collision-free straight joint
path. The rotation
diversity that :func:`hyperarm_perception.handeye.check_pose_diversity` asks for comes from
the spread of the draws; the caller checks it. Units: m, rad; poses 4x4 in the root frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hyperarm_ik.collision import CollisionModel
from hyperarm_ik.kinematics import Kinematics

from .markers import T_LINK_OPTICAL, CameraModel, PerceptionError

__all__ = ["PostureRules", "PostureError", "target_postures", "NOMINAL_TARGET", "parse_pose"]

#: candidates drawn per posture wanted: the chain of collision-free paths picks among them
_CANDIDATES = 3

#: Where the calibration target sits on the gripper, nominally (the calibration estimates
#: it): "x y z roll pitch yaw" of its frame in tool0 (m, rad), on the gripper's flat side,
#: its marker facing tool0's +z, just clear of the gripper's 20 mm capsule.
NOMINAL_TARGET = "0 0.02 0.026 0 0 0"


def parse_pose(text: str, what: str) -> np.ndarray:
    """4x4 from "x y z roll pitch yaw" (m, rad; rpy as in the URDF); PerceptionError naming
    ``what`` for anything else."""
    try:
        values = [float(v) for v in text.replace(",", " ").split()]
    except ValueError:
        values = []
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise PerceptionError(f"{what}: expected 6 finite numbers 'x y z roll pitch yaw' "
                              f"(m, rad), got {text!r}")
    import pinocchio as pin

    out = np.eye(4)
    out[:3, :3] = pin.rpy.rpyToMatrix(*values[3:])
    out[:3, 3] = values[:3]
    return out


class PostureError(PerceptionError):
    """Not enough postures satisfy the rules within the draws allowed."""


@dataclass(frozen=True)
class PostureRules:
    """``max_view_angle`` (rad): the target's normal against its line of sight;
    ``margin_px``: the target's centre this far inside the image's edges; ``min_depth``
    (m): the target at least this far from the camera along its view; ``clearance`` (m): the
    target at least this high above the table; ``max_draws``: random postures tried."""

    max_view_angle: float = math.radians(40.0)
    margin_px: float = 60.0
    min_depth: float = 0.2
    clearance: float = 0.08
    max_draws: int = 200_000


def _visible(T: np.ndarray, camera_inv: np.ndarray, cam: CameraModel,
             rules: PostureRules) -> bool:
    c = camera_inv @ T                      # the target in camera_link (x: along the view)
    if c[0, 3] < rules.min_depth:
        return False
    sight = c[:3, 3] / np.linalg.norm(c[:3, 3])
    if float(-c[:3, 2] @ sight) < math.cos(rules.max_view_angle):
        return False
    o = T_LINK_OPTICAL.T @ c[:, 3]          # its centre in the optical frame
    uv = cam.K @ o[:3]
    u, v = uv[0] / uv[2], uv[1] / uv[2]
    m = rules.margin_px
    return m < u < cam.width - m and m < v < cam.height - m


def target_postures(kin: Kinematics, collision: CollisionModel, cam: CameraModel,
                    camera_pose: np.ndarray, target_in_tool: np.ndarray, count: int,
                    start: np.ndarray, rng: np.random.Generator,
                    rules: PostureRules | None = None, table_height: float = -math.inf
                    ) -> list[np.ndarray]:
    """``count`` arm postures (joint vectors) for the calibration, in the order to visit
    them from ``start``: the target (``target_in_tool``, its frame in tool0, its marker's
    normal along its z) seen by the camera (``cam``, at ``camera_pose``: camera_link in the
    root frame) under ``rules``, above ``table_height`` + clearance, no collision in the
    posture nor on the straight joint path from the one before. :class:`PostureError` if
    the draws run out."""
    rules = rules or PostureRules()
    camera_inv = np.linalg.inv(camera_pose)
    found: list[np.ndarray] = []
    wanted = _CANDIDATES * count        # spares: a greedy chain can dead-end
    for _ in range(rules.max_draws):
        if len(found) == wanted:
            break
        q = kin.random_configuration(rng)
        T = kin.forward(q) @ target_in_tool
        if T[2, 3] < table_height + rules.clearance or not _visible(T, camera_inv, cam, rules):
            continue
        if not collision.in_collision(q):
            found.append(q)
    if len(found) < wanted:
        raise PostureError(f"only {len(found)} of {wanted} postures show the target to the "
                           f"camera within {rules.max_draws} draws: move the camera or the "
                           "target, or relax the rules")
    # visit in order of joint travel, each reachable on a free straight joint path
    order, here, left = [], np.asarray(start, dtype=float), list(found)
    while left and len(order) < count:
        left.sort(key=lambda q: float(np.max(np.abs(q - here))))
        for i, q in enumerate(left):
            if collision.check_path(here, q).free:
                order.append(left.pop(i))
                here = order[-1]
                break
        else:
            break                           # the rest cannot be reached from here
    if len(order) < count:
        raise PostureError(f"only {len(order)} of {count} postures can be reached one after "
                           "the other on collision-free joint paths")
    return order
