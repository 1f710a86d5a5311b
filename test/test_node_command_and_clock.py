"""The controller's command on the wire, its own output check, and one ``/clock`` subscription per process.

Real nodes in this process over DDS (the session's isolated domain). The controller publishes its command
serialised (nodes/cdr.py RotorCommandWriter): what a subscriber reads must be the JointState rclpy would
have made of the law's output. A command that is not finite or negative is never published. Nodes that
keep their own simulated time let rclpy's time source go (nodes/clock.py ros_clock_without_time_source): a
controller, or a fleet's process, has one ``/clock`` subscription, and the node's ROS clock still reads
the simulated time heard.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import rclpy
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_harness import spin_until
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from multirotor_ros.control.gains import airframe_gains
from multirotor_ros.control.law import SaturationController
from multirotor_ros.nodes.cdr import OdometryWriter
from multirotor_ros.nodes.clock import GRAPH_CLOCK_TOPIC
from multirotor_ros.nodes.controller import ControllerNode
from multirotor_ros.nodes.fleet_controller import FleetControllerNode
from multirotor_ros.nodes.messages import odometry_values_of_state, rotor_names, stamp_from_ns, stamp_to_ns

pytestmark = pytest.mark.ros
SIM_TIME = Parameter("use_sim_time", value=True)
PERIOD_NS = 4_000_000  # the controller's 250 Hz
HOVER = np.zeros(13)
HOVER[[2, 6]] = 1.0  # 1 m up, level (w = 1), at rest
DELIVERY_S = 5.0  # [s] wall time for a message to cross DDS in this process


def _odometry(x: np.ndarray, t_ns: int) -> bytes:
    template = Odometry()
    template.header.frame_id, template.child_frame_id = "world", "base_link"
    return OdometryWriter(template).write(stamp_from_ns(t_ns), odometry_values_of_state(x))


def _listening(context: Context, topic: str, publisher_node: ControllerNode) -> tuple[Node, list[JointState]]:
    """A node in ``context`` recording ``topic``, once the controller's publisher has matched it."""
    listener = Node("command_listener", context=context)
    heard: list[JointState] = []
    listener.create_subscription(JointState, topic, heard.append, 10)
    deadline = time.monotonic() + DELIVERY_S
    while publisher_node._command_pub.get_subscription_count() < 1:
        assert time.monotonic() < deadline, "the listener never matched the controller's motor_speed_cmd"
        time.sleep(0.01)
    return listener, heard


def _fly_one_period(node: ControllerNode) -> None:
    """The clock at 0, then the state of the first tick: the controller computes that tick at once."""
    node.time.heard(Clock(clock=stamp_from_ns(0)))
    node.on_odometry(_odometry(HOVER, PERIOD_NS))


def test_the_command_on_the_wire_is_the_laws_output_as_rclpy_reads_it(rclpy_context: Context) -> None:
    node = ControllerNode(context=rclpy_context, namespace="/wire", parameter_overrides=[SIM_TIME])
    listener, heard = _listening(rclpy_context, "/wire/motor_speed_cmd", node)
    _fly_one_period(node)
    spin_until(rclpy_context, [listener], lambda: bool(heard), DELIVERY_S)

    # The same law on the same state, holding the pose of the first odometry (module docstring).
    law = SaturationController(node.airframe, airframe_gains(node.airframe))
    p, v, q, w = HOVER[0:3], HOVER[3:6], HOVER[6:10], HOVER[10:13]
    expected = law.update(PERIOD_NS * 1e-9, p, v, q, w, p.copy(), 0.0).omega_cmd_rad_s
    (command,) = heard
    assert stamp_to_ns(command.header.stamp) == PERIOD_NS
    assert list(command.name) == rotor_names(node.airframe.n_rotors)
    assert np.array_equal(np.array(command.velocity), expected)
    assert len(command.position) == len(command.effort) == 0
    node.destroy_node()
    listener.destroy_node()


@pytest.mark.parametrize("bad", [math.nan, math.inf, -1.0])
def test_a_non_finite_or_negative_command_is_never_published_and_the_law_starts_over(
    rclpy_context: Context, bad: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    node = ControllerNode(context=rclpy_context, namespace="/bad_output", parameter_overrides=[SIM_TIME])
    listener, heard = _listening(rclpy_context, "/bad_output/motor_speed_cmd", node)
    update, resets = node.law.update, []

    def broken_update(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202 - the law's own signature
        output = update(*args, **kwargs)
        output.omega_cmd_rad_s[3] = bad
        return output

    monkeypatch.setattr(node.law, "update", broken_update)
    monkeypatch.setattr(node.law, "reset", lambda: resets.append(True))
    _fly_one_period(node)
    spin_until(rclpy_context, [listener], lambda: bool(heard), 0.5)

    assert heard == []
    assert node._output_refusals.counts == {"non-finite or negative rotor speed": 1}
    assert resets == [True]
    node.destroy_node()
    listener.destroy_node()


def _clock_subscribers(context: Context, under: str) -> list[str]:
    """The nodes under the namespace ``under`` with a ``/clock`` subscription, one entry per subscription."""
    probe = Node("clock_probe", context=context)
    try:
        # Nodes of one context share its participant: the graph knows them at once. Other processes of
        # the session's domain may be in it too: only the test's own namespace counts.
        names = (
            f"{info.node_namespace.rstrip('/')}/{info.node_name}"
            for info in probe.get_subscriptions_info_by_topic(GRAPH_CLOCK_TOPIC)
        )
        return sorted(name for name in names if name.startswith(under + "/"))
    finally:
        probe.destroy_node()


def test_a_controller_has_one_clock_subscription_and_its_ros_clock_reads_the_time_heard(
    rclpy_context: Context,
) -> None:
    node = ControllerNode(context=rclpy_context, namespace="/one_clock", parameter_overrides=[SIM_TIME])
    assert _clock_subscribers(rclpy_context, "/one_clock") == ["/one_clock/controller"]
    node.time.heard(Clock(clock=stamp_from_ns(12_345_000_000)))
    assert node.get_clock().now().nanoseconds == 12_345_000_000
    node.destroy_node()


def test_a_fleet_process_has_one_clock_subscription_and_every_ros_clock_reads_the_time_heard() -> None:
    # The fleet's process under a namespace, as ros2 launch starts it (-r __ns:=/NS for the whole process).
    context = rclpy.Context()
    rclpy.init(args=["--ros-args", "-r", "__ns:=/clock_fleet"], context=context)
    try:
        fleet = FleetControllerNode(
            context=context,
            parameter_overrides=[SIM_TIME, Parameter("vehicles", value=["uav1", "uav2", "uav3"])],
        )
        assert _clock_subscribers(context, "/clock_fleet") == ["/clock_fleet/fleet_controller"]
        fleet._shared_clock._heard(Clock(clock=stamp_from_ns(7_000_000_000)))
        assert fleet.get_clock().now().nanoseconds == 7_000_000_000
        for member in fleet.members:
            assert member.time.now_ns() == member.get_clock().now().nanoseconds == 7_000_000_000
        for node in (*fleet.members, fleet):
            node.destroy_node()
    finally:
        context.try_shutdown()


def test_use_sim_time_off_gives_the_ros_clock_back_to_the_wall(rclpy_context: Context) -> None:
    node = ControllerNode(context=rclpy_context, namespace="/back_to_wall", parameter_overrides=[SIM_TIME])
    node.time.heard(Clock(clock=stamp_from_ns(3_000_000_000)))
    node.set_parameters([Parameter("use_sim_time", value=False)])
    assert abs(node.get_clock().now().nanoseconds - time.time_ns()) < 1_000_000_000
    assert _clock_subscribers(rclpy_context, "/back_to_wall") == [
        "/back_to_wall/controller"
    ]  # its own, not rclpy's again
    node.destroy_node()
