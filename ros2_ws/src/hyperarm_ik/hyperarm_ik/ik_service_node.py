"""ik_service: serves ``solve_ik`` (hyperarm_interfaces/SolveIK) with the IK solvers.

The target is a PoseStamped of tool0 in base_link (world for the rail variant); the seed
comes from the request, else the latest ``joint_states``, else q = 0. Bad requests get
success=false and a message naming the problem. Diagnostics on /diagnostics at 1 Hz.

Requests are served concurrently: the service callback is in a reentrant group, spun by a
MultiThreadedExecutor, and each request borrows one of ``concurrency`` independent solver
sets (:class:`~hyperarm_ik.ik_core.IKPool`), so a long request (up to ``max_timeout``) does
not delay an ordinary one. More than ``concurrency`` simultaneous requests wait for a free
solver set.
"""
from __future__ import annotations

import sys
import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description.joints import JointStateError
from hyperarm_description.model import VARIANTS, DescriptionError, load_description
from hyperarm_description.params import OneOf, ParamSpec, Range, declare_parameters
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import run_node
from hyperarm_description.world import WorldSpec, load_world
from hyperarm_interfaces.srv import SolveIK

from .errors import IKError
from .ik_core import IKDefaults, IKPool, IKRequest
from .solvers.base import COLLISION_MODES
from .kinematics import Kinematics
from .ros_conversions import joint_state
from .solvers import DEFAULT_SOLVER, solver_names


DEFAULT_CONCURRENCY = 4
MAX_CONCURRENCY = 16
SWITCH_INTERVAL = 0.001  # s, sys.setswitchinterval of the ik_service process
_COLLISION_MODES = {SolveIK.Request.COLLISIONS_DEFAULT: "",
                    SolveIK.Request.COLLISIONS_IGNORE: "ignore",
                    SolveIK.Request.COLLISIONS_CHECK: "check",
                    SolveIK.Request.COLLISIONS_AVOID: "avoid"}
_D = IKDefaults()
#: Every parameter of the node (also its --help): name -> (default, description, check).
PARAMETERS: ParamSpec = {
    "variant": ("arm", f"robot variant: {' or '.join(VARIANTS)}", None),
    "description_file": ("", "robot description YAML ('' = the packaged one)", None),
    "default_solver": (DEFAULT_SOLVER, "solver used when a request names none: "
                       f"{', '.join(solver_names())}", None),
    "position_tolerance": (_D.position_tolerance, "m, used when a request gives 0", None),
    "orientation_tolerance": (_D.orientation_tolerance, "rad, used when a request gives 0",
                              None),
    "timeout": (_D.timeout, "s, solve time budget when a request gives 0", None),
    "max_timeout": (_D.max_timeout, "s, requests asking for more are refused", None),
    "concurrency": (DEFAULT_CONCURRENCY, "requests solved at the same time (one solver set "
                    "each); more wait for a free one", Range(1, MAX_CONCURRENCY)),
    "collisions": (_D.collisions, "collision handling of requests that leave it at "
                   "COLLISIONS_DEFAULT", OneOf(COLLISION_MODES)),
    "world_file": ("", "work-cell YAML whose world: mapping (table, pegs, poles) is avoided "
                   "('' = self-collision only)", None),
    "collision_margin": (0.0, "m, added to every collision capsule", Range(0.0, 0.1)),
}


def world_summary(world_file: str, world: WorldSpec | None) -> str:
    """What the IK's collision checks know of the surroundings, for the first log line."""
    if world is None:
        return ("self-collisions only, no work cell (world_file ''): targets in or under "
                "the table are not refused")
    pegs = ", ".join(p.name for p in world.pegs) or "no pegs"
    return (f"the work cell {world_file} (table top at z = {world.table_height:.3f} m, "
            f"pegs: {pegs}, {len(world.poles)} poles) and self-collisions")


class IkServiceNode(Node):
    """Answers SolveIK requests; never raises out of the callback."""

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to rclpy's Node (e.g. context, parameter_overrides)."""
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("ik_service", **kwargs)
        values = declare_parameters(self, PARAMETERS)
        get = values.__getitem__
        try:
            desc = load_description(get("description_file") or None, get("variant"))
            defaults = IKDefaults(solver=get("default_solver"),
                                  position_tolerance=float(get("position_tolerance")),
                                  orientation_tolerance=float(get("orientation_tolerance")),
                                  timeout=float(get("timeout")),
                                  max_timeout=float(get("max_timeout")),
                                  collisions=get("collisions"))
            world = load_world(get("world_file")) if get("world_file") else None
            self._pool = IKPool(lambda: Kinematics(desc), defaults,
                                int(get("concurrency")), world,
                                float(get("collision_margin")))
        except (DescriptionError, IKError, OSError, TypeError, ValueError) as exc:
            raise SystemExit(f"ik_service: bad parameter: {exc}") from exc
        self._stats = {"requests": 0, "solved": 0, "refused": 0, "last_time": 0.0,
                       "last_message": "", "busy": 0, "peak_busy": 0}
        self._stats_lock = threading.Lock()
        self._throttle = ReasonThrottle(2.0)  # per reason: a new kind of error is never hidden
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_joint_states,
                                 qos_for(contract.JOINT_STATES))
        self.create_service(SolveIK, contract.SOLVE_IK, self._on_solve,
                            callback_group=ReentrantCallbackGroup())
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS))
        self.create_timer(1.0, self._publish_diagnostics)
        # the first line says which world is avoided: a stack without the work cell answers
        # targets in or under the table (the launch files pass config/workcell.yaml)
        self.get_logger().info(
            f"ik_service: collisions: {defaults.collisions} with "
            f"{world_summary(get('world_file'), world)}; {desc.variant} variant, targets in "
            f"{self._pool.frame}, solvers {', '.join(self._pool.cores[0].solvers)} (default "
            f"{defaults.solver}), {self._pool.size} requests at a time")

    def _on_joint_states(self, msg: JointState) -> None:
        try:
            self._pool.update_joint_states(msg.name, msg.position, msg.velocity, msg.effort)
        except JointStateError as exc:
            if (text := self._throttle.message(f"joint_states: {exc}")):
                self.get_logger().warn(text)

    def _count(self, **add) -> None:
        with self._stats_lock:
            for k, v in add.items():
                self._stats[k] += v

    def _on_solve(self, request: SolveIK.Request, response: SolveIK.Response):
        self._count(requests=1)
        pose = request.target.pose
        req = IKRequest(
            frame_id=request.target.header.frame_id,
            position=(pose.position.x, pose.position.y, pose.position.z),
            orientation=(pose.orientation.x, pose.orientation.y, pose.orientation.z,
                         pose.orientation.w),
            seed_names=list(request.seed.name), seed_positions=list(request.seed.position),
            solver=request.solver, position_only=request.position_only,
            position_tolerance=request.position_tolerance,
            orientation_tolerance=request.orientation_tolerance, timeout=request.timeout,
            collisions=_COLLISION_MODES.get(request.collisions, f"<{request.collisions}>"),
            block_held=request.block_held)
        try:
            result, source = self._pool.solve(req)
        except IKError as exc:
            self._count(refused=1)
            response.success = False
            response.message = f"request refused: {exc}"
            if (text := self._throttle.message(response.message)):
                self.get_logger().warn(text)
            return response
        except Exception as exc:  # a bug must not take the service down
            self._count(refused=1)
            response.success = False
            response.message = f"internal error: {type(exc).__name__}: {exc}"
            self.get_logger().error(response.message)
            return response
        response.success = bool(result.success)
        response.solution = joint_state(self._pool.kin.joint_names, result.q)
        response.solution.header.stamp = self.get_clock().now().to_msg()
        response.position_error = float(result.position_error)
        response.orientation_error = float(result.orientation_error)
        response.iterations = int(result.iterations)
        response.solve_time = float(result.solve_time)
        response.message = f"{result.message} (seed: {source})"
        response.contacts = list(result.contacts)
        self._count(solved=int(result.success))
        with self._stats_lock:
            self._stats["last_time"] = result.solve_time
            self._stats["last_message"] = response.message
        if not result.success:
            if (text := self._throttle.message(response.message)):
                self.get_logger().info(text)
        return response

    def _publish_diagnostics(self) -> None:
        with self._stats_lock:
            self._stats["busy"] = self._pool.busy
            self._stats["peak_busy"] = self._pool.peak_busy
            stats = dict(self._stats)
        st = DiagnosticStatus(level=DiagnosticStatus.OK, name=f"{self.get_name()}: IK",
                              hardware_id="hyperarm",
                              message=f"{stats['requests']} requests")
        st.values = [KeyValue(key=k, value=str(v)) for k, v in stats.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [st]
        self._diag.publish(msg)


def main(args: list[str] | None = None) -> None:
    # a solving thread hands the GIL over after at most 1 ms (Python's default: 5 ms), so a
    # short request is not held up by a long one for long (measured: see the benchmark)
    sys.setswitchinterval(SWITCH_INTERVAL)
    # threads: MAX_CONCURRENCY solves + the subscription and the diagnostics timer
    run_node(IkServiceNode, args,
             executor=lambda: MultiThreadedExecutor(num_threads=MAX_CONCURRENCY + 2),
             parameters=PARAMETERS, robot_description=False)


if __name__ == "__main__":
    main()
