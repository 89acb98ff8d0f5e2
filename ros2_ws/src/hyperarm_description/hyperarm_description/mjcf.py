"""MuJoCo model (MJCF) of the robot and its work cell, generated from the description (no ROS).

Written from ``hyperarm.yaml`` (a :class:`~hyperarm_description.model.RobotDescription`)
and, optionally, a work cell (a :class:`~hyperarm_description.world.WorldSpec`) with Python's
``xml.etree.ElementTree``, every number at full precision (MuJoCo's own writer,
``MjSpec.to_xml``, keeps 6 significant digits: joint limits 4e-6 rad off, and any angle
that is not a multiple of 90 degrees ~1e-7 off), and compiled by MuJoCo
(``mujoco.MjModel.from_xml_string``; ``mujoco.MjSpec.from_string`` edits it further).
Nothing is hand-kept: edit the YAML files and regenerate (``generate_mjcf``, docs/mujoco.md).

Bodies and frames follow the URDF (hyperarm_description.urdf) exactly, so MuJoCo's forward
kinematics equals pinocchio's: the worldbody is the root frame (base_link for ``arm``,
world for ``rail_arm``); ``rail_carriage`` (rail_arm only) slides on joint ``rail``;
``base_link``, ``link1`` .. ``link9`` (hinge ``joint<i>`` about the body's z), ``tool0``
(fixed on link9, DH frame 9) and ``gripper_finger`` (hinge ``gripper`` about tool0's x at
0.04 m along tool0's y, as in the URDF), and two fingers (``finger_left``/``finger_right``,
slide joints along tool0's ±z coupled to ``gripper`` by stiff equality constraints, box pads
that hold the block by friction). With ``host``/``mount`` the root sits on a mocap body
``host`` (and a 6-D spring-damper ``mount``) instead. Link masses, centres of mass and
inertias are the
description's (the URDF's inertial frames); collision geometry is the description's
capsules; joint ranges are its limits.

Servo dynamics (assumptions, docs/mujoco.md): each joint's ``armature`` is its servo's
rotor inertia reflected through its gears (``ServoSpec.armature``); ``damping`` (viscous,
N·m·s/rad) and ``frictionloss`` (Coulomb, N·m) are the work cell's servo damping and current
friction (:class:`PhysicsOptions`). Each actuated joint has one ``general`` actuator named
like the joint, built as a position PD (force = kp·(ctrl - q) - kv·q̇ within ±the servo's
stall torque); :func:`set_servo_mode` turns it into a motor (current mode) or switches it
off at run time by changing ``actuator_gainprm``/``biasprm``/``forcerange``/``ctrlrange``,
never rebuilding the model.

The work cell: the table (a box under ``table_height`` over its extent, or a plane when
unbounded), the pegs and poles (cylinders), and the block: a free body whose box with a
vertical hole is ``hole_pieces`` convex prisms (meshes) around a regular polygon circumscribed
about the hole's circle (so a peg that fits the real hole fits the model), starting threaded on
its ``start`` peg, resting on the table. Contacts use elliptic friction cones; the block's
pieces have torsional friction (condim 4).

The camera: a MuJoCo camera named like the description's camera frame, at its pose (MuJoCo
cameras look along their -z with +y up; camera_link looks along its +x with +z up) with the
description's vertical field of view.

Units: m, rad, kg, s (MuJoCo's ``fovy`` is in degrees by MuJoCo's convention).
"""
from __future__ import annotations

import argparse
import math
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import mujoco
import numpy as np

from .model import (VARIANTS, DescriptionError, RobotDescription, _rpy_matrix,
                    camera_link_pose, check_number, load_description, read_yaml)
from .urdf import _fixed_part, _rz
from .world import MOCK_WORLD_KEYS, WorldSpec, parse_world

__all__ = ["PhysicsOptions", "Mount", "CAMERA_FROM_LINK", "SERVO_MODES", "MOUNT_JOINTS",
           "PAD_HALF_SIZE", "FINGER_MASS", "build_model", "generate_mjcf", "block_pieces",
           "prism_inertia", "finger_travel", "options_from_workcell", "set_servo_mode",
           "camera_link_pose", "render_png", "main"]

#: Rotation of a MuJoCo camera's frame in ``camera_link`` (columns: the MuJoCo camera's x, y,
#: z axes): MuJoCo looks along -z with +y up, camera_link along +x with +z up.
CAMERA_FROM_LINK = np.array([[0.0, 0.0, -1.0],
                             [-1.0, 0.0, 0.0],
                             [0.0, 1.0, 0.0]])

#: Dynamixel operating modes and what :func:`set_servo_mode` makes of the joint's actuator.
SERVO_MODES = ("position", "current_based_position", "current", "off")

#: Collision geoms of the robot (capsules, carriage) and of the work cell / block.
_ROBOT_GROUP, _WORLD_GROUP, _BLOCK_GROUP = 0, 1, 2

#: Contact bits (MuJoCo collides two geoms when contype of one & conaffinity of the other):
#: robot capsules (arm links, base, carriage) touch each other, the poles, the table, the
#: pegs and the block. The hand (the last link's capsule and the gripper's, envelopes of
#: the wrist, palm and closed fingers) touches the links and the poles only: the pegs pass
#: between the fingers into the held block's hole, and the finger pads, which hold the
#: block, meet the block, the table, the pegs and the poles for the hand. The work cell's
#: geoms (table, pegs, poles) do not touch each other.
_BIT_ROBOT, _BIT_POLE, _BIT_BLOCK, _BIT_HAND, _BIT_PAD, _BIT_PEG, _BIT_TABLE = \
    1, 2, 4, 8, 16, 32, 64
_CELL = _BIT_ROBOT | _BIT_BLOCK | _BIT_PAD
_CONTACT = {
    "robot": {"contype": _BIT_ROBOT, "conaffinity": _BIT_ROBOT},
    "hand": {"contype": _BIT_HAND, "conaffinity": _BIT_ROBOT | _BIT_POLE},
    "pad": {"contype": _BIT_PAD, "conaffinity": _BIT_BLOCK},
    "pole": {"contype": _BIT_POLE, "conaffinity": _CELL},
    "peg": {"contype": _BIT_PEG, "conaffinity": _CELL},
    "table": {"contype": _BIT_TABLE, "conaffinity": _CELL},
    "block": {"contype": _BIT_BLOCK, "conaffinity": _BIT_ROBOT | _BIT_BLOCK},
}

#: The finger pads (assumptions: the description gives only the opening): boxes of these
#: half sizes (m) along tool0 x, y, z, their inner faces ``gripper.max_opening`` apart at
#: the gripper's upper limit and touching at its lower limit, centred on tool0's origin in
#: x and y (where the held block's centre is); each finger's mass (kg).
PAD_HALF_SIZE = (0.012, 0.012, 0.003)
FINGER_MASS = 0.01


@dataclass(frozen=True)
class PhysicsOptions:
    """Physics settings of the generated model (SI units). Defaults are the default work
    cell's (hyperarm_driver/config/workcell.yaml) where it has the value.

    timestep: s, MuJoCo's step (1 kHz: the contacts' rate). friction: Coulomb coefficient of
    every contact (work cell ``world.friction``). torsional_friction: m, MuJoCo's torsional
    coefficient of the block's contacts (friction torque per normal force). joint_damping:
    N·m·s/rad, viscous friction of every arm and gripper joint (``servo.damping``).
    joint_frictionloss: N·m, Coulomb friction of every arm and gripper joint
    (``current.friction``). arm_kp, gripper_kp: N·m/rad, rail_kp: N/m: the position loops
    (``servo.stiffness``, ``servo.gripper_stiffness``, ``servo.rail_stiffness``);
    arm_kv, gripper_kv: N·m·s/rad, rail_kv: N·s/m: their damping (an assumption). hole_pieces:
    convex pieces of the block around its hole (>= 6)."""

    timestep: float = 0.001
    friction: float = 0.5
    torsional_friction: float = 0.005
    joint_damping: float = 0.05
    joint_frictionloss: float = 0.03
    arm_kp: float = 20.0
    arm_kv: float = 0.5
    gripper_kp: float = 5.0
    gripper_kv: float = 0.05
    rail_kp: float = 20000.0
    rail_kv: float = 2000.0
    hole_pieces: int = 12

    def __post_init__(self) -> None:
        for name in ("timestep", "friction", "arm_kp", "gripper_kp", "rail_kp"):
            check_number(getattr(self, name), f"options.{name}", positive=True)
        for name in ("torsional_friction", "joint_damping", "joint_frictionloss", "arm_kv",
                     "gripper_kv", "rail_kv"):
            check_number(getattr(self, name), f"options.{name}", nonneg=True)
        if isinstance(self.hole_pieces, bool) or not isinstance(self.hole_pieces, int) \
                or self.hole_pieces < 6:
            raise DescriptionError(f"options.hole_pieces: an integer >= 6, got "
                                   f"{self.hole_pieces!r}")


def _quat(r: np.ndarray) -> np.ndarray:
    """MuJoCo quaternion (w, x, y, z) of a 3x3 rotation matrix."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(r, dtype=float).reshape(9))
    return q


def _f(x: float) -> str:
    """Full-precision (round-trip) text of a float; -0.0 and |x| < 1e-15 as 0."""
    return "0" if abs(x) < 1e-15 else repr(float(x))


def _el(parent: ET.Element, tag: str, **attrs: Any) -> ET.Element:
    """A child element; numbers and sequences of numbers written at full precision (MuJoCo's
    own writer, ``MjSpec.to_xml``, keeps 6 significant digits)."""
    out = {}
    for key, value in attrs.items():
        if value is None:
            continue
        if isinstance(value, str):
            out[key] = value
        elif isinstance(value, int):
            out[key] = str(value)
        elif isinstance(value, (float, np.floating)):
            out[key] = _f(value)
        else:
            out[key] = " ".join(_f(v) for v in np.asarray(value, dtype=float).reshape(-1))
    return ET.SubElement(parent, tag, out)


def _pose(t: np.ndarray) -> dict[str, np.ndarray]:
    """pos/quat attributes of a 4x4 pose in the parent."""
    return {"pos": t[:3, 3], "quat": _quat(t[:3, :3])}


def _inertia_in_link(inertia: Sequence[float], a: float, d: float) -> np.ndarray:
    """The link inertia (ixx iyy izz ixy ixz iyz, about the centre of mass, in the URDF's
    inertial frame turned by Ry(beta) onto the segment) as a 3x3 matrix in the link frame."""
    beta = math.atan2(-d, a) if math.hypot(a, d) > 1e-9 else 0.0
    ixx, iyy, izz, ixy, ixz, iyz = inertia
    i_local = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    r = _rpy_matrix((0.0, beta, 0.0))
    return r @ i_local @ r.T


def _inertial(body: ET.Element, mass: float, com: Sequence[float], i: np.ndarray) -> None:
    """<inertial> with MuJoCo's ``fullinertia`` (M11 M22 M33 M12 M13 M23, body frame)."""
    _el(body, "inertial", pos=com, mass=mass,
        fullinertia=[i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]])


_ROBOT_RGBA = (0.75, 0.75, 0.78, 1.0)


def _capsules(body: ET.Element, desc: RobotDescription, frame: str) -> None:
    for cap in desc.capsules:
        if cap.frame != frame:
            continue
        a, b = cap.endpoints()
        _el(body, "geom", name=f"capsule_{cap.name}", type="capsule", size=[cap.radius],
            fromto=[*a, *b], group=_ROBOT_GROUP, rgba=_ROBOT_RGBA, mass=0.0,
            **_CONTACT["hand" if frame in (desc.tool_frame, f"link{len(desc.joints)}")
                       else "robot"])


def _joint(body: ET.Element, name: str, kind: str, axis: Sequence[float], lower: float,
           upper: float, armature: float | None, opts: PhysicsOptions) -> None:
    dyn = {} if armature is None else {"armature": armature, "damping": opts.joint_damping,
                                       "frictionloss": opts.joint_frictionloss}
    _el(body, "joint", name=name, type=kind, axis=axis, range=[lower, upper],
        limited="true", **dyn)


def _actuator(actuators: ET.Element, name: str, lower: float, upper: float, kp: float,
              kv: float, force: float | None) -> None:
    """A ``general`` actuator on joint ``name`` set up as a position PD (kp, kv), its control
    the target position within the joint's range, its force within ±``force`` (None: no
    limit)."""
    limit = {} if force is None else {"forcelimited": "true", "forcerange": [-force, force]}
    _el(actuators, "general", name=name, joint=name, gaintype="fixed", biastype="affine",
        gainprm=[kp], biasprm=[0.0, -kp, -kv], ctrllimited="true", ctrlrange=[lower, upper],
        **({"forcelimited": "false"} if force is None else limit))


#: The passive mount's joints (:class:`Mount`): translations along the host's x, y, z, then
#: rotations about its x, y, z (roll, pitch, yaw), in one body.
MOUNT_JOINTS = ("mount_x", "mount_y", "mount_z", "mount_roll", "mount_pitch", "mount_yaw")


@dataclass(frozen=True)
class Mount:
    """A passive 6-D spring-damper between the host (a UAV's airframe frame) and the robot's
    root, as the mock's ``mount:`` (hyperarm_driver/config/host_motion/*.yaml): the mounted
    body's ``mass`` (kg) and diagonal ``inertia`` (kg·m², at the root's origin, root axes),
    diagonal ``stiffness`` (N/m x3, then N·m/rad x3) and ``damping`` (N·s/m x3, then
    N·m·s/rad x3). Raises DescriptionError naming a bad field."""

    mass: float
    inertia: tuple[float, float, float]
    stiffness: tuple[float, float, float, float, float, float]
    damping: tuple[float, float, float, float, float, float]

    def __post_init__(self) -> None:
        check_number(self.mass, "mount.mass", positive=True)
        for name, n, positive in (("inertia", 3, True), ("stiffness", 6, True),
                                  ("damping", 6, False)):
            values = getattr(self, name)
            if isinstance(values, (str, bytes)) or not hasattr(values, "__len__") \
                    or len(values) != n:
                raise DescriptionError(f"mount.{name}: expected {n} numbers, got {values!r}")
            for i, v in enumerate(values):
                check_number(v, f"mount.{name}[{i}]", positive=positive, nonneg=not positive)

    @classmethod
    def from_mapping(cls, raw: Any, where: str = "mount") -> "Mount":
        """A mount from a parsed ``mount:`` mapping (keys mass, inertia, stiffness, damping)."""
        if not isinstance(raw, Mapping):
            raise DescriptionError(f"{where}: expected a mapping, got {type(raw).__name__}")
        keys = {"mass", "inertia", "stiffness", "damping"}
        unknown, missing = sorted(set(map(str, raw)) - keys), sorted(keys - set(raw))
        if unknown or missing:
            raise DescriptionError(f"{where}: unknown key(s) {unknown}, missing {missing}")
        return cls(mass=raw["mass"], inertia=tuple(raw["inertia"]),
                   stiffness=tuple(raw["stiffness"]), damping=tuple(raw["damping"]))


def _host(worldbody: ET.Element, mount: Mount | None) -> ET.Element:
    """The mocap body ``host`` (its pose set at run time through ``data.mocap_pos`` /
    ``mocap_quat``: the scripted host motion) and, with a ``mount``, the body ``mount``
    hanging on it by the six spring-damper joints :data:`MOUNT_JOINTS`; returns the body
    the robot's root goes into."""
    host = _el(worldbody, "body", name="host", mocap="true")
    if mount is None:
        return host
    body = _el(host, "body", name="mount")
    _inertial(body, mount.mass, (0.0, 0.0, 0.0), np.diag(mount.inertia))
    for k, name in enumerate(MOUNT_JOINTS):
        _el(body, "joint", name=name, type="slide" if k < 3 else "hinge",
            axis=np.eye(3)[k % 3], stiffness=mount.stiffness[k], damping=mount.damping[k],
            limited="false")
    return body


def _robot(parent: ET.Element, actuators: ET.Element, desc: RobotDescription,
           opts: PhysicsOptions) -> None:
    if desc.rail:
        r = desc.rail
        carriage = _el(parent, "body", name="rail_carriage")
        _inertial(carriage, r.carriage_mass, (0.0, 0.0, 0.0), 0.01 * np.eye(3))  # as the URDF
        _joint(carriage, r.name, "slide", r.axis, r.lower, r.upper, None, opts)
        _el(carriage, "geom", name="rail_carriage", type="box", size=[0.1, 0.1, 0.02],
            pos=[0.0, 0.0, 0.02], group=_ROBOT_GROUP, rgba=[0.3, 0.4, 0.6, 1.0], mass=0.0,
            **_CONTACT["robot"])
        _actuator(actuators, r.name, r.lower, r.upper, opts.rail_kp, opts.rail_kv, None)
        mount = np.eye(4)
        mount[:3, :3] = _rpy_matrix(r.mount_rpy)
        mount[:3, 3] = r.mount_xyz
        parent = _el(carriage, "body", name=desc.base_frame, **_pose(mount))
    else:
        parent = _el(parent, "body", name=desc.base_frame)
    _capsules(parent, desc, desc.base_frame)
    prev_fixed = np.eye(4)
    for i, j in enumerate(desc.joints, start=1):
        body = _el(parent, "body", name=f"link{i}", **_pose(prev_fixed @ _rz(j.dh.theta)))
        _inertial(body, j.link.mass, j.link.com,
                  _inertia_in_link(j.link.inertia, j.dh.a, j.dh.d))
        _joint(body, j.name, "hinge", (0.0, 0.0, 1.0), j.lower, j.upper, j.servo.armature,
               opts)
        _capsules(body, desc, f"link{i}")
        _actuator(actuators, j.name, j.lower, j.upper, opts.arm_kp, opts.arm_kv, j.effort)
        parent = body
        prev_fixed = _fixed_part(j.dh)
    tool = _el(parent, "body", name=desc.tool_frame, **_pose(prev_fixed))
    _capsules(tool, desc, desc.tool_frame)
    g = desc.gripper
    finger = _el(tool, "body", name="gripper_finger", pos=[0.0, 0.04, 0.0])
    _inertial(finger, 0.02, (0.0, 0.0, 0.0), 1e-6 * np.eye(3))  # as the URDF
    _joint(finger, g.name, "hinge", (1.0, 0.0, 0.0), g.lower, g.upper, g.servo.armature, opts)
    _el(finger, "geom", name="gripper_finger", type="box", size=[0.005, 0.02, 0.01],
        pos=[0.0, -0.02, 0.0], contype=0, conaffinity=0, group=_ROBOT_GROUP, rgba=_ROBOT_RGBA,
        mass=0.0)
    _actuator(actuators, g.name, g.lower, g.upper, opts.gripper_kp, opts.gripper_kv, g.effort)
    _fingers(tool, desc, opts)


def finger_travel(desc: RobotDescription) -> float:
    """Each finger's travel per radian of the gripper joint, m/rad: the pads' opening grows
    linearly from 0 at the lower limit to ``max_opening`` at the upper one (an assumption:
    the linkage is not modelled), half of it per finger."""
    g = desc.gripper
    return 0.5 * g.max_opening / (g.upper - g.lower)


def _fingers(tool: ET.Element, desc: RobotDescription, opts: PhysicsOptions) -> None:
    """Two fingers on tool0, sliding along tool0's +z (``finger_left``) and -z
    (``finger_right``), coupled to the gripper joint by equality constraints (added by
    :func:`_finger_coupling`): the servo's torque τ squeezes each pad with τ / (2 ·
    finger_travel) N."""
    g = desc.gripper
    hx, hy, hz = PAD_HALF_SIZE
    i = FINGER_MASS / 12.0 * np.diag([(2 * hy) ** 2 + (2 * hz) ** 2,
                                       (2 * hx) ** 2 + (2 * hz) ** 2,
                                       (2 * hx) ** 2 + (2 * hy) ** 2])
    travel = finger_travel(desc)
    for side, sign in (("left", 1.0), ("right", -1.0)):
        body = _el(tool, "body", name=f"finger_{side}")
        _inertial(body, FINGER_MASS, (0.0, 0.0, sign * hz), i)
        _el(body, "joint", name=f"finger_{side}", type="slide", axis=[0.0, 0.0, sign],
            range=[0.0, travel * (g.upper - g.lower)], limited="true",
            damping=opts.joint_damping)
        _el(body, "geom", name=f"pad_{side}", type="box", size=PAD_HALF_SIZE,
            pos=[0.0, 0.0, sign * hz], condim=4, group=_ROBOT_GROUP,
            friction=[opts.friction, opts.torsional_friction, 1e-4],
            rgba=[0.25, 0.25, 0.28, 1.0], mass=0.0, **_CONTACT["pad"])


def _finger_coupling(root: ET.Element, desc: RobotDescription, opts: PhysicsOptions) -> None:
    """<equality>: finger = finger_travel · (gripper - lower), per finger; as stiff as
    MuJoCo allows (time constant 2 timesteps, impedance 0.99-0.999): the servo's torque
    reaches the pads through it (MuJoCo's default, 0.02 s, let the fingers lag the joint by
    19 mm under the default grip torque; this: 0.05 mm)."""
    g = desc.gripper
    travel = finger_travel(desc)
    eq = _el(root, "equality")
    for side in ("left", "right"):
        _el(eq, "joint", name=f"finger_{side}", joint1=f"finger_{side}", joint2=g.name,
            polycoef=[-travel * g.lower, travel, 0.0, 0.0, 0.0],
            solref=[2.0 * opts.timestep, 1.0], solimp=[0.99, 0.999, 0.0001, 0.5, 2.0])


def block_pieces(size: Sequence[float], hole_radius: float, pieces: int
                 ) -> list[np.ndarray]:
    """The block (a box of ``size`` x y z, m, centred at the origin) minus its vertical hole,
    as ``pieces`` convex prisms around a regular n-gon (n = ``pieces``) circumscribed about the
    hole's circle (radius ``hole_radius``, m): its edges touch the circle at angles
    2π(k + 1/2)/n, its corners lie at hole_radius / cos(π/n) at angles 2πk/n. Piece k is the
    part of the box between the rays at 2πk/n and 2π(k+1)/n outside the n-gon's edge k, each
    given as its vertices (m, rows x y z; bottom ring then top ring). The modelled hole
    holds the real one: a peg that fits the real hole fits the model; across the corners it
    is up to hole_radius·(1/cos(π/n) - 1) wider. Raises ValueError if the hole does not fit
    in the box or n < 3."""
    hx, hy, hz = 0.5 * size[0], 0.5 * size[1], 0.5 * size[2]
    if pieces < 3:
        raise ValueError(f"pieces: at least 3, got {pieces}")
    corner = hole_radius / math.cos(math.pi / pieces)
    if not 0.0 < corner < min(hx, hy):
        raise ValueError(f"a hole of radius {hole_radius:g} m ({pieces} pieces: corners at "
                         f"{corner:g} m) does not fit in a block of {size[0]:g} x {size[1]:g} m")
    corners = [(hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy)]
    corner_angles = [math.atan2(y, x) % (2 * math.pi) for x, y in corners]

    def on_box(theta: float) -> tuple[float, float]:
        c, s = math.cos(theta), math.sin(theta)
        t = min(hx / abs(c) if abs(c) > 1e-15 else math.inf,
                hy / abs(s) if abs(s) > 1e-15 else math.inf)
        return t * c, t * s

    out = []
    for k in range(pieces):
        t0, t1 = 2 * math.pi * k / pieces, 2 * math.pi * (k + 1) / pieces
        ring = [(corner * math.cos(t0), corner * math.sin(t0)), on_box(t0)]
        ring += [c for c, a in sorted(zip(corners, corner_angles), key=lambda ca: ca[1])
                 if t0 < a < t1]
        ring += [on_box(t1), (corner * math.cos(t1), corner * math.sin(t1))]
        out.append(np.array([(x, y, z) for z in (-hz, hz) for x, y in ring]))
    return out


def prism_inertia(pieces: Sequence[np.ndarray], height: float, mass: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Centre of mass (m) and 3x3 inertia about it (kg·m²) of the prisms ``pieces`` (as
    :func:`block_pieces` gives them: bottom ring then top ring, z from -height/2 to
    height/2, m) of uniform density totalling ``mass`` (kg); exact polygon moments, float64
    (MuJoCo's own mesh inertia works on float32 vertices: 1e-7 relative)."""
    area = sx = sy = sxx = syy = sxy = 0.0
    for verts in pieces:
        ring = verts[: len(verts) // 2, :2]
        x, y = ring[:, 0], ring[:, 1]
        xn, yn = np.roll(x, -1), np.roll(y, -1)
        c = x * yn - xn * y
        sign = 1.0 if c.sum() >= 0.0 else -1.0  # counter-clockwise rings count positive
        c = sign * c
        area += c.sum() / 2.0
        sx += float(np.sum(c * (x + xn))) / 6.0       # ∫x dA
        sy += float(np.sum(c * (y + yn))) / 6.0       # ∫y dA
        syy += float(np.sum(c * (x * x + x * xn + xn * xn))) / 12.0  # ∫x² dA
        sxx += float(np.sum(c * (y * y + y * yn + yn * yn))) / 12.0  # ∫y² dA
        sxy += float(np.sum(c * (x * yn + 2 * x * y + 2 * xn * yn + xn * y))) / 24.0
    rho_a = mass / area  # mass per area of the footprint
    com = np.array([sx / area, sy / area, 0.0])
    i = rho_a * np.array([[sxx + area * height ** 2 / 12.0, -sxy, 0.0],
                          [-sxy, syy + area * height ** 2 / 12.0, 0.0],
                          [0.0, 0.0, sxx + syy]])
    # parallel axis: about the centre of mass
    d = com
    i -= mass * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
    return com, i


def _world(asset: ET.Element, worldbody: ET.Element, world: WorldSpec,
           opts: PhysicsOptions) -> None:
    t = world.table
    grey = [0.55, 0.55, 0.58, 1.0]
    _el(asset, "texture", name="table", type="2d", builtin="checker", rgb1=[0.78, 0.66, 0.5],
        rgb2=[0.7, 0.58, 0.43], width=256, height=256)
    _el(asset, "material", name="table", texture="table", texrepeat=[8, 8],
        texuniform="true")
    if all(math.isfinite(v) for v in (*t.x_range, *t.y_range)):
        thick = 0.05
        _el(worldbody, "geom", name="table", type="box",
            size=[0.5 * (t.x_range[1] - t.x_range[0]), 0.5 * (t.y_range[1] - t.y_range[0]),
                  0.5 * thick],
            pos=[0.5 * sum(t.x_range), 0.5 * sum(t.y_range), t.height - 0.5 * thick],
            group=_WORLD_GROUP, material="table", **_CONTACT["table"])
    else:
        _el(worldbody, "geom", name="table", type="plane", size=[0.0, 0.0, 0.05],
            pos=[0.0, 0.0, t.height], group=_WORLD_GROUP, material="table",
            **_CONTACT["table"])
    for p in world.pegs:
        _el(worldbody, "geom", name=f"peg_{p.name}", type="cylinder",
            size=[p.radius, 0.5 * p.height], pos=[*p.xy, t.height + 0.5 * p.height],
            group=_WORLD_GROUP, rgba=grey, **_CONTACT["peg"])
    for p in world.poles:
        _el(worldbody, "geom", name=f"pole_{p.name}", type="cylinder",
            size=[p.radius, 0.5 * p.height], pos=[*p.xy, 0.5 * (p.z_min + p.z_max)],
            group=_WORLD_GROUP, rgba=[0.8, 0.3, 0.2, 1.0], **_CONTACT["pole"])
    b = world.block
    if b is None:
        return
    pieces = block_pieces(b.size, b.hole_radius, opts.hole_pieces)
    start = world.peg(b.start)
    body = _el(worldbody, "body", name="block", pos=[*start.xy, t.height + 0.5 * b.size[2]])
    _inertial(body, b.mass, *prism_inertia(pieces, b.size[2], b.mass))
    _el(body, "freejoint", name="block")
    for k, verts in enumerate(pieces):
        _el(asset, "mesh", name=f"block_piece{k}", vertex=verts, inertia="convex")
        _el(body, "geom", name=f"block_piece{k}", type="mesh", mesh=f"block_piece{k}",
            condim=4,
            friction=[opts.friction, opts.torsional_friction, 0.0001], group=_BLOCK_GROUP,
            rgba=[0.2, 0.5, 0.85, 1.0], **_CONTACT["block"])


def _touching_at_ready(root: ET.Element, desc: RobotDescription) -> list[tuple[str, str]]:
    """Pairs of robot bodies whose capsules touch at q = 0 (the stretched arm): they share
    a joint (link7 and link9 around the zero-length link8), so the IK's collision checker
    skips them too. Parent-child pairs MuJoCo filters itself."""
    model = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    robot = {desc.base_frame, "rail_carriage", desc.tool_frame, "gripper_finger",
             "finger_left", "finger_right",
             *(f"link{i}" for i in range(1, len(desc.joints) + 1))}
    pairs = set()
    for c in data.contact[: data.ncon]:
        names = tuple(sorted(model.body(model.geom_bodyid[g]).name for g in c.geom))
        if set(names) <= robot:
            pairs.add(names)
    return sorted(pairs)


def generate_mjcf(desc: RobotDescription, world: WorldSpec | None = None,
                  options: PhysicsOptions | None = None, *, host: bool = False,
                  mount: Mount | None = None) -> str:
    """The MJCF text of ``desc`` (its variant decides the rail) and, if given, its work cell
    ``world`` (in the root frame); self-contained (meshes inline), numbers at full
    precision. ``host``: the robot's root sits on a mocap body ``host`` (a scripted host
    motion moves it; the work cell and the camera stay in the world); ``mount`` (implies
    ``host``): on a passive 6-D spring-damper from it."""
    opts = options or PhysicsOptions()
    root = ET.Element("mujoco", model=desc.name + ("_rail" if desc.rail else ""))
    src = Path(desc.source).name if desc.source else "the robot description"
    root.append(ET.Comment(f" GENERATED from {src} by hyperarm_description.mjcf (variant "
                           f"{desc.variant}). Do not edit: edit the YAML and run "
                           f"generate_mjcf. "))
    _el(root, "compiler", angle="radian", autolimits="true")
    _el(root, "option", timestep=opts.timestep, cone="elliptic", integrator="implicitfast")
    # contacts as stiff as MuJoCo allows at this timestep (time constant 2 steps; its default
    # 0.02 s let the 10 g fingers sink 1.2 mm into the block they squeeze)
    _el(_el(root, "default"), "geom", friction=[opts.friction, opts.torsional_friction, 1e-4],
        solref=[2.0 * opts.timestep, 1.0])
    _el(_el(root, "visual"), "global", offwidth=1280, offheight=960)
    asset = _el(root, "asset")
    _el(asset, "texture", name="sky", type="skybox", builtin="gradient", rgb1=[0.6, 0.7, 0.8],
        rgb2=[0.2, 0.25, 0.3], width=256, height=256)
    worldbody = _el(root, "worldbody")
    _el(worldbody, "light", name="top", pos=[0.3, 0.0, 2.0], dir=[0.0, 0.0, -1.0],
        directional="true")
    actuators = ET.Element("actuator")
    _robot(_host(worldbody, mount) if host or mount is not None else worldbody, actuators,
           desc, opts)
    if world is not None:
        _world(asset, worldbody, world, opts)
    pose = camera_link_pose(desc)
    _el(worldbody, "camera", name=desc.camera.frame, pos=pose[:3, 3],
        quat=_quat(pose[:3, :3] @ CAMERA_FROM_LINK), fovy=math.degrees(desc.camera.fovy))
    _el(worldbody, "site", name=desc.camera.frame, size=[0.01], rgba=[0.1, 0.8, 0.1, 1.0],
        **_pose(pose))
    _finger_coupling(root, desc, opts)
    root.append(actuators)
    pairs = _touching_at_ready(root, desc)
    if pairs:
        contact = ET.Element("contact")
        for a, b in pairs:
            _el(contact, "exclude", name=f"touch_at_ready_{a}_{b}", body1=a, body2=b)
        root.insert(list(root).index(actuators), contact)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode") + "\n"


def build_model(desc: RobotDescription, world: WorldSpec | None = None,
                options: PhysicsOptions | None = None, *, host: bool = False,
                mount: Mount | None = None) -> mujoco.MjModel:
    """The compiled MuJoCo model of :func:`generate_mjcf`'s text."""
    return mujoco.MjModel.from_xml_string(generate_mjcf(desc, world, options, host=host,
                                                        mount=mount))


def set_servo_mode(model: mujoco.MjModel, joint: str, mode: str, *, kp: float = 0.0,
                   kv: float = 0.0, force_limit: float = math.inf,
                   ctrl_range: tuple[float, float] | None = None) -> None:
    """Switch joint ``joint``'s actuator to a Dynamixel operating ``mode`` at run time
    (changes ``model``'s actuator parameters; the model is not rebuilt):

    - ``position`` / ``current_based_position``: a PD, force = kp·(ctrl - q) - kv·q̇ (kp
      N·m/rad or N/m, kv N·m·s/rad or N·s/m) within ±``force_limit`` (N·m; the current
      limit in current-based position), ctrl the goal position within ``ctrl_range``
      (default: the joint's range);
    - ``current``: a motor, force = ctrl (N·m) within ±``force_limit`` (ctrl too);
    - ``off``: no force (torque off).

    Raises ValueError for an unknown joint or mode, or a negative/NaN gain or limit."""
    if mode not in SERVO_MODES:
        raise ValueError(f"mode: unknown servo mode {mode!r} (known: {', '.join(SERVO_MODES)})")
    aid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, joint)
    if aid < 0:
        raise ValueError(f"joint: no actuator named {joint!r}")
    for name, value in (("kp", kp), ("kv", kv), ("force_limit", force_limit)):
        if not value >= 0.0:  # also NaN
            raise ValueError(f"{name}: must be >= 0, got {value!r}")
    jid = model.actuator_trnid[aid, 0]
    gain, bias = model.actuator_gainprm[aid], model.actuator_biasprm[aid]
    gain[:] = 0.0
    bias[:] = 0.0
    model.actuator_forcelimited[aid] = 1
    model.actuator_forcerange[aid] = [-force_limit, force_limit]
    if mode in ("position", "current_based_position"):
        gain[0], bias[1], bias[2] = kp, -kp, -kv
        model.actuator_ctrlrange[aid] = ctrl_range if ctrl_range is not None \
            else model.jnt_range[jid]
    elif mode == "current":
        gain[0] = 1.0
        model.actuator_ctrlrange[aid] = [-force_limit, force_limit]
    else:  # off
        model.actuator_forcerange[aid] = [0.0, 0.0]


def render_png(model: mujoco.MjModel, path: str | Path, *, width: int = 960,
               height: int = 640, lookat: Sequence[float] = (0.3, 0.0, -0.08),
               distance: float = 1.1, azimuth: float = -135.0, elevation: float = -25.0
               ) -> Path:
    """Render ``model`` at its initial state (qpos0) from a free camera looking at
    ``lookat`` (m, root frame) from ``distance`` (m), ``azimuth`` and ``elevation`` (deg,
    MuJoCo's convention) offscreen into a PNG at ``path``. Needs an OpenGL backend: set
    ``MUJOCO_GL=egl`` (or ``osmesa``) before importing mujoco on a machine without a
    display."""
    from PIL import Image

    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = lookat
    cam.distance, cam.azimuth, cam.elevation = distance, azimuth, elevation
    with mujoco.Renderer(model, height, width) as renderer:
        renderer.update_scene(data, camera=cam)
        pixels = renderer.render()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(pixels).save(out)
    return out


def options_from_workcell(data: Mapping[str, Any], where: str = "") -> PhysicsOptions:
    """:class:`PhysicsOptions` from a parsed work-cell file (its ``world.friction``,
    ``servo.damping``/``stiffness``/``gripper_stiffness``/``rail_stiffness`` and
    ``current.friction``; defaults for what it lacks). Raises DescriptionError naming a bad
    field."""
    base = PhysicsOptions()
    found: dict[str, float] = {}
    for section, key, field in (("world", "friction", "friction"),
                                ("servo", "damping", "joint_damping"),
                                ("servo", "stiffness", "arm_kp"),
                                ("servo", "gripper_stiffness", "gripper_kp"),
                                ("servo", "rail_stiffness", "rail_kp"),
                                ("current", "friction", "joint_frictionloss")):
        sec = data.get(section) if isinstance(data, Mapping) else None
        if isinstance(sec, Mapping) and key in sec:
            found[field] = check_number(sec[key], f"{where}{section}.{key}", nonneg=True)
    kwargs = {f: found.get(f, getattr(base, f)) for f in base.__dataclass_fields__}
    return PhysicsOptions(**kwargs)


def main(argv: list[str] | None = None) -> int:
    """Console script ``generate_mjcf``: write the MJCF of a variant (and a work cell)."""
    ap = argparse.ArgumentParser(
        prog="generate_mjcf",
        description="Write the MuJoCo model (MJCF) of the robot, generated from the robot "
                    "description and, with --workcell, its work cell (docs/mujoco.md). Open "
                    "it with: python -m mujoco.viewer --mjcf=FILE")
    ap.add_argument("--variant", choices=VARIANTS, default="arm",
                    help="robot variant (default: arm)")
    ap.add_argument("--description", help="robot YAML (default: the packaged hyperarm.yaml)")
    ap.add_argument("--workcell", help="work-cell YAML (hyperarm_driver/config/workcell*.yaml):"
                    " adds the table, pegs, poles and block, and takes its friction and "
                    "servo settings; default: the robot alone")
    ap.add_argument("--host-motion", metavar="YAML", help="a host-motion file "
                    "(hyperarm_driver/config/host_motion/*.yaml): the robot's root on a "
                    "mocap body 'host', and on its passive 6-D spring-damper mount if the "
                    "file has 'mount:'")
    ap.add_argument("--timestep", type=float, help="physics step, s (default 0.001)")
    ap.add_argument("-o", "--out", help="output file (default: hyperarm_<variant>.xml)")
    ap.add_argument("--render", metavar="PNG", help="also render the model offscreen into this "
                    "picture (needs MUJOCO_GL=egl or osmesa without a display)")
    args = ap.parse_args(argv)
    try:
        desc = load_description(args.description, args.variant)
        world, options = None, PhysicsOptions()
        if args.workcell:
            data = read_yaml(Path(args.workcell), "work-cell file")
            if not isinstance(data, Mapping) or "world" not in data:
                raise DescriptionError(f"{args.workcell}: no 'world' mapping at the top level")
            world = parse_world(data["world"], extra_keys=MOCK_WORLD_KEYS)
            options = options_from_workcell(data)
        if args.timestep is not None:
            options = PhysicsOptions(**{**options.__dict__, "timestep": args.timestep})
        mount = None
        if args.host_motion:
            motion = read_yaml(Path(args.host_motion), "host-motion file")
            if isinstance(motion, Mapping) and motion.get("mount") is not None:
                mount = Mount.from_mapping(motion["mount"], f"{args.host_motion}: mount")
        text = generate_mjcf(desc, world, options, host=bool(args.host_motion), mount=mount)
    except (DescriptionError, ValueError) as exc:
        print(f"generate_mjcf: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out or f"hyperarm_{args.variant}.xml")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    print(f"wrote {out}")
    if args.render:
        try:
            png = render_png(mujoco.MjModel.from_xml_string(text), args.render)
        except Exception as exc:  # no OpenGL backend: mujoco raises several kinds
            print(f"generate_mjcf: cannot render ({type(exc).__name__}: {exc}); set "
                  "MUJOCO_GL=egl or osmesa", file=sys.stderr)
            return 3
        print(f"wrote {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
