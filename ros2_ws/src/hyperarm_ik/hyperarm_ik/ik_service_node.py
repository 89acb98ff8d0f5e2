"""ik_service: serves ``solve_ik`` (hyperarm_interfaces/SolveIK) with the IK solvers.

The target is a PoseStamped of tool0 in base_link (world for the rail variant); the seed
comes from the request, else the latest ``joint_states``, else q = 0. Bad requests get
success=false and a message naming the problem. Diagnostics on /diagnostics at 1 Hz.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from sensor_msgs.msg import JointState

from hyperarm_description import contract
from hyperarm_description.joints import JointStateError
from hyperarm_description.model import VARIANTS, DescriptionError, load_description
from hyperarm_description.params import ParamSpec
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import run_node
from hyperarm_interfaces.srv import SolveIK

from .errors import IKError
from .ik_core import IKCore, IKDefaults, IKRequest
from .kinematics import Kinematics
from .ros_conversions import joint_state
from .solvers import DEFAULT_SOLVER, solver_names


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
}


class IkServiceNode(Node):
    """Answers SolveIK requests; never raises out of the callback."""

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to rclpy's Node (e.g. context, parameter_overrides)."""
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("ik_service", **kwargs)
        for name, (default, text, _check) in PARAMETERS.items():
            self.declare_parameter(name, default, ParameterDescriptor(
                description=text, read_only=True, dynamic_typing=isinstance(default, float)))
        get = lambda n: self.get_parameter(n).value  # noqa: E731
        try:
            desc = load_description(get("description_file") or None, get("variant"))
            defaults = IKDefaults(solver=get("default_solver"),
                                  position_tolerance=float(get("position_tolerance")),
                                  orientation_tolerance=float(get("orientation_tolerance")),
                                  timeout=float(get("timeout")),
                                  max_timeout=float(get("max_timeout")))
            self._core = IKCore(Kinematics(desc), defaults)
        except (DescriptionError, IKError, TypeError, ValueError) as exc:
            raise SystemExit(f"ik_service: bad parameter: {exc}") from exc
        self._stats = {"requests": 0, "solved": 0, "refused": 0, "last_time": 0.0,
                       "last_message": ""}
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_joint_states,
                                 qos_for(contract.JOINT_STATES))
        self.create_service(SolveIK, contract.SOLVE_IK, self._on_solve)
        self._diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS,
                                           qos_for(contract.DIAGNOSTICS))
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(
            f"ik_service: {desc.variant} variant, targets in {self._core.frame}, solvers "
            f"{', '.join(self._core.solvers)} (default {defaults.solver})")

    def _on_joint_states(self, msg: JointState) -> None:
        try:
            self._core.joint_states.update(msg.name, msg.position, msg.velocity, msg.effort)
        except JointStateError as exc:
            self.get_logger().warn(f"joint_states: {exc}", throttle_duration_sec=5.0)

    def _on_solve(self, request: SolveIK.Request, response: SolveIK.Response):
        self._stats["requests"] += 1
        pose = request.target.pose
        req = IKRequest(
            frame_id=request.target.header.frame_id,
            position=(pose.position.x, pose.position.y, pose.position.z),
            orientation=(pose.orientation.x, pose.orientation.y, pose.orientation.z,
                         pose.orientation.w),
            seed_names=list(request.seed.name), seed_positions=list(request.seed.position),
            solver=request.solver, position_only=request.position_only,
            position_tolerance=request.position_tolerance,
            orientation_tolerance=request.orientation_tolerance, timeout=request.timeout)
        try:
            result, source = self._core.solve(req)
        except IKError as exc:
            self._stats["refused"] += 1
            response.success = False
            response.message = f"request refused: {exc}"
            self.get_logger().warn(response.message, throttle_duration_sec=2.0)
            return response
        except Exception as exc:  # a bug must not take the service down
            self._stats["refused"] += 1
            response.success = False
            response.message = f"internal error: {type(exc).__name__}: {exc}"
            self.get_logger().error(response.message)
            return response
        response.success = bool(result.success)
        response.solution = joint_state(self._core.kin.joint_names, result.q)
        response.solution.header.stamp = self.get_clock().now().to_msg()
        response.position_error = float(result.position_error)
        response.orientation_error = float(result.orientation_error)
        response.iterations = int(result.iterations)
        response.solve_time = float(result.solve_time)
        response.message = f"{result.message} (seed: {source})"
        self._stats["solved"] += int(result.success)
        self._stats["last_time"] = result.solve_time
        self._stats["last_message"] = response.message
        if not result.success:
            self.get_logger().info(response.message, throttle_duration_sec=2.0)
        return response

    def _publish_diagnostics(self) -> None:
        st = DiagnosticStatus(level=DiagnosticStatus.OK, name=f"{self.get_name()}: IK",
                              hardware_id="hyperarm",
                              message=f"{self._stats['requests']} requests")
        st.values = [KeyValue(key=k, value=str(v)) for k, v in self._stats.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [st]
        self._diag.publish(msg)


def main(args: list[str] | None = None) -> None:
    run_node(IkServiceNode, args, parameters=PARAMETERS, robot_description=False)


if __name__ == "__main__":
    main()
