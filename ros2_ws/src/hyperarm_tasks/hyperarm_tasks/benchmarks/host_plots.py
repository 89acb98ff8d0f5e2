"""host_plots: PNG figures of host-motion compensation (docs/host.md) from the mock's simulation.

    host_plots DIR

writes into DIR (created if missing; the docs' copies are in docs/benchmarks/img):

- ``host_tool_error.png``: tool0's position and orientation error over time, compensated
  by :class:`~hyperarm_control.host.CompensationLoop` on the mock's simulated servos: the rail
  sweep (+-0.2 m at 0.2 m/s, judged by FK of the joint states, rail included) and the
  ``uav_sway`` host motion (judged by FK on the host pose and by the mock's truth), with the
  issue's bounds;
- ``host_reaction.png``: the base moment (norm) over the figure-8 task's traversal, as
  shipped and with ``redundancy: min_reaction``, and the reaction wrench on base_link
  during the uav_sway;
- ``host_passive_mount.png``: ``uav_sway_passive`` for 20 s, the tool's error and the
  mount's deflection, on the shipped mount (an 8 kg airframe) and on a 0.5 kg plate (the
  same modes and damping ratio), which the compensation drives unstable.

Runs in about 20 s (no ROS; the figure-8 task runs twice in simulated time).
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hyperarm_control.benchmark.host_sim import rail_sweep, sway

from .host_figure8 import figure8_task

if TYPE_CHECKING:
    from hyperarm_driver.mock.host_motion import HostMotionSpec


def write_plots(out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    rail, uav = rail_sweep(), sway("uav_sway")
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    ax[0].plot(rail["t"], rail["position_error"] * 1e3, label="rail sweep (FK, rail included)")
    ax[0].plot(uav["t"], uav["position_error"] * 1e3, label="uav_sway (FK on host_pose)")
    ax[0].plot(uav["t"], uav["truth_position_error"] * 1e3, "--",
               label="uav_sway (mock truth)")
    ax[0].axhline(8.0, color="r", lw=0.8, label="max bound 8 mm (RMS bound 3 mm)")
    ax[0].set_ylabel("tool position error (mm)")
    ax[0].legend(fontsize=8)
    ax[1].plot(rail["t"], np.degrees(rail["orientation_error"]), label="rail sweep")
    ax[1].plot(uav["t"], np.degrees(uav["orientation_error"]), label="uav_sway (FK)")
    ax[1].plot(uav["t"], np.degrees(uav["truth_orientation_error"]), "--",
               label="uav_sway (truth)")
    ax[1].axhline(2.0, color="r", lw=0.8, label="bound 2 deg")
    ax[1].set_ylabel("orientation error (deg)")
    ax[1].set_xlabel("time since compensation enabled (s)")
    ax[1].legend(fontsize=8)
    err = _save(plt, fig, ax, out / "host_tool_error.png",
                "host_compensation on the mock's simulated servos (1 step of transport)")

    base, low = figure8_task(None), figure8_task("min_reaction")
    fig, ax = plt.subplots(2, 1, figsize=(9, 6))
    for run, label in ((base, "default"), (low, "redundancy: min_reaction")):
        ax[0].plot(run["t"], run["moment"], label=f"{label} (peak {run['moment'].max():.2f} "
                   f"N·m, {100 * run['metrics']['track_reached_fraction']:.1f} % of the "
                   "waypoints within 1 mm)")
    ax[0].set_ylabel("|base moment| (N·m)")
    ax[0].set_xlabel("time along the figure-8 (s)")
    ax[0].legend(fontsize=8)
    w = uav["wrench"]
    for i, name in enumerate(("Mx", "My", "Mz")):
        ax[1].plot(uav["t"], w[:, 3 + i], label=f"{name} (N·m)")
    ax[1].plot(uav["t"], w[:, 2] / 10.0, label="Fz / 10 (N)")
    ax[1].set_xlabel("time since compensation enabled, uav_sway (s)")
    ax[1].set_ylabel("reaction on base_link")
    ax[1].legend(fontsize=8, ncol=4)
    rea = _save(plt, fig, ax, out / "host_reaction.png",
                "What the arm does to its mount (base_reaction, from the measured joints)")
    passive = sway("uav_sway_passive", duration=20.0)
    light = sway(_light_mount(), duration=20.0)
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for run, label, color in ((passive, "shipped mount (8 kg airframe)", "C0"),
                              (light, "0.5 kg plate, same modes and damping ratio", "C1")):
        ax[0].plot(run["t"], run["position_error"] * 1e3, color=color,
                   label=f"{label}: tool (FK)")
        ax[1].plot(run["t"], np.linalg.norm(run["mount"][:, :3], axis=1) * 1e3, color=color,
                   label=f"{label}: translation (mm)")
        ax[1].plot(run["t"], np.linalg.norm(run["mount"][:, 3:], axis=1) * 1e3, "--",
                   color=color, alpha=0.7, label=f"{label}: rotation (mrad)")
    ax[0].axhline(8.0, color="r", lw=0.8, label="max bound 8 mm (RMS bound 3 mm)")
    ax[0].set_ylabel("tool position error (mm)")
    ax[0].set_yscale("log")
    ax[1].set_ylabel("mount deflection")
    ax[1].set_xlabel("time since compensation enabled (s)")
    for a in ax:
        a.legend(fontsize=8)
    mnt = _save(plt, fig, ax, out / "host_passive_mount.png",
                "uav_sway on a passive mount: the arm's reactions move its base")
    for name, run in (("rail sweep", rail), ("uav_sway", uav),
                      ("uav_sway_passive, 20 s", passive), ("0.5 kg plate, 20 s", light)):
        p = run["position_error"]
        print(f"{name}: RMS {np.sqrt(np.mean(p ** 2)) * 1e3:.2f} mm, max {p.max() * 1e3:.2f} "
              f"mm, {math.degrees(run['orientation_error'].max()):.2f} deg")
    print(f"figure-8 peak base moment: {base['moment'].max():.3f} N·m default, "
          f"{low['moment'].max():.3f} N·m min_reaction "
          f"({100 * (1 - low['moment'].max() / base['moment'].max()):.1f} % lower)")
    return [err, rea, mnt]


def _save(plt, fig, ax, path: Path, title: str) -> Path:
    """Grid every axis, title, lay out and write ``fig`` to ``path``; close it."""
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _light_mount() -> HostMotionSpec:
    """``uav_sway_passive`` with the mount's body a 0.5 kg plate (0.002 kg·m²), its springs
    and dampers scaled to the same ~4 / 8 Hz modes and damping ratio ~0.1 with the arm."""
    import dataclasses

    from hyperarm_driver.mock.host_motion import MountSpec, load_host_motion

    spec = load_host_motion("uav_sway_passive")
    return dataclasses.replace(spec, name="uav_sway_light_mount", mount=MountSpec(
        mass=0.5, inertia=(0.002, 0.002, 0.002),
        stiffness=(1200.0, 1200.0, 1200.0, 150.0, 150.0, 150.0),
        damping=(9.5, 9.5, 9.5, 0.6, 0.6, 0.6)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="host_plots", description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", type=Path, metavar="DIR",
                    help="write the PNG figures into DIR (e.g. docs/benchmarks/img)")
    a = ap.parse_args(argv)
    for path in write_plots(a.dir):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
