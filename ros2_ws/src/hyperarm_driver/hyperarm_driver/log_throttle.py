"""Re-export of :class:`hyperarm_description.log_throttle.ReasonThrottle` (shared by every
node: throttling per reason, not per call site)."""
from hyperarm_description.log_throttle import ReasonThrottle

__all__ = ["ReasonThrottle"]
