"""run_task: command-line client of the task node (for shell scripts).

    run_task ready [--timeout 60] [--namespace /hyperarm]

Prints stage feedback; exit code 0 on success, 1 on failure/cancel/rejection, 2 on bad use.
Ctrl-C cancels the running task before exiting.
"""
from __future__ import annotations

import argparse
import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException

from hyperarm_description import contract

from .task_client import TaskClient, TaskResult


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args_no_ros = rclpy.utilities.remove_ros_args(["run_task", *argv])[1:]
    ap = argparse.ArgumentParser(prog="run_task", description=__doc__.split("\n\n")[0])
    ap.add_argument("task", help="task name, e.g. ready, rest")
    ap.add_argument("--timeout", type=float, default=120.0, help="overall timeout, s")
    ap.add_argument("--namespace", default=contract.DEFAULT_NAMESPACE)
    args = ap.parse_args(args_no_ros)
    rclpy.init(args=["run_task", *argv])
    node = rclpy.create_node("run_task_client", namespace=args.namespace)
    client = TaskClient(node)
    code = 1
    try:
        if not client.send(args.task, timeout=min(args.timeout, 15.0)):
            print(f"run_task: {client.message}", file=sys.stderr)
            return 1
        deadline = time.monotonic() + args.timeout
        last = None
        while not client.done():
            fb = client.feedback()
            if fb is not None and fb.stage != last:
                last = fb.stage
                print(f"[{fb.stage_index + 1}/{fb.stage_count}] {fb.stage}", flush=True)
            if time.monotonic() > deadline:
                print(f"run_task: timeout after {args.timeout:g} s, cancelling", file=sys.stderr)
                client.cancel()
                return 1
        outcome = client.result()
        print(f"run_task: {outcome.name.lower()}: {client.message}", flush=True)
        code = 0 if outcome is TaskResult.SUCCEEDED else 1
    except (KeyboardInterrupt, ExternalShutdownException):
        print("run_task: interrupted, cancelling the task", file=sys.stderr)
        if rclpy.ok():
            client.cancel(timeout=2.0)
        code = 1
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
