"""`hyperarm`: the robot from the shell, with or without the `ros2` CLI.

ROS subcommands talk to the running nodes (namespace /hyperarm, this shell's ROS_DOMAIN_ID):
state, diag, torque, hold, reboot, home, move, ik, run, traj. Bus subcommands open the serial port
themselves, without ROS (stop the driver first): scan, set-id, set-baud, calibrate.
Exit codes: 0 done, 1 failed or refused (the message says why), 2 bad usage.
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading
from typing import Any, Callable

from hyperarm_description import contract

__all__ = ["main", "build_parser"]


def _fmt(v: float, width: int = 9, prec: int = 4) -> str:
    return "nan".rjust(width) if math.isnan(v) else f"{round(v, prec) + 0.0:{width}.{prec}f}"


# ROS subcommands -------------------------------------------------------------------------
def _client():
    from .ros_client import HyperarmClient
    return HyperarmClient()


def _variant_joints(variant: str) -> tuple[str, ...]:
    from hyperarm_description.model import load_description
    return tuple(load_description(None, variant).limits_by_name())


def _state_table(states: dict[str, tuple], order: tuple[str, ...] = ()) -> str:
    """The joints of ``order`` first, in that order, then any other heard."""
    lines = [f"{'joint':10} {'position':>9} {'velocity':>9} {'effort':>9}"]
    names = [n for n in order if n in states] + [n for n in states if n not in order]
    for name, (p, v, e) in ((n, states[n]) for n in names):
        lines.append(f"{name:10} {_fmt(p)} {_fmt(v)} {_fmt(e)}")
    return "\n".join(lines)


def cmd_state(a: argparse.Namespace) -> int:
    import time

    from .ros_client import MissingJoints

    known = _variant_joints("rail_arm")
    if (unknown := [n for n in a.joints if n not in known]):
        print(f"hyperarm state: no such joint: {', '.join(unknown)} (joints: "
              f"{', '.join(known)})", file=sys.stderr)
        return 2
    required = tuple(a.joints) or _variant_joints(a.variant)
    with _client() as c:
        while True:
            try:
                text = _state_table(c.joint_states(a.timeout, required), required)
            except MissingJoints as exc:
                if a.once:
                    print(_state_table(exc.states, required))
                    raise
                text = _state_table(exc.states, required) + f"\nmissing: {', '.join(exc.missing)}"
            if a.once:
                print(text)
                return 0
            print("\033[H\033[J" + text + "\n(rad, rad/s, N·m; rail m, m/s, N; Ctrl-C to quit)",
                  flush=True)
            time.sleep(0.2)


def cmd_diag(a: argparse.Namespace) -> int:
    levels = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
    with _client() as c:
        statuses = c.diagnostics(a.timeout)
    worst = 0
    for name, s in sorted(statuses.items()):
        level = int.from_bytes(s.level, "little") if isinstance(s.level, bytes) else int(s.level)
        worst = max(worst, level)
        print(f"{levels.get(level, level):5} {name}: {s.message}")
        if a.verbose:
            for kv in s.values:
                print(f"        {kv.key}: {kv.value}")
    return 1 if worst >= 2 else 0


def cmd_torque(a: argparse.Namespace) -> int:
    with _client() as c:
        print(c.set_torque(a.state == "on", a.timeout, rail=a.rail) or f"torque {a.state}")
    return 0


def cmd_hold(a: argparse.Namespace) -> int:
    with _client() as c:
        print(c.trigger(contract.RAIL_HOLD if a.rail else contract.HOLD, a.timeout) or "holding")
    return 0


def cmd_reboot(a: argparse.Namespace) -> int:
    with _client() as c:
        r = c.reboot(list(a.joints), a.timeout)
    print(f"rebooted: {', '.join(r.rebooted) or '(none)'}; {r.message}")
    return 0


def cmd_home(a: argparse.Namespace) -> int:
    import time

    start = time.monotonic()
    with _client() as c:
        started = c.trigger(contract.RAIL_HOME, a.timeout)
        name = c.wait_homed(max(0.0, a.timeout - (time.monotonic() - start)))
    print(f"{started}; homed ({name})" if started else f"homed ({name})")
    return 0


def parse_assignments(items: list[str], limits: dict[str, tuple[float, float]]) -> dict[str, float]:
    """JOINT=VALUE items (rad; rail m) checked against the joint limits: every problem is
    reported and nothing is sent (a command with one bad value is rejected whole)."""
    out, bad = {}, []
    for item in items:
        name, sep, text = item.partition("=")
        if not sep:
            bad.append(f"{item!r}: expected JOINT=VALUE")
            continue
        if name not in limits:
            bad.append(f"{name}: no such joint (joints: {', '.join(limits)})")
            continue
        try:
            value = float(text)
        except ValueError:
            bad.append(f"{name}: {text!r} is not a number")
            continue
        lo, hi = limits[name]
        if not math.isfinite(value) or not lo <= value <= hi:
            bad.append(f"{name}={value:g} outside its limits {lo:.4f}..{hi:.4f}")
        out[name] = value
    if bad:
        raise ValueError("; ".join(bad))
    return out


def cmd_move(a: argparse.Namespace) -> int:
    from hyperarm_description.model import load_description

    limits = load_description(a.description or None, a.variant).limits_by_name()
    try:
        target = parse_assignments(a.assignments, limits)
    except ValueError as exc:
        print(f"hyperarm move: refused, nothing sent: {exc}", file=sys.stderr)
        return 1
    with _client() as c:
        taken = c.send_command(target, a.timeout)
    print("taken: " + ", ".join(f"{n}={v:g} (from {taken[n][0]:.4f})"
                                for n, v in target.items()))
    return 0


def cmd_ik(a: argparse.Namespace) -> int:
    from hyperarm_interfaces.srv import SolveIK

    if len(a.pose) not in (3, 7):
        print(f"hyperarm ik: give X Y Z (m), and optionally QX QY QZ QW (got {len(a.pose)} "
              "numbers)", file=sys.stderr)
        return 2
    req = SolveIK.Request()
    req.target.header.frame_id = contract.BASE_FRAME
    p = req.target.pose.position
    p.x, p.y, p.z = a.pose[:3]
    if len(a.pose) == 7:
        o = req.target.pose.orientation
        o.x, o.y, o.z, o.w = a.pose[3:]
    else:
        req.target.pose.orientation.w = 1.0
        req.position_only = True
    req.solver = a.solver
    with _client() as c:
        r = c.solve_ik(req, a.timeout)
    if not r.success:
        print(f"no solution: {r.message}", file=sys.stderr)
        return 1
    for name, q in zip(r.solution.name, r.solution.position):
        print(f"{name:8} {_fmt(q, 8)}")
    orientation = ("orientation free (position only)" if req.position_only else
                   f"orientation error {r.orientation_error:.2e} rad")
    print(f"position error {r.position_error * 1000:.3f} mm, {orientation}, "
          f"{r.iterations} iterations, {r.solve_time * 1000:.1f} ms")
    return 0


def cmd_run(a: argparse.Namespace) -> int:
    def show(fb: Any) -> None:
        print(f"  [{fb.stage_index + 1}/{fb.stage_count}] {fb.stage} {fb.progress * 100:.0f} %",
              flush=True)

    last: list[str] = []
    with _client() as c:
        r = c.run_task(a.task, a.timeout, lambda fb: (last != [fb.stage] and (
            show(fb), last.clear(), last.append(fb.stage))))
    print(f"task {a.task} done in {r.total_time:.2f} s: {r.message}")
    return 0


def cmd_traj(a: argparse.Namespace) -> int:
    from hyperarm_control.client import TrajectoryFileError, goal_from_file

    try:
        goal = goal_from_file(a.file)
    except TrajectoryFileError as exc:
        print(f"hyperarm traj: refused, nothing sent: {exc}", file=sys.stderr)
        return 1
    points = goal.trajectory.points
    duration = points[-1].time_from_start.sec + 1e-9 * points[-1].time_from_start.nanosec
    print(f"sending {len(points)} points of {', '.join(goal.trajectory.joint_names)} "
          f"({duration:.2f} s) to arm_controller", flush=True)
    shown = [-1.0]

    def show(fb: Any) -> None:
        t = fb.desired.time_from_start.sec + 1e-9 * fb.desired.time_from_start.nanosec
        if t - shown[0] >= 0.5:       # a line every 0.5 s of the trajectory
            shown[0] = t
            worst = max((abs(e) for e in fb.error.positions), default=0.0)
            print(f"  t = {t:6.2f} s   largest path error {worst * 1000:7.2f} mrad",
                  flush=True)

    with _client() as c:
        result, feedback = c.follow_trajectory(goal, a.timeout, show)
    worst = max((abs(e) for f in feedback for e in f.error.positions), default=0.0)
    print(f"trajectory succeeded: largest path error {worst * 1000:.2f} mrad over "
          f"{len(feedback)} feedback messages")
    return 0


# Bus subcommands (no ROS) ----------------------------------------------------------------
def _confirm(question: str, yes: bool) -> bool:
    if yes:
        return True
    if not sys.stdin.isatty():
        print(f"{question} -- refusing without a terminal to confirm on; pass --yes",
              file=sys.stderr)
        return False
    return input(f"{question} [y/N] ").strip().lower() in ("y", "yes")


def cmd_scan(a: argparse.Namespace) -> int:
    from .dxl_tools import COMMON_BAUDS, scan

    bauds = a.baud or list(COMMON_BAUDS)
    found = scan(a.port, bauds, a.ids or None)
    if not found:
        print(f"no Dynamixel answered on {a.port} at {', '.join(map(str, bauds))} baud: check "
              "power, wiring, and that no driver holds the port", file=sys.stderr)
        return 1
    print(f"{'id':>3} {'baud':>8} {'model':12} firmware")
    for f in found:
        print(f"{f.id:3d} {f.baud:8d} {f.model:12} {f.firmware}")
    return 0


def cmd_set_id(a: argparse.Namespace) -> int:
    from .dxl_tools import set_id

    if not _confirm(f"change servo ID {a.old} to {a.new} on {a.port} at {a.baud} baud?", a.yes):
        return 1
    set_id(a.port, a.baud, a.old, a.new)
    print(f"ID {a.old} is now ID {a.new}")
    return 0


def cmd_set_baud(a: argparse.Namespace) -> int:
    from .dxl_tools import set_baud

    if not _confirm(f"set servo {a.id} on {a.port} from {a.baud} to {a.new_baud} baud?", a.yes):
        return 1
    set_baud(a.port, a.baud, a.id, a.new_baud)
    print(f"ID {a.id} now answers at {a.new_baud} baud")
    return 0


def cmd_calibrate(a: argparse.Namespace) -> int:
    from hyperarm_description.model import load_description

    from .dxl_tools import read_ticks, write_calibrated_copy, zero_offsets

    desc = load_description(a.description or None, a.variant)
    pose = {}
    for item in a.pose:
        name, _, text = item.partition("=")
        pose[name] = float(text)
    ticks = read_ticks(a.port, a.baud, [j.servo.id for j in desc.joints])
    offsets = zero_offsets(a.description or None, a.variant, ticks, pose)
    print(f"{'joint':8} {'id':>3} {'ticks':>6} zero_offset (rad)")
    for j in desc.joints:
        print(f"{j.name:8} {j.servo.id:3d} {ticks[j.servo.id]:6d} {offsets[j.name]:+.6f}")
    out = write_calibrated_copy(a.description or None, offsets, a.output, a.variant)
    print(f"written to {out}; use it with --ros-args -p description_file:={out}")
    return 0


# parser ----------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hyperarm", description=__doc__.split("\n\n")[0],
                                epilog=__doc__.split("\n\n", 1)[1],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)

    def add(name: str, fn: Callable[[argparse.Namespace], int], text: str,
            timeout: float = 5.0) -> argparse.ArgumentParser:
        sp = sub.add_parser(name, help=text, description=text)
        sp.set_defaults(fn=fn)
        sp.add_argument("--timeout", type=float, default=timeout,
                        help=f"seconds to wait for the nodes (default {timeout:g})")
        return sp

    variant = os.environ.get("HYPERARM_VARIANT", "arm")
    sp = add("state", cmd_state, "live table of the joints (joint_states of every driver); "
             "waits for every joint of the variant, exit 1 naming those missing")
    sp.add_argument("--once", action="store_true", help="print one table and exit")
    sp.add_argument("--variant", default=variant, choices=("arm", "rail_arm"),
                    help=f"whose joints to wait for (default {variant}: $HYPERARM_VARIANT "
                    "or arm)")
    sp.add_argument("--joints", nargs="+", default=[], metavar="JOINT",
                    help="wait for these joints instead (e.g. --joints rail: the rail driver "
                    "alone)")
    sp = add("diag", cmd_diag, "diagnostics summary (/diagnostics); exit 1 on an ERROR",
             timeout=3.0)
    sp.add_argument("-v", "--verbose", action="store_true", help="show every key/value")
    sp = add("torque", cmd_torque, "switch torque on or off (set_torque)")
    sp.add_argument("state", choices=("on", "off"))
    sp.add_argument("--rail", action="store_true", help="the rail (rail/set_torque)")
    sp = add("hold", cmd_hold, "stop where you are (hold)")
    sp.add_argument("--rail", action="store_true", help="the rail (rail/hold)")
    sp = add("reboot", cmd_reboot, "reboot servos (none named: those reporting an error)",
             timeout=10.0)
    sp.add_argument("joints", nargs="*", metavar="JOINT")
    add("home", cmd_home, "home the rail (rail/home, rail_arm) and wait until /diagnostics "
        "reports it homed", timeout=120.0)
    sp = add("move", cmd_move, "command joints: JOINT=VALUE (rad; rail m), limits checked; "
             "waits until joint_states shows every joint taking its goal (exit 1 with the "
             "driver's refusal, or naming the joints that did not move)")
    sp.add_argument("assignments", nargs="+", metavar="JOINT=VALUE")
    sp.add_argument("--variant", default=variant, choices=("arm", "rail_arm"),
                    help=f"whose joint limits (default {variant}: $HYPERARM_VARIANT or arm)")
    sp.add_argument("--description", default="", help="robot YAML ('' = packaged)")
    sp = add("ik", cmd_ik, "solve IK for a tool0 pose in base_link (solve_ik); prints joints")
    sp.usage = "hyperarm ik [-h] [--timeout TIMEOUT] [--solver SOLVER] X Y Z [QX QY QZ QW]"
    sp.add_argument("pose", type=float, nargs="*", metavar="X Y Z [QX QY QZ QW]",
                    help="tool0's position (m), then optionally its orientation as a "
                    "quaternion (none: position only)")
    sp.add_argument("--solver", default="", help="solver name ('' = the service default)")
    sp = add("run", cmd_run, "run a task on task_node (run_task action)", timeout=300.0)
    sp.add_argument("task")
    sp = add("traj", cmd_traj, "send a joint trajectory file (YAML: joint_names, points with "
             "time and positions, optional velocities and tolerances; docs/ros-interfaces.md) "
             "to arm_controller (FollowJointTrajectory) and wait for the result; Ctrl-C "
             "cancels (the arm holds)", timeout=10.0)
    sp.add_argument("file", help="the trajectory YAML")

    def bus(name: str, fn: Callable[[argparse.Namespace], int], text: str,
            baud: bool = True) -> argparse.ArgumentParser:
        sp = sub.add_parser(name, help=text, description=text + " No ROS; stop the driver "
                            "first (one process per port).")
        sp.set_defaults(fn=fn)
        sp.add_argument("--port", default="/dev/hyperarm_u2d2", help="serial device")
        if baud:
            sp.add_argument("--baud", type=int, default=1_000_000, help="the servos' baud rate")
        return sp

    sp = bus("scan", cmd_scan, "ping the bus over baud rates and list ID, model, firmware.",
             baud=False)
    sp.add_argument("--baud", type=int, action="append", default=[],
                    help="a rate to try (repeatable; default the common ones)")
    sp.add_argument("--ids", type=int, nargs="*", default=[], help="only these IDs")
    sp = bus("set-id", cmd_set_id, "give a servo another ID (asks for confirmation).")
    sp.add_argument("old", type=int)
    sp.add_argument("new", type=int)
    sp.add_argument("--yes", action="store_true", help="do not ask")
    sp = bus("set-baud", cmd_set_baud, "change a servo's baud rate (asks for confirmation).")
    sp.add_argument("id", type=int)
    sp.add_argument("new_baud", type=int)
    sp.add_argument("--yes", action="store_true", help="do not ask")
    sp = bus("calibrate", cmd_calibrate, "zero-offset calibration: with the arm held in the "
             "calibration pose, record the present ticks and write zero_offset into a copy of "
             "the description (docs/user-guide.md).")
    sp.add_argument("--output", required=True, help="the calibrated copy to write")
    sp.add_argument("--pose", nargs="*", default=[], metavar="JOINT=RAD",
                    help="the calibration pose (default all joints 0)")
    sp.add_argument("--variant", default="arm", choices=("arm", "rail_arm"))
    sp.add_argument("--description", default="", help="robot YAML ('' = packaged)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    interrupted: list[int] = []

    def on_sigint(signum: int, frame: Any) -> None:
        interrupted.append(signum)
        signal.default_int_handler(signum, frame)   # KeyboardInterrupt, as before

    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, on_sigint) if main_thread else None
    try:
        return args.fn(args)
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # one clear line, never a traceback, for the errors we know
        if interrupted:
            # a Ctrl-C inside a library's C code comes out as that library's error (seen:
            # rclpy's import during a Ctrl-C raised ImportError "initialization failed")
            print(f"hyperarm {args.command}: interrupted ({type(exc).__name__}: {exc})",
                  file=sys.stderr)
            return 130
        from .dxl_tools import BusToolError
        known: tuple[type, ...] = (BusToolError, OSError, ValueError)
        try:
            from .ros_client import ClientError
            known += (ClientError,)
        except ImportError:
            pass
        try:
            from hyperarm_description.model import DescriptionError
            known += (DescriptionError,)
        except ImportError:
            pass
        if isinstance(exc, known):
            print(f"hyperarm {args.command}: {exc}", file=sys.stderr)
            return 1
        raise
    finally:
        if main_thread:
            signal.signal(signal.SIGINT, previous)


if __name__ == "__main__":
    sys.exit(main())
