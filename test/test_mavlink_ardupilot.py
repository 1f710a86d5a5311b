"""ArduPilot's JSON interface: an ArduPilot-like peer flies the identified model in lockstep over UDP."""

from __future__ import annotations

import json
import re
import socket
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from multirotor_ros.frames import enu_to_ned, flu_to_frd, quat_enu_flu_to_ned_frd
from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.ardupilot import ArduPilotConfig, encode_servo_packet
from multirotor_ros.mavlink.bridge import (
    MAX_DEFERRED,
    BridgeConfig,
    BridgeOutputs,
    BridgeThread,
    MavlinkBridge,
)
from multirotor_ros.mavlink.peers import ArduPilotLikePeer, HoverController
from multirotor_ros.mavlink.physics import SimulatorPhysics
from multirotor_ros.mavlink.vehicle import VehicleState
from multirotor_ros.mavlink.wire import UdpEndpoint
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.integrator import Integrator

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
    physics = SimulatorPhysics.for_airframe(airframe, seed=2)
    config = BridgeConfig(
        "ardupilot", ardupilot=ArduPilotConfig(port=0, peer_timeout_s=0.5), ground_station=None
    )
    outputs = BridgeOutputs(
        lambda s, t: None, lambda state: states.__setitem__(round(state.t_s * 1e6), state), lambda sp: None
    )
    with BridgeThread(MavlinkBridge(config, channels, physics, outputs)) as bridge:
        yield bridge, states


def hover_peer(bridge: MavlinkBridge, rotor_channels: RotorChannels, **options: float) -> ArduPilotLikePeer:
    """A SITL-like peer at the test rate, flying the quad to a hover on the bridge's port."""
    return ArduPilotLikePeer(
        bridge.flight_stack_port, HoverController(rotor_channels), frame_rate_hz=FRAME_RATE_HZ, **options
    )


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
    peer = hover_peer(bridge, channels)
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
    peer = hover_peer(bridge, channels)
    try:
        first = peer.exchange([1000] * 16)
        again = peer.exchange([1000] * 16, frame_count=peer.frame_count)
        after = peer.exchange([1000] * 16)
    finally:
        peer.close()
    assert again == first
    assert after["timestamp"] == pytest.approx(first["timestamp"] + 1.0 / FRAME_RATE_HZ)
    assert bridge.ardupilot.repeated_frames == 1 and bridge.refusals.total == 0


def test_a_frame_count_going_back_means_sitl_restarted_and_the_vehicle_is_reset(ardupilot_bridge, quad):
    bridge, _ = ardupilot_bridge
    _, channels = quad
    peer = hover_peer(bridge, channels, arm_after_s=0.1)
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
    peer = hover_peer(bridge, channels, channels=32, arm_after_s=0.1)
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
    first = hover_peer(bridge, channels)
    second = hover_peer(bridge, channels)
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


def test_a_sitl_restarted_on_a_new_port_takes_over_at_once(ardupilot_bridge, quad):
    bridge, _ = ardupilot_bridge
    _, channels = quad
    first = hover_peer(bridge, channels)
    restarted = hover_peer(bridge, channels)
    try:
        first.fly(0.5)
        reply = restarted.exchange([1000] * 16)  # frame 1 from a new address, at once
    finally:
        first.close()
        restarted.close()
    assert reply["timestamp"] == pytest.approx(1.0 / FRAME_RATE_HZ)  # the vehicle reset for the new SITL
    assert bridge.ardupilot.restarts == 1 and bridge.refusals.total == 0


@pytest.mark.parametrize("frame_rate_hz", [400, 1200, 2000])
def test_every_frame_advances_exactly_one_period_whatever_the_rate(quad, frame_rate_hz):
    airframe, channels = quad
    config = BridgeConfig("ardupilot", ardupilot=ArduPilotConfig(port=0), ground_station=None)
    outputs = BridgeOutputs(lambda s, t: None, lambda state: None, lambda sp: None)
    physics = SimulatorPhysics.for_airframe(airframe, seed=2)  # 1 kHz physics: 1/400 s takes 3 sub-steps
    with BridgeThread(MavlinkBridge(config, channels, physics, outputs)) as bridge:
        peer = ArduPilotLikePeer(
            bridge.flight_stack_port, HoverController(channels), frame_rate_hz=frame_rate_hz
        )
        try:
            record = peer.fly(1.0)
        finally:
            peer.close()
    stamps = np.array([reply["timestamp"] for reply in record.replies])
    np.testing.assert_allclose(np.diff(stamps), 1.0 / frame_rate_hz, atol=1e-9)  # never 0, never 2 steps
    assert stamps[-1] * frame_rate_hz == pytest.approx(round(stamps[-1] * frame_rate_hz), abs=1e-6)


def _answers(quad, answer_ahead: bool, frames: list[tuple[int, list[int]]]) -> list[dict]:
    """A bridge's answers (physics seed 2) to servo packets of (frame rate, pwm), frame counts 1, 2, ..."""
    airframe, channels = quad
    config = BridgeConfig(
        "ardupilot", ardupilot=ArduPilotConfig(port=0, answer_ahead=answer_ahead), ground_station=None
    )
    outputs = BridgeOutputs(lambda s, t: None, lambda state: None, lambda sp: None)
    physics = SimulatorPhysics.for_airframe(airframe, seed=2)
    with BridgeThread(MavlinkBridge(config, channels, physics, outputs)) as bridge:
        peer = ArduPilotLikePeer(bridge.flight_stack_port, HoverController(channels))
        try:
            answers = []
            for rate_hz, pwm in frames:
                peer.frame_rate_hz = rate_hz
                answers.append(peer.exchange(pwm))
            # A repeated frame gets its answer again; a frame count from 1 again (SITL restarted) is
            # answered at once from the reset vehicle, with nothing integrated ahead.
            answers.append(peer.exchange(frames[-1][1], frame_count=peer.frame_count))
            peer.frame_count, peer.frame_rate_hz = 0, frames[0][0]
            answers.append(peer.exchange(frames[0][1]))
        finally:
            peer.close()
        assert bridge.refusals.total == 0 and bridge.ardupilot.restarts == 1
    return answers


def test_answering_ahead_gives_the_exact_answers_to_each_frame_one_frame_late(quad):
    """Answered ahead, servos P1, P2, ... get the answers exact lockstep gives to P1, P1, P2, ...

    Bit for bit, the sensor noise included, through a change of frame rate (which takes effect one frame
    later too), a repeated frame and a restart.
    """
    rng = np.random.default_rng(7)
    frames = [
        (1200 if k < 150 else 400, rng.integers(1720, 1950, 4).tolist() + [1000] * 12) for k in range(300)
    ]
    ahead = _answers(quad, True, frames)
    exact = _answers(quad, False, frames[:1] + frames[:-1])
    assert ahead[:-1] == exact[:-1]
    assert -ahead[-3]["position"][2] > 0.2  # it flew
    stamps = np.array([answer["timestamp"] for answer in ahead[:-2]])
    np.testing.assert_allclose(np.diff(stamps)[:150], 1 / 1200, atol=1e-9)  # the 151st at 400 Hz: one late
    np.testing.assert_allclose(np.diff(stamps)[150:], 1 / 400, atol=1e-9)
    assert ahead[-2] == ahead[-3]  # the repeated frame
    restarted = ahead[-1]
    assert restarted["timestamp"] == pytest.approx(1 / 1200) and restarted == exact[-1]


@pytest.mark.parametrize(("dt_ns", "substeps"), [(2_500_000, 3), (833_333, 1), (500_000, 1), (4_000_000, 4)])
def test_a_frame_is_integrated_in_equal_substeps_no_longer_than_the_physics_step(quad, dt_ns, substeps):
    airframe, _ = quad
    physics = SimulatorPhysics.for_airframe(airframe, noise=False)
    hover = np.full(4, 1.02 * physics.hover_speed_rad_s)  # climbing: the state changes at every sub-step
    physics.advance_to(hover, 1_000_000)
    x_before = physics.simulator.x.copy()
    state = physics.advance_to(hover, 1_000_000 + dt_ns)
    reference = Integrator(physics.simulator.model, dt_ns / substeps * 1e-9, ground_height_m=0.0)
    x_expected = reference.advance(1e-3, x_before, physics.simulator.commands_rad_s, substeps)
    np.testing.assert_array_equal(physics.simulator.x, x_expected)
    assert state.t_s == pytest.approx(1e-3 + dt_ns * 1e-9, abs=1e-12) and physics.t_ns == 1_000_000 + dt_ns


@pytest.mark.parametrize("frame_rate_hz", [400, 1200])
def test_the_imu_is_sampled_at_the_frame_rate_with_that_rates_white_noise(quad, frame_rate_hz):
    airframe, _ = quad
    physics = SimulatorPhysics.for_airframe(airframe, seed=3)
    resting = np.zeros(4)
    gyro = [physics.advance_to(resting, round(k * 1e9 / frame_rate_hz)).imu_w_WB_B for k in range(1, 3001)]
    config = physics.imu_config
    assert config.imu_rate_hz == frame_rate_hz
    expected = config.gyro_noise_density_rad_s_sqrt_hz * np.sqrt(frame_rate_hz)  # density x root of the rate
    assert config.gyro_sample_std_rad_s == pytest.approx(expected)
    # At rest the gyro reads its bias (which hardly walks in 3,000 samples) plus that white noise.
    np.testing.assert_allclose(np.std(gyro, axis=0), expected, rtol=0.1)


def test_deferred_work_waits_until_every_waiting_frame_is_answered(quad):
    # The node publishes to ROS through defer(): two frames already queued are both answered first.
    airframe, channels = quad
    events: list[str] = []
    bridge: MavlinkBridge

    def on_state(state: VehicleState) -> None:
        bridge.defer(lambda: events.append(f"published {state.t_s:.3f}"))

    config = BridgeConfig("ardupilot", ardupilot=ArduPilotConfig(port=0), ground_station=None)
    outputs = BridgeOutputs(lambda s, t: None, on_state, lambda sp: None)
    bridge = MavlinkBridge(config, channels, SimulatorPhysics.for_airframe(airframe), outputs)
    sitl = raw_socket()
    try:
        session = bridge.ardupilot
        assert session is not None
        send = session.endpoint.send
        session.endpoint.send = lambda data, address: events.append("answered") or send(data, address)
        for frame in (1, 2):
            sitl.sendto(
                encode_servo_packet(FRAME_RATE_HZ, frame, [1000] * 16),
                ("127.0.0.1", bridge.flight_stack_port),
            )
        time.sleep(0.05)  # both datagrams queued before the loop looks
        bridge.spin_once(0.5)
        assert events == ["answered", "answered", "published 0.004", "published 0.008"]
    finally:
        sitl.close()
        bridge.close()


def test_deferred_work_is_done_even_while_input_keeps_waiting(quad):
    airframe, channels = quad
    config = BridgeConfig("ardupilot", ardupilot=ArduPilotConfig(port=0), ground_station=None)
    outputs = BridgeOutputs(lambda s, t: None, lambda state: None, lambda sp: None)
    bridge = MavlinkBridge(config, channels, SimulatorPhysics.for_airframe(airframe), outputs)
    busy, feeder = socket.socketpair()
    try:
        feeder.send(b"x")  # never read: the selector always has input waiting
        bridge._register(busy, lambda: None)
        done: list[int] = []
        for k in range(MAX_DEFERRED + 4):
            bridge.defer(lambda k=k: done.append(k))
        bridge.spin_once(0.0)
        assert done == [0, 1, 2, 3]  # the oldest, down to the bound on what may wait
    finally:
        bridge._unregister(busy)
        busy.close()
        feeder.close()
        bridge.close()


def test_after_a_quick_turn_the_next_frame_is_polled_for_and_after_a_slow_one_it_is_not(quad):
    airframe, channels = quad
    budget_s = 0.01
    config = BridgeConfig(
        "ardupilot", ardupilot=ArduPilotConfig(port=0, busy_wait_s=budget_s), ground_station=None
    )
    outputs = BridgeOutputs(lambda s, t: None, lambda state: None, lambda sp: None)
    bridge = MavlinkBridge(config, channels, SimulatorPhysics.for_airframe(airframe), outputs)
    session = bridge.ardupilot
    assert session is not None
    sitl = raw_socket()

    def send(frame: int) -> None:
        packet = encode_servo_packet(FRAME_RATE_HZ, frame, [1000] * 16)
        sitl.sendto(packet, ("127.0.0.1", bridge.flight_stack_port))

    try:
        send(1)
        bridge.spin_once(0.5)
        sitl.recvfrom(65536)
        assert session.frames == 1  # SITL's turn not known yet: nothing polled, the selector sleeps

        # SITL's last turn was short: the frame it sends while the bridge polls is answered in that poll.
        session.last_turn_s = budget_s / 10
        late_sender = threading.Timer(budget_s / 5, send, (2,))
        late_sender.start()
        assert session.wait_for_next_frame()
        late_sender.join()
        assert session.frames == 2
        sitl.recvfrom(65536)

        # The loop goes on polling: its selector only looks (timeout 0) while the next frame is expected,
        # and the frame that comes then is answered by the poll, not after a sleep in the selector.
        timeouts: list[float | None] = []
        select = bridge._selector.select
        bridge._selector.select = lambda timeout=None: (timeouts.append(timeout), select(timeout))[1]
        late_sender = threading.Timer(budget_s / 5, send, (3,))
        late_sender.start()
        bridge.spin_once(0.5)
        late_sender.join()
        bridge._selector.select = select
        assert session.frames == 3
        assert timeouts and all(timeout == 0.0 for timeout in timeouts)
        sitl.recvfrom(65536)

        # A turn longer than the budget (SITL keeping real time): no polling, however soon the frame comes.
        session.last_turn_s = 2 * budget_s
        started = time.perf_counter()
        assert not session.wait_for_next_frame()
        assert time.perf_counter() - started < budget_s / 2
        assert session.frames == 3
    finally:
        sitl.close()
        bridge.close()


def test_polling_for_a_frame_handles_a_queued_one_and_gives_up_after_its_budget(quad):
    received: list[bytes] = []
    endpoint = UdpEndpoint("127.0.0.1", 0, lambda data, address: received.append(data))
    sender = raw_socket()
    try:
        started = time.perf_counter()
        assert not endpoint.wait_briefly(0.002)
        assert time.perf_counter() - started >= 0.002
        sender.sendto(b"frame", ("127.0.0.1", endpoint.port))
        time.sleep(0.01)
        assert endpoint.wait_briefly(0.002)
        assert received == [b"frame"]
    finally:
        sender.close()
        endpoint.close()


@pytest.mark.parametrize("busy_wait_s", [-0.001, 0.02, float("nan")])
def test_a_busy_wait_outside_0_to_10_ms_is_refused(busy_wait_s):
    with pytest.raises(ValueError, match="busy wait"):
        ArduPilotConfig(busy_wait_s=busy_wait_s)
