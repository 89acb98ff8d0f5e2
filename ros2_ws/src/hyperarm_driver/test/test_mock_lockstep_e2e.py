"""End-to-end tier: the mock's lockstep option (``lockstep_timeout``, on simulated time)
through the installed mock_driver.

While a controller answers each joint_states with a joint_command of the same header
stamp, every tick waits for that answer (at most ``lockstep_timeout`` s of wall time): a
controller that takes 60 ms to answer slows the simulation to its pace instead of missing
steps; when the answers stop, one timeout later the simulation runs at its rate again;
nobody answering, it never waits.
"""
from __future__ import annotations

import threading
import time

import pytest

from hyperarm_description import contract
from hyperarm_description.qos import qos_for

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


def test_lockstep_waits_for_the_answering_command(launch, rclpy_context, executor, wait_for):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState

    launch("hyperarm_driver", "mock_driver", params={
        "sim_speed": 1.0, "lockstep_timeout": 0.5, "diagnostics_period": 0.2})
    probe = rclpy.create_node("lockstep_probe", namespace=contract.DEFAULT_NAMESPACE,
                              context=rclpy_context)
    arrivals: list[float] = []
    answer = {"delay": None}            # s before answering a state; None: no answer
    cmd = probe.create_publisher(JointState, contract.JOINT_COMMAND,
                                 qos_for(contract.JOINT_COMMAND))

    def reply(msg: JointState) -> None:
        out = JointState(name=list(contract.ARM_JOINTS))
        out.header.stamp = msg.header.stamp
        out.position = [p for n, p in zip(msg.name, msg.position) if n in contract.ARM_JOINTS]
        cmd.publish(out)

    def on_state(msg: JointState) -> None:
        arrivals.append(time.monotonic())
        delay = answer["delay"]
        if delay is not None:
            threading.Timer(delay, reply, args=(msg,)).start()
    probe.create_subscription(JointState, contract.JOINT_STATES, on_state,
                              qos_for(contract.JOINT_STATES))
    lockstep: list[dict] = []
    probe.create_subscription(
        DiagnosticArray, contract.DIAGNOSTICS,
        lambda m: lockstep.extend({kv.key: kv.value for kv in st.values} for st in m.status
                                  if st.name == "mock_driver: lockstep"),
        qos_for(contract.DIAGNOSTICS))
    executor.add_node(probe)

    def rate(seconds: float) -> float:
        """joint_states per second of wall time over the next ``seconds``."""
        n0, t0 = len(arrivals), time.monotonic()
        time.sleep(seconds)
        return (len(arrivals) - n0) / (time.monotonic() - t0)

    try:
        wait_for(lambda: len(arrivals) > 20 and lockstep, 30.0, what="joint_states")
        free = rate(1.0)                          # nobody answers: no wait
        answer["delay"] = 0.06
        time.sleep(0.3)
        paced = rate(1.5)                         # each tick waits ~60 ms for the answer
        answer["delay"] = None
        time.sleep(0.7)                           # one timeout (0.5 s), then free again
        after = rate(1.0)
        wait_for(lambda: lockstep[-1]["engaged"] == "False", 5.0, what="disengaged")
        print(f"joint_states per s: {free:.1f} free, {paced:.1f} answered after 60 ms, "
              f"{after:.1f} after the answers stopped; lockstep {lockstep[-1]}")
        assert free > 60.0, free                  # the 100 Hz rate (a loaded machine: less)
        assert paced < 20.0, paced                # 1 / (60 ms + a tick's work) at most
        assert after > 60.0, after
        assert int(lockstep[-1]["timed_out"]) >= 1, lockstep[-1]
    finally:
        executor.remove_node(probe)
        probe.destroy_node()
