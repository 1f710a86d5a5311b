"""Helpers every node of the package shares: entry point, message conversion, refusal bookkeeping.

Entry point
    ``run_node(node_factory, args) -> int``: initialises rclpy in a context of its own (shut down in a
    ``finally``), builds the node with ``node_factory(context=context)``, spins it with a single-threaded
    executor and returns 0 when the spin ends by Ctrl-C (KeyboardInterrupt) or by an external
    shutdown (ExternalShutdownException, e.g. SIGINT handled by rclpy). A node class whose
    ``__init__`` forwards ``**kwargs`` to ``rclpy.node.Node`` is a valid factory. A bad parameter or
    airframe while the node is built (ValueError, ParameterException): one line on stderr, status 2.

Rotor speeds (sensor_msgs/JointState, shared/spec/interfaces.md)
    ``rotor_names(n) -> ["rotor_1", ..., "rotor_n"]``.
    ``rotor_speeds_from_joint_state(msg, n_rotors, limit_rad_s) -> RotorSpeeds | Refusal``: names
    ``rotor_1..rotor_N`` in any order, exactly once each, ``velocity`` of the same length, every speed
    finite, >= 0 and <= ``limit_rad_s``. Returns the speeds in rotor order 1..N with the stamp, or a
    :class:`Refusal` (``reason``: a short category used for counting; ``detail``: what exactly was wrong).
    ``joint_state_from_rotor_speeds(speeds, stamp) -> JointState`` with names rotor_1..rotor_N.

State messages (pose in world ENU; twist of Odometry in body FLU as REP-105 says)
    ``odometry_message(x, stamp, frame_id="odom", child_frame_id="base_link") -> Odometry`` from the
    flat model state (multirotor_ros.model.state layout).
    ``imu_message(stamp, frame_id, q_WB, specific_force_B, w_WB_B, *, accel_var, gyro_var,
    orientation_var) -> Imu``; ``pose_message(stamp, frame_id, p_WB_W, q_WB) -> PoseStamped``.
    ``setpoint_from_pose(msg) -> (p_W, yaw) | Refusal``: a ``setpoint`` PoseStamped read as position
    and yaw, refused when not finite or the quaternion is not a rotation.

Quaternions and stamps
    ``quaternion_to_msg(q_wxyz)``, ``quaternion_from_msg(msg) -> (w, x, y, z)`` (frames.py holds the
    field order rule); ``stamp_to_ns(stamp)``, ``stamp_from_ns(ns)``, ``stamp_to_s(stamp)``.

Refusals
    :class:`RefusalCounter`: ``refuse(reason, detail)`` counts the refusal under ``reason``, logs the
    first refusal of each reason as a warning with its detail, and afterwards at most one summary
    (counts per reason) every ``summary_period_s`` of wall time. ``counts`` (dict), ``total``.

Parameters
    :class:`ParameterSpec` rows and ``declare_parameters(node, specs)``: every parameter declared with
    a descriptor (type, range, unit in the description, read-only when it cannot change at run time);
    ``check_parameters(specs, parameters) -> SetParametersResult`` for the on-set callback: refuses a
    wrong type, a non-finite number, a value outside the range or a read-only change, with a reason.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.frames import ros_quat_to_wxyz, wxyz_to_ros_quat
from multirotor_ros.model import state as S
from multirotor_ros.model.rotation import FloatArray, quat_to_euler, quat_to_matrix

# ------------------------------------------------------------------------------------------------
# Entry point


def run_node(node_factory: Callable[..., Any], args: Sequence[str] | None = None) -> int:
    """Initialise rclpy, spin the node made by ``node_factory(context=...)``, return the exit status.

    A ValueError or rclpy ParameterException raised while the node is built (a bad parameter value or
    airframe) is printed as one line and gives exit status 2: the node cannot run, and a traceback
    would hide the reason.
    """
    import sys

    import rclpy
    from rclpy.exceptions import ParameterException
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    context = rclpy.Context()
    # A context of our own so that several nodes (or a test's probe) can share a process; rclpy installs
    # its SIGINT/SIGTERM handlers only for the default context unless asked, and Ctrl-C must end the spin.
    # (Context's own ``with`` initialises it without arguments, so the ROS arguments need init() here.)
    rclpy.init(
        args=None if args is None else list(args),
        context=context,
        signal_handler_options=SignalHandlerOptions.ALL,
    )
    node = None
    try:
        try:
            node = node_factory(context=context)
        except (ValueError, ParameterException) as error:
            print(f"{Path(sys.argv[0] if args is None else args[0]).name}: {error}", file=sys.stderr)
            return 2
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # A signal can shut the context down while a callback is publishing; that is a normal end too.
        if context.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        context.try_shutdown()
    return 0


# ------------------------------------------------------------------------------------------------
# Rotor speeds as JointState


@dataclass(frozen=True)
class Refusal:
    """Why a message was refused: ``reason`` is the counting category, ``detail`` the specifics."""

    reason: str
    detail: str


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
        return Refusal("non-finite speed", f"rotor_{k + 1} = {speeds[k]}")
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


def joint_state_from_rotor_speeds(speeds_rad_s: ArrayLike, stamp: Any) -> Any:
    """A JointState with ``rotor_1..rotor_N`` and the speeds [rad/s] as ``velocity``."""
    from sensor_msgs.msg import JointState

    speeds = np.asarray(speeds_rad_s, dtype=float)
    message = JointState()
    message.header.stamp = stamp
    message.name = rotor_names(speeds.size)
    message.velocity = speeds.tolist()
    return message


# ------------------------------------------------------------------------------------------------
# Quaternions and stamps


def quaternion_to_msg(q_wxyz: ArrayLike) -> Any:
    """Our (w, x, y, z) as a geometry_msgs/Quaternion."""
    from geometry_msgs.msg import Quaternion

    x, y, z, w = wxyz_to_ros_quat(q_wxyz)
    return Quaternion(x=x, y=y, z=z, w=w)


def quaternion_from_msg(message: Any) -> FloatArray:
    """A geometry_msgs/Quaternion as our (w, x, y, z)."""
    return ros_quat_to_wxyz(message.x, message.y, message.z, message.w)


def stamp_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def stamp_to_s(stamp: Any) -> float:
    """builtin_interfaces/Time -> seconds (float)."""
    return stamp_to_ns(stamp) * 1e-9


def stamp_from_ns(nanoseconds: int) -> Any:
    """Integer nanoseconds (>= 0) -> builtin_interfaces/Time."""
    from builtin_interfaces.msg import Time

    sec, nanosec = divmod(int(nanoseconds), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


# ------------------------------------------------------------------------------------------------
# State messages


def _point(values: ArrayLike) -> Any:
    from geometry_msgs.msg import Point

    x, y, z = (float(v) for v in np.asarray(values, dtype=float))
    return Point(x=x, y=y, z=z)


def _vector(values: ArrayLike) -> Any:
    from geometry_msgs.msg import Vector3

    x, y, z = (float(v) for v in np.asarray(values, dtype=float))
    return Vector3(x=x, y=y, z=z)


def odometry_message(
    x: ArrayLike, stamp: Any, frame_id: str = "odom", child_frame_id: str = "base_link"
) -> Any:
    """nav_msgs/Odometry of one flat state: pose in world ENU, twist in body FLU (REP-105)."""
    from geometry_msgs.msg import Point, Quaternion, Vector3
    from nav_msgs.msg import Odometry

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
    """(p_WB_W, v_WB_W, q_WB, w_WB_B) of an Odometry (twist in body FLU), or a Refusal if not finite."""
    pose = message.pose.pose
    twist = message.twist.twist
    p = np.array([pose.position.x, pose.position.y, pose.position.z])
    q = quaternion_from_msg(pose.orientation)
    v_B = np.array([twist.linear.x, twist.linear.y, twist.linear.z])
    w_B = np.array([twist.angular.x, twist.angular.y, twist.angular.z])
    if not all(np.all(np.isfinite(a)) for a in (p, q, v_B, w_B)):
        return Refusal("non-finite odometry", f"position {p}, orientation {q}, twist {v_B} {w_B}")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-3:
        return Refusal("invalid orientation", f"quaternion norm {norm:.6g}, expected 1")
    q = q / norm
    return p, quat_to_matrix(q) @ v_B, q, w_B


def imu_message(
    stamp: Any,
    frame_id: str,
    q_WB: ArrayLike,
    specific_force_B: ArrayLike,
    w_WB_B: ArrayLike,
    *,
    accel_var: float,
    gyro_var: float,
    orientation_var: float,
) -> Any:
    """sensor_msgs/Imu: orientation, body rates and specific force in body FLU, diagonal covariances."""
    from sensor_msgs.msg import Imu

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


def _diagonal(variance: float) -> list[float]:
    return [float(variance), 0.0, 0.0, 0.0, float(variance), 0.0, 0.0, 0.0, float(variance)]


def pose_message(stamp: Any, frame_id: str, p_WB_W: ArrayLike, q_WB: ArrayLike) -> Any:
    """geometry_msgs/PoseStamped of a position (world ENU) and attitude."""
    from geometry_msgs.msg import PoseStamped

    message = PoseStamped()
    message.header.stamp = stamp
    message.header.frame_id = frame_id
    message.pose.position = _point(p_WB_W)
    message.pose.orientation = quaternion_to_msg(q_WB)
    return message


def setpoint_from_pose(message: Any) -> tuple[FloatArray, float] | Refusal:
    """Desired position (world ENU) and yaw of a ``setpoint`` PoseStamped.

    An all-zero quaternion (a PoseStamped left at its defaults) means yaw 0.
    """
    p = np.array([message.pose.position.x, message.pose.position.y, message.pose.position.z])
    q = quaternion_from_msg(message.pose.orientation)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        return Refusal("non-finite setpoint", f"position {p}, orientation {q}")
    norm = float(np.linalg.norm(q))
    if norm == 0.0:
        return p, 0.0
    if abs(norm - 1.0) > 1e-3:
        return Refusal("invalid orientation", f"setpoint quaternion norm {norm:.6g}, expected 1")
    return p, float(quat_to_euler(q / norm)[2])


# ------------------------------------------------------------------------------------------------
# Refusals


class RefusalCounter:
    """Counts refused messages per reason; logs the first of each reason, then throttled summaries."""

    def __init__(
        self,
        logger: Any,
        what: str,
        summary_period_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ):
        self._logger = logger
        self._what = what
        self._summary_period_s = summary_period_s
        self._clock = clock
        self.counts: dict[str, int] = {}
        self._counts_at_summary: dict[str, int] = {}
        self._last_summary = clock()

    @property
    def total(self) -> int:
        """Refusals counted so far, all reasons together."""
        return sum(self.counts.values())

    def refuse(self, reason: str, detail: str) -> None:
        """Count one refusal; log it if it is the first of its reason, else maybe a summary."""
        first = reason not in self.counts
        self.counts[reason] = self.counts.get(reason, 0) + 1
        now = self._clock()
        if first:
            self._logger.warning(
                f"refused {self._what}: {reason}: {detail} (further refusals of this kind are counted "
                f"and summarised every {self._summary_period_s:g} s)"
            )
            self._counts_at_summary[reason] = 1
        elif now - self._last_summary >= self._summary_period_s:
            self._log_summary(now)

    def _log_summary(self, now: float) -> None:
        new = {r: c - self._counts_at_summary.get(r, 0) for r, c in self.counts.items()}
        new = {r: c for r, c in new.items() if c > 0}
        if new:
            parts = ", ".join(f"{reason}: {count}" for reason, count in sorted(new.items()))
            self._logger.warning(
                f"refused {sum(new.values())} more {self._what} in the last "
                f"{now - self._last_summary:.0f} s ({parts}); total {self.total}"
            )
        self._counts_at_summary = dict(self.counts)
        self._last_summary = now


# ------------------------------------------------------------------------------------------------
# Parameters


@dataclass(frozen=True)
class ParameterSpec:
    """One declared parameter: default (its type is the parameter's type), range, unit, meaning."""

    name: str
    default: float | int | bool | str
    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    read_only: bool = False
    low_exclusive: bool = False

    def full_description(self) -> str:
        """The description with unit and range, as ``ros2 param describe`` shows it."""
        text = self.description
        if self.unit:
            text += f" [{self.unit}]"
        return text

    def check(self, value: Any) -> str | None:
        """None if ``value`` is acceptable, else the reason."""
        expected = type(self.default)
        if expected is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if type(value) is not expected:
            return f"{self.name} must be a {expected.__name__}, got {type(value).__name__} {value!r}"
        if isinstance(value, float) and not math.isfinite(value):
            return f"{self.name} must be finite, got {value}"
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if self.low is not None and (value < self.low or (self.low_exclusive and value == self.low)):
                relation = ">" if self.low_exclusive else ">="
                return (
                    f"{self.name} must be {relation} {self.low:g} {self.unit}".rstrip() + f", got {value:g}"
                )
            if self.high is not None and value > self.high:
                return f"{self.name} must be <= {self.high:g} {self.unit}".rstrip() + f", got {value:g}"
        return None

    def descriptor(self) -> Any:
        """The rcl_interfaces ParameterDescriptor of this parameter."""
        return _descriptor(self)


def _descriptor(spec: ParameterSpec) -> Any:
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType

    types = {
        bool: ParameterType.PARAMETER_BOOL,
        int: ParameterType.PARAMETER_INTEGER,
        float: ParameterType.PARAMETER_DOUBLE,
        str: ParameterType.PARAMETER_STRING,
    }
    descriptor = ParameterDescriptor(
        name=spec.name,
        type=types[type(spec.default)],
        description=spec.full_description(),
        read_only=spec.read_only,
    )
    if isinstance(spec.default, float) and spec.low is not None and spec.high is not None:
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high))
        ]
    elif (
        isinstance(spec.default, int)
        and not isinstance(spec.default, bool)
        and spec.low is not None
        and spec.high is not None
    ):
        descriptor.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)]
    return descriptor


def declare_parameters(
    node: Any, specs: Iterable[ParameterSpec], defaults: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """Declare every spec on ``node`` (``defaults`` overrides a spec's default); return name -> value.

    A value given at start-up (``-p name:=value``) that fails the spec's check raises ValueError with
    the reason, so a node started with a bad parameter stops at once with a clear message.
    """
    values = {}
    for spec in specs:
        default = (defaults or {}).get(spec.name, spec.default)
        value = node.declare_parameter(spec.name, default, spec.descriptor()).value
        reason = spec.check(value)
        if reason is not None:
            raise ValueError(f"parameter {reason}")
        values[spec.name] = float(value) if isinstance(spec.default, float) else value
    return values


def check_parameters(specs: Mapping[str, ParameterSpec], parameters: Iterable[Any]) -> Any:
    """On-set callback body: a SetParametersResult refusing the first invalid value with its reason."""
    from rcl_interfaces.msg import SetParametersResult

    for parameter in parameters:
        spec = specs.get(parameter.name)
        if spec is None:
            continue  # use_sim_time and other standard parameters: rclpy checks those itself.
        if spec.read_only:
            return SetParametersResult(
                successful=False, reason=f"{spec.name} is read-only: set it at start-up"
            )
        reason = spec.check(parameter.value)
        if reason is not None:
            return SetParametersResult(successful=False, reason=reason)
    return SetParametersResult(successful=True)
