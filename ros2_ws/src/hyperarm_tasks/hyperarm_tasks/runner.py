"""Runs a task's steps against a robot interface (no ROS): the sequencing, motion
streaming, detections, grasp monitoring, retries, cancel and failure handling.

The task node implements :class:`Robot` over ROS topics and services; tests implement it
over the mock's simulation directly. Units: m, rad, s, N, N·m. Poses are 4x4 matrices in
the robot's root frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Protocol, Sequence

import numpy as np
import pinocchio as pin

from hyperarm_description.limits import limit_step
from hyperarm_ik.collision import CollisionModel
from hyperarm_ik.kinematics import Kinematics
from hyperarm_ik.solvers import make_solver

from .errors import Cancelled, StepFailed
from .perception import DOWN, DetectionBuffer, Estimate
from .sequence import Task
from .steps import STALE_STATES, STEP_TYPES, PoseSpec, Step
from .tracking import PathClock

__all__ = ["Robot", "HybridCommand", "Feedback", "RunResult", "RunnerParams", "Runner",
           "Located"]


@dataclass(frozen=True)
class HybridCommand:
    """A hybrid position/force goal for the force node (HybridGoal, root frame):
    ``xyz``/``rotation`` the pseudo-goal pose of tool0, ``stiffness`` (N/m x3, N·m/rad x3),
    ``force_axes`` (x y z rx ry rz force-controlled), ``wrench`` (N, N·m)."""

    xyz: np.ndarray
    rotation: np.ndarray
    stiffness: tuple[float, ...]
    force_axes: tuple[bool, ...]
    wrench: tuple[float, ...]


class Robot(Protocol):
    """What the runner needs from the robot. Every method returns promptly."""

    detections: DetectionBuffer

    def now(self) -> float: ...                       # s, the clock detections are stamped on
    def sleep(self, seconds: float) -> None: ...
    def cancel_requested(self) -> bool: ...
    def joint_positions(self) -> dict[str, float]: ...
    def joint_efforts(self) -> dict[str, float]: ...
    def joint_states_age(self) -> float: ...          # s since the last joint_states arrived
    def command(self, positions: Mapping[str, float],
                efforts: Mapping[str, float] | None = None) -> None: ...
    def hold(self) -> str | None: ...                 # None = done, else the reason
    def fault(self, joints: Sequence[str]) -> str | None: ...   # a driver's refusal reason
    def given_object(self, name: str) -> np.ndarray | None: ...  # pose from the goal
    def wrench(self) -> np.ndarray | None: ...        # (6,) at tool0, N and N·m, or None
    def force_available(self) -> bool: ...
    def set_force_control(self, enabled: bool) -> str | None: ...
    def send_hybrid(self, goal: HybridCommand) -> None: ...
    def force_passive(self) -> tuple[str, str] | None: ...   # went passive: (kind, reason)
    def home_rail(self) -> str | None: ...
    def rail_homed(self) -> bool | None: ...
    def log(self, level: str, message: str) -> None: ...   # "info", "warn", "error"


@dataclass
class Feedback:
    step: str = ""
    phase: str = ""
    index: int = 0
    count: int = 0
    progress: float = 0.0               # 0..1 over the whole task
    step_progress: float = 0.0          # 0..1 within the step
    waypoint: np.ndarray = field(default_factory=lambda: np.zeros(3))   # m, tool0 target
    force: float = 0.0                  # N, measured force along z at tool (0 if unknown)
    depth: float = 0.0                  # m, insertion depth (force_insert)


@dataclass(frozen=True)
class Located:
    """Where the camera last located an object: ``pose`` (4x4, root frame) from sightings
    whose newest was exposed at ``stamp`` (s, the robot's clock)."""

    stamp: float
    pose: np.ndarray


@dataclass
class RunResult:
    success: bool
    message: str
    failure_kind: str = ""
    step_names: list[str] = field(default_factory=list)
    step_durations: list[float] = field(default_factory=list)
    total_time: float = 0.0
    metrics: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class RunnerParams:
    """Tunables (the node's parameters)."""

    command_rate: float = 50.0          # Hz, joint goals streamed
    detection_frames: int = 5           # frames averaged per estimate
    detection_max_age: float = 1.0      # s, older sightings are stale
    detection_timeout: float = 3.0      # s, waiting for fresh sightings
    detection_outlier: float = 0.01     # m, from the median
    # s: an object the camera located and the arm has not touched since keeps that pose this
    # long while the camera cannot see it (the arm hides it); 0: only fresh sightings count
    located_max_age: float = 60.0
    solver: str = ""                    # IK solver ("" = default)
    joint_tolerance: float = 0.01       # rad, joint-space goal reached
    grasp_min_position: float = 0.05    # rad, gripper closed further = nothing held
    grasp_min_effort_ratio: float = 0.5  # |effort| >= ratio * commanded effort = holding

    def __post_init__(self) -> None:
        if not 1.0 <= self.command_rate <= 500.0:
            raise ValueError(f"command_rate {self.command_rate} not within 1..500 Hz")
        if self.detection_frames < 1:
            raise ValueError("detection_frames must be >= 1")
        for name in ("detection_max_age", "detection_timeout", "detection_outlier",
                     "joint_tolerance", "grasp_min_position"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0")
        if not self.located_max_age >= 0.0:
            raise ValueError("located_max_age must be >= 0")


MOVED_SIGHTINGS = 2   # newer sightings away from a located pose that say the object moved
TOUCH_RADIUS = 0.04   # m: fingers closing on or releasing what is this near tool0 move it
                      # (the block's centre is 6.5 cm from its peg's top on the table)
STATE_WAIT = 5.0   # s: at a task's start, wait this long for the first joint_states
STREAM_STALL_LIMIT = 5.0   # s of stale joint_states that fail a streamed move (kind driver)
TURN_FROM = 0.3   # a move_to line turns the tool over its last 70 % (plan_line)


def min_jerk(tau: float) -> float:
    """Min-jerk time scaling s(tau) on [0, 1] (peak rate 1.875)."""
    t = min(max(tau, 0.0), 1.0)
    return t * t * t * (10.0 - 15.0 * t + 6.0 * t * t)


class Runner:
    """Runs one task. ``on_feedback`` is called at every streamed command."""

    def __init__(self, robot: Robot, kin: Kinematics, task: Task,
                 params: RunnerParams | None = None,
                 on_feedback: Callable[[Feedback], None] | None = None,
                 collisions: CollisionModel | None = None) -> None:
        self.robot, self.kin, self.task = robot, kin, task
        # the IK library's collision model (self-collisions and the work cell): every planned
        # joint path is checked before it is sent (None: not checked)
        self.collisions = collisions
        self.params = params or RunnerParams()
        self.period = 1.0 / self.params.command_rate
        self.desc = kin.desc
        self.solver = make_solver(self.params.solver, kin)
        if collisions is not None:
            self.solver.use_collision_model(collisions)
        self.on_feedback = on_feedback or (lambda fb: None)
        self.fb = Feedback(count=len(task.steps))
        self.step: Step | None = None
        self.attempt = 0                    # retries of the current step so far
        self.holding: float | None = None   # grip effort while a grasp is held
        self.tool_target: np.ndarray | None = None   # last commanded tool0 pose
        self.q_target: np.ndarray | None = None      # last commanded chain joints
        self.force_on = False
        self.metrics: dict[str, float] = {}
        # the last joint_command sent, per joint: the step limiter's reference (forgotten
        # when something else moves the arm: a hold, force control)
        self.last_sent: dict[str, float] = {}
        self.commanded = False              # any joint_command or force control yet
        # objects the camera located and the arm has not touched since (see object_pose);
        # when the fingers last closed on or released each touched object (robot clock, s);
        # the objects a held grasp holds (never located while held)
        self.located: dict[str, Located] = {}
        self.touched_at: dict[str, float] = {}
        self.held_objects: set[str] = set()
        self._limits = {j.name: (j.lower, j.upper, j.velocity) for j in self.desc.joints}
        if self.desc.rail is not None:
            r = self.desc.rail
            self._limits[r.name] = (r.lower, r.upper, r.velocity)

    # --- state ---------------------------------------------------------------------------
    @property
    def chain(self) -> list[str]:
        return self.kin.joint_names

    def q_measured(self) -> np.ndarray:
        pos = self.robot.joint_positions()
        missing = [n for n in self.chain if n not in pos]
        if missing:
            raise StepFailed("driver", f"driver not ready: no joint_states for "
                                       f"{', '.join(missing)}")
        return np.array([pos[n] for n in self.chain])

    def tool_measured(self) -> np.ndarray:
        return self.kin.forward(self.q_measured())

    def tool_reference(self) -> np.ndarray:
        """The last commanded tool pose, else the measured one."""
        return self.tool_target.copy() if self.tool_target is not None else self.tool_measured()

    # --- the loop's heartbeat --------------------------------------------------------------
    def feedback(self, phase: str, step_progress: float, waypoint=None, depth: float = 0.0):
        fb = self.fb
        fb.phase, fb.step_progress = phase, float(min(max(step_progress, 0.0), 1.0))
        fb.progress = (fb.index + fb.step_progress) / max(fb.count, 1)
        if waypoint is not None:
            fb.waypoint = np.asarray(waypoint, dtype=float)[:3].copy()
        # the contact force while force control runs (asking for it otherwise costs the
        # task node a 100 Hz subscription: RosRobot.wrench)
        w = self.robot.wrench() if self.force_on else None
        fb.force = float(w[2]) if w is not None else 0.0
        fb.depth = depth
        self.on_feedback(fb)

    def tick(self, joints: Sequence[str] = ()) -> None:
        """Sleep one period; raise Cancelled, or StepFailed for a driver fault on
        ``joints`` or a lost grasp."""
        self.robot.sleep(self.period)
        if self.robot.cancel_requested():
            raise Cancelled(f"cancelled during {self.step.name if self.step else '?'}")
        if joints:
            reason = self.robot.fault(joints)
            if reason:
                raise StepFailed("driver", f"driver refused: {reason}")
        if self.holding is not None:
            self.check_holding()

    def check_holding(self) -> None:
        g = self.desc.gripper.name
        pos = self.robot.joint_positions().get(g, 0.0)
        eff = abs(self.robot.joint_efforts().get(g, 0.0))
        p = self.params
        if pos < p.grasp_min_position or eff < p.grasp_min_effort_ratio * self.holding:
            self.release_grasp()     # dropped: where it fell is for the camera to say
            raise StepFailed("grasp_lost", f"grasp lost: gripper at {pos:.3f} rad (empty below "
                             f"{p.grasp_min_position:g}), effort {eff:.2f} N·m")

    # --- objects and poses -----------------------------------------------------------------
    def detect(self, name: str, timeout: float | None = None,
               since: float | None = None, frames: int | None = None) -> Estimate:
        """Averaged fresh sightings of ``name`` (taken after ``since``, if given: the object
        has moved; and after the gripper last closed or opened near it), waited for up to
        ``timeout`` s. Locates the object (:attr:`located`) unless it is held."""
        p = self.params
        timeout = p.detection_timeout if timeout is None else timeout
        t0 = self.robot.now()
        since = self._since(name, since)
        while True:
            est = self._fresh(name, self.robot.now(), since, frames)
            if est is not None:
                self._locate(name, est)
                return est
            if self.robot.now() - t0 > timeout:
                newest = self.robot.detections.newest(name)
                if newest is None:
                    raise StepFailed("detection", f"object {name!r} not seen by the camera "
                                                  f"in {timeout:g} s")
                age = self.robot.now() - newest.stamp
                raise StepFailed("detection", f"detections of {name!r} are stale: the newest "
                                 f"is {age:.1f} s old (max {p.detection_max_age:g} s), waited "
                                 f"{timeout:g} s")
            self.tick()

    def _fresh(self, name: str, now: float, since: float | None,
               frames: int | None = None) -> Estimate | None:
        """The average of the newest ``frames`` (``detection_frames``) sightings of ``name``
        fresh at ``now`` and taken after ``since`` (None if too few)."""
        p = self.params
        n = frames or p.detection_frames
        return self.robot.detections.estimate(name, now, n, max(p.detection_max_age, 0.15 * n),
                                              p.detection_outlier, since)

    def _since(self, name: str, since: float | None) -> float | None:
        touched = self.touched_at.get(name)
        if touched is None:
            return since
        return touched if since is None else max(since, touched)

    def _locate(self, name: str, est: Estimate) -> None:
        if name not in self.held_objects:
            self.located[name] = Located(est.stamp, est.pose.copy())

    def object_pose(self, name: str) -> np.ndarray:
        """``name``'s pose: given with the goal; else the camera's fresh sightings (a
        ``detection_frames`` average) if it has them now; else, for an object the camera
        located (a ``locate`` step, or an earlier estimate) at most ``located_max_age`` s
        ago, not held, with no gripper closing on or releasing it since (:meth:`touch`) and
        not seen since elsewhere (:data:`MOVED_SIGHTINGS` newer sightings or more, whose
        median lies farther than ``detection_outlier`` from it: a moved object), while the
        camera sees other objects (a camera that sees nothing is failing, not hidden), where
        it was located (logged: the arm hides it); else fresh sightings waited for as
        :meth:`detect` does (failing kind "detection")."""
        given = self.robot.given_object(name)
        if given is not None:
            return np.asarray(given, dtype=float)
        p = self.params
        now = self.robot.now()
        est = self._fresh(name, now, self._since(name, None))
        if est is not None:
            self._locate(name, est)
            return est.pose
        loc = self.located.get(name)
        blind = now - self.robot.detections.last_seen_any > p.detection_max_age
        if loc is not None and blind:
            # the camera sees nothing at all now: it is failing, not hidden by the arm
            self.robot.log("warn", f"{name} not in view now and the camera has seen no "
                           f"object for more than detection_max_age "
                           f"({p.detection_max_age:g} s): not using where it was located")
        elif (loc is not None and p.located_max_age > 0.0
                and now - loc.stamp <= p.located_max_age and name not in self.held_objects):
            newer = self.robot.detections.since(name, loc.stamp)
            far = [float(np.linalg.norm(s.pose[:3, 3] - loc.pose[:3, 3])) for s in newer]
            # moved: at least MOVED_SIGHTINGS newer sightings whose median lies farther than
            # detection_outlier from it (one stray sighting, e.g. a marker half under the
            # hand, is not evidence: it failed 1 soak cycle in 10)
            moved = len(far) >= MOVED_SIGHTINGS and float(np.median(far)) > p.detection_outlier
            if not moved:
                xyz = ", ".join(f"{v:.3f}" for v in loc.pose[:3, 3])
                self.robot.log("info", f"{name} not in view now: using where the camera "
                               f"located it {now - loc.stamp:.1f} s ago, ({xyz}) m (untouched "
                               f"since; located_max_age {p.located_max_age:g} s)")
                self.metrics["located_used"] = self.metrics.get("located_used", 0.0) + 1.0
                return loc.pose.copy()
            self.robot.log("info", f"{name}: seen {len(far)} time(s) since it was located, "
                           f"{float(np.median(far)) * 1000:.0f} mm from there (median; more "
                           f"than detection_outlier {p.detection_outlier * 1000:g} mm): "
                           f"waiting for fresh sightings")
        return self.detect(name).pose

    def touch(self, xyz: np.ndarray | None, radius: float = TOUCH_RADIUS) -> list[str]:
        """The fingers close on, or release, what is at ``xyz`` (m, root frame; None: the
        tool's position is unknown, every located object counts): every located object
        within ``radius`` of it may move now, so its located pose is forgotten, and only
        sightings taken from now on place it again. Returns the names forgotten."""
        if xyz is None:
            gone = list(self.located)
        else:
            xyz = np.asarray(xyz, dtype=float)
            gone = [n for n, loc in self.located.items()
                    if float(np.linalg.norm(loc.pose[:3, 3] - xyz)) <= radius]
        now = self.robot.now()
        for n in gone:
            del self.located[n]
            self.touched_at[n] = now
        return gone

    def resolve(self, spec: PoseSpec) -> np.ndarray:
        """The 4x4 tool0 target of ``spec`` in the root frame."""
        if spec.relative_to == "tool":
            base = self.tool_reference()
        elif spec.relative_to in self.task.frames:
            base = np.eye(4)
            base[:3, 3] = self.task.frames[spec.relative_to]
        elif spec.relative_to == self.desc.root_frame:
            base = np.eye(4)
        else:
            base = self.object_pose(spec.relative_to)
        out = np.eye(4)
        out[:3, 3] = base[:3, 3] + np.asarray(spec.offset)
        out[:3, :3] = DOWN if spec.orientation == "down" else self.tool_reference()[:3, :3]
        return out

    def check_targets(self) -> None:
        """Before the first motion: every step's target that is known now (relative to the
        root frame, a task frame, a given object or one the camera sees now; not the
        tool-relative ones, which depend on the run) must lie within the arm's reach bound
        (hyperarm_ik's ``reach_excess``: a certain refusal, with the distance beyond it) and
        have an IK solution (two seeds).
        StepFailed("unreachable") names the step, its target and the point (m)."""
        seeds = [self.q_measured(), np.zeros(len(self.chain))]
        for step in self.task.steps:
            spec = getattr(step, "target", None)
            if not isinstance(spec, PoseSpec) or spec.relative_to == "tool":
                continue
            try:
                target = self.resolve(spec)
            except StepFailed as exc:        # an object not seen yet: checked when reached
                self.robot.log("info", f"target of {step.name} ({spec.describe()}) not "
                                       f"checked before the start: {exc}")
                continue
            p = target[:3, 3]
            where = (f"target of step '{step.name}' ({spec.describe()}) at "
                     f"({', '.join(f'{v:.3f}' for v in p)}) m")
            excess = self.kin.reach_excess(p)
            if excess > 0.0:
                raise StepFailed("unreachable", f"{where} is {excess:.3f} m beyond the arm's "
                                 f"workspace (reach {self.kin.reach:.3f} m from the shoulder)")
            res = None
            for seed in seeds:
                if self.robot.cancel_requested():
                    raise Cancelled(f"cancelled before {self.task.steps[0].name}")
                # collisions are not asked here: the capsules flag the shipped task's own
                # postures (docs/tasks.md); each planned path is checked before it is sent
                res = self.solver.solve(p, target[:3, :3], seed, position_tolerance=1e-4,
                                        orientation_tolerance=1e-3, timeout=0.3, clock="cpu")
                if res.success:
                    break
            if not res.success:
                raise StepFailed("unreachable", f"{where}: no IK solution within the workspace "
                                 f"({-excess:.3f} m inside the reach bound): {res.message}")

    # --- IK and motion ---------------------------------------------------------------------
    def ik(self, pose: np.ndarray, seed: np.ndarray, collisions: str = "avoid"):
        """IK for ``pose`` from ``seed``; ``collisions`` ("avoid", "ignore") applies when
        the runner has a collision model. The 0.1 s timeout counts this thread's CPU time:
        a plan does not depend on how busy the machine is (a waypoint's solve cut by its
        deadline sends the move to joint space: reproduced with a 0.1 ms deadline)."""
        mode = collisions if self.collisions is not None else "ignore"
        return self.solver.solve(pose[:3, 3], pose[:3, :3], seed, position_tolerance=1e-4,
                                 orientation_tolerance=1e-3, timeout=0.1, collisions=mode,
                                 held=self.holding is not None, clock="cpu")

    def plan_line(self, target: np.ndarray, spacing: float, allow_fallback: bool,
                  label: str) -> tuple[list[np.ndarray], np.ndarray]:
        """Joint waypoints along a straight tool line to ``target`` (IK at every
        interpolated point); on an intermediate failure, a joint-space line if allowed."""
        start = self.tool_reference()
        q = self.q_target if self.q_target is not None else self.q_measured()
        a, b = start[:3, 3], target[:3, 3]
        n = max(1, int(math.ceil(float(np.linalg.norm(b - a)) / spacing)))
        qs = [q.copy()]
        # orientation: slerped over the last 70 % of the line, eased in and out (smoothstep
        # 3u^2 - 2u^3: no turn rate at either end). From the stretched, singular ready pose a
        # turn about the arm's own axis (ready -> "down" is a half turn about x) is outside
        # the Jacobian's range: the arm must bend (come in) before it can turn. Slerped at a
        # uniform rate along the whole line, every block transfer's first move fell back to
        # joint space (issue 24 item 6), and 16 of 20 random first moves from ready; eased
        # over the whole line 10 of 20; turned over the last 70 % 2 of 20 (test_runner_sim).
        turn = pin.log3(target[:3, :3] @ start[:3, :3].T)
        for k in range(1, n + 1):
            pose = target.copy()
            pose[:3, 3] = a + (b - a) * k / n
            u = min(max((k / n - TURN_FROM) / (1.0 - TURN_FROM), 0.0), 1.0)
            pose[:3, :3] = pin.exp3(turn * (u * u * (3.0 - 2.0 * u))) @ start[:3, :3]
            res = self.ik(pose, qs[-1])
            if not res.success:
                final = self.ik(target, qs[-1] if k == n else q)
                where = (f"IK failed for {label} at waypoint {k}/{n} "
                         f"({', '.join(f'{v:.3f}' for v in pose[:3, 3])}) m: {res.message}")
                if k < n and final.success and allow_fallback:
                    self.robot.log("warn", f"{where}; falling back to a joint-space move")
                    self.check_collisions(label, q, final.q)
                    return [q, final.q], target
                raise StepFailed("collision" if res.contacts else "ik", where)
            qs.append(res.q)
        self.check_collisions(label, *qs)
        return qs, target

    def check_collisions(self, label: str, *qs: np.ndarray) -> None:
        """StepFailed("collision") if the joint path through ``qs`` (straight joint-space
        segments between them, sampled every 0.02 rad) hits the arm itself or the work cell
        (the held block included while a grasp is held). Nothing is sent before the check."""
        if self.collisions is None or len(qs) == 0:
            return
        held = self.holding is not None
        segments = list(zip(qs[:-1], qs[1:])) or [(qs[0], qs[0])]
        for k, (a, b) in enumerate(segments):
            chk = self.collisions.check_path(a, b, held=held)
            if not chk.free:
                raise StepFailed("collision", f"{label}: the planned path would collide "
                                 f"(segment {k + 1}/{len(segments)}): {chk.message}")

    def stream(self, qs: list[np.ndarray], duration: float, phase: str,
               efforts: Mapping[str, float] | None = None, waypoints=None) -> None:
        """Stream the joint path ``qs`` over ``duration`` s (min-jerk in path parameter), on
        a :class:`PathClock`: a late tick slows it down and a stall of the driver (stale
        joint_states) holds it, taken back to the driver's last joint_states, so a stall
        never makes the goal jump along the path."""
        names = self.chain
        m = len(qs) - 1
        clock = PathClock(self.robot.now(), duration, self.period, STALE_STATES)
        while True:
            t = clock.tick(self.robot.now(), self.robot.joint_states_age())
            if clock.stalled_for > STREAM_STALL_LIMIT:
                raise StepFailed("driver", f"no joint_states for {clock.stalled_for:.1f} s "
                                 f"while {phase} (the driver stalled or stopped): the path "
                                 "was held where the driver last reported")
            s = min_jerk(t / duration) if duration > 0 else 1.0
            x = s * m
            i = min(int(x), m - 1) if m > 0 else 0
            q = qs[i] + (qs[min(i + 1, m)] - qs[i]) * (x - i) if m > 0 else qs[0]
            self.send(names, q, efforts)
            wp = None
            if waypoints is not None:
                wp = waypoints[0] + (waypoints[1] - waypoints[0]) * s
            self.feedback(phase, 0.9 * s, wp)
            if t >= duration:
                return
            self.tick(names)

    def send(self, names: Sequence[str], q: np.ndarray,
             efforts: Mapping[str, float] | None = None) -> None:
        if self.force_on:
            raise RuntimeError("joint_command while force control is enabled")  # a bug
        self.command(dict(zip(names, (float(v) for v in q))), efforts)
        self.q_target = np.asarray(q, dtype=float).copy()

    def command(self, positions: Mapping[str, float],
                efforts: Mapping[str, float] | None = None) -> dict[str, float]:
        """Send one joint_command (rad, m; efforts N·m, N) with the step limiter applied
        last (issue 24): no arm or rail joint steps further in one cycle than its velocity
        limit × the period, nor leaves its limits, measured from the last command sent or,
        when none is known (the start, after a hold or force control), the measured
        position. The gripper's goals are not limited: an open or a close is one goal
        past the object with an effort limit (the squeeze), which the servo's profile
        moves and its current limit bounds. Returns what was sent."""
        names = list(positions)
        measured = self.robot.joint_positions()
        sent = {n: float(positions[n]) for n in names}
        arm = [n for n in names if n != self.desc.gripper.name]
        if arm:
            q = np.array([sent[n] for n in arm])
            prev = np.array([self.last_sent.get(n, measured.get(n, sent[n])) for n in arm])
            lim = np.array([self._limits[n] for n in arm])
            sent.update(zip(arm, limit_step(q, prev, lim[:, 2], self.period, lim[:, 0],
                                            lim[:, 1]).tolist()))
        self.robot.command(sent, efforts)
        self.commanded = True
        self.last_sent.update(sent)
        return sent

    def path_duration(self, qs: list[np.ndarray], length: float, speed: float) -> float:
        vmax = np.array([0.5 * (self.desc.rail.velocity if self.desc.rail and n == self.desc.rail.name
                                else self._vel(n)) for n in self.chain])
        dq = np.abs(np.diff(np.array(qs), axis=0)).sum(axis=0) if len(qs) > 1 else np.zeros(1)
        joint_t = float(np.max(dq / vmax)) if len(qs) > 1 else 0.0
        return 1.875 * max(length / speed, joint_t, 0.2)

    def _vel(self, name: str) -> float:
        for j in self.desc.joints:
            if j.name == name:
                return j.velocity
        return 1.0

    def move_line(self, target: np.ndarray, speed: float, spacing: float, tolerance: float,
                  timeout: float, allow_fallback: bool, label: str,
                  efforts: Mapping[str, float] | None = None) -> None:
        """Cartesian straight line to ``target`` at ``speed`` (peak), then settle within
        ``tolerance`` (m, measured tool position) or fail after ``timeout``."""
        t_start = self.robot.now()
        start = self.tool_reference()
        qs, target = self.plan_line(target, spacing, allow_fallback, label)
        length = float(np.linalg.norm(target[:3, 3] - start[:3, 3]))
        duration = self.path_duration(qs, length, speed)
        if duration > timeout:
            raise StepFailed("timeout", f"{label}: the move needs {duration:.1f} s at "
                             f"{speed:g} m/s, more than the step's timeout {timeout:g} s")
        self.stream(qs, duration, "moving", efforts, (start[:3, 3], target[:3, 3]))
        self.tool_target = target.copy()
        self.settle(target, tolerance, t_start + timeout, label)

    def settle(self, target: np.ndarray, tolerance: float, deadline: float, label: str) -> None:
        while True:
            err = float(np.linalg.norm(self.tool_measured()[:3, 3] - target[:3, 3]))
            if err <= tolerance:
                return
            if self.robot.now() > deadline:
                reason = self.robot.fault(self.chain)
                raise StepFailed("driver" if reason else "timeout",
                                 f"{label}: tool did not reach its target (still "
                                 f"{err * 1000:.1f} mm away, tolerance {tolerance * 1000:.1f} mm)"
                                 + (f": {reason}" if reason else ""))
            self.feedback("settling", 0.95, target[:3, 3])
            self.tick(self.chain)

    def move_joint_goal(self, goal: Mapping[str, float], tolerance: float, timeout: float,
                        efforts: Mapping[str, float] | None = None, phase: str = "moving",
                        settle_on_stop: bool = False) -> None:
        """Command ``goal`` (by name) until every joint is within ``tolerance`` (or, with
        ``settle_on_stop``, has stopped moving); StepFailed after ``timeout``."""
        names = list(goal)
        reason = self.robot.fault(names)
        if reason:
            raise StepFailed("driver", f"driver refused: {reason}")
        chain_goal = [goal.get(n) for n in self.chain]
        if self.collisions is not None and all(v is not None for v in chain_goal):
            self.check_collisions(f"{self.step.name if self.step else 'move'} (joint goal)",
                                  self.q_measured(), np.array(chain_goal, dtype=float))
        t0 = self.robot.now()
        last, last_t, still_for = None, t0, 0.0
        while True:
            self.command(goal, efforts)
            pos = self.robot.joint_positions()
            missing = [n for n in names if n not in pos]
            if missing:
                err = math.inf
            else:
                err = max(abs(pos[n] - v) for n, v in goal.items())
            if err <= tolerance:
                break
            if settle_on_stop and not missing:
                # stopped: 0.3 s without moving, counted only while joint_states are fresh
                # (a stalled stream looks still: no evidence; a late one does not restart
                # the count either)
                now, now_t = np.array([pos[n] for n in names]), self.robot.now()
                if last is not None and np.max(np.abs(now - last)) >= 2e-4:
                    still_for = 0.0
                elif last is not None and self.robot.joint_states_age() <= STALE_STATES:
                    still_for += now_t - last_t
                last, last_t = now, now_t
                if still_for > 0.3:
                    break
            elapsed = self.robot.now() - t0
            if elapsed > timeout:
                why = (f"no joint_states for {', '.join(missing)}" if missing else
                       self.robot.fault(names) or f"still {err:.3f} away (tolerance {tolerance:g})")
                raise StepFailed("driver" if missing or self.robot.fault(names) else "timeout",
                                 f"joints did not reach the goal in {timeout:g} s ({why})")
            self.feedback(phase, min(elapsed / timeout, 0.99))
            self.tick(names)
        chain_goal = [goal.get(n) for n in self.chain]
        if all(v is not None for v in chain_goal):
            self.q_target = np.array(chain_goal, dtype=float)
            self.tool_target = self.kin.forward(self.q_target)

    # --- force control ---------------------------------------------------------------------
    def force_off(self) -> None:
        if self.force_on:
            reason = self.robot.set_force_control(False)
            self.force_on = False
            self.last_sent.clear()   # the force node moved the arm; it holds it now
            if reason:
                self.robot.log("error", f"could not disable force control: {reason}")
            self.keep_squeezing()

    def keep_squeezing(self) -> None:
        """After a hold (ours, or the force node's when it is disabled): a hold commands the
        present position, so the fingers would stop squeezing and drop a held block; keep
        closing them at the grip effort."""
        if self.holding is not None:
            g = self.desc.gripper
            self.command({g.name: g.lower}, {g.name: self.holding})

    # --- the task --------------------------------------------------------------------------
    def run(self) -> RunResult:
        steps = self.task.steps
        result = RunResult(False, "")
        t_task = self.robot.now()
        # a task sent right after the stack started: the driver's joint_states may not have
        # reached this node yet (DDS discovery); wait a little for them (the first step then
        # fails "driver not ready" with the joints still missing)
        while (any(n not in self.robot.joint_positions() for n in self.chain)
               and self.robot.now() - t_task < STATE_WAIT and not self.robot.cancel_requested()):
            self.robot.sleep(self.period)
        retries: dict[int, int] = {}
        i = 0
        try:
            if not self.robot.cancel_requested():
                self.check_targets()
        except StepFailed as exc:
            self.safe_stop()
            result.message = f"refused before any motion: {exc}"
            result.failure_kind = exc.kind
            i = len(steps) + 1          # no step runs (and no success)
        except Cancelled:
            i = 0                       # the loop's first look reports it
        while i < len(steps):
            step = steps[i]
            if self.robot.cancel_requested():
                # a cancel that came after the last step's last look (or before the first
                # step): no new step starts
                self.safe_stop()
                result.message = f"cancelled before {step.name}"
                result.failure_kind = "cancelled"
                break
            self.step, self.attempt = step, retries.get(i, 0)
            self.fb.step, self.fb.index = step.name, i
            # logged before the feedback goes out: a client reacting to the feedback (a
            # Ctrl-C on "[1/13]") acts after the step's logged start, never before it
            self.robot.log("info", f"step {i + 1}/{len(steps)} {step.name} ({step.type})"
                           + (f", retry {self.attempt}" if self.attempt else ""))
            self.feedback("start", 0.0)
            t0 = self.robot.now()
            try:
                STEP_TYPES[step.type].run(step, self)
            except StepFailed as exc:
                r = step.retry
                used = retries.get(i, 0)
                if used < r.attempts and (not r.on or exc.kind in r.on):
                    retries[i] = used + 1
                    self.force_off()
                    self.robot.log("warn", f"step {step.name} failed ({exc}); retry "
                                   f"{used + 1}/{r.attempts} from {steps[r.from_index].name}"
                                   + (f", the gripper opened and the tool {r.clear * 100:g} cm "
                                      f"up first" if r.clear else ""))
                    try:
                        if r.clear:
                            self.clear_for_retry(r.clear)
                    except StepFailed as why:     # kind: the clearing's (what blocks now)
                        exc = StepFailed(why.kind, f"{exc}; clearing for the retry failed: "
                                                   f"{why}")
                    except Cancelled:
                        self.safe_stop()
                        result.message = f"cancelled during {step.name}"
                        result.failure_kind = "cancelled"
                        result.step_names.append(step.name)
                        result.step_durations.append(self.robot.now() - t0)
                        break
                    except BaseException:
                        self.safe_stop()
                        raise
                    else:
                        result.step_names.append(step.name)
                        result.step_durations.append(self.robot.now() - t0)
                        i = r.from_index
                        continue
                self.safe_stop()
                result.step_names.append(step.name)
                result.step_durations.append(self.robot.now() - t0)
                result.message = f"step '{step.name}' ({step.type}) failed: {exc}"
                if self.holding is not None:    # say where the grasped object is left
                    p = self.tool_measured()[:3, 3]
                    result.message += (f"; the grasped object is left in the gripper, tool0 "
                                       f"at ({', '.join(f'{v:.3f}' for v in p)}) m (holding)")
                result.failure_kind = exc.kind
                break
            except Cancelled:
                self.safe_stop()
                result.message = f"cancelled during {step.name}"
                result.failure_kind = "cancelled"
                break
            except BaseException:
                self.safe_stop()
                raise
            result.step_names.append(step.name)
            result.step_durations.append(self.robot.now() - t0)
            i += 1
        else:
            if i > len(steps):          # refused before any motion
                result.total_time = self.robot.now() - t_task
                result.metrics = dict(self.metrics)
                return result
            result.success = True
            result.message = f"task {self.task.name!r} done"
            self.fb.index, self.fb.step = len(steps) - 1, steps[-1].name
            self.feedback("done", 1.0)
        result.total_time = self.robot.now() - t_task
        self.metrics["retries"] = float(sum(retries.values()))
        result.metrics = dict(self.metrics)
        return result

    def tool_position_or_none(self) -> np.ndarray | None:
        try:
            return self.tool_measured()[:3, 3]
        except StepFailed:           # no joint_states of some chain joint
            return None

    def release_grasp(self) -> None:
        """An open: what was held is let go where the fingers are (forgotten: only fresh
        sightings place it again)."""
        if self.holding is not None or self.held_objects:
            self.touch(self.tool_position_or_none())
            for name in self.held_objects:
                self.touched_at[name] = self.robot.now()
        self.holding = None
        self.held_objects = set()

    def clear_for_retry(self, distance: float) -> None:
        """Before a retry goes back (``retry.clear``): open the gripper (whatever it held
        stays where it is) and move the tool straight up by ``distance`` (m) at 5 cm/s, so
        that the way back (a joint-space ``ready``, say) starts clear of what the fingers
        were around. Raises StepFailed (the gripper's or the move's reason)."""
        g = self.desc.gripper
        self.release_grasp()
        # from where the arm is: a failure raised mid-stream (a grasp lost during a lift)
        # leaves the last finished move's target behind the arm
        self.q_target = self.q_measured()
        self.tool_target = self.kin.forward(self.q_target)
        self.move_joint_goal({g.name: g.upper}, 0.02, 5.0, None, "opening to clear")
        target = self.tool_reference()
        target[:3, 3] += np.array([0.0, 0.0, distance])
        self.move_line(target, 0.05, 0.005, 0.003, 15.0, True,
                       f"clearing for the retry ({distance * 100:g} cm up)")

    def safe_stop(self) -> None:
        """Force control off, then hold where the arm is (nothing to do before the first
        command: the drivers hold their own positions; at start-up their hold service may
        not even be discovered yet, and waiting for it delayed a Ctrl-C by seconds)."""
        self.force_off()
        if not self.commanded:
            return
        reason = self.robot.hold()
        self.last_sent.clear()      # the drivers hold the measured position now
        if reason:
            self.robot.log("error", f"hold failed: {reason}")
        self.keep_squeezing()
