"""Collision checks of the arm with itself and its work cell, on pinocchio + coal (no ROS).

Geometry (one source, hyperarm_description): the robot is the description's collision
capsules (``desc.capsules``: one per link and one for the gripper, on their URDF frames); the
work cell is a :class:`hyperarm_description.world.WorldSpec` (the mock's ``world:`` schema):

- the table: a box 0.1 m thick under ``table_height`` over its x/y extent, or a half-space
  z <= table_height when the extent is unbounded;
- every peg and pole: a vertical coal cylinder;
- the block, only while it is held: attached to tool0 at ``held_pose`` (default: centred
  on tool0, its z axis along tool0's y, i.e. vertical with the hand pointing down, as the
  mock grasps it), modelled as four boxes around a square hole of half-side
  ``hole_radius`` (coal has no boolean shapes), so that a peg threading the hole is not a
  collision. A block at rest is not modelled (its position after a put-down is not known
  here; the peg under it is).

Pairs: every pair of robot capsules except those of adjacent links and those that already
touch in the stretched ready pose q = 0 (they share a joint: link7 and link9 around the
zero-length link8), every robot capsule against every world object, and the held block
against the world and the links that do not hold it (all but link9 and the gripper). While
the block is held the gripper's capsule is not checked against the pegs: it fills the
space between the fingers, through which the peg passes once the block's hole threads it
(the block's own model then decides).

Units: m, rad. Poses in the model's root frame (base_link; world for the rail variant).
``margin`` (m) inflates every robot capsule (and the held block) by that much.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import coal
import numpy as np
import pinocchio as pin

from hyperarm_description.world import WorldSpec

from .errors import IKError, InvalidOptionError
from .kinematics import Kinematics

__all__ = ["CollisionModel", "Contact", "PathCheck", "CollisionError", "TABLE_THICKNESS",
           "DEFAULT_HELD_POSE", "check_joint_path", "pose_path"]

TABLE_THICKNESS = 0.1  # m, of the table box under its top surface (bounded tables)
#: block centre at tool0, the block's z axis along tool0's y (hand pointing down: z up)
DEFAULT_HELD_POSE = pin.SE3(pin.utils.rotate("x", -math.pi / 2), np.zeros(3)).homogeneous


#: m, how far below the table's top the hand's capsules (envelopes of the wrist, palm and
#: closed fingers, reaching 5 mm below the finger pads) may go: the pads themselves meet the
#: table, and a grasp aimed at a block's detected pose may be aimed up to 4 mm low (the
#: camera's height noise: a block taken off a peg's base was refused at 2 mm low with 6 mm)
HAND_TABLE_ALLOWANCE = 0.009


class CollisionError(IKError):
    """A collision model cannot be built from the description and work cell given."""


@dataclass(frozen=True)
class Contact:
    """Two bodies in collision (``a`` is a robot part, ``b`` a robot part or an obstacle)."""

    a: str
    b: str

    def __str__(self) -> str:
        return f"{self.a} with {self.b}"


@dataclass
class PathCheck:
    """Outcome of a path check: ``free``, else the first colliding sample along it."""

    free: bool
    samples: int
    s: float | None = None            # path parameter in [0, 1] of the first collision
    q: np.ndarray | None = None       # configuration there
    contacts: list[Contact] = field(default_factory=list)
    message: str = ""


class CollisionModel:
    """Self and world collision checks for one robot variant and work cell.

    ``check(q, held=...)`` lists the contacts at q; ``in_collision`` is its fast yes/no.
    One instance is not thread-safe (pinocchio data); build one per thread.
    """

    def __init__(self, kin: Kinematics, world: WorldSpec | None = None, *,
                 margin: float = 0.0, held_pose: np.ndarray | None = None) -> None:
        if not math.isfinite(margin) or margin < 0.0:
            raise InvalidOptionError(f"collision margin must be >= 0 m, got {margin!r}")
        self.kin = kin
        self.world = world
        self.margin = float(margin)
        self.held_pose = np.array(DEFAULT_HELD_POSE if held_pose is None else held_pose,
                                  dtype=float)
        if self.held_pose.shape != (4, 4):
            raise InvalidOptionError("held_pose must be a 4x4 homogeneous matrix")
        model = kin.model
        self.model = model
        self.data = model.createData()
        caps = kin.desc.capsules
        if not caps:
            raise CollisionError("the robot description has no collision capsules "
                                 "(collision.capsules in its YAML)")
        gm = pin.GeometryModel()
        self._robot: list[int] = []
        self._body_joint: dict[int, int] = {}
        for cap in caps:
            if not model.existFrame(cap.frame):
                raise CollisionError(f"capsule {cap.name}: frame {cap.frame!r} is not in "
                                     f"the model")
            f = model.frames[model.getFrameId(cap.frame)]
            placement = f.placement * pin.SE3(cap.placement())
            gid = gm.addGeometryObject(pin.GeometryObject(
                cap.name, f.parentJoint, model.getFrameId(cap.frame), placement,
                coal.Capsule(cap.radius + self.margin, cap.length)))
            self._robot.append(gid)
            self._body_joint[gid] = f.parentJoint
        self._world: list[int] = []
        if world is not None:
            for name, geom, pose in _world_objects(world):
                self._world.append(gm.addGeometryObject(pin.GeometryObject(
                    name, 0, 0, pin.SE3(pose), geom)))
                if name == "table":      # the hand's floor (see _pairs)
                    floor = pose.copy()
                    floor[2, 3] -= HAND_TABLE_ALLOWANCE
                    self._world.append(gm.addGeometryObject(pin.GeometryObject(
                        "table (the hand's envelope)", 0, 0, pin.SE3(floor), geom)))
        # the held block: four boxes around its hole, on tool0
        self._block: list[int] = []
        if world is not None and world.block is not None:
            tool = model.frames[kin.tool_id]
            for k, (geom, pose) in enumerate(_block_frame(world.block.size,
                                                          world.block.hole_radius,
                                                          self.margin)):
                gid = gm.addGeometryObject(pin.GeometryObject(
                    f"block_{k}", tool.parentJoint, kin.tool_id,
                    tool.placement * pin.SE3(self.held_pose @ pose), geom))
                self._block.append(gid)
                self._body_joint[gid] = tool.parentJoint
        self.geom = gm
        self._pairs(caps)

    # --- pairs ---------------------------------------------------------------------------
    def _pairs(self, caps) -> None:
        gm = self.geom
        names = [o.name for o in gm.geometryObjects]
        touching = self._touching_at_ready()
        order = {c.name: i for i, c in enumerate(caps)}
        self_pairs = []
        for i, a in enumerate(self._robot):
            for b in self._robot[i + 1:]:
                ja, jb = self._body_joint[a], self._body_joint[b]
                if abs(ja - jb) <= 1 or (a, b) in touching:
                    continue  # same or adjacent links, or parts that share a joint
                self_pairs.append((a, b))
        holders = {n for n in ("gripper", f"link{len(self.kin.desc.joints)}") if n in order}
        # the hand (the last link's capsule and the gripper's, envelopes of the wrist, palm
        # and closed fingers) meets neither a peg nor the table, as in the MuJoCo model the
        # mock steps (hyperarm_description.mjcf): the peg passes between the fingers into
        # the block's hole, and the finger pads (not modelled here) meet the table, the
        # envelope reaching 5 mm below them: the hand meets the table's top lowered by
        # HAND_TABLE_ALLOWANCE instead (a tool target in the table is still refused)
        passed = {w for w in self._world if names[w].startswith("peg ") or names[w] == "table"}
        hand_floor = {w for w in self._world if names[w].startswith("table (")}
        world_pairs = [(a, w) for a in self._robot for w in self._world
                       if not (names[a] in holders and w in passed)
                       and (names[a] in holders or w not in hand_floor)]
        block_pairs = [(blk, w) for blk in self._block for w in self._world
                       if w not in hand_floor]
        block_pairs += [(blk, a) for blk in self._block for a in self._robot
                        if names[a] not in holders]
        self._hand_pegs: list[tuple[int, int]] = []
        self._groups = {"self": self_pairs, "world": world_pairs, "block": block_pairs}
        for a, b in self_pairs + world_pairs + block_pairs:
            gm.addCollisionPair(pin.CollisionPair(a, b))
        self._pair_index = {(p.first, p.second): k for k, p in enumerate(gm.collisionPairs)}
        self._names = names
        self.gdata = pin.GeometryData(gm)
        self._active_held: bool | None = None
        self._set_held(False)

    def _touching_at_ready(self) -> set[tuple[int, int]]:
        """Pairs of robot capsules in contact at q = 0 (the stretched arm)."""
        gm = self.geom
        gd = pin.GeometryData(gm)
        pin.forwardKinematics(self.model, self.data, np.zeros(self.model.nq))
        pin.updateGeometryPlacements(self.model, self.data, gm, gd)
        out = set()
        req = coal.CollisionRequest()
        for i, a in enumerate(self._robot):
            for b in self._robot[i + 1:]:
                res = coal.CollisionResult()
                if coal.collide(gm.geometryObjects[a].geometry, _transform(gd.oMg[a]),
                                gm.geometryObjects[b].geometry, _transform(gd.oMg[b]), req, res):
                    out.add((a, b))
        return out

    def _set_held(self, held: bool) -> None:
        """Switch the held block's pairs on (and the gripper's with the pegs off) or back."""
        if held == self._active_held:
            return
        gd = self.gdata
        for pairs, on in ((self._groups["block"], held), (self._hand_pegs, not held)):
            for a, b in pairs:
                k = self._pair_index[(a, b)]
                if on:
                    gd.activateCollisionPair(k)
                else:
                    gd.deactivateCollisionPair(k)
        self._active_held = held

    @property
    def pair_count(self) -> dict[str, int]:
        """How many pairs of each group are checked (self, world, block)."""
        return {k: len(v) for k, v in self._groups.items()}

    @property
    def has_block(self) -> bool:
        return bool(self._block)

    # --- checks --------------------------------------------------------------------------
    def _update(self, q: np.ndarray) -> None:
        pin.forwardKinematics(self.model, self.data, q)
        pin.updateGeometryPlacements(self.model, self.data, self.geom, self.gdata)

    def in_collision(self, q: np.ndarray, held: bool = False) -> bool:
        """Whether any checked pair collides at q (stops at the first)."""
        self._set_held(held and self.has_block)
        self._update(np.asarray(q, dtype=float))
        return bool(pin.computeCollisions(self.geom, self.gdata, True))

    def check(self, q: np.ndarray, held: bool = False) -> list[Contact]:
        """Every colliding pair at q, robot part first (empty: collision-free)."""
        self._set_held(held and self.has_block)
        self._update(np.asarray(q, dtype=float))
        if not pin.computeCollisions(self.geom, self.gdata, False):
            return []
        out = []
        for k, res in enumerate(self.gdata.collisionResults):
            if res.isCollision() and self.gdata.activeCollisionPairs[k]:
                p = self.geom.collisionPairs[k]
                out.append(self._contact(p.first, p.second))
        return out

    def _contact(self, a: int, b: int) -> Contact:
        na, nb = self._label(a), self._label(b)
        if b in self._block and a not in self._block:
            na, nb = nb, na
        return Contact(na, nb)

    def _label(self, gid: int) -> str:
        if gid in self._block:
            return "held block"
        return self._names[gid]

    def clearance_gradient(self, q: np.ndarray, held: bool = False
                           ) -> tuple[float, np.ndarray] | None:
        """(signed distance m, d distance / dq) of the deepest colliding pair at q, or None
        when collision-free. The gradient moves the pair apart (a null-space push)."""
        contacts = self.check(q, held)
        if not contacts:
            return None
        gd, gm = self.gdata, self.geom
        best = None
        for k, res in enumerate(gd.collisionResults):
            if not (res.isCollision() and gd.activeCollisionPairs[k]):
                continue
            pair = gm.collisionPairs[k]
            # a fresh, stateless coal query: pinocchio's functors warm start GJK from the
            # previous query, which would make the push (and the answer) history-dependent
            dres = coal.DistanceResult()
            coal.distance(gm.geometryObjects[pair.first].geometry, _transform(gd.oMg[pair.first]),
                          gm.geometryObjects[pair.second].geometry,
                          _transform(gd.oMg[pair.second]), coal.DistanceRequest(), dres)
            if best is None or dres.min_distance < best[1].min_distance:
                best = (k, dres)
        k, dres = best
        pair = gm.collisionPairs[k]
        p1, p2 = dres.getNearestPoint1(), dres.getNearestPoint2()
        n = np.asarray(dres.normal, dtype=float)  # from object 1 to object 2
        if not np.all(np.isfinite(n)) or np.linalg.norm(n) < 1e-12:
            n = p2 - p1
            nn = np.linalg.norm(n)
            n = n / nn if nn > 1e-12 else np.array([0.0, 0.0, 1.0])
        pin.computeJointJacobians(self.model, self.data, q)
        grad = np.zeros(self.model.nv)
        for gid, point, sign in ((pair.first, p1, -1.0), (pair.second, p2, 1.0)):
            j = self._body_joint.get(gid, 0)
            if j == 0:
                continue  # a world object does not move
            jac = pin.getJointJacobian(self.model, self.data, j,
                                       pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            r = point - self.data.oMi[j].translation
            jp = jac[:3] - np.cross(r, jac[3:].T).T  # velocity of the point, root frame
            grad += sign * (n @ jp)
        return float(dres.min_distance), grad

    # --- paths ----------------------------------------------------------------------------
    def check_path(self, q_a: np.ndarray, q_b: np.ndarray, held: bool = False,
                   max_step: float = 0.02, escape: bool = False) -> PathCheck:
        """Check the straight joint-space segment from q_a to q_b, sampled so that no joint
        moves more than ``max_step`` rad (rail: m) between samples, both ends included.
        ``escape``: q_a is where the arm is (measured) and may already touch (a press, a
        servo deflected into a contact): the path may start in collision as long as its
        deepest pair gets no deeper (signed distance, 0.1 mm of slack) until it is free;
        from then on as without."""
        qa, qb = np.asarray(q_a, dtype=float), np.asarray(q_b, dtype=float)
        if not (np.all(np.isfinite(qa)) and np.all(np.isfinite(qb))) \
                or qa.shape != (self.model.nq,) or qb.shape != (self.model.nq,):
            raise InvalidOptionError(f"path ends need {self.model.nq} finite joint values")
        if not math.isfinite(max_step) or max_step <= 0.0:
            raise InvalidOptionError(f"max_step must be > 0, got {max_step!r}")
        n = max(1, int(math.ceil(float(np.max(np.abs(qb - qa))) / max_step)))
        samples = [(i / n, qa + (qb - qa) * (i / n)) for i in range(n + 1)]
        if escape:
            start = self.clearance_gradient(qa, held)
            if start is not None:
                depth = start[0]
                for k, (s, q) in enumerate(samples):
                    now = self.clearance_gradient(q, held)
                    if now is None:
                        return self._scan(samples[k:], held, offset=k)
                    if now[0] < depth - 1e-4:
                        contacts = self.check(q, held)
                        return PathCheck(False, k + 1, s, np.array(q), contacts,
                                         f"deeper into a contact at s = {s:.3f} "
                                         f"({-now[0] * 1e3:.1f} mm, from "
                                         f"{-start[0] * 1e3:.1f} mm): "
                                         + ", ".join(str(c) for c in contacts))
                    depth = max(depth, now[0])
                return PathCheck(True, len(samples), message="leaves no contact it started in "
                                 "deeper")
        return self._scan(samples, held)

    def check_configurations(self, path: Sequence[tuple[float, np.ndarray]],
                             held: bool = False) -> PathCheck:
        """Check given (s, q) samples in order (e.g. IK solutions along a Cartesian line)."""
        return self._scan(path, held)

    def _scan(self, samples, held: bool, offset: int = 0) -> PathCheck:
        for k, (s, q) in enumerate(samples, start=offset):
            if self.in_collision(q, held):
                contacts = self.check(q, held)
                return PathCheck(False, k + 1, s, np.array(q), contacts,
                                 f"in collision at s = {s:.3f}: "
                                 + ", ".join(str(c) for c in contacts))
        return PathCheck(True, offset + len(samples), message="collision-free")


def _transform(m: pin.SE3) -> coal.Transform3s:
    return coal.Transform3s(m.rotation, m.translation)


def check_joint_path(model: CollisionModel, q_a, q_b, held: bool = False,
                     max_step: float = 0.02) -> PathCheck:
    """Function form of :meth:`CollisionModel.check_path` (for callers without a class)."""
    return model.check_path(q_a, q_b, held, max_step)


def pose_path(kin: Kinematics, solve: Callable[[np.ndarray, np.ndarray, np.ndarray], object],
              model: CollisionModel, pose_a: np.ndarray, pose_b: np.ndarray, q_start,
              held: bool = False, step: float = 0.005, angle_step: float = 0.05) -> PathCheck:
    """Check the straight Cartesian line of tool0 from ``pose_a`` to ``pose_b`` (4x4):
    poses interpolated (position linearly, rotation along the geodesic) every ``step`` m /
    ``angle_step`` rad, each solved by ``solve(p, R, seed) -> IKResult`` warm started from
    the previous solution (from ``q_start`` first), then checked for collisions.
    An IK failure along the line is reported as not free (message "IK failed at s")."""
    ta, tb = np.asarray(pose_a, dtype=float), np.asarray(pose_b, dtype=float)
    dist = float(np.linalg.norm(tb[:3, 3] - ta[:3, 3]))
    rel = pin.log3(ta[:3, :3].T @ tb[:3, :3])
    n = max(1, int(math.ceil(max(dist / step, float(np.linalg.norm(rel)) / angle_step))))
    q = np.asarray(q_start, dtype=float)
    samples = []
    for i in range(n + 1):
        s = i / n
        p = ta[:3, 3] + (tb[:3, 3] - ta[:3, 3]) * s
        r = ta[:3, :3] @ pin.exp3(rel * s)
        res = solve(p, r, q)
        if not res.success:
            return PathCheck(False, i + 1, s, np.array(res.q), [],
                             f"IK failed at s = {s:.3f}: {res.message}")
        q = np.array(res.q)
        samples.append((s, q))
    return model.check_configurations(samples, held)


# --- geometry of the work cell -----------------------------------------------------------
def _world_objects(world: WorldSpec) -> list[tuple[str, coal.CollisionGeometry, np.ndarray]]:
    out = []
    t = world.table
    pose = np.eye(4)
    if all(map(math.isfinite, (*t.x_range, *t.y_range))):
        sx, sy = t.x_range[1] - t.x_range[0], t.y_range[1] - t.y_range[0]
        pose[:3, 3] = (0.5 * sum(t.x_range), 0.5 * sum(t.y_range),
                       t.height - 0.5 * TABLE_THICKNESS)
        out.append(("table", coal.Box(sx, sy, TABLE_THICKNESS), pose))
    else:  # unbounded: everything below the top surface
        out.append(("table", coal.Halfspace(np.array([0.0, 0.0, 1.0]), t.height), pose))
    for peg in world.pegs:
        pose = np.eye(4)
        pose[:3, 3] = (peg.xy[0], peg.xy[1], t.height + 0.5 * peg.height)
        out.append((f"peg {peg.name}", coal.Cylinder(peg.radius, peg.height), pose))
    for pole in world.poles:
        pose = np.eye(4)
        pose[:3, 3] = (pole.xy[0], pole.xy[1], 0.5 * (pole.z_min + pole.z_max))
        out.append((f"pole {pole.name}", coal.Cylinder(pole.radius, pole.height), pose))
    return out


def _block_frame(size, hole: float, margin: float) -> list[tuple[coal.Box, np.ndarray]]:
    """Four boxes making a block of ``size`` (x, y, z; m) with a square vertical hole of
    half-side ``hole`` at its centre, in the block's frame (centre at the origin)."""
    sx, sy, sz = (v + 2.0 * margin for v in size)
    h = max(0.0, hole - margin)
    out = []
    wx = 0.5 * sx - h  # the two slabs along x (full depth in y)
    for sign in (-1.0, 1.0):
        pose = np.eye(4)
        pose[0, 3] = sign * (h + 0.5 * wx)
        out.append((coal.Box(wx, sy, sz), pose))
    wy = 0.5 * sy - h  # the two slabs along y, between them
    for sign in (-1.0, 1.0):
        pose = np.eye(4)
        pose[1, 3] = sign * (h + 0.5 * wy)
        out.append((coal.Box(2.0 * h, wy, sz), pose))
    return out
