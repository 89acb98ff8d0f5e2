"""calibrate_camera: eye-to-hand calibration of the fixed camera on the running robot (or mock).

Moves the arm through ``--poses`` postures chosen to show the gripper's calibration target
to the camera (:mod:`hyperarm_perception.calibration_postures`: random within the limits,
seeded, collision-free, ordered by joint travel), each through ``arm_controller``'s
FollowJointTrajectory action (a move aborted for its path or goal tolerance is tried again
from where the arm stopped, twice at most, saying so); at each, once the arm has settled,
records tool0's pose
(FK of ``joint_states``) and the target's pose and covariance from ``detections``
(``marker_detector``);
then solves camera_link in the root frame (:func:`hyperarm_perception.handeye.calibrate_eye_to_hand`,
outliers dropped), prints the residuals and how far the description's camera is from the
result, and writes the extrinsics as YAML (the description's ``camera:`` format). Needs the
arm driver, ``arm_controller``, a camera and ``marker_detector`` running. Ctrl-C cancels the
motion and exits 130 without writing. Exit 1 on any failure, with the reason.
"""
from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

DEFAULT_OUTPUT = "camera_extrinsics.yaml"

#: a move aborted for its path or goal tolerance (FollowJointTrajectory's error codes -4, -5:
#: the arm fell behind, e.g. a stalled driver on a loaded computer) is tried again, from
#: where the arm stopped, this many times; any other failure ends the calibration
_RETRIES = 2
_RETRY_CODES = (-4, -5)

#: s after the settle within which a picture must show the target, else the posture is
#: skipped (a camera at 10 Hz with a detector behind it; more on a loaded computer)
_SEEN_WITHIN = 6.0


def _parser() -> argparse.ArgumentParser:
    from .calibration_postures import NOMINAL_TARGET

    ap = argparse.ArgumentParser(
        prog="calibrate_camera", description=__doc__.split("\n\n")[0],
        epilog="docs/perception.md (Hand-eye calibration) walks through it.")
    ap.add_argument("--poses", type=int, default=12, help="postures to visit (>= 3; default 12)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the postures' draw (default 0)")
    ap.add_argument("--target", default=NOMINAL_TARGET,
                    help="nominal 'x y z roll pitch yaw' (m, rad) of the target in tool0, to "
                         f"choose postures (the calibration estimates it; default "
                         f"'{NOMINAL_TARGET}')")
    ap.add_argument("--output", "-o", default=DEFAULT_OUTPUT,
                    help=f"YAML to write (default {DEFAULT_OUTPUT})")
    ap.add_argument("--speed", type=float, default=0.3,
                    help="fraction of the joints' velocity and acceleration limits the moves "
                         "peak at (default 0.3)")
    ap.add_argument("--path-tolerance", type=float, default=0.3,
                    help="rad each joint may fall behind its path before arm_controller aborts "
                         "the move (default 0.3: the path is collision-checked and a lagging "
                         "arm stays on it; arm_controller's own default is 0.1)")
    ap.add_argument("--settle", type=float, default=0.5,
                    help="s to wait after each move before using a detection (default 0.5)")
    ap.add_argument("--timeout", type=float, default=30.0,
                    help="s to wait for the robot's topics and the action server (default 30)")
    ap.add_argument("--description-out", metavar="PATH",
                    help="also write a copy of the description (--description, or the "
                         "packaged one) with the calibrated camera, for -p "
                         "description_file:=PATH on every node (task_node, tf_publisher)")
    ap.add_argument("--variant", default="arm", help="robot variant (default arm)")
    ap.add_argument("--description", help="robot YAML (default: the packaged one); its camera "
                    "is only used to choose postures")
    ap.add_argument("--workcell", help="work-cell YAML for the collision checks (default: "
                    "hyperarm_driver's config/workcell.yaml)")
    return ap


class _Listener:
    """The newest joint_states and the target's detections (an executor thread fills them)."""

    def __init__(self, node, target: str) -> None:
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import CameraInfo, JointState

        from hyperarm_description import contract
        from hyperarm_description.qos import qos_for
        from hyperarm_interfaces.msg import Detections

        self.lock = threading.Lock()
        self.joints: dict[str, float] = {}
        #: header stamp (s) of the newest joint_states: the robot's clock, which also stamps
        #: the images (the mock's simulated time on sim time)
        self.joints_stamp = -math.inf
        #: (stamp s, pose 4x4, covariance 6x6 or None) of the target
        self.detections: list[tuple[float, np.ndarray, np.ndarray | None]] = []
        self.info: CameraInfo | None = None
        self._target = target
        node.create_subscription(JointState, contract.JOINT_STATES, self._on_joints,
                                 qos_for(contract.JOINT_STATES))
        node.create_subscription(Detections, contract.DETECTIONS, self._on_detections,
                                 qos_for(contract.DETECTIONS))
        node.create_subscription(CameraInfo, "camera/camera_info", self._on_info,
                                 qos_profile_sensor_data)

    def _on_joints(self, msg) -> None:
        from hyperarm_description.freshness import stamp_seconds

        with self.lock:
            self.joints.update(zip(msg.name, (float(v) for v in msg.position)))
            self.joints_stamp = max(self.joints_stamp, stamp_seconds(msg.header.stamp))

    def _on_detections(self, msg) -> None:
        from hyperarm_description.freshness import stamp_seconds
        from hyperarm_ik.ros_conversions import pose_to_matrix

        cov = np.asarray(msg.covariances, dtype=float)
        per_pose = len(cov) == 36 * len(msg.poses) and np.all(np.isfinite(cov))
        for i, (name, pose) in enumerate(zip(msg.names, msg.poses)):
            if name == self._target:
                c = cov[36 * i:36 * i + 36].reshape(6, 6) if per_pose else None
                with self.lock:
                    self.detections.append((stamp_seconds(msg.header.stamp),
                                            pose_to_matrix(pose), c))

    def _on_info(self, msg) -> None:
        with self.lock:
            self.info = msg


def _wait(cond, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            raise RuntimeError(f"no {what} within {timeout:g} s")
        time.sleep(0.02)


def _yaml(result, desc, used: int, tried: int) -> str:
    import pinocchio as pin

    def xyz_rpy(T):
        return ([round(float(v), 6) for v in T[:3, 3]],
                [round(float(v), 6) for v in pin.rpy.matrixToRpy(T[:3, :3])])

    cam_xyz, cam_rpy = xyz_rpy(result.camera_pose)
    tgt_xyz, tgt_rpy = xyz_rpy(result.target_in_tool)
    s = result.summary()
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (f"# Written by calibrate_camera ({stamp}): {desc.camera.frame} in "
            f"{desc.base_frame if not desc.rail else 'world'} from {used} of {tried} postures.\n"
            f"# Paste the camera block into the robot description (hyperarm.yaml, camera:),\n"
            f"# or run with --description-out for a description file that has it.\n"
            f"camera:\n  frame: {desc.camera.frame}\n  xyz: {cam_xyz}\n  rpy: {cam_rpy}\n"
            f"target_in_tool0:\n  xyz: {tgt_xyz}\n  rpy: {tgt_rpy}\n"
            f"residuals:  # of the inliers: position in m, angle in rad\n"
            + "".join(f"  {k}: {float(v):.6g}\n" for k, v in s.items())
            + f"method: {result.method}\n")


def write_camera_copy(description: str | None, camera_pose: np.ndarray, out: str,
                      variant: str = "arm") -> Path:
    """A copy of the description YAML (``description``, None: the packaged one) whose
    ``camera`` xyz (m) and rpy (rad, 6 decimals) are ``camera_pose`` (4 x 4, camera_link in
    the root frame); checked by parsing it. Raises DescriptionError saying why."""
    import pinocchio as pin

    from hyperarm_description.model import DescriptionError, write_description_copy

    t = np.asarray(camera_pose, dtype=float)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise DescriptionError("the camera pose is not a finite 4 x 4 transform")
    xyz = [round(float(v), 6) for v in t[:3, 3]]
    rpy = [round(float(v), 6) for v in pin.rpy.matrixToRpy(t[:3, :3])]

    def edit(data: dict) -> None:
        data["camera"]["xyz"], data["camera"]["rpy"] = xyz, rpy

    header = ("# The robot description with the camera from calibrate_camera (m, rad).\n"
              "# Use it with -p description_file:=<this file> on every node.\n")
    return write_description_copy(description, out, edit, header, variant)


def _check_options(args: argparse.Namespace) -> np.ndarray:
    """The options' ranges, before anything heavy is imported (a typo is answered at once);
    returns the nominal target pose in tool0 (4 x 4). Raises ValueError naming the option."""
    from .calibration_postures import parse_pose

    if args.poses < 3:
        raise ValueError(f"--poses must be >= 3, got {args.poses}")
    if not 0.0 < args.speed <= 1.0:
        raise ValueError(f"--speed must be in (0, 1], got {args.speed}")
    if not 0.0 < args.path_tolerance <= 1.0:
        raise ValueError(f"--path-tolerance must be in (0, 1] rad, got {args.path_tolerance}")
    if not 0.0 <= args.settle <= 60.0 or not 0.0 < args.timeout <= 3600.0:
        raise ValueError(f"--settle must be in [0, 60] s and --timeout in (0, 3600] s, got "
                         f"{args.settle} and {args.timeout}")
    if args.description_out and args.description and \
            Path(args.description_out).resolve() == Path(args.description).resolve():
        raise ValueError("--description-out must be another file than --description")
    return parse_pose(args.target, "--target")


def run(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from hyperarm_control.client import TrajectoryClient, goal_from_points
    from hyperarm_description import contract
    from hyperarm_description.mjcf import camera_link_pose
    from hyperarm_description.model import load_description
    from hyperarm_description.world import load_world
    from hyperarm_ik.collision import CollisionModel
    from hyperarm_ik.kinematics import Kinematics

    from .calibration_postures import target_postures
    from .camera_input import camera_model
    from .handeye import calibrate_eye_to_hand
    from .markers import rotation_angle

    target_in_tool = _check_options(args)
    desc = load_description(args.description, args.variant)
    if args.workcell:
        cell = Path(args.workcell)
    else:
        from ament_index_python.packages import get_package_share_directory
        cell = Path(get_package_share_directory("hyperarm_driver")) / "config" / "workcell.yaml"
    world = load_world(cell)
    kin = Kinematics(desc)
    names = [j.name for j in desc.joints]
    limits = np.array([j.velocity for j in desc.joints])
    path_tolerance = {n: args.path_tolerance for n in names}
    accels = np.array([j.acceleration for j in desc.joints])

    # our handlers (main) raise KeyboardInterrupt; rclpy's own would shut the context down
    # and stop the executor before the cancel below could go out and be confirmed
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("calibrate_camera", namespace=contract.DEFAULT_NAMESPACE)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spin = threading.Thread(target=executor.spin, daemon=True)
    listen = _Listener(node, "calibration_target")
    client = TrajectoryClient(node)
    spin.start()
    sent = False
    try:
        _wait(lambda: all(n in listen.joints for n in names), args.timeout, "joint_states")
        _wait(client.server_ready, args.timeout, "arm_controller action server")
        _wait(lambda: listen.info is not None, args.timeout, "camera/camera_info")
        info = listen.info
        cam = camera_model(info.k, info.d, info.distortion_model, info.width, info.height)
        with listen.lock:
            start = np.array([listen.joints[n] for n in names])
        postures = target_postures(kin, CollisionModel(kin, world), cam, camera_link_pose(desc),
                                   target_in_tool, args.poses, start,
                                   np.random.default_rng(args.seed),
                                   table_height=world.table.height)
        tools, targets, covariances = [], [], []
        here = start
        for i, q in enumerate(postures, 1):
            for attempt in range(1 + _RETRIES):
                # the controller's rest-to-rest cubic peaks at 1.5 d/T in velocity and
                # 6 d/T^2 in acceleration: T keeps both within --speed of the limits
                step = np.abs(q - here)
                duration = max(1.0, float(np.max(1.5 * step / (args.speed * limits))),
                               float(np.max(np.sqrt(6.0 * step / (args.speed * accels)))))
                goal = goal_from_points(names, [duration], [q.tolist()],
                                        path_tolerance=path_tolerance)
                client.send(goal)      # from the executor's thread: no answer is lost
                sent = True
                if not client.wait(duration + args.timeout):
                    raise RuntimeError(f"posture {i}: the move did not end")
                status, result = client.result()
                if status == 4:
                    break
                reason = result.error_string if result is not None else "rejected"
                code = result.error_code if result is not None else 0
                if code not in _RETRY_CODES or attempt == _RETRIES:
                    raise RuntimeError(f"posture {i}: the move failed: {reason}")
                # off its path (a stall of the driver or the controller): again, from here
                print(f"posture {i}/{len(postures)}: the move was aborted ({reason}); "
                      "trying again from where the arm stopped", flush=True)
                time.sleep(args.settle)
                with listen.lock:
                    here = np.array([listen.joints[n] for n in names])
            here = q
            time.sleep(args.settle)
            with listen.lock:        # only pictures taken after the settle, on the robot's clock
                since = listen.joints_stamp
            try:
                _wait(lambda: any(d[0] >= since for d in listen.detections), _SEEN_WITHIN,
                      "detection of the target")
            except RuntimeError:
                print(f"posture {i}/{len(postures)}: target not seen, skipped", flush=True)
                continue
            with listen.lock:
                _, pose, cov = next(d for d in reversed(listen.detections) if d[0] >= since)
                q_now = np.array([listen.joints[n] for n in names])
            tools.append(kin.forward(q_now))
            targets.append(pose)
            covariances.append(cov)
            print(f"posture {i}/{len(postures)}: target at "
                  f"{np.round(pose[:3, 3], 4).tolist()} m in {desc.camera.frame}", flush=True)
        # the detector's covariances weigh each detection (its depth is the weak axis); a
        # detector that publishes none gets calibrate_eye_to_hand's isotropic default
        weights = covariances if all(c is not None for c in covariances) else None
        if weights is None:
            print("no covariances in the detections: weighing them all alike (the result "
                  "takes the detector's depth bias)", flush=True)
        result = calibrate_eye_to_hand(tools, targets, weights)
    finally:
        import signal

        for sig in (signal.SIGINT, signal.SIGTERM):    # a second signal must not skip this
            signal.signal(sig, signal.SIG_IGN)
        if sent and not client.done():     # a move under way (or its goal unanswered): stop it
            end = time.monotonic() + 1.0
            while client.accepted() is None and time.monotonic() < end:
                time.sleep(0.01)
            client.cancel()
            if not client.wait(2.0):
                print("calibrate_camera: the arm_controller did not confirm the cancel",
                      file=sys.stderr)
        executor.shutdown(timeout_sec=1.0)
        spin.join(timeout=2.0)
        node.destroy_node()
        rclpy.try_shutdown()
    nominal = camera_link_pose(desc)
    moved = 1e3 * float(np.linalg.norm(result.camera_pose[:3, 3] - nominal[:3, 3]))
    turned = math.degrees(rotation_angle(nominal[:3, :3].T @ result.camera_pose[:3, :3]))
    s = result.summary()
    used = int(np.count_nonzero(result.inliers))
    Path(args.output).write_text(_yaml(result, desc, used, len(postures)), encoding="utf-8")
    if args.description_out:
        write_camera_copy(args.description, result.camera_pose, args.description_out,
                          args.variant)
        print(f"wrote {args.description_out}: the description with this camera; use it with "
              f"--ros-args -p description_file:={args.description_out}")
    print(f"calibrated from {used} of {len(postures)} postures: "
          + ", ".join(f"{k} {v:.4g}" for k, v in s.items()))
    print(f"the description's camera is {moved:.1f} mm and {turned:.2f} deg from the "
          f"calibration; wrote {args.output}")
    return 0


def _interrupt(_signum, _frame) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    import signal

    # Ctrl-C and SIGTERM stop the motion (the goal is cancelled) and write nothing
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    args = _parser().parse_args(argv)
    try:
        _check_options(args)
        return run(args)
    except KeyboardInterrupt:
        print("calibrate_camera: interrupted; nothing written", file=sys.stderr)
        return 130
    except Exception as exc:    # every failure is a sentence, exit 1
        print(f"calibrate_camera: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
