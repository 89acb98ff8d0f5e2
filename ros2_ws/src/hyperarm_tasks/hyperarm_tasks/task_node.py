"""task_node: runs task files (YAML sequences) through the RunTask action.

Thin: parameters, the action server and the ROS side of the robot (:mod:`.ros_robot`); the
sequencing is :class:`hyperarm_tasks.runner.Runner`, the task files
:mod:`hyperarm_tasks.sequence`. One goal at a time: a goal while another runs is rejected
with its reason: the goal is accepted and aborted at once, its result's ``failure_kind``
"rejected" and ``message`` the reason (rclpy's goal callback cannot give a reason with a plain
rejection; the running task is not touched). Cancel: the runner stops where it is, force control off, the
drivers hold, and the result says "cancelled during <step>". See docs/tasks.md.

The task runs in a thread of its own (the action's execute callback awaits it), so one
executor thread takes the messages: rclpy's SingleThreadedExecutor (issue 28: with the
MultiThreadedExecutor's hand-offs of joint_states at 100 Hz the node took 17-20 % of a core
over a block transfer, now 15 %; rclpy's EventsExecutor spins a whole core while a
coroutine awaits). When the node is stopped (SIGINT, SIGTERM) during a task, the task is
stopped as a cancel stops it, for at most ``STOP_WAIT`` s, before the node is destroyed.
"""
from __future__ import annotations

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import RCLError
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.task import Future

from hyperarm_description import contract
from hyperarm_description.params import ParamSpec, Range, declare_parameters
from hyperarm_description.qos import NO_PUB_EVENTS, qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node
from hyperarm_description.world import load_world
from hyperarm_ik.collision import CollisionModel
from hyperarm_ik.kinematics import Kinematics
from hyperarm_ik.solvers import make_solver, solver_names
from hyperarm_interfaces.action import RunTask
from hyperarm_interfaces.msg import TaskFeedback

from .errors import TaskError, TaskFileError, UnknownTaskError
from .recording import TASK_FEEDBACK
from .ros_robot import RosRobot, pose_to_matrix
from .runner import Feedback, Runner, RunnerParams
from .sequence import load_task, packaged_tasks_dir

FEEDBACK_PERIOD = 0.05   # s, feedback published at most this often
DIAGNOSTICS_PERIOD = 1.0   # s, the inputs' diagnostics
STOP_WAIT = 1.0   # s: a task running when the node stops gets this long to stop and hold

#: Every parameter of the node (also its --help): name -> (default, description, check).
PARAMETERS: ParamSpec = {
    "command_rate": (50.0, "rate at which goals are streamed on joint_command, Hz",
                     Range(1.0, 500.0)),
    "tasks_dir": ("", "directories of user task files (':'-separated), searched before the "
                      "package's share/hyperarm_tasks/tasks", None),
    "detection_frames": (5, "camera frames averaged per object estimate", Range(1, 30)),
    "detection_max_age": (1.0, "s: an older detection is stale (and a detections message "
                               "older than that, or than the newest used, is not used); a "
                               "located pose has its own age, located_max_age",
                          Range(0.05, 60.0)),
    "joint_states_max_age": (0.5, "s: a joint_states message older than this, or than the "
                                  "newest one used from the same driver, is not used",
                             Range(0.01, 10.0)),
    "detection_timeout": (3.0, "s: wait this long for fresh detections", Range(0.1, 60.0)),
    "detection_outlier": (0.01, "m: detections this far from the median are rejected",
                          Range(0.0005, 1.0)),
    "located_max_age": (60.0, "s: an object the camera located (a locate step, or an "
                              "earlier estimate), not held and untouched by a close or release "
                              "since, keeps that pose this long while the camera cannot see "
                              "it; 0: only fresh detections count", Range(0.0, 3600.0)),
    "solver": ("", "IK solver ('' = the default; see hyperarm_ik)", None),
    "collision_check": (False, "IK avoids, and every planned joint path (move_to, "
                               "move_joints, retreat) is checked for, collisions of the arm "
                               "with itself and the work cell before it is sent (hyperarm_ik's "
                               "collision model; a colliding path fails the step, kind "
                               "'collision'); off by default, see docs/tasks.md", None),
    "world_file": ("", "work-cell YAML whose world: mapping (table, pegs, poles) the paths "
                       "are checked against ('' = the arm's self-collisions only)", None),
}


class TaskNode(Node):
    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to rclpy's Node (a context, parameter_overrides: in-process tests)."""
        super().__init__("task_node", namespace=contract.DEFAULT_NAMESPACE, **kwargs)
        self._desc = declare_robot_description(self)
        p = declare_parameters(self, PARAMETERS)
        if p["solver"] and p["solver"] not in solver_names(self._desc.variant):
            raise SystemExit(f"task_node: parameter solver={p['solver']!r} not one of "
                             f"{', '.join(solver_names(self._desc.variant))}")
        self._dirs = [d for d in p.pop("tasks_dir").split(":") if d]
        check, world_file = p.pop("collision_check"), p.pop("world_file")
        states_max_age = p.pop("joint_states_max_age")
        self._params = RunnerParams(**p)
        self._kin = Kinematics(self._desc)
        # the solver's first construction takes about 1 s (2-3 s at load 16): once here, so
        # that a goal (and a cancel right after it) does not wait for it
        make_solver(self._params.solver, self._kin)
        self._collisions = None
        if check:
            try:
                world = load_world(world_file) if world_file else None
            except (OSError, ValueError) as exc:
                raise SystemExit(f"task_node: parameter world_file: {exc}") from None
            self._collisions = CollisionModel(self._kin, world)
        self._robot = RosRobot(self, self._desc, states_max_age, p["detection_max_age"])
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS),
                                           event_callbacks=NO_PUB_EVENTS)
        self._diag_counts: dict[str, int] = {}
        # every feedback also on a plain topic, under a type stock MCAP readers decode
        self._feedback = self.create_publisher(
            TaskFeedback, TASK_FEEDBACK,
            QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE),
            event_callbacks=NO_PUB_EVENTS)
        self.create_timer(DIAGNOSTICS_PERIOD, self._publish_diagnostics)
        self._lock = threading.Lock()
        self._busy: str | None = None
        self._worker: threading.Thread | None = None
        self._job: tuple = (None, None)   # the running goal's handle and its result future
        self._server = ActionServer(
            self, RunTask, contract.RUN_TASK, execute_callback=self._execute,
            goal_callback=self._on_goal, cancel_callback=self._on_cancel,
            callback_group=ReentrantCallbackGroup())
        checked = ("off" if self._collisions is None else
                   f"work cell {world_file}" if world_file else "self-collisions only")
        self.get_logger().info(f"task_node ready: action {contract.RUN_TASK}, tasks from "
                               f"{', '.join(self._dirs + [str(packaged_tasks_dir())])}; "
                               f"path collision check: {checked}; robot description "
                               f"{self._desc.source}")

    def _publish_diagnostics(self) -> None:
        """'task_node: inputs': joint_states and detections accepted and rejected by reason
        (totals); WARN while messages are being rejected."""
        self._robot.drop_idle_inputs()
        counts = self._robot.input_counts()
        new = {k: v - self._diag_counts.get(k, 0) for k, v in counts.items()
               if "_rejected_" in k and v > self._diag_counts.get(k, 0)}
        self._diag_counts = counts
        st = DiagnosticStatus(name="task_node: inputs", hardware_id="task_node")
        st.level = DiagnosticStatus.WARN if new else DiagnosticStatus.OK
        st.message = ("rejected in the last period: " + ", ".join(
            f"{k.replace('_rejected_', ' ')} {v}" for k, v in sorted(new.items()))
            if new else "inputs ok")
        st.values = [KeyValue(key=k, value=str(v)) for k, v in sorted(counts.items())]
        msg = DiagnosticArray(status=[st])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diag.publish(msg)

    def _on_goal(self, goal: RunTask.Goal) -> GoalResponse:
        # Every goal is accepted; _execute refuses one while another runs, with the reason
        # in its result (a GoalResponse.REJECT reaches the client without any reason).
        return GoalResponse.ACCEPT

    def _on_cancel(self, handle) -> CancelResponse:
        # visible to the task thread before this line is logged: no step starts after it
        # (rclpy moves the goal to CANCELING only once this callback has returned)
        self._robot.cancel_accepted = bytes(handle.goal_id.uuid)
        step = self._runner_step()
        self.get_logger().warn(f"cancel requested for task {handle.request.task!r} during "
                               f"{step}")
        return CancelResponse.ACCEPT

    def _runner_step(self) -> str:
        runner = getattr(self, "_runner", None)
        return runner.step.name if runner is not None and runner.step else "no step"

    async def _execute(self, handle) -> RunTask.Result:
        """The action's execute callback: one goal at a time (another is refused with its
        reason, as is any goal once the node is stopping); the task runs in a thread of its
        own, awaited here, so that the executor keeps taking messages meanwhile."""
        with self._lock:
            busy = self._busy
            if busy is None and not self._robot.stopping:
                self._busy = handle.request.task
        if busy is not None or self._robot.stopping:
            reason = (f"task {handle.request.task!r} rejected: " +
                      (f"task {busy!r} is running (one goal at a time)" if busy is not None
                       else "task_node is stopping"))
            self.get_logger().warn(reason)
            handle.abort()
            return RunTask.Result(success=False, message=reason, failure_kind="rejected")
        done = Future()
        self._job = (handle, done)

        def work() -> None:
            try:
                result, error = self._run(handle), None
            except Exception as exc:         # handed to the awaiting callback, raised there
                result, error = None, exc
            except BaseException as exc:     # (not re-raised in the executor as it is)
                result, error = None, RuntimeError(f"task thread ended by {exc!r}")
            # the slot is free before the client can have the result (a client's next goal
            # right after it is not refused as "running")
            self._runner = None
            self._robot.goal_handle = None
            if self._robot.cancel_accepted == bytes(handle.goal_id.uuid):
                self._robot.cancel_accepted = None     # (a client reusing the id later)
            with self._lock:
                self._busy = None
                self._worker = None
            if not done.done():              # (else before_shutdown answered already)
                if error is None:
                    done.set_result(result)
                else:
                    done.set_exception(error)
            ex = self.executor
            if ex is not None:
                ex.wake()

        self._worker = threading.Thread(target=work, name=f"task {handle.request.task}",
                                        daemon=True)
        self._worker.start()
        try:
            return await done
        finally:
            self._job = (None, None)    # the result goes out as this coroutine returns

    def before_shutdown(self) -> bool:
        """(run_node, at SIGINT/SIGTERM) No goal is taken from now on. A running task is
        stopped as a cancel stops it (force control off, the drivers told to hold) and its
        client gets an aborted result; the executor spins meanwhile, for at most STOP_WAIT
        s. A task still running then (a hold that waits for a driver that is going away)
        is answered from here: aborted, "did not stop within STOP_WAIT s". True when a task
        was running or its result is not sent yet (run_node then spins to send it)."""
        self._robot.stopping = True
        with self._lock:
            worker, busy = self._worker, self._busy
        if worker is None or not worker.is_alive():
            return self._job[1] is not None    # a result not sent yet: run_node's spins
        self.get_logger().warn(f"stopping: task {busy!r} stops during {self._runner_step()}")
        end = time.monotonic() + STOP_WAIT
        ex = self.executor
        while worker.is_alive() and time.monotonic() < end:
            if ex is not None:
                ex.spin_once(timeout_sec=0.01)
            else:
                worker.join(0.01)
        handle, done = self._job
        if worker.is_alive() and not done.done():
            message = (f"task_node stopped: task {busy!r} did not stop within {STOP_WAIT:g} s "
                       f"(during {self._runner_step()})")
            self.get_logger().error(message)
            _end_goal(handle, "abort")
            done.set_result(RunTask.Result(success=False, message=message,
                                           failure_kind="cancelled"))
            # run_node's flush spins send the result; the thread ends with the process
        return True      # run_node's flush spins send the result out

    def _given(self, goal: RunTask.Goal) -> dict:
        if len(goal.object_names) != len(goal.object_poses):
            raise TaskError(f"{len(goal.object_names)} object names for "
                            f"{len(goal.object_poses)} poses")
        out = {}
        for name, pose in zip(goal.object_names, goal.object_poses):
            if pose.header.frame_id not in ("", self._desc.root_frame):
                raise TaskError(f"object {name!r} is in {pose.header.frame_id!r}; give it in "
                                f"{self._desc.root_frame!r}")
            out[name] = pose_to_matrix(pose.pose)
        return out

    def _run(self, handle) -> RunTask.Result:
        result = RunTask.Result()
        name = handle.request.task
        try:
            task = load_task(name, self._desc, self._dirs)
            self._robot.given = self._given(handle.request)
        except (TaskError, ValueError) as exc:
            result.success, result.message = False, str(exc)
            result.failure_kind = "task_file" if isinstance(
                exc, (TaskFileError, UnknownTaskError)) else "goal"
            self.get_logger().error(f"task {name!r}: {exc}")
            _end_goal(handle, "abort")
            return result
        self._robot.goal_handle = handle
        last = [0.0]

        def feedback(fb: Feedback) -> None:
            now = time.monotonic()
            if now - last[0] < FEEDBACK_PERIOD and fb.phase not in ("start", "done"):
                return
            last[0] = now
            msg = RunTask.Feedback(stage=fb.step, phase=fb.phase, stage_index=fb.index,
                                   stage_count=fb.count, progress=float(fb.progress),
                                   step_progress=float(fb.step_progress), force=fb.force,
                                   depth=fb.depth)
            msg.step_type = task.steps[fb.index].type
            msg.waypoint.header.frame_id = self._desc.root_frame
            msg.waypoint.header.stamp = self.get_clock().now().to_msg()
            msg.waypoint.point.x, msg.waypoint.point.y, msg.waypoint.point.z = \
                (float(v) for v in fb.waypoint)
            handle.publish_feedback(msg)
            plain = TaskFeedback(task=name, stage=msg.stage, step_type=msg.step_type,
                                 phase=msg.phase, stage_index=msg.stage_index,
                                 stage_count=msg.stage_count, progress=msg.progress,
                                 step_progress=msg.step_progress, waypoint=msg.waypoint,
                                 force=msg.force, depth=msg.depth)
            plain.goal_id.uuid = handle.goal_id.uuid
            self._feedback.publish(plain)

        self.get_logger().info(f"task {name!r}: {len(task.steps)} steps from {task.source}")
        if self._robot.cancel_requested():   # cancelled while loading: nothing was started
            result.success, result.failure_kind = False, "cancelled"
            result.message = f"cancelled before {task.steps[0].name}" if task.steps else \
                "cancelled"
            if self._cancel_confirmed(handle):
                self.get_logger().warn(f"task {name!r}: {result.message} (nothing started)")
                _end_goal(handle, "canceled")
            else:                            # the node is stopping
                result.message = f"task_node stopped: {result.message}"
                self.get_logger().error(f"task {name!r}: {result.message} (nothing started)")
                _end_goal(handle, "abort")
            return result
        self._runner = Runner(self._robot, self._kin, task, self._params, feedback,
                              collisions=self._collisions)
        cpu0, wall0 = time.process_time(), time.monotonic()
        out = self._runner.run()
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        result.success, result.message, result.failure_kind = (out.success, out.message,
                                                               out.failure_kind)
        result.stage_names, result.stage_durations = out.step_names, out.step_durations
        result.total_time = out.total_time
        metrics = {k: v for k, v in out.metrics.items() if not k.endswith("_logged")}
        # this process's CPU (every thread: the runner's and the executor's) over the task,
        # as a fraction of one core (issue 28: the soak prints it per cycle)
        metrics["task_node_cpu"] = cpu / wall if wall > 0.0 else 0.0
        result.metric_names, result.metric_values = list(metrics), list(metrics.values())
        if out.success:
            self.get_logger().info(f"{out.message} in {out.total_time:.2f} s")
            _end_goal(handle, "succeed")
        elif out.failure_kind == "cancelled" and self._cancel_confirmed(handle):
            self.get_logger().warn(f"task {name!r}: {out.message} (force control off, holding)")
            _end_goal(handle, "canceled")
        else:
            if self._robot.stopping and out.failure_kind == "cancelled":
                result.message = f"task_node stopped: {out.message}"
            self.get_logger().error(f"task {name!r}: {result.message}")
            if self.context.ok():
                _end_goal(handle, "abort")
        return result

    def _cancel_confirmed(self, handle) -> bool:
        """The goal's cancel was accepted (rclpy may not have moved it to CANCELING yet:
        that follows the cancel callback in the executor's thread, within moments)."""
        if self._robot.cancel_accepted != bytes(handle.goal_id.uuid):
            return handle.is_cancel_requested
        end = time.monotonic() + 1.0
        while not handle.is_cancel_requested and time.monotonic() < end and self.context.ok():
            time.sleep(0.005)
        return handle.is_cancel_requested

    def destroy_node(self) -> None:
        # The action server first: its pending tasks must not outlive the node's handles.
        self._server.destroy()
        super().destroy_node()


def _end_goal(handle, how: str) -> None:
    """``handle.succeed()``, ``.abort()`` or ``.canceled()`` unless the goal has ended
    already (before_shutdown answered a task that did not stop in time)."""
    if handle is None or not handle.is_active:
        return
    try:
        getattr(handle, how)()
    except RCLError:    # ended meanwhile by the other thread: an invalid transition
        pass


def main(args: list[str] | None = None) -> None:
    run_node(TaskNode, args, parameters=PARAMETERS)


if __name__ == "__main__":
    main()
