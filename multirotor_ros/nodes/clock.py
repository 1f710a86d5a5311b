"""Time on the graph: the ``clock`` topic's QoS, and the wall clock for timers that ignore sim time."""

from __future__ import annotations

from rclpy.clock import Clock, ClockType
from rclpy.qos import QoSProfile, ReliabilityPolicy

# The graph's one clock, whatever the publisher's namespace (rclpy's time source listens on /clock).
GRAPH_CLOCK_TOPIC = "/clock"
# As rclpy's time source subscribes to ``clock``: only the newest time matters.
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)


def steady_clock() -> Clock:
    """A monotonic wall clock: timers on it run in wall time even under ``use_sim_time``."""
    return Clock(clock_type=ClockType.STEADY_TIME)
