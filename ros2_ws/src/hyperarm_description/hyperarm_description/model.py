"""Typed, validated robot description loaded from the package's YAML (no ROS needed).

Units: metres, radians, kilograms, seconds. Every validation error names the offending field
with a dotted path, e.g. ``arm.joints[3].dh.alpha``.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import yaml

__all__ = [
    "DescriptionError",
    "DHRow",
    "ServoSpec",
    "LinkSpec",
    "JointSpec",
    "GripperSpec",
    "RailSpec",
    "CameraSpec",
    "camera_link_pose",
    "CapsuleSpec",
    "RobotDescription",
    "VARIANTS",
    "check_number",
    "check_vector",
    "default_description_path",
    "load_description",
    "parse_angle",
    "read_yaml",
    "write_description_copy",
]

VARIANTS = ("arm", "rail_arm")

_PI_EXPR = re.compile(
    r"^\s*(?P<sign>[-+])?\s*(?:(?P<k>\d+(?:\.\d+)?)\s*\*?\s*)?pi\s*(?:/\s*(?P<n>\d+(?:\.\d+)?))?\s*$"
)
_DEG_EXPR = re.compile(r"^\s*(?P<v>[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?)\s*deg\s*$")


class DescriptionError(ValueError):
    """The robot description file is missing a field or holds an invalid value."""


def parse_angle(value: Any, where: str) -> float:
    """Angle in rad from a number (rad), ``"k*pi/n"`` or ``"x deg"``."""
    if isinstance(value, bool):
        raise DescriptionError(f"{where}: expected an angle, got {value!r}")
    if isinstance(value, (int, float)):
        out = float(value)
    elif isinstance(value, str):
        m = _PI_EXPR.match(value)
        d = _DEG_EXPR.match(value)
        if m:
            k = float(m.group("k")) if m.group("k") else 1.0
            n = float(m.group("n")) if m.group("n") else 1.0
            out = (-1.0 if m.group("sign") == "-" else 1.0) * k * math.pi / n
        elif d:
            out = math.radians(float(d.group("v")))
        else:
            raise DescriptionError(
                f"{where}: cannot read angle {value!r} (use rad, 'k*pi/n' or 'x deg')")
    else:
        raise DescriptionError(f"{where}: expected an angle, got {value!r}")
    if not math.isfinite(out):
        raise DescriptionError(f"{where}: angle must be finite, got {value!r}")
    return out


def check_number(value: Any, where: str, *, positive: bool = False, nonneg: bool = False,
                 error: type[Exception] = DescriptionError) -> float:
    """``value`` as a finite float (bools refused), optionally > 0 or >= 0; else raises
    ``error`` naming ``where`` (a dotted path). Shared with other YAML loaders (the mock's
    work cell), which pass their own error class."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise error(f"{where}: expected a number, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise error(f"{where}: must be finite, got {value!r}")
    if positive and out <= 0.0:
        raise error(f"{where}: must be > 0, got {out}")
    if nonneg and out < 0.0:
        raise error(f"{where}: must be >= 0, got {out}")
    return out


_num = check_number


def _req(mapping: Any, key: str, where: str) -> Any:
    if not isinstance(mapping, Mapping):
        raise DescriptionError(f"{where}: expected a mapping, got {type(mapping).__name__}")
    if key not in mapping:
        raise DescriptionError(f"{where}.{key}: missing")
    return mapping[key]


def check_vector(value: Any, where: str, n: int = 3, *,
                 error: type[Exception] = DescriptionError) -> tuple[float, ...]:
    """``value`` as a tuple of ``n`` finite floats (a list in YAML); else raises ``error``
    naming ``where`` (and the index of a bad element)."""
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != n:
        raise error(f"{where}: expected a list of {n} numbers, got {value!r}")
    return tuple(check_number(v, f"{where}[{i}]", error=error) for i, v in enumerate(value))


_vec3 = check_vector


@dataclass(frozen=True)
class DHRow:
    """One row of a standard DH table: T = Rz(theta + q) Tz(d) Tx(a) Rx(alpha). m, rad."""

    theta: float
    d: float
    a: float
    alpha: float

    def transform(self, q: float = 0.0) -> np.ndarray:
        """4x4 homogeneous transform of this row at joint angle ``q`` (rad)."""
        ct, st = math.cos(self.theta + q), math.sin(self.theta + q)
        ca, sa = math.cos(self.alpha), math.sin(self.alpha)
        return np.array([
            [ct, -st * ca, st * sa, self.a * ct],
            [st, ct * ca, -ct * sa, self.a * st],
            [0.0, sa, ca, self.d],
            [0.0, 0.0, 0.0, 1.0],
        ])


@dataclass(frozen=True)
class ServoSpec:
    """A Dynamixel servo: bus ID, model name, direction sign and zero offset (rad); its
    model's gear ratio (output/motor, 1) and motor rotor inertia (kg·m², 0 = not given)."""

    id: int
    model: str
    model_number: int
    direction: int = 1
    zero_offset: float = 0.0
    operating_mode: str = "position"
    gear_ratio: float = 1.0
    rotor_inertia: float = 0.0

    @property
    def armature(self) -> float:
        """The rotor's inertia reflected through the gears to the joint, kg·m²
        (rotor_inertia · gear_ratio²)."""
        return self.rotor_inertia * self.gear_ratio ** 2


@dataclass(frozen=True)
class LinkSpec:
    """Approximate inertial data of the link a joint moves (kg, m, kg·m²)."""

    mass: float
    com: tuple[float, float, float]
    radius: float
    inertia: tuple[float, float, float, float, float, float]  # ixx iyy izz ixy ixz iyz


@dataclass(frozen=True)
class JointSpec:
    """A revolute arm joint: DH row, limits (rad, rad/s, rad/s², N·m), servo and link."""

    name: str
    dh: DHRow
    lower: float
    upper: float
    velocity: float
    acceleration: float
    effort: float
    servo: ServoSpec
    link: LinkSpec


@dataclass(frozen=True)
class GripperSpec:
    """The 1-actuator gripper: joint range (rad), opening (m) and default grip torque (N·m)."""

    name: str
    lower: float
    upper: float
    velocity: float
    effort: float
    servo: ServoSpec
    max_opening: float
    grip_effort: float


@dataclass(frozen=True)
class RailSpec:
    """The prismatic rail of the rail_arm variant (m, m/s, m/s², kg)."""

    name: str
    axis: tuple[float, float, float]
    lower: float
    upper: float
    velocity: float
    acceleration: float
    carriage_mass: float
    mount_xyz: tuple[float, float, float]
    mount_rpy: tuple[float, float, float]
    pmac_motor: int
    counts_per_metre: float


@dataclass(frozen=True)
class CameraSpec:
    """Fixed camera frame in the root frame (base_link, or world for rail_arm). m, rad.
    ``fovy``: the image's vertical field of view, rad."""

    frame: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    fovy: float = math.radians(45.0)


def camera_link_pose(desc: "RobotDescription") -> np.ndarray:
    """4x4 pose of the camera frame (camera_link) in the root frame: the description's
    ``camera`` xyz (m) and rpy (rad, fixed axes as in URDF)."""
    t = np.eye(4)
    t[:3, :3] = _rpy_matrix(desc.camera.rpy)
    t[:3, 3] = desc.camera.xyz
    return t


def _rpy_matrix(rpy: Sequence[float]) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (the URDF convention), rad."""
    cr, sr = math.cos(rpy[0]), math.sin(rpy[0])
    cp, sp = math.cos(rpy[1]), math.sin(rpy[1])
    cy, sy = math.cos(rpy[2]), math.sin(rpy[2])
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


@dataclass(frozen=True)
class CapsuleSpec:
    """A collision capsule fixed to a robot frame: the points within ``radius`` (m) of a
    segment of ``length`` (m, > 0) centred at ``xyz`` (m) in ``frame``, along the z axis of
    the rotation ``rpy`` (rad, URDF convention). ``frame`` is a URDF link (``link1`` ..
    ``link9``, ``tool0`` for the gripper). In the URDF it is a cylinder plus two spheres;
    in coal it is ``coal.Capsule(radius, length)`` at :meth:`placement`."""

    name: str
    frame: str
    radius: float
    length: float
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]

    def placement(self) -> np.ndarray:
        """4x4 pose of the capsule's centre in ``frame`` (its z axis along the segment)."""
        t = np.eye(4)
        t[:3, :3] = _rpy_matrix(self.rpy)
        t[:3, 3] = self.xyz
        return t

    def endpoints(self) -> tuple[np.ndarray, np.ndarray]:
        """The segment's two ends (m) in ``frame``: centre -+ length/2 along the axis."""
        t = self.placement()
        half = 0.5 * self.length * t[:3, 2]
        return t[:3, 3] - half, t[:3, 3] + half


@dataclass(frozen=True)
class RobotDescription:
    """The whole robot for one variant. ``joints`` are the nine arm joints, base to tool."""

    name: str
    variant: str
    base_frame: str
    tool_frame: str
    joints: tuple[JointSpec, ...]
    gripper: GripperSpec
    rail: RailSpec | None
    camera: CameraSpec
    source: str = field(default="", compare=False)
    #: Collision capsules: one per arm link (named like the link) and ``gripper`` (on tool0).
    capsules: tuple[CapsuleSpec, ...] = ()

    @property
    def arm_joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    @property
    def kinematic_joint_names(self) -> list[str]:
        """Joints of the IK chain, in pinocchio order: rail (if any) then joint1..joint9."""
        return ([self.rail.name] if self.rail else []) + self.arm_joint_names

    @property
    def all_joint_names(self) -> list[str]:
        """Every actuated joint: rail (if any), arm joints, gripper."""
        return self.kinematic_joint_names + [self.gripper.name]

    @property
    def root_frame(self) -> str:
        return "world" if self.rail else self.base_frame

    def lower_limits(self) -> np.ndarray:
        """Lower limits of the kinematic chain (rail m, joints rad)."""
        lo = [j.lower for j in self.joints]
        return np.array(([self.rail.lower] if self.rail else []) + lo)

    def upper_limits(self) -> np.ndarray:
        """Upper limits of the kinematic chain (rail m, joints rad)."""
        hi = [j.upper for j in self.joints]
        return np.array(([self.rail.upper] if self.rail else []) + hi)

    def limits_by_name(self) -> dict[str, tuple[float, float]]:
        """(lower, upper) of every actuated joint by name, gripper and rail included."""
        out = {j.name: (j.lower, j.upper) for j in self.joints}
        out[self.gripper.name] = (self.gripper.lower, self.gripper.upper)
        if self.rail:
            out[self.rail.name] = (self.rail.lower, self.rail.upper)
        return out

    def capsule(self, name: str) -> CapsuleSpec:
        """The collision capsule called ``name`` (``link1`` .. ``link9``, ``gripper``)."""
        for c in self.capsules:
            if c.name == name:
                return c
        raise DescriptionError(f"no capsule named {name!r} "
                               f"(capsules: {[c.name for c in self.capsules]})")

    def frame_poses(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """4x4 poses in ``base_link`` of the frames capsules attach to, at the 9 arm angles
        ``q`` (rad): base_link, link1 .. link9 (link i: origin on joint axis i, z along it,
        i.e. DH frame i-1 turned by theta_i + q_i) and tool0 (DH frame 9), as in the URDF."""
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (len(self.joints),):
            raise ValueError(f"expected {len(self.joints)} joint angles, got {q.shape[0]}")
        out = {self.base_frame: np.eye(4)}
        t = np.eye(4)
        for i, (joint, qi) in enumerate(zip(self.joints, q), start=1):
            c, s = math.cos(joint.dh.theta + qi), math.sin(joint.dh.theta + qi)
            rz = np.array([[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0],
                           [0.0, 0.0, 0.0, 1.0]])
            out[f"link{i}"] = t @ rz
            t = t @ joint.dh.transform(float(qi))
        out[self.tool_frame] = t
        return out

    def capsule_segments(self, q: np.ndarray) -> list[tuple[CapsuleSpec, np.ndarray, np.ndarray]]:
        """Every capsule with its segment's two ends (m) in ``base_link`` at arm angles ``q``
        (rad), in the order of :attr:`capsules`."""
        frames = self.frame_poses(q)
        out = []
        for cap in self.capsules:
            t = frames[cap.frame]
            a, b = cap.endpoints()
            out.append((cap, t[:3, :3] @ a + t[:3, 3], t[:3, :3] @ b + t[:3, 3]))
        return out

    def dh_forward(self, q: np.ndarray) -> np.ndarray:
        """Tool pose (4x4) in ``base_link`` from the DH table; ``q`` = 9 arm angles (rad)."""
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (len(self.joints),):
            raise ValueError(f"expected {len(self.joints)} joint angles, got {q.shape[0]}")
        t = np.eye(4)
        for joint, qi in zip(self.joints, q):
            t = t @ joint.dh.transform(float(qi))
        return t


def _cylinder_inertia(mass: float, radius: float, length: float) -> tuple[float, ...]:
    """Solid cylinder along x of the link frame, about its centre of mass."""
    length = max(length, 2.0 * radius)
    ixx = 0.5 * mass * radius**2
    iyy = izz = mass * (3.0 * radius**2 + length**2) / 12.0
    return (ixx, iyy, izz, 0.0, 0.0, 0.0)


def _servo(raw: Any, where: str, models: Mapping[str, Any], default_mode: str) -> ServoSpec:
    sid = _req(raw, "id", where)
    if isinstance(sid, bool) or not isinstance(sid, int) or not 0 <= sid <= 252:
        raise DescriptionError(f"{where}.id: must be an integer 0..252, got {sid!r}")
    model = _req(raw, "model", where)
    if model not in models:
        raise DescriptionError(
            f"{where}.model: unknown servo model {model!r} (known: {', '.join(models)})")
    direction = raw.get("direction", 1)
    if direction not in (1, -1):
        raise DescriptionError(f"{where}.direction: must be 1 or -1, got {direction!r}")
    mode = raw.get("operating_mode", default_mode)
    if mode not in ("position", "current_based_position", "current", "extended_position"):
        raise DescriptionError(f"{where}.operating_mode: unknown mode {mode!r}")
    spec = models[model]
    return ServoSpec(
        id=sid, model=model, model_number=int(spec["model_number"]),
        direction=int(direction),
        zero_offset=parse_angle(raw.get("zero_offset", 0.0), f"{where}.zero_offset"),
        operating_mode=mode,
        gear_ratio=_num(spec.get("gear_ratio", 1.0), f"servo_models.{model}.gear_ratio",
                        positive=True),
        rotor_inertia=_num(spec.get("rotor_inertia", 0.0),
                           f"servo_models.{model}.rotor_inertia", nonneg=True))


def _limits(lower: float, upper: float, where: str) -> None:
    if lower >= upper:
        raise DescriptionError(f"{where}: lower limit {lower:g} must be < upper limit {upper:g}")


CAPSULE_KEYS = frozenset({"frame", "radius", "length", "xyz", "rpy"})


def _capsules(raw: Any, link_names: list[str], base_frame: str, tool_frame: str
              ) -> tuple[CapsuleSpec, ...]:
    """``collision.capsules``: a mapping name -> {frame, radius, length, xyz, rpy}; one per
    arm link (frame = its name) and ``gripper`` (frame tool0 by default), all required."""
    w = "collision.capsules"
    if not isinstance(raw, Mapping) or not raw:
        raise DescriptionError(f"{w}: must be a non-empty mapping of capsule name to capsule")
    frames = {base_frame, tool_frame, *link_names}
    required = [*link_names, "gripper"]
    missing = [n for n in required if n not in raw]
    if missing:
        raise DescriptionError(f"{w}: missing capsule(s) {missing} (every link and the "
                               f"gripper needs one)")
    out = []
    for name, rc in raw.items():
        cw = f"{w}.{name}"
        if not isinstance(rc, Mapping):
            raise DescriptionError(f"{cw}: expected a mapping")
        unknown = sorted(set(rc) - CAPSULE_KEYS)
        if unknown:
            raise DescriptionError(f"{cw}: unknown key(s) {unknown}; known: {sorted(CAPSULE_KEYS)}")
        frame = rc.get("frame", tool_frame if name == "gripper" else name)
        if frame not in frames:
            raise DescriptionError(f"{cw}.frame: {frame!r} is not a robot link "
                                   f"(known: {sorted(frames)})")
        rpy = rc.get("rpy", [0.0, 0.0, 0.0])
        if not isinstance(rpy, Sequence) or isinstance(rpy, str) or len(rpy) != 3:
            raise DescriptionError(f"{cw}.rpy: expected 3 angles, got {rpy!r}")
        out.append(CapsuleSpec(
            name=str(name), frame=str(frame),
            radius=_num(_req(rc, "radius", cw), f"{cw}.radius", positive=True),
            length=_num(_req(rc, "length", cw), f"{cw}.length", positive=True),
            xyz=_vec3(_req(rc, "xyz", cw), f"{cw}.xyz"),  # type: ignore[arg-type]
            rpy=tuple(parse_angle(v, f"{cw}.rpy[{i}]")  # type: ignore[arg-type]
                      for i, v in enumerate(rpy))))
    return tuple(out)


def parse_description(data: Any, variant: str = "arm", source: str = "<data>") -> RobotDescription:
    """Validate a parsed YAML mapping and build the description of ``variant``."""
    if variant not in VARIANTS:
        raise DescriptionError(f"variant: unknown variant {variant!r} (known: {', '.join(VARIANTS)})")
    if not isinstance(data, Mapping):
        raise DescriptionError(f"{source}: top level must be a mapping")
    models = _req(data, "servo_models", "")
    if not isinstance(models, Mapping) or not models:
        raise DescriptionError("servo_models: must be a non-empty mapping")
    for mname, m in models.items():
        _num(_req(m, "model_number", f"servo_models.{mname}"), f"servo_models.{mname}.model_number")
        _num(_req(m, "stall_torque", f"servo_models.{mname}"),
             f"servo_models.{mname}.stall_torque", positive=True)
    defaults = data.get("defaults", {}) or {}
    d_lower = parse_angle(defaults.get("joint_lower", "-150 deg"), "defaults.joint_lower")
    d_upper = parse_angle(defaults.get("joint_upper", "150 deg"), "defaults.joint_upper")
    d_vel = _num(defaults.get("joint_velocity", 3.0), "defaults.joint_velocity", positive=True)
    d_acc = _num(defaults.get("joint_acceleration", 10.0), "defaults.joint_acceleration",
                 positive=True)

    arm = _req(data, "arm", "")
    raw_joints = _req(arm, "joints", "arm")
    if not isinstance(raw_joints, list) or len(raw_joints) != 9:
        n = len(raw_joints) if isinstance(raw_joints, list) else "no"
        raise DescriptionError(f"arm.joints: the arm has 9 joints, found {n}")
    joints: list[JointSpec] = []
    ids: dict[int, str] = {}
    for i, rj in enumerate(raw_joints):
        w = f"arm.joints[{i}]"
        name = _req(rj, "name", w)
        if not isinstance(name, str) or not name:
            raise DescriptionError(f"{w}.name: must be a non-empty string")
        w = f"arm.joints[{i}] ({name})"
        rdh = _req(rj, "dh", w)
        dh = DHRow(theta=parse_angle(_req(rdh, "theta", f"{w}.dh"), f"{w}.dh.theta"),
                   d=_num(_req(rdh, "d", f"{w}.dh"), f"{w}.dh.d"),
                   a=_num(_req(rdh, "a", f"{w}.dh"), f"{w}.dh.a"),
                   alpha=parse_angle(_req(rdh, "alpha", f"{w}.dh"), f"{w}.dh.alpha"))
        lower = parse_angle(rj.get("lower", d_lower), f"{w}.lower")
        upper = parse_angle(rj.get("upper", d_upper), f"{w}.upper")
        _limits(lower, upper, f"{w}.lower/upper")
        servo = _servo(_req(rj, "servo", w), f"{w}.servo", models, "position")
        if servo.id in ids:
            raise DescriptionError(f"{w}.servo.id: ID {servo.id} already used by {ids[servo.id]}")
        ids[servo.id] = name
        rl = _req(rj, "link", w)
        mass = _num(_req(rl, "mass", f"{w}.link"), f"{w}.link.mass", positive=True)
        radius = _num(rl.get("radius", 0.02), f"{w}.link.radius", positive=True)
        com = _vec3(rl.get("com", [0.0, 0.0, 0.0]), f"{w}.link.com")
        length = math.hypot(dh.a, dh.d)
        link = LinkSpec(mass=mass, com=com, radius=radius,
                        inertia=_cylinder_inertia(mass, radius, length))  # type: ignore[arg-type]
        joints.append(JointSpec(
            name=name, dh=dh, lower=lower, upper=upper,
            velocity=_num(rj.get("velocity", d_vel), f"{w}.velocity", positive=True),
            acceleration=_num(rj.get("acceleration", d_acc), f"{w}.acceleration", positive=True),
            effort=float(models[servo.model]["stall_torque"]), servo=servo, link=link))
    names = [j.name for j in joints]
    if len(set(names)) != len(names):
        raise DescriptionError(f"arm.joints: duplicate joint names in {names}")

    rg = _req(data, "gripper", "")
    gname = _req(rg, "name", "gripper")
    if gname in names:
        raise DescriptionError(f"gripper.name: {gname!r} is already an arm joint")
    glower = parse_angle(_req(rg, "lower", "gripper"), "gripper.lower")
    gupper = parse_angle(_req(rg, "upper", "gripper"), "gripper.upper")
    _limits(glower, gupper, "gripper.lower/upper")
    gservo = _servo(_req(rg, "servo", "gripper"), "gripper.servo", models,
                    "current_based_position")
    if gservo.id in ids:
        raise DescriptionError(f"gripper.servo.id: ID {gservo.id} already used by {ids[gservo.id]}")
    gripper = GripperSpec(
        name=gname, lower=glower, upper=gupper,
        velocity=_num(rg.get("velocity", 2.0), "gripper.velocity", positive=True),
        effort=float(models[gservo.model]["stall_torque"]), servo=gservo,
        max_opening=_num(_req(rg, "max_opening", "gripper"), "gripper.max_opening", positive=True),
        grip_effort=_num(_req(rg, "grip_effort", "gripper"), "gripper.grip_effort", positive=True))

    variants = _req(data, "variants", "")
    _req(variants, variant, "variants")
    rail = None
    if variant == "rail_arm":
        rr = _req(variants["rail_arm"], "rail", "variants.rail_arm")
        w = "variants.rail_arm.rail"
        rname = _req(rr, "name", w)
        if rname in names or rname == gname:
            raise DescriptionError(f"{w}.name: {rname!r} is already a joint name")
        lower = _num(_req(rr, "lower", w), f"{w}.lower")
        upper = _num(_req(rr, "upper", w), f"{w}.upper")
        _limits(lower, upper, f"{w}.lower/upper")
        axis = np.array(_vec3(_req(rr, "axis", w), f"{w}.axis"))
        if not math.isclose(float(np.linalg.norm(axis)), 1.0, abs_tol=1e-9):
            raise DescriptionError(f"{w}.axis: must be a unit vector, got {axis.tolist()}")
        pmac = _req(rr, "pmac", w)
        motor = _req(pmac, "motor", f"{w}.pmac")
        if isinstance(motor, bool) or not isinstance(motor, int) or not 1 <= motor <= 32:
            raise DescriptionError(f"{w}.pmac.motor: must be an integer 1..32, got {motor!r}")
        rail = RailSpec(
            name=rname, axis=tuple(axis.tolist()), lower=lower, upper=upper,  # type: ignore[arg-type]
            velocity=_num(_req(rr, "velocity", w), f"{w}.velocity", positive=True),
            acceleration=_num(_req(rr, "acceleration", w), f"{w}.acceleration", positive=True),
            carriage_mass=_num(rr.get("carriage_mass", 1.0), f"{w}.carriage_mass", positive=True),
            mount_xyz=_vec3(rr.get("mount_xyz", [0, 0, 0]), f"{w}.mount_xyz"),
            mount_rpy=tuple(parse_angle(v, f"{w}.mount_rpy[{i}]")  # type: ignore[arg-type]
                            for i, v in enumerate(rr.get("mount_rpy", [0, 0, 0]))),
            pmac_motor=motor,
            counts_per_metre=_num(_req(pmac, "counts_per_metre", f"{w}.pmac"),
                                  f"{w}.pmac.counts_per_metre", positive=True))
    rc = _req(data, "camera", "")
    camera = CameraSpec(
        frame=str(_req(rc, "frame", "camera")),
        xyz=_vec3(_req(rc, "xyz", "camera"), "camera.xyz"),
        rpy=tuple(parse_angle(v, f"camera.rpy[{i}]")  # type: ignore[arg-type]
                  for i, v in enumerate(_req(rc, "rpy", "camera"))),
        fovy=parse_angle(rc.get("fovy", "45 deg"), "camera.fovy"))
    if len(camera.rpy) != 3:
        raise DescriptionError(f"camera.rpy: expected 3 angles, got {len(camera.rpy)}")
    if not 0.0 < camera.fovy < math.pi:
        raise DescriptionError(f"camera.fovy: must be between 0 and 180 deg, got "
                               f"{math.degrees(camera.fovy):g} deg")
    tool_frame = str(arm.get("tool_frame", "tool0"))
    base_frame = str(arm.get("base_frame", "base_link"))
    rcol = _req(data, "collision", "")
    capsules = _capsules(_req(rcol, "capsules", "collision"),
                         [f"link{i}" for i in range(1, len(joints) + 1)], base_frame, tool_frame)
    return RobotDescription(
        name=str(data.get("name", "hyperarm")), variant=variant, camera=camera,
        base_frame=base_frame,
        tool_frame=tool_frame,
        joints=tuple(joints), gripper=gripper, rail=rail, source=source, capsules=capsules)


def default_description_path() -> Path:
    """Path of the YAML shipped with this package."""
    return Path(str(resources.files("hyperarm_description") / "config" / "hyperarm.yaml"))


def load_description(path: str | Path | None = None, variant: str = "arm") -> RobotDescription:
    """Load and validate the description. ``path`` defaults to the packaged YAML."""
    p = Path(path) if path else default_description_path()
    return parse_description(read_yaml(p, "robot description"), variant=variant, source=str(p))


def write_description_copy(source: str | Path | None, out: str | Path,
                           edit: Callable[[dict], None], header: str,
                           variant: str = "arm") -> Path:
    """A copy of the description YAML ``source`` (None: the packaged one), changed by
    ``edit`` (called on the parsed data), checked by parsing it, then written to ``out``
    under ``header`` (comment lines) for ``-p description_file:=<out>``. The source is never
    overwritten; a copy that does not parse is not written. Comments of the source are not
    kept. Raises :class:`DescriptionError` saying why."""
    src = Path(source) if source else default_description_path()
    data = read_yaml(src, "robot description")
    edit(data)
    dest = Path(out)
    if dest.resolve() == src.resolve():
        raise DescriptionError("refusing to overwrite the description itself: give another "
                               "file")
    text = header + yaml.safe_dump(data, sort_keys=False)
    try:
        parse_description(yaml.safe_load(text), variant=variant, source=str(dest))
    except DescriptionError as exc:
        raise DescriptionError(f"the changed description is not valid: {exc}") from None
    try:
        dest.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise DescriptionError(f"cannot write {dest}: {exc.strerror}") from exc
    return dest


def read_yaml(path: Path, what: str, error: type[Exception] = DescriptionError) -> Any:
    """The parsed YAML of file ``path`` (a ``what``, for the message); an unreadable file or
    invalid YAML raises ``error``. Shared with other YAML loaders (the mock's work cell)."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise error(f"cannot read {what} {path}: {exc.strerror}") from exc
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML: {exc}") from exc
