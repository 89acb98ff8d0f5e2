"""plot_task: PNG figures of a task recording (MCAP from task_recorder / run_task.sh --record).

    plot_task run.mcap [--out DIR]

Writes DIR/tool_path.png (tool0 over the pegs, top and side views, like Danko & Oh's
Fig. 2), DIR/joints.png (measured joint trajectories, commanded dashed),
DIR/insertion.png (force and depth during the insertion) and, when the run tracked a path
(``track_path``, e.g. the figure-8), DIR/tracking.png (commanded and measured path, and the
measured path's closest approach to every commanded point). No rclpy: the recording is
decoded with mcap-ros2-support and tool0 is computed from joint_states by FK.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from hyperarm_description import load_description
from hyperarm_ik.kinematics import Kinematics

from .perception import DetectionBuffer, camera_pose
from .recording import read_recording
from .tracking import closest_approach

__all__ = ["load_series", "plot_recording", "main"]


def _stamp(header) -> float:
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


def load_series(path: str | Path) -> dict:
    """Time series of a recording (times in s from the first message)."""
    states, commands, feedback, wrench, dets = [], [], [], [], []
    for topic, t, msg in read_recording(path):
        # the task's feedback: task_feedback (TaskFeedback), or in older recordings the
        # action's feedback topic (the fields under .feedback)
        name = ("feedback" if "_action" in topic or topic.endswith("/task_feedback")
                else topic.rsplit("/", 1)[-1])
        if name == "joint_states":
            states.append((t, dict(zip(msg.name, msg.position))))
        elif name == "joint_command":
            commands.append((t, dict(zip(msg.name, msg.position))))
        elif name == "feedback":
            fb = getattr(msg, "feedback", msg)
            feedback.append((t, fb.stage, fb.phase, fb.depth, fb.force,
                             (fb.waypoint.point.x, fb.waypoint.point.y, fb.waypoint.point.z)))
        elif name == "ee_wrench":
            wrench.append((t, msg.wrench.force.z))
        elif name == "detections":
            dets.append((_stamp(msg.header), list(msg.names), list(msg.poses)))
    times = [s[0] for s in states + commands + feedback]
    t0 = min(times) if times else 0.0
    return {"t0": t0, "states": states, "commands": commands, "feedback": feedback,
            "wrench": wrench, "detections": dets}


def _objects(series: dict, desc) -> dict[str, np.ndarray]:
    """Mean detected position (root frame) of each object over the recording."""
    buf = DetectionBuffer(camera_pose(desc), history=100000)
    for stamp, names, poses in series["detections"]:
        mats = []
        for p in poses:
            m = np.eye(4)
            m[:3, 3] = (p.position.x, p.position.y, p.position.z)
            mats.append(m)
        buf.add(stamp, names, mats)
    out = {}
    for name in ("source_peg", "destination_peg"):
        s = buf._seen.get(name)
        if s:
            out[name] = np.mean([x.pose[:3, 3] for x in s], axis=0)
    return out


def plot_recording(path: str | Path, out_dir: str | Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = load_series(path)
    if not series["states"]:
        raise SystemExit(f"plot_task: {path} has no joint_states")
    names = list(series["states"][-1][1])
    variant = "rail_arm" if "rail" in names else "arm"
    desc = load_description(variant=variant)
    kin = Kinematics(desc)
    t0 = series["t0"]
    ts, xyz, q = [], [], []
    for t, pos in series["states"]:
        if all(n in pos for n in kin.joint_names):
            qq = np.array([pos[n] for n in kin.joint_names])
            ts.append(t - t0)
            q.append(qq)
            xyz.append(kin.forward(qq)[:3, 3])
    ts, xyz, q = np.array(ts), np.array(xyz), np.array(q)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []

    # 1. tool path over the pegs (top x-y, side y-z; on rail_arm x-z, one above the other)
    objs = _objects(series, desc)
    h = 0 if variant == "rail_arm" else 1      # side view along the rail: x-z, else y-z
    fig, (top, side) = plt.subplots(*((2, 1) if h == 0 else (1, 2)),
                                    figsize=(11, 5.5) if h == 0 else (11, 4.8))
    top.plot(xyz[:, 0], xyz[:, 1], lw=1, label="tool0")
    side.plot(xyz[:, h], xyz[:, 2], lw=1, label="tool0")
    for name, p in objs.items():
        top.add_patch(plt.Circle((p[0], p[1]), 0.008, color="0.5", alpha=0.6))
        top.annotate(name, (p[0], p[1]), textcoords="offset points", xytext=(6, 6), fontsize=8)
        side.add_patch(plt.Rectangle((p[h] - 0.008, p[2] - 0.08), 0.016, 0.08, color="0.5",
                                     alpha=0.6))
        side.annotate(name, (p[h], p[2]), textcoords="offset points", xytext=(6, 6), fontsize=8)
    top.set(xlabel="x (m)", ylabel="y (m)", title="top view", aspect="equal")
    side.set(xlabel=f"{'xy'[h]} (m)", ylabel="z (m)", aspect="equal",
             title=f"side view (looking along {'yx'[h]})")
    for ax in (top, side):
        ax.grid(True, alpha=0.3)
    fig.suptitle(f"tool path ({Path(path).name})")
    fig.tight_layout()
    written.append(out_dir / "tool_path.png")
    fig.savefig(written[-1], dpi=110)
    plt.close(fig)

    # 2. joint trajectories
    fig, ax = plt.subplots(figsize=(11, 5))
    for i, n in enumerate(kin.joint_names):
        line, = ax.plot(ts, q[:, i], lw=1, label=n)
        cmd = [(t - t0, c[n]) for t, c in series["commands"] if n in c]
        if cmd:
            c = np.array(cmd)
            ax.plot(c[:, 0], c[:, 1], "--", lw=0.7, color=line.get_color())
    ax.set(xlabel="time (s)", ylabel="joint position (rad; rail m)",
           title="joint trajectories (measured; commanded dashed)")
    ax.grid(True, alpha=0.3)
    ax.legend(ncol=5, fontsize=8)
    fig.tight_layout()
    written.append(out_dir / "joints.png")
    fig.savefig(written[-1], dpi=110)
    plt.close(fig)

    # 3. insertion force and depth: one column per insertion (attempt)
    ins = [f for f in series["feedback"] if f[2] in ("descending", "dithering")]
    segments = _segments(ins)
    cols = max(1, len(segments))
    fig, axes = plt.subplots(2, cols, figsize=(5 * cols + 1, 6), squeeze=False)
    wr = np.array([(t - t0, fz) for t, fz in series["wrench"]]) if series["wrench"] else None
    for k, seg in enumerate(segments):
        ax1, ax2 = axes[0, k], axes[1, k]
        a = np.array([(f[0] - t0, f[3]) for f in seg])
        rel = a[:, 0] - a[0, 0]
        ax2.plot(rel, np.maximum(a[:, 1], 0.0) * 1000, label="depth down the peg")
        if wr is not None and len(wr):
            sel = (wr[:, 0] >= a[0, 0]) & (wr[:, 0] <= a[-1, 0])
            ax1.plot(wr[sel, 0] - a[0, 0], wr[sel, 1], label="ee_wrench fz (N)")
        else:
            # no force estimate (no force node): the press, measured minus commanded height
            wz = np.array([f[5][2] for f in seg])
            z_at = np.interp(a[:, 0], ts, xyz[:, 2])
            ax1.plot(rel, (z_at - wz) * 1000, label="press: measured - commanded z (mm)")
        sel = (ts >= a[0, 0]) & (ts <= a[-1, 0])
        ax1b = ax1.twinx()
        ax1b.plot(ts[sel] - a[0, 0], xyz[sel, 2], color="C2", lw=0.8)
        ax1b.set_ylabel("tool z (m)", color="C2")
        ax1.set_title(f"insertion {k + 1} ({seg[0][1]}, at {a[0, 0]:.1f} s)")
        ax1.set_ylabel("force z (N)" if wr is not None and len(wr) else "press (mm)")
        ax2.set(xlabel="time from the start of the insertion (s)", ylabel="depth (mm)")
        for ax in (ax1, ax2):
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=8, loc="upper left")
    if not segments:
        axes[0, 0].set_title("no insertion in this recording")
    fig.tight_layout()
    written.append(out_dir / "insertion.png")
    fig.savefig(written[-1], dpi=110)
    plt.close(fig)

    # 4. path tracking (track_path): one row per tracked path
    tracks = _segments([f for f in series["feedback"] if f[2] == "tracking"])
    if tracks:
        written.append(_plot_tracking(plt, tracks, ts + t0, xyz, out_dir / "tracking.png",
                                      Path(path).name))
    return written


def _segments(feedback: list, gap: float = 1.0) -> list[list]:
    """Feedback entries split where more than ``gap`` s pass between two."""
    out: list[list] = []
    for f in feedback:
        if not out or f[0] - out[-1][-1][0] > gap:
            out.append([])
        out[-1].append(f)
    return out


def _plot_tracking(plt, tracks: list[list], t_meas: np.ndarray, xyz: np.ndarray, out: Path,
                   name: str, reach: float = 1e-3, window: float = 1.0) -> Path:
    """Commanded (feedback waypoints) and measured (FK) path, y-z view, and the closest
    approach of the measured path to each commanded point, within ``window`` s of it."""
    fig, axes = plt.subplots(len(tracks), 2, figsize=(12, 4.6 * len(tracks)), squeeze=False)
    for row, seg in zip(axes, tracks):
        tc = np.array([f[0] for f in seg])
        cmd = np.array([f[5] for f in seg])
        sel = (t_meas >= tc[0] - window) & (t_meas <= tc[-1] + window)
        tm, meas = t_meas[sel], xyz[sel]
        lo = np.searchsorted(tm, tc - window, side="left")
        hi = np.maximum(np.searchsorted(tm, tc + window, side="right") - 1, lo)
        err, _ = closest_approach(cmd, meas, np.stack([lo, hi], axis=1))
        ok = int(np.count_nonzero(err <= reach))
        path_ax, err_ax = row
        path_ax.plot(cmd[:, 1], cmd[:, 2], "--", color="0.4", lw=1.2, label="commanded")
        path_ax.plot(meas[:, 1], meas[:, 2], lw=0.8, label="measured (FK of joint_states)")
        path_ax.set(xlabel="y (m)", ylabel="z (m)", aspect="equal",
                    title=f"tool path, x = {np.median(cmd[:, 0]):.3f} m (y-z view)")
        err_ax.plot(tc - tc[0], err * 1000, lw=0.8, label="closest approach")
        err_ax.axhline(reach * 1000, color="r", ls=":", lw=1, label=f"{reach * 1000:g} mm")
        err_ax.set(xlabel="time from the start of the tracking (s)",
                   ylabel="measured path to commanded point (mm)",
                   title=f"{ok}/{len(err)} commanded points within {reach * 1000:g} mm "
                         f"(max {err.max() * 1000:.3f} mm)")
        for ax in row:
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=8)
    fig.suptitle(f"path tracking ({name})")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="plot_task", description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", help="MCAP file of a task run")
    ap.add_argument("--out", default=None, help="output directory (default: next to the file)")
    args = ap.parse_args(argv)
    path = Path(args.recording)
    if not path.is_file():
        print(f"plot_task: {path}: no such file", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else path.with_suffix("")
    try:
        for p in plot_recording(path, out):
            print(p)
    except SystemExit as exc:
        print(exc, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
