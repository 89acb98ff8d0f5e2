"""hybrid_force_calibrate: fits each arm servo's torque scale and offset from static poses.

Drives the arm (position-only joint_command; run it with hybrid_force disabled and nothing
touching the arm) through ``poses`` postures around the present one, each approached from
both sides, averages the measured efforts at rest, fits them against the description's
gravity torques (hyperarm_control.force.calibration) and writes ``output_file``, the YAML that
hybrid_force loads with ``calibration_file``. Exits 0 when the file is written, 1 on error.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from rclpy.node import Node
from sensor_msgs.msg import JointState

from hyperarm_description.log_throttle import ReasonThrottle
from hyperarm_description import contract
from hyperarm_description.params import NonEmpty, ParamSpec, Range, declare_parameters
from hyperarm_description.qos import qos_for
from hyperarm_description.ros_main import declare_robot_description, run_node

from .force.calibration import (CalibrationError, CalibrationRun, calibration_poses,
                                fit_calibration, fit_friction, save_calibration)
from .force.law import GravityModel, Payload
from hyperarm_ik.collision import CollisionModel
from hyperarm_ik.kinematics import Kinematics
from hyperarm_ik.ros_conversions import JointStateInput

PARAMETERS: ParamSpec = {
    "output_file": ("", "path of the calibration YAML to write", NonEmpty()),
    "poses": (12, "number of static poses", Range(3, 100)),
    "spread": (0.6, "rad: each joint (but joint1) moves up to this from the present pose",
               Range(0.05, 1.5)),
    "seed": (0, "seed of the pose draw", Range(0, 2**31 - 1)),
    "min_tool_height": (-0.10, "m: poses with tool0 or any link's collision capsule below "
                        "this height (root z) are skipped",
                        Range(-10.0, 10.0)),
    "approach": (0.05, "rad: each pose is approached from this far on both sides",
                 Range(0.0, 0.5)),
    "settle": (0.5, "s at rest before averaging", Range(0.0, 10.0)),
    "average": (0.5, "s of efforts averaged per approach", Range(0.05, 10.0)),
    "timeout": (10.0, "s to reach a pose", Range(0.5, 120.0)),
    "payload_mass": (0.0, "kg held at tool0 during the calibration", Range(0.0, 10.0)),
}


class CalibrationNode(Node):
    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("namespace", contract.DEFAULT_NAMESPACE)
        super().__init__("hybrid_force_calibrate", **kwargs)
        self._log_throttle = ReasonThrottle(5.0)  # per reason, not per call site
        desc = declare_robot_description(self)
        self._p = declare_parameters(self, PARAMETERS)
        self._kin = Kinematics(desc)
        self._self = CollisionModel(self._kin, None)    # the arm's self-collisions
        self._cal_data = self._kin.model.createData()
        self._gravity = GravityModel(self._kin)
        self._payload = Payload(self._p["payload_mass"])
        self._arm = list(desc.arm_joint_names)
        self._arm_idx = [self._kin.joint_names.index(n) for n in self._arm]
        self._input = JointStateInput(self.get_logger(), self._log_throttle)
        self._cache = self._input.cache
        self._run: CalibrationRun | None = None
        self._cmd = self.create_publisher(JointState, contract.JOINT_COMMAND,
                                          qos_for(contract.JOINT_COMMAND))
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_states,
                                 qos_for(contract.JOINT_STATES))
        self.get_logger().info(f"hybrid_force_calibrate: {self._p['poses']} poses -> "
                               f"{self._p['output_file']}; waiting for joint_states")

    def _on_states(self, msg: JointState) -> None:
        names = self._kin.joint_names
        if not self._input.merge(msg) or not self._input.ready(names, self._arm):
            return
        q = self._cache.positions(names)
        qa = q[self._arm_idx]
        effort = np.array([self._cache.effort[n] for n in self._arm])
        velocity = np.array([self._cache.velocity.get(n, 0.0) for n in self._arm])
        now = self.get_clock().now().nanoseconds * 1e-9
        try:
            if self._run is None:
                self._run = self._start(q)
            goal = self._run.step(now, qa, effort, velocity)
        except CalibrationError as exc:
            raise SystemExit(f"hybrid_force_calibrate: {exc}") from None
        if goal is not None:
            out = JointState(name=self._arm, position=[float(v) for v in goal])
            self._cmd.publish(out)
        elif self._run.done:
            self._finish(q)

    def _lowest_link(self, q: np.ndarray) -> float:
        """The lowest point (root z, m) of the links' collision capsules at q (a link on the
        table would stall a servo there: the contact, not gravity, in its effort)."""
        model, data = self._kin.model, self._cal_data
        pin.framesForwardKinematics(model, data, q)
        low = math.inf
        for cap in self._kin.desc.capsules:
            m = data.oMf[model.getFrameId(cap.frame)]
            for end in cap.endpoints():
                low = min(low, float((m.rotation @ end + m.translation)[2]) - cap.radius)
        return low

    def _start(self, q: np.ndarray) -> CalibrationRun:
        p = self._p
        arm = self._arm_idx
        poses = calibration_poses(self._kin.lower[arm], self._kin.upper[arm], q[arm],
                                  4 * p["poses"], p["spread"], p["seed"])
        keep = []
        shift = np.r_[0.0, np.full(len(arm) - 1, p["approach"])]   # the approach points
        for pose in poses:
            full = q.copy()
            full[arm] = pose
            if self._kin.forward(full)[2, 3] < p["min_tool_height"] \
                    or self._lowest_link(full) < p["min_tool_height"]:
                continue
            # the arm must not touch itself at the pose or its approach points (it would
            # stall there: the servos' friction and the contact, not gravity, in the efforts)
            ends = [full.copy(), full.copy()]
            ends[0][arm] += shift
            ends[1][arm] -= shift
            if any(self._self.in_collision(c) for c in [full, *ends]):
                continue
            keep.append(pose)
            if len(keep) == p["poses"]:
                break
        if len(keep) < 3:
            raise CalibrationError("fewer than 3 poses keep the tool above min_tool_height "
                                   "with the arm clear of itself")
        self.get_logger().info(f"calibrating over {len(keep)} poses")
        return CalibrationRun(np.array(keep), p["approach"], p["settle"], p["average"],
                              timeout=p["timeout"])

    def _finish(self, q: np.ndarray) -> None:
        run = self._run
        model = []
        for qa in run.q_at:
            full = q.copy()
            full[self._arm_idx] = qa
            model.append(self._gravity.torques(full, self._payload)[self._arm_idx])
        model = np.array(model)
        measured = run.efforts()
        cal = fit_calibration(self._arm, model, measured)
        # Coulomb friction from the moves between the poses (against the full dynamics:
        # inertia while speeding up and slowing down would hide it)
        qs, vs, acc, es = run.moving_samples()
        if len(qs):
            def chain(x: np.ndarray, rest: np.ndarray) -> np.ndarray:   # arm -> chain rows
                out = np.repeat(rest[None, :], len(x), axis=0)
                out[:, self._arm_idx] = x
                return out
            still = np.zeros_like(q)                  # the rail (if any) at rest
            tm = np.array([self._gravity.inverse_dynamics(a, b, c, self._payload)[
                self._arm_idx] for a, b, c in zip(chain(qs, q), chain(vs, still),
                                                  chain(acc, still))])
            cal = fit_friction(cal, self._arm, tm, es, vs)
        save_calibration(cal, self._p["output_file"])
        before = float(np.sqrt(np.mean((measured - model) ** 2)))
        after = float(np.sqrt(np.mean((cal.correct(self._arm, measured) - model) ** 2)))
        fitted = ", ".join(f"{n} x{c.scale:.3f} {c.offset:+.3f}" + ("" if c.identified else "*")
                           + f" friction {c.friction:.3f}" for n, c in cal.joints.items())
        self.get_logger().info(f"wrote {self._p['output_file']}: torque RMS error "
                               f"{before:.4f} -> {after:.4f} N·m; {fitted} (* offset only)")
        raise SystemExit(0)


def main(args: list[str] | None = None) -> None:
    run_node(CalibrationNode, args, parameters=PARAMETERS)


if __name__ == "__main__":
    main()
