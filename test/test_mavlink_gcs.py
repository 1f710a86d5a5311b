"""Ground-station link: telemetry a ground station can show, setpoints in, signing enforced."""

from __future__ import annotations

import math
import socket
import time
from collections import Counter
from collections.abc import Iterator

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from multirotor_ros.frames import enu_to_ned, quat_enu_flu_to_ned_frd
from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.bridge import BridgeConfig, BridgeOutputs, BridgeThread, MavlinkBridge
from multirotor_ros.mavlink.gcs import GroundStationConfig, GroundStationLink, Setpoint
from multirotor_ros.mavlink.sensors import Home, LocalTangentPlane, SensorModel
from multirotor_ros.mavlink.signing import SigningPolicy, parse_signing_key, signing_timestamp_now
from multirotor_ros.mavlink.vehicle import VehicleState
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.rotation import euler_to_quat, quat_to_euler
from multirotor_ros.refusals import RefusalCounter

KEY = parse_signing_key("ground station passphrase")
YAW_ENU = 0.3  # [rad]
STATE = VehicleState(
    t_s=12.5,
    p_WB_W=np.array([3.0, -4.0, 5.0]),
    v_WB_W=np.array([0.5, 0.25, -0.1]),
    q_WB=euler_to_quat([0.05, -0.1, YAW_ENU]),
    w_WB_B=np.array([0.01, 0.02, 0.03]),
    rotor_speeds_rad_s=np.array([600.0, 610.0, 620.0, 630.0]),
    imu_specific_force_B=np.array([0.0, 0.0, 9.81]),
    imu_w_WB_B=np.array([0.01, 0.02, 0.03]),
)


class GroundStation:
    """A pymavlink ground station on a UDP socket (optionally signing with a key)."""

    def __init__(self, key: bytes | None = None):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.parser = mavlink2.MAVLink(None)
        self.parser.robust_parsing = True
        self.sender = mavlink2.MAVLink(_Sink(), 255, 190)
        if key is not None:
            self.sender.signing.secret_key = key
            self.sender.signing.sign_outgoing = True
            self.sender.signing.link_id = 3
            self.sender.signing.timestamp = signing_timestamp_now()
        self.bridge_address: tuple[str, int] | None = None

    def collect(self, seconds: float) -> list:
        messages = []
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                data, sender = self.sock.recvfrom(65536)
            except TimeoutError:
                continue
            parsed = [
                m
                for m in self.parser.parse_buffer(data) or []
                if not isinstance(m, mavlink2.MAVLink_bad_data)
            ]
            # A datagram that is not MAVLink comes from another program that once had this port number
            # (another test's peer on a busy machine): it is not the bridge's, so it is not an answer.
            if parsed:
                self.bridge_address = sender
                messages += parsed
        return messages

    def send(self, message: object) -> None:
        if self.bridge_address is None:
            self.collect(0.5)
        self.sender.send(message)
        self.sock.sendto(self.sender.file.data, self.bridge_address)

    def close(self) -> None:
        self.sock.close()


class _Sink:
    data = b""

    def write(self, data: bytes) -> None:
        self.data = bytes(data)


@pytest.fixture(scope="module")
def channels():
    return RotorChannels(load_airframe("quad_x"))


def start_bridge(channels, gcs_port: int, key: bytes | None, setpoints: list) -> BridgeThread:
    config = BridgeConfig("none", ground_station=GroundStationConfig(port=gcs_port))
    outputs = BridgeOutputs(lambda s, t: None, lambda s: None, setpoints.append)
    bridge = MavlinkBridge(config, channels, None, outputs, signing=SigningPolicy(key))
    thread = BridgeThread(bridge).start()
    bridge.update_external_state(STATE)
    return thread


@pytest.fixture
def unsigned_setup(channels) -> Iterator[tuple[MavlinkBridge, GroundStation, list]]:
    station = GroundStation()
    setpoints: list[Setpoint] = []
    thread = start_bridge(channels, station.port, None, setpoints)
    try:
        yield thread.bridge, station, setpoints
    finally:
        thread.stop()
        station.close()


@pytest.fixture
def signed_setup(channels) -> Iterator[tuple[MavlinkBridge, list]]:
    setpoints: list[Setpoint] = []
    station = GroundStation(KEY)
    thread = start_bridge(channels, station.port, KEY, setpoints)
    try:
        yield thread.bridge, station, setpoints
    finally:
        thread.stop()
        station.close()


def by_type(messages: list) -> dict[str, list]:
    table: dict[str, list] = {}
    for message in messages:
        table.setdefault(message.get_type(), []).append(message)
    return table


def setpoint_message(
    sender: mavlink2.MAVLink, frame: int, xyz: tuple, yaw: float | None = None, target: int = 1
):
    # Position (and yaw) used; velocity, acceleration, yaw rate ignored; bit 10 ignores the yaw.
    mask = 0b1001_1111_1000 if yaw is not None else 0b1101_1111_1000
    return sender.set_position_target_local_ned_encode(
        0, target, 1, frame, mask, *xyz, 0, 0, 0, 0, 0, 0, yaw or 0.0, 0
    )


def test_telemetry_shows_the_vehicle_where_the_state_says(unsigned_setup):
    _, station, _ = unsigned_setup
    table = by_type(station.collect(1.5))
    counts = Counter({kind: len(messages) for kind, messages in table.items()})
    # Rates (on a busy machine allow some slack): 50 Hz attitude/position, 10 Hz global, 1 Hz status.
    assert counts["ATTITUDE"] >= 45 and counts["LOCAL_POSITION_NED"] >= 45
    assert counts["GLOBAL_POSITION_INT"] >= 9 and counts["HEARTBEAT"] >= 1 and counts["SYS_STATUS"] >= 1
    heartbeat = table["HEARTBEAT"][0]
    assert heartbeat.type == mavlink2.MAV_TYPE_QUADROTOR and heartbeat.get_srcSystem() == 1
    assert heartbeat.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED  # rotors turning

    attitude = table["ATTITUDE"][-1]
    roll, pitch, yaw = quat_to_euler(quat_enu_flu_to_ned_frd(STATE.q_WB))
    np.testing.assert_allclose([attitude.roll, attitude.pitch, attitude.yaw], [roll, pitch, yaw], atol=1e-6)
    assert attitude.yaw == pytest.approx(math.pi / 2 - YAW_ENU)
    assert attitude.time_boot_ms == 12500
    local = table["LOCAL_POSITION_NED"][-1]
    np.testing.assert_allclose([local.x, local.y, local.z], enu_to_ned(STATE.p_WB_W), atol=1e-6)
    np.testing.assert_allclose([local.vx, local.vy, local.vz], enu_to_ned(STATE.v_WB_W), atol=1e-6)
    glob = table["GLOBAL_POSITION_INT"][-1]
    p = LocalTangentPlane(Home()).enu(glob.lat * 1e-7, glob.lon * 1e-7, glob.alt * 1e-3)
    np.testing.assert_allclose(p, STATE.p_WB_W, atol=0.02)
    assert glob.relative_alt == 5000 and glob.hdg == round(math.degrees(math.pi / 2 - YAW_ENU) * 100)
    outputs = table["ACTUATOR_OUTPUT_STATUS"][-1]
    np.testing.assert_allclose(outputs.actuator[:4], STATE.rotor_speeds_rad_s)
    assert outputs.active == 0b1111
    esc = table["ESC_TELEMETRY_1_TO_4"][-1]
    np.testing.assert_allclose(esc.rpm, np.round(STATE.rotor_speeds_rad_s * 60 / (2 * math.pi)))


def test_timesync_is_answered(unsigned_setup):
    _, station, _ = unsigned_setup
    station.send(station.sender.timesync_encode(0, 123456789))
    answers = [m for m in station.collect(0.5) if m.get_type() == "TIMESYNC"]
    assert answers and answers[0].ts1 == 123456789 and answers[0].tc1 > 0


def test_set_message_interval_slows_the_attitude(unsigned_setup):
    _, station, _ = unsigned_setup
    station.send(
        station.sender.command_long_encode(
            1,
            1,
            mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL,
            0,
            mavlink2.MAVLINK_MSG_ID_ATTITUDE,
            200_000,
            0,
            0,
            0,
            0,
            0,
        )
    )
    messages = station.collect(1.2)
    acks = [m for m in messages if m.get_type() == "COMMAND_ACK"]
    assert acks and acks[0].result == mavlink2.MAV_RESULT_ACCEPTED
    assert 3 <= sum(m.get_type() == "ATTITUDE" for m in messages[len(messages) // 4 :]) <= 8


def test_setpoints_become_enu_positions_in_every_supported_frame(unsigned_setup):
    bridge, station, setpoints = unsigned_setup
    sender = station.sender
    station.send(setpoint_message(sender, mavlink2.MAV_FRAME_LOCAL_NED, (1.0, 2.0, -3.0), yaw=0.0))
    station.send(setpoint_message(sender, mavlink2.MAV_FRAME_LOCAL_OFFSET_NED, (1.0, 0.0, 0.0)))
    station.send(setpoint_message(sender, mavlink2.MAV_FRAME_BODY_OFFSET_NED, (2.0, 0.0, 0.0), yaw=0.1))
    station.send(setpoint_message(sender, mavlink2.MAV_FRAME_LOCAL_NED, (9.0, 9.0, -9.0), target=7))  # not us
    station.collect(0.4)
    assert len(setpoints) == 3
    absolute, offset, body = setpoints
    np.testing.assert_allclose(absolute.p_W_m, [2.0, 1.0, 3.0])  # NED (1, 2, -3) is ENU (2, 1, 3)
    assert absolute.yaw_W_rad == pytest.approx(math.pi / 2)  # facing north
    np.testing.assert_allclose(offset.p_W_m, STATE.p_WB_W + [0.0, 1.0, 0.0])  # one metre north
    assert offset.yaw_W_rad == pytest.approx(YAW_ENU, abs=1e-9)  # yaw ignored: keep the heading
    heading = np.array([math.cos(YAW_ENU), math.sin(YAW_ENU), 0.0])
    np.testing.assert_allclose(body.p_W_m, STATE.p_WB_W + 2.0 * heading, atol=1e-9)  # 2 m straight ahead
    assert body.yaw_W_rad == pytest.approx(YAW_ENU - 0.1)  # turn 0.1 rad clockwise (to the right)
    assert bridge.refusals.total == 0


def test_setpoints_that_cannot_be_flown_are_refused(unsigned_setup):
    bridge, station, setpoints = unsigned_setup
    sender = station.sender
    velocity_only = sender.set_position_target_local_ned_encode(
        0, 1, 1, 1, 0b0000_1111_1100_0111, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0
    )
    station.send(velocity_only)
    station.send(setpoint_message(sender, mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, (1.0, 2.0, 3.0)))
    station.send(setpoint_message(sender, mavlink2.MAV_FRAME_LOCAL_NED, (float("nan"), 0.0, 0.0)))
    station.send(setpoint_message(sender, mavlink2.MAV_FRAME_LOCAL_NED, (1e6, 0.0, 0.0)))
    station.collect(0.4)
    assert setpoints == []
    assert bridge.refusals.counts == {
        "unsupported setpoint": 1,
        "unsupported frame": 1,
        "non-finite setpoint": 1,
        "setpoint out of range": 1,
    }


def test_with_a_key_only_signed_commands_move_the_setpoint(signed_setup):
    bridge, station, setpoints = signed_setup
    # The telemetry is signed: a parser holding the key accepts it (pymavlink refuses anything else).
    checker = mavlink2.MAVLink(None)
    checker.signing.secret_key = KEY
    station.parser = checker
    assert any(m.get_type() == "ATTITUDE" for m in station.collect(0.5))

    station.send(setpoint_message(station.sender, mavlink2.MAV_FRAME_LOCAL_NED, (1.0, 2.0, -3.0)))
    unsigned = GroundStation()
    wrong_key = GroundStation(parse_signing_key("not the key"))
    for intruder in (unsigned, wrong_key):
        intruder.bridge_address = station.bridge_address
        intruder.send(setpoint_message(intruder.sender, mavlink2.MAV_FRAME_LOCAL_NED, (50.0, 50.0, -10.0)))
        intruder.send(intruder.sender.heartbeat_encode(mavlink2.MAV_TYPE_GCS, 8, 0, 0, 0))
        intruder.close()
    station.collect(0.4)
    assert [s.p_W_m.tolist() for s in setpoints] == [[2.0, 1.0, 3.0]]
    # The unsigned intruder's HEARTBEAT passes the signing policy but makes no peer of it.
    assert bridge.refusals.counts == {
        "unsigned command": 1,
        "bad signature": 2,
        "ground station not admitted": 1,
    }


def test_link_without_a_state_yet_reads_setpoints_against_home():
    refusals = RefusalCounter()
    link = GroundStationLink(
        GroundStationConfig(port=9),
        SensorModel(Home()),
        4,
        SigningPolicy(None),
        refusals,
        lambda setpoint: None,
    )
    try:
        sender = mavlink2.MAVLink(_Sink(), 255, 190)
        setpoint = link.setpoint_from_message(
            setpoint_message(sender, mavlink2.MAV_FRAME_LOCAL_OFFSET_NED, (1, 0, 0))
        )
        assert isinstance(setpoint, Setpoint)
        np.testing.assert_allclose(setpoint.p_W_m, [0.0, 1.0, 0.0])
    finally:
        link.close()
