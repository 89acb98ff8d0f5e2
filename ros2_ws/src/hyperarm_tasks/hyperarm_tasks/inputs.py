"""The task node's stamped inputs, judged whole before use (no ROS).

Each feed answers, for one message, ``None`` (use it) or a rejection ``(reason, text)``:
``reason`` is the key of the node's log throttle and of its diagnostics count (one per
kind, so a NaN after a bad quaternion after a late message are three log lines, never one
throttled line), ``text`` names the stream and the bad field.

- :class:`StateFeed`, ``joint_states``: malformed (the kinds of
  :func:`hyperarm_control.host.inputs.joint_state_problem`, and ``effort_nan`` /
  ``effort_inf``: the runner reads the gripper's effort), then late or out of order
  (:class:`~hyperarm_description.freshness.StampGate`, per source: each driver publishes
  its own joints with its own stamps).
- :class:`DetectionFeed`, ``detections``: ``frame`` (not the camera's), ``length`` (names
  and poses differ), each pose's ``position_nan`` ... ``quaternion_norm``
  (:func:`hyperarm_control.host.inputs.pose_problem`), then late or out of order.

A message older than the newest one used (same source), older than ``max_age`` s, stamped
more than ``max_future`` s ahead or unstamped is rejected; times are the node's clock (s).
"""
from __future__ import annotations

import math
from typing import Sequence

from hyperarm_description import contract
from hyperarm_description.freshness import StampGate
from hyperarm_control.host.inputs import InputProblem, joint_state_problem, pose_problem

__all__ = ["StateFeed", "DetectionFeed", "InputProblem"]


class _Feed:
    """Counts of every rejection by reason (diagnostics), around one :class:`StampGate`."""

    def __init__(self, stream: str, max_age: float, max_future: float) -> None:
        self.stream = stream
        self.gate = StampGate(stream, max_age, max_future)
        self.malformed: dict[str, int] = {}

    def _malformed(self, problem: InputProblem) -> InputProblem:
        reason, text = problem
        self.malformed[reason] = self.malformed.get(reason, 0) + 1
        return f"{self.stream} {reason}", text

    def _fresh(self, stamp: float, now: float, source) -> InputProblem | None:
        rejected = self.gate.check(stamp, now, source=source)
        return None if rejected is None else (f"{self.stream} {rejected.reason}", rejected.text)

    def counts(self) -> dict[str, int]:
        """Messages rejected, by "<stream>_rejected_<reason>", and accepted."""
        out = {f"{self.stream}_rejected_{r}": n for r, n in self.gate.counts.items()}
        out.update({f"{self.stream}_rejected_{r}": n for r, n in self.malformed.items()})
        out[f"{self.stream}_accepted"] = self.gate.accepted
        return out


class StateFeed(_Feed):
    """``joint_states`` for the runner."""

    def __init__(self, max_age: float, max_future: float = 0.5) -> None:
        super().__init__(contract.JOINT_STATES, max_age, max_future)

    def check(self, names: Sequence[str], position: Sequence[float],
              velocity: Sequence[float], effort: Sequence[float], stamp: float,
              now: float) -> InputProblem | None:
        """None if the message (positions rad or m, velocities rad/s or m/s, efforts N·m
        or N; ``stamp`` and ``now`` s) may be used, else (reason, text)."""
        problem = joint_state_problem(names, position, velocity, effort)
        if problem is None and len(effort) == len(names):
            for name, v in zip(names, effort):
                if not math.isfinite(float(v)):
                    problem = (f"effort_{'nan' if math.isnan(float(v)) else 'inf'}",
                               f"joint_states ignored: effort of {name} is {float(v)}")
                    break
        if problem is not None:
            return self._malformed(problem)
        source = (names[0] if len(names) == 1 else
                  f"{names[0]}..{names[-1]} ({len(names)} joints)" if names else "no joints")
        return self._fresh(stamp, now, source)


class DetectionFeed(_Feed):
    """``detections`` (poses in the camera's frame ``frame``)."""

    def __init__(self, frame: str, max_age: float, max_future: float = 0.5) -> None:
        super().__init__(contract.DETECTIONS, max_age, max_future)
        self.frame = frame

    def check(self, frame: str, names: Sequence[str],
              poses: Sequence[tuple[Sequence[float], Sequence[float]]], stamp: float,
              now: float) -> InputProblem | None:
        """None if the message may be used, else (reason, text). ``poses``: per object
        (position x y z m, orientation x y z w); ``frame`` '' counts as the camera's."""
        what = f"{self.stream} ignored"
        if frame not in ("", self.frame):
            return self._malformed(("frame", f"{what}: header.frame_id is {frame!r}, "
                                             f"needs {self.frame!r}"))
        if len(names) != len(poses):
            return self._malformed(("length", f"{what}: {len(names)} names for "
                                              f"{len(poses)} poses"))
        for i, (name, (position, orientation)) in enumerate(zip(names, poses)):
            problem = pose_problem(self.frame, position, orientation, self.frame,
                                   f"{what}: poses[{i}] ({name!r})")
            if problem is not None:
                return self._malformed(problem)
        return self._fresh(stamp, now, frame or self.frame)
