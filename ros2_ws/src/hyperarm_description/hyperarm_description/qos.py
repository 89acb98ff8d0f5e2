"""rclpy QoS profiles for the contract's topics (imports rclpy: for nodes only)."""
from __future__ import annotations

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from .contract import QOS

__all__ = ["qos_for", "observer_qos", "NO_PUB_EVENTS", "NO_SUB_EVENTS", "DISCOVERY_SETTLE",
           "discovery_settle_left"]

#: ``event_callbacks`` for a publisher / subscription with no QoS event handlers. rclpy's
#: default handlers only log an incompatible peer's QoS, and each is a waitable that the
#: Python executors re-add to their wait set on every wake: per message on a busy node
#: (the task node spent most of its CPU there, issue 28). For topics whose QoS the contract
#: fixes; the drivers keep the handlers on joint_states and joint_command, so an
#: incompatible peer is still named.
NO_PUB_EVENTS = PublisherEventCallbacks(use_default_callbacks=False)
NO_SUB_EVENTS = SubscriptionEventCallbacks(use_default_callbacks=False)

_REL = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT}
_DUR = {"volatile": DurabilityPolicy.VOLATILE, "transient_local": DurabilityPolicy.TRANSIENT_LOCAL}


def qos_for(topic: str) -> QoSProfile:
    """The QoS profile the contract fixes for ``topic`` (a name from ``contract``)."""
    try:
        s = QOS[topic]
    except KeyError:
        raise KeyError(f"no QoS in the contract for topic {topic!r}") from None
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(s["depth"]),
                      reliability=_REL[s["reliability"]], durability=_DUR[s["durability"]])


def observer_qos(topic: str, depth: int = 1000) -> QoSProfile:
    """``topic``'s contract profile with a history of ``depth``: for an observer that must see
    every message (a recorder, a test checking every command), where the contract's depth
    (1 for joint_command: a driver wants only the newest) would let a busy reader lose some."""
    q = qos_for(topic)
    q.depth = depth
    return q


def action_server_qos() -> dict[str, QoSProfile]:
    """Keyword arguments for an rclpy ActionServer: its goal, cancel and result services
    with a request queue of 100 (the default 10 lost goals and result requests of a client
    that sent 50 at once: their callers waited forever), reliable and volatile as the
    services' default."""
    deep = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
    return {"goal_service_qos_profile": deep, "cancel_service_qos_profile": deep,
            "result_service_qos_profile": deep}


#: s an action client waits after it is made before its first goal: the server must also
#: have discovered the client's response reader (the client finding the server is one
#: direction); rmw_fastrtps drops a response to a reader it has not matched yet ("failed to
#: send response (timeout)") and the goal runs while the client waits for an answer
DISCOVERY_SETTLE = 0.5


def discovery_settle_left(created: float, now: float) -> float:
    """Seconds (>= 0) a client made at ``created`` (monotonic s) still waits at ``now``
    before its first goal (:data:`DISCOVERY_SETTLE`)."""
    return max(0.0, created + DISCOVERY_SETTLE - now)

