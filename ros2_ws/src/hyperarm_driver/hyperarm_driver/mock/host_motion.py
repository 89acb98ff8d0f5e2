"""Host motion of the simulated robot: a scripted rail sweep, a scripted 6-D motion of the
robot's base in ``world`` (a hovering UAV's sway, heave and tilt) and an optional passive
6-D spring-damper mount that the arm's reaction moves (no ROS).

Units: m, rad, s, kg, N, N·m. ``world`` is the robot's root frame at rest (``base_link`` on
the arm variant, the rail's fixed frame on ``rail_arm``): the work cell (table, pegs, block,
poles) and the camera stay where they are in it, gravity stays along world -z.

How it enters the simulation (:class:`JointSim` calls :meth:`HostMotion.before_step` and
:meth:`HostMotion.after_step` around every MuJoCo step): the generated model has the
robot's root on a mocap body ``host`` (hyperarm_description.mjcf), whose pose the script
sets; MuJoCo then computes every link, tool and capsule pose in world, where the work cell
is. The root's acceleration enters as d'Alembert forces on every body below the host
(-m·(a + α × r) at each body's centre of mass, r from the root's origin; the velocity
products of the root's own rotation are neglected: below 0.05 m/s² for the shipped
motions), so the joints' torques, the reported efforts, the mount and the contacts see the
tilt and the sway; gravity stays world -z.

- Rail sweep (``rail``, rail_arm only): the rail's profile follows a back-and-forth between
  ``center - amplitude`` and ``center + amplitude`` at ``speed`` with ``acceleration`` at
  the turnarounds (``center``: where the rail is when the motion starts); the rail's servo
  (its lag and stiffness) follows the profile. The ramp scales the profile's speed (a time
  warp), so the rail never exceeds ``speed`` and stops at rest where it is.
- Base motion (``base``): a sum of sines per axis (x, y, z in m; roll, pitch, yaw in rad,
  ``R = Rz(yaw) Ry(pitch) Rx(roll)``), amplitude scaled by the ramp: it starts and ends at
  the rest pose with no jump in position, velocity or acceleration.
- Ramp: smootherstep (C2) over ``ramp`` s; stopping midway reverses it.
- Passive mount (``mount``): the root hangs on six spring-damper joints of MuJoCo
  (``mount_x`` .. ``mount_yaw``: diagonal stiffness and damping, translations then
  rotations in the host's axes) from the scripted host frame, the mounted body (``mass``,
  diagonal ``inertia``, at the root's origin) between them; MuJoCo moves it under the arm's
  reaction, gravity and contacts. The springs' rest positions are set so that they carry
  the load at the moment the motion starts (preloaded), so the base moves only with
  changes of that load.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jsonschema
import numpy as np
import pinocchio as pin

from hyperarm_description.model import read_yaml

from .config import MockError, default_workcell_path
from .servos import ControlMode
from .world import WorldEvent

if TYPE_CHECKING:
    from .joint_sim import JointSim

__all__ = ["HostMotionError", "HostMotionConfigError", "AXES", "Oscillation", "RailSweep",
           "MountSpec", "HostMotionSpec", "Phase", "Ramp", "HostMotion",
           "smootherstep", "host_motion_schema", "parse_host_motion", "load_host_motion",
           "shipped_host_motions", "host_motion_path", "GRAVITY"]

AXES = ("x", "y", "z", "roll", "pitch", "yaw")
GRAVITY = np.array([0.0, 0.0, -9.81])    # m/s², world
MAX_TRANSLATION = 0.2    # m, amplitude of one sine of the base
MAX_ROTATION = 0.35      # rad (20°), amplitude of one sine of the base (small-angle host)


class HostMotionError(MockError):
    """A host-motion request the simulation refuses (e.g. starting the rail sweep with the
    rail unhomed or its sweep outside the rail's range)."""


class HostMotionConfigError(HostMotionError, ValueError):
    """A host-motion YAML (or value) is invalid; the message names the field."""


def _finite(value: float, where: str, *, positive: bool = False, nonneg: bool = False,
            most: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise HostMotionConfigError(f"{where}: expected a finite number, got {value!r}")
    if positive and not value > 0.0:
        raise HostMotionConfigError(f"{where}: must be > 0, got {value!r}")
    if nonneg and not value >= 0.0:
        raise HostMotionConfigError(f"{where}: must be >= 0, got {value!r}")
    if most is not None and value > most:
        raise HostMotionConfigError(f"{where}: at most {most:g}, got {value!r}")
    return float(value)


# -- specification --------------------------------------------------------------------------
@dataclass(frozen=True)
class Oscillation:
    """One sine of the base motion: ``amplitude`` (m for x/y/z, rad for roll/pitch/yaw) *
    sin(2π ``frequency`` (Hz) t + ``phase`` (rad)), t from the motion's start."""

    axis: str
    amplitude: float
    frequency: float
    phase: float = 0.0

    def __post_init__(self) -> None:
        if self.axis not in AXES:
            raise HostMotionConfigError(f"axis: {self.axis!r} is not one of {', '.join(AXES)}")
        most = MAX_TRANSLATION if AXES.index(self.axis) < 3 else MAX_ROTATION
        _finite(self.amplitude, "amplitude", nonneg=True, most=most)
        _finite(self.frequency, "frequency", positive=True, most=5.0)
        _finite(self.phase, "phase")


@dataclass(frozen=True)
class RailSweep:
    """The rail's back-and-forth: ±``amplitude`` (m) about its start at ``speed`` (m/s),
    turning around with ``acceleration`` (m/s²)."""

    amplitude: float
    speed: float
    acceleration: float = 0.5

    def __post_init__(self) -> None:
        _finite(self.amplitude, "rail.amplitude", positive=True, most=1.5)
        _finite(self.speed, "rail.speed", positive=True, most=2.0)
        _finite(self.acceleration, "rail.acceleration", positive=True, most=20.0)
        if self.speed ** 2 / self.acceleration > 2.0 * self.amplitude:
            raise HostMotionConfigError(
                f"rail.acceleration: {self.acceleration:g} m/s² cannot turn around at "
                f"{self.speed:g} m/s within ±{self.amplitude:g} m (needs >= "
                f"{self.speed ** 2 / (2.0 * self.amplitude):g} m/s²)")

    @property
    def period(self) -> float:
        """s, one full back-and-forth at full speed."""
        v, a = self.speed, self.acceleration
        cruise = (2.0 * self.amplitude - v * v / a) / v
        return 2.0 * (cruise + 2.0 * v / a)

    def position(self, tau: float) -> tuple[float, float, float]:
        """Offset (m), its derivatives d/dτ (m/s) and d²/dτ² (m/s²) at profile time τ (s):
        0 at τ = 0, moving towards +amplitude."""
        v, a, amp = self.speed, self.acceleration, self.amplitude
        x1 = amp - v * v / (2.0 * a)               # where a turnaround starts
        cruise = (2.0 * amp - v * v / a) / v
        turn = 2.0 * v / a
        u = (tau + x1 / v) % self.period           # u = 0: at -x1 going up
        if u < cruise:
            return -x1 + v * u, v, 0.0
        u -= cruise
        if u < turn:
            return x1 + v * u - 0.5 * a * u * u, v - a * u, -a
        u -= turn
        if u < cruise:
            return x1 - v * u, -v, 0.0
        u -= cruise
        return -x1 - v * u + 0.5 * a * u * u, -v + a * u, a


@dataclass(frozen=True)
class MountSpec:
    """Passive mount: the mounted body's ``mass`` (kg) and diagonal ``inertia`` (kg·m², at
    the root's origin, root axes), diagonal ``stiffness`` (N/m x3, then N·m/rad x3) and
    ``damping`` (N·s/m x3, then N·m·s/rad x3)."""

    mass: float
    inertia: tuple[float, float, float]
    stiffness: tuple[float, ...]
    damping: tuple[float, ...]

    def __post_init__(self) -> None:
        _finite(self.mass, "mount.mass", positive=True)
        for name, values, n, pos in (("inertia", self.inertia, 3, True),
                                     ("stiffness", self.stiffness, 6, True),
                                     ("damping", self.damping, 6, False)):
            if len(values) != n:
                raise HostMotionConfigError(f"mount.{name}: expected {n} numbers, got "
                                            f"{len(values)}")
            for i, v in enumerate(values):
                _finite(v, f"mount.{name}[{i}]", positive=pos, nonneg=not pos)

    def body_inertia(self) -> pin.Inertia:
        return pin.Inertia(self.mass, np.zeros(3), np.diag(self.inertia))


@dataclass(frozen=True)
class HostMotionSpec:
    """A host motion: ``ramp`` (s), optional rail sweep, base sines and passive mount."""

    name: str
    ramp: float = 2.0
    rail: RailSweep | None = None
    base: tuple[Oscillation, ...] = ()
    mount: MountSpec | None = None
    description: str = ""
    source: str = "<data>"

    def __post_init__(self) -> None:
        _finite(self.ramp, "ramp", positive=True, most=60.0)
        if self.rail is None and not self.base and self.mount is None:
            raise HostMotionConfigError("give at least one of rail, base, mount")


def host_motion_schema() -> dict:
    """JSON schema (draft 2020-12) of a host-motion YAML."""
    pos = {"type": "number", "exclusiveMinimum": 0}
    nonneg = {"type": "number", "minimum": 0}

    def vec(n: int, item: dict) -> dict:
        return {"type": "array", "items": item, "minItems": n, "maxItems": n}

    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "type": "object", "additionalProperties": False, "required": ["schema_version"],
        "anyOf": [{"required": ["rail"]}, {"required": ["base"]}, {"required": ["mount"]}],
        "properties": {
            "schema_version": {"const": 1},
            "description": {"type": "string"},
            "ramp": pos,
            "rail": {"type": "object", "additionalProperties": False,
                     "required": ["amplitude", "speed"],
                     "properties": {"amplitude": pos, "speed": pos, "acceleration": pos}},
            "base": {"type": "array", "minItems": 1, "items": {
                "type": "object", "additionalProperties": False,
                "required": ["axis", "amplitude", "frequency"],
                "properties": {"axis": {"enum": list(AXES)}, "amplitude": nonneg,
                               "frequency": pos, "phase": {"type": "number"}}}},
            "mount": {"type": "object", "additionalProperties": False,
                      "required": ["mass", "inertia", "stiffness", "damping"],
                      "properties": {"mass": pos, "inertia": vec(3, pos),
                                     "stiffness": vec(6, pos), "damping": vec(6, nonneg)}},
        },
    }


def _where(path) -> str:
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".") \
        or "<top level>"


def _schema_message(err: jsonschema.ValidationError) -> str:
    if err.validator == "additionalProperties" and isinstance(err.instance, dict):
        known = err.schema.get("properties", {})
        extra = sorted(set(err.instance) - set(known), key=str)
        return f"unknown field(s) {extra}; known: {sorted(known)}"
    if err.validator == "anyOf" and not err.absolute_path:
        return "give at least one of rail, base, mount"
    return err.message


def parse_host_motion(data: Any, source: str = "<data>", name: str = "") -> HostMotionSpec:
    """Validate a parsed host-motion YAML (schema, then the constructors' checks) and build
    its spec; raises :class:`HostMotionConfigError` naming the source and the field."""
    validator = jsonschema.Draft202012Validator(host_motion_schema())
    errors = sorted(validator.iter_errors(data), key=lambda e: -len(e.absolute_path))
    if errors:
        err = errors[0]
        raise HostMotionConfigError(f"{source}: {_where(err.absolute_path)}: "
                                    f"{_schema_message(err)}")
    try:
        rail = RailSweep(**data["rail"]) if "rail" in data else None
        base = []
        for i, raw in enumerate(data.get("base", ())):
            try:
                base.append(Oscillation(**raw))
            except HostMotionConfigError as exc:
                raise HostMotionConfigError(f"base[{i}].{exc}") from None
        mount = None
        if "mount" in data:
            m = data["mount"]
            mount = MountSpec(mass=m["mass"], inertia=tuple(m["inertia"]),
                              stiffness=tuple(m["stiffness"]), damping=tuple(m["damping"]))
        return HostMotionSpec(name=name or Path(source).stem, ramp=data.get("ramp", 2.0),
                              rail=rail, base=tuple(base), mount=mount,
                              description=data.get("description", ""), source=source)
    except HostMotionConfigError as exc:
        raise HostMotionConfigError(f"{source}: {exc}") from None


def _shipped_dir() -> Path:
    """config/host_motion, next to the packaged work cell (installed share/, else source)."""
    return default_workcell_path().parent / "host_motion"


def shipped_host_motions() -> list[str]:
    """Names of the host motions shipped in config/host_motion."""
    return sorted(p.stem for p in _shipped_dir().glob("*.yaml"))


def host_motion_path(value: str) -> Path:
    """A host-motion YAML by path (ends in .yaml/.yml or contains a /) or by the name of a
    shipped one."""
    if value.endswith((".yaml", ".yml")) or "/" in value:
        return Path(value)
    p = _shipped_dir() / f"{value}.yaml"
    if not p.exists():
        raise HostMotionConfigError(f"host_motion {value!r}: no such shipped motion; shipped: "
                                    f"{', '.join(shipped_host_motions())} (or a path to a "
                                    ".yaml file)")
    return p


def load_host_motion(value: str | Path) -> HostMotionSpec:
    """Load and validate a host-motion YAML, by path or shipped name."""
    p = host_motion_path(str(value))
    return parse_host_motion(read_yaml(p, "host-motion file", HostMotionConfigError),
                             source=str(p), name=p.stem)


# -- ramp -----------------------------------------------------------------------------------
def smootherstep(u: float) -> tuple[float, float, float]:
    """s = 6u⁵ - 15u⁴ + 10u³ on [0, 1] and its first two derivatives (zero at both ends)."""
    u = min(max(u, 0.0), 1.0)
    return (u ** 3 * (10.0 - 15.0 * u + 6.0 * u * u), 30.0 * u * u * (1.0 - u) ** 2,
            60.0 * u * (1.0 - u) * (1.0 - 2.0 * u))


class Phase(str, Enum):
    OFF = "off"
    RAMP_IN = "ramping_in"
    ON = "on"
    RAMP_OUT = "ramping_out"


class Ramp:
    """The motion's scale s(t) in [0, 1]: 0 -> 1 over ``duration`` s after :meth:`start`,
    back to 0 after :meth:`stop` (smootherstep; a stop midway reverses from where it is)."""

    def __init__(self, duration: float) -> None:
        self.duration = _finite(duration, "ramp", positive=True)
        self.u = 0.0
        self.direction = 0

    @property
    def phase(self) -> Phase:
        if self.direction > 0:
            return Phase.RAMP_IN
        if self.direction < 0:
            return Phase.RAMP_OUT
        return Phase.ON if self.u >= 1.0 else Phase.OFF

    def start(self) -> None:
        if self.u < 1.0:
            self.direction = 1

    def stop(self) -> None:
        self.direction = -1 if self.u > 0.0 else 0

    def reset(self) -> None:
        self.u, self.direction = 0.0, 0

    def step(self, dt: float) -> None:
        if self.direction:
            self.u = min(max(self.u + self.direction * dt / self.duration, 0.0), 1.0)
            if self.u in (0.0, 1.0):
                self.direction = 0

    def value(self) -> tuple[float, float, float]:
        """s, ds/dt (1/s), d²s/dt² (1/s²) now."""
        s, d1, d2 = smootherstep(self.u)
        if not self.direction:
            return s, 0.0, 0.0
        return s, self.direction * d1 / self.duration, d2 / self.duration ** 2


# -- passive mount --------------------------------------------------------------------------
# -- the host motion in a simulation --------------------------------------------------------
def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of two 3-vectors (np.cross costs ~20x more on tiny arrays)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def _rpy_kinematics(c: np.ndarray, cd: np.ndarray, cdd: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """R = Rz(yaw) Ry(pitch) Rx(roll) of ``c[3:]`` and its angular velocity and acceleration
    (rad/s, rad/s², world) from the angles' first and second time derivatives."""
    roll, pitch, yaw = c[3:]
    rz = pin.rpy.rpyToMatrix(0.0, 0.0, yaw)
    rzy = rz @ pin.rpy.rpyToMatrix(0.0, pitch, 0.0)
    ez, ey, ex = np.array([0.0, 0.0, 1.0]), rz[:, 1], rzy[:, 0]
    dr, dp, dy = cd[3:]
    w_zy = dy * ez + dp * ey
    omega = w_zy + dr * ex
    alpha = (cdd[5] * ez + cdd[4] * ey + dp * _cross(dy * ez, ey)
             + cdd[3] * ex + dr * _cross(w_zy, ex))
    return rzy @ pin.rpy.rpyToMatrix(roll, 0.0, 0.0), omega, alpha


@dataclass
class _Script:
    """Per-step results of the scripted part (world)."""

    pose: pin.SE3 = field(default_factory=pin.SE3.Identity)
    accel: np.ndarray = field(default_factory=lambda: np.zeros(6))  # spatial, world origin


class _MountView:
    """The passive mount's state as MuJoCo has it: ``displacement`` (6: m, then rad, the
    mount joints' positions from their preloaded rest), ``velocity``."""

    def __init__(self, motion: "HostMotion") -> None:
        self._motion = motion

    @property
    def displacement(self) -> np.ndarray:
        ph = self._motion.sim.physics
        dofs = ph.mount_dofs
        return ph.data.qpos[ph.model.jnt_qposadr[ph.model.dof_jntid[dofs]]] - \
            self._motion._rest

    @property
    def velocity(self) -> np.ndarray:
        ph = self._motion.sim.physics
        return ph.data.qvel[ph.mount_dofs].copy()


class HostMotion:
    """A :class:`HostMotionSpec` acting on a :class:`JointSim` (attach with ``sim.host =
    HostMotion(spec, sim)``: the simulation rebuilds its MuJoCo model with the host and
    mount). Starts at rest (:attr:`phase` OFF); :meth:`enable` ramps it in,
    :meth:`disable` ramps it out; :meth:`abort` stops it at once (the rail lost its torque)."""

    def __init__(self, spec: HostMotionSpec, sim: "JointSim") -> None:
        if spec.rail is not None and sim.rail is None:
            raise HostMotionConfigError(f"{spec.source}: rail: the {sim.desc.variant} variant "
                                        "has no rail")
        self.spec, self.sim = spec, sim
        self._ri = sim.names.index(sim.rail) if sim.rail is not None else None
        self.ramp = Ramp(spec.ramp)
        self.mount = _MountView(self) if spec.mount is not None else None
        self._rest = np.zeros(6)
        self.script_time = 0.0       # s since the motion first started (the sines' clock)
        self.tau = 0.0               # s of rail-profile time (the ramp's time warp)
        self.rail_center = 0.0       # m
        self.rail_target = 0.0       # m, the rail profile's position this step
        self.last_abort = ""
        self._script = _Script()
        self._root = pin.SE3.Identity()          # T_world_root this step
        self.base_pose = np.eye(4)               # T_world_base_link, after the last step
        self._bodies: np.ndarray | None = None   # MuJoCo bodies below the host
        self._at_rest = True

    def mjcf_mount(self):
        """The mount of the generated model (hyperarm_description.mjcf.Mount), or None."""
        from hyperarm_description.mjcf import Mount

        m = self.spec.mount
        return None if m is None else Mount(mass=m.mass, inertia=tuple(m.inertia),
                                            stiffness=tuple(m.stiffness),
                                            damping=tuple(m.damping))

    # -- commands -----------------------------------------------------------------------
    @property
    def phase(self) -> Phase:
        return self.ramp.phase

    @property
    def drives_rail(self) -> bool:
        """Whether the rail follows the script now (joint_command's rail part is refused)."""
        return self.spec.rail is not None and self.phase is not Phase.OFF

    def enable(self) -> str:
        """Start (or resume) the motion, ramped in; raises :class:`HostMotionError` if it
        cannot (rail unpowered, unhomed or its sweep out of range)."""
        if self.phase in (Phase.ON, Phase.RAMP_IN):
            return f"host motion {self.spec.name} already {self.phase.value}"
        if self.spec.rail is not None and self.phase is Phase.OFF:
            self._check_rail()
        if self.phase is Phase.OFF:
            self._preload()
        self.last_abort = ""
        self.ramp.start()
        return f"host motion {self.spec.name} started (ramp {self.spec.ramp:g} s)"

    def _preload(self) -> None:
        """The mount springs' rest positions: where they carry the load now (MuJoCo's
        ``qpos_spring``), so the base stays where it is until the load changes."""
        ph = self.sim.physics
        if self.mount is None or not len(ph.mount_dofs):
            return
        m, d = ph.model, ph.data
        dofs = ph.mount_dofs
        qadr = m.jnt_qposadr[m.dof_jntid[dofs]]
        k = m.jnt_stiffness[m.dof_jntid[dofs]]
        # the spring force -k (q - q_rest) balances the load: the bias forces at rest
        load = d.qfrc_bias[dofs]
        m.qpos_spring[qadr] = d.qpos[qadr] + load / k
        self._rest = d.qpos[qadr].copy()

    def _check_rail(self) -> None:
        sim, i = self.sim, self._ri
        if sim.mode[i] is ControlMode.OFF or sim.rail in sim.errors:
            raise HostMotionError(f"{sim.rail} amplifier not enabled: rail/set_torque true "
                                  "first")
        if sim.require_homing and not sim.homed:
            raise HostMotionError(f"{sim.rail} is not homed: call rail/home first")
        center = float(sim.position[i]) - self.spec.rail.position(self.tau)[0]
        amp = self.spec.rail.amplitude
        if center - amp < sim.lower[i] or center + amp > sim.upper[i]:
            raise HostMotionError(
                f"rail sweep {center - amp:.3f}..{center + amp:.3f} m from here leaves the "
                f"rail's range [{sim.lower[i]:g}, {sim.upper[i]:g}] m: move the rail first")
        self.rail_center = center

    def disable(self) -> str:
        if self.phase is Phase.OFF:
            return f"host motion {self.spec.name} is off"
        self.ramp.stop()
        return f"host motion {self.spec.name} ramping out ({self.spec.ramp:g} s)"

    def abort(self, reason: str) -> None:
        """Stop at once (no ramp): the host is back at rest on the next step."""
        if self.phase is not Phase.OFF:
            self.last_abort = reason
            self.sim.events.append(WorldEvent("host_motion_stopped", reason))
        self.ramp.reset()

    # -- simulation hooks -----------------------------------------------------------------
    def before_step(self, dt: float) -> None:
        """Advance the script by ``dt`` s: the host's pose into MuJoCo's mocap body, its
        acceleration as d'Alembert forces on the bodies below it (JointSim calls this
        before each MuJoCo step)."""
        was = self.phase
        if was is Phase.OFF and self._at_rest:
            return
        s0 = self.ramp.value()[0]
        self.ramp.step(dt)
        s, sd, sdd = self.ramp.value()
        if self.phase is not Phase.OFF or was is not Phase.OFF:
            self.script_time += dt
        if self.spec.rail is not None and (was is not Phase.OFF):
            self._drive_rail(dt, s0, s)
        self._script = self._base_script(s, sd, sdd)
        self._apply(self._script.pose, self._script.accel)
        self._at_rest = self.phase is Phase.OFF

    def _drive_rail(self, dt: float, s0: float, s: float) -> None:
        """The rail's profile (not its goal filter: the PMAC runs the trajectory) follows the
        sweep; a rail without torque, or in error, stops the motion."""
        sim, i = self.sim, self._ri
        if sim.mode[i] is ControlMode.OFF or sim.rail in sim.errors:
            self.abort(f"{sim.rail} lost its torque: host motion stopped")
            return
        self.tau += 0.5 * (s0 + s) * dt
        self.rail_target = self.rail_center + self.spec.rail.position(self.tau)[0]
        sim.set_profile_position(i, self.rail_target)

    def _base_script(self, s: float, sd: float, sdd: float) -> _Script:
        if not self.spec.base or s == 0.0 and sd == 0.0 and sdd == 0.0:
            return _Script()
        c, cd, cdd = np.zeros(6), np.zeros(6), np.zeros(6)
        t = self.script_time
        for osc in self.spec.base:
            k = AXES.index(osc.axis)
            w = 2.0 * math.pi * osc.frequency
            sn, cs = math.sin(w * t + osc.phase), math.cos(w * t + osc.phase)
            a = osc.amplitude
            c[k] += s * a * sn
            cd[k] += sd * a * sn + s * a * w * cs
            cdd[k] += sdd * a * sn + 2.0 * sd * a * w * cs - s * a * w * w * sn
        rot, _omega, alpha = _rpy_kinematics(c, cd, cdd)
        p = c[:3]
        # spatial acceleration at the world origin whose linear part gives the root
        # origin's true acceleration (the velocity products are neglected: module doc)
        return _Script(pin.SE3(rot, p.copy()), np.r_[cdd[:3] - _cross(alpha, p), alpha])

    def _apply(self, root: pin.SE3, accel: np.ndarray) -> None:
        """The host's pose (mocap) and the d'Alembert forces of its acceleration (spatial,
        at the world origin) on every body below it."""
        ph = self.sim.physics
        self._root = root
        ph.set_host_pose(root.homogeneous)
        m, d = ph.model, ph.data
        if self._bodies is None:
            host = ph.body["host"]
            below = [b for b in range(m.nbody) if b != host and _descends(m, b, host)]
            self._bodies = np.array(below)
        b = self._bodies
        if not np.any(accel):
            d.xfrc_applied[b] = 0.0
            return
        com = d.xipos[b]
        a_lin, alpha = accel[:3], accel[3:]
        acc = a_lin + np.cross(alpha, com)           # the spatial field at each centre
        d.xfrc_applied[b, :3] = -m.body_mass[b, None] * acc
        d.xfrc_applied[b, 3:] = 0.0

    def after_step(self, dt: float) -> None:
        """After each MuJoCo step: the base's pose in world."""
        ph = self.sim.physics
        self.base_pose = ph.body_pose(ph.base_body)

    # -- outputs --------------------------------------------------------------------------
    def root_pose(self) -> np.ndarray:
        """T_world_root (4x4) of the last step: the scripted host frame."""
        return self._root.homogeneous

    def status(self) -> dict[str, str]:
        """Key values for the diagnostics."""
        p = self.base_pose
        tilt = math.degrees(math.acos(min(max(float(p[2, 2]), -1.0), 1.0)))
        out = {"name": self.spec.name, "phase": self.phase.value,
               "ramp": f"{self.ramp.value()[0]:.3f}", "script_time_s": f"{self.script_time:.3f}",
               "base_xyz_m": " ".join(f"{v:.4f}" for v in p[:3, 3]),
               "base_tilt_deg": f"{tilt:.2f}", "last_abort": self.last_abort}
        if self.spec.rail is not None:
            out.update({"rail_center_m": f"{self.rail_center:.4f}",
                        "rail_target_m": f"{self.rail_target:.4f}"})
        if self.mount is not None:
            d = self.mount.displacement
            out.update({"mount_displacement_mm": " ".join(f"{1e3 * v:.3f}" for v in d[:3]),
                        "mount_rotation_deg": " ".join(f"{math.degrees(v):.3f}" for v in d[3:])})
        return out


def _descends(model, body: int, ancestor: int) -> bool:
    while body > 0:
        if body == ancestor:
            return True
        body = int(model.body_parentid[body])
    return False
