"""PX4's simulator interface: a PX4-like peer flies the identified model in lockstep over TCP."""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from multirotor_ros.frames import enu_to_ned, quat_enu_flu_to_ned_frd
from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.bridge import BridgeConfig, BridgeOutputs, BridgeThread, MavlinkBridge
from multirotor_ros.mavlink.messages import MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED, MAV_RESULT_UNSUPPORTED
from multirotor_ros.mavlink.peers import HoverController, Px4LikePeer
from multirotor_ros.mavlink.physics import SimulatorPhysics
from multirotor_ros.mavlink.px4 import FIELDS_ALL, FLAG_LOCKSTEP, Px4Config
from multirotor_ros.mavlink.sensors import Home, LocalTangentPlane
from multirotor_ros.mavlink.vehicle import VehicleState
from multirotor_ros.model.airframe import load_airframe

STEP_S = 0.004  # 250 Hz


@dataclass
class Recorded:
    """What the bridge handed to its outputs (what the node would publish)."""

    states: dict[int, VehicleState] = field(default_factory=dict)  # by time_usec
    commands: list[np.ndarray] = field(default_factory=list)

    def outputs(self) -> BridgeOutputs:
        return BridgeOutputs(
            lambda speeds, t: self.commands.append(speeds),
            lambda state: self.states.__setitem__(round(state.t_s * 1e6), state),
            lambda setpoint: None,
        )

    def state_at(self, time_usec: int, timeout_s: float = 2.0) -> VehicleState:
        """The state handed out at ``time_usec`` (the bridge hands it out just after its answer)."""
        deadline = time.monotonic() + timeout_s
        while time_usec not in self.states and time.monotonic() < deadline:
            time.sleep(0.001)
        return self.states[time_usec]


@pytest.fixture(scope="module")
def quad():
    airframe = load_airframe("quad_x")
    return airframe, RotorChannels(airframe)


def px4_bridge_thread(quad, recorded: Recorded, **config: float) -> BridgeThread:
    airframe, channels = quad
    physics = SimulatorPhysics.for_airframe(airframe, seed=4)
    bridge_config = BridgeConfig("px4", px4=Px4Config(port=0, step_s=STEP_S, **config), ground_station=None)
    return BridgeThread(MavlinkBridge(bridge_config, channels, physics, recorded.outputs()))


@pytest.fixture
def px4_bridge(quad) -> Iterator[tuple[MavlinkBridge, Recorded]]:
    recorded = Recorded()
    with px4_bridge_thread(quad, recorded) as bridge:
        yield bridge, recorded


def armed_peer(bridge: MavlinkBridge, channels: RotorChannels) -> Px4LikePeer:
    """A PX4-like peer on the bridge's port that arms after 0.2 s and flies the quad to a hover."""
    return Px4LikePeer(bridge.flight_stack_port, HoverController(channels), arm_after_s=0.2)


def mean_specific_force_frd(sensors: list) -> np.ndarray:
    return np.mean([[s.xacc, s.yacc, s.zacc] for s in sensors], axis=0)


def test_px4_like_peer_hovers_ten_seconds_in_lockstep_and_everything_agrees_with_the_physics(
    px4_bridge, quad
):
    bridge, recorded = px4_bridge
    _, channels = quad
    peer = Px4LikePeer(bridge.flight_stack_port, HoverController(channels, altitude_m=2.0), arm_after_s=0.5)
    try:
        record = peer.fly(10.0)
    finally:
        peer.close()

    # Lockstep: one HIL_SENSOR per actuator message, time advancing by exactly one step each.
    times = np.array([s.time_usec for s in record.sensors])
    assert len(times) == record.actuator_messages
    assert times[-1] >= 10_000_000
    lockstep = np.diff(times[times > 100_000])
    assert np.all(lockstep == round(STEP_S * 1e6))
    assert bridge.px4.lockstep and bridge.refusals.total == 0
    assert all(s.fields_updated == FIELDS_ALL == 0x1BFF for s in record.sensors)

    # At rest (disarmed, on the ground): the accelerometer reads minus gravity along FRD z.
    resting = [s for s in record.sensors if s.time_usec < 400_000]
    np.testing.assert_allclose(mean_specific_force_frd(resting), [0.0, 0.0, -9.81], atol=0.05)
    assert resting[0].pressure_alt == pytest.approx(Home().altitude_m, abs=0.01)

    # Hovering on the peer's own controller at 2 m.
    final = recorded.state_at(times[-1])
    assert final.p_WB_W[2] == pytest.approx(2.0, abs=0.15)
    assert np.linalg.norm(final.v_WB_W) < 0.2
    assert record.sensors[-1].pressure_alt == pytest.approx(Home().altitude_m + final.p_WB_W[2], abs=0.01)
    hovering = [s for s in record.sensors if s.time_usec > 8_000_000]
    np.testing.assert_allclose(mean_specific_force_frd(hovering), [0.0, 0.0, -9.81], atol=0.1)

    # Ground truth (HIL_STATE_QUATERNION, asked for at 200 Hz) agrees with the physics through frames.py.
    assert record.acks[0].command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL
    assert record.acks[0].result == MAV_RESULT_ACCEPTED
    assert len(record.states) > 0.9 * 200 * 10
    plane = LocalTangentPlane(Home())
    for message in record.states[::50]:
        state = recorded.states[message.time_usec]
        np.testing.assert_allclose(
            message.attitude_quaternion, quat_enu_flu_to_ned_frd(state.q_WB), atol=1e-6
        )
        np.testing.assert_allclose(
            [message.vx, message.vy, message.vz], np.round(enu_to_ned(state.v_WB_W) * 100), atol=1
        )
        p = plane.enu(message.lat * 1e-7, message.lon * 1e-7, message.alt * 1e-3)
        np.testing.assert_allclose(p, state.p_WB_W, atol=0.02)

    # GPS at 10 Hz, in degE7 / mm / cm/s NED, agreeing with the physics too.
    assert 95 <= len(record.gps) <= 105
    for fix in record.gps[::10]:
        state = recorded.states[fix.time_usec]
        p = plane.enu(fix.lat * 1e-7, fix.lon * 1e-7, fix.alt * 1e-3)
        np.testing.assert_allclose(p, state.p_WB_W, atol=0.02)
        np.testing.assert_allclose([fix.vn, fix.ve, fix.vd], np.round(enu_to_ned(state.v_WB_W) * 100), atol=1)
        assert fix.fix_type == 3
    assert record.heartbeats >= 10

    # The commands went out as motor_speed_cmd, through the motor map (rad/s, within the airframe's range).
    commands = np.array(recorded.commands)
    assert commands.shape[1] == 4 and commands.max() <= 1100.0 and commands[-1].min() > 500.0


def test_set_message_interval_answers(px4_bridge, quad):
    bridge, _ = px4_bridge
    _, channels = quad
    peer = Px4LikePeer(bridge.flight_stack_port, HoverController(channels))
    try:
        for message_id, interval_us in [
            (mavlink2.MAVLINK_MSG_ID_HIL_GPS, 50_000),
            (mavlink2.MAVLINK_MSG_ID_ATTITUDE, 1e4),
        ]:
            peer.mav.send(
                peer.mav.command_long_encode(
                    0, 0, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, message_id, interval_us, 0, 0, 0, 0, 0
                )
            )
        peer.mav.send(
            peer.mav.command_long_encode(0, 0, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        )
        record = peer.fly(0.3)
    finally:
        peer.close()
    # 20 Hz GPS is outside PX4's 5..10 Hz; ATTITUDE is not a simulator message; arming is not ours to do.
    assert [a.result for a in record.acks] == [
        MAV_RESULT_ACCEPTED,
        MAV_RESULT_DENIED,
        MAV_RESULT_UNSUPPORTED,
        MAV_RESULT_UNSUPPORTED,
    ]


def test_bad_input_mid_flight_is_dropped_and_counted_and_the_flight_goes_on(px4_bridge, quad):
    bridge, recorded = px4_bridge
    _, channels = quad
    peer = armed_peer(bridge, channels)
    try:
        peer.fly(1.0)
        mav = peer.mav
        good = mav.hil_actuator_controls_encode(
            0,
            peer.controller.channels.px4_controls_for_speeds(np.full(4, 700.0)).tolist(),
            129,
            FLAG_LOCKSTEP,
        )
        good_bytes = good.pack(mav)
        bad_crc = bytearray(good_bytes)
        bad_crc[-1] ^= 0x55
        unknown = bytearray(mav.heartbeat_encode(0, 0, 0, 0, 0).pack(mav))
        unknown[7:10] = (44444).to_bytes(3, "little")
        garbage = b"\x00\x13\x37 not mavlink at all \xff"
        truncated = good_bytes[:20]
        out_of_range = mav.hil_actuator_controls_encode(0, [1.7] * 16, 129, FLAG_LOCKSTEP).pack(mav)
        non_finite = mav.hil_actuator_controls_encode(0, [float("nan")] * 16, 129, FLAG_LOCKSTEP).pack(mav)
        peer.sock.sendall(garbage + bytes(bad_crc) + bytes(unknown) + truncated + good_bytes)
        peer.sock.sendall(out_of_range + non_finite)
        t_before = bridge.simulation.latest.t_s
        record = peer.fly(3.0)
    finally:
        peer.close()
    counts = bridge.refusals.counts
    assert counts.get("corrupt bytes", 0) >= 1
    assert counts.get("bad CRC", 0) >= 1
    assert counts.get("unknown message id", 0) == 1
    assert counts["out-of-range control"] == 1
    assert counts["non-finite control"] == 1
    # Lockstep kept going (refused actuator messages still step, or PX4's clock would stop) and the
    # vehicle still hovers.
    assert record.sensors[-1].time_usec >= 3_000_000 and t_before < 3.0
    assert recorded.state_at(record.sensors[-1].time_usec).p_WB_W[2] == pytest.approx(2.0, abs=0.3)
    assert len(recorded.states) >= 3.0 / STEP_S


def test_disconnect_freezes_the_vehicle_and_a_reconnecting_peer_continues_the_flight(px4_bridge, quad):
    bridge, _ = px4_bridge
    _, channels = quad
    first = armed_peer(bridge, channels)
    first.fly(2.5)
    first.close()
    deadline = time.monotonic() + 2.0
    while bridge.px4.connected and time.monotonic() < deadline:
        time.sleep(0.01)
    frozen = bridge.simulation.latest
    time.sleep(0.3)
    assert bridge.simulation.latest is frozen  # no flight stack, no time: the state is kept
    assert frozen.p_WB_W[2] > 1.0

    second = Px4LikePeer(bridge.flight_stack_port, HoverController(channels), arm_after_s=0.0, origin=Home())
    try:
        record = second.fly(frozen.t_s + 1.0)
    finally:
        second.close()
    assert record.sensors[0].time_usec > frozen.t_s * 1e6  # the clock continues, it does not restart
    assert bridge.simulation.latest.p_WB_W[2] == pytest.approx(2.0, abs=0.3)
    assert bridge.px4.connections == 2


def test_a_second_flight_stack_is_refused_while_one_flies(px4_bridge, quad):
    bridge, _ = px4_bridge
    _, channels = quad
    peer = Px4LikePeer(bridge.flight_stack_port, HoverController(channels))
    try:
        peer.fly(0.2)
        intruder = socket.create_connection(("127.0.0.1", bridge.flight_stack_port))
        intruder.settimeout(2.0)
        assert intruder.recv(100) == b""  # closed at once
        intruder.close()
        record = peer.fly(0.5)
    finally:
        peer.close()
    assert bridge.refusals.counts == {"second peer": 1}
    assert record.sensors[-1].time_usec >= 500_000


def test_without_the_lockstep_flag_the_physics_runs_on_the_wall_clock(px4_bridge):
    bridge, _ = px4_bridge
    sock = socket.create_connection(("127.0.0.1", bridge.flight_stack_port))
    mav = mavlink2.MAVLink(None, 1, 1)
    try:
        start = time.monotonic()
        sensors = []
        sock.settimeout(2.0)
        while time.monotonic() - start < 0.6:
            for message in mav.parse_buffer(sock.recv(65536)) or []:
                if message.get_type() == "HIL_SENSOR":
                    sensors.append(message.time_usec)
                    controls = mav.hil_actuator_controls_encode(0, [0.0] * 16, 1, 0)  # no lockstep flag
                    sock.sendall(controls.pack(mav))
        elapsed = time.monotonic() - start
    finally:
        sock.close()
    assert not bridge.px4.lockstep
    simulated = (sensors[-1] - sensors[0]) * 1e-6
    # Free-running: simulated time follows the wall clock (slower only if the machine cannot keep up).
    assert 0.3 * elapsed < simulated <= elapsed + 0.05


def test_external_physics_forwards_states_and_publishes_commands(quad):
    _, channels = quad
    recorded = Recorded()
    config = BridgeConfig("px4", px4=Px4Config(port=0), ground_station=None)
    with BridgeThread(MavlinkBridge(config, channels, None, recorded.outputs())) as bridge:
        sock = socket.create_connection(("127.0.0.1", bridge.flight_stack_port))
        sock.settimeout(2.0)
        mav = mavlink2.MAVLink(None, 1, 1)
        try:
            time.sleep(0.1)
            q_WB = np.array([math.cos(0.2), 0.0, 0.0, math.sin(0.2)])  # yawed 0.4 rad
            state = VehicleState(
                1.25,
                np.array([1.0, 2.0, 3.0]),
                np.array([0.5, 0.0, 0.0]),
                q_WB,
                np.zeros(3),
                np.full(4, 600.0),
                np.array([0.0, 0.0, 9.81]),
                np.array([0.0, 0.0, 0.1]),
            )
            bridge.update_external_state(state)
            received = []
            while not any(m.get_type() == "HIL_SENSOR" for m in received):
                received += mav.parse_buffer(sock.recv(65536)) or []
            sensor = next(m for m in received if m.get_type() == "HIL_SENSOR")
            assert sensor.time_usec == 1_250_000
            np.testing.assert_allclose([sensor.xacc, sensor.yacc, sensor.zacc], [0.0, 0.0, -9.81], atol=1e-6)
            np.testing.assert_allclose(
                [sensor.xgyro, sensor.ygyro, sensor.zgyro], [0.0, 0.0, -0.1], atol=1e-7
            )
            controls = channels.px4_controls_for_speeds(np.array([500.0, 600.0, 700.0, 800.0]))
            sock.sendall(mav.hil_actuator_controls_encode(0, controls.tolist(), 129, FLAG_LOCKSTEP).pack(mav))
            deadline = time.monotonic() + 2.0
            while not recorded.commands and time.monotonic() < deadline:
                time.sleep(0.01)
        finally:
            sock.close()
    np.testing.assert_allclose(recorded.commands[0], [500.0, 600.0, 700.0, 800.0], atol=1e-3)
    assert recorded.states == {}  # nothing stepped here: the simulator node owns the physics


def test_a_corrupt_header_swallowing_actuator_messages_does_not_deadlock_lockstep(quad):
    _, channels = quad
    with px4_bridge_thread(quad, Recorded(), stall_timeout_s=0.3) as bridge:
        peer = armed_peer(bridge, channels)
        try:
            peer.fly(0.5)
            climbing_from_m = bridge.simulation.latest.p_WB_W[2]
            # A MAVLink 2 header announcing a 120-byte payload: the parser takes the next actuator
            # messages for that payload, and neither side would ever send again.
            peer.sock.sendall(bytes([0xFD, 120, 0, 0, 0, 1, 1, 0, 0, 0]))
            record = peer.fly(1.5)
        finally:
            peer.close()
        assert bridge.px4.stalls >= 1
        assert bridge.refusals.counts.get("bad CRC", 0) + bridge.refusals.counts.get("corrupt bytes", 0) >= 1
        assert record.sensors[-1].time_usec >= 1_500_000
        assert bridge.simulation.latest.p_WB_W[2] > climbing_from_m + 0.3  # still climbing to its 2 m


def test_lockstep_at_400_hz_advances_exactly_one_step_per_actuator_message(quad):
    # 2.5 ms steps on 1 kHz physics: three sub-steps of 0.833 ms, not steps of 2 and 3 ms in turn.
    recorded = Recorded()
    airframe, channels = quad
    physics = SimulatorPhysics.for_airframe(airframe, seed=4)
    config = BridgeConfig("px4", px4=Px4Config(port=0, step_s=0.0025), ground_station=None)
    with BridgeThread(MavlinkBridge(config, channels, physics, recorded.outputs())) as bridge:
        peer = armed_peer(bridge, channels)
        try:
            record = peer.fly(2.0)
        finally:
            peer.close()
    times = np.array([s.time_usec for s in record.sensors])
    assert np.all(np.diff(times[times > 100_000]) == 2500)
    assert bridge.refusals.total == 0


def test_a_command_computed_on_an_older_sensor_is_held_without_moving_time(px4_bridge, quad):
    bridge, _ = px4_bridge
    _, channels = quad
    peer = armed_peer(bridge, channels)
    try:
        peer.fly(0.5)
        newest = peer.record.sensors[-1].time_usec
        controls = channels.px4_controls_for_speeds(np.full(4, 600.0)).tolist()
        # Answers to two sensors ago (PX4 still busy with one the stall rule sent) and from the future.
        peer.mav.send(peer.mav.hil_actuator_controls_encode(newest - 4000, controls, 129, FLAG_LOCKSTEP))
        deadline = time.monotonic() + 2.0
        while bridge.px4.late_commands == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert bridge.simulation.latest.t_s * 1e6 == pytest.approx(newest + 4000)  # the answer to newest only
        peer.mav.send(peer.mav.hil_actuator_controls_encode(newest + 10**9, controls, 129, FLAG_LOCKSTEP))
        record = peer.fly(1.0)
    finally:
        peer.close()
    # The future stamp counts as answering the newest sensor (one step), which makes the peer's own answer
    # to that sensor, read after, a second late one.
    assert bridge.px4.late_commands == 2
    assert bridge.refusals.counts == {"actuator stamp ahead": 1}
    times = np.array([s.time_usec for s in record.sensors])
    assert np.all(np.diff(times[times > 100_000]) == 4000)  # one step per sensor, none skipped or doubled
