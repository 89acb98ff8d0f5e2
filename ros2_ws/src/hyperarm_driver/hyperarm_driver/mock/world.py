"""The simulated work cell: table, pegs and a block with a hole (geometry only, no ROS).

Poses are 4x4 homogeneous matrices in the robot's root frame (z up), lengths in m.

The block is either resting (on a peg, threaded down to its base, or on the table) or held
by the gripper (then rigidly attached to tool0 by the grasp transform). While held it meets:

- the table (the block's bottom cannot go below ``table_height``);
- a peg's top, when the block's bottom is at or below the top, it is not threaded on the
  peg and the peg's top disc touches the block's bottom face outside the hole, i.e. the hole
  is misaligned by more than the radial clearance (the peg pushes back up; a block brought
  down beside the peg but overlapping it is pushed up the same way: side collisions of an
  unthreaded block are not modelled otherwise);
- a peg's side, when the block is threaded on it (the hole's wall stops the block moving
  more than the clearance off the peg's axis).

The block gets threaded on a peg when its bottom goes below the peg's top while its hole
axis is within the clearance of the peg's axis: that is the only way down a peg, so
insertion succeeds only when aligned. Contacts are reported as penetrations along a normal;
the robot model (``joint_sim``) turns them into forces through the contact stiffness and the
servos' finite stiffness. Tilt of the block is ignored: the hole is treated as vertical.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from .config import MockError, WorldConfig

__all__ = ["WorldError", "BlockState", "Contact", "WorldEvent", "World"]

# Depth (m) below a peg's top that the block's bottom must reach, aligned, to be threaded
# (more than the penalty penetration of a pressing contact, so pressing never threads).
THREAD_DEPTH = 0.001


class WorldError(MockError):
    """An impossible request to the work cell (e.g. grasping a block that is not there)."""


class BlockState(str, Enum):
    ON_PEG = "on_peg"
    ON_TABLE = "on_table"
    HELD = "held"


@dataclass(frozen=True)
class Contact:
    """A penetrating contact on the held block: ``normal`` (unit, the direction the world
    pushes the block), ``depth`` (m, > 0 = penetrating), ``point`` (m, on the block: the
    centre of its bottom face for the horizontal surfaces), ``frictional`` (a horizontal
    surface: the block sticks to it up to the friction cone)."""

    kind: str
    normal: np.ndarray
    depth: float
    point: np.ndarray
    frictional: bool = False


@dataclass(frozen=True)
class WorldEvent:
    """Something that happened: grasped, released, dropped, threaded, unthreaded, landed."""

    kind: str
    detail: str


_UP = np.array([0.0, 0.0, 1.0])
_UP.flags.writeable = False


def _yaw_only(rot: np.ndarray) -> np.ndarray:
    yaw = math.atan2(rot[1, 0], rot[0, 0])
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class World:
    """Table, pegs and the block; tracks the block's state and reports contacts."""

    def __init__(self, cfg: WorldConfig) -> None:
        self.cfg = cfg
        self._half = np.array(cfg.block.size) / 2.0
        self._corner = math.hypot(self._half[0], self._half[1])   # m, centre to a corner
        self._pegs = {p.name: p for p in cfg.pegs}
        self.events: list[WorldEvent] = []
        self.state = BlockState.ON_PEG
        self.peg: str | None = cfg.block.start   # the peg the block is threaded on, if any
        self._grasp: np.ndarray | None = None    # tool0 -> block, while held
        p = self._pegs[cfg.block.start]
        self._pose = np.eye(4)
        self._pose[:3, 3] = (p.xy[0], p.xy[1], cfg.table_height + self._half[2])

    # -- queries ------------------------------------------------------------------------
    def peg_top(self, name: str) -> np.ndarray:
        """Pose of the centre of peg ``name``'s top (z up)."""
        p = self._pegs[name]
        out = np.eye(4)
        out[:3, 3] = (p.xy[0], p.xy[1], self.cfg.table_height + p.height)
        return out

    @property
    def peg_names(self) -> list[str]:
        return list(self._pegs)

    def block_pose(self, tool_pose: np.ndarray | None = None) -> np.ndarray:
        """Pose of the block's centre (needs ``tool_pose`` of tool0 while held)."""
        if self.state is BlockState.HELD:
            if tool_pose is None:
                raise WorldError("the block is held: its pose needs the tool pose")
            return tool_pose @ self._grasp  # type: ignore[operator]
        return self._pose.copy()

    def grasp_transform(self) -> np.ndarray:
        """tool0 -> block (4x4) while held; WorldError otherwise."""
        if self._grasp is None:
            raise WorldError("the block is not held")
        return self._grasp.copy()

    def grasp_point(self, tool_pose: np.ndarray) -> np.ndarray:
        return tool_pose[:3, :3] @ np.asarray(self.cfg.grasp.offset) + tool_pose[:3, 3]

    def block_between_fingers(self, tool_pose: np.ndarray) -> bool:
        """Whether the (resting) block's centre is within the capture radius of the grasp
        point, so that closing fingers would meet it."""
        if self.state is BlockState.HELD:
            return True
        d = np.linalg.norm(self.grasp_point(tool_pose) - self._pose[:3, 3])
        return bool(d <= self.cfg.grasp.capture_radius)

    def width_between_fingers(self, tool_pose: np.ndarray) -> float:
        """Width (m) of the block along tool0's z axis, the fingers' closing direction (the
        finger joint turns about tool0's x axis; the hand points along tool0's -y)."""
        y = tool_pose[:3, 2]
        rot = self.block_pose(tool_pose)[:3, :3]
        return float(sum(abs(float(y @ rot[:, i])) * self.cfg.block.size[i] for i in range(3)))

    def misalignment(self, peg: str, block_pose: np.ndarray) -> float:
        """Horizontal distance (m) of the block's hole axis from peg ``peg``'s axis."""
        p = self._pegs[peg]
        return math.hypot(block_pose[0, 3] - p.xy[0], block_pose[1, 3] - p.xy[1])

    def _touches_top(self, peg: str, block_pose: np.ndarray) -> bool:
        """Whether the peg's top disc meets the block's bottom face (outside the hole)."""
        p = self._pegs[peg]
        ex, ey = p.xy[0] - float(block_pose[0, 3]), p.xy[1] - float(block_pose[1, 3])
        e = math.hypot(ex, ey)
        if e <= self.cfg.block.hole_radius - p.radius:
            return False  # the disc is inside the hole
        if e >= self._corner + p.radius:
            return False  # beyond the block's corners
        # the peg's axis in the block's frame; tilt ignored: the hole is vertical
        yaw = math.atan2(float(block_pose[1, 0]), float(block_pose[0, 0]))
        c, s = math.cos(yaw), math.sin(yaw)
        dx = max(abs(c * ex + s * ey) - self._half[0], 0.0)
        dy = max(abs(-s * ex + c * ey) - self._half[1], 0.0)
        return math.hypot(dx, dy) < p.radius

    # -- contacts of the held block -----------------------------------------------------
    def contacts(self, tool_pose: np.ndarray) -> list[Contact]:
        """Penetrating contacts of the held block at this tool pose (empty if not held)."""
        if self.state is not BlockState.HELD:
            return []
        pose = self.block_pose(tool_pose)
        centre = pose[:3, 3]
        bottom = centre[2] - self._half[2]
        out: list[Contact] = []
        up = _UP
        depth = self.cfg.table_height - bottom
        if depth > 0.0:
            out.append(Contact("table", up, depth, np.array([centre[0], centre[1], bottom]),
                               frictional=True))
        for name, p in self._pegs.items():
            top = self.cfg.table_height + p.height
            if name == self.peg:
                e = self.misalignment(name, pose)
                excess = e - (self.cfg.block.hole_radius - p.radius)
                if excess > 0.0 and e > 0.0:
                    n = -np.array([centre[0] - p.xy[0], centre[1] - p.xy[1], 0.0]) / e
                    low = max(bottom, self.cfg.table_height)     # middle of the overlap
                    z = low + 0.5 * (min(top, centre[2] + self._half[2]) - low)
                    out.append(Contact(f"peg_side:{name}", n, excess,
                                       np.array([centre[0], centre[1], z])))
                continue
            depth = top - bottom
            if 0.0 < depth <= p.height and self._touches_top(name, pose):
                out.append(Contact(f"peg_top:{name}", up, depth,
                                   np.array([centre[0], centre[1], bottom]), frictional=True))
        return out

    def update_held(self, tool_pose: np.ndarray) -> None:
        """Update threading from the held block's actual pose (after contact forces)."""
        if self.state is not BlockState.HELD:
            return
        pose = self.block_pose(tool_pose)
        bottom = pose[2, 3] - self._half[2]
        if self.peg is not None:
            top = self.cfg.table_height + self._pegs[self.peg].height
            if bottom > top:
                self.events.append(WorldEvent("unthreaded", self.peg))
                self.peg = None
            return
        for name, p in self._pegs.items():
            top = self.cfg.table_height + p.height
            if (bottom < top - THREAD_DEPTH and bottom > top - 2.0 * self._half[2]
                    and self.misalignment(name, pose) <= self.cfg.block.hole_radius - p.radius):
                self.peg = name
                self.events.append(WorldEvent("threaded", name))
                return

    # -- grasping -----------------------------------------------------------------------
    def grasp(self, tool_pose: np.ndarray) -> None:
        """Attach the block to the tool where it is now (fingers closed on it)."""
        if self.state is BlockState.HELD:
            return
        if not self.block_between_fingers(tool_pose):
            raise WorldError("the block is not between the fingers")
        self._grasp = np.linalg.inv(tool_pose) @ self._pose
        self.state = BlockState.HELD
        self.events.append(WorldEvent("grasped", f"on {self.peg}" if self.peg else "from table"))

    def release(self, tool_pose: np.ndarray, kind: str = "released") -> None:
        """Let go of the block (``kind`` "released" or "dropped"): it falls and comes to
        rest threaded on a peg's base if its hole is on the peg, else on the table (beside a
        peg if it would land on one)."""
        if self.state is not BlockState.HELD:
            return
        pose = self.block_pose(tool_pose)
        self._grasp = None
        xy = pose[:2, 3].copy()
        rest = np.eye(4)
        rest[:3, :3] = _yaw_only(pose[:3, :3])
        landed = self.peg
        if landed is None:
            for name, p in self._pegs.items():
                top = self.cfg.table_height + p.height
                if (pose[2, 3] - self._half[2] >= top - 2.0 * self._half[2]
                        and self.misalignment(name, pose) <= self.cfg.block.hole_radius - p.radius):
                    landed = name
                    break
        if landed is None:
            for name, p in self._pegs.items():
                probe = pose.copy()
                if self._touches_top(name, probe):
                    d = xy - np.array(p.xy)
                    n = d / np.linalg.norm(d) if np.linalg.norm(d) > 1e-9 else np.array([1.0, 0.0])
                    reach = float(np.linalg.norm(self._half[:2])) + p.radius + 1e-3
                    xy = np.array(p.xy) + n * reach
                    break
        if landed is not None:
            p = self._pegs[landed]
            xy = pose[:2, 3]  # stays within the clearance of the axis
            self.state = BlockState.ON_PEG
        else:
            self.state = BlockState.ON_TABLE
        self.peg = landed
        rest[:3, 3] = (xy[0], xy[1], self.cfg.table_height + self._half[2])
        self._pose = rest
        where = f"on peg {landed}" if landed else f"on the table at ({xy[0]:.3f}, {xy[1]:.3f})"
        self.events.append(WorldEvent(kind, where))

    def on_peg(self, name: str) -> bool:
        """Whether the block rests threaded on peg ``name`` (down at its base)."""
        return self.state is BlockState.ON_PEG and self.peg == name

    def take_events(self) -> list[WorldEvent]:
        out, self.events = self.events, []
        return out
