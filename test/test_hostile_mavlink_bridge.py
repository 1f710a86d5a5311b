"""Hostile input to the MAVLink bridge: encoders, malformed frames, rate requests, strangers, ROS floods.

No value breaks an encoder, no frame escapes as an exception, no stranger gets telemetry, and a flooded
node keeps telling its ground station where the vehicle is.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from nav_msgs.msg import Odometry
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu, JointState
from test_mavlink_gcs import KEY, STATE, GroundStation, by_type

from multirotor_ros.cli.fuzz import flood, hostile_messages
from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.ardupilot import state_json_line
from multirotor_ros.mavlink.bridge import BridgeConfig, BridgeOutputs, BridgeThread, MavlinkBridge
from multirotor_ros.mavlink.gcs import GroundStationConfig, GroundStationLink
from multirotor_ros.mavlink.malformed import MALFORMED_KINDS, malformed_frames
from multirotor_ros.mavlink.messages import ned_view
from multirotor_ros.mavlink.px4 import Px4Config, Px4Session
from multirotor_ros.mavlink.sensors import Home, SensorModel
from multirotor_ros.mavlink.signing import SigningPolicy
from multirotor_ros.mavlink.vehicle import Simulation, VehicleState
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.nodes.messages import (
    imu_message,
    joint_state_from_rotor_speeds,
    odometry_message,
    stamp_from_ns,
)
from multirotor_ros.refusals import RefusalCounter

HOSTILE_FLOATS = st.one_of(
    st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 1e39, -1e39, 1e200, 0.0]),
    st.floats(allow_nan=True, allow_infinity=True),
)
FRAMES_PER_PORT = 2000  # bench/bench_mavlink.py --fuzz sends 10,000


def vectors(length: int) -> st.SearchStrategy[np.ndarray]:
    return st.lists(HOSTILE_FLOATS, min_size=length, max_size=length).map(np.array)


@st.composite
def hostile_states(draw: st.DrawFn) -> VehicleState:
    return VehicleState(
        t_s=draw(st.one_of(st.floats(0.0, 1e6), st.sampled_from([1e12, 2.0**31]))),
        p_WB_W=draw(vectors(3)),
        v_WB_W=draw(vectors(3)),
        q_WB=draw(vectors(4)),
        w_WB_B=draw(vectors(3)),
        rotor_speeds_rad_s=draw(vectors(4)),
        imu_specific_force_B=draw(vectors(3)),
        imu_w_WB_B=draw(vectors(3)),
    )


@pytest.fixture(scope="module")
def channels() -> RotorChannels:
    return RotorChannels(load_airframe("quad_x"))


@pytest.fixture(scope="module")
def encoders(channels) -> Iterator[tuple[GroundStationLink, Px4Session]]:
    refusals = RefusalCounter(lambda line: None)
    sensors = SensorModel(Home())
    gcs = GroundStationLink(
        GroundStationConfig(port=9), sensors, 4, SigningPolicy(None), refusals, lambda setpoint: None
    )
    simulation = Simulation(4, 9.81, None, lambda speeds, t_s: None, lambda state: None)
    px4 = Px4Session(Px4Config(port=0), simulation, channels, sensors, refusals)
    try:
        yield gcs, px4
    finally:
        gcs.close()
        px4.close()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # numpy's overflow warnings on 1e308: expected here
@settings(max_examples=300, deadline=None)
@given(state=hostile_states())
def test_every_telemetry_message_packs_hostile_floats_without_an_exception(encoders, state):
    gcs, px4 = encoders
    view = ned_view(state)
    messages = [m for message_id in gcs.schedule_ids() for m in gcs._build(message_id, state, view)]
    fix = px4.sensors.gps(state.p_WB_W, state.v_WB_W)
    stamp = 1
    messages += [
        px4._hil_sensor(state, view, stamp),
        px4._hil_gps(fix, stamp),
        px4._hil_state_quaternion(fix, view, stamp),
        px4._heartbeat(),
    ]
    parser = mavlink2.MAVLink(None)
    for message in messages:
        codec = gcs.codec if message.get_type() in {"HEARTBEAT", "SYS_STATUS"} else px4.codec
        decoded = parser.parse_buffer(codec.encode(message))
        assert decoded and decoded[0].get_type() == message.get_type()
    state_json_line(state)  # ArduPilot's answer line: no exception either


def test_clamped_values_are_the_field_limits():
    refusals = RefusalCounter(lambda line: None)
    link = GroundStationLink(
        GroundStationConfig(port=9), SensorModel(Home()), 4, SigningPolicy(None), refusals, lambda s: None
    )
    try:
        # The reproduction: 1e308 m and 1e39 m/s raised OverflowError in the encoder.
        state = STATE._replace(p_WB_W=np.array([1e308, 0.0, 0.0]), v_WB_W=np.array([1e39, 0.0, 0.0]))
        parser = mavlink2.MAVLink(None)
        view = ned_view(state)
        local = parser.parse_buffer(link.codec.encode(link._build(32, state, view)[0]))[0]
        assert local.y == pytest.approx(3.4028234663852886e38, rel=1e-6)  # east = ENU x
        assert local.vy == pytest.approx(3.4028234663852886e38, rel=1e-6)
        assert link.codec.values_clamped >= 2
    finally:
        link.close()


# ---------------------------------------------------------------- malformed frames on every port


def refusals_per_frame(handle, refusals: RefusalCounter, frames: list[tuple[str, bytes]]) -> dict[str, int]:
    """Feed every frame to ``handle``; how many frames of each kind were counted as refused."""
    counted = dict.fromkeys(MALFORMED_KINDS, 0)
    for kind, frame in frames:
        before = refusals.total
        handle(frame)
        counted[kind] += refusals.total > before
    return counted


def test_malformed_frames_on_the_ground_station_port_are_each_refused_and_counted(encoders):
    gcs, _ = encoders
    frames = malformed_frames(FRAMES_PER_PORT, seed=11)
    sent = {kind: sum(k == kind for k, _ in frames) for kind in MALFORMED_KINDS}
    heartbeat_rate_hz = gcs.schedule.rate_hz(0)
    counted = refusals_per_frame(
        lambda frame: gcs._on_datagram(frame, ("127.0.0.1", 9)), gcs.refusals, frames
    )
    # Every damaged frame is refused; hostile fields are refused by their handler (setpoint, interval)
    # or not for this link (actuator controls).
    assert {k: counted[k] for k in MALFORMED_KINDS[:-1]} == {k: sent[k] for k in MALFORMED_KINDS[:-1]}
    assert counted["hostile fields"] >= sent["hostile fields"] * 0.7
    assert "internal error" not in gcs.refusals.counts
    assert gcs.schedule.rate_hz(0) == heartbeat_rate_hz  # the 1 us HEARTBEAT requests were all denied


def test_malformed_frames_on_the_flight_stack_port_are_refused_and_counted(encoders):
    _, px4 = encoders
    frames = malformed_frames(FRAMES_PER_PORT, seed=12)
    counted = refusals_per_frame(px4._on_data, px4.refusals, frames)
    # A stream keeps what looks like the start of a packet for the next read, so a refusal may be counted
    # one or more frames later (about 60 % show their own at once; the rest are counted with a later one).
    damaged = MALFORMED_KINDS[:-1]
    assert sum(counted[k] for k in damaged) >= 0.5 * sum(k in damaged for k, _ in frames)
    assert "internal error" not in px4.refusals.counts


def test_a_gcs_port_under_fuzz_still_answers_its_ground_station(channels):
    station = GroundStation()
    config = BridgeConfig("none", ground_station=GroundStationConfig(port=station.port))
    bridge = MavlinkBridge(
        config, channels, None, BridgeOutputs(lambda s, t: None, lambda s: None, lambda s: None)
    )
    with BridgeThread(bridge):
        bridge.update_external_state(STATE)
        fuzzer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            for index, (_, frame) in enumerate(malformed_frames(600, seed=13)):
                fuzzer.sendto(frame, ("127.0.0.1", bridge.gcs.local_port))
                if index % 50 == 49:
                    time.sleep(0.005)  # the kernel drops what the loop has not read yet
            station.collect(0.3)
            station.send(station.sender.timesync_encode(0, 42))
            table = by_type(station.collect(1.0))
        finally:
            fuzzer.close()
            station.close()
    assert any(m.ts1 == 42 for m in table.get("TIMESYNC", []))
    assert len(table.get("ATTITUDE", [])) >= 30
    assert "internal error" not in bridge.refusals.counts and bridge.refusals.total > 600


# ---------------------------------------------------------------- ground stations and rates


def test_rate_requests_are_bounded_and_answered_with_the_refused_parameter(channels):
    station = GroundStation()
    config = BridgeConfig("none", ground_station=GroundStationConfig(port=station.port))
    bridge = MavlinkBridge(
        config, channels, None, BridgeOutputs(lambda s, t: None, lambda s: None, lambda s: None)
    )
    with BridgeThread(bridge):
        bridge.update_external_state(STATE)
        try:
            station.collect(0.3)
            station.send(
                station.sender.command_long_encode(
                    1, 1, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 0, 1, 0, 0, 0, 0, 0
                )
            )
            table = by_type(station.collect(2.0))
        finally:
            station.close()
    (ack,) = table["COMMAND_ACK"]
    assert ack.result == mavlink2.MAV_RESULT_DENIED and ack.result_param2 == 2
    assert len(table["HEARTBEAT"]) <= 3  # still 1 Hz, not thousands a second
    assert bridge.refusals.counts == {"message interval refused": 1}


def test_telemetry_goes_to_the_configured_station_and_a_bounded_number_of_others(channels):
    configured = GroundStation()
    others = [GroundStation() for _ in range(5)]
    config = BridgeConfig("none", ground_station=GroundStationConfig(port=configured.port, max_peers=2))
    bridge = MavlinkBridge(
        config, channels, None, BridgeOutputs(lambda s, t: None, lambda s: None, lambda s: None)
    )
    with BridgeThread(bridge):
        bridge.update_external_state(STATE)
        try:
            for station in others:
                station.bridge_address = ("127.0.0.1", bridge.gcs.local_port)
                station.send(station.sender.heartbeat_encode(mavlink2.MAV_TYPE_GCS, 8, 0, 0, 0))
                time.sleep(0.05)  # in order: the first two become peers
            received = [len(station.collect(0.6)) for station in [configured, *others]]
        finally:
            for station in [configured, *others]:
                station.close()
    assert all(count > 10 for count in received[:3]) and received[3:] == [0, 0, 0]
    assert bridge.refusals.counts == {"ground station not admitted": 3}


def test_with_a_key_an_unsigned_station_elsewhere_gets_nothing(channels):
    configured = GroundStation(KEY)
    spoofer = GroundStation()
    config = BridgeConfig("none", ground_station=GroundStationConfig(port=configured.port))
    bridge = MavlinkBridge(
        config,
        channels,
        None,
        BridgeOutputs(lambda s, t: None, lambda s: None, lambda s: None),
        signing=SigningPolicy(KEY),
    )
    with BridgeThread(bridge):
        bridge.update_external_state(STATE)
        try:
            spoofer.bridge_address = ("127.0.0.1", bridge.gcs.local_port)
            spoofer.send(spoofer.sender.heartbeat_encode(mavlink2.MAV_TYPE_GCS, 8, 0, 0, 0))
            interval = spoofer.sender.command_long_encode(
                1, 1, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 0, 20_000, 0, 0, 0, 0, 0
            )
            spoofer.send(interval)  # unsigned: refused like an unsigned setpoint
            spoofed = spoofer.collect(0.6)
            configured.parser.signing.secret_key = KEY
            watched = configured.collect(0.6)
        finally:
            configured.close()
            spoofer.close()
    assert spoofed == [] and sum(m.get_type() == "HEARTBEAT" for m in watched) <= 2
    assert bridge.refusals.counts == {"ground station not admitted": 1, "unsigned command": 1}


# ---------------------------------------------------------------- the node under a topic flood

FLOODED_TOPICS = {  # fuzz kind: (topic, type, messages)
    "odometry": ("odom", Odometry, 1500),
    "imu": ("imu", Imu, 1500),
    "joint_state": ("motor_speeds", JointState, 800),
}
HOVER = S.make_state(4, position_m=(1.0, 2.0, 3.0), rotor_speed_rad_s=600.0)[0]


def valid_message(kind: str, now_ns: int) -> object:
    stamp = stamp_from_ns(now_ns)
    if kind == "odometry":
        return odometry_message(HOVER, stamp)
    if kind == "imu":
        return imu_message(stamp, "base_link", HOVER[S.QUATERNION], [0.0, 0.0, 9.81], [0.0, 0.0, 0.0],
                           accel_var=0.0, gyro_var=0.0, orientation_var=0.0)  # fmt: skip
    return joint_state_from_rotor_speeds(HOVER[S.ROTORS_START :], stamp)


@pytest.mark.ros
def test_flooded_node_keeps_its_ground_station_informed_and_strangers_uninformed(start_node, ros_probe):
    airframe = load_airframe("quad_x")
    station, spoofer = GroundStation(), GroundStation()
    publishers = {
        kind: ros_probe.publisher(f"/hostile/{topic}", msg_type, qos_profile_sensor_data)
        for kind, (topic, msg_type, _) in FLOODED_TOPICS.items()
    }
    node = start_node(
        "mavlink_bridge",
        namespace="/hostile",
        parameters={
            "airframe": "quad_x",
            "flight_stack": "none",
            "gcs_port": station.port,
            "gcs_max_peers": 0,
        },
    )
    for publisher in publishers.values():
        ros_probe.wait_for_subscribers(publisher, timeout=30.0)

    def publish_valid() -> None:
        for kind, publisher in publishers.items():
            publisher.publish(valid_message(kind, time.time_ns()))

    try:
        for kind, (_, _, count) in FLOODED_TOPICS.items():
            items = hostile_messages(kind, count, seed=7, airframe=airframe)
            flood(items, publishers[kind].publish, time.time_ns, rate_hz=1000.0, background=publish_valid)
        # The spoofer, at a port of its own, asks for telemetry; the configured station watches.
        deadline = time.monotonic() + 1.5
        received = []
        while time.monotonic() < deadline:
            publish_valid()
            received += station.collect(0.05)
        spoofer.bridge_address = station.bridge_address
        spoofer.send(spoofer.sender.heartbeat_encode(mavlink2.MAV_TYPE_GCS, 8, 0, 0, 0))
        for _ in range(20):
            publish_valid()
            received += station.collect(0.05)
        spoofed = spoofer.collect(0.5)
    finally:
        station.close()
        spoofer.close()
    node.assert_running()
    positions = [m for m in received if m.get_type() == "LOCAL_POSITION_NED"]
    assert len(positions) > 20, f"telemetry stopped; node log:\n{node.log_tail()}"
    last = positions[-1]
    np.testing.assert_allclose([last.x, last.y, last.z], [2.0, 1.0, -3.0], atol=1e-5)  # ENU (1, 2, 3)
    assert all(math.isfinite(v) for m in positions for v in (m.x, m.y, m.z, m.vx, m.vy, m.vz))
    assert spoofed == []  # gcs_max_peers 0: only the configured ground station hears the vehicle
    log = node.log_text()
    assert "Traceback" not in log and "internal error" not in log
    refusal_lines = [line for line in log.splitlines() if "refused" in line]
    assert 5 <= len(refusal_lines) <= 40, "\n".join(refusal_lines)  # once per reason, plus summaries
    assert len(log.splitlines()) < 80
