"""The real ArduCopter flies through the bridge (SITL of shared/flight_stacks/ardupilot, see SOURCE.md).

Each airframe of config/ flies the mission of :mod:`multirotor_ros.mavlink.arducopter` (pre-arm checks
and EKF with every check on, GUIDED, arm, take off to 5 m, hover, 10 m north turning east, LAND, disarm)
on the bridge's derived motor map, SITL told the frame that map implies; the bridge's own physics is the
truth the flight is judged by, in its world ENU frame. SITL runs in a scratch directory, on an instance
whose ports are free, at a requested speedup of 10: lockstep keeps every frame exact however fast it goes.
One SITL start serves each airframe's tests (the quad's mission, then its restart).
"""

from __future__ import annotations

import math
import signal
import socket
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.arducopter import (
    ArduCopterSitl,
    GroundStation,
    Mission,
    MissionTimes,
    find_arducopter,
    fly,
    frame_parameters,
)
from multirotor_ros.mavlink.ardupilot import ArduPilotConfig
from multirotor_ros.mavlink.bridge import BridgeConfig, BridgeOutputs, BridgeThread, MavlinkBridge
from multirotor_ros.mavlink.physics import SimulatorPhysics
from multirotor_ros.mavlink.vehicle import VehicleState
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.rotation import quat_to_euler

ARDUCOPTER = find_arducopter()
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        ARDUCOPTER is None, reason="no ArduCopter SITL binary (shared/flight_stacks/ardupilot)"
    ),
]
SPEEDUP = 10.0  # requested of SITL; lockstep runs as fast as both sides answer, up to that
MISSION = Mission(hold_s=6.0)
SETTLED_AFTER_S = 3.0  # [s] after reaching 5 m, the hover is judged (ArduCopter's take-off overshoot is over)
TRUTH_RATE_HZ = 100.0  # [Hz] of simulated time: the bridge's states kept for judging


@dataclass
class Truth:
    """The bridge's states, at most ``rate_hz`` of simulated time (a mission's 85,000 frames would be 100 MB).

    ``rate_hz`` None: every state.
    """

    rate_hz: float | None = TRUTH_RATE_HZ
    times_s: list[float] = field(default_factory=list)
    states: list[VehicleState] = field(default_factory=list)

    def keep(self, state: VehicleState) -> None:
        period_s = 0.0 if self.rate_hz is None else 1.0 / self.rate_hz
        if not self.times_s or state.t_s >= self.times_s[-1] + period_s or state.t_s < self.times_s[-1]:
            self.times_s.append(state.t_s)
            self.states.append(state)

    def between(self, start_s: float, end_s: float) -> list[VehicleState]:
        """States of the newest run of the clock with start_s <= t <= end_s."""
        restart = max(
            (k for k in range(1, len(self.times_s)) if self.times_s[k] < self.times_s[k - 1]), default=0
        )
        return [
            s
            for t, s in zip(self.times_s[restart:], self.states[restart:], strict=True)
            if start_s <= t <= end_s
        ]


@dataclass
class Session:
    """One airframe: the bridge in this process, ArduCopter SITL against it, a ground station."""

    airframe_name: str
    channels: RotorChannels
    physics: SimulatorPhysics
    bridge: MavlinkBridge
    loop: BridgeThread
    sitl: ArduCopterSitl
    truth: Truth
    station: GroundStation | None = None

    def connect(self) -> GroundStation:
        if self.station is not None:
            self.station.close()
        self.station = GroundStation(self.sitl.mavlink_port)
        return self.station

    def sitl_minus_bridge_s(self) -> float:
        """ArduCopter's clock minus the bridge's (SITL's boot came before its first frame)."""
        station = self.station
        assert station is not None
        station.latest.pop("GLOBAL_POSITION_INT", None)
        station.wait(lambda: "GLOBAL_POSITION_INT" in station.latest, 10.0, "a position report")
        return station.time_s - self.bridge.simulation.latest.t_s

    def close(self) -> None:
        if self.station is not None:
            self.station.close()
        self.sitl.stop()
        self.loop.stop()


def start_session(
    airframe_name: str,
    workdir: Path,
    rate_hz: int = 1200,
    truth: Truth | None = None,
    answer_ahead: bool = False,
) -> Session:
    airframe = load_airframe(airframe_name)
    channels = RotorChannels(airframe)
    physics = SimulatorPhysics.for_airframe(airframe, seed=7)
    truth = truth or Truth()
    config = BridgeConfig(
        "ardupilot", ardupilot=ArduPilotConfig(port=0, answer_ahead=answer_ahead), ground_station=None
    )
    bridge = MavlinkBridge(
        config, channels, physics, BridgeOutputs(lambda s, t: None, truth.keep, lambda s: None)
    )
    loop = BridgeThread(bridge).start()
    assert ARDUCOPTER is not None and bridge.ardupilot is not None
    sitl = ArduCopterSitl(
        ARDUCOPTER, workdir, bridge.ardupilot.endpoint.port, frame_parameters(channels.map.frame),
        speedup=SPEEDUP, rate_hz=rate_hz,
    ).start()  # fmt: skip
    session = Session(airframe_name, channels, physics, bridge, loop, sitl, truth)
    session.connect()
    return session


class Sessions:
    """One session at a time, kept for the next test of the same airframe."""

    def __init__(self, scratch: Path):
        self.scratch = scratch
        self.current: Session | None = None

    def get(self, airframe_name: str) -> Session:
        if self.current is not None and self.current.airframe_name != airframe_name:
            self.close()
        if self.current is None:
            self.current = start_session(airframe_name, self.scratch / airframe_name)
        return self.current

    def close(self) -> None:
        if self.current is not None:
            self.current.close()
            self.current = None


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Sessions]:
    opened = Sessions(tmp_path_factory.mktemp("arducopter"))
    try:
        yield opened
    finally:
        opened.close()


def euler_deg(states: list[VehicleState]) -> np.ndarray:
    return np.degrees([quat_to_euler(s.q_WB) for s in states])


def judge_mission(session: Session, station: GroundStation, times: MissionTimes) -> None:
    """The flight, as the bridge's physics saw it, did what the mission asked, and as the model says."""
    offset = session.sitl_minus_bridge_s()
    hover = session.truth.between(times.reached_s + SETTLED_AFTER_S - offset, times.held_s - offset)
    heights = np.array([s.p_WB_W[2] for s in hover])
    attitude = euler_deg(hover)
    arrived = session.truth.between(times.arrived_s - offset - 0.02, times.arrived_s - offset + 0.02)[0]
    landed = session.bridge.simulation.latest
    outputs = np.array(
        [[getattr(m, f"servo{c}_raw") for c in session.channels.channels]
         for t, m in station.heard.servo_outputs if times.reached_s + SETTLED_AFTER_S <= t <= times.held_s]
    )  # fmt: skip
    hover_speeds = np.full(session.physics.n_rotors, session.physics.hover_speed_rad_s)
    model_pwm = session.channels.pwm_for_speeds(hover_speeds)[np.array(session.channels.channels) - 1]
    report = (
        f"{session.airframe_name}: take-off {times.reached_s - times.armed_s:.1f} s, hover at "
        f"{heights.mean():.3f} m +-{np.abs(heights - heights.mean()).max():.3f}, roll/pitch std "
        f"{attitude[:, 0].std():.3f}/{attitude[:, 1].std():.3f} deg, arrived at {arrived.p_WB_W.round(3)} "
        f"yaw {euler_deg([arrived])[0, 2]:.2f} deg, hover PWM {outputs.mean():.2f} us "
        f"(model {model_pwm.mean():.2f})"
    )
    print(report)
    assert times.reached_s - times.armed_s < 12.0, report  # about 6 s of climb after the spool-up
    assert np.abs(heights - heights.mean()).max() < 0.05, report
    assert abs(heights.mean() - MISSION.altitude_m) < 0.2, report  # ArduCopter's estimate of 5 m
    assert attitude[:, :2].std(axis=0).max() < 0.2, report
    # Arrived where it was sent, in the bridge's ENU frame: north is +y, facing east is yaw 0.
    assert math.hypot(arrived.p_WB_W[0], arrived.p_WB_W[1] - MISSION.north_m) < 0.3, report
    assert abs(arrived.p_WB_W[2] - MISSION.altitude_m) < 0.2, report
    assert abs(euler_deg([arrived])[0, 2]) < 3.0, report
    # ArduCopter holds the vehicle with the PWM the model says holds it: the motor map, channel map and
    # frames are all the same on both sides.
    assert abs(outputs.mean() - model_pwm.mean()) < 2.0, report
    assert landed.p_WB_W[2] < 0.02 and not station.armed, report


def check_lockstep(session: Session) -> None:
    """No frame missed or repeated; at SITL's own 1200 Hz, the time on the grid to the nanosecond."""
    ardupilot = session.bridge.ardupilot
    assert ardupilot is not None
    integrated_ahead = 1 if ardupilot.config.answer_ahead else 0  # the next frame's state is there already
    # SITL keeps sending frames after the landing: the counters are read on the loop's thread, between
    # two frames, or a frame counted but not yet simulated would show as one too many.
    read = threading.Event()
    counts: dict[str, float] = {}

    def snapshot() -> None:
        counts.update(
            frames=ardupilot.frames,
            missed=ardupilot.missed_frames,
            restarts=ardupilot.restarts,
            t_s=session.bridge.simulation.latest.t_s,
        )
        read.set()

    session.bridge.run_in_loop(snapshot)
    assert read.wait(5.0), "the bridge's loop did not run the snapshot within 5 s"
    assert counts["missed"] == 0 and session.bridge.refusals.total == 0, session.bridge.refusals.counts
    t_s = counts["t_s"]
    assert abs(t_s * 1200 - round(t_s * 1200)) < 1200 * 1e-9
    if counts["restarts"] == 0:
        assert counts["frames"] + integrated_ahead == round(t_s * 1200)  # each frame 1/1200 s


@pytest.mark.parametrize(
    "airframe_name", ["hexarotor_f550", "x8_octorotor", "quad_x"]
)  # quad last: see below
def test_arducopter_flies_the_mission_on_the_derived_motor_map(
    sessions: Sessions, airframe_name: str
) -> None:
    session = sessions.get(airframe_name)
    station = session.station
    assert station is not None
    judge_mission(session, station, fly(station, MISSION))
    check_lockstep(session)


def test_arducopter_flies_the_mission_answered_ahead(tmp_path: Path) -> None:
    """Each frame answered with the state integrated after the last one (one frame of actuator delay)."""
    session = start_session("quad_x", tmp_path, answer_ahead=True)
    try:
        station = session.station
        assert station is not None
        judge_mission(session, station, fly(station, MISSION))
        check_lockstep(session)
    finally:
        session.close()


def test_a_sitl_restart_mid_hover_resets_the_vehicle_and_the_new_sitl_flies_it(sessions: Sessions) -> None:
    session = sessions.get("quad_x")  # continues after the quad's mission when it ran just before
    hovering = session.station
    assert hovering is not None
    hovering.wait_ready_to_arm(MISSION.timeout_s)
    hovering.set_mode("GUIDED")
    hovering.arm()
    reached = hovering.take_off(3.0, MISSION.timeout_s)
    hovering.wait(lambda: hovering.time_s > reached + 1.0, 30.0, "a second of hover")
    session.sitl.stop(signal.SIGKILL)  # as a crash would: mid-hover
    frozen = session.bridge.simulation.latest
    assert frozen.p_WB_W[2] > 2.5
    session.sitl.start(wipe=False)
    station = session.connect()
    ardupilot = session.bridge.ardupilot
    assert ardupilot is not None
    station.wait(lambda: ardupilot.restarts == 1, 30.0, "the bridge seeing SITL's frames start again")
    first = session.truth.between(0.0, 0.1)
    assert first and np.allclose(first[0].p_WB_W, 0.0) and first[0].t_s < 0.01  # back home, on the ground
    station.wait_ready_to_arm(MISSION.timeout_s)
    station.set_mode("GUIDED")
    station.arm()
    reached = station.take_off(3.0, MISSION.timeout_s)
    station.wait(lambda: station.time_s > reached + 2.0, 30.0, "two seconds of hover")
    assert session.bridge.simulation.latest.p_WB_W[2] == pytest.approx(3.0, abs=0.3)
    check_lockstep(session)


@pytest.mark.parametrize("rate_hz", [400, 1200, 2000])
def test_every_frame_advances_time_by_exactly_its_period_at_any_sitl_rate(
    tmp_path: Path, rate_hz: int
) -> None:
    truth = Truth(rate_hz=None)
    session = start_session("quad_x", tmp_path, rate_hz=rate_hz, truth=truth)
    try:
        station = session.station
        assert station is not None
        station.wait(lambda: len(truth.times_s) > 3 * rate_hz, 60.0, f"3 s of {rate_hz} Hz frames")
        offset_s = session.sitl_minus_bridge_s()
    finally:
        session.close()
    # SITL starts at 1200 Hz and moves its frame rate towards SIM_RATE_HZ a hertz or two a frame
    # (SIM_JSON.cpp: adjust_frame_time within rate +-1, truncated to the packet's integer): each frame
    # advances by 1 / the rate its packet gave, to the nanosecond, never by 0.
    steps = np.diff(truth.times_s)
    rates = 1.0 / steps
    np.testing.assert_allclose(rates, np.round(rates), rtol=2e-6)
    np.testing.assert_allclose(steps[-rate_hz:], 1.0 / rate_hz, atol=1e-9)  # the last second at the rate
    # SITL's clock is the frames' (ArduCopter booted a few frames before the first one reached us).
    assert 0.0 <= -offset_s < 0.1
    ardupilot = session.bridge.ardupilot
    assert ardupilot is not None and ardupilot.missed_frames == 0 and session.bridge.refusals.total == 0


# ---------------------------------------------------------------------------------------------- the graph


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def level(status_or_level: DiagnosticStatus | bytes) -> int:
    """A diagnostic level as an int (rclpy gives them as one byte)."""
    value = status_or_level.level if isinstance(status_or_level, DiagnosticStatus) else status_or_level
    return int.from_bytes(value, "little") if isinstance(value, bytes) else int(value)


OK = level(DiagnosticStatus.OK)


@pytest.mark.ros
def test_the_identifier_names_a_rotor_fault_injected_while_arducopter_flies(
    start_node, ros_probe, tmp_path: Path
) -> None:
    airframe_name, faulty_rotor, effectiveness = "hexarotor_f550", 2, 0.6
    port = free_udp_port()
    diagnostics = ros_probe.subscribe("/f1/diagnostics", DiagnosticArray)
    bridge = start_node(
        "mavlink_bridge",
        namespace="/f1",
        parameters={"airframe": airframe_name, "flight_stack": "ardupilot", "flight_stack_port": port,
                    "publish_clock": True, "gcs_enabled": False, "seed": 3},
    )  # fmt: skip
    identifier = start_node(
        "identifier", namespace="/f1", parameters={"airframe": airframe_name, "use_sim_time": True}
    )
    ros_probe.wait_for_node("/f1/identifier", timeout=60.0)
    ros_probe.wait_for_node("/f1/mavlink_bridge", timeout=60.0)
    frame = RotorChannels(load_airframe(airframe_name)).map.frame
    assert frame is not None
    log = bridge.wait_for_log("outputs:", 30.0)
    assert f"ardupilot outputs: rotor_channels 5,1,4,6,2,3, derived from {frame.title}" in log
    assert ARDUCOPTER is not None
    with ArduCopterSitl(
        ARDUCOPTER, tmp_path / "sitl", port, frame_parameters(frame), speedup=2.0
    ).start() as sitl:
        station = GroundStation(sitl.mavlink_port)
        try:
            station.wait_ready_to_arm(MISSION.timeout_s)
            station.set_mode("GUIDED")
            station.arm()
            reached = station.take_off(MISSION.altitude_m, MISSION.timeout_s)
            station.wait(lambda: station.time_s > reached + 5.0, 60.0, "a settled hover")
            # The identifier publishes its inputs' health in messages of their own: wait for the rotors'.
            healthy = diagnostics.wait_for(
                lambda m: any(s.name.startswith("rotor_") for s in m.status), timeout=30.0
            )[-1]
            statuses = [(s.name, level(s), s.message) for s in healthy.status if s.name.startswith("rotor_")]
            assert all(status_level == OK for _, status_level, _ in statuses), statuses
            outcomes = ros_probe.set_parameters(
                "/f1/mavlink_bridge", {"fault_effectiveness": effectiveness, "fault_motor": faulty_rotor}
            )
            assert all(outcome.successful for outcome in outcomes.values()), outcomes
            named = diagnostics.wait_for(
                lambda m: any(s.name.startswith("rotor_") and level(s) != OK for s in m.status),
                timeout=60.0,
            )[-1]
            flying = station.relative_altitude_m
        finally:
            station.close()
    flagged = [s.name for s in named.status if s.name.startswith("rotor_") and level(s) != OK]
    assert flagged == [f"rotor_{faulty_rotor}"], [(s.name, level(s), s.message) for s in named.status]
    assert flying > 3.0  # ArduCopter kept flying on the five good rotors and the weak one
    assert "fault injected" in bridge.log_text() and identifier.running
