"""What RViz shows of a vehicle: tf transforms and visualization_msgs markers, built from plain values.

tf (REP-105)
    ``transform_from_odometry(odometry, out=None) -> TransformStamped``: odom -> base_link of an
    Odometry (its frame ids, stamp and pose).
    ``rotor_transforms(positions_B, base_frame, stamp) -> [TransformStamped]``: base_link -> rotor_k,
    static, named after the base frame's prefix (``uav1/base_link`` -> ``uav1/rotor_1``).

Markers (one MarkerArray per update, namespaces ``body``, ``rotor``, ``effectiveness``, ``setpoint``,
``path``; ids stable so that RViz replaces rather than accumulates them)
    ``vehicle_markers(view, stamp) -> MarkerArray`` of a :class:`VehicleView`: the arms and rotor discs
    in the body frame (``frame_locked``: they move with tf), each disc coloured by its commanded speed
    (blue at the airframe's slowest, red at its fastest), a ring round it coloured by the identifier's
    estimate of its effectiveness (green 1, red 0; grey while nothing is known) with a label when it is
    below ``WEAK_ROTOR_LABEL_BELOW``, the setpoint (a sphere and an arrow along its yaw) and the path
    flown, in the world frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point, Quaternion, TransformStamped, Vector3
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from multirotor_ros.model.rotation import FloatArray

BASE_FRAME = "base_link"
# Below this estimated effectiveness a rotor's ring gets a text label (share and rotor number).
WEAK_ROTOR_LABEL_BELOW = 0.9
# Drawing sizes as shares of the rotor radius (arms, disc thickness, ring) or in metres (setpoint).
ARM_WIDTH_SHARE = 0.15
DISC_THICKNESS_SHARE = 0.05
RING_RADIUS_SHARE = 1.15
SETPOINT_DIAMETER_M = 0.15
PATH_WIDTH_M = 0.02
GREY = ColorRGBA(r=0.6, g=0.6, b=0.6, a=0.8)


def transform_from_odometry(odometry: object, out: TransformStamped | None = None) -> TransformStamped:
    """Odom -> base_link of ``odometry`` (nav_msgs/Odometry): the same frames, stamp and pose."""
    message = TransformStamped() if out is None else out
    message.header = odometry.header  # type: ignore[attr-defined]
    message.child_frame_id = odometry.child_frame_id  # type: ignore[attr-defined]
    pose = odometry.pose.pose  # type: ignore[attr-defined]
    translation = message.transform.translation
    translation.x, translation.y, translation.z = pose.position.x, pose.position.y, pose.position.z
    message.transform.rotation = pose.orientation
    return message


def frame_prefix_of(base_frame: str) -> str:
    """``uav1/`` of ``uav1/base_link``: the prefix the vehicle's other frames share."""
    return base_frame[: -len(BASE_FRAME)] if base_frame.endswith(BASE_FRAME) else f"{base_frame}/"


def rotor_frame(base_frame: str, number: int) -> str:
    """The frame of rotor ``number`` (1-based) of the vehicle whose body frame is ``base_frame``."""
    return f"{frame_prefix_of(base_frame)}rotor_{number}"


def rotor_transforms(positions_B: FloatArray, base_frame: str, stamp: Time) -> list[TransformStamped]:
    """base_link -> rotor_k for rotors at ``positions_B`` (N, 3) [m], body FLU: fixed, for /tf_static."""
    transforms = []
    for number, (x, y, z) in enumerate(np.asarray(positions_B, dtype=float).tolist(), start=1):
        message = TransformStamped()
        message.header.stamp = stamp
        message.header.frame_id = base_frame
        message.child_frame_id = rotor_frame(base_frame, number)
        message.transform.translation = Vector3(x=x, y=y, z=z)
        message.transform.rotation = Quaternion(w=1.0)
        transforms.append(message)
    return transforms


@dataclass
class VehicleView:
    """What the markers of one vehicle show; ``None`` where nothing has been received yet."""

    world_frame: str
    base_frame: str
    rotor_positions_m: FloatArray  # (N, 3), body FLU
    rotor_radius_m: float
    speed_range_rad_s: tuple[float, float]
    commanded_speeds_rad_s: FloatArray | None = None
    effectiveness: FloatArray | None = None
    setpoint: tuple[FloatArray, float] | None = None  # (position, yaw) in the world frame
    path_m: Sequence[tuple[float, float, float]] = ()


def speed_colour(speed_rad_s: float, speed_range_rad_s: tuple[float, float]) -> ColorRGBA:
    """Blue at the slowest speed, red at the fastest, through purple."""
    low, high = speed_range_rad_s
    share = float(np.clip((speed_rad_s - low) / max(high - low, 1e-9), 0.0, 1.0))
    return ColorRGBA(r=share, g=0.1, b=1.0 - share, a=0.9)


def effectiveness_colour(effectiveness: float) -> ColorRGBA:
    """Green when healthy (1), yellow at half, red when the rotor gives nothing (0)."""
    share = float(np.clip(effectiveness, 0.0, 1.0))
    return ColorRGBA(r=min(1.0, 2.0 * (1.0 - share)), g=min(1.0, 2.0 * share), b=0.0, a=0.9)


def _marker(namespace: str, marker_id: int, kind: int, frame: str, stamp: Time) -> Marker:
    marker = Marker()
    marker.header.frame_id = frame
    marker.header.stamp = stamp
    marker.ns = namespace
    marker.id = marker_id
    marker.type = kind
    marker.action = Marker.ADD
    marker.pose.orientation.w = 1.0
    marker.lifetime = Duration()  # until replaced
    return marker


def _point(xyz: Sequence[float] | FloatArray) -> Point:
    return Point(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))


def vehicle_markers(view: VehicleView, stamp: Time) -> MarkerArray:
    """The markers of one vehicle (module docstring)."""
    radius = view.rotor_radius_m
    body_stamp = Time()  # frame_locked body markers: the newest transform, whatever its stamp
    markers = []

    arms = _marker("body", 0, Marker.LINE_LIST, view.base_frame, body_stamp)
    arms.frame_locked = True
    arms.scale.x = ARM_WIDTH_SHARE * radius
    arms.color = ColorRGBA(r=0.2, g=0.2, b=0.2, a=1.0)
    for position in view.rotor_positions_m:
        arms.points += [Point(), _point(position)]
    markers.append(arms)

    for index, position in enumerate(view.rotor_positions_m):
        number = index + 1
        disc = _marker("rotor", number, Marker.CYLINDER, view.base_frame, body_stamp)
        disc.frame_locked = True
        disc.pose.position = _point(position)
        disc.scale = Vector3(x=2 * radius, y=2 * radius, z=DISC_THICKNESS_SHARE * radius)
        disc.color = (
            GREY
            if view.commanded_speeds_rad_s is None
            else speed_colour(float(view.commanded_speeds_rad_s[index]), view.speed_range_rad_s)
        )
        markers.append(disc)

        ring = _marker("effectiveness", number, Marker.CYLINDER, view.base_frame, body_stamp)
        ring.frame_locked = True
        # Just below the disc and wider: a rim of the effectiveness colour round the speed colour.
        ring.pose.position = _point(position - np.array([0.0, 0.0, DISC_THICKNESS_SHARE * radius]))
        ring.scale = Vector3(
            x=2 * RING_RADIUS_SHARE * radius,
            y=2 * RING_RADIUS_SHARE * radius,
            z=0.5 * DISC_THICKNESS_SHARE * radius,
        )
        effectiveness = None if view.effectiveness is None else float(view.effectiveness[index])
        ring.color = GREY if effectiveness is None else effectiveness_colour(effectiveness)
        markers.append(ring)

        label = _marker("effectiveness", 100 + number, Marker.TEXT_VIEW_FACING, view.base_frame, body_stamp)
        label.frame_locked = True
        label.pose.position = _point(position + np.array([0.0, 0.0, 2.0 * radius]))
        label.scale.z = radius
        label.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
        if effectiveness is not None and effectiveness < WEAK_ROTOR_LABEL_BELOW:
            label.text = f"rotor {number}: {effectiveness:.0%}"
        else:
            label.action = Marker.DELETE
        markers.append(label)

    if view.setpoint is not None:
        position, yaw = view.setpoint
        target = _marker("setpoint", 0, Marker.SPHERE, view.world_frame, stamp)
        target.pose.position = _point(position)
        target.scale = Vector3(x=SETPOINT_DIAMETER_M, y=SETPOINT_DIAMETER_M, z=SETPOINT_DIAMETER_M)
        target.color = ColorRGBA(r=0.1, g=0.8, b=0.2, a=0.6)
        heading = _marker("setpoint", 1, Marker.ARROW, view.world_frame, stamp)
        heading.pose.position = _point(position)
        heading.pose.orientation = Quaternion(z=math.sin(yaw / 2), w=math.cos(yaw / 2))
        heading.scale = Vector3(
            x=3 * SETPOINT_DIAMETER_M, y=0.2 * SETPOINT_DIAMETER_M, z=0.2 * SETPOINT_DIAMETER_M
        )
        heading.color = target.color
        markers += [target, heading]

    if len(view.path_m) >= 2:
        path = _marker("path", 0, Marker.LINE_STRIP, view.world_frame, stamp)
        path.scale.x = PATH_WIDTH_M
        path.color = ColorRGBA(r=1.0, g=0.6, b=0.0, a=0.8)
        path.points = [_point(p) for p in view.path_m]
        markers.append(path)
    return MarkerArray(markers=markers)
