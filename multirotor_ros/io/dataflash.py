"""ArduPilot dataflash (.bin) -> flight log, read with pymavlink's DFReader.

Messages used (ArduPilot's LogStructure; NED/FRD turned into ENU/FLU by :mod:`multirotor_ros.frames`):

- ``XKF1`` (EKF3, core ``C`` = 0), ``NKF1`` (EKF2) or ``EKF1`` (the first EKF, ArduCopter 3.1-3.3 of
  2014-2015) is the time base: VN, VE, VD and PN, PE, PD (NED, m/s and m from the EKF origin) -> vx, vy,
  vz and x, y, z in ENU.
  Without either, ``POS`` (Lat, Lng, Alt) is the time base and the position is made local around
  the first fix with an equirectangular projection (metres per degree on a 6371 km sphere; good to
  millimetres over a flight's few hundred metres); then there is no velocity group.
- ``ATT``: Roll, Pitch, Yaw in degrees, ZYX of body FRD -> NED -> roll, pitch, yaw of FLU -> ENU.
- ``IMU`` (instance ``I`` = 0 when the field exists): GyrX..Z (FRD, rad/s) -> p, q, r;
  AccX..Z (FRD specific force) -> imu_fx, imu_fy, imu_fz (FLU).
- ``RCOU``: C1..C14 (Ch1..Ch12 before 2016, Chan1..Chan8 earlier), PWM [µs] -> u_k (channels from
  ``SERVOn_FUNCTION`` parameters, see :mod:`multirotor_ros.io.rotor_channels`), omega_k through the
  motor map.
- ``PARM``: parameters, for the motor-to-channel assignment.

Time stamps are ``TimeUS`` (µs since boot), or ``TimeMS`` (ms since boot) in logs before 2016. The
field names are those of ArduPilot's LogStructure of each generation; a log that has none of the
messages a group needs is refused with what it has and what would do.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from multirotor_ros.frames import frd_to_flu, ned_to_enu, quat_ned_frd_to_enu_flu
from multirotor_ros.io.flight_log import FlightLog
from multirotor_ros.io.log_builder import ConversionError, LogBuilder
from multirotor_ros.io.resample import sort_unique
from multirotor_ros.io.rotor_channels import RotorChannelError, resolve_rotor_channels
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import euler_to_matrix, matrix_to_quat

EARTH_RADIUS_M = 6_371_000.0
RCOU_CHANNELS = 14
# Position and velocity estimates, newest EKF first (EKF3, EKF2, the 2014 EKF).
EKF_MESSAGES = ("XKF1", "NKF1", "EKF1")
MESSAGES = [*EKF_MESSAGES, "POS", "ATT", "IMU", "RCOU", "PARM", "MSG"]
# Time fields and their unit [s], newest first.
TIME_FIELDS = (("TimeUS", 1e-6), ("TimeMS", 1e-3))
# RCOU channel names by generation: C1.. (2016 on), Ch1.. (3.2-3.3), Chan1.. (3.0-3.1).
RCOU_PREFIXES = ("C", "Ch", "Chan")


def read_messages(path: Path) -> dict[str, list[dict[str, Any]]]:
    """The messages this converter uses, as dicts per type, in log order."""
    from pymavlink.DFReader import DFReader_binary

    try:
        reader = DFReader_binary(str(path), zero_time_base=False)
    except Exception as error:  # DFReader raises whatever struct/mmap raise on a broken file
        raise ConversionError(f"{path}: not a readable dataflash log: {error}") from None
    messages: dict[str, list[dict[str, Any]]] = defaultdict(list)
    try:
        while (message := reader.recv_match(type=MESSAGES)) is not None:
            messages[message.get_type()].append(message.to_dict())
    finally:
        reader.close()
    return messages


def _stamps_s(rows: list[dict[str, Any]], name: str) -> np.ndarray:
    """The rows' time since boot [s], from whichever time field this generation of log has."""
    for field, unit_s in TIME_FIELDS:
        if field in rows[0]:
            return np.array([row[field] for row in rows], dtype=float) * unit_s
    raise ConversionError(
        f"{name} messages have no time field ({' or '.join(f for f, _ in TIME_FIELDS)}); their fields: "
        f"{', '.join(key for key in rows[0] if key != 'mavpackettype')}"
    )


def _table(rows: list[dict[str, Any]], fields: list[str], name: str) -> tuple[np.ndarray, np.ndarray]:
    stamps = _stamps_s(rows, name)
    values = np.array([[row[field] for field in fields] for row in rows], dtype=float).reshape(
        len(rows), len(fields)
    )
    return sort_unique(stamps, values)[:2]


def _primary(rows: list[dict[str, Any]], field: str) -> list[dict[str, Any]]:
    """Rows of instance 0 when the message has an instance field."""
    return [row for row in rows if row.get(field, 0) == 0]


def convert_dataflash(
    path: str | Path, airframe: Airframe, rotor_channels: str | None = None
) -> tuple[FlightLog, list[str]]:
    """Convert an ArduPilot dataflash log; returns the log and warnings for the user."""
    path = Path(path)
    messages = read_messages(path)
    warnings: list[str] = []
    name = next((name for name in EKF_MESSAGES if messages.get(name)), None)
    if name is not None:
        ekf = _primary(messages[name], "C")
        t, values = _table(ekf, ["PN", "PE", "PD", "VN", "VE", "VD"], name)
        builder = LogBuilder(t, f"{name} stamps")
        builder.put(["x", "y", "z"], ned_to_enu(values[:, :3]))
        builder.put(["vx", "vy", "vz"], ned_to_enu(values[:, 3:]))
        motion = f"x,y,z and vx,vy,vz: {name} PN,PE,PD and VN,VE,VD (NED, EKF origin) -> ENU"
    elif messages.get("POS"):
        t, values = _table(messages["POS"], ["Lat", "Lng", "Alt"], "POS")
        builder = LogBuilder(t, "POS stamps")
        lat0, lng0, alt0 = values[0]
        metres_per_degree = math.radians(1.0) * EARTH_RADIUS_M
        east = (values[:, 1] - lng0) * metres_per_degree * math.cos(math.radians(lat0))
        north = (values[:, 0] - lat0) * metres_per_degree
        builder.put(["x", "y", "z"], np.column_stack([east, north, values[:, 2] - alt0]))
        motion = (
            f"x,y,z: POS Lat,Lng,Alt, equirectangular ENU around the first fix "
            f"({lat0:.7f}, {lng0:.7f}, {alt0:.2f} m); no velocity group"
        )
    else:
        present = ", ".join(sorted(messages)) or "none of them"
        raise ConversionError(
            f"{path}: no position: none of the EKF messages {', '.join(EKF_MESSAGES)} nor POS (of "
            f"{', '.join(MESSAGES)} it has {present}). ArduPilot logs them with the EKF enabled and "
            "LOG_BITMASK's attitude and GPS bits set; a log without them cannot give a flight log"
        )

    if not messages.get("ATT"):
        raise ConversionError(f"{path}: no ATT messages: the attitude is required")
    ts, euler_deg = _table(messages["ATT"], ["Roll", "Pitch", "Yaw"], "ATT")
    q_ned_frd = matrix_to_quat(euler_to_matrix(np.radians(euler_deg)))
    builder.put_attitude(ts, quat_ned_frd_to_enu_flu(q_ned_frd), "ATT Roll,Pitch,Yaw")

    imu = _primary(messages.get("IMU", []), "I")
    if imu:
        ts, values = _table(imu, ["GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"], "IMU")
        builder.put_stream(["p", "q", "r"], ts, frd_to_flu(values[:, :3]), "linear", "IMU GyrX..Z")
        builder.put_stream(
            ["imu_fx", "imu_fy", "imu_fz"], ts, frd_to_flu(values[:, 3:]), "linear", "IMU AccX..Z"
        )
        builder.metadata["imu_columns"] = (
            "imu_fx, imu_fy, imu_fz: accelerometer specific force, body FLU [m/s^2]"
        )
    else:
        warnings.append("no IMU messages: p, q, r not written")

    if not messages.get("RCOU"):
        raise ConversionError(f"{path}: no RCOU messages: the actuator outputs are required")
    parameters = {row["Name"]: row["Value"] for row in messages.get("PARM", [])}
    prefix, count = _rcou_channels(messages["RCOU"][0])
    try:
        channels, channel_note = resolve_rotor_channels(airframe, rotor_channels, parameters, count)
    except RotorChannelError as error:
        raise ConversionError(f"{path}: {error}") from None
    ts, pwm = _table(messages["RCOU"], [f"{prefix}{i}" for i in range(1, count + 1)], "RCOU")
    warning = builder.put_actuators(
        ts, pwm, channels, f"{channel_note}; RCOU {prefix}n", "pwm_us", airframe, "RCOU"
    )
    if warning:
        warnings.append(warning)

    versions = [
        row["Message"] for row in messages.get("MSG", []) if row["Message"].startswith(("Ardu", "APM"))
    ]
    first = {
        "source": "ardupilot_dataflash",
        "converted_from": f"{path.name} (ArduPilot dataflash{'; ' + versions[0] if versions else ''})",
        "airframe": airframe.name,
        "frames": "converted from NED/FRD: world ENU, body FLU; roll,pitch,yaw ZYX of body FLU -> world ENU",
        "derived": motion,
    }
    return builder.build(first), warnings


def _rcou_channels(row: dict[str, Any]) -> tuple[str, int]:
    """The RCOU channel fields' prefix in this log's generation and how many channels it has."""
    for prefix in RCOU_PREFIXES:
        count = 0
        while f"{prefix}{count + 1}" in row:
            count += 1
        if count:
            return prefix, min(count, RCOU_CHANNELS)
    raise ConversionError(
        f"RCOU messages have none of the channel fields {', '.join(p + '1' for p in RCOU_PREFIXES)}; their "
        f"fields: {', '.join(key for key in row if key != 'mavpackettype')}"
    )
