"""ethz-asl data-driven-dynamics CSV -> flight log.

The CSV (e.g. shared/data/real_logs/quadrotor_model.csv) is what that project's ULog processing
writes after resampling PX4 topics to 100 Hz (its configs/quadrotor_model.yaml lists the sources):

========================  ==========================================  ================================
columns                   PX4 source                                  frame, unit
========================  ==========================================  ================================
timestamp                 ULog timestamp                              µs
u0..u3                    actuator_outputs output[0..3]               PWM µs, PX4 quad X motor order
vx, vy, vz                vehicle_local_position vx, vy, vz           world NED, m/s
q0..q3                    vehicle_attitude q[0..3]                    (w, x, y, z), body FRD -> NED
ang_vel_x..z              vehicle_angular_velocity xyz                body FRD, rad/s
acc_b_x..z                sensor_combined accelerometer_m_s2          body FRD specific force, m/s²
ang_acc_b_x..z            vehicle_angular_acceleration xyz            body FRD, rad/s²
========================  ==========================================  ================================

The data confirm the frames (checked when this module was written, on quadrotor_model.csv):
acc_b_z ≈ -9.81 at hover, so acc_b is an FRD specific force; with q as FRD -> NED and g = +9.80665
along NED z, R·acc_b + g has mean ≈ (0, 0, 0.09) m/s² over the log and matches the time
derivative of (vx, vy, vz) with correlation 0.9996 (x, y) and 0.994 (z). The same check with
(vx, vy, vz) read as body-frame velocities fails (correlation < 0), so despite descriptions of
the file as "body velocity" they are world NED velocities, as the project's config says.

Written columns: roll, pitch, yaw (ZYX, body FLU -> world ENU), vx, vy, vz (world ENU), ax, ay, az
= R_WB·f_B + g_W (world ENU, gravity removed, g = 9.80665 m/s², PX4's CONSTANTS_ONE_G), p, q, r
and p_dot, q_dot, r_dot (body FLU), imu_fx..imu_fz (FLU specific force), ``landed``; u_k from u0..u3
(PX4 quad X order, see :mod:`multirotor_ros.io.rotor_channels`) and omega_k through the motor map.
Dropped: the unnamed index, old_index and aux1..aux6 (RC switch channels).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from multirotor_ros.frames import frd_to_flu, ned_to_enu, quat_ned_frd_to_enu_flu
from multirotor_ros.io.flight_log import FlightLog
from multirotor_ros.io.log_builder import ConversionError, LogBuilder, read_numeric_csv
from multirotor_ros.io.rotor_channels import RotorChannelError, resolve_rotor_channels
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import quat_to_matrix

STANDARD_GRAVITY_M_S2 = 9.80665
REQUIRED = ["timestamp", "vx", "vy", "vz", "q0", "q1", "q2", "q3", "acc_b_x", "acc_b_y", "acc_b_z"]


def looks_like_ddd_csv(header: list[str]) -> bool:
    """The header has the columns this converter needs and actuator columns u0, u1, ..."""
    return all(name in header for name in REQUIRED) and "u0" in header


def _read_table(path: Path) -> tuple[list[str], np.ndarray]:
    header, values = read_numeric_csv(path)
    missing = [name for name in REQUIRED if name not in header]
    if missing:
        raise ConversionError(
            f"{path}:1: not a data-driven-dynamics CSV: missing column(s) {', '.join(missing)}"
        )
    return header, values


def convert_ddd_csv(
    path: str | Path, airframe: Airframe, rotor_channels: str | None = None
) -> tuple[FlightLog, list[str]]:
    """Convert a data-driven-dynamics CSV; returns the log and warnings for the user."""
    path = Path(path)
    header, values = _read_table(path)

    def columns(*names: str) -> np.ndarray:
        return np.column_stack([values[:, header.index(name)] for name in names])

    t = columns("timestamp")[:, 0] * 1e-6
    if np.any(np.diff(t) <= 0):
        bad = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise ConversionError(f"{path}:{bad + 2}: column 'timestamp': not after the previous row")
    warnings: list[str] = []
    builder = LogBuilder(t, "the CSV's timestamp column")

    q_WB = quat_ned_frd_to_enu_flu(columns("q0", "q1", "q2", "q3"))
    builder.put_attitude(t, q_WB, "q0..q3")
    builder.put(["vx", "vy", "vz"], ned_to_enu(columns("vx", "vy", "vz")))
    f_B = frd_to_flu(columns("acc_b_x", "acc_b_y", "acc_b_z"))
    a_W = np.einsum("nij,nj->ni", quat_to_matrix(q_WB), f_B) + np.array([0.0, 0.0, -STANDARD_GRAVITY_M_S2])
    builder.put(["ax", "ay", "az"], a_W)
    builder.put(["imu_fx", "imu_fy", "imu_fz"], f_B)
    derived = [
        "vx,vy,vz: world NED velocity -> ENU",
        f"ax,ay,az: R_WB * acc_b (FLU specific force) + (0, 0, -{STANDARD_GRAVITY_M_S2}) m/s^2",
    ]
    if all(f"ang_vel_{axis}" in header for axis in "xyz"):
        builder.put(["p", "q", "r"], frd_to_flu(columns("ang_vel_x", "ang_vel_y", "ang_vel_z")))
    if all(f"ang_acc_b_{axis}" in header for axis in "xyz"):
        builder.put(
            ["p_dot", "q_dot", "r_dot"], frd_to_flu(columns("ang_acc_b_x", "ang_acc_b_y", "ang_acc_b_z"))
        )
        derived.append("p_dot,q_dot,r_dot: ang_acc_b (FRD) -> FLU [rad/s^2]")
    if "landed" in header:
        builder.put(["landed"], columns("landed"))

    actuator_names: list[str] = []
    while f"u{len(actuator_names)}" in header:
        actuator_names.append(f"u{len(actuator_names)}")
    try:
        channels, channel_note = resolve_rotor_channels(
            airframe, rotor_channels, None, len(actuator_names), channel_names=actuator_names
        )
    except RotorChannelError as error:
        raise ConversionError(f"{path}: {error}") from None
    warning = builder.put_actuators(
        t,
        columns(*actuator_names),
        channels,
        channel_note,
        "pwm_us",
        airframe,
        "u0..u" + str(len(actuator_names) - 1),
    )
    if warning:
        warnings.append(warning)
    first = {
        "source": "ddd_csv",
        "converted_from": f"{path.name} (ethz-asl data-driven-dynamics CSV, resampled PX4 ULog topics)",
        "airframe": airframe.name,
        "frames": "converted from NED/FRD: world ENU, body FLU; roll,pitch,yaw ZYX of body FLU -> world ENU",
        "derived": "; ".join(derived),
    }
    return builder.build(first), warnings
