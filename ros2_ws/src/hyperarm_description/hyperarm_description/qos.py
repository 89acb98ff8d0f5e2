"""rclpy QoS profiles for the contract's topics (imports rclpy: for nodes only)."""
from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from .contract import QOS

__all__ = ["qos_for"]

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
