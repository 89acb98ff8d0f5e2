"""The SRDF's disabled collision pairs against fresh samples: 10,000 random configurations
within the joint limits (another seed than the generator's), checked three ways: the
capsules placed by the description's own DH forward kinematics with a closed-form segment
distance (no pinocchio, no coal), our collision model (hyperarm_ik.collision.CollisionModel),
and, for the rail carriage's box, the generator's per-shape coal queries. A Never pair is in
contact in none of them; a pair seen in contact is disabled only as Adjacent or Always (and
Always only when in contact in >= 95 % of them); the Adjacent pairs are the URDF's
neighbours. Under 10 s on a 2-core machine."""
from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from hyperarm_description.model import VARIANTS, load_description
from hyperarm_description.urdf import generate_urdf
from hyperarm_ik.collision import CollisionModel
from hyperarm_ik.kinematics import Kinematics
from hyperarm_moveit_config.collision_matrix import (ALWAYS_FRACTION, LinkGeometry,
                                                     adjacent_pairs, random_configurations)
from hyperarm_moveit_config.generate import SEED, config_paths, package_dir

pytestmark = pytest.mark.core

SAMPLES = 10000
TEST_SEED = SEED + 2026          # not the generator's samples
GRAZE = 1e-9                     # m: closer than this to touching counts as neither


def _disabled(variant: str) -> dict[tuple[str, str], str]:
    root = ET.parse(package_dir() / config_paths(variant)["srdf"]).getroot()
    return {(d.get("link1"), d.get("link2")): d.get("reason")
            for d in root.findall("disable_collisions")}


def _pair(a: str, b: str) -> tuple[str, str]:
    return (a, b) if a < b else (b, a)


def _segment_distances(p1, q1, p2, q2) -> np.ndarray:
    """Distances between the segments [p1[k], q1[k]] and [p2[k], q2[k]] (arrays N x 3) of
    non-zero length: the clamped closed form of their closest points (Ericson, Real-Time
    Collision Detection 5.1.9), vectorised over k. The reference here, free of coal."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = np.einsum("ij,ij->i", d1, d1), np.einsum("ij,ij->i", d2, d2)
    b, c, f = (np.einsum("ij,ij->i", d1, d2), np.einsum("ij,ij->i", d1, r),
               np.einsum("ij,ij->i", d2, r))
    denom = a * e - b * b
    s = np.where(denom > 1e-15, np.clip((b * f - c * e) / np.where(denom > 1e-15, denom, 1.0),
                                        0.0, 1.0), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0),
                 np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(p1 + d1 * s[:, None] - (p2 + d2 * t[:, None]), axis=1)


@pytest.fixture(scope="module")
def clearances() -> dict[tuple[str, str], np.ndarray]:
    """Link pair -> the least clearance (m) between their capsules in each of the SAMPLES
    configurations (the arm's joints; the rail moves every capsule alike)."""
    desc = load_description()
    qs = random_configurations(desc, SAMPLES, TEST_SEED)
    caps = desc.capsules
    ends = np.empty((len(caps), 2, SAMPLES, 3))
    for k, q in enumerate(qs):
        for i, (_, a, b) in enumerate(desc.capsule_segments(q)):
            ends[i, 0, k], ends[i, 1, k] = a, b
    out: dict[tuple[str, str], np.ndarray] = {}
    for i in range(len(caps)):
        for j in range(i + 1, len(caps)):
            if caps[i].frame == caps[j].frame:
                continue
            gap = _segment_distances(ends[i, 0], ends[i, 1], ends[j, 0], ends[j, 1]) \
                - caps[i].radius - caps[j].radius
            key = _pair(caps[i].frame, caps[j].frame)
            out[key] = np.minimum(out[key], gap) if key in out else gap
    return out


@pytest.mark.parametrize("variant", VARIANTS)
def test_adjacent_pairs_are_the_kinematic_neighbours(variant):
    desc = load_description(variant=variant)
    chain = ["base_link"] + [f"link{i}" for i in range(1, len(desc.joints) + 1)] + ["tool0"]
    expected = {_pair(a, b) for a, b in zip(chain, chain[1:])}
    if desc.rail:
        expected.add(("base_link", "rail_carriage"))
    got = {p for p, reason in _disabled(variant).items() if reason == "Adjacent"}
    assert got == expected


def test_links_without_geometry_make_their_neighbours_adjacent():
    """MoveIt's rule: a link with no collision geometry joins its neighbours (repeatedly),
    and pairs with such a link are not listed."""
    shape = "<collision><geometry><sphere radius='0.1'/></geometry></collision>"
    links = {"a": shape, "b": "", "c": shape, "d": "", "e": shape, "f": shape}
    joints = [("a", "b"), ("b", "c"), ("b", "d"), ("d", "e"), ("c", "f")]
    urdf = ET.fromstring(
        "<robot name='r'>"
        + "".join(f"<link name='{n}'>{g}</link>" for n, g in links.items())
        + "".join(f"<joint name='{p}{c}' type='fixed'><parent link='{p}'/><child link='{c}'/>"
                  "</joint>" for p, c in joints)
        + "</robot>")
    assert adjacent_pairs(urdf) == {("a", "c"), ("a", "e"), ("c", "e"), ("c", "f")}


@pytest.mark.parametrize("variant", VARIANTS)
def test_never_pairs_are_in_contact_in_none_of_10000_configurations(variant, clearances):
    never = [p for p, reason in _disabled(variant).items() if reason == "Never"]
    assert never
    for p in never:
        assert p in clearances, f"{p}: not a pair of capsules (no reference here)"
        least = float(clearances[p].min())
        assert least > GRAZE, f"{p} disabled as Never, but {least * 1000:.2f} mm apart"


@pytest.mark.parametrize("variant", VARIANTS)
def test_pairs_seen_in_contact_are_disabled_only_when_adjacent_or_always(variant, clearances):
    disabled = _disabled(variant)
    for p, gap in clearances.items():
        share = float(np.mean(gap < -GRAZE))
        reason = disabled.get(p)
        if share > 0.0:
            assert reason in (None, "Adjacent", "Always"), (p, reason, share)
        if reason == "Always":
            assert share >= ALWAYS_FRACTION, (p, share)
        if reason is None:
            assert share < ALWAYS_FRACTION, (p, share)


@pytest.mark.parametrize("variant", VARIANTS)
def test_our_collision_model_sees_no_never_pair(variant, clearances):
    """hyperarm_ik's CollisionModel (what IK and paths check) over the same configurations:
    it never reports a Never pair, and it sees exactly the pairs the reference sees."""
    desc = load_description(variant=variant)
    model = CollisionModel(Kinematics(desc))
    link = {c.name: c.frame for c in desc.capsules}
    checked = {_pair(link[model.geom.geometryObjects[p.first].name],
                     link[model.geom.geometryObjects[p.second].name])
               for p in model.geom.collisionPairs}
    qs = random_configurations(load_description(), SAMPLES, TEST_SEED)
    rail = [0.0] if desc.rail else []
    seen = set()
    for q in qs:
        seen |= {_pair(link[c.a], link[c.b]) for c in model.check(np.concatenate([rail, q]))}
    disabled = _disabled(variant)
    assert not {p for p in seen if disabled.get(p) == "Never"}
    assert {p for p in seen if disabled.get(p) is not None} <= \
        {p for p, r in disabled.items() if r == "Always"}
    reference = {p for p in checked if np.any(clearances[p] < -GRAZE)}
    assert seen == reference


def test_rail_carriage_pairs():
    """The rail carriage's box (a URDF box, not a capsule): link1 and link2 overlap it in
    every configuration (Always), every other link touches it sometimes (checked)."""
    desc = load_description(variant="rail_arm")
    geometry = LinkGeometry(desc, generate_urdf(desc))
    disabled = _disabled("rail_arm")
    pairs = {_pair(a, "rail_carriage"): geometry.shape_pairs(a, "rail_carriage")
             for a in geometry.links if a != "rail_carriage"}
    pairs = {p: s for p, s in pairs.items() if disabled.get(p) != "Adjacent"}
    counts = dict.fromkeys(pairs, 0)
    n = 2000
    for q in random_configurations(desc, n, TEST_SEED):
        for p in geometry.contacts(q, pairs):
            counts[p] += 1
    for p, count in counts.items():
        assert count > 0, p
        assert (disabled.get(p) == "Always") == (count >= ALWAYS_FRACTION * n), (p, count)
        assert disabled.get(p) in (None, "Always")
    assert {p for p in counts if disabled.get(p) == "Always"} == \
        {("link1", "rail_carriage"), ("link2", "rail_carriage")}
