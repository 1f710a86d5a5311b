"""ROS messages <-> numpy, in the frames of shared/spec/interfaces.md; bad content is a Refusal, not an error.

Rotor speeds (sensor_msgs/JointState)
    ``rotor_names(n) -> ["rotor_1", ..., "rotor_n"]``.
    ``rotor_speeds_from_joint_state(msg, n_rotors, limit_rad_s) -> RotorSpeeds | Refusal``: names
    ``rotor_1..rotor_N`` in any order, exactly once each, ``velocity`` of the same length, every speed
    finite, >= 0 and <= ``limit_rad_s``. Returns the speeds in rotor order 1..N with the stamp.
    ``joint_state_from_rotor_speeds(speeds, stamp) -> JointState`` with names rotor_1..rotor_N.

State (pose in world ENU; the twist of Odometry in body FLU, as REP-105 says)
    ``odometry_message(x, stamp, frame_id, child_frame_id)`` of the flat model state
    (multirotor_ros.model.state layout); ``state_from_odometry(msg) -> (p_WB_W, v_WB_W, q_WB, w_WB_B)``,
    the same of its 13 values (``odometry_values``, or read from the wire: nodes/cdr.py) with
    ``state_from_odometry_values``.
    ``pose_message(stamp, frame_id, p_WB_W, q_WB)``; ``pose_from_message(msg) -> (p_WB_W, q_WB)``.
    ``setpoint_from_pose(msg) -> (p_W, yaw)``: a ``setpoint`` PoseStamped as position and yaw.

IMU (sensor_msgs/Imu: orientation, body rates and specific force in body FLU)
    ``imu_message(stamp, frame_id, q_WB, specific_force_B, w_WB_B, *, accel_var, gyro_var,
    orientation_var)``; ``simulated_imu_message(stamp, frame_id, reading, sensors)`` with the
    covariances of the simulated sensor's noise; ``imu_from_message(msg) -> (w_WB_B, specific_force_B)``.
    ``odometry_covariances(sensors) -> (pose, twist)``: the odometry's covariances from the same noise.

Quaternions and stamps
    ``quaternion_to_msg(q_wxyz)``, ``quaternion_from_msg(msg) -> (w, x, y, z)`` (frames.py holds the
    field order rule); ``stamp_to_ns(stamp)``, ``stamp_from_ns(ns)``, ``stamp_to_s(stamp)``.

Every ``*_from_*`` reader of a state refuses non-finite values and a quaternion whose norm is not 1
(within 1e-3; the accepted one is normalised).

Speed (issue 10: nodes convert several messages per 4 ms control period). The readers check the common
case (every value finite, a unit quaternion, rotors named in order) on plain floats and return at once;
only a message that fails it takes the slower path that finds and words the reason, so the refusals
are the same as ever. The builders take ``out=``: a message of the right type to fill in place instead
of a new one (constructing an Odometry alone costs more than filling it). Publishing copies a message
into the middleware before ``publish`` returns (rclpy converts it to its C struct, which rcl then
serialises), so a publisher may reuse one message for every publish; a caller that keeps a message it
published (to resend it, say) must not pass the same object as ``out`` of the next one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, Quaternion
from nav_msgs.msg import Odometry
from numpy.typing import ArrayLike
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import Imu, JointState

from multirotor_ros.frames import ros_quat_to_wxyz, wxyz_to_ros_quat
from multirotor_ros.model import state as S
from multirotor_ros.model.rotation import FloatArray, quat_to_euler, quat_to_matrix
from multirotor_ros.plausibility import StateLimits, format_vector
from multirotor_ros.refusals import Refusal
from multirotor_ros.simulation.sensors import ImuReading, SensorConfig

# Topics whose newest message a late subscriber needs (the simulator's injected_faults, crashed): kept.
LATCHED_QOS = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)

# ------------------------------------------------------------------------------------------------
# Rotor speeds as JointState


@dataclass(frozen=True)
class RotorSpeeds:
    """Validated rotor speeds [rad/s] in rotor order 1..N and the message's stamp [ns] (0 = unstamped)."""

    speeds_rad_s: FloatArray
    stamp_ns: int


def rotor_names(n_rotors: int) -> list[str]:
    """``["rotor_1", ..., "rotor_N"]``."""
    return list(_rotor_names(n_rotors))


@cache
def _rotor_names(n_rotors: int) -> tuple[str, ...]:
    return tuple(f"rotor_{k}" for k in range(1, n_rotors + 1))


def rotor_speeds_from_joint_state(message: Any, n_rotors: int, limit_rad_s: float) -> RotorSpeeds | Refusal:
    """Validate a rotor-speed JointState (see the module docstring); never raises on bad content."""
    return rotor_speeds_from_parts(
        message.name, message.velocity, stamp_to_ns(message.header.stamp), n_rotors, limit_rad_s
    )


def rotor_speeds_from_parts(
    names: Any, velocity: Any, stamp_ns: int, n_rotors: int, limit_rad_s: float
) -> RotorSpeeds | Refusal:
    """rotor_speeds_from_joint_state of a JointState's names, velocities and stamp [ns] (read apart)."""
    # The common case: names in rotor order, every speed within [0, limit] (NaN fails the comparison).
    if (
        len(velocity) == n_rotors
        and tuple(names) == _rotor_names(n_rotors)
        and all(0.0 <= v <= limit_rad_s for v in velocity)
    ):
        return RotorSpeeds(np.array(velocity, dtype=float), stamp_ns)
    return _checked_rotor_speeds(names, velocity, n_rotors, limit_rad_s, stamp_ns)


def _checked_rotor_speeds(
    message_names: Any, message_velocity: Any, n_rotors: int, limit_rad_s: float, stamp_ns: int
) -> RotorSpeeds | Refusal:
    """rotor_speeds_from_parts of any content: names in any order, and the reason of a refusal."""
    names = list(message_names)
    velocity = np.asarray(message_velocity, dtype=float)
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
    return RotorSpeeds(speeds, stamp_ns)


def _rotor_number(name: str, n_rotors: int) -> int | None:
    prefix, _, digits = name.partition("_")
    if prefix != "rotor" or not digits.isdigit() or digits.startswith("0"):
        return None
    number = int(digits)
    return number if 1 <= number <= n_rotors else None


def joint_state_from_rotor_speeds(
    speeds_rad_s: ArrayLike, stamp: Time, *, out: JointState | None = None
) -> JointState:
    """A JointState of rotor_1..rotor_N with the speeds [rad/s] as ``velocity``; ``out``: fill that one."""
    speeds = np.asarray(speeds_rad_s, dtype=float).reshape(-1)
    message = JointState() if out is None else out
    message.header.stamp = stamp
    names = _rotor_names(speeds.size)
    if out is None or tuple(message.name) != names:
        message.name = list(names)
    message.velocity = speeds.tolist()
    return message


# ------------------------------------------------------------------------------------------------
# Quaternions, vectors and stamps


def quaternion_to_msg(q_wxyz: ArrayLike) -> Quaternion:
    """Our (w, x, y, z) as a geometry_msgs/Quaternion."""
    message = Quaternion()
    _set_quaternion(message, q_wxyz)
    return message


def quaternion_from_msg(message: Any) -> FloatArray:
    """A geometry_msgs/Quaternion as our (w, x, y, z)."""
    return ros_quat_to_wxyz(message.x, message.y, message.z, message.w)


def vector_from_msg(message: Any) -> FloatArray:
    """A geometry_msgs/Vector3 or Point as an array (x, y, z)."""
    return np.array([message.x, message.y, message.z], dtype=float)


def _set_xyz(message: Any, values: ArrayLike) -> None:
    """Fill a Point or Vector3 in place with three values."""
    message.x, message.y, message.z = np.asarray(values, dtype=float).reshape(3).tolist()


def _set_quaternion(message: Any, q_wxyz: ArrayLike) -> None:
    """Fill a geometry_msgs/Quaternion in place with our (w, x, y, z)."""
    message.x, message.y, message.z, message.w = wxyz_to_ros_quat(q_wxyz)


QUATERNION_NORM_TOLERANCE = StateLimits().quaternion_norm_tolerance


def _unit_quaternion(q_WB: FloatArray, what: str) -> FloatArray | Refusal:
    # The largest component first: the norm of 1e308-sized components overflows.
    largest = float(np.max(np.abs(q_WB)))
    norm = largest if largest > 2.0 else float(np.linalg.norm(q_WB))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        return Refusal("invalid orientation", f"{what} quaternion norm {norm:.6g}, expected 1")
    return q_WB / norm


def _unit_norm(w: float, x: float, y: float, z: float) -> float | None:
    """The norm of a finite quaternion if it is 1 within the tolerance, else None (the slow path says why)."""
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    return norm if abs(norm - 1.0) <= QUATERNION_NORM_TOLERANCE else None


def _finite(*values: float) -> bool:
    return all(map(math.isfinite, values))


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
    x: ArrayLike,
    stamp: Time,
    frame_id: str = "odom",
    child_frame_id: str = "base_link",
    *,
    out: Odometry | None = None,
) -> Odometry:
    """nav_msgs/Odometry of one flat state: pose in world ENU, twist in body FLU (REP-105).

    ``out``: an Odometry to fill in place (its covariances are left as they are: zero, unknown).
    """
    px, py, pz, qx, qy, qz, w, bx, by, bz, wx, wy, wz = odometry_values_of_state(x)
    message = Odometry() if out is None else out
    message.header.stamp = stamp
    message.header.frame_id = frame_id
    message.child_frame_id = child_frame_id
    pose = message.pose.pose
    pose.position.x, pose.position.y, pose.position.z = px, py, pz
    o = pose.orientation
    o.x, o.y, o.z, o.w = qx, qy, qz, w
    twist = message.twist.twist
    twist.linear.x, twist.linear.y, twist.linear.z = bx, by, bz
    twist.angular.x, twist.angular.y, twist.angular.z = wx, wy, wz
    return message


def odometry_values_of_state(x: ArrayLike) -> tuple[float, ...]:
    """The 13 values of a flat state's Odometry, in the message's order (odometry_values)."""
    # Plain floats rather than numpy: the simulator builds hundreds of these per second.
    s = np.asarray(x, dtype=float).reshape(-1)[: S.ROTORS_START].tolist()
    px, py, pz, vx, vy, vz, w, qx, qy, qz, wx, wy, wz = s
    # v_B = R^T v_W, with R the rotation matrix of q (rows of R^T are the columns of R).
    return (
        px, py, pz, qx, qy, qz, w,
        (1 - 2 * (qy * qy + qz * qz)) * vx + 2 * (qx * qy + w * qz) * vy + 2 * (qx * qz - w * qy) * vz,
        2 * (qx * qy - w * qz) * vx + (1 - 2 * (qx * qx + qz * qz)) * vy + 2 * (qy * qz + w * qx) * vz,
        2 * (qx * qz + w * qy) * vx + 2 * (qy * qz - w * qx) * vy + (1 - 2 * (qx * qx + qy * qy)) * vz,
        wx, wy, wz,
    )  # fmt: skip


def state_from_odometry(message: Any) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | Refusal:
    """(p_WB_W, v_WB_W, q_WB, w_WB_B) of an Odometry (twist in body FLU), or a Refusal."""
    return state_from_odometry_values(odometry_values(message))


def odometry_values(message: Any) -> tuple[float, ...]:
    """An Odometry's pose and twist as 13 floats, in the message's order (see state_from_odometry_values)."""
    pose, twist = message.pose.pose, message.twist.twist
    position, o, linear, angular = pose.position, pose.orientation, twist.linear, twist.angular
    return (
        position.x, position.y, position.z, o.x, o.y, o.z, o.w,
        linear.x, linear.y, linear.z, angular.x, angular.y, angular.z,
    )  # fmt: skip


def state_from_odometry_values(
    values: tuple[float, ...],
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | Refusal:
    """state_from_odometry of position, orientation (x, y, z, w), body linear and angular velocity."""
    px, py, pz, qx, qy, qz, w, bx, by, bz, wx, wy, wz = values
    norm = _unit_norm(w, qx, qy, qz) if _finite(*values) else None
    if norm is None:
        return _checked_state(values)
    w, qx, qy, qz = w / norm, qx / norm, qy / norm, qz / norm
    # v_W = R v_B, R the rotation matrix of the unit quaternion (model/rotation.py quat_to_matrix).
    v_W = (
        (1 - 2 * (qy * qy + qz * qz)) * bx + 2 * (qx * qy - w * qz) * by + 2 * (qx * qz + w * qy) * bz,
        2 * (qx * qy + w * qz) * bx + (1 - 2 * (qx * qx + qz * qz)) * by + 2 * (qy * qz - w * qx) * bz,
        2 * (qx * qz - w * qy) * bx + 2 * (qy * qz + w * qx) * by + (1 - 2 * (qx * qx + qy * qy)) * bz,
    )
    return np.array((px, py, pz)), np.array(v_W), np.array((w, qx, qy, qz)), np.array((wx, wy, wz))


def _checked_state(
    values: tuple[float, ...],
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | Refusal:
    """state_from_odometry_values of any values, with the reason of a refusal."""
    p = np.array(values[0:3], dtype=float)
    q = ros_quat_to_wxyz(*values[3:7])
    v_B = np.array(values[7:10], dtype=float)
    w_B = np.array(values[10:13], dtype=float)
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


def pose_message(
    stamp: Time, frame_id: str, p_WB_W: ArrayLike, q_WB: ArrayLike, *, out: PoseStamped | None = None
) -> PoseStamped:
    """geometry_msgs/PoseStamped of a position (world ENU) and attitude (``out``: filled in place)."""
    message = PoseStamped() if out is None else out
    message.header.stamp = stamp
    message.header.frame_id = frame_id
    _set_xyz(message.pose.position, p_WB_W)
    _set_quaternion(message.pose.orientation, q_WB)
    return message


def pose_from_message(message: Any) -> tuple[FloatArray, FloatArray] | Refusal:
    """(p_WB_W, q_WB) of a PoseStamped (a measured pose, e.g. motion capture), or a Refusal."""
    position, o = message.pose.position, message.pose.orientation
    px, py, pz, w, qx, qy, qz = position.x, position.y, position.z, o.w, o.x, o.y, o.z
    norm = _unit_norm(w, qx, qy, qz) if _finite(px, py, pz, w, qx, qy, qz) else None
    if norm is None:
        return _checked_pose(message)
    return np.array((px, py, pz)), np.array((w / norm, qx / norm, qy / norm, qz / norm))


def _checked_pose(message: Any) -> tuple[FloatArray, FloatArray] | Refusal:
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
    position, o = message.pose.position, message.pose.orientation
    px, py, pz, w, qx, qy, qz = position.x, position.y, position.z, o.w, o.x, o.y, o.z
    norm = _unit_norm(w, qx, qy, qz) if _finite(px, py, pz, w, qx, qy, qz) else None
    if norm is None:
        return _checked_setpoint(message)
    w, qx, qy, qz = w / norm, qx / norm, qy / norm, qz / norm
    # The yaw of model/rotation.py quat_to_euler.
    return np.array((px, py, pz)), math.atan2(2 * (w * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))


def _checked_setpoint(message: Any) -> tuple[FloatArray, float] | Refusal:
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
    out: Imu | None = None,
) -> Imu:
    """sensor_msgs/Imu: orientation, body rates and specific force in body FLU, diagonal covariances.

    ``out``: an Imu to fill in place.
    """
    message = Imu() if out is None else out
    message.header.stamp = stamp
    message.header.frame_id = frame_id
    _set_quaternion(message.orientation, q_WB)
    _set_xyz(message.angular_velocity, w_WB_B)
    _set_xyz(message.linear_acceleration, specific_force_B)
    # The setters copy: a cached diagonal is never shared with a message.
    message.orientation_covariance = _diagonal(float(orientation_var))
    message.angular_velocity_covariance = _diagonal(float(gyro_var))
    message.linear_acceleration_covariance = _diagonal(float(accel_var))
    return message


def simulated_imu_message(
    stamp: Time, frame_id: str, reading: ImuReading, sensors: SensorConfig, *, out: Imu | None = None
) -> Imu:
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
        out=out,
    )


@cache
def odometry_covariances(sensors: SensorConfig) -> tuple[FloatArray, FloatArray]:
    """(pose, twist) covariances, 6x6 row-major, of the simulator's odometry (REP-105 order x y z, rx ry rz).

    The odometry is the true state, but what stands for it on a real vehicle is the simulated sensors: the
    motion-capture pose (its position and angle noise), a velocity differenced from two of its samples
    (sqrt 2 x position noise x its rate) and the gyro's per-sample noise. Those are the covariances given,
    so that a consumer that weighs odometry (a state estimator, RViz's covariance display) gets the
    uncertainty it would have with the real sensors; without sensor noise they are zero.
    """
    position_var = sensors.pose_position_noise_m**2
    angle_var = sensors.pose_angle_noise_rad**2
    velocity_var = 2.0 * position_var * sensors.pose_rate_hz**2
    rate_var = sensors.gyro_sample_std_rad_s**2
    pose = np.diag([position_var] * 3 + [angle_var] * 3).reshape(36)
    twist = np.diag([velocity_var] * 3 + [rate_var] * 3).reshape(36)
    pose.flags.writeable = twist.flags.writeable = False
    return pose, twist


def _diagonal(variance: float) -> FloatArray:
    diagonal = np.diag([variance] * 3).reshape(9)
    diagonal.flags.writeable = False
    return diagonal


def imu_from_message(message: Any) -> tuple[FloatArray, FloatArray] | Refusal:
    """(w_WB_B, specific_force_B) of an Imu (body FLU), or a Refusal if not finite."""
    w, f = message.angular_velocity, message.linear_acceleration
    values = (w.x, w.y, w.z, f.x, f.y, f.z)
    if _finite(*values):
        return np.array(values[:3]), np.array(values[3:])
    w_B = vector_from_msg(w)
    f_B = vector_from_msg(f)
    return Refusal("non-finite imu", f"rates {format_vector(w_B)}, specific force {format_vector(f_B)}")
