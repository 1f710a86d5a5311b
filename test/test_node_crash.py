"""A crash over real DDS: the simulator says so (``crashed``, one error line), the wreck stays down, reset.

The physics of ground contact and crashes is tested without ROS in test_ground_contact.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from ros_harness import NodeProcess, RosProbe
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.nodes.messages import LATCHED_QOS, rotor_names

STARTUP_TIMEOUT_S = 120.0
HEIGHT_M = 5.0


def command(speed_rad_s: float) -> JointState:
    message = JointState()  # stamp 0: taken as of now, as `ros2 topic pub` sends it
    message.name = rotor_names(8)
    message.velocity = [float(speed_rad_s)] * 8
    return message


def tilt_rad(message: Odometry) -> float:
    o = message.pose.pose.orientation
    return math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (o.x * o.x + o.y * o.y))))


@pytest.mark.ros
def test_a_vehicle_that_falls_crashes_stays_down_and_is_reset(ros_probe: RosProbe, tmp_path) -> None:
    crashed = ros_probe.subscribe("/crashed", Bool, LATCHED_QOS)
    odom = ros_probe.subscribe("/odom", Odometry)
    commands = ros_probe.publisher("/motor_speed_cmd", JointState)
    top_speed = load_airframe("x8_octorotor").rotor_speed_max_rad_s
    with NodeProcess(
        "simulator",
        tmp_path / "simulator.log",
        parameters={"initial_z": HEIGHT_M, "real_time_factor": 1.0, "command_timeout_s": 0.0},
    ) as simulator:
        assert not crashed.wait_for(count=1, timeout=STARTUP_TIMEOUT_S)[-1].data
        odom.wait_for(lambda m: m.pose.pose.position.z > HEIGHT_M - 0.1, timeout=STARTUP_TIMEOUT_S)
        ros_probe.wait_for_subscribers(commands, timeout=STARTUP_TIMEOUT_S)
        commands.publish(command(0.0))  # rotors off at 5 m: it falls at about 10 m/s onto the ground
        crashed.wait_for(lambda m: m.data, timeout=30.0)
        assert "crashed at t = " in simulator.wait_for_log("crashed at t = ", timeout=10.0)

        # Full thrust on the wreck: it does not move, turn or take off.
        odom.clear()
        for _ in range(20):
            commands.publish(command(top_speed))
        lying = odom.wait_for(count=200, timeout=30.0)  # 0.8 s at 250 Hz
        positions = np.array(
            [[m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z] for m in lying]
        )
        assert np.ptp(positions, axis=0).max() < 1e-9 and positions[:, 2].max() < 0.01
        assert np.ptp([tilt_rad(m) for m in lying]) < 1e-9
        assert max(abs(m.twist.twist.angular.z) for m in lying) == 0.0
        log = simulator.log_text()
        assert log.count("crashed at t = ") == 1, "one error line per crash"
        line = next(line for line in log.splitlines() if "crashed at t = " in line)
        assert "m/s" in line and len(line) < 200

        response = ros_probe._call(Trigger, "/simulator/reset", Trigger.Request(), timeout=30.0)
        assert response.success, response.message
        crashed.wait_for(lambda m: not m.data, count=2, timeout=30.0)
        odom.wait_for(lambda m: m.pose.pose.position.z > HEIGHT_M - 0.1, timeout=30.0)
