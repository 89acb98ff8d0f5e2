"""The robot's TF tree from its pinocchio model (no ROS): what robot_state_publisher
publishes from the generated URDF, computed by our FK.

Every joint of the URDF is one transform, parent link -> child link (the child link's
frame in the parent link's frame, m and unit quaternions):

- a **fixed** joint (``camera_link_joint``, ``tool0_joint``, and ``rail_mount`` on rail_arm)
  is constant: :meth:`TfTree.static_transforms`, for ``/tf_static``;
- a **moving** joint (``rail``, ``joint1`` .. ``joint9``, ``gripper``) depends on its own
  position only: :meth:`TfTree.transforms` gives those of the joints one ``joint_states``
  message names, for ``/tf``.

Frames: ``base_link`` -> ``link1`` .. ``link9`` -> ``tool0`` -> ``gripper_finger``, and
``camera_link`` on the root; on rail_arm the root is ``world`` -> ``rail_carriage`` ->
``base_link``. The tree is read from the model built from the generated URDF
(:func:`hyperarm_description.pinocchio_model.build_model`, gripper included), so frame names
and values are the URDF's. Composed from the root, the transforms give pinocchio's frame
placements (``Kinematics.forward`` for tool0); tests hold them to 1e-9.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np
import pinocchio as pin

from hyperarm_description.joints import JointStateError, check_command
from hyperarm_description.model import RobotDescription
from hyperarm_description.pinocchio_model import build_model

__all__ = ["FrameTransform", "TfEdge", "TfTree", "check_joint_state", "compose"]


@dataclass(frozen=True)
class FrameTransform:
    """``child`` in ``parent``: ``matrix`` 4x4 homogeneous (m)."""

    parent: str
    child: str
    matrix: np.ndarray

    @property
    def translation(self) -> np.ndarray:
        """(3,) m."""
        return self.matrix[:3, 3]

    @property
    def quaternion(self) -> np.ndarray:
        """(x, y, z, w), unit norm."""
        q = pin.Quaternion(np.asarray(self.matrix[:3, :3]))
        q.normalize()
        return np.array([q.x, q.y, q.z, q.w])


@dataclass(frozen=True)
class TfEdge:
    """One URDF joint as a TF edge: ``joint`` (its name), ``parent`` and ``child`` links,
    ``fixed`` or moving. ``index``: pinocchio joint index of a moving joint (else 0)."""

    joint: str
    parent: str
    child: str
    fixed: bool
    index: int
    parent_inv: pin.SE3     # the parent link's frame in its pinocchio joint, inverted
    child_placement: pin.SE3  # the child link's frame in its pinocchio joint


def check_joint_state(names: Sequence[str], position: Sequence[float],
                      velocity: Sequence[float], effort: Sequence[float],
                      known: Iterable[str]) -> dict[str, float]:
    """{name: position} of a joint_states message, judged whole: at least one joint, one
    finite position per name, names unique and in ``known``, ``velocity`` and ``effort``
    each empty or one finite value per name. Raises :class:`JointStateError` naming the
    problem."""
    if len(names) == 0:
        raise JointStateError("no joint names")
    positions = check_command(names, position, known, "position")
    for label, values in (("velocity", velocity), ("effort", effort)):
        if len(values) == 0:
            continue
        if len(values) != len(names):
            raise JointStateError(f"{label}: {len(values)} values for {len(names)} joint "
                                  "names")
        bad = [n for n, v in zip(names, values) if not math.isfinite(float(v))]
        if bad:
            raise JointStateError(f"non-finite {label} for {bad}")
    return positions


def compose(transforms: Iterable[FrameTransform], root: str) -> dict[str, np.ndarray]:
    """4x4 pose in ``root`` of every frame reachable from it through ``transforms``."""
    by_parent: dict[str, list[FrameTransform]] = {}
    for t in transforms:
        by_parent.setdefault(t.parent, []).append(t)
    out = {root: np.eye(4)}
    todo = [root]
    while todo:
        parent = todo.pop()
        for t in by_parent.get(parent, ()):
            out[t.child] = out[parent] @ t.matrix
            todo.append(t.child)
    return out


class TfTree:
    """The TF edges of ``desc``'s URDF, evaluated with pinocchio."""

    def __init__(self, desc: RobotDescription) -> None:
        self.desc = desc
        self.model = build_model(desc, include_gripper=True)
        self._data = self.model.createData()
        self.root = desc.root_frame
        frames = self.model.frames
        edges: list[TfEdge] = []
        for b in frames:
            if b.type != pin.FrameType.BODY or b.parentFrame == 0:
                continue   # not a link, or the root link (on the model's universe)
            j = frames[b.parentFrame]
            p = frames[j.parentFrame]
            fixed = j.type == pin.FrameType.FIXED_JOINT
            if p.type != pin.FrameType.BODY or (fixed and p.parentJoint != b.parentJoint) \
                    or (not fixed and self.model.parents[b.parentJoint] != p.parentJoint):
                raise RuntimeError(f"unexpected pinocchio frame tree at {b.name}")
            edges.append(TfEdge(j.name, p.name, b.name, fixed,
                                0 if fixed else b.parentJoint, p.placement.inverse(),
                                pin.SE3(b.placement)))
        self.edges: tuple[TfEdge, ...] = tuple(edges)
        self.frames: tuple[str, ...] = (self.root,) + tuple(e.child for e in edges)
        self._moving = {e.joint: e for e in edges if not e.fixed}
        #: moving joints, in pinocchio's order (rail, joint1..joint9, gripper)
        self.joint_names: tuple[str, ...] = tuple(self.model.names[1:])
        if set(self._moving) != set(self.joint_names):   # a guard on the URDF generator
            raise RuntimeError(f"moving TF edges {sorted(self._moving)} != model joints "
                               f"{list(self.joint_names)}")
        self._idx_q = {n: self.model.idx_qs[self.model.getJointId(n)]
                       for n in self.joint_names}

    def static_transforms(self) -> list[FrameTransform]:
        """The fixed joints' transforms (every one; for ``/tf_static``)."""
        return [FrameTransform(e.parent, e.child,
                               (e.parent_inv * e.child_placement).homogeneous)
                for e in self.edges if e.fixed]

    def check(self, names: Sequence[str], position: Sequence[float],
              velocity: Sequence[float] = (), effort: Sequence[float] = ()) -> dict[str, float]:
        """:func:`check_joint_state` against this robot's moving joints."""
        return check_joint_state(names, position, velocity, effort, self.joint_names)

    def transforms(self, positions: dict[str, float]) -> list[FrameTransform]:
        """The transforms of the moving joints in ``positions`` (name -> rad, rail m;
        checked by :meth:`check`), in the order given. Each depends on its own joint only."""
        q = np.zeros(self.model.nq)
        for name, value in positions.items():
            q[self._idx_q[name]] = value
        pin.forwardKinematics(self.model, self._data, q)
        out = []
        for name in positions:
            e = self._moving[name]
            m = e.parent_inv * self._data.liMi[e.index] * e.child_placement
            out.append(FrameTransform(e.parent, e.child, m.homogeneous))
        return out
