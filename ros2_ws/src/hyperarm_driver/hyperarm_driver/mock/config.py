"""The mock's configuration: servo dynamics, imperfections, work cell and camera (no ROS).

Loaded from a YAML file (the packaged default is ``config/workcell.yaml``, which mirrors
Danko & Oh's block-transfer demonstration) and validated here; every error names the
offending field with a dotted path, e.g. ``world.pegs.destination.radius``.

Units: SI throughout (m, rad, s, N, N·m). World coordinates are in the robot's root frame
(``base_link`` for the ``arm`` variant, ``world`` for ``rail_arm``), z up.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from hyperarm_description.model import check_number, check_vector, read_yaml

__all__ = [
    "MockError",
    "MockConfigError",
    "ServoConfig",
    "ImperfectionConfig",
    "PegConfig",
    "BlockConfig",
    "GraspConfig",
    "WorldConfig",
    "CameraConfig",
    "MockConfig",
    "default_workcell_path",
    "load_mock_config",
    "parse_mock_config",
]


class MockError(Exception):
    """Root of every error raised by the mock's core modules."""


class MockConfigError(MockError, ValueError):
    """The work-cell YAML is missing a field or holds an invalid value."""


# The number checks are the robot description's (hyperarm_description.model), raising this
# module's error; here they are wrapped with the key lookup and the default.
def _num(raw: Mapping[str, Any], key: str, where: str, default: float | None = None, *,
         positive: bool = False, nonneg: bool = False) -> float:
    if key not in raw:
        if default is None:
            raise MockConfigError(f"{where}.{key}: missing")
        return float(default)
    return check_number(raw[key], f"{where}.{key}", positive=positive, nonneg=nonneg,
                        error=MockConfigError)


def _vec(raw: Mapping[str, Any], key: str, where: str, n: int,
         default: tuple[float, ...] | None = None) -> tuple[float, ...]:
    if key not in raw:
        if default is None:
            raise MockConfigError(f"{where}.{key}: missing")
        return default
    return check_vector(raw[key], f"{where}.{key}", n, error=MockConfigError)


def _section(raw: Mapping[str, Any], key: str, where: str) -> Mapping[str, Any]:
    value = raw.get(key, {})
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise MockConfigError(f"{where}{key}: expected a mapping, got {type(value).__name__}")
    _reject_unknown(value, _KNOWN.get(key, None), f"{where}{key}")
    return value


def _reject_unknown(raw: Mapping[str, Any], known: frozenset[str] | None, where: str) -> None:
    if known is None:
        return
    unknown = sorted(set(raw) - known)
    if unknown:
        raise MockConfigError(f"{where}: unknown key(s) {unknown}; known: {sorted(known)}")


_KNOWN = {
    "servo": frozenset({"stiffness", "gripper_stiffness", "rail_stiffness", "lag", "damping",
                        "gripper_acceleration"}),
    "imperfections": frozenset({"repeatability", "move_threshold", "position_noise",
                                "velocity_noise", "effort_noise", "state_latency",
                                "command_latency", "seed"}),
    "world": frozenset({"table_height", "contact_stiffness", "friction", "pegs", "block",
                        "grasp"}),
    "camera": frozenset({"rate", "position_noise", "orientation_noise", "latency", "seed"}),
}


@dataclass(frozen=True)
class ServoConfig:
    """Servo dynamics shared by every joint.

    stiffness: N·m/rad, the position loop's finite stiffness (arm joints); gripper_stiffness
    likewise for the gripper; rail_stiffness N/m for the rail axis. lag: s, first-order time
    constant between the velocity/acceleration-limited profile and the joint. damping:
    N·m·s/rad viscous friction of a joint in torque mode or with torque off.
    gripper_acceleration: rad/s² (the description has none for the gripper).
    """

    stiffness: float = 20.0
    gripper_stiffness: float = 5.0
    rail_stiffness: float = 2.0e4
    lag: float = 0.02
    damping: float = 0.05
    gripper_acceleration: float = 20.0


@dataclass(frozen=True)
class ImperfectionConfig:
    """Imperfections of the real arm.

    repeatability: rad, standard deviation of a hidden joint offset drawn anew for every
    move (backlash and link flex that the encoders do not see: joint_states look perfect but
    the true tool, the camera and the work cell see the offset). move_threshold: rad, a goal
    change larger than this starts a new move. position/velocity/effort_noise: standard
    deviations added to joint_states (rad, rad/s, N·m). state_latency / command_latency: s.
    seed: integer for reproducible runs, or null for a random one.
    """

    repeatability: float = 0.0
    move_threshold: float = 0.02
    position_noise: float = 0.0
    velocity_noise: float = 0.0
    effort_noise: float = 0.0
    state_latency: float = 0.0
    command_latency: float = 0.0
    seed: int | None = None


@dataclass(frozen=True)
class PegConfig:
    """A vertical cylindrical peg standing on the table: axis at ``xy`` (m), height, radius."""

    name: str
    xy: tuple[float, float]
    height: float
    radius: float


@dataclass(frozen=True)
class BlockConfig:
    """The block: box of ``size`` (x, y, z; m) with a vertical through-hole of ``hole_radius``
    at its centre, mass (kg), starting on peg ``start``."""

    size: tuple[float, float, float]
    hole_radius: float
    mass: float
    start: str


@dataclass(frozen=True)
class GraspConfig:
    """Grasping. offset: grasp point in tool0 (m). capture_radius: m, how far the block's
    centre may be from the grasp point for the fingers to close on it. min_effort: N·m, the
    gripper servo torque below which the block slips out (dropped)."""

    offset: tuple[float, float, float]
    capture_radius: float
    min_effort: float


@dataclass(frozen=True)
class WorldConfig:
    """The work cell: table height (m), contact stiffness (N/m), Coulomb friction
    coefficient of the block on the peg tops and the table, pegs, block, grasping."""

    table_height: float
    contact_stiffness: float
    friction: float
    pegs: tuple[PegConfig, ...]
    block: BlockConfig
    grasp: GraspConfig

    def peg(self, name: str) -> PegConfig:
        for p in self.pegs:
            if p.name == name:
                return p
        raise MockConfigError(f"no peg named {name!r} (pegs: {[p.name for p in self.pegs]})")

    def clearance(self, peg: str) -> float:
        """Radial clearance (m) between the block's hole and peg ``peg``."""
        return self.block.hole_radius - self.peg(peg).radius


@dataclass(frozen=True)
class CameraConfig:
    """Simulated camera: rate (Hz), noise standard deviations (m per axis of camera_link,
    rad per axis of a small rotation), latency between exposure and publication (s), seed."""

    rate: float = 10.0
    position_noise: float = 0.0
    orientation_noise: float = 0.0
    latency: float = 0.0
    seed: int | None = None


@dataclass(frozen=True)
class MockConfig:
    servo: ServoConfig
    imperfections: ImperfectionConfig
    world: WorldConfig
    camera: CameraConfig
    source: str = "<data>"


def _seed(raw: Mapping[str, Any], where: str) -> int | None:
    value = raw.get("seed")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise MockConfigError(
            f"{where}.seed: must be a non-negative integer or null, got {value!r}")
    return value


def _world(raw: Mapping[str, Any]) -> WorldConfig:
    w = "world"
    raw_pegs = raw.get("pegs")
    if not isinstance(raw_pegs, Mapping) or not raw_pegs:
        raise MockConfigError(f"{w}.pegs: must be a non-empty mapping of peg name to peg")
    pegs = []
    for name, rp in raw_pegs.items():
        pw = f"{w}.pegs.{name}"
        if not isinstance(rp, Mapping):
            raise MockConfigError(f"{pw}: expected a mapping")
        _reject_unknown(rp, frozenset({"xy", "height", "radius"}), pw)
        pegs.append(PegConfig(name=str(name), xy=_vec(rp, "xy", pw, 2),  # type: ignore[arg-type]
                              height=_num(rp, "height", pw, positive=True),
                              radius=_num(rp, "radius", pw, positive=True)))
    rb = raw.get("block")
    if not isinstance(rb, Mapping):
        raise MockConfigError(f"{w}.block: missing or not a mapping")
    _reject_unknown(rb, frozenset({"size", "hole_radius", "mass", "start"}), f"{w}.block")
    size = _vec(rb, "size", f"{w}.block", 3)
    if min(size) <= 0.0:
        raise MockConfigError(f"{w}.block.size: every side must be > 0, got {list(size)}")
    block = BlockConfig(size=size,  # type: ignore[arg-type]
                        hole_radius=_num(rb, "hole_radius", f"{w}.block", positive=True),
                        mass=_num(rb, "mass", f"{w}.block", 0.05, positive=True),
                        start=str(rb.get("start", "")))
    names = [p.name for p in pegs]
    if block.start not in names:
        raise MockConfigError(f"{w}.block.start: {block.start!r} is not a peg (pegs: {names})")
    if 2.0 * block.hole_radius >= min(size[0], size[1]):
        raise MockConfigError(f"{w}.block.hole_radius: a hole of radius {block.hole_radius:g} m "
                              f"does not fit in a block of {size[0]:g} x {size[1]:g} m")
    for p in pegs:
        if p.radius >= block.hole_radius:
            raise MockConfigError(
                f"{w}.pegs.{p.name}.radius: {p.radius:g} m does not fit the block's hole "
                f"(hole_radius {block.hole_radius:g} m): clearance must be > 0")
        if p.height <= size[2]:
            raise MockConfigError(f"{w}.pegs.{p.name}.height: {p.height:g} m must exceed the "
                                  f"block's height {size[2]:g} m")
    for i, a in enumerate(pegs):
        for b in pegs[i + 1:]:
            if math.dist(a.xy, b.xy) < max(size[0], size[1]) + a.radius + b.radius:
                raise MockConfigError(f"{w}.pegs: {a.name} and {b.name} are too close for the "
                                      f"block to sit on one of them")
    rg = raw.get("grasp", {}) or {}
    if not isinstance(rg, Mapping):
        raise MockConfigError(f"{w}.grasp: expected a mapping")
    _reject_unknown(rg, frozenset({"offset", "capture_radius", "min_effort"}), f"{w}.grasp")
    grasp = GraspConfig(offset=_vec(rg, "offset", f"{w}.grasp", 3,  # type: ignore[arg-type]
                                    (0.0, 0.0, 0.0)),
                        capture_radius=_num(rg, "capture_radius", f"{w}.grasp", 0.015,
                                            positive=True),
                        min_effort=_num(rg, "min_effort", f"{w}.grasp", 0.3, positive=True))
    return WorldConfig(table_height=_num(raw, "table_height", w),
                       contact_stiffness=_num(raw, "contact_stiffness", w, 5000.0, positive=True),
                       friction=_num(raw, "friction", w, 0.5, nonneg=True),
                       pegs=tuple(pegs), block=block, grasp=grasp)


def parse_mock_config(data: Any, source: str = "<data>") -> MockConfig:
    """Validate a parsed YAML mapping and build the mock's configuration."""
    if not isinstance(data, Mapping):
        raise MockConfigError(f"{source}: top level must be a mapping")
    _reject_unknown(data, frozenset({"schema_version", *_KNOWN}), "<top level>")
    if data.get("schema_version", 1) != 1:
        raise MockConfigError(
            f"schema_version: only 1 is known, got {data.get('schema_version')!r}")
    rs = _section(data, "servo", "")
    servo = ServoConfig(
        stiffness=_num(rs, "stiffness", "servo", ServoConfig.stiffness, positive=True),
        gripper_stiffness=_num(rs, "gripper_stiffness", "servo", ServoConfig.gripper_stiffness,
                               positive=True),
        rail_stiffness=_num(rs, "rail_stiffness", "servo", ServoConfig.rail_stiffness,
                            positive=True),
        lag=_num(rs, "lag", "servo", ServoConfig.lag, nonneg=True),
        damping=_num(rs, "damping", "servo", ServoConfig.damping, positive=True),
        gripper_acceleration=_num(rs, "gripper_acceleration", "servo",
                                  ServoConfig.gripper_acceleration, positive=True))
    ri = _section(data, "imperfections", "")
    imp = ImperfectionConfig(
        repeatability=_num(ri, "repeatability", "imperfections", 0.0, nonneg=True),
        move_threshold=_num(ri, "move_threshold", "imperfections", 0.02, positive=True),
        position_noise=_num(ri, "position_noise", "imperfections", 0.0, nonneg=True),
        velocity_noise=_num(ri, "velocity_noise", "imperfections", 0.0, nonneg=True),
        effort_noise=_num(ri, "effort_noise", "imperfections", 0.0, nonneg=True),
        state_latency=_num(ri, "state_latency", "imperfections", 0.0, nonneg=True),
        command_latency=_num(ri, "command_latency", "imperfections", 0.0, nonneg=True),
        seed=_seed(ri, "imperfections"))
    rw = data.get("world")
    if not isinstance(rw, Mapping):
        raise MockConfigError("world: missing or not a mapping")
    _reject_unknown(rw, _KNOWN["world"], "world")
    rc = _section(data, "camera", "")
    camera = CameraConfig(
        rate=_num(rc, "rate", "camera", 10.0, positive=True),
        position_noise=_num(rc, "position_noise", "camera", 0.0, nonneg=True),
        orientation_noise=_num(rc, "orientation_noise", "camera", 0.0, nonneg=True),
        latency=_num(rc, "latency", "camera", 0.0, nonneg=True),
        seed=_seed(rc, "camera"))
    if camera.rate > 1000.0:
        raise MockConfigError(f"camera.rate: at most 1000 Hz, got {camera.rate:g}")
    return MockConfig(servo=servo, imperfections=imp, world=_world(rw), camera=camera,
                      source=source)


def default_workcell_path() -> Path:
    """The packaged work cell: the installed share/ copy, else the source tree's."""
    try:
        from ament_index_python.packages import get_package_share_directory

        p = Path(get_package_share_directory("hyperarm_driver")) / "config" / "workcell.yaml"
        if p.exists():
            return p
    except Exception:  # noqa: BLE001 - ament index absent (plain Python use): fall through
        pass
    return Path(__file__).resolve().parents[2] / "config" / "workcell.yaml"


def load_mock_config(path: str | Path | None = None) -> MockConfig:
    """Load and validate a work-cell YAML (``None`` or ``''`` = the packaged default)."""
    p = Path(path) if path else default_workcell_path()
    return parse_mock_config(read_yaml(p, "work-cell file", MockConfigError), source=str(p))
