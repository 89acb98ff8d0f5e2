"""URDF generation from the robot description (no ROS needed).

Link frames: ``link<i>`` has its origin on joint axis i with z along the axis and x towards
the next joint, i.e. DH frame i-1 rotated by q_i. Joint i's origin is therefore the fixed
part Tz(d) Tx(a) Rx(alpha) of DH row i-1 (identity for joint 1) times Rz(theta_i), and the
fixed joint ``tool0_joint`` adds row 9's fixed part, so ``tool0`` is exactly DH frame 9.

The generated files in ``urdf/`` are committed; ``generate_urdf --check`` (and a test) fails
if they are stale. Regenerate with ``generate_urdf`` (console script) after editing the YAML.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from .model import VARIANTS, DHRow, RobotDescription, load_description

__all__ = ["generate_urdf", "rpy_from_matrix", "urdf_path", "main"]


def rpy_from_matrix(r: np.ndarray) -> tuple[float, float, float]:
    """URDF roll-pitch-yaw (R = Rz(yaw) Ry(pitch) Rx(roll)) of a rotation matrix, rad."""
    sp = -r[2, 0]
    if abs(sp) >= 1.0 - 1e-12:
        pitch = math.copysign(math.pi / 2.0, sp)
        yaw = 0.0
        roll = math.atan2(-r[1, 2], r[1, 1])
    else:
        pitch = math.asin(sp)
        roll = math.atan2(r[2, 1], r[2, 2])
        yaw = math.atan2(r[1, 0], r[0, 0])
    return roll, pitch, yaw


def _fixed_part(row: DHRow) -> np.ndarray:
    """Tz(d) Tx(a) Rx(alpha): the part of a DH row after the joint rotation."""
    ca, sa = math.cos(row.alpha), math.sin(row.alpha)
    return np.array([[1.0, 0.0, 0.0, row.a],
                     [0.0, ca, -sa, 0.0],
                     [0.0, sa, ca, row.d],
                     [0.0, 0.0, 0.0, 1.0]])


def _rz(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _f(x: float) -> str:
    """Full-precision float text; -0.0 and tiny rounding noise printed as 0."""
    return "0" if abs(x) < 1e-15 else repr(float(x))


def _origin(t: np.ndarray | None = None, xyz=None, rpy=None) -> str:
    if t is not None:
        xyz = t[:3, 3]
        rpy = rpy_from_matrix(t[:3, :3])
    return (f'<origin xyz="{" ".join(_f(v) for v in xyz)}" '
            f'rpy="{" ".join(_f(v) for v in rpy)}"/>')


def _segment_geometry(a: float, d: float, radius: float, material: str) -> list[str]:
    """Cylinder from the link origin to (a, 0, d), plus a box for the servo at the joint."""
    out = [
        "    <visual>",
        f'      <origin xyz="0 0 0" rpy="0 0 0"/>',
        f'      <geometry><box size="{_f(2 * radius)} {_f(2 * radius)} {_f(2 * radius)}"/></geometry>',
        f'      <material name="{material}"/>',
        "    </visual>",
    ]
    length = math.hypot(a, d)
    if length > 1e-9:
        gamma = math.atan2(a, d)  # rotate z onto the segment direction
        seg = (f'<origin xyz="{_f(a / 2)} 0 {_f(d / 2)}" rpy="0 {_f(gamma)} 0"/>'
               f'<geometry><cylinder radius="{_f(radius * 0.6)}" length="{_f(length)}"/></geometry>')
        out.append(f"    <visual>{seg}<material name=\"{material}\"/></visual>")
    return out


def _capsule_collisions(desc: RobotDescription, frame: str) -> list[str]:
    """<collision> elements of the capsules on ``frame``: a cylinder plus a sphere at each
    end of its segment (URDF has no capsule primitive), named ``<capsule>_cylinder``,
    ``<capsule>_end0`` and ``<capsule>_end1``."""
    out = []
    for cap in desc.capsules:
        if cap.frame != frame:
            continue
        a, b = cap.endpoints()
        out.append(f'    <collision name="{cap.name}_cylinder">'
                   f"{_origin(cap.placement())}"
                   f'<geometry><cylinder radius="{_f(cap.radius)}" length="{_f(cap.length)}"/>'
                   "</geometry></collision>")
        for k, end in enumerate((a, b)):
            out.append(f'    <collision name="{cap.name}_end{k}">'
                       f"{_origin(xyz=end, rpy=(0.0, 0.0, 0.0))}"
                       f'<geometry><sphere radius="{_f(cap.radius)}"/></geometry></collision>')
    return out


def _inertial(mass: float, com, inertia, a: float, d: float) -> list[str]:
    beta = math.atan2(-d, a) if math.hypot(a, d) > 1e-9 else 0.0  # x onto the segment
    ixx, iyy, izz, ixy, ixz, iyz = inertia
    return [
        "    <inertial>",
        f"      {_origin(xyz=com, rpy=(0.0, beta, 0.0))}",
        f'      <mass value="{_f(mass)}"/>',
        f'      <inertia ixx="{_f(ixx)}" ixy="{_f(ixy)}" ixz="{_f(ixz)}" iyy="{_f(iyy)}" '
        f'iyz="{_f(iyz)}" izz="{_f(izz)}"/>',
        "    </inertial>",
    ]


def generate_urdf(desc: RobotDescription) -> str:
    """The URDF text of ``desc`` (its variant decides whether the rail is included)."""
    src = Path(desc.source).name if desc.source else "the robot description"
    lines = [
        '<?xml version="1.0"?>',
        f"<!-- GENERATED from {src} by hyperarm_description.urdf (variant {desc.variant}).",
        "     Do not edit: edit the YAML and run `generate_urdf`. -->",
        f'<robot name={quoteattr(desc.name + ("_rail" if desc.rail else ""))}>',
        '  <material name="dxl_black"><color rgba="0.1 0.1 0.1 1"/></material>',
        '  <material name="bracket"><color rgba="0.75 0.75 0.78 1"/></material>',
        '  <material name="rail"><color rgba="0.3 0.4 0.6 1"/></material>',
    ]
    root = desc.root_frame
    if desc.rail:
        r = desc.rail
        lines += [
            '  <link name="world"/>',
            f'  <link name="rail_carriage">',
            "    <inertial><origin xyz=\"0 0 0\" rpy=\"0 0 0\"/>"
            f'<mass value="{_f(r.carriage_mass)}"/>'
            '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>',
            '    <visual><origin xyz="0 0 0.02" rpy="0 0 0"/><geometry><box size="0.2 0.2 0.04"/>'
            '</geometry><material name="rail"/></visual>',
            '    <collision><origin xyz="0 0 0.02" rpy="0 0 0"/><geometry><box size="0.2 0.2 0.04"/>'
            "</geometry></collision>",
            "  </link>",
            f'  <joint name="{r.name}" type="prismatic">',
            '    <parent link="world"/>',
            '    <child link="rail_carriage"/>',
            '    <origin xyz="0 0 0" rpy="0 0 0"/>',
            f'    <axis xyz="{" ".join(_f(v) for v in r.axis)}"/>',
            f'    <limit lower="{_f(r.lower)}" upper="{_f(r.upper)}" effort="1000" '
            f'velocity="{_f(r.velocity)}"/>',
            "  </joint>",
            '  <joint name="rail_mount" type="fixed">',
            '    <parent link="rail_carriage"/>',
            f'    <child link="{desc.base_frame}"/>',
            f"    {_origin(xyz=r.mount_xyz, rpy=r.mount_rpy)}",
            "  </joint>",
        ]
    lines += [
        f'  <link name="{desc.base_frame}">',
        '    <visual><origin xyz="0 0 -0.02" rpy="0 0 0"/><geometry><cylinder radius="0.05" '
        'length="0.04"/></geometry><material name="bracket"/></visual>',
        *_capsule_collisions(desc, desc.base_frame),
        "  </link>",
    ]
    parent = desc.base_frame
    prev_fixed = np.eye(4)
    for i, j in enumerate(desc.joints, start=1):
        child = f"link{i}"
        t = prev_fixed @ _rz(j.dh.theta)
        lines += [f'  <link name="{child}">']
        lines += _inertial(j.link.mass, j.link.com, j.link.inertia, j.dh.a, j.dh.d)
        lines += _segment_geometry(j.dh.a, j.dh.d, j.link.radius,
                                   "dxl_black" if i % 2 else "bracket")
        lines += _capsule_collisions(desc, child)
        lines += ["  </link>",
                  f'  <joint name="{j.name}" type="revolute">',
                  f'    <parent link="{parent}"/>',
                  f'    <child link="{child}"/>',
                  f"    {_origin(t)}",
                  '    <axis xyz="0 0 1"/>',
                  f'    <limit lower="{_f(j.lower)}" upper="{_f(j.upper)}" effort="{_f(j.effort)}" '
                  f'velocity="{_f(j.velocity)}"/>',
                  "  </joint>"]
        parent = child
        prev_fixed = _fixed_part(j.dh)
    g = desc.gripper
    lines += [
        f'  <link name="{desc.tool_frame}">',
        *_capsule_collisions(desc, desc.tool_frame),
        "  </link>",
        f'  <joint name="{desc.tool_frame}_joint" type="fixed">',
        f'    <parent link="{parent}"/>',
        f'    <child link="{desc.tool_frame}"/>',
        f"    {_origin(prev_fixed)}",
        "  </joint>",
        # The gripper sits just behind tool0 (tool0's -y axis points along the hand).
        '  <link name="gripper_finger">',
        '    <inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="0.02"/>'
        '<inertia ixx="1e-6" ixy="0" ixz="0" iyy="1e-6" iyz="0" izz="1e-6"/></inertial>',
        '    <visual><origin xyz="0 -0.02 0" rpy="0 0 0"/><geometry><box size="0.01 0.04 0.02"/>'
        '</geometry><material name="bracket"/></visual>',
        "  </link>",
        f'  <joint name="{g.name}" type="revolute">',
        f'    <parent link="{desc.tool_frame}"/>',
        '    <child link="gripper_finger"/>',
        '    <origin xyz="0 0.04 0" rpy="0 0 0"/>',
        '    <axis xyz="1 0 0"/>',
        f'    <limit lower="{_f(g.lower)}" upper="{_f(g.upper)}" effort="{_f(g.effort)}" '
        f'velocity="{_f(g.velocity)}"/>',
        "  </joint>",
        f'  <link name="{desc.camera.frame}"/>',
        f'  <joint name="{desc.camera.frame}_joint" type="fixed">',
        f'    <parent link="{root}"/>',
        f'    <child link="{desc.camera.frame}"/>',
        f"    {_origin(xyz=desc.camera.xyz, rpy=desc.camera.rpy)}",
        "  </joint>",
        "</robot>",
    ]
    return "\n".join(lines) + "\n"


def urdf_path(variant: str = "arm") -> Path:
    """Path of the committed, generated URDF of ``variant`` inside the package."""
    from importlib import resources
    return Path(str(resources.files("hyperarm_description") / "urdf" / f"hyperarm_{variant}.urdf"))


def main(argv: list[str] | None = None) -> int:
    """Console script: write (or --check) the URDF of every variant."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--description", help="robot YAML (default: the packaged one)")
    ap.add_argument("--out-dir", help="where to write (default: the package's urdf/ folder)")
    ap.add_argument("--check", action="store_true", help="fail if a committed URDF is stale")
    args = ap.parse_args(argv)
    stale = []
    for variant in VARIANTS:
        text = generate_urdf(load_description(args.description, variant))
        target = (Path(args.out_dir) / f"hyperarm_{variant}.urdf") if args.out_dir \
            else urdf_path(variant)
        current = target.read_text(encoding="utf-8") if target.exists() else None
        if args.check:
            if current != text:
                stale.append(str(target))
        elif current != text:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(text, encoding="utf-8")
            print(f"wrote {target}")
    if stale:
        print("stale URDF (run generate_urdf): " + ", ".join(stale), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
