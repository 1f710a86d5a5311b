"""The ``mavlink_bridge`` node: flights over MAVLink show up on ROS topics, and the other way round."""

from __future__ import annotations

import math
import socket
import threading
import time

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from rclpy.qos import qos_profile_sensor_data
from ros_harness import NodeProcess
from sensor_msgs.msg import Imu, JointState
from test_mavlink_gcs import GroundStation

from multirotor_ros.frames import enu_to_ned, quat_enu_flu_to_ned_frd
from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.peers import ArduPilotLikePeer, HoverController, Px4LikePeer
from multirotor_ros.mavlink.sensors import Home, LocalTangentPlane
from multirotor_ros.mavlink.signing import parse_signing_key
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.rotation import quat_to_euler
from multirotor_ros.nodes.messages import (
    imu_message,
    joint_state_from_rotor_speeds,
    odometry_message,
    quaternion_from_msg,
    stamp_from_ns,
    stamp_to_ns,
)

pytestmark = pytest.mark.ros


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_px4_flight_in_lockstep_is_published_and_agrees_with_what_px4_was_sent(start_node, ros_probe):
    channels = RotorChannels(load_airframe("quad_x"))
    port = free_port(socket.SOCK_STREAM)
    odom = ros_probe.subscribe("/uav1/odom", Odometry, qos=100)
    imu = ros_probe.subscribe("/uav1/imu", Imu, qos_profile_sensor_data)
    commands = ros_probe.subscribe("/uav1/motor_speed_cmd", JointState, qos=100)
    start_node(
        "mavlink_bridge",
        namespace="/uav1",
        parameters={"airframe": "quad_x", "flight_stack_port": port, "gcs_enabled": False, "seed": 3},
    )
    # Fly only once the probe hears the node: the flight runs faster than real time and would be half over.
    deadline = time.monotonic() + 60.0
    while min(ros_probe.node.count_publishers(t) for t in ("/uav1/odom", "/uav1/imu")) < 1:
        assert time.monotonic() < deadline, "the node's publishers never appeared"
        time.sleep(0.05)
    time.sleep(0.5)
    peer = Px4LikePeer(port, HoverController(channels, altitude_m=1.5), arm_after_s=0.5, timeout_s=60.0)
    try:
        record = peer.fly(3.0)
    finally:
        peer.close()
    odom.wait_for(lambda m: stamp_to_ns(m.header.stamp) >= 2_900_000_000, timeout=20.0)

    # Odometry (ENU/FLU on ROS) and what PX4 got (NED/FRD on the wire) describe one vehicle.
    plane = LocalTangentPlane(Home())
    by_time = {stamp_to_ns(m.header.stamp) // 1000: m for m in odom.messages}
    compared = 0
    for truth in record.states:
        message = by_time.get(truth.time_usec)
        if message is None:
            continue
        q_WB = quaternion_from_msg(message.pose.pose.orientation)
        np.testing.assert_allclose(truth.attitude_quaternion, quat_enu_flu_to_ned_frd(q_WB), atol=1e-6)
        p = message.pose.pose.position
        p_from_px4 = plane.enu(truth.lat * 1e-7, truth.lon * 1e-7, truth.alt * 1e-3)
        np.testing.assert_allclose(p_from_px4, [p.x, p.y, p.z], atol=0.02)
        compared += 1
    assert compared >= 20
    gps_compared = 0
    for fix in record.gps:
        message = by_time.get(fix.time_usec)
        if message is None:
            continue
        p = message.pose.pose.position
        np.testing.assert_allclose(plane.enu(fix.lat * 1e-7, fix.lon * 1e-7, fix.alt * 1e-3), [p.x, p.y, p.z],
                                   atol=0.02)  # fmt: skip
        gps_compared += 1
    assert gps_compared >= 5
    assert by_time[max(by_time)].pose.pose.position.z == pytest.approx(1.5, abs=0.3)

    # At rest, the imu topic reads +g up in FLU where PX4 read -g along FRD z.
    resting = [m for m in imu.messages if stamp_to_ns(m.header.stamp) < 400_000_000]
    assert resting
    specific_force = [
        [m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in resting
    ]
    np.testing.assert_allclose(np.mean(specific_force, axis=0), [0.0, 0.0, 9.81], atol=0.1)
    sensor = next(s for s in record.sensors if s.time_usec < 400_000)
    assert sensor.zacc == pytest.approx(-9.81, abs=0.1)
    last = commands.wait_for(count=1)[-1]
    assert last.name == ["rotor_1", "rotor_2", "rotor_3", "rotor_4"] and min(last.velocity) > 300.0


def test_ground_station_only_forwards_the_simulator_topics_and_turns_signed_setpoints_into_setpoint(
    start_node, ros_probe
):
    passphrase = "node test key"
    station = GroundStation(parse_signing_key(passphrase))
    checker = mavlink2.MAVLink(None)
    checker.signing.secret_key = parse_signing_key(passphrase)
    station.parser = checker  # accepts only telemetry signed with the key
    setpoints = ros_probe.subscribe("/uav2/setpoint", PoseStamped)
    odom_pub = ros_probe.publisher("/uav2/odom", Odometry)
    imu_pub = ros_probe.publisher("/uav2/imu", Imu, qos_profile_sensor_data)
    speeds_pub = ros_probe.publisher("/uav2/motor_speeds", JointState)
    node = start_node(
        "mavlink_bridge",
        namespace="/uav2",
        parameters={
            "airframe": "quad_x",
            "flight_stack": "none",
            "gcs_port": station.port,
            "signing_key": passphrase,
        },
    )
    ros_probe.wait_for_subscribers(odom_pub, timeout=30.0)
    ros_probe.wait_for_subscribers(imu_pub, timeout=10.0)

    x = S.make_state(4, position_m=(4.0, -2.0, 6.0), euler_rad=(0.0, 0.0, 1.0), rotor_speed_rad_s=650.0)[0]
    stop = threading.Event()

    def simulator() -> None:
        t_ns = 1_000_000_000
        while not stop.is_set():
            stamp = stamp_from_ns(t_ns)
            odom_pub.publish(odometry_message(x, stamp))
            imu = imu_message(stamp, "base_link", x[S.QUATERNION], [0.0, 0.0, 9.81], [0.0, 0.0, 0.0],
                              accel_var=0.0, gyro_var=0.0, orientation_var=0.0)  # fmt: skip
            imu_pub.publish(imu)
            speeds_pub.publish(joint_state_from_rotor_speeds(x[S.ROTORS_START :], stamp))
            t_ns += 10_000_000
            time.sleep(0.01)

    feeder = threading.Thread(target=simulator, daemon=True)
    feeder.start()
    try:
        messages = station.collect(2.0)
        positions = [m for m in messages if m.get_type() == "LOCAL_POSITION_NED"]
        assert positions, f"no telemetry; node log:\n{node.log_tail()}"
        last = positions[-1]
        np.testing.assert_allclose([last.x, last.y, last.z], enu_to_ned([4.0, -2.0, 6.0]), atol=1e-5)
        attitude = [m for m in messages if m.get_type() == "ATTITUDE"][-1]
        assert attitude.yaw == pytest.approx(math.pi / 2 - 1.0, abs=1e-5)

        unsigned = GroundStation()
        unsigned.bridge_address = station.bridge_address
        for sender, target in ((unsigned, (9.0, 9.0, -9.0)), (station, (1.0, 2.0, -3.0))):
            sender.send(
                sender.sender.set_position_target_local_ned_encode(
                    0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, 0b1001_1111_1000, *target, 0, 0, 0, 0, 0, 0, 0.5, 0
                )
            )
        unsigned.close()
        received = setpoints.wait_for(count=1, timeout=10.0)
        time.sleep(0.5)
    finally:
        stop.set()
        feeder.join(5)
        station.close()
    assert len(setpoints.messages) == 1
    pose = received[0].pose
    np.testing.assert_allclose([pose.position.x, pose.position.y, pose.position.z], [2.0, 1.0, 3.0])
    yaw = quat_to_euler(quaternion_from_msg(pose.orientation))[2]
    assert yaw == pytest.approx(math.pi / 2 - 0.5)  # NED yaw 0.5 rad east of north, as ENU yaw
    assert received[0].header.frame_id == "odom"
    assert "refused input: unsigned command" in node.log_text()


@pytest.mark.parametrize(
    ("parameters", "message"),
    [
        ({"rotor_channels": "1,2,3"}, "rotor_channels has 3 entries, quad_x has 4 rotors"),
        # Channel k for rotor k: what flipped ArduCopter's quad at lift-off; refused with each reason.
        ({"rotor_channels": "1,2,3,4", "flight_stack": "ardupilot"},
         "rotor_channels 1,2,3,4 would flip quad_x on ArduPilot QUAD X (FRAME_CLASS 1, FRAME_TYPE 1): "
         "channel 2 is motor 2 (rear-left, ccw) but drives rotor_2 (rear-right, cw)"),
    ],
)  # fmt: skip
def test_bad_parameters_stop_the_node_with_a_clear_message(tmp_path, parameters, message):
    process = NodeProcess(
        "mavlink_bridge",
        tmp_path / "bad.log",
        parameters={"airframe": "quad_x", "gcs_enabled": False, **parameters},
    )
    assert process.process.wait(60.0) == 2
    assert message in process.log_text()


def test_the_node_answers_ardupilot_ahead_when_asked_and_says_so(tmp_path):
    port = free_port(socket.SOCK_DGRAM)
    parameters = {
        "airframe": "quad_x", "gcs_enabled": False, "flight_stack": "ardupilot", "flight_stack_port": port,
        "flight_stack_answer_ahead": True,
    }  # fmt: skip
    with NodeProcess("mavlink_bridge", tmp_path / "ahead.log", parameters=parameters) as node:
        assert "each frame answered ahead" in node.wait_for_log("outputs:", 60.0), node.log_text()
        peer = ArduPilotLikePeer(
            port, HoverController(RotorChannels(load_airframe("quad_x"))), arm_after_s=0.1
        )
        try:
            record = peer.fly(1.5)
        finally:
            peer.close()
        node.assert_running()
    stamps = np.array([reply["timestamp"] for reply in record.replies])
    np.testing.assert_allclose(np.diff(stamps), 1.0 / peer.frame_rate_hz, atol=1e-9)
    assert -record.replies[-1]["position"][2] > 0.5  # climbing towards the hover height


@pytest.mark.slow
def test_mavproxy_flies_the_simulated_vehicle_through_setpoint_with_signed_commands_only(
    start_node, ros_probe, tmp_path
):
    # The whole graph: simulator and controller nodes fly; the bridge only forwards (ground station only).
    from test_mavlink_mavproxy import read_tlog, start_mavproxy, stop

    passphrase = "graph-test-key"  # one word: MAVProxy's `signing key` takes one
    gcs_port = free_port(socket.SOCK_DGRAM)
    bridge_port = free_port(socket.SOCK_DGRAM)
    odom = ros_probe.subscribe("/uav3/odom", Odometry)
    # On the ground: started in the air, it fell and crashed in CI when the controller came up more than
    # 0.5 s after the simulator (real time, "no motor command for 0.50 s ... rotors stopped").
    start_node("simulator", namespace="/uav3", parameters={"seed": 1})
    start_node("controller", namespace="/uav3")
    bridge = start_node(
        "mavlink_bridge",
        namespace="/uav3",
        parameters={
            "flight_stack": "none",
            "gcs_port": gcs_port,
            "gcs_bind_port": bridge_port,
            "signing_key": passphrase,
        },
    )
    odom.wait_for(timeout=60.0)
    processes = [
        start_mavproxy(tmp_path, "signed", f"udpin:127.0.0.1:{gcs_port}",
                       [f"signing key {passphrase}", "repeat add 0.5 position 0 0 -2"]),
        start_mavproxy(tmp_path, "unsigned", f"udpout:127.0.0.1:{bridge_port}",
                       ["repeat add 0.5 position 3 3 -1"]),
    ]  # fmt: skip
    try:
        odom.wait_for(lambda m: abs(m.pose.pose.position.z - 2.0) < 0.1, timeout=40.0)
        time.sleep(1.0)
    finally:
        for process in processes:
            stop(process)
    p = odom.messages[-1].pose.pose.position
    assert math.hypot(p.x, p.y) < 0.5  # the unsigned setpoint, 4.2 m away, was never flown
    assert "refused input: unsigned command" in bridge.log_text()
    positions = [
        m for m in read_tlog(tmp_path / "signed" / "flight.tlog") if m.get_type() == "LOCAL_POSITION_NED"
    ]
    # MAVProxy watched it climb from the ground to 2 m (how well it then holds 2 m is the controller's
    # business, and varies with the machine's load).
    assert positions[0].z > -1.5 and any(abs(p.z + 2.0) < 0.15 for p in positions)
