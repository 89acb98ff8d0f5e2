"""Reference tool paths, shared by the IK benchmark and the tasks (no ROS).

Danko & Oh (ICUAS 2013, Table II) track a figure "8" of 1,000 waypoints and count those
reached within 1 mm. Ours is a lemniscate of Gerono in the root frame's y-z plane in front
of the arm, held at the ready pose's tool orientation (tool0 at q = 0):

    p(s) = centre + (0, half_width sin s, half_height sin 2s),  s = 2 pi k / n, k = 0..n-1

``ik_benchmark`` solves it (set ``figure8``; ``figure8_wide`` is :data:`FIGURE8_WIDE`) and
the shipped task ``figure8`` (hyperarm_tasks, step ``track_path``) tracks it on the arm.
Units: m, rad.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Figure8", "FIGURE8", "FIGURE8_WIDE", "FIGURE8_WAYPOINTS", "PATHS",
           "hold_orientation"]

FIGURE8_WAYPOINTS = 1000   #: Table II's count


@dataclass(frozen=True)
class Figure8:
    """A figure "8" (lemniscate of Gerono) in the y-z plane: ``center`` (m, root frame),
    ``half_width`` (m, along y) and ``half_height`` (m, along z)."""

    center: tuple[float, float, float] = (0.40, 0.0, 0.20)
    half_width: float = 0.12
    half_height: float = 0.06

    def __post_init__(self) -> None:
        c = tuple(float(v) for v in self.center)
        if len(c) != 3 or not all(math.isfinite(v) for v in c):
            raise ValueError(f"figure-8 center must be 3 finite numbers (m), got {self.center!r}")
        object.__setattr__(self, "center", c)
        for name in ("half_width", "half_height"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"figure-8 {name} must be > 0 m, got {v!r}")

    def points(self, n: int = FIGURE8_WAYPOINTS) -> np.ndarray:
        """(n, 3) waypoint positions (m), evenly spaced in the curve's parameter, starting at
        the centre (the crossing) and going +y first."""
        if n < 2:
            raise ValueError(f"a figure-8 needs at least 2 waypoints, got {n}")
        s = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
        out = np.empty((n, 3))
        out[:, 0] = self.center[0]
        out[:, 1] = self.center[1] + self.half_width * np.sin(s)
        out[:, 2] = self.center[2] + self.half_height * np.sin(2.0 * s)
        return out


#: the benchmark's figure8 (Table II's set) and the task's
FIGURE8 = Figure8()
#: the second 1,000-waypoint figure-8: larger and higher, so that the paper's solvers meet
#: the joint limits along it
FIGURE8_WIDE = Figure8(center=(0.30, 0.0, 0.35), half_width=0.20, half_height=0.10)
#: named paths (a task's ``track_path`` ``path:``)
PATHS: dict[str, Figure8] = {"figure8": FIGURE8, "figure8_wide": FIGURE8_WIDE}


def hold_orientation(kin) -> np.ndarray:
    """The orientation a figure-8 is held at: tool0's at the ready pose (q = 0), 3x3."""
    return kin.forward(np.zeros(kin.nq))[:3, :3].copy()
