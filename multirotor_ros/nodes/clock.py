"""Time on the graph: the ``clock`` topic's QoS, a node's own simulated time, and the wall clock."""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext

from rclpy.clock import Clock, ClockType, ROSClock
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from rclpy.time import Time
from rosgraph_msgs.msg import Clock as ClockMessage
from std_msgs.msg import Header

from multirotor_ros.nodes import subscriptions
from multirotor_ros.nodes.messages import LATCHED_QOS, stamp_from_ns, stamp_to_ns

# The graph's one clock, whatever the publisher's namespace (rclpy's time source listens on /clock).
GRAPH_CLOCK_TOPIC = "/clock"
# As rclpy's time source subscribes to ``clock``: only the newest time matters.
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
# Who publishes the graph's clock, and since when (ClockClaim): reliable and transient local, so a node that
# discovers the claimant late still gets its claim.
CLOCK_CLAIM_TOPIC = "/clock_claim"
CLAIM_REPEAT_S = 2.0  # [s] wall time between repetitions of a claim (ClockClaim)


class ClockClaim:
    """One publisher of ``/clock`` per graph, decided by who claimed it first.

    A node that publishes the clock stakes its claim when it starts (:meth:`stake`): a ``std_msgs/Header`` on
    ``/clock_claim`` whose stamp is the wall time (system clock) of the claim and whose ``frame_id`` is the
    node's fully qualified name. Every claim heard from another node is kept (:attr:`heard`); once this
    node has claimed, a claim that came first (earlier stamp; the smaller name on a tie) makes this node
    yield: ``on_yield(name, earlier_by_s)`` is called once. Why: the check before publishing (listening
    for another clock) depends on discovery, which on a loaded machine took over 4 s, and two simulators
    started together both pass it; the claims settle it whenever discovery completes, the same way on
    both sides, so exactly one keeps the clock. The claim is repeated every ``CLAIM_REPEAT_S``: Fast DDS
    was seen to lose a transient-local sample published while the reader was being matched (neither
    delivered live nor as history).
    """

    def __init__(self, node: Node, on_yield: Callable[[str, float], None]):
        self._name = node.get_fully_qualified_name()
        self._on_yield = on_yield
        self._publisher = node.create_publisher(Header, CLOCK_CLAIM_TOPIC, LATCHED_QOS)
        node.create_subscription(Header, CLOCK_CLAIM_TOPIC, self._heard, LATCHED_QOS)
        self.heard: dict[str, int] = {}  # other claimants -> their claim's wall time [ns]
        self.mine: tuple[int, str] | None = None
        self.yielded = False
        self._node = node

    def stake(self) -> None:
        """Claim the clock now (publish the claim) and yield at once to any earlier claim already heard."""
        self.mine = (time.time_ns(), self._name)
        self._publish()
        self._node.create_timer(CLAIM_REPEAT_S, self._publish, clock=steady_clock())
        for name, claimed_ns in list(self.heard.items()):
            self._compare(name, claimed_ns)

    def _publish(self) -> None:
        assert self.mine is not None
        self._publisher.publish(Header(stamp=stamp_from_ns(self.mine[0]), frame_id=self._name))

    def _heard(self, claim: Header) -> None:
        if claim.frame_id == self._name:
            return
        claimed_ns = stamp_to_ns(claim.stamp)
        self.heard[claim.frame_id] = claimed_ns
        self._compare(claim.frame_id, claimed_ns)

    def _compare(self, name: str, claimed_ns: int) -> None:
        if self.mine is not None and not self.yielded and (claimed_ns, name) < self.mine:
            self.yielded = True
            self._on_yield(name, (self.mine[0] - claimed_ns) * 1e-9)


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
    node is on simulated time. With ``subscribe`` false the node makes no subscription: a
    :class:`SharedClock` of its process gives it every ``/clock`` message.

    rclpy's time source is let go (:func:`ros_clock_without_time_source`); the time heard here is set on the
    node's ROS clock instead, so that ``get_clock()`` reads the same simulated time.
    """

    def __init__(self, node: Node, on_clock: Callable[[int], None] | None = None, *, subscribe: bool = True):
        self._on_clock = on_clock
        self._ros_clock = ros_clock_without_time_source(node)
        self.simulated = bool(node.get_parameter("use_sim_time").value)
        self.simulated_now_ns: int | None = None  # the newest /clock heard
        # Where a /clock not dispatched yet waits, and who hears it (_catch_up): this node or a SharedClock.
        self._source: tuple[Subscription, Callable[[ClockMessage], None]] | None = None
        if subscribe:
            clock = subscriptions.subscribe(node, ClockMessage, GRAPH_CLOCK_TOPIC, self.heard, CLOCK_QOS)
            self._source = (clock, self.heard)

    @property
    def running(self) -> bool:
        """Whether the node has a time: always on the wall clock, after the first /clock on simulated time."""
        return not self.simulated or self.simulated_now_ns is not None

    def now_ns(self) -> int:
        """The node's time [ns]: the newest simulated time heard (0 before any), or the wall clock."""
        if self.simulated:
            return self.simulated_now_ns or 0
        return self._ros_clock.now().nanoseconds

    def set_simulated(self, simulated: bool) -> None:
        """``use_sim_time`` changed: on simulated time, no time until the next /clock."""
        self.simulated = simulated
        self.simulated_now_ns = None

    def now_to_judge(self, stamp_ns: int, tolerance_ns: int) -> int:
        """The node's time [ns] to judge ``stamp_ns`` by, a stamp allowed ``tolerance_ns`` ahead of it.

        Before the first ``/clock``, or for a stamp further ahead, a ``/clock`` message that has arrived but
        that the executor has not dispatched yet is heard first (:meth:`_catch_up`).
        """
        if not self.running or stamp_ns > self.now_ns() + tolerance_ns:
            self._catch_up()
        return self.now_ns()

    def _catch_up(self) -> None:
        """Hear a ``/clock`` message that has arrived but that the executor has not dispatched yet.

        For a stamp that looks ahead of this node's clock: the executor dispatches one subscription at a
        time, and one that takes its whole queue at once (subscriptions.subscribe) reads states up to its
        depth ahead of the last ``/clock`` dispatched. An identifier that had been busy for a moment
        beside a lockstep simulator running a few times faster than real time took an odometry 0.504 s
        ahead of its clock for a stamp from the future (CI, 2026-11-28). The simulator publishes each
        state before the clock of its time, so the newest clock waiting is at most one period behind any
        state waiting. Without a subscription of its own, the :class:`SharedClock` that tells it takes it.
        """
        if self._source is None or not self.simulated:
            return
        subscription, hear = self._source
        waiting = subscriptions.take_waiting(subscription, ClockMessage)
        if waiting is not None:
            hear(waiting)

    def told_by(self, subscription: Subscription, hear: Callable[[ClockMessage], None]) -> None:
        """A ``SharedClock``'s ``subscription`` brings this node's ``/clock``, and ``hear`` tells it."""
        self._source = (subscription, hear)

    def heard(self, message: ClockMessage) -> None:
        """A ``/clock`` message: the node's simulated time now."""
        now_ns = stamp_to_ns(message.clock)
        self.hear(now_ns, Time(nanoseconds=now_ns, clock_type=ClockType.ROS_TIME))

    def hear(self, now_ns: int, now: Time) -> None:
        """The simulated time heard on ``/clock``, in [ns] and as ``now`` (the same, for the ROS clock)."""
        self.simulated_now_ns = now_ns
        self._ros_clock.set_ros_time_override(now)
        if self.simulated and self._on_clock is not None:
            self._on_clock(now_ns)


class SharedClock:
    """One ``/clock`` subscription for the nodes of a process, each with its ``NodeTime(subscribe=False)``.

    Every subscription in a process gets every ``/clock`` message: taken from the middleware, converted to
    Python and dispatched once per subscription. Ten controllers in one process at 250 Hz took 2,500 such
    messages a second where 250 carry the time. The same caveat as ``NodeTime``'s: create it last in the
    constructor, just before the spin. ``times``: the nodes' times, told in their order.
    """

    def __init__(
        self,
        node: Node,
        times: list[NodeTime],
        around: Callable[[], AbstractContextManager[None]] = nullcontext,
    ):
        """``around``: what the telling of each clock runs inside (a fleet gathers its commands so)."""
        self.times = times
        self._around = around
        self._ros_clock = ros_clock_without_time_source(node)
        subscription = subscriptions.subscribe(node, ClockMessage, GRAPH_CLOCK_TOPIC, self._heard, CLOCK_QOS)
        for node_time in times:
            node_time.told_by(subscription, self._heard)

    def _heard(self, message: ClockMessage) -> None:
        now_ns = stamp_to_ns(message.clock)
        now = Time(nanoseconds=now_ns, clock_type=ClockType.ROS_TIME)
        self._ros_clock.set_ros_time_override(now)
        with self._around():
            for node_time in self.times:
                node_time.hear(now_ns, now)


def ros_clock_without_time_source(node: Node) -> ROSClock:
    """``node``'s ROS clock, whose time the caller sets from now on: rclpy's time source is detached.

    A node that keeps its own simulated time (:class:`NodeTime`, :class:`SharedClock`) does not read it,
    yet under ``use_sim_time`` it took every ``/clock`` message too: from the middleware, converted to
    Python and set on the node's clock. A process of ten controllers had eleven such subscriptions, and a
    simulator delivers each of its clocks to every one. The time source stays the node's parameter
    callback: ``use_sim_time`` still switches the node's ROS clock between the wall and the override set
    by whoever hears ``/clock`` (rclpy has no public access to a node's time source).
    """
    node._time_source.detach_node()  # noqa: SLF001 - see above
    clock = node.get_clock()
    if not isinstance(clock, ROSClock):
        raise TypeError(f"{node.get_name()}: its clock is a {type(clock).__name__}, not rclpy's ROSClock")
    return clock
