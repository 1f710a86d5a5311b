"""PX4 ULog -> flight log, read with pyulog.

What is taken, and how frames change (NED/FRD -> ENU/FLU through :mod:`multirotor_ros.frames`):

- ``vehicle_local_position`` is the time base. x, y, z, vx, vy, vz, ax, ay, az are NED in the
  EKF's local frame; ax..az are kinematic (gravity removed), so they are our acceleration group.
  Cells whose PX4 validity flag is 0 (``xy_valid``, ``z_valid``, ``v_xy_valid``, ``v_z_valid``)
  are left empty: an EKF without GPS reports x = y = 0 with xy_valid = 0.
- ``vehicle_attitude.q`` is the Hamilton quaternion (w, x, y, z) of body FRD -> world NED; it is
  turned into body FLU -> world ENU and then ZYX Euler angles.
- ``sensor_combined``: gyro_rad (FRD) -> p, q, r (FLU); accelerometer_m_s2 (FRD specific force)
  -> extra columns imu_fx, imu_fy, imu_fz (FLU).
- ``actuator_outputs`` (instance 0 = PX4's MAIN outputs unless chosen otherwise): PWM [µs] as
  u_k, channels chosen by :mod:`multirotor_ros.io.rotor_channels` (``VT_MOT_ID`` tells where a
  VTOL's lift motors are), omega_k through the airframe's motor map.
- ``vehicle_land_detected.landed`` (published when it changes) -> ``landed`` (1 on the ground, 0 in
  the air), held until the next message: identification and discrepancy take ground contact from it.

A file that ends inside a message was cut short (a power loss, a partial download): it is converted up
to where it ends with a warning, and a topic it lacks is reported as lost to the truncation.

A ULog usually starts and ends on the ground (the sample log in shared/data/real_logs is mostly
idle on the ground); the converter keeps the whole log, and tools pick the flight with t ranges.
"""

from __future__ import annotations

import contextlib
import io
import math
import mmap
import struct
from pathlib import Path
from typing import Any

import numpy as np

from multirotor_ros.frames import frd_to_flu, ned_to_enu, quat_ned_frd_to_enu_flu
from multirotor_ros.io.flight_log import FlightLog
from multirotor_ros.io.log_builder import ConversionError, LogBuilder
from multirotor_ros.io.resample import sort_unique
from multirotor_ros.io.rotor_channels import RotorChannelError, resolve_rotor_channels
from multirotor_ros.model.airframe import Airframe

TOPICS = [
    "vehicle_local_position",
    "vehicle_attitude",
    "sensor_combined",
    "actuator_outputs",
    "vehicle_land_detected",
]
# The file header (magic, version, timestamp), then messages of a 3-byte header (size, type) and a body.
ULOG_FILE_HEADER = struct.Struct("<7sBQ")
ULOG_MAGIC = b"ULog\x01\x125"
ULOG_MESSAGE_HEADER = struct.Struct("<HB")


def truncation_of(path: Path) -> str | None:
    """How the file was cut short, or None if it ends on a message boundary.

    ULog has no end marker: a file cut at a message boundary cannot be told from a whole one, and
    pyulog stops quietly at a partial message; walking the message headers finds a cut anywhere else.
    """
    size = path.stat().st_size
    if size < ULOG_FILE_HEADER.size:
        return f"truncated: {size} bytes, shorter than a ULog's {ULOG_FILE_HEADER.size}-byte header"
    with path.open("rb") as file, mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as data:
        if data[: len(ULOG_MAGIC)] != ULOG_MAGIC:
            return None  # not a ULog: pyulog says so
        offset, header = ULOG_FILE_HEADER.size, ULOG_MESSAGE_HEADER
        while offset + header.size <= size:
            end = offset + header.size + header.unpack_from(data, offset)[0]
            if end > size:
                break
            offset = end
    if offset == size:
        return None
    return (
        f"truncated: the file ends at byte {size} inside a message that starts at byte {offset} "
        "(cut short by a power loss or a partial download)"
    )


def _stamps(data: dict[str, Any]) -> np.ndarray:
    return np.asarray(data["timestamp"], dtype=float) * 1e-6


def _fields(data: dict[str, Any], names: list[str]) -> np.ndarray:
    return np.column_stack([np.asarray(data[name], dtype=float) for name in names])


def _stream(
    ulog: Any, topic: str, instance: int, path: Path, required: bool, truncation: str | None
) -> dict[str, Any] | None:
    try:
        dataset = ulog.get_dataset(topic, instance)
    except (KeyError, IndexError, ValueError):
        if required:
            present = ", ".join(sorted({d.name for d in ulog.data_list})) or "none"
            if truncation:
                raise ConversionError(
                    f"{path}: {truncation}, before any {topic} (instance {instance}) message; topics it "
                    f"holds: {present}"
                ) from None
            raise ConversionError(
                f"{path}: no {topic} (instance {instance}) in this ULog; topics present: {present}"
            ) from None
        return None
    return dataset.data


def convert_ulog(
    path: str | Path, airframe: Airframe, rotor_channels: str | None = None, actuator_instance: int = 0
) -> tuple[FlightLog, list[str]]:
    """Convert a PX4 ULog; returns the log and warnings for the user."""
    path = Path(path)
    try:
        truncation = truncation_of(path)
    except OSError as error:
        raise ConversionError(f"{path}: cannot read: {error.strerror or error}") from None
    try:
        ulog = _read_ulog(path)
    except Exception as error:  # pyulog raises bare Exceptions on corrupt files
        raise ConversionError(f"{path}: {truncation or 'not a readable ULog'}: {error}") from None
    warnings: list[str] = []

    position = _stream(ulog, "vehicle_local_position", 0, path, True, truncation)
    assert position is not None
    stamps = _stamps(position)
    t_base, kept_rows, dropped = sort_unique(stamps, np.arange(stamps.size, dtype=float))
    rows = kept_rows.astype(int)
    if dropped:
        warnings.append(f"{dropped} repeated vehicle_local_position stamps dropped")
    builder = LogBuilder(t_base, "vehicle_local_position stamps")

    def ned_group(names: list[str], valid_xy: str, valid_z: str) -> np.ndarray:
        values = ned_to_enu(_fields(position, names)[rows])
        # Validity is masked after the axis change: a NaN inside the conversion would spread to all axes.
        values[np.asarray(position[valid_xy])[rows] == 0, :2] = np.nan
        values[np.asarray(position[valid_z])[rows] == 0, 2] = np.nan
        return values

    builder.put(["x", "y", "z"], ned_group(["x", "y", "z"], "xy_valid", "z_valid"))
    builder.put(["vx", "vy", "vz"], ned_group(["vx", "vy", "vz"], "v_xy_valid", "v_z_valid"))
    builder.put(["ax", "ay", "az"], ned_to_enu(_fields(position, ["ax", "ay", "az"])[rows]))
    for name, flag in (("x,y", "xy_valid"), ("z", "z_valid"), ("vx,vy", "v_xy_valid"), ("vz", "v_z_valid")):
        invalid = int(np.count_nonzero(np.asarray(position[flag])[rows] == 0))
        if invalid:
            builder.metadata[f"empty_{name.replace(',', '_')}"] = (
                f"{invalid} of {rows.size} rows: PX4 {flag} = 0"
            )

    attitude = _stream(ulog, "vehicle_attitude", 0, path, True, truncation)
    assert attitude is not None
    ts, q, _ = sort_unique(_stamps(attitude), _fields(attitude, [f"q[{i}]" for i in range(4)]))
    builder.put_attitude(ts, quat_ned_frd_to_enu_flu(q), "vehicle_attitude.q")

    imu = _stream(ulog, "sensor_combined", 0, path, False, truncation)
    if imu is not None:
        ts, gyro, _ = sort_unique(
            _stamps(imu), frd_to_flu(_fields(imu, [f"gyro_rad[{i}]" for i in range(3)]))
        )
        builder.put_stream(["p", "q", "r"], ts, gyro, "linear", "sensor_combined.gyro_rad")
        ts, accel, _ = sort_unique(
            _stamps(imu), frd_to_flu(_fields(imu, [f"accelerometer_m_s2[{i}]" for i in range(3)]))
        )
        builder.put_stream(
            ["imu_fx", "imu_fy", "imu_fz"], ts, accel, "linear", "sensor_combined.accelerometer_m_s2"
        )
        builder.metadata["imu_columns"] = (
            "imu_fx, imu_fy, imu_fz: accelerometer specific force, body FLU [m/s^2]"
        )
    else:
        warnings.append("no sensor_combined: p, q, r not written")

    outputs = _stream(ulog, "actuator_outputs", actuator_instance, path, True, truncation)
    assert outputs is not None
    n_channels = int(np.max(outputs["noutputs"]))
    parameters = dict(ulog.initial_parameters)
    try:
        channels, channel_note = resolve_rotor_channels(airframe, rotor_channels, parameters, n_channels)
    except RotorChannelError as error:
        raise ConversionError(f"{path}: {error}") from None
    ts, pwm, _ = sort_unique(_stamps(outputs), _fields(outputs, [f"output[{i}]" for i in range(n_channels)]))
    warning = builder.put_actuators(
        ts,
        pwm,
        channels,
        f"{channel_note}; actuator_outputs instance {actuator_instance}",
        "pwm_us",
        airframe,
        f"actuator_outputs[{actuator_instance}]",
    )
    if warning:
        warnings.append(warning)

    land = _stream(ulog, "vehicle_land_detected", 0, path, False, truncation)
    if land is not None:
        ts, landed, _ = sort_unique(_stamps(land), _fields(land, ["landed"]))
        builder.put_stream(["landed"], ts, landed, "hold", "vehicle_land_detected.landed", max_gap_s=math.inf)
        builder.metadata["landed_column"] = "landed: PX4's land detector, 1 on the ground, 0 in the air"
    else:
        warnings.append("no vehicle_land_detected: no landed column (ground contact is judged from motion)")
    if truncation is not None:
        warnings.append(f"{truncation}; converted up to t = {builder.t_abs[-1]:.3f} s of the log's clock")

    info = ulog.msg_info_dict
    described = ", ".join(
        f"{key} {info[key]}" for key in ("sys_name", "ver_sw_branch", "ver_hw") if key in info
    )
    mav_type = parameters.get("MAV_TYPE")
    if mav_type is not None:
        described += f", MAV_TYPE {int(mav_type)}"
    first = {
        "source": "px4_ulog",
        "converted_from": f"{path.name} (PX4 ULog; {described})",
        "airframe": airframe.name,
        "frames": "converted from NED/FRD: x..az world ENU, roll,pitch,yaw ZYX of body FLU -> world ENU, "
        "p,q,r and imu_f* body FLU",
    }
    return builder.build(first), warnings


def _read_ulog(path: Path) -> Any:
    """The topics of :data:`TOPICS` read by pyulog, whose notes on corrupt files (stdout) are dropped."""
    from pyulog import ULog

    with contextlib.redirect_stdout(io.StringIO()):
        return ULog(str(path), TOPICS)
