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
servos' finite stiffness. A tilted block's hole is a tilted cylinder: the peg (vertical)
enters it only if both of the hole's rims (the circles where its axis meets the block's top
and bottom faces) are within the clearance of the peg's axis (``accepts``), so a hole whose
clearance is smaller than the tilt over the block's height (L·tan θ > 2 c) cannot be
threaded at all, as a real peg jams; a block the hole cannot accept rests on the peg's top.
The contact geometry is otherwise that of an upright block (footprints, the threaded side).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from .config import MockError, WorldConfig

__all__ = ["WorldError", "BlockState", "Contact", "WorldEvent", "World",
           "segment_closest_points", "rim_offsets"]

# Depth (m) below a peg's top that the block's bottom must reach, aligned, to be threaded
# (more than the penalty penetration of a pressing contact, so pressing never threads).
THREAD_DEPTH = 0.001
# Contact memory of an unthreaded held block (``World.track``): at its actual pose, a block
# whose bottom is above a peg's top minus TOP_SLACK (m: more than a pressing contact's
# penetration) is "over" that peg, else "beside" it; pegs farther than NEAR (m) beyond the
# block's corners are forgotten.
TOP_SLACK = 0.003
NEAR = 0.03


class WorldError(MockError):
    """An impossible request to the work cell (e.g. grasping a block that is not there)."""


class BlockState(str, Enum):
    ON_PEG = "on_peg"            # threaded on a peg, down at its base
    ON_PEG_TOP = "on_peg_top"    # resting on a peg's top, misaligned (balanced on it)
    ON_TABLE = "on_table"
    HELD = "held"
    ABSENT = "none"              # a work cell without a block


@dataclass(frozen=True)
class Contact:
    """A penetrating contact on the held block: ``normal`` (unit, the direction the world
    pushes the block), ``depth`` (m, > 0 = penetrating), ``point`` (m, on the block: where
    the depth is measured and the normal force acts: on the table the centre of its bottom
    face, moving to its lowest point as it tilts; on a peg's top the face's centre as if
    upright, a tilted face over the top not modelled), ``frictional`` (a horizontal
    surface: the block sticks to it up to the friction cone), ``slide`` (m, frictional
    only: the material point friction holds, the bottom face's centre; None: ``point``)."""

    kind: str
    normal: np.ndarray
    depth: float
    point: np.ndarray
    frictional: bool = False
    slide: np.ndarray | None = None


@dataclass(frozen=True)
class WorldEvent:
    """Something that happened: grasped, released, dropped, threaded, unthreaded, landed."""

    kind: str
    detail: str


_UP = np.array([0.0, 0.0, 1.0])
_UP.flags.writeable = False
TILT_BLEND = 0.0005   # m: a tilted block's bottom this much lower at its lowest point than
                      # at its face's centre presses there (less: a blend of the two)


def segment_closest_points(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Closest points (m) of segments a0-a1 and b0-b1 (closed form, clamped; Ericson,
    Real-Time Collision Detection, 5.1.9)."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a, e, f = float(d1 @ d1), float(d2 @ d2), float(d2 @ r)
    if a <= 1e-18 and e <= 1e-18:
        return a0, b0
    if a <= 1e-18:
        s, t = 0.0, min(max(f / e, 0.0), 1.0)
    else:
        c = float(d1 @ r)
        if e <= 1e-18:
            s, t = min(max(-c / a, 0.0), 1.0), 0.0
        else:
            b = float(d1 @ d2)
            den = a * e - b * b
            s = min(max((b * f - c * e) / den, 0.0), 1.0) if den > 1e-18 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                s, t = min(max(-c / a, 0.0), 1.0), 0.0
            elif t > 1.0:
                s, t = min(max((b - c) / a, 0.0), 1.0), 1.0
    return a0 + d1 * s, b0 + d2 * t


def rim_offsets(peg_xy, half_height: float, block_pose: np.ndarray) -> tuple[float, float]:
    """Horizontal distances (m) of a block's hole rims (its z axis at ±``half_height`` from
    its centre) from the vertical axis through ``peg_xy`` (m)."""
    axis = block_pose[:3, 2] * half_height
    out = []
    for sign in (1.0, -1.0):
        rim = block_pose[:3, 3] + sign * axis
        out.append(math.hypot(float(rim[0]) - peg_xy[0], float(rim[1]) - peg_xy[1]))
    return out[0], out[1]


def _yaw_only(rot: np.ndarray) -> np.ndarray:
    yaw = math.atan2(rot[1, 0], rot[0, 0])
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class World:
    """Table, pegs and the block; tracks the block's state and reports contacts."""

    def __init__(self, cfg: WorldConfig) -> None:
        self.cfg = cfg
        self._pegs = {p.name: p for p in cfg.pegs}
        self._grasp_offset = np.asarray(cfg.grasp.offset, dtype=float)   # m, in tool0
        self._table_z = cfg.table_height          # m (read per contact check: kept here)
        self.events: list[WorldEvent] = []
        self._grasp: np.ndarray | None = None    # tool0 -> block, while held
        self._held_key: bytes | None = None      # _pose_of's last tool pose, its block pose
        self._held_pose = np.eye(4)
        self._touch: dict[str, bool] = {}        # _touches_top's answers for _held_pose
        self._pose = np.eye(4)
        # per unthreaded peg near the held block, from its last actual pose (``track``):
        # ("top", None) resting on / above the top's disc, ("side", n) beside the peg (n:
        # horizontal unit normal pushing the block away from the peg's axis)
        self._memory: dict[str, tuple[str, np.ndarray | None]] = {}
        if cfg.block is None:                    # nothing to grasp
            self._half = np.zeros(3)
            self._half_xyz = (0.0, 0.0, 0.0)
            self._corner = 0.0
            self.state, self.peg = BlockState.ABSENT, None
            return
        self._half = np.array(cfg.block.size) / 2.0
        self._half_xyz = tuple(self._half.tolist())
        self._corner = math.hypot(self._half[0], self._half[1])   # m, centre to a corner
        self.state = BlockState.ON_PEG
        self.peg: str | None = cfg.block.start   # the peg the block is threaded on, if any
        p = self._pegs[cfg.block.start]
        self._pose[:3, 3] = (p.xy[0], p.xy[1], cfg.table_height + self._half[2])

    # -- queries ------------------------------------------------------------------------
    def peg_top(self, name: str) -> np.ndarray:
        """Pose of the centre of peg ``name``'s top (z up)."""
        p = self._pegs[name]
        out = np.eye(4)
        out[:3, 3] = (p.xy[0], p.xy[1], self._table_z + p.height)
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

    def _pose_of(self, tool_pose: np.ndarray) -> np.ndarray:
        """:meth:`block_pose` for this module's read-only use: while held, the same array
        for the same tool pose (a step asks several questions of one pose: its top and
        side contacts, its penetration, the tracking), so that :meth:`_touches_top`'s
        answers for it are kept too (pure functions of the peg and the pose)."""
        if self.state is not BlockState.HELD:
            return self.block_pose(tool_pose)
        key = tool_pose.tobytes()
        if key != self._held_key:
            self._held_key, self._held_pose = key, tool_pose @ self._grasp
            self._touch = {}
        return self._held_pose

    def grasp_transform(self) -> np.ndarray:
        """tool0 -> block (4x4) while held; WorldError otherwise."""
        if self._grasp is None:
            raise WorldError("the block is not held")
        return self._grasp.copy()

    def grasp_point(self, tool_pose: np.ndarray) -> np.ndarray:
        return tool_pose[:3, :3] @ self._grasp_offset + tool_pose[:3, 3]

    def block_between_fingers(self, tool_pose: np.ndarray) -> bool:
        """Whether the (resting) block's centre is within the capture radius of the grasp
        point, so that closing fingers would meet it."""
        if self.state is BlockState.HELD:
            return True
        if self.state is BlockState.ABSENT:
            return False
        g, c = self.grasp_point(tool_pose).tolist(), self._pose[:3, 3].tolist()
        d = math.hypot(g[0] - c[0], g[1] - c[1], g[2] - c[2])
        return d <= self.cfg.grasp.capture_radius

    def width_between_fingers(self, tool_pose: np.ndarray) -> float:
        """Width (m) of the block along tool0's z axis, the fingers' closing direction (the
        finger joint turns about tool0's x axis; the hand points along tool0's -y)."""
        across = (tool_pose[:3, 2] @ self._pose_of(tool_pose)[:3, :3]).tolist()
        size = self.cfg.block.size
        return abs(across[0]) * size[0] + abs(across[1]) * size[1] + abs(across[2]) * size[2]

    def misalignment(self, peg: str, block_pose: np.ndarray) -> float:
        """Horizontal distance (m) of the block's hole axis from peg ``peg``'s axis."""
        p = self._pegs[peg]
        return math.hypot(block_pose[0, 3] - p.xy[0], block_pose[1, 3] - p.xy[1])

    def hole_offset(self, tool_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """For a held block threaded on a peg, at ``tool_pose``: the point (3,) of its wall
        contact (the block's axis at the middle of its overlap with the peg, as in
        :meth:`contacts`) and its hole axis's horizontal offset (2,) from the peg's axis
        (m); else None."""
        if self.peg is None or self.state is not BlockState.HELD:
            return None
        centre = self._pose_of(tool_pose)[:3, 3]
        p = self._pegs[self.peg]
        low = max(centre[2] - self._half[2], self._table_z)
        z = low + 0.5 * (min(self._table_z + p.height, centre[2] + self._half[2]) - low)
        return (np.array([centre[0], centre[1], z]),
                np.array([centre[0] - p.xy[0], centre[1] - p.xy[1]]))

    def rim_offsets(self, peg: str, block_pose: np.ndarray) -> tuple[float, float]:
        """Horizontal distances (m) of the hole's two rims (its axis, the block's z, at the
        block's top and bottom faces) from peg ``peg``'s axis."""
        return rim_offsets(self._pegs[peg].xy, float(self._half[2]), block_pose)

    def accepts(self, peg: str, block_pose: np.ndarray) -> bool:
        """Whether peg ``peg`` fits through the block's hole at this pose: both rims within
        the radial clearance of its axis (upright, the hole's axis within the clearance)."""
        c = self.cfg.block.hole_radius - self._pegs[peg].radius
        return max(self.rim_offsets(peg, block_pose)) <= c

    def _touches_top(self, peg: str, block_pose: np.ndarray) -> bool:
        """Whether the peg's top disc meets the block's bottom face (outside the hole), or
        the peg's top meets the hole's wall (a hole too tilted to accept it)."""
        if block_pose is self._held_pose and self._held_key is not None:
            known = self._touch.get(peg)
            if known is None:
                known = self._touch[peg] = self._top_overlap(peg, block_pose)
            return known
        return self._top_overlap(peg, block_pose)

    def _top_overlap(self, peg: str, block_pose: np.ndarray) -> bool:
        """:meth:`_touches_top`, computed."""
        p = self._pegs[peg]
        ex, ey = p.xy[0] - float(block_pose[0, 3]), p.xy[1] - float(block_pose[1, 3])
        e = math.hypot(ex, ey)
        if e <= self.cfg.block.hole_radius - p.radius:
            return not self.accepts(peg, block_pose)   # the disc is inside the hole
        if e >= self._corner + p.radius:
            return False  # beyond the block's corners
        # the peg's axis in the block's frame; tilt ignored: the hole is vertical
        yaw = math.atan2(float(block_pose[1, 0]), float(block_pose[0, 0]))
        c, s = math.cos(yaw), math.sin(yaw)
        dx = max(abs(c * ex + s * ey) - self._half[0], 0.0)
        dy = max(abs(-s * ex + c * ey) - self._half[1], 0.0)
        return math.hypot(dx, dy) < p.radius

    def _table_point(self, pose: np.ndarray) -> tuple[np.ndarray, float]:
        """Where a tilted block presses on the table (3,) and its height (m): its bottom
        face's centre while upright, moving continuously to its lowest corner as it tilts
        (a corner TILT_BLEND lower than the face's centre is the point)."""
        rot, centre = pose[:3, :3], pose[:3, 3]
        h = self._half
        point = centre.copy()
        for i in range(3):
            w = max(-1.0, min(1.0, h[i] * float(rot[2, i]) / TILT_BLEND))
            point -= (w * h[i]) * rot[:, i]
        return point, float(point[2])

    def _lowest(self, pose: np.ndarray) -> float:
        """Height (m) of the block's lowest corner."""
        r0, r1, r2, z = pose[2].tolist()
        hx, hy, hz = self._half_xyz
        return z - (abs(r0) * hx + abs(r1) * hy + abs(r2) * hz)

    def _side_contact(self, peg: str, block_pose: np.ndarray) -> tuple[float, np.ndarray] | None:
        """The unthreaded block's side against peg ``peg``: when the peg's axis is outside
        the block's footprint but the peg overlaps it, the overlap (m) and the horizontal
        normal pushing the block away; None otherwise (no overlap, or the axis under the
        block's solid part: only the top can push then)."""
        p = self._pegs[peg]
        ex, ey = p.xy[0] - float(block_pose[0, 3]), p.xy[1] - float(block_pose[1, 3])
        if math.hypot(ex, ey) >= self._corner + p.radius:
            return None
        yaw = math.atan2(float(block_pose[1, 0]), float(block_pose[0, 0]))
        c, s = math.cos(yaw), math.sin(yaw)
        lx, ly = c * ex + s * ey, -s * ex + c * ey            # peg axis in the block's frame
        dx = max(abs(lx) - self._half[0], 0.0)
        dy = max(abs(ly) - self._half[1], 0.0)
        d = math.hypot(dx, dy)
        if d == 0.0 or d >= p.radius:
            return None
        nx, ny = math.copysign(dx, lx) / d, math.copysign(dy, ly) / d   # block -> peg
        n = -np.array([c * nx - s * ny, s * nx + c * ny, 0.0])
        return p.radius - d, n

    def _outward(self, peg: str, block_pose: np.ndarray) -> np.ndarray | None:
        """Horizontal unit normal pushing the block away from peg ``peg`` (from the point of
        the block's footprint nearest the peg's axis); None when the axis is inside the
        footprint (under the solid part or the hole)."""
        p = self._pegs[peg]
        ex, ey = p.xy[0] - float(block_pose[0, 3]), p.xy[1] - float(block_pose[1, 3])
        yaw = math.atan2(float(block_pose[1, 0]), float(block_pose[0, 0]))
        c, s = math.cos(yaw), math.sin(yaw)
        lx, ly = c * ex + s * ey, -s * ex + c * ey
        dx = max(abs(lx) - self._half[0], 0.0)
        dy = max(abs(ly) - self._half[1], 0.0)
        d = math.hypot(dx, dy)
        if d == 0.0:
            return None
        nx, ny = math.copysign(dx, lx) / d, math.copysign(dy, ly) / d
        return -np.array([c * nx - s * ny, s * nx + c * ny, 0.0])

    def _side_depth(self, peg: str, block_pose: np.ndarray, n: np.ndarray) -> float:
        """Overlap (m) of the block's footprint with peg ``peg``'s disc along the horizontal
        normal ``n`` (peg -> block): the peg's radius minus the gap between the axis and
        the footprint's supporting line across ``n``; > 0 = penetrating, at any depth."""
        p = self._pegs[peg]
        rx, ry = float(block_pose[0, 3]) - p.xy[0], float(block_pose[1, 3]) - p.xy[1]
        support = (self._half[0] * abs(float(n[0] * block_pose[0, 0] + n[1] * block_pose[1, 0]))
                   + self._half[1] * abs(float(n[0] * block_pose[0, 1] + n[1] * block_pose[1, 1])))
        return p.radius - (float(n[0]) * rx + float(n[1]) * ry - support)

    def track(self, tool_pose: np.ndarray) -> None:
        """Remember, from the held block's actual pose, which side of every nearby
        unthreaded peg it is on (``contacts`` then applies that peg's top or side at any
        commanded depth: a block over a top can only leave it upwards or over the edge,
        a block beside a peg only sideways or upwards)."""
        if self.state is not BlockState.HELD:
            self._memory.clear()
            return
        pose = self._pose_of(tool_pose)
        bottom = float(pose[2, 3]) - self._half[2]
        for name, p in self._pegs.items():
            if name == self.peg or self.misalignment(name, pose) >= self._corner + p.radius + NEAR:
                self._memory.pop(name, None)
                continue
            top = self._table_z + p.height
            over = self._touches_top(name, pose)
            if bottom >= top - TOP_SLACK and over:
                self._memory[name] = ("top", None)
                continue
            n = self._outward(name, pose)
            beside = self._memory.get(name, ("", None))[0] == "side" and bottom < top
            if n is not None and (not over or beside):
                # (beside and overlapping: the overlap is resolved sideways, along the
                # normal of the block's feature nearest the axis now, the block may turn)
                self._memory[name] = ("side", n)
            elif bottom >= top and not over:
                self._memory.pop(name, None)   # above, over the hole: free (may thread)
            # else: inside the footprint below the top (a penetration the solver is
            # resolving) or over the hole below the top (threading): keep what it was

    def penetration(self, tool_pose: np.ndarray) -> float:
        """Largest interpenetration (m) of the held block with the table and the pegs at
        this tool pose, from the geometry alone (no contact memory): the table's depth; per
        unthreaded peg overlapping the block (its top above the bottom, its disc over the
        footprint's solid part), the least of the vertical depth below its top and the
        sideways overlap; on the threaded peg, the excess over the clearance. The table:
        the block's lowest corner (tilt included); the pegs: the block as if upright (a
        tilted block's face over a peg's top is not modelled). 0 when not held. For
        invariant checks."""
        if self.state is not BlockState.HELD:
            return 0.0
        pose = self._pose_of(tool_pose)
        low = self._lowest(pose)                      # the lowest corner (tilt included)
        worst = max(self._table_z - low, 0.0)
        for name, p in self._pegs.items():
            top = self._table_z + p.height
            if name == self.peg:
                worst = max(worst, self.misalignment(name, pose) - self.cfg.clearance(name))
                continue
            bottom = float(pose[2, 3]) - self._half[2]   # (upright: tilt not modelled here)
            if top <= bottom or math.hypot(p.xy[0] - float(pose[0, 3]), p.xy[1]
                                           - float(pose[1, 3])) >= self._corner + p.radius:
                continue   # below the bottom, or beyond the block's corners: no overlap
            n = self._outward(name, pose)
            if n is not None:
                worst = max(worst, min(top - bottom, self._side_depth(name, pose, n)))
            elif self._touches_top(name, pose):
                worst = max(worst, top - bottom)
        return worst

    # -- contacts of the robot's links with the poles ------------------------------------
    def pole_contacts(self, segments, normals: dict | None = None) -> list[Contact]:
        """Penetrating contacts of link capsules with the poles: ``segments`` are
        (capsule name, radius, end a, end b) in the root frame (m). Each contact is named
        ``pole:<pole>:<capsule>``; its normal pushes the capsule away from the pole's axis,
        its point is on the capsule's surface. Frictionless (a smooth pole).
        ``normals`` (by contact name) keep an ongoing contact's side: its depth is then
        measured along that normal, so a link pushed past the pole's axis (a thin
        obstacle) is still pushed back the way it came, not through."""
        normals = normals or {}
        out: list[Contact] = []
        for pole in self.cfg.poles:
            b0 = np.array([pole.xy[0], pole.xy[1], pole.z_min])
            b1 = np.array([pole.xy[0], pole.xy[1], pole.z_max])
            for name, radius, a0, a1 in segments:
                kind = f"pole:{pole.name}:{name}"
                # cheap reject: horizontal distance of the segment's box from the axis
                if kind not in normals and (min(a0[0], a1[0]) - radius - pole.radius > pole.xy[0]
                        or max(a0[0], a1[0]) + radius + pole.radius < pole.xy[0]
                        or min(a0[1], a1[1]) - radius - pole.radius > pole.xy[1]
                        or max(a0[1], a1[1]) + radius + pole.radius < pole.xy[1]):
                    continue
                pa, pb = segment_closest_points(a0, a1, b0, b1)
                d = pa - pb
                if kind in normals:
                    n = normals[kind]
                    depth = radius + pole.radius - float(n @ d)
                    if depth > 0.0:
                        out.append(Contact(kind, n, depth, pa - n * radius))
                    continue
                dist = float(np.linalg.norm(d))
                depth = radius + pole.radius - dist
                if depth <= 0.0:
                    continue
                if dist > 1e-9:
                    n = d / dist
                else:   # the axes cross: push horizontally, across the capsule's axis
                    across = np.cross([0.0, 0.0, 1.0], a1 - a0)
                    norm = float(np.linalg.norm(across))
                    n = across / norm if norm > 1e-12 else np.array([1.0, 0.0, 0.0])
                out.append(Contact(kind, n, depth, pa - n * radius))
        return out

    # -- contacts of the held block -----------------------------------------------------
    def contacts(self, tool_pose: np.ndarray, side_normal: np.ndarray | None = None,
                 margin: float = 0.0) -> list[Contact]:
        """Penetrating contacts of the held block at this tool pose (empty if not held).
        With ``side_normal``, the side of the peg the block is threaded on is taken as the
        plane of that normal tangent to the clearance circle, and reported at any depth
        (re-linearizing a contact found elsewhere: the linear solution may overshoot the
        curved side, even past the axis, where its own normal would flip).
        A peg the block is over or beside at its last actual pose (``track``) contributes
        that top or side at any depth; with ``margin`` (m) also when it is up to that far
        apart (a negative depth: a solver linearizing at a pose pushed out of the contact
        must still see the surface it was pushed out by)."""
        if self.state is not BlockState.HELD:
            return []
        pose = self._pose_of(tool_pose)
        centre = pose[:3, 3]
        bottom = centre[2] - self._half[2]
        lowest = self._lowest(pose)                   # its lowest corner (tilt included)
        out: list[Contact] = []
        up = _UP
        slide = np.array([centre[0], centre[1], bottom])   # friction's material point
        if self._table_z - lowest > -margin:
            point, z = self._table_point(pose)
            out.append(Contact("table", up, self._table_z - z, point, frictional=True,
                               slide=slide))
        for name, p in self._pegs.items():
            top = self._table_z + p.height
            if name == self.peg:
                e = self.misalignment(name, pose)
                clearance = self.cfg.block.hole_radius - p.radius
                rel = np.array([centre[0] - p.xy[0], centre[1] - p.xy[1], 0.0])
                if side_normal is not None:
                    n, excess = side_normal, float(-(side_normal @ rel)) - clearance
                else:
                    n, excess = (-rel / e if e > 0.0 else None), e - clearance
                if n is not None and (excess > 0.0 or side_normal is not None):
                    low = max(bottom, self._table_z)     # middle of the overlap
                    z = low + 0.5 * (min(top, centre[2] + self._half[2]) - low)
                    out.append(Contact(f"peg_side:{name}", n, excess,
                                       np.array([centre[0], centre[1], z])))
                continue
            depth = top - bottom
            memory = self._memory.get(name)
            if memory is not None:   # the side it is on, at its last actual pose
                kind, n = memory
                if kind == "top" and depth > -margin and self._touches_top(name, pose):
                    out.append(Contact(f"peg_top:{name}", up, depth, slide, frictional=True))
                elif kind == "side" and depth > -margin:
                    excess = self._side_depth(name, pose, n)
                    if excess > -margin:
                        low = max(bottom, self._table_z)
                        z = low + 0.5 * (min(top, centre[2] + self._half[2]) - low)
                        out.append(Contact(f"peg_side:{name}", n, excess,
                                           np.array([centre[0], centre[1], z])))
                continue
            if depth <= 0.0 or centre[2] + self._half[2] <= self._table_z:
                continue
            if math.hypot(p.xy[0] - float(centre[0]), p.xy[1] - float(centre[1])) \
                    >= self._corner + p.radius:
                continue   # beyond the block's corners: neither its side nor its top
            side = self._side_contact(name, pose)
            if side is not None and side[0] < depth:
                excess, n = side   # beside the peg, low: pushed off sideways
                low = max(bottom, self._table_z)
                z = low + 0.5 * (min(top, centre[2] + self._half[2]) - low)
                out.append(Contact(f"peg_side:{name}", n, excess,
                                   np.array([centre[0], centre[1], z])))
            elif self._touches_top(name, pose):
                out.append(Contact(f"peg_top:{name}", up, depth, slide, frictional=True))
        return out

    def update_held(self, tool_pose: np.ndarray) -> None:
        """Update threading from the held block's actual pose (after contact forces)."""
        if self.state is not BlockState.HELD:
            return
        pose = self._pose_of(tool_pose)
        bottom = pose[2, 3] - self._half[2]
        if self.peg is not None:
            top = self._table_z + self._pegs[self.peg].height
            if bottom > top:
                self.events.append(WorldEvent("unthreaded", self.peg))
                self.peg = None
        else:
            for name, p in self._pegs.items():
                top = self._table_z + p.height
                # (the centre is midway between the rims: farther than the clearance from
                # the axis, one rim is too: not accepted)
                if bottom < top - THREAD_DEPTH \
                        and self.misalignment(name, pose) <= self.cfg.clearance(name) \
                        and self.accepts(name, pose):
                    self.peg = name
                    self.events.append(WorldEvent("threaded", name))
                    break
        self.track(tool_pose)

    # -- grasping -----------------------------------------------------------------------
    def grasp(self, tool_pose: np.ndarray) -> None:
        """Attach the block to the tool where it is now (fingers closed on it)."""
        if self.state is BlockState.HELD:
            return
        if not self.block_between_fingers(tool_pose):
            raise WorldError("the block is not between the fingers")
        self._grasp = np.linalg.inv(tool_pose) @ self._pose
        self._held_key = None
        if self.state is BlockState.ON_PEG_TOP:
            where, self.peg = f"on top of {self.peg}", None
        else:
            where = f"on {self.peg}" if self.peg else "from table"
        self.state = BlockState.HELD
        self._memory.clear()
        self.track(tool_pose)
        self.events.append(WorldEvent("grasped", where))

    def release(self, tool_pose: np.ndarray, kind: str = "released") -> None:
        """Let go of the block (``kind`` "released" or "dropped"). It falls: threaded down a
        peg if its hole is within the clearance of the peg's axis (its xy kept within the
        clearance); else, over a peg's top, it stays balanced on the top if its centre is
        over the top's disc, or tips off onto the table just clear of the peg; else onto
        the table where it is."""
        if self.state is not BlockState.HELD:
            return
        pose = self.block_pose(tool_pose)
        self._grasp = None
        self._held_key = None
        self._memory.clear()
        xy = pose[:2, 3].copy()
        rest = np.eye(4)
        rest[:3, :3] = _yaw_only(pose[:3, :3])
        z = self._table_z + self._half[2]
        landed = self.peg
        if landed is None:
            for name, p in self._pegs.items():
                if self.misalignment(name, pose) <= self.cfg.block.hole_radius - p.radius:
                    landed = name
                    break
        on_top = None
        if landed is None:
            for name, p in self._pegs.items():
                if self._touches_top(name, pose) and \
                        pose[2, 3] - self._half[2] > self._table_z + p.height - 0.01:
                    if self.misalignment(name, pose) <= p.radius:   # balanced on the top
                        on_top = name
                        z = self._table_z + p.height + self._half[2]
                    else:                                           # tips off
                        xy = self._clear_of(name, pose)
                    break
        if landed is not None:
            p = self._pegs[landed]
            e = np.array(xy) - np.array(p.xy)
            clearance = self.cfg.block.hole_radius - p.radius
            if np.linalg.norm(e) > clearance:                       # the hole's wall
                xy = np.array(p.xy) + e * clearance / np.linalg.norm(e)
            self.state = BlockState.ON_PEG
        elif on_top is not None:
            self.state = BlockState.ON_PEG_TOP
        else:
            self.state = BlockState.ON_TABLE
        self.peg = landed if landed is not None else on_top
        rest[:3, 3] = (xy[0], xy[1], z)
        self._pose = rest
        if landed:
            where = f"on peg {landed}"
        elif on_top:
            where = f"on top of peg {on_top} ({1e3 * self.misalignment(on_top, rest):.1f} mm " \
                    "off its axis)"
        else:
            where = f"on the table at ({xy[0]:.3f}, {xy[1]:.3f})"
        self.events.append(WorldEvent(kind, where))

    def _clear_of(self, peg: str, pose: np.ndarray) -> np.ndarray:
        """The block's xy moved directly away from peg ``peg``'s axis just far enough for
        its footprint to clear the peg (it tipped off the top)."""
        p = self._pegs[peg]
        d = pose[:2, 3] - np.array(p.xy)
        norm = float(np.linalg.norm(d))
        n = d / norm if norm > 1e-9 else np.array([1.0, 0.0])
        probe = pose.copy()
        step = 0.0005
        for k in range(int((self._corner + p.radius) / step) + 2):
            probe[:2, 3] = np.array(p.xy) + n * (norm + k * step)
            if not self._touches_top(peg, probe) and self._side_contact(peg, probe) is None:
                break
        return probe[:2, 3].copy()

    def on_peg(self, name: str) -> bool:
        """Whether the block rests threaded on peg ``name`` (down at its base)."""
        return self.state is BlockState.ON_PEG and self.peg == name

    def take_events(self) -> list[WorldEvent]:
        out, self.events = self.events, []
        return out
