"""run_task: command-line client of the task node (for shell scripts).

    run_task block_transfer [--timeout 300] [--namespace /hyperarm] [--quiet]

Prints a line per step (and per phase), then the result; exit code 0 on success, 1 on
failure, cancel or rejection (with the task node's reason), 2 on bad use. Ctrl-C or SIGTERM
at any moment stops it: before the goal is sent, no task is sent (exit 1 at once); once it is
sent, the running task is cancelled (the arm holds, force control off) and the node's
confirmation awaited; a second Ctrl-C while cancelling only says it is already cancelling.
The signal handler is installed before rclpy is imported (a shell starts a background job
with SIGINT ignored until a handler is set: the first second of start-up would be deaf).
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time

#: s the client waits, after a Ctrl-C, for the node to confirm the cancel (a cancel is
#: answered in milliseconds; the wait only bounds a node that has gone away).
CANCEL_WAIT = 1.5


class _Interrupted(BaseException):
    """SIGINT/SIGTERM (a BaseException: no library's ``except Exception`` swallows it)."""


def _parse(argv: list[str]) -> argparse.Namespace:
    from rclpy.utilities import remove_ros_args

    from hyperarm_description import contract

    args_no_ros = remove_ros_args(["run_task", *argv])[1:]
    ap = argparse.ArgumentParser(prog="run_task", description=__doc__.split("\n\n")[0])
    ap.add_argument("task", help="task name, e.g. block_transfer, ready, rest")
    ap.add_argument("--timeout", type=float, default=300.0, help="overall timeout, s")
    ap.add_argument("--namespace", default=contract.DEFAULT_NAMESPACE)
    ap.add_argument("--quiet", action="store_true", help="only the result line")
    ap.add_argument("--wait-ready", type=float, default=0.0, metavar="S",
                    help="first wait up to S s for joint_states and the task node")
    ap.add_argument("--wait-force", action="store_true",
                    help="with --wait-ready, also wait for the force node (its "
                         f"{contract.HYBRID_ENABLE} service)")
    ap.add_argument("--wait-detections", action="store_true",
                    help="with --wait-ready, also wait for the camera's first detections "
                         f"on {contract.DETECTIONS} (a rendered camera and its detector "
                         "take seconds to start)")
    return ap.parse_args(args_no_ros)


def _wait_ready(node, client, timeout: float, force: bool = False,
                spin=None, detections: bool = False) -> str | None:
    """Wait for joint_states and the action server (and, with ``force``, the force node's
    enable service; with ``detections``, a first Detections message); None when all are
    there, else what is missing."""
    import rclpy
    spin = spin or (lambda n, t: rclpy.spin_once(n, timeout_sec=t))
    from sensor_msgs.msg import JointState
    from std_srvs.srv import SetBool

    from hyperarm_description import contract
    from hyperarm_description.qos import qos_for

    seen: set[str] = set()
    sub = node.create_subscription(JointState, contract.JOINT_STATES,
                                   lambda m: seen.update(m.name), qos_for(contract.JOINT_STATES))
    enable = node.create_client(SetBool, contract.HYBRID_ENABLE) if force else None
    cameras: list[bool] = []
    cam = None
    if detections:
        from hyperarm_interfaces.msg import Detections
        cam = node.create_subscription(Detections, contract.DETECTIONS,
                                       lambda m: cameras.append(True),
                                       qos_for(contract.DETECTIONS))
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            spin(node, 0.05)
            if (seen and client.server_ready() and (enable is None or enable.service_is_ready())
                    and (cam is None or cameras)):
                return None
        return ("no joint_states from a driver" if not seen
                else "the task node's run_task action is not available"
                if not client.server_ready()
                else f"the force node's {contract.HYBRID_ENABLE} service is not available"
                if enable is not None and not enable.service_is_ready()
                else f"no detections from the camera on {contract.DETECTIONS}")
    finally:
        node.destroy_subscription(sub)
        if enable is not None:
            node.destroy_client(enable)
        if cam is not None:
            node.destroy_subscription(cam)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    state = {"interrupts": 0}

    def on_signal(signum, _frame):
        state["interrupts"] += 1
        if state["interrupts"] == 1:
            state["signal"] = signal.Signals(signum).name
            if state.get("in_rclpy"):
                # raised inside rclpy's C++ calls it came out as a TypeError from pybind
                # (seen: take_feedback); spin() below raises it once spin_once returned
                return
            state["raised"] = True
            raise _Interrupted(state["signal"])
        print("run_task: already cancelling, please wait", file=sys.stderr, flush=True)

    # First of all (rclpy's import and init take a second): from here on a signal stops us.
    # rclpy's own handler would shut the context down before the cancel could go out.
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    try:
        return _main(argv, state)
    except _Interrupted as exc:     # before the goal could be sent: nothing to cancel
        print(f"run_task: {exc} received during start-up: no task sent", file=sys.stderr,
              flush=True)
        return 1


def _main(argv: list[str], state: dict) -> int:
    args = _parse(argv)
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from .task_client import TaskClient, TaskResult

    if state["interrupts"]:   # a library swallowed the exception during its import
        raise _Interrupted("signal")
    rclpy.init(args=["run_task", *argv], signal_handler_options=SignalHandlerOptions.NO)

    def spin(node, timeout: float) -> None:
        """rclpy.spin_once with a Ctrl-C held off until it returns (at most ``timeout``)."""
        state["in_rclpy"] = True
        try:
            rclpy.spin_once(node, timeout_sec=timeout)
        finally:
            state["in_rclpy"] = False
        if state["interrupts"] and not state.get("raised"):
            state["raised"] = True
            raise _Interrupted(state["signal"])

    node = client = None
    code = 1
    try:
        node = rclpy.create_node("run_task_client", namespace=args.namespace)
        client = TaskClient(node, spin=spin)
        if args.wait_ready > 0.0:
            reason = _wait_ready(node, client, args.wait_ready, args.wait_force, spin,
                                 args.wait_detections)
            if reason:
                print(f"run_task: not ready after {args.wait_ready:g} s: {reason}",
                      file=sys.stderr)
                return 1
        if not client.send(args.task, timeout=min(args.timeout, 15.0)):
            print(f"run_task: {client.message}", file=sys.stderr)
            return 1
        deadline = time.monotonic() + args.timeout
        last = None
        while not client.done():
            for fb in ([] if args.quiet else client.new_feedback()):
                if (fb.stage, fb.phase) == last:
                    continue
                if last is None or fb.stage != last[0] or fb.phase == "start":
                    print(f"[{fb.stage_index + 1}/{fb.stage_count}] {fb.stage} ({fb.step_type})",
                          flush=True)
                elif fb.phase != "done":
                    p = fb.waypoint.point
                    where = ([f"tool target {p.x:.3f} {p.y:.3f} {p.z:.3f} m"]
                             if (p.x, p.y, p.z) != (0.0, 0.0, 0.0) else [])
                    where += [f"depth {fb.depth * 1000:.1f} mm"] if fb.depth > 0 else []
                    print(f"      {fb.phase}" + (f" ({', '.join(where)})" if where else ""),
                          flush=True)
                last = (fb.stage, fb.phase)
            if time.monotonic() > deadline:
                print(f"run_task: timeout after {args.timeout:g} s, cancelling", file=sys.stderr)
                client.cancel()
                return 1
        outcome = client.result()
        res = client.result_message()
        extra = ""
        if res is not None and outcome is TaskResult.SUCCEEDED:
            extra = f" in {res.total_time:.1f} s"
            figures = ", ".join(f"{n} {v:.4g}" for n, v in zip(res.metric_names,
                                                               res.metric_values))
            extra += f" ({figures})" if figures else ""
        print(f"run_task: {outcome.name.lower()}: {client.message}{extra}", flush=True)
        if res is not None and len(res.stage_names):
            # every step run, in order (a retried one again), with its duration
            print("run_task: time per step (s): " + ", ".join(
                f"{n} {d:.2f}" for n, d in zip(res.stage_names, res.stage_durations)),
                flush=True)
        code = 0 if outcome is TaskResult.SUCCEEDED else 1
    except _Interrupted as exc:
        if client is None or not client.sent():
            print(f"run_task: {exc} received before the task was sent: no task sent",
                  file=sys.stderr, flush=True)
            return 1
        print(f"run_task: {exc} received, cancelling the task", file=sys.stderr, flush=True)
        try:
            # a goal whose acceptance is still on its way is cancelled as soon as it is known
            client.cancel(timeout=CANCEL_WAIT)
            end = time.monotonic() + CANCEL_WAIT
            while not client.done() and time.monotonic() < end:
                pass
            if client.result_message() is not None:
                print(f"run_task: {client.result().name.lower()}: {client.message}",
                      flush=True)
            elif client.accepted() is False:
                print(f"run_task: {client.message}", flush=True)
            else:
                print(f"run_task: no confirmation of the cancel within {CANCEL_WAIT:g} s",
                      file=sys.stderr, flush=True)
        except _Interrupted:
            pass
        code = 1
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def entry() -> None:
    """The console script: :func:`main`, then the process ends at once. Everything the
    client opened is closed by then (node destroyed, rclpy shut down); the interpreter's
    finalization (Fast DDS's and pinocchio's teardown, about 0.45 s) would only delay
    run_task.sh's stop of the stack after a Ctrl-C (issue 24: within 2 s)."""
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    entry()
