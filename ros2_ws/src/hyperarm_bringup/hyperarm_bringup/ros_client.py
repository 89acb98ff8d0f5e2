"""A small rclpy facade for the `hyperarm` command line (nav2_simple_commander-like).

The caller owns it (``with HyperarmClient() as c:``); every call spins the node briefly and
raises :class:`ClientError` with a sentence a user can act on: no node serving the name, no
answer within the timeout, a refusal (success=false and the node's message).
"""
from __future__ import annotations

import os
import time
from typing import Any, Callable

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from hyperarm_description import contract
from hyperarm_description.qos import qos_for
from hyperarm_interfaces.srv import Reboot, SolveIK

__all__ = ["ClientError", "HyperarmClient"]


class ClientError(Exception):
    """A command could not be done; the message says why."""


def _where() -> str:
    return f"ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}"


class HyperarmClient:
    def __init__(self, namespace: str = contract.DEFAULT_NAMESPACE) -> None:
        rclpy.init()
        self.namespace = namespace
        self.node = rclpy.create_node("hyperarm_cli", namespace=namespace)

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.try_shutdown()

    def __enter__(self) -> "HyperarmClient":
        return self

    def __exit__(self, *_: Any) -> None:
        self.close()

    def _full(self, name: str) -> str:
        return name if name.startswith("/") else f"{self.namespace}/{name}"

    def _spin_until(self, done: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not done():
            if time.monotonic() > deadline:
                return False
            rclpy.spin_once(self.node, timeout_sec=0.05)
        return True

    # topics
    def collect(self, msg_type: Any, topic: str, count: int, timeout: float) -> list[Any]:
        """The first ``count`` messages on ``topic``; ClientError if none came in time."""
        got: list[Any] = []
        qos = qos_for(topic) if topic in contract.QOS else 10
        sub = self.node.create_subscription(msg_type, topic, got.append, qos)
        try:
            self._spin_until(lambda: len(got) >= count, timeout)
        finally:
            self.node.destroy_subscription(sub)
        if not got:
            raise ClientError(f"nothing on {self._full(topic)} within {timeout:g} s: is a "
                              f"driver running ({_where()})?")
        return got

    def joint_states(self, timeout: float, window: float = 0.3) -> dict[str, tuple]:
        """name -> (position, velocity, effort) merged over every driver's joint_states
        (arm driver and rail driver publish their own joints)."""
        first = self.collect(JointState, contract.JOINT_STATES, 1, timeout)
        more = []
        sub = self.node.create_subscription(JointState, contract.JOINT_STATES, more.append,
                                            qos_for(contract.JOINT_STATES))
        self._spin_until(lambda: False, window)
        self.node.destroy_subscription(sub)
        out: dict[str, tuple] = {}
        for msg in first + more:
            for i, name in enumerate(msg.name):
                pick = (lambda seq: seq[i] if i < len(seq) else float("nan"))
                out[name] = (pick(msg.position), pick(msg.velocity), pick(msg.effort))
        return out

    def diagnostics(self, timeout: float) -> dict[str, Any]:
        """name -> the newest DiagnosticStatus of every hyperarm component on /diagnostics.

        Listens until ``timeout`` s have passed since the last publisher of /diagnostics was
        discovered (DDS discovery of a fresh process takes a moment and must not eat a
        node's listening window), at most three times ``timeout`` in all.
        """
        out: dict[str, Any] = {}
        sub = self.node.create_subscription(
            DiagnosticArray, contract.DIAGNOSTICS,
            lambda m: out.update({s.name: s for s in m.status}), qos_for(contract.DIAGNOSTICS))
        start = time.monotonic()
        deadline, known = start + timeout, 0
        try:
            while time.monotonic() < min(deadline, start + 3 * timeout):
                rclpy.spin_once(self.node, timeout_sec=0.05)
                count = self.node.count_publishers(contract.DIAGNOSTICS)
                if count > known:
                    deadline = time.monotonic() + timeout
                known = count
        finally:
            self.node.destroy_subscription(sub)
        if not out:
            raise ClientError(f"no /diagnostics within {timeout:g} s: is a node running "
                              f"({_where()})?")
        return out

    def publish_command(self, msg: JointState, timeout: float) -> None:
        pub = self.node.create_publisher(JointState, contract.JOINT_COMMAND,
                                         qos_for(contract.JOINT_COMMAND))
        try:
            if not self._spin_until(lambda: pub.get_subscription_count() > 0, timeout):
                raise ClientError(f"no driver subscribes to {self._full(contract.JOINT_COMMAND)}"
                                  f" ({_where()})")
            pub.publish(msg)
            self._spin_until(lambda: False, 0.2)  # let it go out before the node goes
        finally:
            self.node.destroy_publisher(pub)

    # services
    def call(self, srv_type: Any, name: str, request: Any, timeout: float) -> Any:
        client = self.node.create_client(srv_type, name)
        try:
            if not client.wait_for_service(timeout_sec=min(timeout, 5.0)):
                raise ClientError(f"no node serves {self._full(name)} ({_where()}): start the "
                                  "driver, or check the variant (rail/ services: rail_arm)")
            future = client.call_async(request)
            if not self._spin_until(future.done, timeout):
                raise ClientError(f"{self._full(name)} did not answer within {timeout:g} s")
            return future.result()
        finally:
            self.node.destroy_client(client)

    def _checked(self, response: Any, name: str) -> Any:
        if not response.success:
            raise ClientError(f"{self._full(name)} refused: {response.message}")
        return response

    def set_torque(self, on: bool, timeout: float, rail: bool = False) -> str:
        name = contract.RAIL_SET_TORQUE if rail else contract.SET_TORQUE
        return self._checked(self.call(SetBool, name, SetBool.Request(data=on), timeout),
                             name).message

    def trigger(self, name: str, timeout: float) -> str:
        return self._checked(self.call(Trigger, name, Trigger.Request(), timeout), name).message

    def reboot(self, joints: list[str], timeout: float) -> Any:
        return self._checked(self.call(Reboot, contract.REBOOT, Reboot.Request(joints=joints),
                                       timeout), contract.REBOOT)

    def solve_ik(self, request: Any, timeout: float) -> Any:
        return self.call(SolveIK, contract.SOLVE_IK, request, timeout)

    def run_task(self, task: str, timeout: float, on_feedback: Callable[[Any], None]) -> Any:
        from hyperarm_tasks.task_client import TaskClient, TaskResult

        client = TaskClient(self.node)
        if not client.send(task, timeout=min(timeout, 10.0)):
            raise ClientError(f"task_node did not accept task {task!r} ({_where()}): is "
                              "task_node running, and is the task name right?")
        deadline = time.monotonic() + timeout
        try:
            while not client.done():
                if time.monotonic() > deadline:
                    client.cancel()
                    raise ClientError(f"task {task!r} not done within {timeout:g} s (canceled)")
                fb = client.feedback()
                if fb is not None:
                    on_feedback(fb)
        except KeyboardInterrupt:
            client.cancel()
            raise
        result = client.result()
        msg = client.result_message()
        if result is not TaskResult.SUCCEEDED:
            raise ClientError(f"task {task!r} {result.name.lower()}: "
                              f"{msg.message if msg else ''}")
        return msg
