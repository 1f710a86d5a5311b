"""ROS messages <-> numpy, in the frames of shared/spec/interfaces.md; bad content is a Refusal, not an error.

Rotor speeds (sensor_msgs/JointState)
    ``rotor_names(n) -> ["rotor_1", ..., "rotor_n"]``.
    ``rotor_speeds_from_joint_state(msg, n_rotors, limit_rad_s) -> RotorSpeeds | Refusal``: names
    ``rotor_1..rotor_N`` in any order, exactly once each, ``velocity`` of the same length, every speed
    finite, >= 0 and <= ``limit_rad_s``. Returns the speeds in rotor order 1..N with the stamp.
    ``joint_state_from_rotor_speeds(speeds, stamp) -> JointState`` with names rotor_1..rotor_N.

State (pose in world ENU; the twist of Odometry in body FLU, as REP-105 says)
    ``odometry_message(x, stamp, frame_id, child_frame_id)`` of the flat model state
    (multirotor_ros.model.state layout); ``state_from_odometry(msg) -> (p_WB_W, v_WB_W, q_WB, w_WB_B)``.
    ``pose_message(stamp, frame_id, p_WB_W, q_WB)``; ``pose_from_message(msg) -> (p_WB_W, q_WB)``.
    ``setpoint_from_pose(msg) -> (p_W, yaw)``: a ``setpoint`` PoseStamped as position and yaw.

IMU (sensor_msgs/Imu: orientation, body rates and specific force in body FLU)
    ``imu_message(stamp, frame_id, q_WB, specific_force_B, w_WB_B, *, accel_var, gyro_var,
    orientation_var)``; ``simulated_imu_message(stamp, frame_id, reading, sensors)`` with the
    covariances of the simulated sensor's noise; ``imu_from_message(msg) -> (w_WB_B, specific_force_B)``.

Quaternions and stamps
    ``quaternion_to_msg(q_wxyz)``, ``quaternion_from_msg(msg) -> (w, x, y, z)`` (frames.py holds the
    field order rule); ``stamp_to_ns(stamp)``, ``stamp_from_ns(ns)``, ``stamp_to_s(stamp)``.

Every ``*_from_*`` reader of a state refuses non-finite values and a quaternion whose norm is not 1
(within 1e-3; the accepted one is normalised).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, PoseStamped, Quaternion, Vector3
from nav_msgs.msg import Odometry
from numpy.typing import ArrayLike
from sensor_msgs.msg import Imu, JointState

from multirotor_ros.frames import ros_quat_to_wxyz, wxyz_to_ros_quat
from multirotor_ros.model import state as S
from multirotor_ros.model.rotation import FloatArray, quat_to_euler, quat_to_matrix
from multirotor_ros.plausibility import StateLimits, format_vector
from multirotor_ros.refusals import Refusal
from multirotor_ros.simulation.sensors import ImuReading, SensorConfig

# ------------------------------------------------------------------------------------------------
# Rotor speeds as JointState


@dataclass(frozen=True)
class RotorSpeeds:
    """Validated rotor speeds [rad/s] in rotor order 1..N and the message's stamp [ns] (0 = unstamped)."""

    speeds_rad_s: FloatArray
    stamp_ns: int


def rotor_names(n_rotors: int) -> list[str]:
    """``["rotor_1", ..., "rotor_N"]``."""
    return [f"rotor_{k}" for k in range(1, n_rotors + 1)]


def rotor_speeds_from_joint_state(message: Any, n_rotors: int, limit_rad_s: float) -> RotorSpeeds | Refusal:
    """Validate a rotor-speed JointState (see the module docstring); never raises on bad content."""
    names = list(message.name)
    velocity = np.asarray(message.velocity, dtype=float)
    if len(names) != n_rotors:
        return Refusal("wrong rotor count", f"{len(names)} names, the airframe has {n_rotors} rotors")
    if velocity.shape != (n_rotors,):
        return Refusal("wrong rotor count", f"{velocity.size} velocities for {n_rotors} rotors")
    order = np.empty(n_rotors, dtype=int)
    seen: set[int] = set()
    for position, name in enumerate(names):
        number = _rotor_number(name, n_rotors)
        if number is None:
            return Refusal("unknown rotor name", f"{name!r} (expected rotor_1 .. rotor_{n_rotors})")
        if number in seen:
            return Refusal("duplicate rotor name", f"{name!r} appears twice")
        seen.add(number)
        order[number - 1] = position
    speeds = velocity[order]
    bad = ~np.isfinite(speeds)
    if bad.any():
        k = int(np.argmax(bad))
        return Refusal("non-finite speed", f"rotor_{k + 1} = {float(speeds[k])}")
    if np.any(speeds < 0):
        k = int(np.argmax(speeds < 0))
        return Refusal("negative speed", f"rotor_{k + 1} = {speeds[k]:g} rad/s")
    if np.any(speeds > limit_rad_s):
        k = int(np.argmax(speeds > limit_rad_s))
        return Refusal(
            "oversized speed",
            f"rotor_{k + 1} = {speeds[k]:g} rad/s > {limit_rad_s:g} rad/s (speeds are rad/s, not rpm)",
        )
    return RotorSpeeds(speeds, stamp_to_ns(message.header.stamp))


def _rotor_number(name: str, n_rotors: int) -> int | None:
    prefix, _, digits = name.partition("_")
    if prefix != "rotor" or not digits.isdigit() or digits.startswith("0"):
        return None
    number = int(digits)
    return number if 1 <= number <= n_rotors else None


def joint_state_from_rotor_speeds(speeds_rad_s: ArrayLike, stamp: Time) -> JointState:
    """A JointState with ``rotor_1..rotor_N`` and the speeds [rad/s] as ``velocity``."""
    speeds = np.asarray(speeds_rad_s, dtype=float)
    message = JointState()
    message.header.stamp = stamp
    message.name = rotor_names(speeds.size)
    message.velocity = speeds.tolist()
    return message


# ------------------------------------------------------------------------------------------------
# Quaternions, vectors and stamps


def quaternion_to_msg(q_wxyz: ArrayLike) -> Quaternion:
    """Our (w, x, y, z) as a geometry_msgs/Quaternion."""
    x, y, z, w = wxyz_to_ros_quat(q_wxyz)
    return Quaternion(x=x, y=y, z=z, w=w)


def quaternion_from_msg(message: Any) -> FloatArray:
    """A geometry_msgs/Quaternion as our (w, x, y, z)."""
    return ros_quat_to_wxyz(message.x, message.y, message.z, message.w)


def vector_from_msg(message: Any) -> FloatArray:
    """A geometry_msgs/Vector3 or Point as an array (x, y, z)."""
    return np.array([message.x, message.y, message.z], dtype=float)


def _point(values: ArrayLike) -> Point:
    x, y, z = (float(v) for v in np.asarray(values, dtype=float))
    return Point(x=x, y=y, z=z)


def _vector(values: ArrayLike) -> Vector3:
    x, y, z = (float(v) for v in np.asarray(values, dtype=float))
    return Vector3(x=x, y=y, z=z)


def _unit_quaternion(q_WB: FloatArray, what: str) -> FloatArray | Refusal:
    # The largest component first: the norm of 1e308-sized components overflows.
    largest = float(np.max(np.abs(q_WB)))
    norm = largest if largest > 2.0 else float(np.linalg.norm(q_WB))
    if abs(norm - 1.0) > StateLimits().quaternion_norm_tolerance:
        return Refusal("invalid orientation", f"{what} quaternion norm {norm:.6g}, expected 1")
    return q_WB / norm


def stamp_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def stamp_to_s(stamp: Any) -> float:
    """builtin_interfaces/Time -> seconds (float)."""
    return stamp_to_ns(stamp) * 1e-9


def stamp_from_ns(nanoseconds: int) -> Time:
    """Integer nanoseconds (>= 0) -> builtin_interfaces/Time."""
    sec, nanosec = divmod(int(nanoseconds), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


# ------------------------------------------------------------------------------------------------
# State messages


def odometry_message(
    x: ArrayLike, stamp: Time, frame_id: str = "odom", child_frame_id: str = "base_link"
) -> Odometry:
    """nav_msgs/Odometry of one flat state: pose in world ENU, twist in body FLU (REP-105)."""
    # Plain floats rather than numpy: the simulator builds hundreds of these per second.
    s = [float(v) for v in np.asarray(x, dtype=float).reshape(-1)[: S.ROTORS_START]]
    w, qx, qy, qz = s[6:10]
    vx, vy, vz = s[3:6]
    # v_B = R^T v_W, with R the rotation matrix of q (rows of R^T are the columns of R).
    v_B = (
        (1 - 2 * (qy * qy + qz * qz)) * vx + 2 * (qx * qy + w * qz) * vy + 2 * (qx * qz - w * qy) * vz,
        2 * (qx * qy - w * qz) * vx + (1 - 2 * (qx * qx + qz * qz)) * vy + 2 * (qy * qz + w * qx) * vz,
        2 * (qx * qz + w * qy) * vx + 2 * (qy * qz - w * qx) * vy + (1 - 2 * (qx * qx + qy * qy)) * vz,
    )
    message = Odometry()
    message.header.stamp = stamp
    message.header.frame_id = frame_id
    message.child_frame_id = child_frame_id
    message.pose.pose.position = Point(x=s[0], y=s[1], z=s[2])
    message.pose.pose.orientation = Quaternion(x=qx, y=qy, z=qz, w=w)
    message.twist.twist.linear = Vector3(x=v_B[0], y=v_B[1], z=v_B[2])
    message.twist.twist.angular = Vector3(x=s[10], y=s[11], z=s[12])
    return message


def state_from_odometry(message: Any) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | Refusal:
    """(p_WB_W, v_WB_W, q_WB, w_WB_B) of an Odometry (twist in body FLU), or a Refusal."""
    p = vector_from_msg(message.pose.pose.position)
    q = quaternion_from_msg(message.pose.pose.orientation)
    v_B = vector_from_msg(message.twist.twist.linear)
    w_B = vector_from_msg(message.twist.twist.angular)
    if not all(np.all(np.isfinite(a)) for a in (p, q, v_B, w_B)):
        return Refusal(
            "non-finite odometry",
            f"position {format_vector(p)}, orientation {format_vector(q)}, "
            f"twist {format_vector(v_B)} {format_vector(w_B)}",
        )
    q_unit = _unit_quaternion(q, "odometry")
    if isinstance(q_unit, Refusal):
        return q_unit
    return p, quat_to_matrix(q_unit) @ v_B, q_unit, w_B


def pose_message(stamp: Time, frame_id: str, p_WB_W: ArrayLike, q_WB: ArrayLike) -> PoseStamped:
    """geometry_msgs/PoseStamped of a position (world ENU) and attitude."""
    message = PoseStamped()
    message.header.stamp = stamp
    message.header.frame_id = frame_id
    message.pose.position = _point(p_WB_W)
    message.pose.orientation = quaternion_to_msg(q_WB)
    return message


def pose_from_message(message: Any) -> tuple[FloatArray, FloatArray] | Refusal:
    """(p_WB_W, q_WB) of a PoseStamped (a measured pose, e.g. motion capture), or a Refusal."""
    p = vector_from_msg(message.pose.position)
    q = quaternion_from_msg(message.pose.orientation)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        return Refusal("non-finite pose", f"position {format_vector(p)}, orientation {format_vector(q)}")
    q_unit = _unit_quaternion(q, "pose")
    if isinstance(q_unit, Refusal):
        return q_unit
    return p, q_unit


def setpoint_from_pose(message: Any) -> tuple[FloatArray, float] | Refusal:
    """Desired position (world ENU) and yaw of a ``setpoint`` PoseStamped, or a Refusal.

    An all-zero quaternion (a PoseStamped left at its defaults) means yaw 0.
    """
    p = vector_from_msg(message.pose.position)
    q = quaternion_from_msg(message.pose.orientation)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        return Refusal("non-finite setpoint", f"position {format_vector(p)}, orientation {format_vector(q)}")
    if not np.any(q):
        return p, 0.0
    q_unit = _unit_quaternion(q, "setpoint")
    if isinstance(q_unit, Refusal):
        return q_unit
    return p, float(quat_to_euler(q_unit)[2])


# ------------------------------------------------------------------------------------------------
# IMU


def imu_message(
    stamp: Time,
    frame_id: str,
    q_WB: ArrayLike,
    specific_force_B: ArrayLike,
    w_WB_B: ArrayLike,
    *,
    accel_var: float,
    gyro_var: float,
    orientation_var: float,
) -> Imu:
    """sensor_msgs/Imu: orientation, body rates and specific force in body FLU, diagonal covariances."""
    message = Imu()
    message.header.stamp = stamp
    message.header.frame_id = frame_id
    message.orientation = quaternion_to_msg(q_WB)
    message.angular_velocity = _vector(w_WB_B)
    message.linear_acceleration = _vector(specific_force_B)
    message.orientation_covariance = _diagonal(orientation_var)
    message.angular_velocity_covariance = _diagonal(gyro_var)
    message.linear_acceleration_covariance = _diagonal(accel_var)
    return message


def simulated_imu_message(stamp: Time, frame_id: str, reading: ImuReading, sensors: SensorConfig) -> Imu:
    """The Imu of a simulated reading, with the per-sample variances of the sensor's white noise."""
    return imu_message(
        stamp,
        frame_id,
        reading.q_WB,
        reading.specific_force_B,
        reading.w_WB_B,
        accel_var=sensors.accel_sample_std_m_s2**2,
        gyro_var=sensors.gyro_sample_std_rad_s**2,
        orientation_var=sensors.orientation_noise_rad**2,
    )


def _diagonal(variance: float) -> list[float]:
    return [float(variance), 0.0, 0.0, 0.0, float(variance), 0.0, 0.0, 0.0, float(variance)]


def imu_from_message(message: Any) -> tuple[FloatArray, FloatArray] | Refusal:
    """(w_WB_B, specific_force_B) of an Imu (body FLU), or a Refusal if not finite."""
    w_B = vector_from_msg(message.angular_velocity)
    f_B = vector_from_msg(message.linear_acceleration)
    if not (np.all(np.isfinite(w_B)) and np.all(np.isfinite(f_B))):
        return Refusal("non-finite imu", f"rates {format_vector(w_B)}, specific force {format_vector(f_B)}")
    return w_B, f_B
