"""``track_path``: track a reference path's waypoints with tool0 at a stated speed.

The path is a named one of :mod:`hyperarm_ik.paths` (``figure8``: the IK benchmark's
figure "8" of Danko & Oh's Table II, 1,000 waypoints; ``figure8_wide``), optionally moved
or resized (``center``, ``half_width``, ``half_height``), held at the ready pose's tool
orientation. The step

1. goes to the first waypoint in a straight line (``approach_speed``);
2. solves IK at every waypoint, each seeded with the previous solution (as the benchmark);
   the joint speeds the stated ``speed`` needs must be within half of each joint's limit,
   and the plan must be free of collisions (the runner's model); else it plans from other
   postures at the first waypoint and moves to the first that gives a clean plan;
3. streams the joint path at ``speed`` along the path (constant speed, ramps of
   ``acceleration`` at both ends), sampling the measured joints at every tick; a late tick
   (a loaded machine) advances the path by at most 1.5 periods, and while joint_states are
   older than 50 ms (the driver stalls) the path waits, taken back to where it was when
   the last joint_states were sent, so the arm is never commanded a jump along the path
   (the traversal then takes longer: ``track_time``);
With ``redundancy: min_reaction`` (fixed arm only) the three free joints also keep the
arm's centre of mass over its mount, lowering the moment it exerts on the mount
(:mod:`hyperarm_control.host.redundancy`): after step 1 the arm moves in the task's null space
(the tool stays at the first waypoint) to the posture that minimises that moment, and step
2 solves every waypoint with the same secondary objective.

4. judges each waypoint by the closest approach of the measured path (FK of the measured
   joints) and puts the figures into the task's metrics (``track_reached``, ...); fails
   (kind ``tracking``) when fewer than ``min_reached`` of them came within ``reach``.

    - name: figure8
      type: track_path
      path: figure8
      speed: 4 cm/s
      min_reached: 0.999
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hyperarm_control.host import OBJECTIVES, HostError, ReactionMinimizer
from hyperarm_ik.paths import FIGURE8_WAYPOINTS, PATHS, Figure8, hold_orientation

from ..errors import StepFailed
from ..tracking import PathClock, arc_length, tracking_report, trapezoid_time_scaling
from . import STALE_STATES, BuildContext, Step, StepType, quantity, register

SETTLE_TIME = 1.0        # s after the last waypoint, sampling until the tool is there
LATE_TICKS = 1.5         # a tick later than this many periods slows the path down instead
WINDOW = 1.0             # s: a waypoint is judged on the path measured this close in time to
                         # when it was commanded (the figure-8 crosses itself ~9 s apart)
PLAN_CANCEL_EVERY = 100  # waypoints solved between two cancel checks
PLAN_STARTS = 8          # postures at the first waypoint tried for a collision-free plan
PLAN_SEED = 0            # their random null-space directions: the same plan on every run
NULL_STEP = 0.3          # rad, the first null-space step to another posture (then 2x, 3x)
NULL_STEPS_MAX = 3       # steps of at most this many NULL_STEP (farther, the solver's
                         # cold start takes over and gives its table posture again)
SAME_POSTURE = 0.01      # rad: a posture within this of one tried already is not tried


@dataclass(frozen=True)
class TrackPath(Step):
    path: str = "figure8"
    figure: Figure8 = Figure8()
    waypoints: int = FIGURE8_WAYPOINTS
    speed: float = 0.04           # m/s along the path
    acceleration: float = 0.1     # m/s^2, the ramps at start and end
    approach_speed: float = 0.10  # m/s, peak, to the first waypoint
    reach: float = 0.001          # m, a waypoint is reached within this
    min_reached: float = 0.0      # fraction of waypoints that must be reached
    redundancy: str = "none"      # "min_reaction": centre of mass over the mount


def build(raw: dict, ctx: BuildContext, index: int) -> TrackPath:
    base = PATHS[raw["path"]]
    center = base.center
    if "center" in raw:
        try:
            center = tuple(ctx.length_vector(raw["center"]))
        except ValueError as exc:
            raise ctx.FieldError(("center",), f"center: {exc}") from None
    figure = Figure8(center,  # type: ignore[arg-type]
                     ctx.si(raw, "half_width", "length", base.half_width, positive=True),
                     ctx.si(raw, "half_height", "length", base.half_height, positive=True))
    return TrackPath(**ctx.common(raw, index, 60.0), path=raw["path"], figure=figure,
                     waypoints=int(raw.get("waypoints", FIGURE8_WAYPOINTS)),
                     speed=ctx.si(raw, "speed", "speed", 0.04, positive=True),
                     acceleration=ctx.si(raw, "acceleration", "acceleration", 0.1,
                                         positive=True),
                     approach_speed=ctx.si(raw, "approach_speed", "speed", 0.10, positive=True),
                     reach=ctx.si(raw, "reach", "length", 0.001, positive=True),
                     min_reached=float(raw.get("min_reached", 0.0)),
                     redundancy=_redundancy(raw, ctx))


def _redundancy(raw: dict, ctx: BuildContext) -> str:
    value = str(raw.get("redundancy", "none"))
    if value != "none" and ctx.desc.rail is not None:
        raise ctx.FieldError(("redundancy",), f"redundancy {value!r} needs the fixed arm "
                             "(variant arm): the mount's reaction is the arm's base_link")
    return value


def _plan_from(step: TrackPath, runner, points: np.ndarray, rot: np.ndarray,
               seed: np.ndarray) -> np.ndarray:
    """IK at every waypoint, each seeded with the previous solution: (n, nq). The
    waypoints' collisions are judged on the whole plan afterwards (:func:`_check_plan`):
    avoiding them one by one would jump the joints between branches."""
    qs = np.empty((len(points), len(seed)))
    pose = np.eye(4)
    pose[:3, :3] = rot
    for k, p in enumerate(points):
        if k % PLAN_CANCEL_EVERY == 0:
            runner.tick()
        pose[:3, 3] = p
        res = runner.ik(pose, seed, collisions="ignore")
        if not res.success:
            raise StepFailed("ik", f"IK failed for {step.name} ({step.path}) at waypoint "
                             f"{k + 1}/{len(points)} ({', '.join(f'{v:.3f}' for v in p)}) m: "
                             f"{res.message}")
        qs[k] = seed = res.q
    return qs


def _check_plan(step: TrackPath, runner, qs: np.ndarray, ds: np.ndarray) -> None:
    """StepFailed when the planned joints hit the arm or the work cell (the runner's
    collision model: the task node's work cell) or need joint speeds beyond half of the
    limits at ``step.speed``."""
    _check_speed(step, runner, qs, ds)
    if runner.collisions is None:
        return
    held = runner.holding is not None
    chk = runner.collisions.check_configurations(
        [(k / max(len(qs) - 1, 1), q) for k, q in enumerate(qs)], held)
    if not chk.free:
        raise StepFailed("collision", f"{step.name} ({step.path}): the planned joints collide "
                         f"at waypoint {chk.samples}/{len(qs)}: "
                         + ", ".join(str(c) for c in chk.contacts))


def other_starts(runner, pose: np.ndarray, here: np.ndarray, count: int):
    """Up to ``count`` other postures of the redundant arm with tool0 at ``pose`` (4x4),
    each different from ``here`` (a solution of it) and from the others, deterministic: the IK's cold start (its
    table posture: any seed far from the pose gives that one), then ``here`` moved by
    growing steps (NULL_STEP, 2 NULL_STEP, ... rad) along fixed random directions of the
    task's null space and solved again from there (a warm start: the solver keeps it)."""
    kin = runner.kin
    rng = np.random.default_rng(PLAN_SEED)
    seen = [here]

    def new(q: np.ndarray) -> bool:        # not a posture tried already
        if any(np.abs(q - other).max() < SAME_POSTURE for other in seen):
            return False
        seen.append(q)
        return True

    far = np.where(here > 0.5 * (kin.lower + kin.upper), kin.lower, kin.upper)
    res = runner.ik(pose, far, collisions="avoid")
    if res.success and new(res.q):
        yield res.q
    j = kin.jacobian(here)
    for k in range(1, count):
        z = rng.normal(size=len(here))
        dq = z - np.linalg.pinv(j) @ (j @ z)             # the null-space part
        norm = float(np.linalg.norm(dq))
        if norm < 1e-9:
            continue
        step = min(k, NULL_STEPS_MAX) * NULL_STEP
        seed = np.minimum(np.maximum(here + dq * (step / norm), kin.lower), kin.upper)
        res = runner.ik(pose, seed, collisions="avoid")
        if res.success and new(res.q):
            yield res.q


def _plan(step: TrackPath, runner, points: np.ndarray, rot: np.ndarray,
          ds: np.ndarray, deadline: float) -> np.ndarray:
    """The joints of every waypoint, free of collisions and within the speed budget: first
    from where the arm is (at the first waypoint), else from up to PLAN_STARTS - 1 other
    postures of the redundant arm at the first waypoint (:func:`other_starts`), the arm
    moving to the first that gives a clean plan in joint space (a checked path) before
    the tracking starts: (n, nq)."""
    here = runner.q_target if runner.q_target is not None else runner.q_measured()
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, points[0]
    first: StepFailed | None = None
    starts = other_starts(runner, pose, here, PLAN_STARTS - 1)
    for attempt in range(PLAN_STARTS):
        runner.feedback("planning", 0.1 * attempt / PLAN_STARTS, points[0])
        start = here if attempt == 0 else next(starts, None)
        if start is None:
            break
        try:
            qs = _plan_from(step, runner, points, rot, start)
            _check_plan(step, runner, qs, ds)
            if attempt:
                runner.check_collisions(f"{step.name} (to another posture)", here, qs[0])
        except StepFailed as exc:
            if exc.kind == "tracking" and attempt == 0:
                raise      # too fast for the stated speed: no other posture is asked for
            first = first or exc
            continue
        if attempt:
            runner.robot.log("info", f"{step.name}: the plan from the arm's posture at the "
                             f"first waypoint failed ({first}); planned from another posture "
                             f"(start {attempt + 1} of {PLAN_STARTS}), moving there first")
            runner.stream([here, qs[0]], runner.path_duration([here, qs[0]], 0.0,
                                                                step.approach_speed),
                          "reconfiguring")
            runner.settle(pose, step.reach, deadline, f"{step.name} (in its new posture)")
        return qs
    assert first is not None
    raise StepFailed(first.kind, f"{first} (and no other of {PLAN_STARTS - 1} postures at the "
                     "first waypoint gave a clean plan)")


def _plan_min_reaction(step: TrackPath, runner, points: np.ndarray,
                       rot: np.ndarray) -> np.ndarray:
    """Null-space move to the minimising posture at the first waypoint (streamed), then the
    waypoints' joints with the centre of mass kept over the mount: (n, nq)."""
    minimizer = ReactionMinimizer(runner.kin)
    poses = np.tile(np.eye(4), (len(points), 1, 1))
    poses[:, :3, :3], poses[:, :3, 3] = rot, points
    try:
        pre = list(minimizer.reconfigure(poses[0], runner.q_measured()))
        runner.stream(pre, runner.path_duration(pre, 0.0, step.approach_speed),
                      "reconfiguring")
        return minimizer.plan(poses, pre[-1], on_waypoint=lambda k: (
            runner.feedback("planning", 0.1 * k / len(points), points[k]), runner.tick())
            if k % PLAN_CANCEL_EVERY == 0 else None)
    except HostError as exc:
        raise StepFailed("ik", f"{step.name} ({step.path}, redundancy "
                         f"{step.redundancy}): {exc}") from None


def _check_speed(step: TrackPath, runner, qs: np.ndarray, ds: np.ndarray) -> None:
    """The joint speeds at ``step.speed`` must be within half of each joint's limit."""
    if len(qs) < 2:
        return
    rate = np.abs(np.diff(qs, axis=0)) / np.maximum(ds, 1e-9)[:, None] * step.speed  # rad/s
    vmax = np.array([0.5 * (runner.desc.rail.velocity if runner.desc.rail
                            and n == runner.desc.rail.name else runner._vel(n))
                     for n in runner.chain])
    ratio = rate.max(axis=0) / vmax
    j = int(np.argmax(ratio))
    if ratio[j] > 1.0:
        raise StepFailed("tracking", f"{step.name}: at {step.speed * 100:g} cm/s "
                         f"{runner.chain[j]} would need {rate[:, j].max():.2f} rad/s, more "
                         f"than half its velocity limit ({vmax[j]:.2f}); at most "
                         f"{step.speed / ratio[j] * 100:.1f} cm/s")


def windows(stamps: np.ndarray, commanded: np.ndarray, n: int) -> np.ndarray:
    """(n, 2) sample index ranges: the samples within WINDOW s of when each waypoint was
    first commanded (``commanded``: non-decreasing fractional waypoint index per sample)."""
    first = np.minimum(np.searchsorted(commanded, np.arange(n), side="left"), len(stamps) - 1)
    t = stamps[first]
    lo = np.searchsorted(stamps, t - WINDOW, side="left")
    hi = np.searchsorted(stamps, t + WINDOW, side="right") - 1
    return np.stack([lo, np.maximum(hi, lo)], axis=1)


#: a path that takes longer than this times its planned duration is reported as slow
SLOW_FACTOR = 1.05


def run(step: TrackPath, runner) -> None:
    robot, kin = runner.robot, runner.kin
    t_step = robot.now()
    deadline = t_step + step.timeout
    points = step.figure.points(step.waypoints)
    rot = hold_orientation(kin)
    first = np.eye(4)
    first[:3, :3], first[:3, 3] = rot, points[0]
    runner.move_line(first, step.approach_speed, 0.005, step.reach, step.timeout, True,
                     f"{step.name} (to its first waypoint)")
    s_at = arc_length(points)
    if step.redundancy == "none":
        qs = _plan(step, runner, points, rot, np.diff(s_at), deadline)
    else:
        qs = _plan_min_reaction(step, runner, points, rot)
        _check_plan(step, runner, qs, np.diff(s_at))
    s_of, duration = trapezoid_time_scaling(float(s_at[-1]), step.speed, step.acceleration)
    if robot.now() + duration + SETTLE_TIME > deadline:
        raise StepFailed("timeout", f"{step.name}: the path needs {duration:.1f} s at "
                         f"{step.speed * 100:g} cm/s, more than the step's timeout "
                         f"({step.timeout:g} s) leaves")
    index = np.arange(len(points), dtype=float)
    names = runner.chain
    samples: list[np.ndarray] = []
    stamps: list[float] = []      # s, when each sample was taken
    commanded: list[float] = []   # fractional waypoint index commanded then
    t0 = robot.now()
    clock = PathClock(t0, duration, runner.period, STALE_STATES, LATE_TICKS)
    while True:
        now = robot.now()
        t = clock.tick(now, robot.joint_states_age())
        x = float(np.interp(s_of(t), s_at, index))
        k = min(int(x), len(points) - 2)
        f = x - k
        runner.send(names, qs[k] + f * (qs[k + 1] - qs[k]))
        samples.append(runner.q_measured())
        stamps.append(robot.now())
        commanded.append(x)
        runner.feedback("tracking", 0.1 + 0.85 * min(t / duration, 1.0),
                        points[k] + f * (points[k + 1] - points[k]))
        if t >= duration:
            break
        if now > deadline:
            raise StepFailed("timeout", f"{step.name}: still tracking after the step's timeout "
                             f"({step.timeout:g} s), at waypoint {k + 1}/{len(points)}")
        runner.tick(names)
    # hold the last waypoint, sampling until the tool is there (or SETTLE_TIME passed)
    t_end = robot.now()
    while robot.now() - t_end < SETTLE_TIME:
        runner.tick(names)
        samples.append(runner.q_measured())
        stamps.append(robot.now())
        commanded.append(float(len(points) - 1))
        if np.linalg.norm(kin.forward(samples[-1])[:3, 3] - points[-1]) <= 0.25 * step.reach:
            break
    runner.q_target = qs[-1].copy()
    runner.tool_target = kin.forward(qs[-1])
    qm = np.array(samples)
    xyz = np.array([kin.forward(q)[:3, 3] for q in qm])
    report = tracking_report(points, qs, xyz, qm, step.reach,
                             windows(np.array(stamps), np.array(commanded), len(points)))
    runner.metrics.update(report.metrics())
    # the speed achieved, reported beside the stated one: the path waits for late ticks and
    # stale joint_states (no jump after a stall), so a loaded machine runs it slower
    took = float(t_end - t0)
    achieved = float(s_at[-1]) / max(took, 1e-9)
    planned = float(s_at[-1]) / max(duration, 1e-9)
    runner.metrics.update(track_speed=step.speed, track_length=float(s_at[-1]),
                          track_time=took, track_planned_time=float(duration),
                          track_mean_speed=achieved, track_planned_mean_speed=planned)
    runner.feedback("tracked", 1.0, points[-1])
    slow = took > SLOW_FACTOR * duration
    robot.log("warn" if slow else "info",
              f"{step.name} ({step.path}, stated {step.speed * 100:g} cm/s; planned "
              f"{duration:.1f} s, mean {planned * 100:.2f} cm/s; took {took:.1f} s, mean "
              f"{achieved * 100:.2f} cm/s"
              + (", slower than planned: late ticks or stale joint_states held the path"
                 if slow else "") + f"): {report.summary()}")
    if report.reached_fraction < step.min_reached:
        raise StepFailed("tracking", f"{report.summary()}: fewer than the required "
                         f"{100.0 * step.min_reached:g} %")


register(StepType(
    "track_path",
    {"path": {"enum": sorted(PATHS), "description": "a reference path of hyperarm_ik.paths"},
     "center": {"type": "array", "minItems": 3, "maxItems": 3, "items": quantity("length")},
     "half_width": quantity("length"), "half_height": quantity("length"),
     "waypoints": {"type": "integer", "minimum": 2, "maximum": 100000},
     "speed": quantity("speed", "along the path"),
     "acceleration": quantity("acceleration", "ramps at both ends"),
     "approach_speed": quantity("speed", "to the first waypoint"),
     "reach": quantity("length", "a waypoint is reached within this"),
     "min_reached": {"type": "number", "minimum": 0, "maximum": 1,
                     "description": "fraction of the waypoints that must be reached"},
     "redundancy": {"enum": list(OBJECTIVES),
                    "description": "min_reaction: the free joints keep the centre of mass "
                                   "over the mount (lower base moment; fixed arm)"}},
    ("path",), build, run, "track a reference path's waypoints at a speed"))
