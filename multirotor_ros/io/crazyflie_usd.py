"""Bitcraze Crazyflie micro-SD card logs ("usd log", the firmware's usddeck.c) -> flight log.

The file describes itself (Bitcraze's own reader is tools/usdlog/cfusdlog.py in crazyflie-firmware):

- ``u8`` magic 0xBC, ``u16`` version (1 or 2), ``u16`` number of event types;
- per event type: ``u16`` id, its name (NUL-terminated), ``u16`` variable count, then each variable as
  a NUL-terminated ``group.name(T)`` where T is a ``struct`` code (``B b H h I i f`` ...);
- records: ``u16`` event id, a timestamp (version 1: ``u32`` ms; version 2: ``u64`` µs), then the
  event's variables packed little-endian;
- a ``u32`` CRC-32 (zlib's) of everything before it.

A file cut short (the card pulled while logging, a power loss) has no CRC at its end: the records are
read up to the last whole one and the user is told how many bytes were left. The same log decoded by
Bitcraze's cfusdlog.py and written as CSV (``timestamp`` [ms], then the variables by name; CrazyPAD ships
every flight in both forms) is read by :func:`read_usd_csv` and converted the same way.

What is taken (Crazyflie's world frame is x forward at start-up, y left, z up, i.e. ENU-like; body
frame x forward, y left, z up, i.e. FLU; a missing variable is left out, never invented):

- ``stateEstimate.x/y/z`` [m] is the time base (its event's stamps); ``vx/vy/vz`` [m/s] in world;
  ``ax/ay/az`` [g] in world with gravity removed, times 9.81 m/s² (the firmware's GRAVITY_MAGNITUDE).
- ``stateEstimate.roll`` and ``yaw`` [deg] -> rad. A log without yaw (three CrazyPAD flights) gets
  yaw = 0, said in the notes: the Crazyflie holds its take-off heading, within a few degrees.
  ``stateEstimate.pitch`` is logged with the legacy sign (positive nose up), so our ZYX pitch is its
  negative. When pitch is not logged (CrazyPAD's motor_data files log roll and yaw only), it is
  derived from the direction of the specific force ``f = a + g e_z`` in the yaw-rotated frame,
  ``atan2(f_x', f_z')`` (a from the velocity's rate of change when no acceleration is logged): the
  estimator computed the world acceleration by rotating the accelerometer with its attitude, so
  rotating it back recovers the tilt. Rotor drag and accelerometer misalignment
  tilt the specific force off the body z axis; the notes give the RMS difference between the roll
  derived the same way and the logged roll (1-4 deg on CrazyPAD's flights) as the measure of that error.
- ``motor.m1..m4`` (the motor power command, 0..65535, after the mixer and before the battery compensation
  that turns it into ``pwm.m*_pwm``) -> ``u_k`` = command / 65535 (``normalized``), and ``omega_k``
  through the airframe's motor map. A brushed motor's thrust follows the voltage it gets, duty x battery
  voltage; the firmware's battery compensation (motors.c) sets the duty ``pwm = V(motor.m) / vbat`` from
  its bench table V(T) of thrust against voltage, so that motor.m alone fixes the voltage. When
  ``pwm.m*_pwm`` and the battery voltage are logged with the commands, ``u_k`` is the command whose
  voltage the motor actually got, ``V^-1(pwm / 65535 x vbat)``: the same as motor.m while the compensation
  holds (CrazyPAD: within 2e-4 of full scale median, 1.2e-3 at worst), and the thrust the motor could give
  where it did not (compensation off, or the battery too low for the voltage: duty at 100 %); the notes
  say which and how often. Without ``motor.m*``, ``pwm.m*_pwm`` is taken the same way with the battery
  voltage, or as it is with a warning (it moves with battery voltage at constant thrust).
- ``pm.vbatMV`` [mV] or ``pm.vbat`` [V] -> extra column ``battery_v``.

A log of the PID controller instead of the motors (CrazyPAD's controller_data files:
``controller.cmd_thrust/cmd_roll/cmd_pitch/cmd_yaw``, the gyro as ``controller.r_roll/r_pitch/r_yaw``,
no motors and no attitude estimate) is converted from what the firmware does with them:

- the motor commands are rebuilt by the firmware's legacy power distribution
  (:func:`motor_commands_of_controller`), the mixer between those outputs and motor.m1..m4; on CrazyPAD,
  the in-flight median command of each rotor, relative to their mean, comes out within 0.016 of a
  motor_data flight of the same session and condition (test_crazyflie_usd.py);
- roll, pitch and yaw: the attitude setpoints (``controller.roll/pitch/yaw``, pitch with the legacy sign)
  blended with the gyro (``r_pitch`` is the legacy-signed pitch rate, so q is its negative; its mean while
  the motors were off before take-off, the bias, removed) by a complementary filter
  (:func:`_attitude_from_controller`); ``p, q, r`` are written too. The notes say how far the result lies from
  the setpoints in flight.

Rotor k of the airframe is Bitcraze's motor M_k matched by geometry (M1 front-right, M2 rear-right,
M3 rear-left, M4 front-left; :data:`~multirotor_ros.io.rotor_channels.CRAZYFLIE_LAYOUT`) unless
``--rotor-channels`` says otherwise.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from multirotor_ros.io.derive import SavitzkyGolay, differentiate
from multirotor_ros.io.flight_log import FlightLog
from multirotor_ros.io.log_builder import ConversionError, LogBuilder, read_numeric_csv
from multirotor_ros.io.resample import sort_unique
from multirotor_ros.io.rotor_channels import CRAZYFLIE_LAYOUT, RotorChannelError, resolve_rotor_channels
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import euler_rates_matrix

USD_MAGIC = 0xBC
CRAZYFLIE_GRAVITY_M_S2 = 9.81
MOTOR_COMMAND_FULL_SCALE = 65535.0
# crazyflie-firmware src/drivers/src/motors.c, motorsCompensateBatteryVoltage: the voltage V [V] a brushed
# motor needs for a thrust T [g of the whole vehicle] is V = a T^2 + b T (Bitcraze's polyfit of its bench
# table, thrust 0-57.9 g at 0-3.09 V), with the command scale 65536 <-> 60 g.
FIRMWARE_VOLTS_PER_GRAM = (-0.0006239, 0.088)
FIRMWARE_FULL_SCALE_THRUST_G = 60.0
# The applied voltage agrees with motor.m (the compensation held) within this share of full scale: the
# duty is an integer and the logged battery voltage a sample of what the firmware filtered.
COMPENSATION_TOLERANCE = 0.005
# CrazyPAD's controller_data files log the PID controller (controller_pid.c) instead of the motors.
CONTROLLER_OUTPUTS = tuple(f"controller.cmd_{axis}" for axis in ("thrust", "roll", "pitch", "yaw"))
# Body rates [rad/s] as the controller saw them: gyro x, minus gyro y (the legacy pitch sign), gyro z.
CONTROLLER_GYRO = ("controller.r_roll", "controller.r_pitch", "controller.r_yaw")
# The attitude setpoints [deg] the attitude loop follows (pitch with the legacy sign).
CONTROLLER_ATTITUDE_SETPOINTS = ("controller.roll", "controller.pitch", "controller.yaw")
# Crossover of the attitude derived from the setpoints and the gyro: about the attitude loop's response
# time (a step of the setpoint is followed within a few tenths of a second).
ATTITUDE_BLEND_TAU_S = 0.5
# Motors off before take-off for at least this long: the gyro's mean there is its bias.
MIN_REST_S = 0.2
# Largest in-flight yaw standard deviation over the 27 CrazyPAD motor_data flights that log yaw (2.6 deg).
HELD_HEADING_STD_DEG = 2.6
# The CSV export's time column [ms], and the longest median step between its records read as ms (1 Hz).
CSV_TIME_COLUMN = "timestamp"
MAX_CSV_PERIOD_MS = 1000.0
_PREAMBLE = struct.Struct("<BHH")
_RECORD_HEADERS = {1: (struct.Struct("<HI"), 1e-3), 2: (struct.Struct("<HQ"), 1e-6)}
_TYPE_CODES = frozenset("bBhHiIqQfd?")
_CRC = struct.Struct("<I")


@dataclass(frozen=True)
class UsdEvent:
    """The records of one event type: stamps [s] of the Crazyflie's clock and one column per variable."""

    name: str
    variables: tuple[str, ...]
    stamps_s: np.ndarray
    values: np.ndarray

    def has(self, *names: str) -> bool:
        """Whether every one of ``names`` is logged by this event."""
        return all(name in self.variables for name in names)

    def column(self, name: str) -> np.ndarray:
        """One variable's values, as floats."""
        return self.values[:, self.variables.index(name)]


@dataclass
class UsdLog:
    """A decoded usd log: its events by name, and what the user should hear about the file."""

    version: int
    events: dict[str, UsdEvent]
    warnings: list[str] = field(default_factory=list)
    container: str = "binary"  # or "csv": Bitcraze's decoding written out (read_usd_csv)

    def describe(self) -> str:
        """What the file was, for the flight log's notes."""
        if self.container == "csv":
            return "CSV export of a Bitcraze usd log (timestamp in ms)"
        return f"Bitcraze usd log version {self.version}"

    def event_with(self, *names: str) -> UsdEvent | None:
        """The event with records that logs all of ``names``, if any."""
        for event in self.events.values():
            if event.has(*names) and event.stamps_s.size:
                return event
        return None


class _Cursor:
    """Reads the header, naming the byte offset of whatever does not parse."""

    def __init__(self, data: bytes, path: Path):
        self.data, self.path, self.offset = data, path, 0

    def fail(self, what: str) -> ConversionError:
        return ConversionError(f"{self.path}: byte {self.offset}: {what}: not a readable Crazyflie usd log")

    def unpack(self, layout: struct.Struct, what: str) -> tuple[int, ...]:
        if self.offset + layout.size > len(self.data):
            raise self.fail(f"the file ends inside the header ({what})")
        values = layout.unpack_from(self.data, self.offset)
        self.offset += layout.size
        return values

    def name(self, what: str) -> str:
        end = self.data.find(b"\0", self.offset)
        if end < 0:
            raise self.fail(f"the file ends inside the header ({what} has no terminating NUL)")
        try:
            text = self.data[self.offset : end].decode("ascii")
        except UnicodeDecodeError:
            raise self.fail(f"{what} is not ASCII text") from None
        self.offset = end + 1
        return text


_U16 = struct.Struct("<H")


def looks_like_usd_csv(header: Sequence[str]) -> bool:
    """A CSV export of a usd log: ``timestamp`` first, then the firmware's ``group.name`` variables."""
    return len(header) > 1 and header[0] == CSV_TIME_COLUMN and all("." in name for name in header[1:])


def read_usd_csv(path: str | Path) -> UsdLog:
    """A usd log as Bitcraze's cfusdlog.py decodes it, written out as CSV (CrazyPAD ships both forms).

    One row per record of one event: ``timestamp`` [ms] (from the first record, or the Crazyflie's clock),
    then the event's variables by their firmware names; the result is one event, ``fixedFrequency``.
    """
    path = Path(path)
    header, values = read_numeric_csv(path)
    if not looks_like_usd_csv(header):
        raise ConversionError(
            f"{path}:1: neither a usd log (first byte 0x{USD_MAGIC:02X}) nor its CSV export (a header of "
            f"'{CSV_TIME_COLUMN}' and then firmware variables, group.name); found "
            f"{', '.join(header[:4]) or 'nothing'}"
        )
    if len(values) < 2:
        raise ConversionError(f"{path}: {len(values)} records: nothing to convert")
    stamps_ms = values[:, 0]
    period_ms = float(np.median(np.diff(stamps_ms)))
    if not 0.0 < period_ms <= MAX_CSV_PERIOD_MS:
        raise ConversionError(
            f"{path}: column {CSV_TIME_COLUMN}: median step {period_ms:g} between records; it is read in ms "
            f"(as cfusdlog.py and CrazyPAD write it), where a logging period is at most {MAX_CSV_PERIOD_MS:g}"
        )
    event = UsdEvent("fixedFrequency", tuple(header[1:]), stamps_ms * 1e-3, values[:, 1:])
    return UsdLog(0, {event.name: event}, [], container="csv")


def _starts_with_magic(path: Path) -> bool:
    try:
        with path.open("rb") as stream:
            return stream.read(1) == bytes([USD_MAGIC])
    except OSError as error:
        raise ConversionError(f"{path}: cannot read: {error.strerror or error}") from None


def read_usd_log(path: str | Path) -> UsdLog:
    """Decode a usd log file; a damaged header is an error, a damaged or missing tail a warning."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as error:
        raise ConversionError(f"{path}: cannot read: {error.strerror or error}") from None
    cursor = _Cursor(data, path)
    magic, version, n_event_types = cursor.unpack(_PREAMBLE, "magic, version, event count")
    if magic != USD_MAGIC:
        raise cursor.fail(f"magic byte 0x{magic:02X}, expected 0x{USD_MAGIC:02X}")
    if version not in _RECORD_HEADERS:
        raise cursor.fail(f"format version {version}; versions 1 and 2 are known")
    layouts: dict[int, tuple[str, tuple[str, ...], struct.Struct]] = {}
    for _ in range(n_event_types):
        (event_id,) = cursor.unpack(_U16, "event id")
        event_name = cursor.name("an event name")
        (n_variables,) = cursor.unpack(_U16, f"variable count of event {event_name!r}")
        names, codes = [], ""
        for _ in range(n_variables):
            declared = cursor.name(f"a variable of event {event_name!r}")
            if (
                len(declared) < 4
                or declared[-3] != "("
                or declared[-1] != ")"
                or declared[-2] not in _TYPE_CODES
            ):
                raise cursor.fail(
                    f"variable {declared!r} of event {event_name!r} is not 'name(T)' with a C type T"
                )
            names.append(declared[:-3])
            codes += declared[-2]
        layouts[event_id] = (event_name, tuple(names), struct.Struct("<" + codes))

    warnings: list[str] = []
    whole = (
        len(data) >= cursor.offset + _CRC.size
        and zlib.crc32(data[: -_CRC.size]) == _CRC.unpack_from(data, len(data) - _CRC.size)[0]
    )
    end = len(data) - _CRC.size if whole else len(data)
    record_header, stamp_unit = _RECORD_HEADERS[version]
    rows: dict[int, list[tuple[float, ...]]] = {event_id: [] for event_id in layouts}
    stamps: dict[int, list[float]] = {event_id: [] for event_id in layouts}
    offset = cursor.offset
    while offset + record_header.size <= end:
        event_id, stamp = record_header.unpack_from(data, offset)
        if event_id not in layouts:
            warnings.append(
                f"record at byte {offset} names event id {event_id}, which the header does not declare: "
                f"the {end - offset} bytes from there are not read (the file is damaged)"
            )
            break
        body = layouts[event_id][2]
        if offset + record_header.size + body.size > end:
            break
        stamps[event_id].append(stamp * stamp_unit)
        rows[event_id].append(body.unpack_from(data, offset + record_header.size))
        offset += record_header.size + body.size
    if not whole:
        left = end - offset
        warnings.append(
            "truncated or damaged: the CRC-32 at the end does not match the content"
            + (f"; the last {left} bytes (a partial record) are not read" if left > 0 else "")
        )
    events = {
        name: UsdEvent(
            name,
            variables,
            np.asarray(stamps[event_id], dtype=float),
            np.asarray(rows[event_id], dtype=float).reshape(len(rows[event_id]), len(variables)),
        )
        for event_id, (name, variables, _) in layouts.items()
    }
    return UsdLog(version, events, warnings)


def _pitch_from_specific_force(accel_W: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ZYX pitch, and the roll implied the same way, from the world specific force and the yaw.

    With R = Rz(yaw) Ry(pitch) Rx(roll), Rz(-yaw) R e_z = (sin pitch cos roll, -sin roll, cos pitch cos roll).
    Where the specific force's upward part is under half of g (free fall, a landing's impact) it does not
    point along the thrust: NaN there (an empty cell, not measured).
    """
    specific = accel_W + np.array([0.0, 0.0, CRAZYFLIE_GRAVITY_M_S2])
    c, s = np.cos(yaw), np.sin(yaw)
    forward = c * specific[:, 0] + s * specific[:, 1]
    left = -s * specific[:, 0] + c * specific[:, 1]
    along_thrust = specific[:, 2] >= 0.5 * CRAZYFLIE_GRAVITY_M_S2
    pitch = np.where(along_thrust, np.arctan2(forward, specific[:, 2]), np.nan)
    implied_roll = np.where(along_thrust, np.arctan2(-left, np.hypot(forward, specific[:, 2])), np.nan)
    return pitch, implied_roll


def motor_commands_of_controller(outputs: np.ndarray) -> np.ndarray:
    """motor.m1..m4 as the firmware's legacy power distribution makes them from the controller's outputs.

    ``outputs``: (n, 4) thrust, roll, pitch, yaw commands. crazyflie-firmware power_distribution_quadrotor.c
    (powerDistributionLegacy, the PID controller's mode; power_distribution_stock.c's X formation before it):
    r = roll / 2 and p = pitch / 2 as int16 (truncated), m1 = T - r + p + Y, m2 = T - r - p - Y,
    m3 = T + r - p + Y, m4 = T + r + p - Y stored as integers; powerDistributionCap then lowers all four by
    what the highest exceeds 65535 and stops each at 0 (the idle thrust of a brushed Crazyflie).
    """
    thrust, roll, pitch, yaw = np.asarray(outputs, dtype=float).T
    r, p = np.trunc(roll / 2.0), np.trunc(pitch / 2.0)
    uncapped = np.trunc(
        np.column_stack(
            [thrust - r + p + yaw, thrust - r - p - yaw, thrust + r - p + yaw, thrust + r + p - yaw]
        )
    )
    excess = np.clip(uncapped.max(axis=1) - MOTOR_COMMAND_FULL_SCALE, 0.0, None)
    return np.clip(uncapped - excess[:, None], 0.0, None)


def _attitude_from_controller(event: UsdEvent, warnings: list[str]) -> tuple[np.ndarray, np.ndarray, str]:
    """roll, pitch, yaw from the controller's gyro and attitude setpoints, the bias-free body rates, a note.

    A complementary filter: the attitude loop follows its setpoints, so below
    :data:`ATTITUDE_BLEND_TAU_S` the attitude is the setpoint's, above it the gyro's (turned into Euler
    rates at the setpoint's attitude). Gyro integration alone drifts and takes a landing's knocks, which
    100 Hz samples miss, for good (4-11 deg on the two CrazyPAD flights checked); a setpoint alone misses
    how the vehicle follows it. With the motors off the firmware sets the setpoint to the estimator's
    attitude.
    """
    t = event.stamps_s
    rates = _columns(event, CONTROLLER_GYRO) * np.array([1.0, -1.0, 1.0])
    motors_off = event.column(CONTROLLER_OUTPUTS[0]) <= 0.0
    first_on = int(np.argmin(motors_off)) if not motors_off.all() else t.size
    if first_on and t[first_on - 1] - t[0] >= MIN_REST_S:
        bias = rates[:first_on].mean(axis=0)
        bias_note = (
            f"gyro bias ({', '.join(f'{b:+.4f}' for b in bias)}) rad/s, its mean over the "
            f"{t[first_on - 1] - t[0]:.1f} s with the motors off before take-off, removed"
        )
    else:
        bias = np.zeros(3)
        bias_note = f"gyro bias NOT removed: less than {MIN_REST_S:g} s with the motors off before take-off"
        warnings.append(f"the gyro's bias is unknown: {bias_note}")
    rates = rates - bias
    setpoint = np.radians(_columns(event, CONTROLLER_ATTITUDE_SETPOINTS)) * np.array([1.0, -1.0, 1.0])
    setpoint[:, 2] = np.unwrap(setpoint[:, 2])
    euler_rates = np.linalg.solve(euler_rates_matrix(setpoint), rates[..., None])[..., 0]
    dt = np.diff(t, prepend=t[0])
    keep = ATTITUDE_BLEND_TAU_S / (ATTITUDE_BLEND_TAU_S + dt)
    euler = np.empty_like(setpoint)
    euler[0] = setpoint[0]
    for k in range(1, t.size):
        euler[k] = keep[k] * (euler[k - 1] + euler_rates[k] * dt[k]) + (1.0 - keep[k]) * setpoint[k]
    euler[:, 2] = np.angle(np.exp(1j * euler[:, 2]))
    flying = ~motors_off
    rms = (
        np.degrees(np.sqrt(np.mean((euler[flying] - setpoint[flying]) ** 2, axis=0)))
        if flying.any()
        else None
    )
    note = (
        "roll,pitch,yaw NOT LOGGED, derived: the controller's attitude setpoints (controller.roll, "
        "-controller.pitch, controller.yaw [deg]) blended with the gyro (controller.r_roll, "
        f"-controller.r_pitch, controller.r_yaw [rad/s], FLU) by a complementary filter of "
        f"{ATTITUDE_BLEND_TAU_S:g} s (the attitude loop follows its setpoints; the gyro says how); "
        + bias_note
    )
    if rms is not None:
        note += (
            f"; in flight the result differs from the setpoints by {rms[0]:.2f}, {rms[1]:.2f} and "
            f"{rms[2]:.2f} deg RMS"
        )
    warnings.append("the attitude is not logged: derived from the controller's setpoints and gyro (notes)")
    return euler, rates, note


def _columns(event: UsdEvent, names: Sequence[str]) -> np.ndarray:
    return np.column_stack([event.column(name) for name in names])


def command_of_applied_voltage(volts: np.ndarray) -> tuple[np.ndarray, int]:
    """The firmware's motor command / 65535 whose voltage (motors.c's table) is ``volts``, and a count.

    The count is of the voltages beyond the table's fit (its vertex, 3.10 V), taken as the vertex.
    """
    a, b = FIRMWARE_VOLTS_PER_GRAM
    vertex_v = -b * b / (4.0 * a)
    volts = np.asarray(volts, dtype=float)
    beyond = int(np.count_nonzero(volts > vertex_v))
    # The rising branch of a T^2 + b T = V (a < 0).
    thrust_g = (-b + np.sqrt(np.clip(b * b + 4.0 * a * np.clip(volts, 0.0, None), 0.0, None))) / (2.0 * a)
    return thrust_g / FIRMWARE_FULL_SCALE_THRUST_G * (
        MOTOR_COMMAND_FULL_SCALE + 1
    ) / MOTOR_COMMAND_FULL_SCALE, beyond


def _battery_variable(event: UsdEvent) -> tuple[str, float] | None:
    """The battery voltage this event logs, with its scale to volts."""
    for name, scale in (("pm.vbatMV", 1e-3), ("pm.vbat", 1.0)):
        if event.has(name):
            return name, scale
    return None


def _applied_voltage_commands(
    motors: UsdEvent, commanded: np.ndarray | None, pwm_names: Sequence[str], warnings: list[str]
) -> tuple[np.ndarray, str] | None:
    """u_k from the voltage the motors got (duty x battery), with the note on how it compares with motor.m.

    None when the duty or the battery voltage is not logged with the motor records.
    """
    battery = _battery_variable(motors)
    if battery is None or not motors.has(*pwm_names):
        return None
    name, scale = battery
    duty = _columns(motors, pwm_names) / MOTOR_COMMAND_FULL_SCALE
    volts = duty * (motors.column(name) * scale)[:, None]
    commands, beyond = command_of_applied_voltage(volts)
    how = (
        f"u_k: the voltage motor k got, pwm.m_k_pwm / 65535 x {name}, as the firmware's command for it "
        "(motors.c's thrust-voltage table inverted) / 65535"
    )
    if beyond:
        warnings.append(
            f"{beyond} motor samples got more than the firmware's thrust-voltage table covers (3.10 V): "
            "taken as its top"
        )
    if commanded is None:
        return commands, how + "; motor.m1..m4 not logged"
    saturated = int(np.count_nonzero(duty >= 1.0))
    departed = np.abs(commands - commanded) > COMPENSATION_TOLERANCE
    agreement = (
        f"; it matches motor.m_k within {float(np.median(np.abs(commands - commanded))):.2e} of full scale "
        f"(median), beyond {COMPENSATION_TOLERANCE:.1%} at {int(np.count_nonzero(departed))} of "
        f"{departed.size} motor samples ({saturated} at full duty)"
    )
    if np.mean(departed) > 0.01:
        warnings.append(
            f"motor.m1..m4 is not the voltage the motors got at {np.mean(departed):.1%} of motor samples "
            f"(battery compensation off, or {saturated} at full duty: the battery could not give it): u_k "
            "from duty x battery voltage"
        )
    return commands, how + agreement


def _estimated_attitude(
    path: Path,
    event: UsdEvent,
    accel_W: np.ndarray | None,
    velocity_names: Sequence[str],
    taken: list[str],
    warnings: list[str],
) -> np.ndarray:
    """roll, pitch, yaw [rad]: the estimator's roll and yaw, pitch logged or derived (module docstring)."""
    t = event.stamps_s
    roll = np.radians(event.column("stateEstimate.roll"))
    if event.has("stateEstimate.yaw"):
        yaw = np.radians(event.column("stateEstimate.yaw"))
        taken.append("roll,yaw: stateEstimate.roll/yaw [deg]")
    else:
        yaw = np.zeros_like(roll)
        taken.append(
            "roll: stateEstimate.roll [deg]; yaw NOT LOGGED, taken as 0: the Crazyflie holds the heading "
            "it started with (CrazyPAD flights that log yaw stay within "
            f"{HELD_HEADING_STD_DEG:g} deg std of it)"
        )
        warnings.append("yaw is not logged: taken as 0, the heading the Crazyflie holds from take-off")
    if event.has("stateEstimate.pitch"):
        pitch = -np.radians(event.column("stateEstimate.pitch"))
        taken.append("pitch: -stateEstimate.pitch [deg] (legacy sign)")
    elif accel_W is not None or event.has(*velocity_names):
        if accel_W is not None:
            tilt_accel, source = accel_W, "the logged acceleration"
        else:
            tilt_accel, how = differentiate(
                t, _columns(event, velocity_names), 1, "velocity", SavitzkyGolay()
            )
            source = f"the rate of change of the logged velocity ({how})"
        pitch, implied_roll = _pitch_from_specific_force(tilt_accel, yaw)
        rms = float(np.degrees(np.sqrt(np.nanmean((implied_roll - roll) ** 2))))
        unknown = int(np.count_nonzero(np.isnan(pitch)))
        taken.append(
            "pitch NOT LOGGED, derived: atan2(f_x', f_z') of the specific force f = a + g e_z rotated by "
            f"-yaw into the heading frame, a from {source} (rotor drag and accelerometer misalignment "
            f"neglected); the roll derived the same way differs from the logged roll by {rms:.2f} deg RMS; "
            f"left empty at {unknown} samples where f_z < g/2 (free fall, impacts)"
        )
        warnings.append(f"pitch is not logged: derived from {source} and yaw (roll check: {rms:.2f} deg RMS)")
    else:
        raise ConversionError(
            f"{path}: stateEstimate.pitch is not logged and cannot be derived without "
            "stateEstimate.ax/ay/az or vx/vy/vz: log one of them"
        )
    return np.column_stack([roll, pitch, yaw])


def convert_crazyflie_usd(
    path: str | Path, airframe: Airframe, rotor_channels: str | None = None
) -> tuple[FlightLog, list[str]]:
    """Convert a usd log; returns the log and warnings for the user."""
    path = Path(path)
    usd = read_usd_log(path) if _starts_with_magic(path) else read_usd_csv(path)
    warnings = list(usd.warnings)
    position_names = [f"stateEstimate.{axis}" for axis in "xyz"]
    motion = usd.event_with(*position_names)
    if motion is None:
        logged = sorted(
            {name for event in usd.events.values() if event.stamps_s.size for name in event.variables}
        )
        raise ConversionError(
            f"{path}: no records with stateEstimate.x, .y and .z (the position is the time base); "
            f"logged: {', '.join(logged) or 'nothing'}"
        )
    n_motors = 4
    motor_names = [f"motor.m{k}" for k in range(1, n_motors + 1)]
    pwm_names = [f"pwm.m{k}_pwm" for k in range(1, n_motors + 1)]
    motors = usd.event_with(*motor_names)
    label = "motor.m1..m4 (motor power command before battery compensation) / 65535"
    if motors is None and (duty := usd.event_with(*pwm_names)) is not None:
        motors, motor_names = duty, pwm_names
        label = "pwm.m1_pwm..m4_pwm (duty cycle after battery compensation) / 65535"
    rebuilt = motors is None
    if motors is None:
        motors = usd.event_with(*CONTROLLER_OUTPUTS)
        label = (
            "motor.m1..m4 NOT LOGGED, rebuilt from controller.cmd_thrust/cmd_roll/cmd_pitch/cmd_yaw by the "
            "firmware's legacy power distribution (power_distribution_quadrotor.c), / 65535"
        )
        if motors is None:
            raise ConversionError(
                f"{path}: no motor commands (motor.m1..m4 or pwm.m1_pwm..m4_pwm) and no controller outputs "
                f"({', '.join(CONTROLLER_OUTPUTS)}) to rebuild them from: a rotor group is needed"
            )
    t, rows, dropped = sort_unique(motion.stamps_s, np.arange(motion.stamps_s.size, dtype=float))
    if dropped:
        warnings.append(f"{dropped} records with repeated stamps dropped")
    index = rows.astype(int)
    event = UsdEvent(motion.name, motion.variables, t, motion.values[index])
    if motors is motion:
        motors = event
    builder = LogBuilder(t, f"the stamps of the {event.name!r} records (stateEstimate.x/y/z)")
    taken = ["x,y,z: stateEstimate.x/y/z [m], Crazyflie world frame (x forward at start-up, y left, z up)"]
    builder.put(["x", "y", "z"], _columns(event, position_names))
    velocity_names = [f"stateEstimate.v{axis}" for axis in "xyz"]
    if event.has(*velocity_names):
        builder.put(["vx", "vy", "vz"], _columns(event, velocity_names))
        taken.append("vx,vy,vz: stateEstimate.vx/vy/vz [m/s], world")
    accel_names = [f"stateEstimate.a{axis}" for axis in "xyz"]
    accel_W = _columns(event, accel_names) * CRAZYFLIE_GRAVITY_M_S2 if event.has(*accel_names) else None
    if accel_W is not None:
        builder.put(["ax", "ay", "az"], accel_W)
        taken.append(
            f"ax,ay,az: stateEstimate.ax/ay/az [g, world, gravity removed] x {CRAZYFLIE_GRAVITY_M_S2}"
        )

    if event.has("stateEstimate.roll"):
        builder.put(
            ["roll", "pitch", "yaw"],
            _estimated_attitude(path, event, accel_W, velocity_names, taken, warnings),
        )
    elif event.has(*CONTROLLER_GYRO, *CONTROLLER_ATTITUDE_SETPOINTS, CONTROLLER_OUTPUTS[0]):
        euler, body_rates, how = _attitude_from_controller(event, warnings)
        builder.put(["roll", "pitch", "yaw"], euler)
        builder.put(["p", "q", "r"], body_rates)
        taken.append(how + "; p,q,r: the same bias-free rates")
    else:
        raise ConversionError(
            f"{path}: no stateEstimate.roll in the {event.name!r} records, nor the controller's gyro and "
            f"attitude setpoints ({', '.join(CONTROLLER_GYRO + CONTROLLER_ATTITUDE_SETPOINTS)}) to derive it "
            "from: the attitude is needed (log it with the position)"
        )

    try:
        channels, channel_note = resolve_rotor_channels(
            airframe, rotor_channels, None, n_motors, channel_names=motor_names, layouts=(CRAZYFLIE_LAYOUT,)
        )
    except RotorChannelError as error:
        raise ConversionError(f"{path}: {error}") from None
    if rebuilt:
        commands = (
            motor_commands_of_controller(_columns(motors, CONTROLLER_OUTPUTS)) / MOTOR_COMMAND_FULL_SCALE
        )
    else:
        commands = _columns(motors, motor_names) / MOTOR_COMMAND_FULL_SCALE
    applied = _applied_voltage_commands(
        motors, None if motor_names == pwm_names else commands, pwm_names, warnings
    )
    if applied is not None:
        commands, how = applied
        taken.append(how)
        label = "the voltage the motors got (pwm.m*_pwm x battery) as the firmware's motor command / 65535"
    elif motor_names == pwm_names:
        warnings.append("motor.m1..m4 not logged: u_k from pwm.m*_pwm, which rises as the battery drains")
    warning = builder.put_actuators(
        motors.stamps_s,
        commands,
        channels,
        channel_note,
        "normalized",
        airframe,
        label,
    )
    if warning:
        warnings.append(warning)
    for name, scale in (("pm.vbatMV", 1e-3), ("pm.vbat", 1.0)):
        battery = usd.event_with(name)
        if battery is not None:
            builder.put_stream(["battery_v"], battery.stamps_s, battery.column(name) * scale, "linear", name)
            taken.append(f"battery_v: {name} [V]")
            break
    first = {
        "source": "crazyflie_usd",
        "converted_from": f"{path.name} ({usd.describe()})",
        "airframe": airframe.name,
        "frames": "Crazyflie world (z up) and body (x forward, y left, z up) are ENU/FLU-like: no change",
        "derived": "; ".join(taken),
    }
    return builder.build(first), warnings
