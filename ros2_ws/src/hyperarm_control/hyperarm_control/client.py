"""A small client of ``arm_controller/follow_joint_trajectory`` for scripts, the CLI and tests,
in the manner of nav2_simple_commander: :meth:`TrajectoryClient.send` a goal, then
:meth:`~TrajectoryClient.done`, :meth:`~TrajectoryClient.feedback`,
:meth:`~TrajectoryClient.cancel` and :meth:`~TrajectoryClient.result`. The caller spins the
node (any executor); nothing here blocks except :meth:`~TrajectoryClient.wait`, which sleeps
while another thread spins.

Goals can be built from plain data with :func:`goal_from_points` (s, rad), or loaded from a
trajectory file with :func:`goal_from_file` (docs/ros-interfaces.md: ``joint_names``, and
``points`` of ``time`` and ``positions``, optional ``velocities``, ``accelerations``;
optional ``goal_tolerance``, ``path_tolerance`` maps and ``goal_time_tolerance``)."""
from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Callable, Mapping, Sequence

from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.task import Future

from hyperarm_description import contract
from hyperarm_description.qos import discovery_settle_left

from .messages import point

__all__ = ["ACTION", "TrajectoryClient", "TrajectoryFileError", "goal_from_points",
           "goal_from_file", "RESULT_NAMES", "in_executor"]

ACTION = contract.ARM_TRAJECTORY_ACTION

#: FollowJointTrajectory.Result error codes by value
RESULT_NAMES = {0: "SUCCESSFUL", -1: "INVALID_GOAL", -2: "INVALID_JOINTS",
                -3: "OLD_HEADER_TIMESTAMP", -4: "PATH_TOLERANCE_VIOLATED",
                -5: "GOAL_TOLERANCE_VIOLATED"}


class TrajectoryFileError(ValueError):
    """A trajectory file that cannot be read or does not follow the schema."""


def _tolerances(given: Mapping[str, float] | None) -> list[JointTolerance]:
    return [JointTolerance(name=str(n), position=float(v)) for n, v in (given or {}).items()]


def goal_from_points(joint_names: Sequence[str], times: Sequence[float],
                     positions: Sequence[Sequence[float]],
                     velocities: Sequence[Sequence[float]] | None = None,
                     goal_tolerance: Mapping[str, float] | None = None,
                     path_tolerance: Mapping[str, float] | None = None,
                     goal_time_tolerance: float = 0.0) -> FollowJointTrajectory.Goal:
    """A goal from times (s from start) and positions (one row per point); tolerances are
    position tolerances by joint name (rad or m; 0 = the controller's default)."""
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = [str(n) for n in joint_names]
    for i, (t, q) in enumerate(zip(times, positions)):
        v = velocities[i] if velocities else None
        goal.trajectory.points.append(point(q, v, t=float(t)))
    goal.goal_tolerance = _tolerances(goal_tolerance)
    goal.path_tolerance = _tolerances(path_tolerance)
    whole = math.floor(goal_time_tolerance)
    goal.goal_time_tolerance.sec = int(whole)
    goal.goal_time_tolerance.nanosec = int(round((goal_time_tolerance - whole) * 1e9))
    return goal


# a point's time and goal_time_tolerance, s: the controller refuses goals over 1 h anyway
MAX_FILE_TIME = 3600.0
TRAJECTORY_SCHEMA = {
    "type": "object",
    "required": ["joint_names", "points"],
    "additionalProperties": False,
    "properties": {
        "joint_names": {"type": "array", "minItems": 1, "items": {"type": "string"}},
        "points": {"type": "array", "minItems": 1, "items": {
            "type": "object", "required": ["time", "positions"], "additionalProperties": False,
            "properties": {
                "time": {"type": "number", "minimum": 0, "maximum": MAX_FILE_TIME},
                "positions": {"type": "array", "items": {"type": "number"}},
                "velocities": {"type": "array", "items": {"type": "number"}}}}},
        "goal_tolerance": {"type": "object", "additionalProperties": {"type": "number"}},
        "path_tolerance": {"type": "object", "additionalProperties": {"type": "number"}},
        "goal_time_tolerance": {"type": "number", "minimum": 0, "maximum": MAX_FILE_TIME},
    },
}


def _numbers(data, where: str = ""):
    """(path, value) of every number in a loaded YAML document."""
    if isinstance(data, dict):
        for k, v in data.items():
            yield from _numbers(v, f"{where}/{k}" if where else str(k))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            yield from _numbers(v, f"{where}/{i}")
    elif isinstance(data, float):
        yield where, data


def goal_from_file(path: str | Path) -> FollowJointTrajectory.Goal:
    """Load a trajectory file (YAML, :data:`TRAJECTORY_SCHEMA`); raises
    :class:`TrajectoryFileError` saying what is wrong and where."""
    import jsonschema
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise TrajectoryFileError(f"{path}: {exc}") from exc
    try:
        jsonschema.validate(data, TRAJECTORY_SCHEMA)
    except jsonschema.ValidationError as exc:
        where = "/".join(str(p) for p in exc.absolute_path) or "(top level)"
        hint = ""
        if isinstance(exc.instance, str):
            try:
                float(exc.instance)
                hint = (f" (YAML reads {exc.instance} as text: write the number with a dot "
                        "and a signed exponent, e.g. 1.0e+3)")
            except ValueError:
                pass
        raise TrajectoryFileError(f"{path}: {where}: {exc.message}{hint}") from exc
    for where, value in _numbers(data):       # the schema's "number" takes .nan and .inf
        if not math.isfinite(value):
            raise TrajectoryFileError(f"{path}: {where}: {value} is not a finite number")
    points = data["points"]
    vel = [p.get("velocities", []) for p in points]
    return goal_from_points(data["joint_names"], [p["time"] for p in points],
                            [p["positions"] for p in points],
                            vel if any(vel) else None, data.get("goal_tolerance"),
                            data.get("path_tolerance"), data.get("goal_time_tolerance", 0.0))


def in_executor(node: Node, start: Callable[[], Future]) -> Future:
    """Call ``start`` (which sends a request, e.g. ``lambda: client.send_goal_async(goal)``)
    in the thread that spins ``node``, and return a future of its future's result.

    rclpy 7.1.6's ActionClient stores a request's sequence number only after the request has
    gone out (ros2/rclpy#1123, fixed upstream by #1308, not in the Jazzy wheels on PyPI). An
    executor spinning in another thread can take the answer in between: rclpy logs "Ignoring
    unexpected goal response" and the future never completes (a CI run: a gripper goal never
    answered). Sent from the executor's own thread, the answer cannot be taken before. A
    node that no executor spins yet calls ``start`` at once (nothing can race it then). An
    exception of ``start`` or of its future is the returned future's exception."""
    executor = node.executor
    if executor is None:
        return start()
    answer = Future(executor=executor)

    def passed_on(sent: Future) -> None:
        if sent.cancelled():
            answer.cancel()
        elif sent.exception() is not None:
            answer.set_exception(sent.exception())
        else:
            answer.set_result(sent.result())

    def send() -> None:
        try:
            sent = start()
        except Exception as exc:       # the request could not go out: the caller hears why
            answer.set_exception(exc)
            return
        sent.add_done_callback(passed_on)

    executor.create_task(send)
    return answer


class TrajectoryClient:
    """One goal at a time on ``action`` (relative to ``node``'s namespace)."""

    def __init__(self, node: Node, action: str = ACTION) -> None:
        self._node = node
        self._client = ActionClient(node, FollowJointTrajectory, action)
        self._created = time.monotonic()
        self._lock = threading.Lock()
        self._handle = None
        self._result_future = None
        self._feedback: list = []
        self._rejected = False

    def server_ready(self) -> bool:
        return self._client.server_is_ready()

    def send(self, goal: FollowJointTrajectory.Goal) -> None:
        """Send ``goal`` (returns at once; :meth:`accepted` and :meth:`done` tell more)."""
        with self._lock:
            self._handle, self._result_future, self._rejected = None, None, False
            self._feedback = []
        # the server must also have matched this client's response reader (DDS discovers
        # in its own threads: a sleep is enough)
        time.sleep(discovery_settle_left(self._created, time.monotonic()))
        fut = in_executor(self._node, lambda: self._client.send_goal_async(
            goal, feedback_callback=self._on_feedback))
        fut.add_done_callback(self._on_response)

    def _on_feedback(self, msg) -> None:
        with self._lock:
            self._feedback.append(msg.feedback)

    def _on_response(self, fut) -> None:
        handle = fut.result()
        with self._lock:
            if not handle.accepted:
                self._rejected = True
                return
            self._handle = handle
            self._result_future = handle.get_result_async()

    def accepted(self) -> bool | None:
        """True once accepted, False if rejected, None while unanswered."""
        with self._lock:
            return False if self._rejected else (None if self._handle is None else True)

    def done(self) -> bool:
        with self._lock:
            return self._rejected or (self._result_future is not None
                                      and self._result_future.done())

    def feedback(self) -> list:
        """Every FollowJointTrajectory feedback received for the present goal."""
        with self._lock:
            return list(self._feedback)

    def cancel(self) -> None:
        with self._lock:
            handle = self._handle
        if handle is not None:
            in_executor(self._node, handle.cancel_goal_async)

    def result(self) -> tuple[int, FollowJointTrajectory.Result | None]:
        """(action status, result) once :meth:`done`; status is action_msgs' GoalStatus
        value (4 succeeded, 5 canceled, 6 aborted)."""
        with self._lock:
            if self._rejected or self._result_future is None or not self._result_future.done():
                return 0, None
            res = self._result_future.result()
        return res.status, res.result

    def wait(self, timeout: float) -> bool:
        """Sleep until :meth:`done` (another thread spins the node) or ``timeout`` s."""
        end = time.monotonic() + timeout
        while not self.done():
            if time.monotonic() > end:
                return False
            time.sleep(0.01)
        return True
