"""Bitcraze usd logs: the reader on files the tests build byte by byte, and every real CrazyPAD flight."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from multirotor_ros.io.convert import convert, detect_format
from multirotor_ros.io.crazyflie_usd import motor_commands_of_controller, read_usd_log
from multirotor_ros.io.log_builder import ConversionError
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.rotation import euler_to_matrix

CRAZYPAD = Path(__file__).resolve().parents[2] / "shared" / "data" / "crazypad"
if not CRAZYPAD.is_dir():  # CI clones main with shared/ beside it
    CRAZYPAD = Path("/work/shared/data/crazypad")
MOTOR_FLIGHTS = sorted(CRAZYPAD.glob("motor_data/*/E*"))
needs_crazypad = pytest.mark.skipif(
    not MOTOR_FLIGHTS, reason="shared/data/crazypad is not beside the repository"
)

FIXED_FREQUENCY = 0xFFFF
STATE_VARIABLES = [
    ("motor.m1", "I"),
    ("motor.m2", "I"),
    ("motor.m3", "I"),
    ("motor.m4", "I"),
    ("pm.vbatMV", "H"),
    *[
        (f"stateEstimate.{name}", "f")
        for name in ("x", "y", "z", "vx", "vy", "vz", "ax", "ay", "az", "roll", "yaw")
    ],
]


def usd_bytes(
    events: dict[int, tuple[str, list[tuple[str, str]]]],
    records: list[tuple[int, int, tuple[float, ...]]],
    version: int = 2,
) -> bytes:
    """A usd log as the firmware writes it: header, records (id, stamp in the version's unit, values), CRC."""
    out = bytearray(struct.pack("<BHH", 0xBC, version, len(events)))
    for event_id, (name, variables) in events.items():
        out += struct.pack("<H", event_id) + name.encode() + b"\0" + struct.pack("<H", len(variables))
        for variable, code in variables:
            out += f"{variable}({code})".encode() + b"\0"
    for event_id, stamp, values in records:
        codes = "".join(code for _, code in events[event_id][1])
        out += struct.pack("<HQ" if version == 2 else "<HI", event_id, stamp)
        out += struct.pack("<" + codes, *values)
    return bytes(out + struct.pack("<I", zlib.crc32(out)))


def hover_records(n: int = 300, pitch_deg: float = 2.0, roll_deg: float = -1.5, yaw_deg: float = 30.0):
    """A vehicle tilted by (roll, pitch, yaw), accelerating as its thrust says: a + g e_z along R e_z."""
    rotation = euler_to_matrix(np.radians([[roll_deg, pitch_deg, yaw_deg]]))[0]
    specific_force = 9.81 * rotation[:, 2] / rotation[2, 2]
    accel_g = (specific_force - [0.0, 0.0, 9.81]) / 9.81
    records = []
    for i in range(n):
        values = (30000, 31000, 32000, 33000, 3900 - i, 0.1 * i / n, 0.0, 0.5, 0.1, 0.0, 0.0, *accel_g)
        records.append((FIXED_FREQUENCY, 1_000_000 + 10_000 * i, (*values, roll_deg, yaw_deg)))
    return records


@pytest.fixture(scope="module")
def crazyflie():
    return load_airframe("crazyflie_2_1")


def test_a_built_log_decodes_and_converts_with_pitch_derived_from_the_acceleration(
    crazyflie, tmp_path
) -> None:
    path = tmp_path / "log00"
    events = {
        FIXED_FREQUENCY: ("fixedFrequency", STATE_VARIABLES),
        12: ("activeMarkerModeChanged", [("mode", "B")]),
    }
    path.write_bytes(usd_bytes(events, hover_records()))
    assert detect_format(path) == "crazyflie-usd"
    usd = read_usd_log(path)
    assert usd.version == 2 and usd.warnings == []
    assert usd.events["activeMarkerModeChanged"].stamps_s.size == 0
    conversion = convert(path, crazyflie)
    log = conversion.log
    assert log.t[0] == 0.0 and log.t[-1] == pytest.approx(2.99)
    np.testing.assert_allclose(np.degrees(log.columns["pitch"]), 2.0, atol=1e-4)
    np.testing.assert_allclose(np.degrees(log.columns["roll"]), -1.5, atol=1e-5)
    np.testing.assert_allclose(log.columns["u_3"], 32000 / 65535)
    np.testing.assert_allclose(log.columns["battery_v"][:2], [3.9, 3.899])
    assert log.metadata["actuator_unit"] == "normalized"
    assert "pitch NOT LOGGED, derived" in log.metadata["derived"]
    assert "differs from the logged roll by 0.00 deg RMS; left empty at 0 samples" in log.metadata["derived"]
    assert log.metadata["rotor_channels"].startswith(
        "1,2,3,4 (motor.m1, motor.m2, motor.m3, motor.m4); Crazyflie"
    )
    assert any("pitch is not logged" in warning for warning in conversion.warnings)


def test_a_logged_pitch_has_its_legacy_sign_turned_and_version_1_stamps_are_milliseconds(crazyflie, tmp_path):
    variables = [*STATE_VARIABLES, ("stateEstimate.pitch", "f")]
    records = [
        (FIXED_FREQUENCY, 500 + 10 * i, (*values, 4.0)) for i, (_, _, values) in enumerate(hover_records(50))
    ]
    path = tmp_path / "log01"
    path.write_bytes(usd_bytes({FIXED_FREQUENCY: ("fixedFrequency", variables)}, records, version=1))
    log = convert(path, crazyflie, fmt="crazyflie-usd").log
    np.testing.assert_allclose(np.degrees(log.columns["pitch"]), -4.0, rtol=1e-6)
    assert log.t[1] == pytest.approx(0.01)


def test_without_acceleration_the_pitch_comes_from_the_velocity_and_without_either_it_is_refused(
    crazyflie, tmp_path
) -> None:
    """A vehicle pitched by 2 deg accelerates along x at g tan(2 deg): its velocity ramps."""
    ramp = 9.81 * np.tan(np.radians(2.0))
    rows = []
    for _, stamp, values in hover_records(200, pitch_deg=2.0, roll_deg=0.0, yaw_deg=0.0):
        row = dict(zip([name for name, _ in STATE_VARIABLES], values, strict=True))
        row["stateEstimate.vx"] = ramp * (stamp - 1_000_000) * 1e-6
        rows.append((stamp, row))

    def write(variables: list[tuple[str, str]]) -> Path:
        records = [(FIXED_FREQUENCY, stamp, tuple(row[name] for name, _ in variables)) for stamp, row in rows]
        path = tmp_path / "log"
        path.write_bytes(usd_bytes({FIXED_FREQUENCY: ("fixedFrequency", variables)}, records))
        return path

    no_accel = [(name, code) for name, code in STATE_VARIABLES if not name.startswith("stateEstimate.a")]
    conversion = convert(write(no_accel), crazyflie)
    np.testing.assert_allclose(np.degrees(conversion.log.columns["pitch"]), 2.0, atol=1e-3)
    assert "a from the rate of change of the logged velocity" in conversion.log.metadata["derived"]
    assert "ax" not in conversion.log.columns
    bare = [(name, code) for name, code in no_accel if not name.startswith("stateEstimate.v")]
    with pytest.raises(ConversionError, match="cannot be derived without stateEstimate.ax/ay/az or vx/vy/vz"):
        convert(write(bare), crazyflie)


def firmware_volts(command: np.ndarray) -> np.ndarray:
    """motors.c: the voltage the firmware gives a motor for a command (65536 <-> 60 g, its bench polyfit)."""
    thrust_g = command / 65536.0 * 60.0
    return -0.0006239 * thrust_g**2 + 0.088 * thrust_g


def test_the_rotor_command_is_the_voltage_the_motor_got_so_the_battery_counts_only_without_compensation(
    crazyflie, tmp_path
) -> None:
    """Thrust follows duty x battery voltage; the firmware's compensation makes it follow motor.m alone."""
    demanded = np.array([30000.0, 31000.0, 52000.0, 33000.0])
    variables = [*STATE_VARIABLES, *[(f"pwm.m{k}_pwm", "I") for k in range(1, 5)]]

    def convert_with(logged_motor, battery_mv: float):
        """A hover whose motors got the voltages of ``demanded``, duty = voltage / battery (at most 100 %)."""
        duty = np.minimum(firmware_volts(demanded) / (battery_mv * 1e-3), 1.0)
        pwm = np.floor(duty * 65535.0)
        records = [
            (
                stamp,
                (*(int(m) for m in logged_motor(pwm)), int(battery_mv), *values[5:], *(int(d) for d in pwm)),
            )
            for _, stamp, values in hover_records(100)
        ]
        path = tmp_path / "log"
        path.write_bytes(
            usd_bytes(
                {FIXED_FREQUENCY: ("fixedFrequency", variables)},
                [(FIXED_FREQUENCY, stamp, values) for stamp, values in records],
            )
        )
        return convert(path, crazyflie)

    # Compensation on (what CrazyPAD's firmware did): the duty follows the battery, u_k is motor.m.
    for battery_mv in (4100.0, 3400.0):
        conversion = convert_with(lambda pwm: demanded, battery_mv)
        u = np.column_stack([conversion.log.columns[f"u_{k}"] for k in range(1, 5)])
        np.testing.assert_allclose(u, np.broadcast_to(demanded / 65535.0, u.shape), atol=1e-4)
        assert "beyond 0.5% at 0 of 400 motor samples (0 at full duty)" in conversion.log.metadata["derived"]
        assert not any("not the voltage the motors got" in warning for warning in conversion.warnings)
    # Compensation off (motor.m is the duty): the same voltages, so the same u_k, whatever motor.m says.
    conversion = convert_with(lambda pwm: pwm, 4100.0)
    u = np.column_stack([conversion.log.columns[f"u_{k}"] for k in range(1, 5)])
    np.testing.assert_allclose(u, np.broadcast_to(demanded / 65535.0, u.shape), atol=1e-4)
    assert any("not the voltage the motors got at 100.0% of motor samples" in w for w in conversion.warnings)
    # A battery too low for M3's voltage: full duty, and u_3 the command of what the battery could give.
    conversion = convert_with(lambda pwm: demanded, 2600.0)
    assert "(100 at full duty)" in conversion.log.metadata["derived"]
    u_3 = conversion.log.columns["u_3"]
    assert np.all(u_3 < 0.98 * demanded[2] / 65535.0)
    np.testing.assert_allclose(firmware_volts(u_3 * 65535.0), 2.6, rtol=2e-4)
    np.testing.assert_allclose(conversion.log.columns["u_1"], demanded[0] / 65535.0, atol=1e-4)


def test_a_log_cut_short_is_read_up_to_its_last_whole_record_and_says_so(crazyflie, tmp_path) -> None:
    whole = usd_bytes({FIXED_FREQUENCY: ("fixedFrequency", STATE_VARIABLES)}, hover_records(100))
    path = tmp_path / "cut"
    path.write_bytes(whole[:-40])
    usd = read_usd_log(path)
    assert usd.events["fixedFrequency"].stamps_s.size == 99
    assert usd.warnings == [
        "truncated or damaged: the CRC-32 at the end does not match the content; "
        "the last 36 bytes (a partial record) are not read"
    ]
    conversion = convert(path, crazyflie)
    assert len(conversion.log) == 99 and conversion.warnings[0].startswith("truncated or damaged")


def test_damaged_headers_and_records_are_named_by_byte(crazyflie, tmp_path) -> None:
    path = tmp_path / "bad"
    good = usd_bytes({FIXED_FREQUENCY: ("fixedFrequency", STATE_VARIABLES)}, hover_records(10))
    path.write_bytes(good[:30])
    with pytest.raises(ConversionError, match=r"bad: byte 24: the file ends inside the header \(a variable"):
        read_usd_log(path)
    path.write_bytes(good.replace(b"motor.m2(I)", b"motor.m2(Z)"))
    with pytest.raises(ConversionError, match=r"variable 'motor.m2\(Z\)' of event 'fixedFrequency' is not"):
        read_usd_log(path)
    path.write_bytes(b"\xbc\x07\x00\x00\x00")
    with pytest.raises(ConversionError, match="byte 5: format version 7; versions 1 and 2 are known"):
        read_usd_log(path)
    header_end = good.index(b"yaw(f)\0") + len("yaw(f)\0")
    record_size = 10 + 4 * 4 + 2 + 11 * 4
    damaged = bytearray(good)
    damaged[header_end + 3 * record_size : header_end + 3 * record_size + 2] = b"\x05\x00"
    path.write_bytes(bytes(damaged))
    usd = read_usd_log(path)
    assert usd.events["fixedFrequency"].stamps_s.size == 3
    assert usd.warnings[0] == (
        f"record at byte {header_end + 3 * record_size} names event id 5, which the header does not declare: "
        f"the {len(good) - header_end - 3 * record_size} bytes from there are not read (the file is damaged)"
    )


def test_logs_without_position_attitude_or_motors_say_what_is_missing(crazyflie, tmp_path) -> None:
    path = tmp_path / "log"
    no_motors = [(name, code) for name, code in STATE_VARIABLES if not name.startswith("motor.")]
    records = [(FIXED_FREQUENCY, stamp, values[4:]) for _, stamp, values in hover_records(20)]
    path.write_bytes(usd_bytes({FIXED_FREQUENCY: ("fixedFrequency", no_motors)}, records))
    with pytest.raises(ConversionError, match=r"no motor commands \(motor.m1..m4 or pwm.m1_pwm..m4_pwm\)"):
        convert(path, crazyflie)
    only_motors = STATE_VARIABLES[:4]
    records = [(FIXED_FREQUENCY, stamp, values[:4]) for _, stamp, values in hover_records(20)]
    path.write_bytes(usd_bytes({FIXED_FREQUENCY: ("fixedFrequency", only_motors)}, records))
    with pytest.raises(
        ConversionError, match=r"no records with stateEstimate.x, .y and .z .*logged: motor.m1, motor.m2"
    ):
        convert(path, crazyflie)


@needs_crazypad
def test_every_crazypad_motor_flight_converts_and_its_rotor_commands_hold_the_vehicle_up(crazyflie) -> None:
    """The firmware's thrust map (this airframe's) on the logged commands balances 29-36 g in hover."""
    assert len(MOTOR_FLIGHTS) >= 30
    for path in MOTOR_FLIGHTS:
        log = convert(path, crazyflie).log
        hovering = (log.columns["z"] > 0.4) & (np.abs(log.columns["vz"]) < 0.05)
        omega = np.column_stack([log.columns[f"omega_{k}"] for k in range(1, 5)])[hovering]
        weight_g = np.median((crazyflie.k_f_N_s2 * omega**2).sum(axis=1)) / 9.81 * 1e3
        assert 29.0 < weight_g < 36.0, (path, weight_g)
        assert log.t[-1] > 20.0


CONTROLLER_VARIABLES = [
    *[(f"stateEstimate.{axis}", "f") for axis in "xyz"],
    *[(f"controller.cmd_{name}", "f") for name in ("thrust", "roll", "pitch", "yaw")],
    *[(f"controller.r_{name}", "f") for name in ("roll", "pitch", "yaw")],
    *[(f"controller.{name}", "f") for name in ("roll", "pitch", "yaw")],
]


def controller_records(n: int, outputs, gyro_rad_s, setpoint_deg, off: int = 0):
    """The PID controller's log: motors off (thrust 0) for the first ``off`` records, then ``outputs``."""
    records = []
    for i in range(n):
        thrust_roll_pitch_yaw = (0.0, 0.0, 0.0, 0.0) if i < off else outputs
        values = (0.0, 0.0, 0.5, *thrust_roll_pitch_yaw, *gyro_rad_s, *setpoint_deg)
        records.append((FIXED_FREQUENCY, 1_000_000 + 10_000 * i, values))
    return records


def test_a_controller_log_gets_the_firmware_mixer_s_motor_commands_and_a_derived_attitude(
    crazyflie, tmp_path
):
    """CrazyPAD's controller_data files: no motors, no attitude estimate; the firmware's mixer and gyro."""
    assert motor_commands_of_controller(np.array([[40000.0, 1001.0, -301.0, 250.0]])).tolist() == [
        [40000 - 500 - 150 + 250, 40000 - 500 + 150 - 250, 40000 + 500 + 150 + 250, 40000 + 500 - 150 - 250]
    ], "r = roll / 2 and p = pitch / 2 truncated as int16 (power_distribution_quadrotor.c)"
    capped = motor_commands_of_controller(np.array([[65000.0, 2000.0, 0.0, 0.0], [100.0, 0.0, 0.0, 400.0]]))
    assert capped.tolist() == [[63535, 63535, 65535, 65535], [500, 0, 500, 0]], (
        "all lowered by the excess, 0 floor"
    )

    path = tmp_path / "E9_log00"
    events = {FIXED_FREQUENCY: ("fixedFrequency", CONTROLLER_VARIABLES)}
    bias = (0.01, -0.02, 0.005)
    setpoint_deg = (2.0, -3.0, 10.0)  # controller.pitch has the legacy sign: our pitch is +3 deg
    path.write_bytes(
        usd_bytes(events, controller_records(500, (40000.0, 0.0, 0.0, 0.0), bias, setpoint_deg, off=50))
    )
    conversion = convert(path, crazyflie)
    log = conversion.log
    np.testing.assert_allclose(log.columns["u_1"][60:], 40000 / 65535)
    np.testing.assert_allclose(log.columns["u_1"][:50], 0.0)
    # A gyro that reads only its bias (seen with the motors off) turns nothing: the setpoints are kept.
    np.testing.assert_allclose(np.degrees(log.columns["roll"]), 2.0, atol=1e-9)
    np.testing.assert_allclose(np.degrees(log.columns["pitch"]), 3.0, atol=1e-9)
    np.testing.assert_allclose(np.degrees(log.columns["yaw"]), 10.0, atol=1e-9)
    np.testing.assert_allclose(log.columns["q"], 0.0, atol=1e-12)
    derived = log.metadata["derived"]
    assert "roll,pitch,yaw NOT LOGGED, derived: the controller's attitude setpoints" in derived
    assert (
        "gyro bias (+0.0100, +0.0200, +0.0050) rad/s, its mean over the 0.5 s with the motors off" in derived
    )
    assert "differs from the setpoints by 0.00, 0.00 and 0.00 deg RMS" in derived
    assert "rebuilt from controller.cmd_thrust/cmd_roll/cmd_pitch/cmd_yaw" in log.metadata["resampling"]
    assert any("the attitude is not logged" in warning for warning in conversion.warnings)
    assert not any("pwm.m" in warning for warning in conversion.warnings), "no duty cycle was taken"
    assert log.metadata["rotor_channels"].startswith("1,2,3,4 (motor.m1, motor.m2, motor.m3, motor.m4)")

    # A turn the setpoint does not follow yet: the gyro gives it at once, the setpoint wins within seconds.
    path.write_bytes(
        usd_bytes(events, controller_records(500, (40000.0, 0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (0.0, 0.0, 0.0)))
    )
    roll = np.degrees(convert(path, crazyflie).log.columns["roll"])
    assert 0.0 < roll[20] < roll[40] and roll[-1] == pytest.approx(np.degrees(0.5 * 0.5), rel=0.05)

    without_setpoints = [(name, code) for name, code in CONTROLLER_VARIABLES if name != "controller.yaw"]
    records = [
        (e, stamp, values[:-1])
        for e, stamp, values in controller_records(100, (40000.0, 0.0, 0.0, 0.0), bias, setpoint_deg)
    ]
    path.write_bytes(usd_bytes({FIXED_FREQUENCY: ("fixedFrequency", without_setpoints)}, records))
    with pytest.raises(
        ConversionError, match=r"nor the controller's gyro and attitude setpoints .*controller.yaw"
    ):
        convert(path, crazyflie)


def _relative_hover_commands(path: Path, airframe) -> np.ndarray:
    log = convert(path, airframe).log
    u = np.column_stack([log.columns[f"u_{k}"] for k in range(1, 5)])
    hovering = (log.columns["z"] > 0.2) & (u.min(axis=1) > 0.3)
    median = np.median(u[hovering], axis=0)
    return median / median.mean()


@needs_crazypad
def test_every_controller_flight_converts_and_its_rebuilt_commands_balance_as_the_motor_flights_do(
    crazyflie,
) -> None:
    """The mixer checked on the real vehicle, whose motors these files do not log.

    A controller_data flight needs the same share of the thrust from each rotor as one of the motor_data
    flights of its session and condition (other flights of the same vehicle; within a session the shares
    move by up to 0.06 between charges, so the nearest is the one to match).
    """
    controller_flights = sorted(CRAZYPAD.glob("controller_data/*/E*"))
    assert len(controller_flights) >= 29
    for path in controller_flights:
        condition, session = path.parent.name, path.name[:2]
        peers = sorted(CRAZYPAD.glob(f"motor_data/{condition}/{session}_*"))
        shares = _relative_hover_commands(path, crazyflie)
        if peers:
            nearest = min(np.abs(_relative_hover_commands(peer, crazyflie) - shares).max() for peer in peers)
            assert nearest < 0.02, (path, shares, nearest)


# The header of CrazyPAD's CSV files (data/motor_data/*/E*_log*.csv upstream): cfusdlog.py's decoding.
CRAZYPAD_CSV_HEADER = (
    "timestamp,motor.m1,motor.m2,motor.m3,motor.m4,pwm.m1_pwm,pwm.m2_pwm,pwm.m3_pwm,pwm.m4_pwm,pm.vbatMV,"
    "stateEstimate.x,stateEstimate.y,stateEstimate.z,stateEstimate.vx,stateEstimate.vy,stateEstimate.vz,"
    "stateEstimate.ax,stateEstimate.ay,stateEstimate.az,stateEstimate.roll,stateEstimate.yaw"
)


def csv_export(binary: Path, out: Path) -> Path:
    """The flight as CrazyPAD's CSV files hold it: timestamp [ms] from the first record, the variables."""
    event = read_usd_log(binary).event_with("stateEstimate.x")
    assert event is not None
    stamps_ms = (event.stamps_s - event.stamps_s[0]) * 1e3
    rows = [
        ",".join(repr(float(v)) for v in (t, *values))
        for t, values in zip(stamps_ms, event.values, strict=True)
    ]
    out.write_text(",".join(("timestamp", *event.variables)) + "\n" + "\n".join(rows) + "\n")
    return out


@needs_crazypad
def test_a_flight_exported_as_csv_converts_as_its_binary_log_does(crazyflie, tmp_path) -> None:
    for binary in (
        CRAZYPAD / "motor_data" / "normal_flight" / "E9_log00",
        CRAZYPAD / "controller_data" / "cut_propeller_M3_3mm" / "E8_log00",
    ):
        exported = csv_export(binary, tmp_path / f"{binary.name}.csv")
        if binary.parent.parent.name == "motor_data":
            assert exported.read_text().split("\n", 1)[0] == CRAZYPAD_CSV_HEADER
        assert detect_format(exported) == "crazyflie-usd"
        from_binary, from_csv = convert(binary, crazyflie).log, convert(exported, crazyflie).log
        np.testing.assert_allclose(from_csv.t, from_binary.t, atol=1e-9)
        assert from_csv.columns.keys() == from_binary.columns.keys()
        for name, column in from_binary.columns.items():
            np.testing.assert_allclose(from_csv.columns[name], column, rtol=1e-9, atol=1e-12, err_msg=name)
        assert from_csv.metadata["converted_from"].endswith(
            "(CSV export of a Bitcraze usd log (timestamp in ms))"
        )


def test_a_damaged_csv_export_is_refused_with_line_and_column(crazyflie, tmp_path) -> None:
    path = tmp_path / "log.csv"
    good_row = "0.0," + ",".join(["1.0"] * 20)
    path.write_text(
        CRAZYPAD_CSV_HEADER + "\n" + good_row + "\n" + good_row.replace("0.0,", "10.0,", 1) + ",7\n"
    )
    with pytest.raises(ConversionError, match=r"log.csv:3: 22 cells, the header has 21"):
        convert(path, crazyflie)
    path.write_text(
        CRAZYPAD_CSV_HEADER + "\n" + good_row + "\n" + good_row.replace(",1.0", ",nope", 3) + "\n"
    )
    with pytest.raises(ConversionError, match=r"log.csv:3: column 'motor.m1': not a number: 'nope'"):
        convert(path, crazyflie)
    microseconds = "\n".join(f"{k * 10_000}.0," + ",".join(["1.0"] * 20) for k in range(5))
    path.write_text(CRAZYPAD_CSV_HEADER + "\n" + microseconds + "\n")
    with pytest.raises(
        ConversionError, match=r"column timestamp: median step 10000 between records; it is read in ms"
    ):
        convert(path, crazyflie)
