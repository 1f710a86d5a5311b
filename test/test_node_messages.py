"""ROS messages <-> numpy (multirotor_ros/nodes/messages.py): round trips, frames and refusals.

Without DDS, except the check that a message may be filled and published again as soon as ``publish``
returns (the reuse the builders' ``out=`` is for).
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, JointState

from multirotor_ros.model import state as S
from multirotor_ros.model.state import make_state
from multirotor_ros.nodes import messages
from multirotor_ros.nodes.messages import (
    imu_from_message,
    imu_message,
    joint_state_from_rotor_speeds,
    odometry_message,
    pose_from_message,
    pose_message,
    quaternion_from_msg,
    quaternion_to_msg,
    rotor_names,
    rotor_speeds_from_joint_state,
    setpoint_from_pose,
    simulated_imu_message,
    stamp_from_ns,
    stamp_to_ns,
    stamp_to_s,
    state_from_odometry,
)
from multirotor_ros.refusals import Refusal
from multirotor_ros.simulation.sensors import ImuReading, SensorConfig

LIMIT_RAD_S = 1000.0
finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
vectors = st.lists(finite, min_size=3, max_size=3).map(np.array)
# Stamps that builtin_interfaces/Time holds: sec is an int32.
stamps_ns = st.integers(min_value=0, max_value=(2**31 - 1) * 1_000_000_000 + 999_999_999)


@st.composite
def unit_quaternions(draw: st.DrawFn) -> np.ndarray:
    q = np.array(draw(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4)))
    assume(np.linalg.norm(q) > 0.1)
    return q / np.linalg.norm(q)


def joint_state(names: list[str], speeds: list[float], stamp_ns: int = 0) -> JointState:
    message = JointState()
    message.header.stamp = stamp_from_ns(stamp_ns)
    message.name = list(names)
    message.velocity = [float(v) for v in speeds]
    return message


ROTORS4 = rotor_names(4)

# ------------------------------------------------------------------ stamps and quaternions


@settings(max_examples=200, deadline=None)
@given(stamps_ns)
def test_stamps_round_trip_exactly(nanoseconds: int) -> None:
    stamp = stamp_from_ns(nanoseconds)
    assert 0 <= stamp.nanosec < 1_000_000_000
    assert stamp_to_ns(stamp) == nanoseconds
    assert stamp_to_s(stamp) == pytest.approx(nanoseconds * 1e-9, rel=1e-15)


@settings(max_examples=200, deadline=None)
@given(st.lists(finite, min_size=4, max_size=4))
def test_quaternions_round_trip_exactly_with_w_first_inside_and_last_in_ros(values: list[float]) -> None:
    message = quaternion_to_msg(values)
    assert (message.w, message.x, message.y, message.z) == tuple(values)
    np.testing.assert_array_equal(quaternion_from_msg(message), values)


# ------------------------------------------------------------------ rotor speeds


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.floats(0.0, LIMIT_RAD_S), min_size=1, max_size=12),
    stamps_ns,
    st.randoms(use_true_random=False),
)
def test_rotor_speeds_round_trip_exactly_in_any_name_order(speeds, stamp_ns, random) -> None:
    message = joint_state_from_rotor_speeds(speeds, stamp_from_ns(stamp_ns))
    assert list(message.name) == rotor_names(len(speeds))
    order = list(range(len(speeds)))
    random.shuffle(order)
    shuffled = joint_state([message.name[k] for k in order], [speeds[k] for k in order], stamp_ns)
    result = rotor_speeds_from_joint_state(shuffled, len(speeds), LIMIT_RAD_S)
    np.testing.assert_array_equal(result.speeds_rad_s, speeds)
    assert result.stamp_ns == stamp_ns


@pytest.mark.parametrize(
    ("names", "speeds", "reason"),
    [
        (ROTORS4[:3], [1, 2, 3], "wrong rotor count"),
        (ROTORS4, [1, 2, 3], "wrong rotor count"),
        (["rotor_1", "rotor_2", "rotor_3", "rotor_5"], [1, 2, 3, 4], "unknown rotor name"),
        (["rotor_1", "rotor_2", "rotor_3", "motor_4"], [1, 2, 3, 4], "unknown rotor name"),
        (["rotor_1", "rotor_2", "rotor_3", "rotor_04"], [1, 2, 3, 4], "unknown rotor name"),
        (["rotor_1", "rotor_1", "rotor_3", "rotor_4"], [1, 2, 3, 4], "duplicate rotor name"),
        (ROTORS4, [1, math.nan, 3, 4], "non-finite speed"),
        (ROTORS4, [1, 2, math.inf, 4], "non-finite speed"),
        (ROTORS4, [1, 2, 3, -0.5], "negative speed"),
        (ROTORS4, [1, 2, 3, 5000.0], "oversized speed"),
    ],
)
def test_bad_rotor_speed_messages_are_refused_with_a_reason(names, speeds, reason) -> None:
    result = rotor_speeds_from_joint_state(joint_state(names, speeds), 4, LIMIT_RAD_S)
    assert isinstance(result, Refusal)
    assert result.reason == reason
    assert result.detail


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=12).filter(lambda name: name not in ROTORS4), st.integers(0, 3))
def test_a_joint_name_that_is_not_one_of_the_rotors_is_refused(name: str, position: int) -> None:
    names = list(ROTORS4)
    names[position] = name
    result = rotor_speeds_from_joint_state(joint_state(names, [1.0] * 4), 4, LIMIT_RAD_S)
    assert isinstance(result, Refusal)
    assert result.reason in ("unknown rotor name", "duplicate rotor name")


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 8).filter(lambda n: n != 4), st.booleans())
def test_a_wrong_number_of_names_or_speeds_is_refused(count: int, wrong_names: bool) -> None:
    names = rotor_names(count) if wrong_names else ROTORS4
    speeds = [1.0] * (4 if wrong_names else count)
    result = rotor_speeds_from_joint_state(joint_state(names, speeds), 4, LIMIT_RAD_S)
    assert isinstance(result, Refusal) and result.reason == "wrong rotor count"


# ------------------------------------------------------------------ odometry, pose and setpoint


def test_odometry_has_the_pose_in_world_and_the_twist_in_body_axes() -> None:
    # Yawed +90 deg and flying north: forward in the body, i.e. +x of FLU.
    x = make_state(4, position_m=(1, 2, 3), velocity_m_s=(0, 2, 0), euler_rad=(0, 0, math.pi / 2))[0]
    message = odometry_message(x, stamp_from_ns(1_500_000_000))
    assert (message.header.frame_id, message.child_frame_id) == ("odom", "base_link")
    assert message.twist.twist.linear.x == pytest.approx(2.0)
    assert message.twist.twist.linear.y == pytest.approx(0.0, abs=1e-12)
    assert message.pose.pose.orientation.z == pytest.approx(math.sqrt(0.5))
    p, v, q, _ = state_from_odometry(message)
    np.testing.assert_allclose(p, [1, 2, 3])
    np.testing.assert_allclose(v, [0, 2, 0], atol=1e-12)
    assert stamp_to_ns(message.header.stamp) == 1_500_000_000


@settings(max_examples=100, deadline=None)
@given(vectors, vectors, unit_quaternions(), vectors)
def test_odometry_round_trips(p_WB_W, v_WB_W, q_WB, w_WB_B) -> None:
    x = make_state(4, position_m=p_WB_W, velocity_m_s=v_WB_W, body_rate_rad_s=w_WB_B)[0]
    x[S.QUATERNION] = q_WB
    p, v, q, w = state_from_odometry(odometry_message(x, Time(), "uav1/odom", "uav1/base_link"))
    np.testing.assert_array_equal(p, p_WB_W)
    np.testing.assert_array_equal(w, w_WB_B)
    np.testing.assert_allclose(q, q_WB, rtol=0, atol=1e-15)
    np.testing.assert_allclose(v, v_WB_W, rtol=1e-12, atol=1e-9)


def test_odometry_that_is_not_finite_or_not_a_rotation_is_refused() -> None:
    message = odometry_message(make_state(4)[0], Time())
    message.pose.pose.position.x = math.nan
    assert state_from_odometry(message).reason == "non-finite odometry"
    message = odometry_message(make_state(4)[0], Time())
    message.pose.pose.orientation.w = 2.0
    assert state_from_odometry(message).reason == "invalid orientation"


@settings(max_examples=100, deadline=None)
@given(vectors, unit_quaternions(), stamps_ns)
def test_poses_round_trip(p_WB_W, q_WB, stamp_ns) -> None:
    message = pose_message(stamp_from_ns(stamp_ns), "odom", p_WB_W, q_WB)
    assert message.header.frame_id == "odom" and stamp_to_ns(message.header.stamp) == stamp_ns
    p, q = pose_from_message(message)
    np.testing.assert_array_equal(p, p_WB_W)
    np.testing.assert_allclose(q, q_WB, rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    ("position", "orientation", "reason"),
    [
        ((math.nan, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), "non-finite pose"),
        ((0.0, 0.0, 0.0), (1.0, math.inf, 0.0, 0.0), "non-finite pose"),
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), "invalid orientation"),
        ((0.0, 0.0, 0.0), (1.0, 0.1, 0.0, 0.0), "invalid orientation"),
    ],
)
def test_a_pose_that_is_not_finite_or_not_a_rotation_is_refused(position, orientation, reason) -> None:
    result = pose_from_message(pose_message(Time(), "odom", position, orientation))
    assert isinstance(result, Refusal) and result.reason == reason


def test_a_setpoint_gives_position_and_yaw() -> None:
    message = PoseStamped()
    message.pose.position.x = 1.0
    message.pose.orientation.z, message.pose.orientation.w = math.sin(0.25), math.cos(0.25)
    position, yaw = setpoint_from_pose(message)
    assert position[0] == 1.0 and yaw == pytest.approx(0.5)
    message.pose.orientation.w = 0.0
    message.pose.orientation.z = 0.0
    assert setpoint_from_pose(message)[1] == 0.0  # an unset orientation means yaw 0
    message.pose.orientation.w = 0.5
    assert setpoint_from_pose(message).reason == "invalid orientation"
    message.pose.position.y = math.inf
    assert setpoint_from_pose(message).reason == "non-finite setpoint"


# ------------------------------------------------------------------ imu


@settings(max_examples=100, deadline=None)
@given(unit_quaternions(), vectors, vectors)
def test_imu_readings_round_trip_exactly(q_WB, specific_force_B, w_WB_B) -> None:
    message = imu_message(
        Time(), "base_link", q_WB, specific_force_B, w_WB_B, accel_var=0.1, gyro_var=0.2, orientation_var=0.3
    )
    w, f = imu_from_message(message)
    np.testing.assert_array_equal(w, w_WB_B)
    np.testing.assert_array_equal(f, specific_force_B)
    np.testing.assert_array_equal(quaternion_from_msg(message.orientation), q_WB)


def test_imu_covariances_are_the_per_sample_variances_of_the_sensor_noise() -> None:
    sensors = SensorConfig(
        imu_rate_hz=400.0,
        accel_noise_density_m_s2_sqrt_hz=0.01,
        gyro_noise_density_rad_s_sqrt_hz=0.002,
        orientation_noise_rad=0.05,
    )
    reading = ImuReading(np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.0, 0.0, 9.81]), np.zeros(3))
    message = simulated_imu_message(Time(), "base_link", reading, sensors)
    # Standard deviation of one sample: density x sqrt(rate) = density x 20.
    np.testing.assert_allclose(np.reshape(message.linear_acceleration_covariance, (3, 3)), np.eye(3) * 0.04)
    np.testing.assert_allclose(np.reshape(message.angular_velocity_covariance, (3, 3)), np.eye(3) * 0.0016)
    np.testing.assert_allclose(np.reshape(message.orientation_covariance, (3, 3)), np.eye(3) * 0.0025)
    assert message.linear_acceleration.z == 9.81


@pytest.mark.parametrize("field", ["angular_velocity", "linear_acceleration"])
def test_an_imu_message_that_is_not_finite_is_refused(field: str) -> None:
    message = Imu()
    getattr(message, field).y = math.nan
    result = imu_from_message(message)
    assert isinstance(result, Refusal) and result.reason == "non-finite imu"


# ------------------------------------------------------------------ fast paths and reused messages

# A quaternion's norm as a factor: well within the tolerance of 1e-3 (accepted, normalised) or well
# beyond it (refused); the fast readers and the checked ones must agree on both.
norm_factors = st.one_of(st.floats(1 - 8e-4, 1 + 8e-4), st.floats(1.002, 1e3), st.floats(0.0, 0.998))
values = st.one_of(finite, st.sampled_from([math.nan, math.inf, -math.inf, 1e300]))


@settings(max_examples=300, deadline=None)
@given(st.lists(values, min_size=3, max_size=3), unit_quaternions(), norm_factors, vectors, vectors)
def test_the_fast_readers_agree_with_the_checked_ones(position, q_WB, factor, v_B, w_B) -> None:
    message = Odometry()
    p, o = message.pose.pose.position, message.pose.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position)
    o.w, o.x, o.y, o.z = (float(v) for v in q_WB * factor)
    t = message.twist.twist
    t.linear.x, t.linear.y, t.linear.z = (float(v) for v in v_B)
    t.angular.x, t.angular.y, t.angular.z = (float(v) for v in w_B)
    pose = PoseStamped()
    pose.pose = message.pose.pose
    for fast, checked, argument in [
        (
            messages.state_from_odometry,
            lambda m: messages._checked_state(messages.odometry_values(m)),
            message,
        ),
        (messages.pose_from_message, messages._checked_pose, pose),
        (messages.setpoint_from_pose, messages._checked_setpoint, pose),
    ]:
        quick, slow = fast(argument), checked(argument)
        if isinstance(slow, Refusal):
            assert quick == slow
        else:
            for a, b in zip(quick, slow, strict=True):
                np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("speed", [0.0, LIMIT_RAD_S, -0.0])
def test_speeds_at_the_bounds_are_taken(speed: float) -> None:
    result = rotor_speeds_from_joint_state(joint_state(ROTORS4, [speed, 1.0, 2.0, 3.0], 7), 4, LIMIT_RAD_S)
    assert not isinstance(result, Refusal)
    np.testing.assert_array_equal(result.speeds_rad_s, [speed, 1.0, 2.0, 3.0])
    assert result.stamp_ns == 7


def test_the_taken_speeds_do_not_share_memory_with_the_message() -> None:
    message = joint_state(ROTORS4, [1.0, 2.0, 3.0, 4.0])
    result = rotor_speeds_from_joint_state(message, 4, LIMIT_RAD_S)
    message.velocity[0] = 9.0
    assert result.speeds_rad_s[0] == 1.0


def test_a_message_filled_in_place_is_the_message_built_new() -> None:
    x1 = make_state(8, position_m=(1, 2, 3), velocity_m_s=(0.5, -1, 2), euler_rad=(0.1, -0.2, 1.0))[0]
    x2 = make_state(8, position_m=(-4, 5, 6), velocity_m_s=(1, 1, -1), body_rate_rad_s=(0.3, 0.2, 0.1))[0]
    stamp1, stamp2 = stamp_from_ns(1_000_000_001), stamp_from_ns(2_000_000_002)
    sensors = SensorConfig()
    reading = ImuReading(x2[S.QUATERNION], np.array([0.1, 0.2, 9.8]), np.array([0.01, 0.02, 0.03]))
    other = ImuReading(x1[S.QUATERNION], np.zeros(3), np.ones(3))
    builders = [
        (Odometry, lambda s, x, out=None: odometry_message(x, s, "a", "b", out=out)),
        (PoseStamped, lambda s, x, out=None: pose_message(s, "odom", x[:3], x[S.QUATERNION], out=out)),
        (
            Imu,
            lambda s, x, out=None: simulated_imu_message(
                s, "base_link", reading if x is x2 else other, sensors, out=out
            ),
        ),
        (JointState, lambda s, x, out=None: joint_state_from_rotor_speeds(x[-8:] * 100 + 1, s, out=out)),
        (
            JointState,
            lambda s, x, out=None: joint_state_from_rotor_speeds(x[-8 if x is x2 else -4 :], s, out=out),
        ),
    ]
    for kind, build in builders:
        reused = build(stamp1, x1, out=kind())
        again = build(stamp2, x2, out=reused)
        assert again is reused
        assert again == build(stamp2, x2), kind


@pytest.mark.ros
def test_a_message_may_be_changed_and_published_again_as_soon_as_publish_returns() -> None:
    import threading

    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    context = rclpy.Context()
    rclpy.init(args=["reuse_check"], context=context)
    node = rclpy.create_node("reuse_check", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    received: list[float] = []
    node.create_subscription(Odometry, "reuse_check", lambda m: received.append(m.pose.pose.position.x), 1000)
    publisher = node.create_publisher(Odometry, "reuse_check", 1000)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        deadline = time.monotonic() + 10.0
        while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        message = Odometry()
        for k in range(300):
            odometry_message(make_state(4, position_m=(k, 0, 0))[0], stamp_from_ns(k), out=message)
            publisher.publish(message)
        while len(received) < 300 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        executor.shutdown()
        spinner.join(10.0)
        node.destroy_node()
        context.try_shutdown()
    assert received == [float(k) for k in range(300)]
