"""Time on the graph: the ``clock`` topic's QoS, a node's own simulated time, and the wall clock."""

from __future__ import annotations

from collections.abc import Callable

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMessage

from multirotor_ros.nodes.messages import stamp_to_ns

# The graph's one clock, whatever the publisher's namespace (rclpy's time source listens on /clock).
GRAPH_CLOCK_TOPIC = "/clock"
# As rclpy's time source subscribes to ``clock``: only the newest time matters.
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)


def steady_clock() -> Clock:
    """A monotonic wall clock: timers on it run in wall time even under ``use_sim_time``."""
    return Clock(clock_type=ClockType.STEADY_TIME)


class NodeTime:
    """A node's time read from ``/clock`` on a subscription of its own under ``use_sim_time``, else the wall.

    Instead of rclpy's time source, so that the node may spin on the EventsExecutor
    (nodes/entry.py ``make_executor``): under it the time source's ``/clock`` subscription, made when
    the node is constructed, often never delivered when the clock was already running before the node
    spun (7 controllers of 12 joining a running simulator read time 0 for good). Make it last in the
    node's constructor, just before the spin. A node that uses it sets ``KEEPS_ITS_OWN_SIMULATED_TIME``
    and has no timer on ROS time. ``on_clock`` is called with each simulated time heard while the
    node is on simulated time.
    """

    def __init__(self, node: Node, on_clock: Callable[[int], None] | None = None):
        self._node = node
        self._on_clock = on_clock
        self.simulated = bool(node.get_parameter("use_sim_time").value)
        self.simulated_now_ns: int | None = None  # the newest /clock heard
        node.create_subscription(ClockMessage, GRAPH_CLOCK_TOPIC, self._heard, CLOCK_QOS)

    @property
    def running(self) -> bool:
        """Whether the node has a time: always on the wall clock, after the first /clock on simulated time."""
        return not self.simulated or self.simulated_now_ns is not None

    def now_ns(self) -> int:
        """The node's time [ns]: the newest simulated time heard (0 before any), or the wall clock."""
        if self.simulated:
            return self.simulated_now_ns or 0
        return self._node.get_clock().now().nanoseconds

    def set_simulated(self, simulated: bool) -> None:
        """``use_sim_time`` changed: on simulated time, no time until the next /clock."""
        self.simulated = simulated
        self.simulated_now_ns = None

    def _heard(self, message: ClockMessage) -> None:
        self.simulated_now_ns = stamp_to_ns(message.clock)
        if self.simulated and self._on_clock is not None:
            self._on_clock(self.simulated_now_ns)
