"""Benchmark: MarkerDetector.detect time per frame on rendered 640x480 images (the
description's camera) of the work cell's markers, and their pose errors.

    python -m hyperarm_perception.benchmarks.detector [--frames 200] [--seed 0]
            [--width 640 --height 480] [--save frame.png]

Prints the median and 95th percentile of the time per frame (ms; rendering excluded) and
the block's lateral / depth (% of distance) / orientation errors; ``--save`` writes the
first frame with the detections drawn (marker outlines and ids, each object's axes at its
pose: x red, y green, z blue, 3 cm). docs/perception.md keeps the figures."""
from __future__ import annotations

import argparse
import math
import time

import cv2
import numpy as np

from hyperarm_perception.markers import (CameraModel, FrameResult, MarkerDetector,
                                         load_marker_map)
from hyperarm_perception.synthetic import MarkerPlacement, look_at_pose, render


def draw(image: np.ndarray, result: FrameResult, cam: CameraModel,
         detector: MarkerDetector) -> np.ndarray:
    """A colour copy of ``image`` with the markers' outlines and ids and each detection's
    axes (3 cm) drawn."""
    out = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    corners, ids, _ = detector._aruco.detectMarkers(image)
    if ids is not None:
        cv2.aruco.drawDetectedMarkers(out, corners, ids)
    for d in result.detections:
        T = d.pose_optical
        cv2.drawFrameAxes(out, cam.K, cam.D, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], 0.03, 2)
        u = cam.K @ T[:3, 3]
        cv2.putText(out, d.object, (int(u[0] / u[2]) + 8, int(u[1] / u[2]) - 8),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 255, 255), 1, cv2.LINE_AA)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--save", help="write the first frame, detections drawn, as a PNG")
    args = parser.parse_args(argv)
    mm = load_marker_map()
    cam = CameraModel.from_fovy(args.width, args.height, math.radians(45.0))
    det = MarkerDetector(mm, cam)
    rng = np.random.default_rng(args.seed)
    times, lateral, depth, angle = [], [], [], []
    for _ in range(args.frames):
        # block and the two peg tiles at the work cell's depths (0.5-0.8 m below the camera)
        d = rng.uniform(0.5, 0.8)
        block = look_at_pose([rng.uniform(-0.1, 0.1), rng.uniform(-0.08, 0.08), d],
                             rng.uniform(0, 0.5), rng.uniform(0, 6.3), rng.uniform(-3, 3))
        pegs = [look_at_pose([x, 0.12, 0.8], 0.1, 0.0, 0.0) for x in (-0.15, 0.15)]
        image = render(cam, mm.dictionary, [MarkerPlacement(i, mm.markers[i].size, pose)
                                            for i, pose in ((0, block), (1, pegs[0]),
                                                            (2, pegs[1]))], rng=rng)
        t0 = time.perf_counter()
        result = det.detect(image)
        times.append(time.perf_counter() - t0)
        if args.save and len(times) == 1:
            cv2.imwrite(args.save, draw(image, result, cam, det))
        found = {x.object: x for x in result.detections}
        if "block" in found:
            truth = block @ np.linalg.inv(mm.markers[0].offset)
            e = found["block"].pose_optical[:3, 3] - truth[:3, 3]
            sight = truth[:3, 3] / np.linalg.norm(truth[:3, 3])
            depth.append(abs(e @ sight) / np.linalg.norm(truth[:3, 3]))
            lateral.append(np.linalg.norm(e - (e @ sight) * sight))
            R = found["block"].pose_optical[:3, :3] @ truth[:3, :3].T
            angle.append(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2))))
    t = np.array(times) * 1000
    print(f"{args.width}x{args.height}, {args.frames} frames: detect median {np.median(t):.2f} ms,"
          f" p95 {np.percentile(t, 95):.2f} ms")
    print(f"block seen in {len(depth)}/{args.frames}: lateral median "
          f"{np.median(lateral) * 1000:.2f} mm (max {np.max(lateral) * 1000:.2f}), depth median "
          f"{np.median(depth) * 100:.2f} % (max {np.max(depth) * 100:.2f}), orientation median "
          f"{math.degrees(np.median(angle)):.2f} deg (max {math.degrees(np.max(angle)):.2f})")
    print("rejections:", {k: v for k, v in det.counts.items() if v})


if __name__ == "__main__":
    main()
