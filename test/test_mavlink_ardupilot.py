"""ArduPilot's JSON interface: an ArduPilot-like peer flies the identified model in lockstep over UDP."""

from __future__ import annotations

import json
import re
import socket
import time
from collections.abc import Iterator

import numpy as np
import pytest

from multirotor_ros.frames import enu_to_ned, flu_to_frd, quat_enu_flu_to_ned_frd
from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.ardupilot import ArduPilotConfig, encode_servo_packet
from multirotor_ros.mavlink.bridge import BridgeConfig, BridgeOutputs, BridgeThread, MavlinkBridge
from multirotor_ros.mavlink.peers import ArduPilotLikePeer, HoverController
from multirotor_ros.mavlink.physics import SimulatorPhysics
from multirotor_ros.mavlink.vehicle import VehicleState
from multirotor_ros.model.airframe import load_airframe

FRAME_RATE_HZ = 250


def parse_like_sitl(line: str) -> dict[str, list[float] | float]:
    """What ArduPilot's SIM_JSON parser does: find each key, skip ``key":``, read the value there."""
    values: dict[str, list[float] | float] = {}
    for key in ("timestamp", "gyro", "accel_body", "position", "velocity", "quaternion"):
        start = line.index(f'"{key}"') + len(key) + 3
        if line[start] == "[":
            match = re.match(r"\[([^\]]*)\]", line[start:])
            assert match, f"{key}: no vector right after the colon"
            values[key] = [float(v) for v in match.group(1).split(",")]
        else:
            values[key] = float(re.match(r"[-+0-9.eE]+", line[start:]).group(0))
    return values


@pytest.fixture(scope="module")
def quad():
    airframe = load_airframe("quad_x")
    return airframe, RotorChannels(airframe)


@pytest.fixture
def ardupilot_bridge(quad) -> Iterator[tuple[MavlinkBridge, dict[int, VehicleState]]]:
    airframe, channels = quad
    states: dict[int, VehicleState] = {}
    physics = SimulatorPhysics.for_airframe(airframe, 1.0 / FRAME_RATE_HZ, seed=2)
    config = BridgeConfig(
        "ardupilot", ardupilot=ArduPilotConfig(port=0, peer_timeout_s=0.5), ground_station=None
    )
    outputs = BridgeOutputs(
        lambda s, t: None, lambda state: states.__setitem__(round(state.t_s * 1e6), state), lambda sp: None
    )
    with BridgeThread(MavlinkBridge(config, channels, physics, outputs)) as bridge:
        yield bridge, states


def raw_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(1.0)
    return sock


def test_ardupilot_like_peer_hovers_ten_seconds_in_lockstep_and_the_json_agrees_with_the_physics(
    ardupilot_bridge, quad
):
    bridge, states = ardupilot_bridge
    _, channels = quad
    peer = ArduPilotLikePeer(bridge.flight_stack_port, HoverController(channels), frame_rate_hz=FRAME_RATE_HZ)
    try:
        record = peer.fly(10.0)
        # The raw line, as SITL's parser reads it: no space after a colon, vectors right after it.
        peer.sock.sendto(
            encode_servo_packet(FRAME_RATE_HZ, peer.frame_count + 1, [1500] * 4 + [0] * 12), peer.address
        )
        raw, _ = peer.sock.recvfrom(65536)
    finally:
        peer.close()
    line = raw.decode("ascii")
    assert line.startswith("\n") and line.endswith("\n") and ": " not in line
    assert parse_like_sitl(line)["timestamp"] == pytest.approx(json.loads(line)["timestamp"])

    replies = record.replies
    stamps = np.array([r["timestamp"] for r in replies])
    np.testing.assert_allclose(np.diff(stamps), 1.0 / FRAME_RATE_HZ, atol=1e-9)  # one step per frame
    assert stamps[-1] >= 10.0 and bridge.ardupilot.frames == record.frames_sent + 1  # + the raw one
    assert bridge.refusals.total == 0

    resting = [r["imu"]["accel_body"] for r in replies if r["timestamp"] < 0.4]
    np.testing.assert_allclose(np.mean(resting, axis=0), [0.0, 0.0, -9.81], atol=0.05)
    assert -replies[-1]["position"][2] == pytest.approx(2.0, abs=0.15)

    for reply in replies[::125]:
        state = states[round(reply["timestamp"] * 1e6)]
        np.testing.assert_allclose(reply["position"], enu_to_ned(state.p_WB_W), atol=1e-8)
        np.testing.assert_allclose(reply["velocity"], enu_to_ned(state.v_WB_W), atol=1e-8)
        np.testing.assert_allclose(reply["quaternion"], quat_enu_flu_to_ned_frd(state.q_WB), atol=1e-8)
        np.testing.assert_allclose(reply["imu"]["gyro"], flu_to_frd(state.imu_w_WB_B), atol=1e-8)
        np.testing.assert_allclose(
            reply["imu"]["accel_body"], flu_to_frd(state.imu_specific_force_B), atol=1e-8
        )


def test_a_repeated_frame_gets_the_same_answer_without_a_step(ardupilot_bridge, quad):
    bridge, _ = ardupilot_bridge
    _, channels = quad
    peer = ArduPilotLikePeer(bridge.flight_stack_port, HoverController(channels), frame_rate_hz=FRAME_RATE_HZ)
    try:
        first = peer.exchange([1000] * 16)
        again = peer.exchange([1000] * 16, frame_count=peer.frame_count)
        after = peer.exchange([1000] * 16)
    finally:
        peer.close()
    assert again == first
    assert after["timestamp"] == pytest.approx(first["timestamp"] + 1.0 / FRAME_RATE_HZ)
    assert bridge.refusals.counts == {"duplicate frame": 1}


def test_a_frame_count_going_back_means_sitl_restarted_and_the_vehicle_is_reset(ardupilot_bridge, quad):
    bridge, _ = ardupilot_bridge
    _, channels = quad
    peer = ArduPilotLikePeer(
        bridge.flight_stack_port, HoverController(channels), frame_rate_hz=FRAME_RATE_HZ, arm_after_s=0.1
    )
    try:
        flying = peer.fly(2.0)
        assert -flying.replies[-1]["position"][2] > 1.0
        peer.frame_count = 0
        restarted = peer.exchange([1000] * 16)
    finally:
        peer.close()
    assert restarted["timestamp"] == pytest.approx(1.0 / FRAME_RATE_HZ)
    np.testing.assert_allclose(restarted["position"], [0.0, 0.0, 0.0], atol=1e-9)
    assert bridge.ardupilot.restarts == 1


def test_the_32_channel_packet_drives_the_rotors_too(ardupilot_bridge, quad):
    bridge, _ = ardupilot_bridge
    _, channels = quad
    peer = ArduPilotLikePeer(
        bridge.flight_stack_port,
        HoverController(channels),
        frame_rate_hz=FRAME_RATE_HZ,
        channels=32,
        arm_after_s=0.1,
    )
    try:
        record = peer.fly(1.5)
    finally:
        peer.close()
    assert -record.replies[-1]["position"][2] > 0.5  # climbing towards 2 m
    assert bridge.refusals.total == 0


def test_bad_packets_and_a_second_sitl_are_refused_and_counted(ardupilot_bridge, quad):
    bridge, _ = ardupilot_bridge
    _, channels = quad
    port = bridge.flight_stack_port
    peer = ArduPilotLikePeer(port, HoverController(channels), frame_rate_hz=FRAME_RATE_HZ)
    intruder = raw_socket()
    intruder.settimeout(0.2)
    try:
        peer.exchange([1000] * 16)
        good = encode_servo_packet(FRAME_RATE_HZ, 99, [1000] * 16)
        for bad in (good[:-2], b"\x00" * 40, encode_servo_packet(0, 2, [1000] * 16), b"hello"):
            peer.sock.sendto(bad, ("127.0.0.1", port))
        intruder.sendto(good, ("127.0.0.1", port))
        with pytest.raises(TimeoutError):
            intruder.recvfrom(100)
        peer.exchange([1000] * 16)  # the current peer is still served
        huge = encode_servo_packet(FRAME_RATE_HZ, peer.frame_count + 1, [3000] * 4 + [1000] * 12)
        peer.sock.sendto(huge, ("127.0.0.1", port))
        peer.sock.recvfrom(65536)
    finally:
        peer.close()
        intruder.close()
    assert bridge.refusals.counts == {
        "bad servo packet size": 2,
        "bad servo magic": 1,
        "bad frame rate": 1,
        "second peer": 1,
        "out-of-range pwm": 1,
    }


def test_after_a_silence_another_address_takes_over(ardupilot_bridge, quad):
    bridge, _ = ardupilot_bridge
    _, channels = quad
    first = ArduPilotLikePeer(
        bridge.flight_stack_port, HoverController(channels), frame_rate_hz=FRAME_RATE_HZ
    )
    second = ArduPilotLikePeer(
        bridge.flight_stack_port, HoverController(channels), frame_rate_hz=FRAME_RATE_HZ
    )
    try:
        first.fly(0.2)
        time.sleep(0.6)  # longer than peer_timeout_s
        second.frame_count = first.frame_count
        reply = second.exchange([1000] * 16)
    finally:
        first.close()
        second.close()
    assert reply["timestamp"] > 0.2  # same flight, new address
    assert bridge.refusals.total == 0
