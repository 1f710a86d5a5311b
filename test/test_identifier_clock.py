"""The identifier on simulated time judges a state's stamp by the newest ``/clock`` that has arrived.

A real IdentifierNode in this process over DDS (the session's isolated domain), fed by a peer node that
plays a lockstep simulator running ahead of the identifier: one more second of odometry and its clock are
waiting when the identifier gets to them. rclpy's SingleThreadedExecutor dispatches the ready
subscriptions in the order they were made, so the odometry (whose callback takes its whole queue) comes
before the ``/clock`` made last in the constructor: what the EventsExecutor did in CI, where an identifier
refused an odometry "stamped 0.504 s ahead of this node's clock" that its clock had already reached.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
import rclpy
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock

from multirotor_ros.nodes.clock import CLOCK_QOS, GRAPH_CLOCK_TOPIC
from multirotor_ros.nodes.identifier import IdentifierNode
from multirotor_ros.nodes.messages import odometry_message, stamp_from_ns

pytestmark = pytest.mark.ros
NAMESPACE = "/clock_catch_up"
NS_PER_S = 1_000_000_000
ON_THE_GROUND = np.zeros(13)
ON_THE_GROUND[6] = 1.0  # level (w = 1), at the origin, at rest


@pytest.fixture
def context() -> Iterator[Context]:
    context = Context()
    rclpy.init(context=context)
    yield context
    context.try_shutdown()


def spin_until(executor: SingleThreadedExecutor, done: Callable[[], bool], timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    assert done()


def odometry_handled(identifier: IdentifierNode) -> bool:
    """Whether an odometry passed the identifier's stamp gate or was refused."""
    return identifier._stamps["odom"].newest_ns is not None or identifier._refused["state"].total > 0


def test_a_state_taken_before_its_clock_is_dispatched_is_judged_by_that_clock(context: Context) -> None:
    identifier = IdentifierNode(
        context=context, namespace=NAMESPACE, parameter_overrides=[Parameter("use_sim_time", value=True)]
    )
    simulator = Node("clock_catch_up_simulator", context=context)
    clock = simulator.create_publisher(Clock, GRAPH_CLOCK_TOPIC, CLOCK_QOS)
    odom = simulator.create_publisher(Odometry, f"{NAMESPACE}/odom", 10)
    deadline = time.monotonic() + 20.0
    while (clock.get_subscription_count() < 1 or odom.get_subscription_count() < 1) and (
        time.monotonic() < deadline
    ):
        time.sleep(0.01)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(identifier)
    try:
        start_ns = 10 * NS_PER_S
        clock.publish(Clock(clock=stamp_from_ns(start_ns)))
        spin_until(executor, lambda: identifier._time.now_ns() == start_ns)

        # A second later: the state, then the clock of its time (as the simulator sends them).
        later_ns = start_ns + NS_PER_S
        odom.publish(odometry_message(ON_THE_GROUND, stamp_from_ns(later_ns)))
        clock.publish(Clock(clock=stamp_from_ns(later_ns)))
        time.sleep(0.3)  # both delivered to the identifier's queues, neither dispatched
        spin_until(executor, lambda: odometry_handled(identifier), timeout_s=5.0)
        assert identifier._refused["state"].counts == {}
        assert identifier._stamps["odom"].newest_ns == later_ns
        assert identifier._time.now_ns() == later_ns

        # A stamp truly ahead of every clock that came is still refused.
        odom.publish(odometry_message(ON_THE_GROUND, stamp_from_ns(later_ns + 2 * NS_PER_S)))
        spin_until(executor, lambda: identifier._refused["state"].total == 1, timeout_s=5.0)
        assert identifier._refused["state"].counts == {"stamp in the future": 1}
    finally:
        executor.shutdown()
        identifier.destroy_node()
        simulator.destroy_node()
