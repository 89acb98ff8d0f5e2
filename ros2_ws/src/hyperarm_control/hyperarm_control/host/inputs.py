"""What is wrong with an input message of host_compensation, by kind (no ROS).

Each malformed-input kind has its own ``reason`` (the key of the node's log throttle and of
its diagnostics count), and the text names the bad field, so a NaN after a bad quaternion
after a wrong frame are three messages, not one throttled line. A message with one bad
value is rejected whole.

- :func:`pose_problem`: a PoseStamped-like pose (frame, position x y z, orientation
  x y z w): ``frame``, ``position_nan``, ``position_inf``, ``orientation_nan``,
  ``orientation_inf``, ``quaternion_norm`` (not unit within 1e-3).
- :func:`joint_state_problem`: a JointState-like message (names and the position,
  velocity and effort arrays): ``length`` (an array neither empty nor one per name),
  ``duplicate`` (a name twice), ``<array>_nan`` / ``<array>_inf`` for a needed joint (the
  position of any joint used, the velocity of the arm's joints).
"""
from __future__ import annotations

import math
from typing import Iterable, Sequence

__all__ = ["InputProblem", "pose_problem", "joint_state_problem", "POSE_REASONS",
           "JOINT_STATE_REASONS"]

POSE_REASONS = ("frame", "position_nan", "position_inf", "orientation_nan", "orientation_inf",
                "quaternion_norm")
JOINT_STATE_REASONS = ("length", "duplicate", "position_nan", "position_inf", "velocity_nan",
                       "velocity_inf", "effort_nan", "effort_inf")

InputProblem = tuple[str, str]     # (reason, text naming the field)


def _not_finite(label: str, values: Iterable[tuple[str, float]]) -> InputProblem | None:
    """The first field of ``values`` ((name, value)) that is NaN or infinite."""
    for name, v in values:
        v = float(v)
        if math.isnan(v):
            return f"{label}_nan", f"{name} is NaN"
        if math.isinf(v):
            return f"{label}_inf", f"{name} is {v}"
    return None


def pose_problem(frame: str, position: Sequence[float], orientation: Sequence[float],
                 expected_frame: str, what: str) -> InputProblem | None:
    """None if the pose is usable, else (reason, text). ``position`` (x, y, z) m,
    ``orientation`` (x, y, z, w); ``what`` starts the text (e.g. "host_pose ignored")."""
    if frame != expected_frame:
        return "frame", f"{what}: header.frame_id is {frame!r}, needs {expected_frame!r}"
    bad = _not_finite("position", zip(("pose.position.x", "pose.position.y",
                                       "pose.position.z"), position))
    if bad is None:
        bad = _not_finite("orientation", zip(("pose.orientation.x", "pose.orientation.y",
                                              "pose.orientation.z", "pose.orientation.w"),
                                             orientation))
    if bad is not None:
        return bad[0], f"{what}: {bad[1]}"
    n = math.sqrt(sum(float(v) * float(v) for v in orientation))
    if not abs(n - 1.0) < 1e-3:
        return "quaternion_norm", (f"{what}: pose.orientation is not a unit quaternion "
                                   f"(|q| = {n:.4g})")
    return None


def joint_state_problem(names: Sequence[str], position: Sequence[float],
                        velocity: Sequence[float], effort: Sequence[float],
                        needed_velocity: Iterable[str] = ()) -> InputProblem | None:
    """None if the joint state is usable, else (reason, text naming the array and joint).
    Every position must be finite; velocities of ``needed_velocity`` joints too (they enter
    the reaction); efforts are not used."""
    n = len(names)
    for label, arr in (("position", position), ("velocity", velocity), ("effort", effort)):
        if len(arr) not in (0, n):
            return "length", f"joint_states ignored: {label} has {len(arr)} values for {n} names"
    if len(set(names)) != n:
        dup = sorted({x for x in names if list(names).count(x) > 1})
        return "duplicate", f"joint_states ignored: duplicate joint names {dup}"
    bad = _not_finite("position", ((f"position of {nm}", v) for nm, v in zip(names, position)))
    if bad is None and len(velocity):
        need = set(needed_velocity)
        bad = _not_finite("velocity", ((f"velocity of {nm}", v)
                                       for nm, v in zip(names, velocity) if nm in need))
    return None if bad is None else (bad[0], f"joint_states ignored: {bad[1]}")
