"""Console script `show_description`: print the robot description and its ready-pose FK."""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from .model import VARIANTS, DescriptionError, load_description


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Print the hyperarm description and tool pose.")
    ap.add_argument("--variant", choices=VARIANTS, default="arm")
    ap.add_argument("--description", help="robot YAML (default: the packaged one)")
    ap.add_argument("--q", type=float, nargs="*", help="arm joint angles in rad (default: 0)")
    args = ap.parse_args(argv)
    try:
        desc = load_description(args.description, args.variant)
    except DescriptionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{desc.name} ({desc.variant}) from {desc.source}")
    print(f"{'joint':8} {'id':>3} {'model':11} {'theta':>8} {'d (m)':>8} {'a (m)':>8} "
          f"{'alpha':>8} {'limits (deg)':>16}")
    for j in desc.joints:
        print(f"{j.name:8} {j.servo.id:3d} {j.servo.model:11} {j.dh.theta:8.4f} {j.dh.d:8.4f} "
              f"{j.dh.a:8.4f} {j.dh.alpha:8.4f} {math.degrees(j.lower):7.1f}..{math.degrees(j.upper):<7.1f}")
    g = desc.gripper
    print(f"{g.name:8} {g.servo.id:3d} {g.servo.model:11} range {math.degrees(g.lower):.0f}.."
          f"{math.degrees(g.upper):.0f} deg, grip {g.grip_effort} N·m")
    if desc.rail:
        print(f"{desc.rail.name:8} PMAC motor {desc.rail.pmac_motor}, {desc.rail.lower}..{desc.rail.upper} m")
    q = np.zeros(9) if not args.q else np.asarray(args.q, dtype=float)
    if q.shape != (9,):
        print("error: --q takes 9 angles", file=sys.stderr)
        return 2
    t = desc.dh_forward(q)
    np.set_printoptions(precision=4, suppress=True)
    print(f"tool0 in {desc.base_frame} at q = {q.tolist()}:")
    t = np.round(t, 4) + 0.0  # + 0.0 turns the -0. of a tiny negative into 0.
    print(f"  position (m): {t[:3, 3]}")
    print(f"  rotation:\n{t[:3, :3]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
