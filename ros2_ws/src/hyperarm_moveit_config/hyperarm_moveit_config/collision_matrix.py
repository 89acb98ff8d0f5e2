"""The SRDF's disabled collision pairs, computed from the robot's own collision geometry the
way MoveIt's Setup Assistant computes them (no ROS, no MoveIt needed).

Geometry: the description's collision capsules as ``hyperarm_ik.collision.CollisionModel``
places them (pinocchio + coal), each belonging to the URDF link it is fixed to (``base`` on
``base_link``, ``gripper`` on ``tool0``), plus the URDF's own ``<collision>`` shapes of the
links that have no capsule (the rail carriage's box on ``rail_arm``). A capsule is exactly the
URDF's cylinder plus two spheres, so this is the geometry MoveIt checks.

Pairs: every two links with collision geometry, names in alphabetical order (as the Setup
Assistant writes them). Each is one of

- ``Adjacent``: joined by a joint, or through links without geometry (MoveIt's connection
  graph: a link without geometry makes all its neighbours adjacent to each other);
- ``Always``: in contact in at least ``always_fraction`` of the sampled configurations
  (default :data:`ALWAYS_FRACTION`, the Setup Assistant's ``min_collision_fraction``):
  parts that share a joint point (link7 and link9 around the zero-length link8) or that
  overlap by construction (link1 and link2 with the rail carriage's box); left enabled,
  MoveIt would find (nearly) every state in collision;
- ``Never``: in contact in none of the sampled configurations;
- enabled (``reason`` None): seen in contact sometimes; MoveIt checks it.

Unlike the Setup Assistant there is no ``Default`` reason (pairs in contact at the default
state q = 0 are not disabled for that alone; :attr:`CollisionMatrix.ready_contacts` lists
the enabled ones, which would make the ready pose invalid in MoveIt).

Samples: ``samples`` configurations drawn uniformly within the joint limits of the kinematic
joints (rail included; the gripper joint moves ``gripper_finger`` only, which has no
collision geometry) by ``numpy.random.default_rng(seed)``, so the result is reproducible.
Every contact is a fresh coal query per pair of shapes: pinocchio's batched
``computeCollisions`` warm-starts GJK from the previous query and missed 2 of 780,000
capsule-box contacts on the rail carriage (a deep penetration reported free).

Units: m, rad.
"""
from __future__ import annotations

import itertools
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin

from hyperarm_description.model import RobotDescription
from hyperarm_ik.collision import CollisionModel
from hyperarm_ik.kinematics import Kinematics

__all__ = ["ADJACENT", "ALWAYS", "NEVER", "ALWAYS_FRACTION", "PairStats", "CollisionMatrix",
           "LinkGeometry", "urdf_collision_links", "adjacent_pairs", "random_configurations",
           "compute_collision_matrix"]

ADJACENT, ALWAYS, NEVER = "Adjacent", "Always", "Never"
#: share of the samples in contact from which a pair counts as always in collision
#: (the MoveIt Setup Assistant's default min_collision_fraction)
ALWAYS_FRACTION = 0.95


def _pair(a: str, b: str) -> tuple[str, str]:
    return (a, b) if a < b else (b, a)


@dataclass(frozen=True)
class PairStats:
    """One pair of links: how many samples had them in contact (0 for adjacent pairs, which
    are not sampled) and why MoveIt need not check it (None: it must)."""

    links: tuple[str, str]
    contacts: int
    reason: str | None


@dataclass(frozen=True)
class CollisionMatrix:
    """Every link pair of one variant, sorted by link names."""

    variant: str
    samples: int
    seed: int
    links: tuple[str, ...]                    # links with collision geometry
    pairs: tuple[PairStats, ...]
    ready_contacts: tuple[tuple[str, str], ...]  # enabled pairs in contact at q = 0
    always_fraction: float = ALWAYS_FRACTION

    def disabled(self) -> list[PairStats]:
        return [p for p in self.pairs if p.reason is not None]

    def counts(self) -> dict[str, int]:
        """Pairs per reason (``enabled`` for those MoveIt checks) and in total."""
        out = {ADJACENT: 0, ALWAYS: 0, NEVER: 0, "enabled": 0}
        for p in self.pairs:
            out[p.reason or "enabled"] += 1
        out["total"] = len(self.pairs)
        return out

    def summary(self) -> str:
        """e.g. '10 Adjacent, 1 Always, 2 Never disabled; 42 of 55 pairs checked'."""
        c = self.counts()
        return (f"{c[ADJACENT]} Adjacent, {c[ALWAYS]} Always, {c[NEVER]} Never disabled; "
                f"{c['enabled']} of {c['total']} pairs checked")


def urdf_collision_links(root: ET.Element) -> set[str]:
    """Names of the URDF links that have at least one ``<collision>`` element."""
    return {link.get("name") for link in root.findall("link")
            if link.find("collision") is not None}


def adjacent_pairs(root: ET.Element) -> set[tuple[str, str]]:
    """The Setup Assistant's adjacent pairs of a URDF: links joined by a joint, where links
    without collision geometry are contracted (their neighbours become adjacent to each
    other, repeatedly); only pairs of links that both have geometry are returned."""
    graph: dict[str, set[str]] = {link.get("name"): set() for link in root.findall("link")}
    for joint in root.findall("joint"):
        parent, child = joint.find("parent").get("link"), joint.find("child").get("link")
        graph[parent].add(child)
        graph[child].add(parent)
    shaped = urdf_collision_links(root)
    changed = True
    while changed:
        changed = False
        for link, neighbours in graph.items():
            if link in shaped:
                continue
            for a, b in itertools.permutations(neighbours, 2):
                if b not in graph[a]:
                    graph[a].add(b)
                    changed = True
    return {_pair(a, b) for a, nbs in graph.items() for b in nbs
            if a != b and a in shaped and b in shaped}


def random_configurations(desc: RobotDescription, n: int, seed: int) -> np.ndarray:
    """``n`` x nq configurations uniform within the kinematic joints' limits (pinocchio
    order: rail first on rail_arm), from ``numpy.random.default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    return rng.uniform(desc.lower_limits(), desc.upper_limits(), size=(n, len(desc.lower_limits())))


class LinkGeometry:
    """The robot's collision shapes, grouped by URDF link, on the pinocchio model.

    ``contacts(q, pairs)`` answers which of the given link pairs touch at q, each shape pair
    with a fresh coal query (no warm start: no state carried between calls)."""

    def __init__(self, desc: RobotDescription, urdf_text: str) -> None:
        kin = Kinematics(desc)
        self.model = kin.model
        self.data = self.model.createData()
        gm = pin.GeometryModel()
        for obj in CollisionModel(kin).geom.geometryObjects:   # the capsules
            gm.addGeometryObject(obj)
        capsule_links = {self._link(o) for o in gm.geometryObjects}
        urdf = pin.buildGeomFromUrdfString(self.model, urdf_text, pin.GeometryType.COLLISION)
        urdf_links = {self._link(o) for o in urdf.geometryObjects}
        if not capsule_links <= urdf_links:
            raise RuntimeError(f"capsules on links without URDF collision geometry: "
                               f"{sorted(capsule_links - urdf_links)}")
        for obj in urdf.geometryObjects:   # links the capsules do not cover (rail carriage)
            if self._link(obj) not in capsule_links:
                gm.addGeometryObject(obj)
        self.geom = gm
        self.gdata = pin.GeometryData(gm)
        self.shapes = [o.geometry for o in gm.geometryObjects]
        self.owner = [self._link(o) for o in gm.geometryObjects]
        self.links = tuple(sorted(set(self.owner)))
        self._request = coal.CollisionRequest()

    def _link(self, obj: pin.GeometryObject) -> str:
        return self.model.frames[obj.parentFrame].name

    def shape_pairs(self, a: str, b: str) -> list[tuple[int, int]]:
        """Indices of every shape of link ``a`` with every shape of link ``b``."""
        ia = [k for k, o in enumerate(self.owner) if o == a]
        ib = [k for k, o in enumerate(self.owner) if o == b]
        return [(i, j) for i in ia for j in ib]

    def contacts(self, q: np.ndarray, pairs: dict[tuple[str, str], list[tuple[int, int]]]
                 ) -> set[tuple[str, str]]:
        """The link pairs (keys of ``pairs``, with their :meth:`shape_pairs`) in contact at q."""
        pin.updateGeometryPlacements(self.model, self.data, self.geom, self.gdata,
                                     np.asarray(q, dtype=float))
        tf = [coal.Transform3s(m.rotation, m.translation) for m in self.gdata.oMg]
        out = set()
        for link_pair, shape_pairs in pairs.items():
            for i, j in shape_pairs:
                if coal.collide(self.shapes[i], tf[i], self.shapes[j], tf[j], self._request,
                                coal.CollisionResult()):
                    out.add(link_pair)
                    break
        return out


def compute_collision_matrix(desc: RobotDescription, urdf_text: str, samples: int = 10000,
                             seed: int = 0, always_fraction: float = ALWAYS_FRACTION
                             ) -> CollisionMatrix:
    """Classify every link pair of ``desc`` (with its generated URDF ``urdf_text``) over
    ``samples`` random configurations: see the module's docstring."""
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    root = ET.fromstring(urdf_text)
    geometry = LinkGeometry(desc, urdf_text)
    if set(geometry.links) != urdf_collision_links(root):
        raise RuntimeError(f"links with collision geometry: capsules + URDF give "
                           f"{sorted(geometry.links)}, the URDF "
                           f"{sorted(urdf_collision_links(root))}")
    adjacent = adjacent_pairs(root)
    checked = {p: geometry.shape_pairs(*p)
               for p in itertools.combinations(geometry.links, 2) if p not in adjacent}
    counts = dict.fromkeys(checked, 0)
    for q in random_configurations(desc, samples, seed):
        for p in geometry.contacts(q, checked):
            counts[p] += 1
    ready = geometry.contacts(np.zeros(len(desc.lower_limits())), checked)
    pairs = []
    for p in itertools.combinations(geometry.links, 2):
        if p in adjacent:
            pairs.append(PairStats(p, 0, ADJACENT))
            continue
        n = counts[p]
        reason = NEVER if n == 0 else ALWAYS if n >= always_fraction * samples else None
        pairs.append(PairStats(p, n, reason))
    always = {p.links for p in pairs if p.reason == ALWAYS}
    return CollisionMatrix(desc.variant, samples, seed, geometry.links, tuple(pairs),
                           tuple(sorted(ready - always)), always_fraction)
