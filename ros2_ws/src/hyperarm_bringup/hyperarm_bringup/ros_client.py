"""A small rclpy facade for the `hyperarm` command line (nav2_simple_commander-like).

The caller owns it (``with HyperarmClient() as c:``); every call spins the node briefly and
raises :class:`ClientError` with a sentence a user can act on: no node serving the name, no
answer within the timeout, a refusal (success=false and the node's message).
"""
from __future__ import annotations

import os
import sys
import time
from typing import Any, Callable

import rclpy
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from hyperarm_description import contract
from hyperarm_description.qos import qos_for
from hyperarm_interfaces.srv import Reboot, SolveIK

from .confirm import GoalWatch, is_refusal, missing_joints

__all__ = ["ClientError", "HyperarmClient", "MissingJoints"]


class ClientError(Exception):
    """A command could not be done; the message says why."""


class MissingJoints(ClientError):
    """joint_states came, but without some joints asked for (``missing``); ``states`` holds
    what was heard (name -> (position, velocity, effort))."""

    def __init__(self, text: str, states: dict[str, tuple], missing: list[str]) -> None:
        super().__init__(text)
        self.states, self.missing = states, missing


# /rosout as rcl publishes it (RMW_QOS_PROFILE_ROSOUT_DEFAULT: reliable, transient local)
_ROSOUT_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)


# s after the first send during which a driver's refusal is awaited even when every joint
# already sits at its goal (a refusal is logged within milliseconds of the command)
_REFUSAL_WAIT = 0.15


def _level(status: Any) -> int:
    """A DiagnosticStatus level as an int (rclpy gives bytes for the byte field)."""
    lvl = status.level
    return int.from_bytes(lvl, "little") if isinstance(lvl, bytes) else int(lvl)


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

    def _joint_state_listener(self) -> tuple[Any, dict[str, tuple], list[int]]:
        """A joint_states subscription filling name -> (position, velocity, effort), newest
        first wins, and a one-item list holding the number of distinct joint-name sets heard
        (each driver publishes its own fixed set: the number of drivers heard from)."""
        out: dict[str, tuple] = {}
        sets: set[tuple[str, ...]] = set()
        heard = [0]

        def on_state(msg: JointState) -> None:
            for i, name in enumerate(msg.name):
                pick = (lambda seq: seq[i] if i < len(seq) else float("nan"))
                out[name] = (pick(msg.position), pick(msg.velocity), pick(msg.effort))
            sets.add(tuple(msg.name))
            heard[0] = len(sets)

        sub = self.node.create_subscription(JointState, contract.JOINT_STATES, on_state,
                                            qos_for(contract.JOINT_STATES))
        return sub, out, heard

    def joint_states(self, timeout: float, required: tuple[str, ...] = (),
                     grace: float = 0.5) -> dict[str, tuple]:
        """name -> (position, velocity, effort) merged over every driver's joint_states
        (arm driver and rail driver publish their own joints).

        Waits until every joint in ``required`` has been heard and every publisher of
        joint_states in the graph has been heard from (at most ``grace`` s more once the
        required ones are in: a driver whose bus is down publishes nothing). Raises
        :class:`MissingJoints` (carrying what was heard) if a required joint is still
        missing at ``timeout``, :class:`ClientError` if nothing came at all.
        """
        sub, out, heard = self._joint_state_listener()
        complete_at: list[float] = []

        def done() -> bool:
            if not out or missing_joints(required, out):
                return False
            if not complete_at:
                complete_at.append(time.monotonic())
            return (heard[0] >= self.node.count_publishers(contract.JOINT_STATES)
                    or time.monotonic() - complete_at[0] >= grace)
        try:
            self._spin_until(done, timeout)
        finally:
            self.node.destroy_subscription(sub)
        if not out:
            raise ClientError(f"nothing on {self._full(contract.JOINT_STATES)} within "
                              f"{timeout:g} s: is a driver running ({_where()})?")
        if (missing := missing_joints(required, out)):
            raise MissingJoints(
                f"no joint_states for {', '.join(missing)} within {timeout:g} s (heard: "
                f"{', '.join(out)}): is their driver running, and is the variant right "
                f"({_where()})?", dict(out), missing)
        return dict(out)

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

    def wait_homed(self, timeout: float) -> str:
        """After rail/home answered: wait until a /diagnostics status reports ``homed``
        true (the rail drivers and the mock do), and return its name. ClientError when it
        reports false for ``timeout`` s (with its message), or when no status reports
        ``homed`` at all."""
        seen: dict[str, tuple[str, str]] = {}     # status name -> (homed, message)

        def on_diag(m: DiagnosticArray) -> None:
            for st in m.status:
                homed = next((kv.value for kv in st.values if kv.key == "homed"), None)
                if homed is not None:
                    seen[st.name] = (homed.lower(), st.message)

        sub = self.node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, on_diag,
                                            qos_for(contract.DIAGNOSTICS))
        try:
            self._spin_until(lambda: any(h == "true" for h, _ in seen.values()), timeout)
        finally:
            self.node.destroy_subscription(sub)
        for name, (homed, _) in seen.items():
            if homed == "true":
                return name
        if not seen:
            raise ClientError(f"no /diagnostics status reported 'homed' within {timeout:g} s "
                              f"({_where()}): is the rail homed? see `hyperarm diag -v`")
        raise ClientError("home started, but not homed within "
                          f"{timeout:g} s: " + "; ".join(f"{n}: {m}" for n, (_, m)
                                                         in seen.items()))

    def _refusals(self, since_ns: int) -> tuple[Any, list[str]]:
        """A /rosout subscription collecting the warnings and errors, logged after
        ``since_ns`` (ns since the epoch), in which a node says it did not apply a
        joint_command (confirm.is_refusal); transient-local, so a refusal logged before
        the subscription matched is still heard."""
        from rcl_interfaces.msg import Log

        found: list[str] = []

        def on_log(m: Log) -> None:
            stamp = m.stamp.sec * 1_000_000_000 + m.stamp.nanosec
            if stamp >= since_ns and m.level >= Log.WARN and is_refusal(m.msg):
                found.append(f"{m.name}: {m.msg}")

        sub = self.node.create_subscription(Log, "/rosout", on_log, _ROSOUT_QOS)
        return sub, found

    def send_command(self, targets: dict[str, float], timeout: float,
                     resend: float = 1.0) -> dict[str, tuple[float, float]]:
        """Send ``targets`` (joint -> rad; rail m) once on joint_command and confirm it.

        1. every named joint is heard on joint_states (so its driver runs);
        2. the command's publisher has matched every subscriber of joint_command in the
           graph, and at least one per driver heard (a driver publishes one set of joints);
        3. it is published (re-sent every ``resend`` s while unconfirmed: a position goal is
           idempotent), and each joint must be seen taking its goal (confirm.GoalWatch).

        Returns joint -> (position before, position that showed the goal taken). Raises
        :class:`ClientError` with the driver's own words when a driver logs a refusal, and
        with the drivers' diagnostics when ``timeout`` s (in all) pass unconfirmed.
        """
        deadline = time.monotonic() + timeout
        sub, states, _ = self._joint_state_listener()
        sets: set[tuple[str, ...]] = set()
        owners = [0]

        def count_owners(msg: JointState) -> None:
            if set(msg.name) & set(targets):
                sets.add(tuple(msg.name))
                owners[0] = len(sets)

        owner_sub = self.node.create_subscription(JointState, contract.JOINT_STATES,
                                                  count_owners, qos_for(contract.JOINT_STATES))
        pub = self.node.create_publisher(JointState, contract.JOINT_COMMAND,
                                         qos_for(contract.JOINT_COMMAND))
        log_sub, refusals = self._refusals(time.time_ns())
        left = lambda: max(0.0, deadline - time.monotonic())  # noqa: E731
        try:
            if not self._spin_until(lambda: not missing_joints(targets, states), left()):
                raise ClientError(
                    f"no joint_states for {', '.join(missing_joints(targets, states))} "
                    f"within {timeout:g} s: is its driver running ({_where()})? nothing sent")

            def matched() -> bool:
                # every reader our (volatile) writer can match: not a transient-local one
                graph = sum(1 for e in self.node.get_subscriptions_info_by_topic(
                    self._full(contract.JOINT_COMMAND))
                    if e.qos_profile.durability != DurabilityPolicy.TRANSIENT_LOCAL)
                return pub.get_subscription_count() >= max(1, graph, owners[0])
            if not self._spin_until(matched, left()):
                raise ClientError(
                    f"the drivers owning {', '.join(targets)} have not all matched "
                    f"{self._full(contract.JOINT_COMMAND)} within {timeout:g} s "
                    f"({pub.get_subscription_count()} subscriber(s) matched; {_where()}): "
                    "nothing sent")
            start = {n: states[n][0] for n in targets}
            watch = GoalWatch(targets, start)
            sent_at, first_sent = [-1e9], []

            def confirmed() -> bool:
                if refusals:
                    return True
                watch.update({n: v[0] for n, v in states.items()})
                # sent at least once, and long enough ago for a refusal to be logged
                if (watch.done() and first_sent
                        and time.monotonic() - first_sent[0] >= _REFUSAL_WAIT):
                    return True
                if time.monotonic() - sent_at[0] >= resend:
                    msg = JointState(name=list(targets), position=list(targets.values()))
                    msg.header.stamp = self.node.get_clock().now().to_msg()
                    pub.publish(msg)
                    pub.wait_for_all_acked(Duration(seconds=min(0.5, left())))
                    sent_at[0] = time.monotonic()
                    first_sent[:] = first_sent or [sent_at[0]]
                return False
            self._spin_until(confirmed, left())
            if refusals:
                raise ClientError("refused: " + "; ".join(dict.fromkeys(refusals)))
            if not watch.done():
                where = ", ".join(f"{n} at {states[n][0]:.4f} (goal {targets[n]:g})"
                                  for n in watch.pending())
                raise ClientError(f"sent, but not taken within {timeout:g} s: {where}"
                                  + self._diagnostic_problems())
            return {n: (start[n], watch.taken[n]) for n in targets}
        finally:
            for s in (sub, owner_sub, log_sub):
                self.node.destroy_subscription(s)
            self.node.destroy_publisher(pub)

    def _diagnostic_problems(self, listen: float = 1.2) -> str:
        """'; the drivers report: ...' with every non-OK /diagnostics status heard within
        ``listen`` s, or a pointer to `hyperarm diag` when there is none."""
        try:
            statuses = self.diagnostics(listen)
        except ClientError:
            statuses = {}
        bad = [f"{name}: {s.message}" for name, s in sorted(statuses.items())
               if _level(s) >= 1]
        return ("; the drivers report: " + "; ".join(bad)) if bad else (
            "; no refusal was logged (see `hyperarm diag` and the driver's log)")

    # services
    def call(self, srv_type: Any, name: str, request: Any, timeout: float) -> Any:
        client = self.node.create_client(srv_type, name)
        try:
            # (polled at the spin period: Client.wait_for_service sleeps 0.25 s a look)
            if not self._spin_until(client.service_is_ready, min(timeout, 5.0)):
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
        """Run ``task`` on task_node. Ctrl-C (KeyboardInterrupt) at any moment cancels it
        (a goal whose acceptance is still on its way is cancelled once known), prints the
        node's confirmation and re-raises; a second Ctrl-C meanwhile only says so."""
        import signal

        from rclpy.signals import (get_current_signal_handlers_options,
                                   install_signal_handlers, uninstall_signal_handlers)

        from hyperarm_tasks.task_client import TaskClient, TaskResult

        # rclpy's SIGINT handler shuts the context down: the cancel could not be confirmed
        # (it raised RCLError 'the given context is not valid'). Python's own handler meanwhile.
        options = get_current_signal_handlers_options()
        uninstall_signal_handlers()
        client = TaskClient(self.node)
        try:
            if not client.send(task, timeout=min(timeout, 10.0)):
                if "not available" in client.message:     # never reached task_node
                    raise ClientError(f"no task_node serves {self._full(contract.RUN_TASK)} "
                                      f"within {min(timeout, 10.0):g} s (--timeout; {_where()}): "
                                      "is task_node running?")
                raise ClientError(f"task_node did not accept task {task!r} ({_where()}): "
                                  f"{client.message}")
            deadline = time.monotonic() + timeout
            while not client.done():
                if time.monotonic() > deadline:
                    client.cancel()
                    raise ClientError(f"task {task!r} not done within {timeout:g} s (canceled)")
                fb = client.feedback()
                if fb is not None:
                    on_feedback(fb)
        except KeyboardInterrupt:
            previous = signal.signal(signal.SIGINT, lambda *_: print(
                "already cancelling, please wait", file=sys.stderr, flush=True))
            try:
                if client.sent():
                    print(f"Ctrl-C: cancelling task {task!r}", file=sys.stderr, flush=True)
                    client.cancel(timeout=1.5)
                    end = time.monotonic() + 1.5
                    while not client.done() and time.monotonic() < end:
                        pass
                    if client.result_message() is not None:
                        print(f"task {task!r} {client.result().name.lower()}: {client.message}",
                              file=sys.stderr, flush=True)
            finally:
                signal.signal(signal.SIGINT, previous)
            raise
        finally:
            install_signal_handlers(options)
        result = client.result()
        msg = client.result_message()
        if result is TaskResult.REJECTED:   # the node's reason (it names the task)
            raise ClientError(client.message)
        if result is not TaskResult.SUCCEEDED:
            raise ClientError(f"task {task!r} {result.name.lower()}: "
                              f"{msg.message if msg else ''}")
        return msg

    def follow_trajectory(self, goal: Any, timeout: float,
                          on_feedback: Callable[[Any], None]) -> tuple[Any, list[Any]]:
        """Send a FollowJointTrajectory ``goal`` to arm_controller and wait for its result:
        ``timeout`` s for the server, then the trajectory's duration + ``timeout``. Returns
        (result, feedback) on success; ClientError with the controller's error code and
        message otherwise. Ctrl-C (KeyboardInterrupt) cancels the goal (the arm holds), says
        so and re-raises."""
        from hyperarm_control.client import RESULT_NAMES, TrajectoryClient

        client = TrajectoryClient(self.node, contract.ARM_TRAJECTORY_ACTION)
        name = self._full(contract.ARM_TRAJECTORY_ACTION)
        if not self._spin_until(client.server_ready, timeout):
            raise ClientError(f"no arm_controller serves {name} within {timeout:g} s "
                              f"(--timeout; {_where()}): is arm_controller running, and are "
                              "the drivers publishing joint_states?")
        points = goal.trajectory.points
        duration = (points[-1].time_from_start.sec + 1e-9 * points[-1].time_from_start.nanosec
                    if points else 0.0)
        seen = [0]

        def progress() -> bool:
            fb = client.feedback()
            for f in fb[seen[0]:]:
                on_feedback(f)
            seen[0] = len(fb)
            return client.done()

        from rclpy.signals import (get_current_signal_handlers_options,
                                   install_signal_handlers, uninstall_signal_handlers)

        # rclpy's SIGINT handler shuts the context down: the cancel could not be confirmed
        # (RCLError 'the given context is not valid'). Python's own handler meanwhile.
        options = get_current_signal_handlers_options()
        uninstall_signal_handlers()
        client.send(goal)
        try:
            if not self._spin_until(progress, duration + timeout):
                client.cancel()
                self._spin_until(client.done, 1.5)
                raise ClientError(f"no result from {name} within {duration + timeout:g} s "
                                  "(the trajectory's duration + --timeout; is arm_controller "
                                  "still running?): cancel sent")
        except KeyboardInterrupt:
            print("Ctrl-C: cancelling the trajectory (the arm holds)", file=sys.stderr,
                  flush=True)
            client.cancel()
            if self._spin_until(client.done, 1.5):
                status, result = client.result()
                text = result.error_string if result is not None else ""
                print(f"arm_controller: {'canceled' if status == 5 else f'status {status}'}"
                      f"{': ' + text if text else ''}", file=sys.stderr, flush=True)
            raise
        finally:
            install_signal_handlers(options)
        if client.accepted() is False:
            raise ClientError(f"{name} rejected the goal")
        status, result = client.result()
        if status != 4:   # action_msgs GoalStatus: 4 succeeded, 5 canceled, 6 aborted
            how = {5: "canceled", 6: "aborted"}.get(status, f"ended with status {status}")
            raise ClientError(f"trajectory {how}: {RESULT_NAMES.get(result.error_code, '?')} "
                              f"({result.error_code}): {result.error_string}")
        return result, client.feedback()
