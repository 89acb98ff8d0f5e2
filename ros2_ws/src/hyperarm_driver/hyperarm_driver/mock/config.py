"""The mock's configuration: servo dynamics, imperfections, work cell and camera (no ROS).

Loaded from a YAML file (the packaged default is ``config/workcell.yaml``, which mirrors
Danko & Oh's block-transfer demonstration) and validated here; every error names the
offending field with a dotted path, e.g. ``world.pegs.destination.radius``.

Units: SI throughout (m, rad, s, N, N·m). World coordinates are in the robot's root frame
(``base_link`` for the ``arm`` variant, ``world`` for ``rail_arm``), z up.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from hyperarm_description.model import check_number, check_vector, read_yaml
from hyperarm_description.world import (MOCK_WORLD_KEYS, WORLD_KEYS, BlockSpec, PegSpec,
                                        PoleSpec, WorldSpec, parse_world)

__all__ = [
    "MockError",
    "MockConfigError",
    "ServoConfig",
    "ImperfectionConfig",
    "PegConfig",
    "BlockConfig",
    "PoleConfig",
    "GraspConfig",
    "WorldConfig",
    "CameraConfig",
    "CurrentConfig",
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
                        "gripper_acceleration", "profile_acceleration", "mode_switch_gap"}),
    "current": frozenset({"enabled", "torque_constant_error", "friction", "quantum"}),
    "imperfections": frozenset({"repeatability", "move_threshold", "position_noise",
                                "velocity_noise", "effort_noise", "state_latency",
                                "command_latency", "seed"}),
    "world": WORLD_KEYS | MOCK_WORLD_KEYS,
    "camera": frozenset({"rate", "position_noise", "orientation_noise", "latency", "seed",
                         "dropouts"}),
}


@dataclass(frozen=True)
class ServoConfig:
    """Servo dynamics shared by every joint.

    stiffness: N·m/rad, the position loop's finite stiffness (arm joints); gripper_stiffness
    likewise for the gripper; rail_stiffness N/m for the rail axis. lag: s, first-order time
    constant between the velocity/acceleration-limited profile and the joint. damping:
    N·m·s/rad viscous friction of a joint in torque mode or with torque off.
    gripper_acceleration: rad/s² (the description has none for the gripper).
    profile_acceleration: rad/s², the arm servos' Profile Acceleration. Absent (None, the
    default): each joint's acceleration limit from the description, as dynamixel_driver
    writes it into the servos; 0: unlimited (a servo's Profile Acceleration 0: the profile
    moves at up to the velocity limit and does not brake towards each streamed goal).
    (The rail keeps its acceleration limit: the PMAC's jog profile.)
    """

    stiffness: float = 20.0
    gripper_stiffness: float = 5.0
    rail_stiffness: float = 2.0e4
    lag: float = 0.02
    damping: float = 0.05
    gripper_acceleration: float = 20.0
    profile_acceleration: float | None = None
    mode_switch_gap: float = 0.005


@dataclass(frozen=True)
class CurrentConfig:
    """The servos' current model (on by default): what a servo exerts for a commanded
    torque or current limit, and the effort it reports, differ from the nominal conversion
    the driver uses. Per servo (arm joints and gripper), drawn once from
    ``imperfections.seed``: a torque-constant ratio (true / nominal) uniform in
    1 +- ``torque_constant_error``, a Coulomb friction uniform in 0.5..1.5 x ``friction``
    (N·m, opposing motion); currents are quantized to ``quantum`` (N·m of nominal torque:
    one unit of Goal/Present Current, ~2.7-3.4 mA). ``enabled: false`` = ideal servos."""

    enabled: bool = True
    torque_constant_error: float = 0.10
    friction: float = 0.03
    quantum: float = 0.005


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


# The work cell's geometry is the shared schema of hyperarm_description.world (the IK
# collision checker reads the same files); these names are kept for the mock's users.
PegConfig = PegSpec
BlockConfig = BlockSpec
PoleConfig = PoleSpec


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
    """The work cell: its geometry ``spec`` (table, pegs, block or None, poles; see
    hyperarm_description.world) and the mock's contact settings: contact stiffness (N/m),
    Coulomb friction coefficient of the block on the peg tops and the table, grasping."""

    spec: WorldSpec
    contact_stiffness: float
    friction: float
    grasp: GraspConfig

    @property
    def table_height(self) -> float:
        return self.spec.table_height

    @property
    def pegs(self) -> tuple[PegSpec, ...]:
        return self.spec.pegs

    @property
    def block(self) -> BlockSpec | None:
        return self.spec.block

    @property
    def poles(self) -> tuple[PoleSpec, ...]:
        return self.spec.poles

    def peg(self, name: str) -> PegSpec:
        return self.spec.peg(name)

    def clearance(self, peg: str) -> float:
        """Radial clearance (m) between the block's hole and peg ``peg``."""
        return self.spec.clearance(peg)


@dataclass(frozen=True)
class CameraConfig:
    """Simulated camera: rate (Hz), noise standard deviations (m per axis of camera_link,
    rad per axis of a small rotation), latency between exposure and publication (s), seed."""

    rate: float = 10.0
    position_noise: float = 0.0
    orientation_noise: float = 0.0
    latency: float = 0.0
    seed: int | None = None
    #: camera faults: (start s, duration s or None = for good) of simulated time during
    #: which images carry no detections (the ground truth topic goes on)
    dropouts: tuple[tuple[float, float | None], ...] = ()

    def dropped(self, t: float) -> bool:
        """Whether an image taken at simulated time ``t`` (s) falls in a dropout."""
        return any(t >= a and (d is None or t < a + d) for a, d in self.dropouts)


@dataclass(frozen=True)
class MockConfig:
    servo: ServoConfig
    imperfections: ImperfectionConfig
    world: WorldConfig
    camera: CameraConfig
    source: str = "<data>"
    current: CurrentConfig = CurrentConfig()


def _seed(raw: Mapping[str, Any], where: str) -> int | None:
    value = raw.get("seed")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise MockConfigError(
            f"{where}.seed: must be a non-negative integer or null, got {value!r}")
    return value


def _dropouts(raw: Any) -> tuple[tuple[float, float | None], ...]:
    """``camera.dropouts``: a list of {start: s, duration: s or null (for good)}."""
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise MockConfigError("camera.dropouts: expected a list of {start, duration}")
    out = []
    for i, rd in enumerate(raw):
        w = f"camera.dropouts[{i}]"
        if not isinstance(rd, Mapping):
            raise MockConfigError(f"{w}: expected a mapping {{start, duration}}")
        _reject_unknown(rd, frozenset({"start", "duration"}), w)
        start = _num(rd, "start", w, nonneg=True)
        dur = rd.get("duration")
        out.append((start, None if dur is None else
                    check_number(dur, f"{w}.duration", positive=True, error=MockConfigError)))
    return tuple(out)


def _world(raw: Mapping[str, Any]) -> WorldConfig:
    w = "world"
    spec = parse_world(raw, w, extra_keys=MOCK_WORLD_KEYS, error=MockConfigError)
    rg = raw.get("grasp", {}) or {}
    if not isinstance(rg, Mapping):
        raise MockConfigError(f"{w}.grasp: expected a mapping")
    _reject_unknown(rg, frozenset({"offset", "capture_radius", "min_effort"}), f"{w}.grasp")
    grasp = GraspConfig(offset=_vec(rg, "offset", f"{w}.grasp", 3,  # type: ignore[arg-type]
                                    (0.0, 0.0, 0.0)),
                        capture_radius=_num(rg, "capture_radius", f"{w}.grasp", 0.015,
                                            positive=True),
                        min_effort=_num(rg, "min_effort", f"{w}.grasp", 0.3, positive=True))
    return WorldConfig(spec=spec,
                       contact_stiffness=_num(raw, "contact_stiffness", w, 5000.0, positive=True),
                       friction=_num(raw, "friction", w, 0.5, nonneg=True), grasp=grasp)


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
                                  ServoConfig.gripper_acceleration, positive=True),
        profile_acceleration=(None if rs.get("profile_acceleration") is None else
                              _num(rs, "profile_acceleration", "servo", nonneg=True)),
        mode_switch_gap=_num(rs, "mode_switch_gap", "servo", ServoConfig.mode_switch_gap,
                             nonneg=True))
    rcur = _section(data, "current", "")
    enabled = rcur.get("enabled", True)
    if not isinstance(enabled, bool):
        raise MockConfigError(f"current.enabled: expected true or false, got {enabled!r}")
    current = CurrentConfig(
        enabled=enabled,
        torque_constant_error=_num(rcur, "torque_constant_error", "current",
                                   CurrentConfig.torque_constant_error, nonneg=True),
        friction=_num(rcur, "friction", "current", CurrentConfig.friction, nonneg=True),
        quantum=_num(rcur, "quantum", "current", CurrentConfig.quantum, nonneg=True))
    if current.torque_constant_error >= 0.5:
        raise MockConfigError("current.torque_constant_error: must be < 0.5 (a fraction), got "
                              f"{current.torque_constant_error:g}")
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
        seed=_seed(rc, "camera"), dropouts=_dropouts(rc.get("dropouts")))
    if camera.rate > 1000.0:
        raise MockConfigError(f"camera.rate: at most 1000 Hz, got {camera.rate:g}")
    return MockConfig(servo=servo, imperfections=imp, world=_world(rw), camera=camera,
                      source=source, current=current)


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
