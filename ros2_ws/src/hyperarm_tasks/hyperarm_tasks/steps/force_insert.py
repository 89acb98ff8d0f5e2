"""``force_insert``: press the held block down onto a peg while dithering in x-y (a spiral
or concentric circles up to ``dither.radius``), until it is ``depth`` down the peg or the
step's timeout (Danko & Oh, Section IV: hybrid force control, the hole finds the peg).

With the force node running (``hybrid_force/enable``), force control is enabled and the
step streams HybridGoal: z force-controlled at ``force`` downward, x-y position-controlled
along the dither; force control is disabled again before the step returns (the contract's
rule: joint_command only while it is off). Without the force node the step presses with a
position pseudo-goal through joint_command: the tool is commanded ``press`` below the
contact height, and the servos' finite stiffness turns the shortfall into the pressing
force (logged once per run).

Contact and depth. The press stalls on the peg's top: the measured tool (FK of
joint_states) stops above the commanded one (the servos deflect); that height is the
contact height. Under force control the z goal then stays at the contact height, so the
block is pressed with ``force`` alone (stiffness x offset = 0 on the top) while the dither
moves it, and it is down the peg when the measured tool is ``depth`` below the contact
height (the force pushes it down by force / stiffness once the hole finds the peg). A block
that meets no contact (straight down the peg) is down when the goal went the full ``press``
below the nominal contact height and the force holds the tool more than
``contact_threshold`` below its goal: nothing holds it up (judged from the nominal top
alone, the grasp's and the arm's error can make a block on the top read 6 mm down). If the
force node goes passive on late joint states, the step enables it again (at most 10 times;
any other passive reason fails the attempt). With the pressing fallback the block is down
the peg when the command is the full ``press`` below the contact height (more than
``depth``) and nothing holds the tool up any more (deflection below
``contact_threshold``). Either way the camera then confirms: the block must be half
``depth`` below where it would rest on the top (else the drop was the tool's alone, e.g.
a re-enable's lag with the block hanging above the top: the step searches on), and on
the peg's axis (within ``align_tolerance``), not down beside it. Encoders do not see the
arm's repeatability error, so heights are judged by deflection, not by absolute tool
height.
The depth reported is the measured drop below the contact height. Retries (``retry``)
rotate and reverse the pattern.

    - name: insert
      type: force_insert
      target: {relative_to: destination_peg, offset: [0, 0, 1.5 cm]}
      depth: 5 mm
      dither: {pattern: spiral, radius: 1.5 cm, pitch: 2 mm, speed: 4 cm/s}
      timeout: 30 s
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..errors import StepFailed
from . import BuildContext, PoseSpec, Step, StepType, pose_schema, quantity, register


STALL_WINDOW = 0.15   # s: the tool stalled if it moved down less than STALL_MOTION in it
STALL_MOTION = 3e-4   # m  (while the command went down more than twice that)
CONTACT_WINDOW = 0.01  # m: a stall counts as contact only this close above the nominal top
MAX_RESUMES = 10      # force control enabled again after it went passive on late joint states
STILL_MOTION = 5e-4   # m: the tool moved less than this while the camera looked (alignment)
ALIGN_TRIES = 3       # camera alignment: looks at most (the arm moved while it looked)


@dataclass(frozen=True)
class ForceInsert(Step):
    target: PoseSpec = PoseSpec("tool")
    depth: float = 0.005            # m down the peg = success
    press: float = 0.015            # m, pseudo-goal below the contact height (no force node)
    force: float = 3.0              # N downward (force node)
    stiffness: float = 300.0        # N/m on z (force node)
    descent_speed: float = 0.02     # m/s
    pattern: str = "spiral"
    radius: float = 0.015           # m
    pitch: float = 0.002            # m of radius per turn
    dither_speed: float = 0.04      # m/s along the pattern
    contact_threshold: float = 0.0015  # m, measured above commanded = stalled on the top
    align_tolerance: float = 0.012  # m, camera: block to peg axis when down (beside: > 2 cm)
    camera_align: bool = True       # camera: put the held block over the target first
    align_limit: float = 0.02       # m, the largest such correction (larger: clipped, warned)


def build(raw: dict, ctx: BuildContext, index: int) -> ForceInsert:
    d = raw.get("dither", {})
    step = _build(raw, ctx, index, d)
    if step.press <= step.depth:
        raise ctx.FieldError(("press",), f"press ({step.press * 1000:.1f} mm) must exceed depth "
                             f"({step.depth * 1000:.1f} mm): the block is pressed that far")
    sink = step.force / step.stiffness
    if sink <= step.contact_threshold:
        raise ctx.FieldError(("force",), f"force / stiffness ({sink * 1000:.1f} mm) must exceed "
                             f"contact_threshold ({step.contact_threshold * 1000:.1f} mm): "
                             "under force control a block that meets no contact is down "
                             "when the force holds the tool that far below its goal")
    return step


def _build(raw: dict, ctx: BuildContext, index: int, d: dict) -> ForceInsert:
    return ForceInsert(
        **ctx.common(raw, index, 30.0), target=ctx.pose(raw, "target"),
        depth=ctx.si(raw, "depth", "length", 0.005, positive=True),
        press=ctx.si(raw, "press", "length", 0.015, positive=True),
        force=ctx.si(raw, "force", "force", 3.0, positive=True),
        stiffness=ctx.si(raw, "stiffness", "stiffness", 300.0, positive=True),
        descent_speed=ctx.si(raw, "descent_speed", "speed", 0.02, positive=True),
        pattern=d.get("pattern", "spiral"),
        radius=ctx.si(d, "radius", "length", 0.015, nonneg=True, path=("dither",)),
        pitch=ctx.si(d, "pitch", "length", 0.002, positive=True, path=("dither",)),
        dither_speed=ctx.si(d, "speed", "speed", 0.04, positive=True, path=("dither",)),
        contact_threshold=ctx.si(raw, "contact_threshold", "length", 0.0015, positive=True),
        align_tolerance=ctx.si(raw, "align_tolerance", "length", 0.012, positive=True),
        camera_align=bool(raw.get("camera_align", True)),
        align_limit=ctx.si(raw, "align_limit", "length", 0.02, nonneg=True))


class Dither:
    """x-y offset (m) along the pattern; ``advance(dt)`` moves ``speed`` x dt along it."""

    def __init__(self, step: ForceInsert, attempt: int) -> None:
        self.step = step
        self.theta = 0.0
        self.phase = 2.39996 * attempt              # golden angle: a new pattern per retry
        self.sign = -1.0 if attempt % 2 else 1.0

    def radius(self) -> float:
        s = self.step
        turns = self.theta / (2.0 * math.pi)
        r = s.pitch * (turns if s.pattern == "spiral" else math.floor(turns) + 1.0)
        return min(r, s.radius)

    def advance(self, dt: float) -> np.ndarray:
        r = max(self.radius(), 0.5 * self.step.pitch)
        self.theta += self.step.dither_speed * dt / r
        return self.offset()

    def offset(self) -> np.ndarray:
        r, a = self.radius(), self.sign * self.theta + self.phase
        return np.array([r * math.cos(a), r * math.sin(a), 0.0])

    @property
    def turns(self) -> float:
        return self.theta / (2.0 * math.pi)


def _camera_check(step: ForceInsert, runner, z_top: float) -> float | None:
    """The camera, once the tool says the block is down: how far (m) the block is below
    where it would rest on the peg's top, ``z_top`` (the target's height: tool0 at the held
    block's centre, the target the tool's pose with the block on the top); if it is down
    (half ``depth`` or more), its hole must be on the peg's axis (StepFailed if it went
    down beside the peg). None without a camera judgement (the target not relative to an
    object the camera sees, or neither it nor the block seen now: a camera the hand hides
    the held block from; the tool's depth then decides, with a warning)."""
    if step.target.relative_to not in runner.task.objects or "block" not in runner.task.objects:
        return None
    # images taken now that the block is down (it moved along the dither before), more of
    # them than usual: block and peg are each seen with ~2 mm of noise per image
    frames = 2 * runner.params.detection_frames
    try:
        block = runner.detect("block", since=runner.robot.now(), frames=frames).xyz
        given = runner.robot.given_object(step.target.relative_to)
        peg = (given[:3, 3] if given is not None else
               runner.detect(step.target.relative_to, frames=frames).xyz)
    except StepFailed as exc:
        if exc.kind != "detection":
            raise
        runner.robot.log("warn", f"{step.name}: no camera check of the insertion ({exc}); "
                                 "the tool's depth decides")
        runner.metrics["camera_check_unseen"] = 1.0
        return None
    seen = z_top - float(block[2])
    if seen < 0.5 * step.depth:
        return seen           # not down: where it is sideways does not matter
    off = float(np.hypot(*(block[:2] - peg[:2])))
    if off > step.align_tolerance:
        raise StepFailed("insertion", f"the block went down {off * 1000:.0f} mm off the axis "
                         f"of {step.target.relative_to} (beside it, not on it)")
    return seen


def _camera_aligned(step: ForceInsert, runner, target: np.ndarray) -> np.ndarray:
    """The target with its x-y shifted so that the held block, as the camera sees it, comes
    over the target: the block's offset from the measured tool (FK of joint_states) is the
    grasp's and the arm's repeatability error, which the encoders do not see (docs/mock.md);
    the tool's goal is the target minus that offset (the block is taken as held at tool0, as
    block_transfer grasps it: down_to_block goes to the block's detected pose). Needs the
    target relative to a detected object and the block among the task's objects; the shift
    is at most ``align_limit``; without fresh sightings of the block the target is kept (a
    warning). The step moves to the shifted target at its descent speed (no jump: a jump
    would be a new move, with a new repeatability error)."""
    objects = runner.task.objects
    if (not step.camera_align or runner.holding is None or "block" not in objects
            or step.target.relative_to not in objects):
        return target
    frames = 2 * runner.params.detection_frames
    for _ in range(ALIGN_TRIES):
        _settle(runner)
        before = runner.tool_measured()[:3, 3]
        try:
            block = runner.detect("block", since=runner.robot.now(), frames=frames).xyz
        except StepFailed as exc:
            if exc.kind != "detection":
                raise
            runner.robot.log("warn", f"{step.name}: no camera alignment ({exc}); inserting "
                                     "from the target as given")
            return target
        tool = runner.tool_measured()[:3, 3]
        if np.linalg.norm(tool - before) < STILL_MOTION:
            break      # the images saw the block where the tool is now
    else:
        runner.robot.log("warn", f"{step.name}: the arm kept moving while the camera looked "
                                 "at the block; no camera alignment")
        return target
    # held at tool0 (the grasp puts tool0 at the block's detected pose): with the tool's
    # FK at x the block is at x + (block - tool); the goal puts the block at the target
    shift = -(block[:2] - tool[:2])
    size = float(np.hypot(*shift))
    if size > step.align_limit:
        runner.robot.log("warn", f"{step.name}: the camera sees the block {size * 1000:.1f} mm "
                                 f"from where the tool should put it; correcting by "
                                 f"align_limit ({step.align_limit * 1000:.0f} mm) only")
        shift *= step.align_limit / size
    runner.metrics["camera_shift"] = float(np.hypot(*shift))
    runner.robot.log("info", f"{step.name}: camera: the held block is "
                             f"{size * 1000:.1f} mm off; x-y target shifted by "
                             f"({shift[0] * 1000:+.1f}, {shift[1] * 1000:+.1f}) mm")
    out = target.copy()
    out[:2, 3] += shift
    return out


def _settle(runner, window: float = 0.2, timeout: float = 2.0) -> None:
    """Wait (up to ``timeout`` s) until the measured tool moved less than STILL_MOTION over
    the last ``window`` s."""
    t0 = runner.robot.now()
    seen: deque[tuple[float, np.ndarray]] = deque()
    while runner.robot.now() - t0 < timeout:
        now, p = runner.robot.now(), runner.tool_measured()[:3, 3]
        seen.append((now, p))
        while now - seen[0][0] > window:
            seen.popleft()
        if now - t0 >= window and np.linalg.norm(p - seen[0][1]) < STILL_MOTION:
            return
        runner.tick()


def _enable(runner, patience: float = 2.0) -> str | None:
    """Enable force control; the force node's reason if it refuses. It refuses to start on
    stale joint states (its own view of them: a loaded machine), so it is asked again, for
    up to ``patience`` s, while that is the reason."""
    robot = runner.robot
    waited = robot.now()
    while True:
        while robot.joint_states_age() > 0.05 and robot.now() - waited < patience:
            runner.tick()
        reason = robot.set_force_control(True)
        if not reason or "stale" not in reason or robot.now() - waited > patience:
            return reason
        runner.tick()


def run(step: ForceInsert, runner) -> None:
    robot = runner.robot
    if runner.holding is None:
        robot.log("warn", f"{step.name}: no grasp is held (inserting anyway)")
    target = runner.resolve(step.target)
    use_force = robot.force_available()
    if use_force:
        reason = _enable(runner)
        if reason:
            raise StepFailed("driver", f"force control could not be enabled: {reason}")
        runner.force_on = True
    elif not runner.metrics.get("pressing_fallback_logged"):
        robot.log("warn", f"{step.name}: no force node (hybrid_force/enable not available): "
                          f"pressing with a position pseudo-goal {step.press * 1000:.0f} mm "
                          "below the contact height through joint_command")
        runner.metrics["pressing_fallback_logged"] = 1.0
    try:
        # the camera looks once the force node holds the arm: its taking over can settle
        # the arm anew (on the robot, the backlash; on the mock, a new move's offset)
        target = _camera_aligned(step, runner, target)
    except BaseException:
        if use_force:
            runner.force_off()
        raise
    start = runner.tool_reference()
    # the way from the start to the target's x-y (a camera correction): at descent_speed
    lateral = target[:2, 3] - start[:2, 3]
    lateral_time = float(np.hypot(*lateral)) / step.descent_speed
    z_contact = float(target[2, 3])
    z_bottom = z_contact - step.press
    dither = Dither(step, runner.attempt)
    q = runner.q_target if runner.q_target is not None else runner.q_measured()
    t0 = robot.now()
    last = t0
    z_cmd = float(start[2, 3])
    z_ref, t_contact, best, dithering = None, None, 0.0, False
    done_ticks = 0
    resumed = 0
    rejected = 0          # "down" judgements the camera did not confirm
    found_xy: np.ndarray | None = None   # force control: measured x-y where the hole found the peg
    history: deque[tuple[float, float, float]] = deque()
    search_again = False   # the contact searched anew, descending from where the tool is
    try:
        while True:
            if search_again:
                search_again = False
                z_ref = t_contact = found_xy = None
                z_cmd = float(runner.tool_measured()[2, 3])
                z_bottom = z_contact - step.press
                done_ticks = 0
                history.clear()
                last = robot.now()
            now = robot.now()
            dt, last = now - last, now
            if dithering and done_ticks == 0:
                off = dither.advance(dt)    # frozen while the depth is being confirmed
            elif not dithering:
                off = np.zeros(3)
            z_cmd = max(z_bottom, z_cmd - step.descent_speed * dt)
            goal = target.copy()
            goal[:3, 3] = target[:3, 3] + off
            if now - t0 < lateral_time:     # still on the way to the target's x-y
                goal[:2, 3] -= lateral * (1.0 - (now - t0) / lateral_time)
            goal[2, 3] = z_cmd
            if found_xy is not None:
                # down the peg (being confirmed): the peg holds the block where the hole found
                # it; an x-y goal elsewhere would only push it sideways against the peg
                goal[:2, 3] = found_xy
            if use_force:
                from ..runner import HybridCommand
                passive = robot.force_passive()
                if passive:     # it holds the arm where it is and ignores goals
                    kind, why = passive
                    if kind != "stale" or resumed >= MAX_RESUMES:
                        runner.metrics["insertion_attempts"] = runner.attempt + 1.0
                        raise StepFailed("insertion", f"force control went passive during "
                                         f"the insertion ({why}); best depth "
                                         f"{best * 1000:.1f} mm")
                    # late joint states (a loaded machine): the fault is latched until
                    # someone enables again; the step does, from the pose held now
                    resumed += 1
                    robot.log("warn", f"{step.name}: force control went passive ({why}); "
                                      f"enabling it again ({resumed}/{MAX_RESUMES})")
                    reason = _enable(runner)
                    if reason:
                        raise StepFailed("driver", f"force control could not be enabled "
                                         f"again: {reason}")
                    # a passive hold looks like a stall on the top: find the contact again,
                    # descending from where the tool is now (the hold may have moved the
                    # arm: a contact found before is no reference any more)
                    search_again = True
                    continue
                robot.send_hybrid(HybridCommand(goal[:3, 3], goal[:3, :3],
                                                (2000.0, 2000.0, step.stiffness, 50.0, 50.0, 50.0),
                                                (False, False, True, False, False, False),
                                                (0.0, 0.0, -step.force, 0.0, 0.0, 0.0)))
            else:
                res = runner.ik(goal, q)
                if not res.success:
                    raise StepFailed("ik", f"IK failed for {step.name} at the dither point "
                                     f"({', '.join(f'{v:.3f}' for v in goal[:3, 3])}) m: "
                                     f"{res.message}")
                q = res.q
                runner.send(runner.chain, q)
                runner.tool_target = goal.copy()
            z_meas = float(runner.tool_measured()[2, 3])
            lag = z_meas - z_cmd
            history.append((now, z_meas, z_cmd))
            while history and now - history[0][0] > STALL_WINDOW:
                history.popleft()
            old_t, old_meas, old_cmd = history[0]
            stalled = (now - old_t >= 0.8 * STALL_WINDOW and old_meas - z_meas < STALL_MOTION
                       and old_cmd - z_cmd > 2.0 * STALL_MOTION)
            near = z_cmd < z_contact + CONTACT_WINDOW     # contact is only expected here
            if z_ref is None and near and lag > step.contact_threshold and stalled:
                z_ref, t_contact = z_meas, now           # stalled on the peg's top
                if use_force:
                    # force control: the z goal stays at the contact height, so the block is
                    # pressed with the feed-forward force alone (K (X0 - X) = 0 on the top):
                    # the dither works against friction of mu x force, and the block drops
                    # by force / K once its hole finds the peg
                    z_bottom = z_cmd = z_ref
                else:
                    z_bottom = z_ref - step.press        # press relative to the contact
            if not dithering and (z_ref is not None or z_cmd <= z_bottom):
                dithering = True
                t_contact = t_contact or now
            # Down the peg: commanded the full press below the contact height and nothing
            # holds the tool up (no vertical deflection). The encoders cannot see the arm's
            # repeatability error, but the deflection is the contact itself.
            depth = (z_ref if z_ref is not None else z_contact) - z_meas
            if use_force:     # the force holds the tool down: down the peg is the depth
                # from a contact found since the last enable or, with none found, from the
                # nominal top once nothing holds the tool up: the goal went the full press
                # down and the feed-forward force pushes the tool below it (on the top the
                # tool stays above its goal; the nominal top alone is off by the grasp's and
                # the arm's error: a block on the top can read 6 mm "down" from it)
                free = z_cmd <= z_bottom + 1e-4 and lag < -step.contact_threshold
                ok = dithering and depth >= step.depth and (z_ref is not None or free)
                best = max(best, depth)
            else:
                ok = z_cmd <= z_bottom + 1e-4 and lag < step.contact_threshold
                if lag < step.contact_threshold:     # depths while held up do not count
                    best = max(best, depth)
            done_ticks = done_ticks + 1 if ok else 0
            if use_force:
                found_xy = runner.tool_measured()[:2, 3].copy() if ok and found_xy is None \
                    else (found_xy if ok else None)
            runner.feedback("dithering" if dithering else "descending",
                            min((now - t0) / step.timeout, 0.99), goal[:3, 3], depth)
            if done_ticks >= 10:
                seen = _camera_check(step, runner, z_contact)
                if seen is not None and seen < 0.5 * step.depth:
                    # the tool dropped, but not the block down the peg: a "contact" that was
                    # the tool lagging its goal (a re-enable's start), the block hanging
                    # above the top; search on from here
                    rejected += 1
                    best = max(seen, 0.0)    # the tool's depth was not the block's
                    robot.log("info", f"{step.name}: the tool reads {depth * 1000:.1f} mm "
                              f"down, but the camera sees the block {seen * 1000:.1f} mm "
                              f"below the peg's top only (not down the peg); searching on")
                    search_again = True
                    continue
                if seen is not None:
                    runner.metrics["camera_depth"] = seen
                if not use_force:
                    # The peg holds the block where the hole found it: the servos deflect
                    # the tool off the dither's last x-y. Later steps that keep x-y (down
                    # the peg) start from the measured x-y, so no side load jams the block.
                    found = goal.copy()
                    found[:2, 3] = runner.tool_measured()[:2, 3]
                    runner.tool_target = found
                runner.metrics["insertion_time"] = now - (t_contact or t0)
                runner.metrics["insertion_depth"] = depth
                runner.metrics["dither_turns"] = dither.turns
                runner.metrics["insertion_attempts"] = runner.attempt + 1.0
                robot.log("info", f"{step.name}: {depth * 1000:.1f} mm down the peg after "
                          f"{now - t0:.1f} s ({dither.turns:.1f} dither turns, radius "
                          f"{dither.radius() * 1000:.1f} mm)")
                return
            if now - t0 > step.timeout:
                runner.metrics["insertion_attempts"] = runner.attempt + 1.0
                raise StepFailed("insertion", f"insertion not achieved in {step.timeout:g} s "
                                 f"(best depth {best * 1000:.1f} mm of {step.depth * 1000:.1f} "
                                 f"mm, {dither.turns:.1f} dither turns up to "
                                 f"{dither.radius() * 1000:.1f} mm"
                                 + (f"; {rejected} drops of the tool the camera saw were "
                                    "not the block down the peg" if rejected else "") + ")")
            runner.tick(runner.chain if not use_force else ())
    finally:
        if use_force:
            runner.force_off()
            runner.q_target = runner.q_measured()
            runner.tool_target = runner.kin.forward(runner.q_target)


register(StepType(
    "force_insert",
    {"target": pose_schema(), "depth": quantity("length"), "press": quantity("length"),
     "force": quantity("force"), "stiffness": quantity("stiffness"),
     "descent_speed": quantity("speed"), "contact_threshold": quantity("length"),
     "align_tolerance": quantity("length"), "camera_align": {"type": "boolean"},
     "align_limit": quantity("length"),
     "dither": {"type": "object", "additionalProperties": False, "properties": {
         "pattern": {"enum": ["spiral", "circle"]}, "radius": quantity("length"),
         "pitch": quantity("length"), "speed": quantity("speed")}}},
    ("target",), build, run, "pressing insertion with an x-y dither"))
