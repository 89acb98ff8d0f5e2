"""Benchmark: the mock's rendered camera (MuJoCo, EGL) and MarkerDetector on its pictures.

    MUJOCO_GL=egl python -m hyperarm_perception.benchmarks.rendered [--frames 40]
            [--seed 0] [--sizes 640x480 1280x960] [--refinements edges subpix]
            [--priors upright none] [--save frame.png]

Per picture size: the render time per frame (ms; blur and noise included), the detector's
time per frame, and each object's errors against the poses it was drawn at, in camera_link:
position (norm), across and along the line of sight, and orientation. Each frame moves the
pegs by up to 4 cm and lays the block on the table at a random place and yaw, clear of the
pegs and their tiles (:func:`_scene`); the arm is turned away (out of view). Also how often the block's marker is found while
the block is threaded on its peg (its marker on a tab beside the peg). ``--save`` writes
the first frame of the first size with the detections drawn. Each of ``--refinements``
(the marker map's ``corner_refinement``), with and without up (``--priors``: the upright
prior and snap),
detects on the same pictures, side by side. docs/perception.md keeps the
figures."""
from __future__ import annotations

import argparse
import math
import os
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

from hyperarm_description.model import load_description, read_yaml  # noqa: E402
from hyperarm_description.world import MOCK_WORLD_KEYS, parse_world  # noqa: E402
from hyperarm_perception.benchmarks.detector import draw  # noqa: E402
from hyperarm_perception.markers import (MarkerDetector, load_marker_map,  # noqa: E402
                                         rotation_angle, up_in_camera_link)
from hyperarm_perception.rendered_camera import (RenderOptions, RenderedCamera,  # noqa: E402
                                                 cell_poses)

CELL = Path(__file__).resolve().parents[3] / "hyperarm_driver" / "config" / "workcell.yaml"
AWAY = {"joint1": math.pi, "joint2": -1.5}   # rad: the arm turned back, out of view


def _points(mm, name: str, pose: np.ndarray) -> list[np.ndarray]:
    """The object's origin and its markers' centres, root-frame x-y (m)."""
    pts = [pose[:2, 3]]
    pts += [(pose @ m.offset)[:2, 3] for m in mm.markers.values() if m.object == name]
    return pts


def _scene(world, rng, mm) -> dict[str, np.ndarray]:
    """The pegs moved by up to 4 cm, the block on the table at a random place and yaw with
    its origin and its markers at least 7 cm from each peg's and its tile's centre (apart:
    a marker partly covered by another object is not what this measures)."""
    poses = cell_poses(world)
    for name in ("source_peg", "destination_peg"):
        poses[name][:2, 3] += rng.uniform(-0.04, 0.04, 2)
    fixed = [p for name in ("source_peg", "destination_peg")
             for p in _points(mm, name, poses[name])]
    while True:
        yaw = rng.uniform(-math.pi, math.pi)
        block = np.eye(4)
        block[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        block[:3, 3] = [*rng.uniform([0.2, -0.2], [0.45, 0.2]),
                        world.table.height + 0.5 * world.block.size[2]]
        if all(np.linalg.norm(a - b) > 0.07 for a in _points(mm, "block", block)
               for b in fixed):
            break
    poses["block"] = block
    return poses


def _row(name: str, errs: list[tuple[float, float, float, float]], tries: int) -> str:
    if not errs:
        return f"  {name:16s} found 0/{tries}"
    e = np.array(errs)
    return (f"  {name:16s} found {len(e)}/{tries}  position median {np.median(e[:, 0]):5.1f} "
            f"max {e[:, 0].max():5.1f} mm | across max {e[:, 1].max():4.1f} mm | along max "
            f"{e[:, 2].max():5.1f} mm | angle median {np.median(e[:, 3]):4.2f} max "
            f"{e[:, 3].max():4.2f} deg")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sizes", nargs="+", default=["640x480", "1280x960"])
    parser.add_argument("--refinements", nargs="+", default=["edges", "subpix"],
                        choices=["edges", "subpix"])
    parser.add_argument("--priors", nargs="+", default=["upright", "none"],
                        choices=["upright", "none"],
                        help="upright: the map's upright objects get the camera's up "
                             "direction (the prior between IPPE's solutions and the upright "
                             "snap: marker_detector's default); none: neither")
    parser.add_argument("--save", help="write the first frame, detections drawn, as a PNG")
    args = parser.parse_args(argv)
    desc = load_description(None, "arm")
    world = parse_world(read_yaml(CELL, "work cell")["world"], extra_keys=MOCK_WORLD_KEYS)
    mm = load_marker_map()
    saved = False
    for size in args.sizes:
        width, height = (int(v) for v in size.split("x"))
        rng = np.random.default_rng(args.seed)
        with RenderedCamera(desc, world, mm, RenderOptions(width=width, height=height,
                                                           seed=args.seed)) as cam:
            up = up_in_camera_link(cam.camera_pose)
            detectors = {f"{r}, prior {prior}": MarkerDetector(
                replace(mm, config=replace(mm.config, corner_refinement=r)), cam.camera,
                up=up if prior == "upright" else None)
                for r in args.refinements for prior in args.priors}
            link = np.linalg.inv(cam.camera_pose)
            cam.render(AWAY, cell_poses(world))          # the first render sets OpenGL up
            render_ms = []
            detect_ms: dict[str, list] = {r: [] for r in detectors}
            errs = {r: {"block": [], "source_peg": [], "destination_peg": []}
                    for r in detectors}
            for _ in range(args.frames):
                poses = _scene(world, rng, mm)
                t0 = time.perf_counter()
                image = cam.render(AWAY, poses)
                t1 = time.perf_counter()
                gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
                render_ms.append(1e3 * (t1 - t0))
                for refinement, detector in detectors.items():
                    t1 = time.perf_counter()
                    result = detector.detect(gray)
                    detect_ms[refinement].append(1e3 * (time.perf_counter() - t1))
                    if args.save and not saved:
                        cv2.imwrite(args.save, draw(gray, result, cam.camera, detector))
                        saved = True
                    for d in result.detections:
                        truth = link @ poses[d.object]
                        err = d.pose[:3, 3] - truth[:3, 3]
                        sight = truth[:3, 3] / np.linalg.norm(truth[:3, 3])
                        along = float(err @ sight)
                        errs[refinement][d.object].append((
                            1e3 * np.linalg.norm(err),
                            1e3 * np.linalg.norm(err - along * sight), 1e3 * abs(along),
                            math.degrees(rotation_angle(d.pose[:3, :3].T @ truth[:3, :3]))))
            threaded_pictures = [cv2.cvtColor(cam.render(AWAY, cell_poses(world)),
                                              cv2.COLOR_RGB2GRAY) for _ in range(5)]
        print(f"{width}x{height}: render median {np.median(render_ms):.1f} ms (p95 "
              f"{np.percentile(render_ms, 95):.1f}), {args.frames} frames")
        for refinement, detector in detectors.items():
            threaded = sum("block" in {d.object for d in detector.detect(g).detections}
                           for g in threaded_pictures)
            print(f" corner_refinement {refinement}: detect median "
                  f"{np.median(detect_ms[refinement]):.1f} ms (p95 "
                  f"{np.percentile(detect_ms[refinement], 95):.1f}), edge fallbacks "
                  f"{detector.counts['edge_fallbacks']}, upright choices "
                  f"{detector.counts['upright_choices']}")
            for name, rows in errs[refinement].items():
                print(_row(name, rows, args.frames))
            print(f"  block threaded on its peg: found {threaded}/5")


if __name__ == "__main__":
    main()
