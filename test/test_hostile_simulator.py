"""Hostile motor commands to the simulator (issue 11), flooded over ROS 2 while the controller flies.

The simulator and a controller fly in lockstep (as in test_nodes_sim_control.py); the seeded mix of
multirotor_ros.cli.fuzz (NaN, negative, oversized and wrong-length speeds, unknown names, stamps at 0,
in the past, an hour ahead and at 2^31 - 1 s, valid commands, bursts) goes to its motor_speed_cmd
stamped at the simulated time it publishes. The simulator must run on, publish nothing non-finite, log
each refusal reason once, and keep taking the controller's commands: the vehicle flies afterwards.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from rclpy.qos import qos_profile_sensor_data
from ros_harness import RosProbe
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from test_hostile_controller import assert_refusals_logged_once_per_reason
from test_nodes_sim_control import (
    STARTUP_TIMEOUT_S,
    Vehicle,
    joint_state,
    lockstep_vehicle,
    module_probe,
    stamp_s,
)

from multirotor_ros.cli.fuzz import flood, has_non_finite, hostile_messages
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.nodes.messages import rotor_names, stamp_to_ns
from multirotor_ros.plausibility import NS_PER_S

FLOOD_COUNT = 3000
FLOOD_RATE_HZ = 1000.0


probe = pytest.fixture(scope="module", name="probe")(module_probe)


@pytest.fixture(scope="module")
def vehicle(probe: RosProbe, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Vehicle]:
    yield from lockstep_vehicle(probe, tmp_path_factory.mktemp("hostile_simulator"), "/hs", seed=8)


@pytest.mark.ros
def test_a_command_flood_leaves_the_simulator_running_finite_and_obeying_the_controller(
    vehicle: Vehicle, probe: RosProbe
) -> None:
    vehicle.settle_at(0.0, 0.0, 1.0)
    clock = probe.subscribe("/clock", Clock, qos_profile_sensor_data)
    outputs = [
        vehicle.odom,
        probe.subscribe("/hs/imu", Imu, qos_profile_sensor_data),
        probe.subscribe("/hs/pose", PoseStamped, qos_profile_sensor_data),
        probe.subscribe("/hs/motor_speeds", JointState),
    ]
    publisher = probe.publisher("/hs/motor_speed_cmd", JointState)
    probe.wait_for_subscribers(publisher, timeout=STARTUP_TIMEOUT_S)
    clock.wait_for(count=1, timeout=STARTUP_TIMEOUT_S)

    def simulated_now_ns() -> int:
        return stamp_to_ns(clock.messages[-1].clock)

    # The reproductions of issue 11 first (one command an hour ahead, one at sec = 2^31 - 1), then the mix.
    hover = [340.0] * 8
    publisher.publish(joint_state(rotor_names(8), hover, stamp_ns=simulated_now_ns() + 3600 * NS_PER_S))
    publisher.publish(joint_state(rotor_names(8), hover, stamp_ns=(2**31 - 1) * NS_PER_S))
    items = hostile_messages("joint_state", FLOOD_COUNT, seed=21, airframe=load_airframe("x8_octorotor"))
    start = stamp_s(vehicle.latest())
    flood(items, publisher.publish, simulated_now_ns, FLOOD_RATE_HZ)
    vehicle.simulator.assert_running()
    # The controller's commands are still taken: the vehicle flies a step after the flood.
    vehicle.settle_at(0.5, -0.5, 1.2, tolerance=0.05)
    for recorder in outputs:
        received = [m for m in recorder.messages if stamp_s(m) >= start]
        assert received, recorder
        assert not any(has_non_finite(m) for m in received), recorder
    log = vehicle.simulator.log_text()
    for reason in ("stamp in the future", "negative speed", "non-finite speed", "oversized speed"):
        assert f"refused motor_speed_cmd: {reason}:" in log, reason
    assert log.count("motor_speed_cmd without a stamp") == 1
    assert "no motor command for" not in log  # the controller's commands never stopped being taken
    assert_refusals_logged_once_per_reason(log, "motor_speed_cmd")
    assert np.isfinite(stamp_s(vehicle.latest()))
