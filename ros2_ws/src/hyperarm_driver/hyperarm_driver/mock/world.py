"""The work cell as MuJoCo has it: where the block is, and what happened to it (no ROS).

The physics (``physics.py``) moves the block; this module only names its state from
MuJoCo's poses and contacts, and reports the changes as events:

- ``held``: both finger pads touch the block;
- ``on_peg``: not held, its hole's axis within the radial clearance of a peg's axis and its
  bottom below that peg's top (threaded; it slides down to the peg's base by itself);
- ``on_peg_top``: not held, touching a peg with its bottom at the peg's top;
- ``on_table``: anywhere else (resting on the table, tipped over, falling).

Poses are 4x4 homogeneous matrices in the root frame (z up), lengths in m.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING

import numpy as np

from .config import MockError, WorldConfig

if TYPE_CHECKING:
    from .physics import ContactPoint, Physics

__all__ = ["WorldError", "BlockState", "WorldEvent", "World", "rim_offsets", "THREAD_DEPTH",
           "TOP_BAND", "LET_GO"]


class WorldError(MockError):
    """An impossible request to the work cell (e.g. the pose of a block that is not there)."""


class BlockState(str, Enum):
    ON_PEG = "on_peg"            # threaded on a peg, down at its base
    ON_PEG_TOP = "on_peg_top"    # resting on a peg's top, misaligned (balanced on it)
    ON_TABLE = "on_table"
    HELD = "held"
    ABSENT = "none"              # a work cell without a block


@dataclass(frozen=True)
class WorldEvent:
    """Something that happened: grasped, released, dropped, threaded, unthreaded, landed."""

    kind: str
    detail: str


def rim_offsets(peg_xy, half_height: float, block_pose: np.ndarray) -> tuple[float, float]:
    """Horizontal distances (m) of a block's hole rims (its z axis at ±``half_height`` from
    its centre) from the vertical axis through ``peg_xy`` (m)."""
    axis = block_pose[:3, 2] * half_height
    out = []
    for sign in (1.0, -1.0):
        rim = block_pose[:3, 3] + sign * axis
        out.append(math.hypot(float(rim[0]) - peg_xy[0], float(rim[1]) - peg_xy[1]))
    return out[0], out[1]


THREAD_DEPTH = 0.001   # m below a peg's top the aligned block's bottom must be: threaded
TOP_BAND = 0.003       # m: a block touching a peg with its bottom this close to the top
                       # rests on the top
LET_GO = 0.03          # s without both pads on the block before a grasp is lost (the pads
                       # bounce off it for a few ms as they close)


class World:
    """The work cell ``cfg`` over a :class:`~hyperarm_driver.mock.physics.Physics`: the block's
    state (``state``, ``peg``), its pose, the pegs' tops, events."""

    def __init__(self, cfg: WorldConfig, physics: Physics) -> None:
        self.cfg = cfg
        self.spec = cfg.spec
        self.physics = physics
        self._pegs = {p.name: p for p in cfg.pegs}
        self._table_z = cfg.table_height
        self.events: list[WorldEvent] = []
        if cfg.block is None:
            self.state, self.peg = BlockState.ABSENT, None
            self._half = np.zeros(3)
            return
        self._half = np.array(cfg.block.size) / 2.0
        self.state, self.peg = BlockState.ON_PEG, cfg.block.start
        self.threaded: str | None = cfg.block.start
        self._apart_since: float | None = None   # s: both pads stopped touching the block

    # -- queries --------------------------------------------------------------------------
    @property
    def peg_names(self) -> list[str]:
        return list(self._pegs)

    def peg_top(self, name: str) -> np.ndarray:
        """Pose of the centre of peg ``name``'s top (z up)."""
        p = self._pegs[name]
        out = np.eye(4)
        out[:3, 3] = (p.xy[0], p.xy[1], self._table_z + p.height)
        return out

    def block_pose(self, tool_pose: np.ndarray | None = None) -> np.ndarray:
        """Pose of the block's centre (``tool_pose`` is not needed: MuJoCo has it)."""
        if self.state is BlockState.ABSENT:
            raise WorldError("this work cell has no block")
        return self.physics.block_pose()

    def misalignment(self, peg: str, block_pose: np.ndarray) -> float:
        """Horizontal distance (m) of the block's centre from peg ``peg``'s axis."""
        p = self._pegs[peg]
        return math.hypot(block_pose[0, 3] - p.xy[0], block_pose[1, 3] - p.xy[1])

    def rim_offsets(self, peg: str, block_pose: np.ndarray) -> tuple[float, float]:
        """Horizontal distances (m) of the hole's two rims (its axis at the block's top and
        bottom faces) from peg ``peg``'s axis."""
        return rim_offsets(self._pegs[peg].xy, float(self._half[2]), block_pose)

    def on_peg(self, name: str) -> bool:
        """Whether the block rests threaded on peg ``name``."""
        return self.state is BlockState.ON_PEG and self.peg == name

    def take_events(self) -> list[WorldEvent]:
        out, self.events = self.events, []
        return out

    # -- update -----------------------------------------------------------------------------
    def _threaded_on(self, pose: np.ndarray) -> str | None:
        bottom = pose[2, 3] - self._half[2] * abs(pose[2, 2])
        for name, p in self._pegs.items():
            if bottom < self._table_z + p.height - THREAD_DEPTH \
                    and max(self.rim_offsets(name, pose)) <= self.cfg.clearance(name) + 1e-4:
                return name
        return None

    def update(self, contacts: list[ContactPoint], opening: bool) -> None:
        """Name the block's state from the last step's ``contacts`` and pose; ``opening``:
        the gripper's goal opens (a lost grasp is ``released``, else ``dropped``)."""
        if self.state is BlockState.ABSENT:
            return
        pads, pegs = set(), set()
        for c in contacts:
            for own, other in ((c.a, c.b), (c.b, c.a)):
                if own.startswith("block_piece"):
                    if other.startswith("pad_"):
                        pads.add(other)
                    elif other.startswith("peg_"):
                        pegs.add(other[4:])
        pose = self.physics.block_pose()
        threaded = self._threaded_on(pose)
        held = len(pads) == 2
        was = self.state
        now = self.physics.time
        if was is BlockState.HELD and not held:
            if self._apart_since is None:
                self._apart_since = now
            held = now - self._apart_since < LET_GO
        if held and len(pads) == 2:
            self._apart_since = None
        if held:
            state, peg = BlockState.HELD, threaded
        elif threaded is not None:
            state, peg = BlockState.ON_PEG, threaded
        else:
            state, peg = BlockState.ON_TABLE, None
            bottom = pose[2, 3] - self._half[2]
            for name in sorted(pegs):
                if abs(bottom - (self._table_z + self._pegs[name].height)) < TOP_BAND:
                    state, peg = BlockState.ON_PEG_TOP, name
                    break
        if held and was is not BlockState.HELD:
            where = {BlockState.ON_PEG: f"on {self.peg}",
                     BlockState.ON_PEG_TOP: f"on top of {self.peg}"}.get(was, "from table")
            self.events.append(WorldEvent("grasped", where))
        elif was is BlockState.HELD and not held:
            x, y, z = pose[:3, 3].tolist()
            # threaded: it stays on that peg (as the mock's events always said); else where
            # it was let go (a "landed" event says where it comes to rest)
            where = f"on peg {threaded}" if threaded is not None else \
                f"at ({x:.3f}, {y:.3f}, {z:.3f})"
            self.events.append(WorldEvent("released" if opening else "dropped", where))
        if held and was is BlockState.HELD and threaded != self.threaded:
            if threaded is not None:
                self.events.append(WorldEvent("threaded", threaded))
            else:
                self.events.append(WorldEvent("unthreaded", self.threaded or ""))
        if not held and state is not was and was is not BlockState.HELD \
                and state in (BlockState.ON_PEG, BlockState.ON_PEG_TOP):
            self.events.append(WorldEvent("landed", f"{state.value} {peg}"))
        self.threaded = threaded
        self.state, self.peg = state, peg
