"""On simulated time a node judges a stamp by the newest ``/clock`` that has arrived (NodeTime.now_to_judge).

Real nodes in this process over DDS (the session's isolated domain), fed by a peer that plays a simulator
running ahead of them: a second more of odometry and the clock of its time are waiting when the node gets
to them. rclpy's SingleThreadedExecutor dispatches a node's ready subscriptions in the order they were
made, so the odometry comes before the ``/clock`` made last in the constructor (a fleet's clock, held by
the fleet node, is left out of the spin for that moment): what the EventsExecutor did in CI, where an
identifier whose odometry queue is taken whole refused an odometry "stamped 0.504 s ahead of this node's
clock" that its clock had already reached. A stamp ahead of every clock that came is still refused.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock

from multirotor_ros.nodes.clock import CLOCK_QOS, GRAPH_CLOCK_TOPIC
from multirotor_ros.nodes.controller import ControllerNode
from multirotor_ros.nodes.fleet_controller import FleetControllerNode
from multirotor_ros.nodes.identifier import IdentifierNode
from multirotor_ros.nodes.messages import odometry_message, stamp_from_ns
from multirotor_ros.plausibility import StampGate
from multirotor_ros.refusals import RefusalCounter

pytestmark = pytest.mark.ros
NS_PER_S = 1_000_000_000
ON_THE_GROUND = np.zeros(13)
ON_THE_GROUND[6] = 1.0  # level (w = 1), at the origin, at rest
SIM_TIME = Parameter("use_sim_time", value=True)


@dataclass
class Judged:
    """A node under test: its nodes (the one judging first), odometry topic, stamp gate and refusals."""

    nodes: list[Node]
    odom_topic: str
    gate: StampGate
    refusals: RefusalCounter
    now_ns: Callable[[], int]


def identifier(context: Context) -> Judged:
    node = IdentifierNode(context=context, namespace="/catch_up_i", parameter_overrides=[SIM_TIME])
    return Judged([node], "/catch_up_i/odom", node._stamps["odom"], node._refused["state"], node._time.now_ns)


def controller(context: Context) -> Judged:
    node = ControllerNode(context=context, namespace="/catch_up_c", parameter_overrides=[SIM_TIME])
    return Judged(
        [node], "/catch_up_c/odom", node._odometry_check.gate, node._odom_refusals, node.time.now_ns
    )


def fleet_controller(context: Context) -> Judged:
    vehicles = Parameter("vehicles", value=["catch_up_f"])
    fleet = FleetControllerNode(context=context, parameter_overrides=[SIM_TIME, vehicles])
    (member,) = fleet.members
    return Judged(
        [member, fleet],
        "/catch_up_f/odom",
        member._odometry_check.gate,
        member._odom_refusals,
        member.time.now_ns,
    )


@pytest.fixture
def context(rclpy_context: Context) -> Context:
    return rclpy_context


def spin_until(executor: SingleThreadedExecutor, done: Callable[[], bool], timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    assert done()


@pytest.mark.parametrize("build", [identifier, controller, fleet_controller])
def test_a_state_taken_before_its_clock_is_dispatched_is_judged_by_that_clock(
    context: Context, build: Callable[[Context], Judged]
) -> None:
    judged = build(context)
    simulator = Node("catch_up_simulator", context=context)
    clock = simulator.create_publisher(Clock, GRAPH_CLOCK_TOPIC, CLOCK_QOS)
    odom = simulator.create_publisher(Odometry, judged.odom_topic, 10)
    deadline = time.monotonic() + 20.0
    while (clock.get_subscription_count() < 1 or odom.get_subscription_count() < 1) and (
        time.monotonic() < deadline
    ):
        time.sleep(0.01)
    executor = SingleThreadedExecutor(context=context)
    for node in judged.nodes:
        executor.add_node(node)
    try:
        start_ns = 10 * NS_PER_S
        clock.publish(Clock(clock=stamp_from_ns(start_ns)))
        spin_until(executor, lambda: judged.now_ns() == start_ns)

        # A second later: the state, then the clock of its time (as the simulator sends them).
        later_ns = start_ns + NS_PER_S
        odom.publish(odometry_message(ON_THE_GROUND, stamp_from_ns(later_ns)))
        clock.publish(Clock(clock=stamp_from_ns(later_ns)))
        time.sleep(0.3)  # both delivered to the node's queues, neither dispatched
        for node in judged.nodes[1:]:
            executor.remove_node(node)  # the fleet's clock: dispatched after its member's odometry
        spin_until(executor, lambda: judged.gate.newest_ns is not None or judged.refusals.total > 0, 5.0)
        assert judged.refusals.counts == {}
        assert judged.gate.newest_ns == later_ns
        assert judged.now_ns() == later_ns

        # A stamp ahead of every clock that came is still refused.
        odom.publish(odometry_message(ON_THE_GROUND, stamp_from_ns(later_ns + 2 * NS_PER_S)))
        spin_until(executor, lambda: judged.refusals.total == 1, timeout_s=5.0)
        assert judged.refusals.counts == {"stamp in the future": 1}
    finally:
        executor.shutdown()
        for node in judged.nodes:
            node.destroy_node()
        simulator.destroy_node()
