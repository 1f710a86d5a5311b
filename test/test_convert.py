"""`multirotor convert`: rosbag2 and dataflash written here, PX4 ULog and ddd-csv from real files."""

import argparse
import csv
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from multirotor_ros.cli import CommandError
from multirotor_ros.cli import convert as convert_command
from multirotor_ros.cli import main as multirotor_main
from multirotor_ros.io.convert import convert, detect_format
from multirotor_ros.io.derive import derive_motion
from multirotor_ros.io.flight_log import FlightLog, read_flight_log, write_flight_log
from multirotor_ros.io.log_builder import ConversionError
from multirotor_ros.io.rotor_channels import (
    RotorChannelError,
    match_layout,
    motor_channels_from_parameters,
    parse_rotor_channels,
    resolve_rotor_channels,
)
from multirotor_ros.model.airframe import Airframe, load_airframe
from multirotor_ros.model.rotation import euler_to_quat, quat_to_matrix

REAL_LOGS = Path(__file__).resolve().parents[2] / "shared" / "data" / "real_logs"
if not REAL_LOGS.is_dir():  # CI clones main with shared/ beside it
    REAL_LOGS = Path("/work/shared/data/real_logs")
ULOG = REAL_LOGS / "sample_log_small.ulg"
DDD_CSV = REAL_LOGS / "quadrotor_model.csv"
needs_real_logs = pytest.mark.skipif(
    not ULOG.is_file(), reason="shared/data/real_logs is not beside the repository"
)


@pytest.fixture(scope="module")
def quad_x():
    return load_airframe("quad_x")


# ---------------------------------------------------------------------------------------------
# Rotor channels


def test_rotor_channel_option_is_checked() -> None:
    assert parse_rotor_channels("1,4,2,3", 4) == [1, 4, 2, 3]
    for text, words in (
        ("1,2,3", "3 channels for 4"),
        ("1,2,2,3", "twice"),
        ("0,1,2,3", "from 1"),
        ("a,b", "comma"),
    ):
        with pytest.raises(RotorChannelError, match=words):
            parse_rotor_channels(text, 4)


def test_airframes_match_the_flight_stack_motor_orders() -> None:
    layout, motors = match_layout(load_airframe("quad_x"))
    assert layout.name.startswith("quad X") and motors == [1, 4, 2, 3]
    layout, motors = match_layout(load_airframe("hexarotor_f550"))
    assert layout.name.startswith("hexa X") and motors == [5, 1, 4, 6, 2, 3]
    assert match_layout(load_airframe("x8_octorotor")) is None  # coaxial: --rotor-channels needed


def test_motor_channels_come_from_the_log_parameters() -> None:
    assert motor_channels_from_parameters({"VT_MOT_ID": 5678}, 4)[0] == {1: 5, 2: 6, 3: 7, 4: 8}
    servo = {f"SERVO{c}_FUNCTION": 32 + m for c, m in ((9, 1), (10, 2), (11, 3), (12, 4))}
    assert motor_channels_from_parameters(servo, 4) == (
        {1: 9, 2: 10, 3: 11, 4: 12},
        "ArduPilot SERVOn_FUNCTION",
    )
    px4 = {f"PWM_MAIN_FUNC{c}": 100 + m for c, m in ((1, 2), (2, 1), (3, 4), (4, 3))}
    assert motor_channels_from_parameters(px4, 4)[0] == {2: 1, 1: 2, 4: 3, 3: 4}
    assert motor_channels_from_parameters({}, 4)[0] == {1: 1, 2: 2, 3: 3, 4: 4}


def test_resolved_channels_and_note(quad_x) -> None:
    channels, note = resolve_rotor_channels(quad_x, None, {}, 4, ["u0", "u1", "u2", "u3"])
    assert channels == [1, 4, 2, 3] and note.startswith("1,4,2,3 (u0, u3, u1, u2); quad X")
    assert resolve_rotor_channels(quad_x, "4,3,2,1", None, 4)[1] == "4,3,2,1; given with --rotor-channels"
    with pytest.raises(RotorChannelError, match="only 4 channels"):
        resolve_rotor_channels(quad_x, "5,6,7,8", None, 4)
    with pytest.raises(RotorChannelError, match="--rotor-channels"):
        resolve_rotor_channels(load_airframe("x8_octorotor"), None, {}, 14)


# ---------------------------------------------------------------------------------------------
# PX4 ULog (real log: a VTOL, mostly on the ground; its lift motors are on MAIN 5-8)


@needs_real_logs
def test_ulog_frames_channels_and_metadata(quad_x, tmp_path: Path) -> None:
    from pyulog import ULog

    conversion = convert(ULOG, quad_x)
    log = conversion.log
    assert conversion.format == "ulog" and conversion.warnings == []
    raw = ULog(str(ULOG), ["vehicle_local_position", "actuator_outputs"])
    position = raw.get_dataset("vehicle_local_position").data
    assert len(log) == position["timestamp"].size and log.t[0] == 0.0
    # ENU z is up: the EKF's NED z of about -1.2 m becomes +1.2 m; x, y are empty because xy_valid = 0.
    # (This z is the EKF settling on the ground, not a hop: the land detector says landed, the
    # barometer is flat and vz does not match dz/dt; the test checks the frames, not the flight.)
    assert np.allclose(log.column("z"), -position["z"])
    assert 1.0 < np.nanmax(log.column("z")) < 1.3
    assert np.all(np.isnan(log.column("x"))) and "xy_valid = 0" in log.metadata["empty_x_y"]
    assert np.allclose(log.column("vz"), -position["vz"])
    assert np.allclose(
        log.group("acceleration"), np.column_stack([position["ay"], position["ax"], -position["az"]])
    )
    # On the ground, level, heading ~2 degrees east of north: ENU yaw = 90 deg - NED heading.
    yaw = log.column("yaw")[2:]
    assert np.allclose(yaw, np.pi / 2 - position["heading"][2:], atol=0.01)
    assert np.nanmax(np.abs(log.euler()[:, :2])) < 0.05
    assert 9.4 < np.nanmedian(log.column("imu_fz")) < 9.9  # specific force points up in FLU at rest
    # VT_MOT_ID = 5678 and PX4's quad X order give our rotors 1..4 on MAIN 5, 8, 6, 7.
    assert log.metadata["rotor_channels"].startswith("5,8,6,7; quad X")
    outputs = raw.get_dataset("actuator_outputs").data
    first_held = np.searchsorted(outputs["timestamp"], position["timestamp"][0], side="right") - 1
    assert log.column("u_2")[0] == outputs["output[7]"][first_held]
    assert log.metadata["actuator_unit"] == "pwm_us" and "motor map" in log.metadata["omega_source"]
    assert np.all((log.rotor_speeds() >= 0) & (log.rotor_speeds() <= 1100))
    assert (
        "MAV_TYPE 22" in log.metadata["converted_from"] and "vehicle_attitude" in log.metadata["resampling"]
    )
    write_flight_log(tmp_path / "ulog.csv", log)
    assert len(read_flight_log(tmp_path / "ulog.csv", n_rotors=4)) == len(log)


@needs_real_logs
def test_ulog_landed_state_is_kept_as_the_land_detector_says(quad_x) -> None:
    from pyulog import ULog

    log = convert(ULOG, quad_x).log
    land = ULog(str(ULOG), ["vehicle_land_detected"]).get_dataset("vehicle_land_detected").data
    landed = log.column("landed")
    assert set(np.unique(landed)) == {0.0, 1.0} and "land detector" in log.metadata["landed_column"]
    # Held from each message to the next: as many changes as the detector's messages have.
    assert np.count_nonzero(np.diff(landed)) == np.count_nonzero(np.diff(land["landed"].astype(float)))


@needs_real_logs
def test_a_truncated_ulog_is_named_truncated_and_converted_up_to_where_it_ends(quad_x, tmp_path) -> None:
    raw = ULOG.read_bytes()
    half = tmp_path / "half.ulg"
    half.write_bytes(raw[: len(raw) // 2])
    conversion = convert(half, quad_x)
    assert 0 < len(conversion.log) < len(convert(ULOG, quad_x).log)
    (truncated,) = [w for w in conversion.warnings if w.startswith("truncated")]
    assert "inside a message" in truncated and "converted up to t =" in truncated
    early = tmp_path / "early.ulg"  # cut inside the definitions: no data at all
    early.write_bytes(raw[: len(raw) // 20])
    with pytest.raises(ConversionError, match="truncated: .* before any vehicle_local_position"):
        convert(early, quad_x)
    empty = tmp_path / "empty.ulg"
    empty.write_bytes(raw[:10])
    with pytest.raises(ConversionError, match="shorter than a ULog's 16-byte header"):
        convert(empty, quad_x, fmt="ulog")


@needs_real_logs
def test_ulog_options(quad_x) -> None:
    log = convert(ULOG, quad_x, rotor_channels="1,2,3,4").log
    assert log.metadata["rotor_channels"].startswith("1,2,3,4; given with --rotor-channels")
    with pytest.raises(ConversionError, match="only 4 channels"):
        convert(ULOG, quad_x, actuator_instance=1, rotor_channels="5,6,7,8")
    with pytest.raises(ConversionError, match="no actuator_outputs \\(instance 5\\)"):
        convert(ULOG, quad_x, actuator_instance=5)
    with pytest.raises(ConversionError, match="rosbag2 only"):
        convert(ULOG, quad_x, namespace="/uav1")


# ---------------------------------------------------------------------------------------------
# data-driven-dynamics CSV (real log)


@needs_real_logs
def test_ddd_csv_world_frames_and_gravity_removed(quad_x) -> None:
    conversion = convert(DDD_CSV, quad_x)
    log = conversion.log
    assert conversion.format == "ddd-csv" and len(log) == 5564
    with DDD_CSV.open(newline="") as stream:
        rows = list(csv.reader(stream))
    raw = {name: np.array([float(row[i]) for row in rows[1:]]) for i, name in enumerate(rows[0]) if name}
    # Velocity: world NED -> ENU.
    assert np.allclose(log.group("velocity"), np.column_stack([raw["vy"], raw["vx"], -raw["vz"]]))
    # Gravity removed: the world acceleration averages ~0 (not -9.8) and is what the velocity does.
    acceleration = log.group("acceleration")
    assert np.all(np.abs(acceleration.mean(axis=0)) < 0.15)
    assert np.all(np.linalg.norm(acceleration[:20], axis=1) < 0.1)  # the first 0.2 s: hovering
    velocity_only = {name: values for name, values in log.columns.items() if name not in ("ax", "ay", "az")}
    dv = derive_motion(FlightLog(log.t, velocity_only)).acceleration
    for axis in range(3):
        assert np.corrcoef(dv[:, axis], acceleration[:, axis])[0, 1] > 0.99
    # Attitude: the vehicle starts level, facing east (NED yaw 90 deg -> ENU yaw 0).
    assert np.allclose(log.euler()[0], [0.0, 0.0, 0.0], atol=0.01)
    # Rotors: u0..u3 are PX4 quad X motors 1..4; ours are 1 FR = u0, 2 RR = u3, 3 RL = u1, 4 FL = u2.
    for k, source in ((1, "u0"), (2, "u3"), (3, "u1"), (4, "u2")):
        assert np.array_equal(log.column(f"u_{k}"), raw[source])
    speeds = log.rotor_speeds()
    motor_map = quad_x.motor_map
    assert np.all(speeds >= motor_map.speed_from_command(1500.0)) and np.all(
        speeds <= motor_map.speed_from_command(1900.0)
    )
    assert log.metadata["derived"].startswith("vx,vy,vz: world NED velocity -> ENU")
    assert "p_dot" in log.columns and "old_index" not in log.columns


# ---------------------------------------------------------------------------------------------
# rosbag2, written here with rosbags in both storage formats


def _write_bag(
    path: Path, storage: str, namespace: str = "/uav1", extra_namespace: str | None = None
) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types = store.types
    Header, Time = types["std_msgs/msg/Header"], types["builtin_interfaces/msg/Time"]
    Point, Quaternion, Vector3 = (types[f"geometry_msgs/msg/{n}"] for n in ("Point", "Quaternion", "Vector3"))
    Pose, Twist = types["geometry_msgs/msg/Pose"], types["geometry_msgs/msg/Twist"]
    PoseCov, TwistCov = (
        types["geometry_msgs/msg/PoseWithCovariance"],
        types["geometry_msgs/msg/TwistWithCovariance"],
    )
    Odometry, JointState = types["nav_msgs/msg/Odometry"], types["sensor_msgs/msg/JointState"]
    Imu, Range = types["sensor_msgs/msg/Imu"], types["sensor_msgs/msg/Range"]
    t0 = 1000.0

    def header(t: float) -> object:
        sec = math.floor(t0 + t)
        return Header(stamp=Time(sec=sec, nanosec=round((t0 + t - sec) * 1e9)), frame_id="odom")

    def joints(t: float, values: list[float], names: list[str]) -> object:
        return JointState(
            header=header(t), name=names, position=np.zeros(0), velocity=np.array(values), effort=np.zeros(0)
        )

    cov = np.zeros(36)
    namespaces = [namespace] + ([extra_namespace] if extra_namespace else [])
    topic_types = {
        "odom": Odometry.__msgtype__,
        "motor_speeds": JointState.__msgtype__,
        "motor_speed_cmd": JointState.__msgtype__,
        "imu": Imu.__msgtype__,
        "range": Range.__msgtype__,
    }
    with Writer(path, version=9, storage_plugin=StoragePlugin[storage.upper()]) as writer:
        connections = {
            f"{ns}/{name}": writer.add_connection(f"{ns}/{name}", msgtype, typestore=store)
            for ns in namespaces
            for name, msgtype in topic_types.items()
        }

        def write(topic: str, t: float, message: object) -> None:
            data = store.serialize_cdr(message, message.__msgtype__)
            writer.write(connections[topic], round((t0 + t) * 1e9), data)

        for ns in namespaces:
            for i in range(200):  # odom and imu at 100 Hz
                t = i * 0.01
                q = euler_to_quat([0.1, -0.05, 0.5 * t])
                v_body = quat_to_matrix(q).T @ np.array([-math.sin(t), math.cos(t), 0.1])
                pose = Pose(
                    position=Point(x=math.cos(t), y=math.sin(t), z=1 + 0.1 * t),
                    orientation=Quaternion(x=q[1], y=q[2], z=q[3], w=q[0]),
                )
                twist = Twist(
                    linear=Vector3(x=v_body[0], y=v_body[1], z=v_body[2]),
                    angular=Vector3(x=0.01, y=0.02, z=0.5),
                )
                odom = Odometry(
                    header=header(t),
                    child_frame_id="base_link",
                    pose=PoseCov(pose=pose, covariance=cov),
                    twist=TwistCov(twist=twist, covariance=cov),
                )
                write(f"{ns}/odom", t, odom)
                imu = Imu(
                    header=header(t),
                    orientation=pose.orientation,
                    orientation_covariance=np.zeros(9),
                    angular_velocity=Vector3(x=0.011, y=0.021, z=0.51),
                    angular_velocity_covariance=np.zeros(9),
                    linear_acceleration=Vector3(x=0.0, y=0.0, z=9.81),
                    linear_acceleration_covariance=np.zeros(9),
                )
                write(f"{ns}/imu", t, imu)
            names = [f"rotor_{k}" for k in range(1, 5)]
            for i in range(100):  # measured speeds at 50 Hz, half the messages with the names reversed
                t = 0.005 + i * 0.02
                values = [400 + 10 * k + 20 * t for k in range(1, 5)]
                write(
                    f"{ns}/motor_speeds",
                    t,
                    joints(t, values[::-1], names[::-1]) if i % 2 else joints(t, values, names),
                )
            write(f"{ns}/motor_speeds", 0.006, joints(0.006, [1.0, 2.0, 3.0], names[:3]))  # refused: 3 rotors
            for i in range(50):  # commands at 25 Hz
                t = i * 0.04
                write(f"{ns}/motor_speed_cmd", t, joints(t, [500.0 + i + k for k in range(1, 5)], names))
            for i in range(40):  # range at 20 Hz
                t = i * 0.05
                ranged = Range(
                    header=header(t),
                    radiation_type=0,
                    field_of_view=0.5,
                    min_range=0.1,
                    max_range=4.0,
                    range=1 + 0.1 * t,
                    variance=0.0,
                )
                write(f"{ns}/range", t, ranged)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_rosbag2_topics_frames_and_resampling(quad_x, tmp_path: Path, storage: str) -> None:
    bag = tmp_path / "run1"
    _write_bag(bag, storage)
    assert detect_format(bag) == "rosbag2"
    conversion = convert(bag, quad_x)  # the only namespace, /uav1, is found
    log = conversion.log
    t = log.t
    assert len(log) == 200 and t[0] == 0.0 and np.allclose(np.diff(t), 0.01)
    assert np.allclose(log.group("position"), np.column_stack([np.cos(t), np.sin(t), 1 + 0.1 * t]))
    # Odometry twist is body FLU; the log has world velocity.
    assert np.allclose(
        log.group("velocity"), np.column_stack([-np.sin(t), np.cos(t), np.full_like(t, 0.1)]), atol=1e-9
    )
    assert np.allclose(log.euler(), np.column_stack([np.full_like(t, 0.1), np.full_like(t, -0.05), 0.5 * t]))
    assert np.allclose(log.column("r"), 0.5) and np.allclose(log.column("imu_r"), 0.51)
    # Measured speeds: linear interpolation (exact for this ramp), empty outside their samples.
    speeds = log.rotor_speeds()
    assert np.all(np.isnan(speeds[[0, -1]]))
    expected = 400 + 10 * np.arange(1, 5)[None, :] + 20 * t[:, None]
    assert np.allclose(speeds[1:-1], expected[1:-1])
    # Commands are held: at t = 0.05 the latest command is the one of t = 0.04.
    assert log.column("omega_cmd_3")[5] == 500.0 + 1 + 3
    assert np.allclose(log.column("range")[:196], 1 + 0.1 * t[:196]) and np.all(
        np.isnan(log.column("range")[196:])
    )
    assert conversion.warnings == [
        "/uav1/motor_speeds: 1 messages skipped (names must be rotor_1..rotor_4, one velocity each)"
    ]
    assert log.metadata["namespace"] == "/uav1" and log.metadata["omega_source"].startswith("measured")
    assert "motor_speeds (50 Hz) by linear interpolation" in log.metadata["resampling"]
    assert "motor_speed_cmd (25 Hz) by zero-order hold" in log.metadata["resampling"]
    path = tmp_path / "run1.csv"
    write_flight_log(path, log)
    assert len(read_flight_log(path, n_rotors=4)) == 200


def test_rosbag2_namespaces(quad_x, tmp_path: Path) -> None:
    two = tmp_path / "two"
    _write_bag(two, "mcap", namespace="/uav1", extra_namespace="/uav2")
    with pytest.raises(ConversionError, match="several vehicles in the bag \\(/uav1, /uav2\\)"):
        convert(two, quad_x)
    assert convert(two, quad_x, namespace="uav2").log.metadata["namespace"] == "/uav2"
    with pytest.raises(ConversionError, match="no /uav3/odom or /uav3/pose"):
        convert(two, quad_x, namespace="/uav3/")
    root = tmp_path / "root"
    _write_bag(root, "sqlite3", namespace="")
    assert convert(next(root.glob("*.db3")), quad_x).log.metadata["namespace"] == "/"
    with pytest.raises(ConversionError, match="motor_speeds names its rotors"):
        convert(root, quad_x, rotor_channels="1,2,3,4")
    with pytest.raises(ConversionError, match="not a rosbag2 directory"):
        convert(tmp_path, quad_x, fmt="rosbag2")


# ---------------------------------------------------------------------------------------------
# ArduPilot dataflash, written here: FMT records describe each message, then the messages follow.

_STRUCT = {
    "Q": "Q",
    "h": "h",
    "B": "B",
    "c": "h",
    "C": "H",
    "f": "f",
    "H": "H",
    "I": "I",
    "N": "16s",
    "Z": "64s",
    "L": "i",
    "e": "i",
}
_SCALE = {"c": 100, "C": 100, "L": 1e7, "e": 100}
_DATAFLASH_FORMATS = {
    "XKF1": (130, "QBccCfffffffccce", "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH"),
    "POS": (131, "QLLfff", "TimeUS,Lat,Lng,Alt,RelHomeAlt,RelOriginAlt"),
    "ATT": (132, "QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF"),
    "IMU": (133, "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
    "RCOU": (134, "Q" + "H" * 14, "TimeUS," + ",".join(f"C{i}" for i in range(1, 15))),
    "PARM": (135, "QNf", "TimeUS,Name,Value"),
    "MSG": (136, "QZ", "TimeUS,Message"),
}


# ArduCopter 3.2 (2014; DataFlash/LogStructure.h and ArduCopter/Log.pde of that release): the first EKF,
# a millisecond clock, RCOU Ch1..Ch12, an IMU per instance with no instance field, PARM without a time.
_DATAFLASH_2014_FORMATS = {
    "EKF1": (140, "IccCffffffccc", "TimeMS,Roll,Pitch,Yaw,VN,VE,VD,PN,PE,PD,GX,GY,GZ"),
    "ATT": (1, "IccccCC", "TimeMS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw"),
    "IMU": (131, "IffffffII", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA"),
    "RCOU": (134, "I" + "h" * 12, "TimeMS," + ",".join(f"Ch{i}" for i in range(1, 13))),
    "PARM": (129, "Nf", "Name,Value"),
    "MSG": (132, "Z", "Message"),
}


def _write_dataflash(
    path: Path,
    messages: list[tuple[str, dict]],
    formats: dict[str, tuple[int, str, str]] = _DATAFLASH_FORMATS,
) -> None:
    data = bytearray()
    for name, (type_id, fmt, labels) in formats.items():
        length = 3 + struct.calcsize("<" + "".join(_STRUCT[c] for c in fmt))
        data += b"\xa3\x95\x80" + struct.pack(
            "<BB4s16s64s", type_id, length, name.encode(), fmt.encode(), labels.encode()
        )
    for name, fields in messages:
        type_id, fmt, labels = formats[name]
        values = []
        for code, label in zip(fmt, labels.split(","), strict=True):
            value = fields.get(label, 0)
            values.append(
                value.encode()
                if isinstance(value, str)
                else round(value * _SCALE[code])
                if code in _SCALE
                else value
            )
        data += b"\xa3\x95" + bytes([type_id]) + struct.pack("<" + "".join(_STRUCT[c] for c in fmt), *values)
    path.write_bytes(bytes(data))


def _dataflash_flight(with_ekf: bool = True) -> list[tuple[str, dict]]:
    messages: list[tuple[str, dict]] = [("MSG", {"Message": "ArduCopter V4.5.7 (test)"})]
    # Motors 1..4 on SERVO5..8, as a quad that uses outputs 1-4 for something else would have them.
    messages += [("PARM", {"Name": f"SERVO{5 + m}_FUNCTION", "Value": 33 + m}) for m in range(4)]
    for i in range(100):
        us = 1_000_000 + i * 10_000
        t = i * 0.01
        if with_ekf:
            messages.append(
                (
                    "XKF1",
                    {"TimeUS": us, "C": 0, "PN": t, "PE": 2 * t, "PD": -3.0, "VN": 1.0, "VE": 2.0, "VD": 0.5},
                )
            )
            messages.append(("XKF1", {"TimeUS": us, "C": 1, "PN": 99.0, "VN": 99.0}))  # second core: ignored
        else:
            messages.append(("POS", {"TimeUS": us, "Lat": 47.0 + 1e-5 * i, "Lng": 8.0, "Alt": 400.0 + t}))
        messages.append(("ATT", {"TimeUS": us + 2000, "Roll": 10.0, "Pitch": 5.0, "Yaw": 90.0}))
        messages.append(
            ("IMU", {"TimeUS": us + 1000, "I": 0, "GyrX": 0.1, "GyrY": 0.2, "GyrZ": 0.3, "AccZ": -9.81})
        )
        messages.append(("IMU", {"TimeUS": us + 1000, "I": 1, "GyrX": 5.0}))  # second IMU: ignored
        if i % 4 == 0:
            messages.append(("RCOU", {"TimeUS": us, **{f"C{c}": 1000 + 100 * c for c in range(1, 15)}}))
    return messages


def _converts_the_test_flight(path: Path, quad_x: Airframe) -> FlightLog:
    """The flight of _dataflash_flight, however its generation of log spells it, converted right."""
    conversion = convert(path, quad_x)
    log = conversion.log
    assert len(log) == 100 and conversion.warnings == []
    t = log.t
    assert np.allclose(log.group("position"), np.column_stack([2 * t, t, np.full_like(t, 3.0)]), atol=1e-6)
    assert np.allclose(log.group("velocity"), [2.0, 1.0, -0.5])
    # NED/FRD Euler (10, 5, 90) deg is ENU/FLU (10, -5, 0) deg; ATT starts 2 ms after the time base.
    assert np.all(np.isnan(log.euler()[0])) and np.allclose(
        np.degrees(log.euler()[1:]), [10.0, -5.0, 0.0], atol=1e-6
    )
    assert np.allclose(np.column_stack([log.column(n) for n in ("p", "q", "r")])[1:], [0.1, -0.2, -0.3])
    assert np.allclose(log.column("imu_fz")[1:], 9.81, atol=1e-5)
    return log


def test_dataflash_frames_channels_and_metadata(quad_x, tmp_path: Path) -> None:
    path = tmp_path / "flight.bin"
    _write_dataflash(path, _dataflash_flight())
    assert detect_format(path) == "dataflash"
    log = _converts_the_test_flight(path, quad_x)
    # SERVO5..8 carry motors 1..4; PX4/ArduPilot quad X order -> our rotors on channels 5, 8, 6, 7.
    assert (
        log.metadata["rotor_channels"].startswith("5,8,6,7; quad X")
        and "SERVOn_FUNCTION" in log.metadata["rotor_channels"]
    )
    assert np.allclose(log.group("actuators"), [1500.0, 1800.0, 1600.0, 1700.0])
    assert np.allclose(
        log.rotor_speeds(), quad_x.motor_map.speed_from_command(np.array([1500.0, 1800.0, 1600.0, 1700.0]))
    )
    assert "ArduCopter V4.5.7" in log.metadata["converted_from"]
    assert "RCOU (25 Hz) by zero-order hold" in log.metadata["resampling"]


@pytest.mark.parametrize("prefix, channels", [("Ch", 12), ("Chan", 8)])  # ArduCopter 3.2, and before
def test_a_2014_arducopter_log_converts_like_todays(
    quad_x, tmp_path: Path, prefix: str, channels: int
) -> None:
    """EKF1 for XKF1, TimeMS for TimeUS, RCOU Ch1.. for C1..: the same flight comes out the same."""
    formats = dict(_DATAFLASH_2014_FORMATS)
    labels = "TimeMS," + ",".join(f"{prefix}{i}" for i in range(1, channels + 1))
    formats["RCOU"] = (134, "I" + "h" * channels, labels)
    messages: list[tuple[str, dict]] = [("MSG", {"Message": "ArduCopter V3.2.1 (36b405fb)"})]
    for i in range(100):
        ms, t = 1_000 + 10 * i, i * 0.01
        messages += [
            ("EKF1", {"TimeMS": ms, "PN": t, "PE": 2 * t, "PD": -3.0, "VN": 1.0, "VE": 2.0, "VD": 0.5}),
            ("ATT", {"TimeMS": ms + 2, "Roll": 10.0, "Pitch": 5.0, "Yaw": 90.0}),
            ("IMU", {"TimeMS": ms + 1, "GyrX": 0.1, "GyrY": 0.2, "GyrZ": 0.3, "AccZ": -9.81}),
        ]
        if i % 4 == 0:  # motors 1..4 on outputs 1..4, as ArduCopter 3.2 always had them
            pulses = {f"{prefix}{c}": 1000 + 100 * c for c in range(1, channels + 1)}
            messages.append(("RCOU", {"TimeMS": ms, **pulses}))
    path = tmp_path / "2014.bin"
    _write_dataflash(path, messages, formats)
    log = _converts_the_test_flight(path, quad_x)
    # Quad X: our rotors 1..4 are ArduCopter's motors 1, 4, 2, 3, on outputs 1, 4, 2, 3.
    assert log.metadata["rotor_channels"].startswith("1,4,2,3; quad X")
    assert np.allclose(log.group("actuators"), [1100.0, 1400.0, 1200.0, 1300.0])
    assert f"RCOU {prefix}n" in log.metadata["rotor_channels"] and "EKF1" in log.metadata["derived"]
    assert "ArduCopter V3.2.1" in log.metadata["converted_from"]


def test_a_dataflash_log_without_any_position_says_what_it_has_and_what_would_do(quad_x, tmp_path):
    path = tmp_path / "attitude_only.bin"
    _write_dataflash(path, [m for m in _dataflash_flight() if m[0] != "XKF1"])
    with pytest.raises(ConversionError) as refused:
        convert(path, quad_x)
    message = str(refused.value)
    assert "none of the EKF messages XKF1, NKF1, EKF1 nor POS" in message
    assert "it has ATT, IMU, MSG, PARM, RCOU" in message and "LOG_BITMASK" in message


def test_dataflash_position_from_pos_and_missing_messages(quad_x, tmp_path: Path) -> None:
    path = tmp_path / "gps.bin"
    _write_dataflash(path, _dataflash_flight(with_ekf=False))
    log = convert(path, quad_x).log
    assert not log.has_group("velocity")
    north_per_step = math.radians(1e-5) * 6_371_000.0
    assert np.allclose(log.column("y"), north_per_step * np.arange(100), atol=1e-3)
    assert np.allclose(log.column("x"), 0.0) and np.allclose(log.column("z"), log.t, atol=1e-4)
    assert log.metadata["derived"].startswith("x,y,z: POS")
    no_attitude = tmp_path / "no_att.bin"
    _write_dataflash(no_attitude, [m for m in _dataflash_flight() if m[0] != "ATT"])
    with pytest.raises(ConversionError, match="no ATT messages"):
        convert(no_attitude, quad_x)
    no_outputs = tmp_path / "no_rcou.bin"
    _write_dataflash(no_outputs, [m for m in _dataflash_flight() if m[0] != "RCOU"])
    with pytest.raises(ConversionError, match="no RCOU"):
        convert(no_outputs, quad_x)


# ---------------------------------------------------------------------------------------------
# Format detection and the command line


def test_format_detection(tmp_path: Path) -> None:
    flight_log = tmp_path / "log.csv"
    flight_log.write_text("# source: test\nt,roll,pitch,yaw\n")
    with pytest.raises(ConversionError, match="already a flight log"):
        detect_format(flight_log)
    other = tmp_path / "other.txt"
    other.write_text("hello\n")
    with pytest.raises(ConversionError, match="unknown format"):
        detect_format(other)
    with pytest.raises(ConversionError, match="no such file"):
        convert(tmp_path / "absent.ulg", load_airframe("quad_x"))


def _run_cli(*argv: str) -> int:
    parser = argparse.ArgumentParser()
    convert_command.configure(parser)
    return convert_command.run(parser.parse_args(list(argv)))


def test_cli_writes_a_readable_log(tmp_path: Path, capsys) -> None:
    path = tmp_path / "flight.bin"
    _write_dataflash(path, _dataflash_flight())
    out = tmp_path / "flight.csv"
    assert _run_cli(str(path), "--airframe", "quad_x", "--out", str(out), "--rotor-channels", "1,2,3,4") == 0
    assert f"wrote {out}: 100 rows" in capsys.readouterr().out
    log = read_flight_log(out, n_rotors=4)
    assert log.metadata["rotor_channels"].startswith("1,2,3,4; given")
    assert list(log.metadata)[:3] == ["source", "converted_from", "airframe"]


def test_cli_user_errors(tmp_path: Path) -> None:
    path = tmp_path / "flight.bin"
    _write_dataflash(path, _dataflash_flight())
    out = str(tmp_path / "out.csv")
    for argv, words in (
        (["--airframe", "quad_x", "--rotor-channels", "1,2,3"], "3 channels for 4 rotors"),
        (["--airframe", "no_such_frame"], "unknown airframe"),
        (["--airframe", "quad_x", "--namespace", "/uav1"], "rosbag2 only"),
        (["--airframe", "quad_x", "--actuator-instance", "1"], "ULog only"),
        (["--airframe", "x8_octorotor"], "give --rotor-channels"),
    ):
        with pytest.raises(CommandError, match=words):
            _run_cli(str(path), *argv, "--out", out)
    with pytest.raises(CommandError, match="is the input file"):
        _run_cli(str(path), "--airframe", "quad_x", "--out", str(path))


def test_cli_help_explains_formats_and_rotor_numbering(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as exited:
        multirotor_main(["convert", "--help"])
    assert exited.value.code == 0
    text = capsys.readouterr().out
    for words in (
        "rosbag2",
        "ulog",
        "dataflash",
        "ddd-csv",
        "--rotor-channels 1,4,2,3",
        "zero-order hold",
        "--namespace",
    ):
        assert words in text
    out = tmp_path / "never.csv"
    assert (
        multirotor_main(["convert", str(tmp_path / "absent.ulg"), "--airframe", "quad_x", "--out", str(out)])
        == 2
    )
    assert "no such file" in capsys.readouterr().err and not out.exists()
