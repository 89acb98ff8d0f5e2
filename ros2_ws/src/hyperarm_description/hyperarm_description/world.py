"""Typed, validated work-cell geometry: table, pegs, block and poles (no ROS needed).

One schema for everything that needs to know what stands around the robot: the mock driver
simulates it (its work-cell file, ``hyperarm_driver/config/workcell*.yaml``, holds this under
``world:`` next to the mock's own settings) and the IK collision checker avoids it. Load a
work-cell file with :func:`load_world`, or validate an already parsed ``world:`` mapping with
:func:`parse_world`.

Units: m. Coordinates are in the robot's root frame (``base_link`` for the ``arm`` variant,
``world`` for ``rail_arm``), z up. YAML keys of the ``world:`` mapping::

    table_height: -0.20              # m, z of the table's top surface (required)
    table: {x: [-0.4, 0.8], y: [-0.6, 0.6]}   # optional extent (m); default: unbounded
    pegs:                            # vertical cylinders standing on the table
      source: {xy: [0.35, 0.12], height: 0.08, radius: 0.008}
    block:                           # optional (omit or null: no block)
      size: [0.04, 0.04, 0.03]       # m, box sides x y z
      hole_radius: 0.010             # m, vertical through-hole at its centre
      mass: 0.05                     # kg (default 0.05)
      start: source                  # the peg it starts threaded on
    poles:                           # optional obstacles: vertical cylinders
      pole1: {xy: [0.25, 0.0], radius: 0.015, height: 0.5}   # from the table up

Every error names the offending field with a dotted path, e.g. ``world.pegs.source.radius``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from .model import DescriptionError, check_number, check_vector, read_yaml

__all__ = [
    "WorldSpecError",
    "TableSpec",
    "PegSpec",
    "BlockSpec",
    "PoleSpec",
    "WorldSpec",
    "WORLD_KEYS",
    "MOCK_WORLD_KEYS",
    "parse_world",
    "load_world",
]

#: Keys of the ``world:`` mapping that this schema reads.
WORLD_KEYS = frozenset({"table_height", "table", "pegs", "block", "poles"})

_UNBOUNDED = (-math.inf, math.inf)


class WorldSpecError(DescriptionError):
    """The work cell's ``world:`` mapping is missing a field or holds an invalid value."""


@dataclass(frozen=True)
class TableSpec:
    """The table: its top surface at z = ``height`` (m) over ``x_range`` x ``y_range`` (m,
    (min, max); +-inf = unbounded)."""

    height: float
    x_range: tuple[float, float] = _UNBOUNDED
    y_range: tuple[float, float] = _UNBOUNDED

    def contains_xy(self, x: float, y: float) -> bool:
        """Whether the point (x, y) (m) is over the table."""
        return (self.x_range[0] <= x <= self.x_range[1]
                and self.y_range[0] <= y <= self.y_range[1])


@dataclass(frozen=True)
class PegSpec:
    """A vertical cylindrical peg standing on the table: axis at ``xy`` (m), ``height`` above
    the table (m), ``radius`` (m)."""

    name: str
    xy: tuple[float, float]
    height: float
    radius: float


@dataclass(frozen=True)
class BlockSpec:
    """The block: box of ``size`` (x, y, z; m) with a vertical through-hole of
    ``hole_radius`` (m) at its centre, ``mass`` (kg), starting threaded on peg ``start``."""

    size: tuple[float, float, float]
    hole_radius: float
    mass: float
    start: str


@dataclass(frozen=True)
class PoleSpec:
    """An obstacle: a vertical cylinder of ``radius`` (m) with its axis at ``xy`` (m), from
    z = ``z_min`` to z = ``z_max`` (m; a pole stands on the table: z_min = table height)."""

    name: str
    xy: tuple[float, float]
    radius: float
    z_min: float
    z_max: float

    @property
    def height(self) -> float:
        """Length of the pole (m)."""
        return self.z_max - self.z_min


@dataclass(frozen=True)
class WorldSpec:
    """The whole work cell. ``block`` is None in a cell without a block."""

    table: TableSpec
    pegs: tuple[PegSpec, ...]
    block: BlockSpec | None
    poles: tuple[PoleSpec, ...] = ()

    @property
    def table_height(self) -> float:
        """z of the table's top surface (m)."""
        return self.table.height

    def peg(self, name: str) -> PegSpec:
        """The peg called ``name``; WorldSpecError if there is none."""
        for p in self.pegs:
            if p.name == name:
                return p
        raise WorldSpecError(f"no peg named {name!r} (pegs: {[p.name for p in self.pegs]})")

    def pole(self, name: str) -> PoleSpec:
        """The pole called ``name``; WorldSpecError if there is none."""
        for p in self.poles:
            if p.name == name:
                return p
        raise WorldSpecError(f"no pole named {name!r} (poles: {[p.name for p in self.poles]})")

    def peg_top_z(self, name: str) -> float:
        """z of peg ``name``'s top face (m)."""
        return self.table.height + self.peg(name).height

    def clearance(self, peg: str) -> float:
        """Radial clearance (m) between the block's hole and peg ``peg``."""
        if self.block is None:
            raise WorldSpecError("this work cell has no block")
        return self.block.hole_radius - self.peg(peg).radius


def _num(raw: Mapping[str, Any], key: str, where: str, default: float | None, err: type[Exception],
         *, positive: bool = False, nonneg: bool = False) -> float:
    if key not in raw:
        if default is None:
            raise err(f"{where}.{key}: missing")
        return float(default)
    return check_number(raw[key], f"{where}.{key}", positive=positive, nonneg=nonneg, error=err)


def _mapping(value: Any, where: str, err: type[Exception], known: frozenset[str] | None = None
             ) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise err(f"{where}: expected a mapping, got {type(value).__name__}")
    if known is not None:
        unknown = sorted(set(map(str, value)) - known)
        if unknown:
            raise err(f"{where}: unknown key(s) {unknown}; known: {sorted(known)}")
    return value


def _range(raw: Mapping[str, Any], key: str, where: str, err: type[Exception]
           ) -> tuple[float, float]:
    if key not in raw:
        return _UNBOUNDED
    lo, hi = check_vector(raw[key], f"{where}.{key}", 2, error=err)
    if lo >= hi:
        raise err(f"{where}.{key}: min {lo:g} must be < max {hi:g}")
    return lo, hi


def _table(raw: Mapping[str, Any], where: str, err: type[Exception]) -> TableSpec:
    height = _num(raw, "table_height", where, None, err)
    rt = raw.get("table")
    if rt is None:
        return TableSpec(height=height)
    rt = _mapping(rt, f"{where}.table", err, frozenset({"x", "y"}))
    return TableSpec(height=height, x_range=_range(rt, "x", f"{where}.table", err),
                     y_range=_range(rt, "y", f"{where}.table", err))


def _pegs(raw: Mapping[str, Any], where: str, err: type[Exception], table: TableSpec
          ) -> tuple[PegSpec, ...]:
    raw_pegs = raw.get("pegs")
    if not isinstance(raw_pegs, Mapping) or not raw_pegs:
        raise err(f"{where}.pegs: must be a non-empty mapping of peg name to peg")
    pegs = []
    for name, rp in raw_pegs.items():
        pw = f"{where}.pegs.{name}"
        rp = _mapping(rp, pw, err, frozenset({"xy", "height", "radius"}))
        if "xy" not in rp:
            raise err(f"{pw}.xy: missing")
        xy = check_vector(rp["xy"], f"{pw}.xy", 2, error=err)
        if not table.contains_xy(*xy):
            raise err(f"{pw}.xy: {list(xy)} is off the table")
        pegs.append(PegSpec(name=str(name), xy=xy,  # type: ignore[arg-type]
                            height=_num(rp, "height", pw, None, err, positive=True),
                            radius=_num(rp, "radius", pw, None, err, positive=True)))
    return tuple(pegs)


def _block(raw: Mapping[str, Any], where: str, err: type[Exception],
           pegs: tuple[PegSpec, ...]) -> BlockSpec | None:
    rb = raw.get("block")
    if rb is None:
        return None
    bw = f"{where}.block"
    rb = _mapping(rb, bw, err, frozenset({"size", "hole_radius", "mass", "start"}))
    if "size" not in rb:
        raise err(f"{bw}.size: missing")
    size = check_vector(rb["size"], f"{bw}.size", 3, error=err)
    if min(size) <= 0.0:
        raise err(f"{bw}.size: every side must be > 0, got {list(size)}")
    block = BlockSpec(size=size,  # type: ignore[arg-type]
                      hole_radius=_num(rb, "hole_radius", bw, None, err, positive=True),
                      mass=_num(rb, "mass", bw, 0.05, err, positive=True),
                      start=str(rb.get("start", "")))
    names = [p.name for p in pegs]
    if block.start not in names:
        raise err(f"{bw}.start: {block.start!r} is not a peg (pegs: {names})")
    if 2.0 * block.hole_radius >= min(size[0], size[1]):
        raise err(f"{bw}.hole_radius: a hole of radius {block.hole_radius:g} m does not fit "
                  f"in a block of {size[0]:g} x {size[1]:g} m")
    for p in pegs:
        if p.radius >= block.hole_radius:
            raise err(f"{where}.pegs.{p.name}.radius: {p.radius:g} m does not fit the block's "
                      f"hole (hole_radius {block.hole_radius:g} m): clearance must be > 0")
        if p.height <= size[2]:
            raise err(f"{where}.pegs.{p.name}.height: {p.height:g} m must exceed the block's "
                      f"height {size[2]:g} m")
    for i, a in enumerate(pegs):
        for b in pegs[i + 1:]:
            if math.dist(a.xy, b.xy) < max(size[0], size[1]) + a.radius + b.radius:
                raise err(f"{where}.pegs: {a.name} and {b.name} are too close for the block "
                          f"to sit on one of them")
    return block


def _poles(raw: Mapping[str, Any], where: str, err: type[Exception], table: TableSpec,
           pegs: tuple[PegSpec, ...], block: BlockSpec | None) -> tuple[PoleSpec, ...]:
    rp_all = raw.get("poles")
    if rp_all is None:
        return ()
    rp_all = _mapping(rp_all, f"{where}.poles", err)
    poles = []
    reach = 0.5 * math.hypot(block.size[0], block.size[1]) if block else 0.0
    for name, rp in rp_all.items():
        pw = f"{where}.poles.{name}"
        rp = _mapping(rp, pw, err, frozenset({"xy", "radius", "height"}))
        if "xy" not in rp:
            raise err(f"{pw}.xy: missing")
        xy = check_vector(rp["xy"], f"{pw}.xy", 2, error=err)
        radius = _num(rp, "radius", pw, None, err, positive=True)
        height = _num(rp, "height", pw, None, err, positive=True)
        if not table.contains_xy(*xy):
            raise err(f"{pw}.xy: {list(xy)} is off the table")
        for p in pegs:
            if math.dist(xy, p.xy) < radius + max(p.radius, reach):
                raise err(f"{pw}.xy: too close to peg {p.name} (the block on the peg, or the "
                          f"peg itself, would be inside the pole)")
        poles.append(PoleSpec(name=str(name), xy=xy, radius=radius,  # type: ignore[arg-type]
                              z_min=table.height, z_max=table.height + height))
    return tuple(poles)


def parse_world(raw: Any, where: str = "world", *, extra_keys: frozenset[str] = frozenset(),
                error: type[Exception] = WorldSpecError) -> WorldSpec:
    """Validate a parsed ``world:`` mapping and build the work cell.

    ``extra_keys`` are further keys allowed in the mapping and left to the caller (the mock's
    contact stiffness, friction and grasp settings); any other unknown key is an error.
    ``error`` is the exception class raised (the mock passes its own); every message starts
    with the dotted path ``where.<field>``."""
    rw = _mapping(raw, where, error, WORLD_KEYS | extra_keys)
    table = _table(rw, where, error)
    pegs = _pegs(rw, where, error, table)
    block = _block(rw, where, error, pegs)
    return WorldSpec(table=table, pegs=pegs, block=block,
                     poles=_poles(rw, where, error, table, pegs, block))


def load_world(path: str | Path) -> WorldSpec:
    """The work cell of a work-cell YAML file (its ``world:`` mapping; every other top-level
    section, such as the mock's servo settings, is ignored, as are the mock's extra world
    keys ``contact_stiffness``, ``friction`` and ``grasp``)."""
    p = Path(path)
    data = read_yaml(p, "work-cell file", WorldSpecError)
    if not isinstance(data, Mapping) or "world" not in data:
        raise WorldSpecError(f"{p}: no 'world' mapping at the top level")
    return parse_world(data["world"], extra_keys=MOCK_WORLD_KEYS)


#: The mock driver's own keys inside ``world:`` (documented in docs/mock.md).
MOCK_WORLD_KEYS = frozenset({"contact_stiffness", "friction", "grasp"})
