"""The identifier on a busy machine (issue 10): breaks in its data are missing data, never evidence.

Pure-core tests (no ROS): simulated flights (multirotor_ros.simulation.simulate_flight, sensor noise,
rotor lag, seed 1 controller) fed to FlightMonitor message by message, as the node would, with
messages lost, stamps out of order, a clock that restarts, a long ground phase with idle rotors, a
take-off, setpoint steps and a landing, and no fault: no alarm. A real fault after a gap is still
found once the noise is learnt again. Then the input watch that names a silent peer, the rules that
tell support from free flight, and the identifier node beside the real simulator and controller in
lockstep, with the simulator's resends.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from hypothesis import given, settings
from hypothesis import strategies as st
from nav_msgs.msg import Odometry
from ros_harness import NodeProcess, RosProbe
from test_node_identifier import ORIGIN_NS, rotor_statuses, samples
from test_nodes_sim_control import Vehicle, stamp_s

from multirotor_ros.diagnosis.campaign import FaultCase, Load, fly_case
from multirotor_ros.diagnosis.contact import HELD_CONFIRM_S, SupportWatch
from multirotor_ros.diagnosis.inputs import InputWatch
from multirotor_ros.diagnosis.monitor import FlightMonitor, StepResult, lower_quartile
from multirotor_ros.diagnosis.residuals import _MEDIAN_ABS_TO_SIGMA, InnovationGate
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import Airframe, load_airframe
from multirotor_ros.model.rotation import FloatArray
from multirotor_ros.nodes.messages import stamp_to_ns
from multirotor_ros.simulation import simulate_flight

Row = tuple[int, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]
NS = 1_000_000_000
IDLE_UNTIL_S = 2.0  # the rotors idle on the ground until then, then hold hover thrust there
TAKE_OFF_S = 4.0
# Take-off, steps with turns (those of the issue among them), a landing.
SETPOINTS = [
    (TAKE_OFF_S, 0.0, 0.0, 1.5, 0.0),
    (8.0, 1.0, 0.0, 1.5, 0.3),
    (11.0, 1.0, 1.0, 2.5, -0.3),
    (14.0, 0.0, 0.0, 1.0, 0.0),
    (17.0, -1.0, 0.5, 2.0, 0.5),
    (20.0, 0.0, 0.0, 0.0, 0.0),
]


@functools.cache
def flight(airframe_name: str) -> list[Row]:
    """25 s from the ground and back (SETPOINTS), flown once per session (hypothesis reuses it).

    Until IDLE_UNTIL_S the rotors idle at 30 % of their median speed in flight.
    """
    airframe = load_airframe(airframe_name)
    log = simulate_flight(airframe, setpoints=SETPOINTS, duration_s=25.0, rng=np.random.default_rng(1))
    idle = np.full(airframe.n_rotors, 0.3 * float(np.median(log.column("omega_1"))))
    return [
        (stamp, p, v, q, w, idle if stamp < ORIGIN_NS + IDLE_UNTIL_S * NS else omega)
        for stamp, p, v, q, w, omega in samples(log)
    ]


@pytest.fixture(scope="module")
def x8() -> Airframe:
    return load_airframe("x8_octorotor")


def replay(
    monitor: FlightMonitor,
    rows: Sequence[Row],
    speeds_kept: Sequence[bool] | None = None,
    states_kept: Sequence[bool] | None = None,
) -> list[StepResult]:
    """Each row's rotor speeds, then its state, unless lost (a False in ``*_kept``); every result."""
    results: list[StepResult] = []
    for k, (stamp, p, v, q, w, omega) in enumerate(rows):
        speeds = monitor.rotor_speeds(stamp, omega) if speeds_kept is None or speeds_kept[k] else []
        state = monitor.state(stamp, p, v, q, w) if states_kept is None or states_kept[k] else []
        for outcome in (speeds, state):
            results += outcome if isinstance(outcome, list) else []
    return results


def lost(rows: Sequence[Row], lost_rows: range) -> list[bool]:
    """Kept flags of ``rows``: all but ``lost_rows``."""
    return [k not in lost_rows for k in range(len(rows))]


def alarms(results: list[StepResult]) -> list[str]:
    """Every alarm raised, in words (empty: none)."""
    return [
        f"t = {r.stamp_ns * 1e-9 - ORIGIN_NS * 1e-9:.2f} s, rotor {int(r.detection.rotor[0]) + 1}"
        for r in results
        if r.detection is not None and r.detection.alarm[0] and r.detection.onset_t[0] == r.t
    ]


def judged_share(results: list[StepResult], rows: list[Row]) -> float:
    """Share of the rows the detector judged (not lost, held, resting or learning the noise)."""
    judged = [r for r in results if r.detection is not None and not r.detection.warming_up]
    return len(judged) / len(rows)


# ------------------------------------------------------------------ no fault, no alarm


@pytest.mark.parametrize("airframe_name", ["x8_octorotor", "quad_x"])
@pytest.mark.parametrize("load", [Load(0.005, 10), Load(0.02, 5), Load(0.01, 30)], ids=str)
def test_ground_take_off_steps_and_landing_with_lost_messages_raise_no_alarm(airframe_name, load):
    airframe = load_airframe(airframe_name)
    rows = flight(airframe_name)
    rng = np.random.default_rng(3)
    speeds_kept, states_kept = load.kept(len(rows), rng), load.kept(len(rows), rng)
    monitor = FlightMonitor(airframe, [])
    results = replay(monitor, rows, speeds_kept, states_kept)
    assert not alarms(results)
    # Nothing learnt or judged on the ground, before the take-off.
    before_take_off = [r for r in results if r.stamp_ns < ORIGIN_NS + TAKE_OFF_S * NS]
    assert before_take_off and all(
        r.skipped in ("resting", "before the first motor_speeds", "no recent motor_speeds")
        for r in before_take_off
    )
    # Not blind for good: between the gaps the detector judged again.
    assert judged_share(results, rows) > 0.0


def test_without_losses_the_detector_judges_the_whole_flight_and_stays_far_from_the_threshold(x8):
    rows = flight(x8.name)
    results = replay(FlightMonitor(x8, []), rows)
    assert not alarms(results)
    assert not any(r.warnings for r in results)
    # From a second after the take-off (settling, noise) to the landing, every sample is judged.
    assert judged_share(results, rows) > (20.0 - TAKE_OFF_S - 1.5) / 25.0
    judged = [r.detection for r in results if r.detection is not None and not r.detection.warming_up]
    peak = max(float(np.max(d.loss / d.threshold)) for d in judged)
    assert peak < 0.8


lost_runs = st.lists(
    st.tuples(
        st.sampled_from(["speeds", "state", "both"]),
        st.integers(0, 2499),  # first row lost
        st.integers(1, 60),  # rows lost
    ),
    max_size=40,
)


@settings(max_examples=12, deadline=None)
@given(runs=lost_runs, resent=st.lists(st.integers(1, 2499), max_size=30))
def test_any_pattern_of_lost_and_resent_messages_in_a_fault_free_flight_raises_no_alarm(x8, runs, resent):
    """Runs of lost messages on either stream or both, and older messages sent again (out of order)."""
    rows = flight(x8.name)
    kept = {"speeds": np.ones(len(rows), dtype=bool), "state": np.ones(len(rows), dtype=bool)}
    for stream, first, length in runs:
        for name in ("speeds", "state") if stream == "both" else (stream,):
            kept[name][first : first + length] = False
    # Five rows back, sent again before a row: refused, or a late message if it was lost then.
    order = [j for k in range(len(rows)) for j in ([k - 5] if k in resent and k >= 5 else []) + [k]]
    results = replay(
        FlightMonitor(x8, []),
        [rows[j] for j in order],
        [bool(kept["speeds"][j]) for j in order],
        [bool(kept["state"][j]) for j in order],
    )
    assert not alarms(results)


def test_a_restarted_clock_starts_a_new_time_line_without_alarm_and_times_go_on(x8):
    """The node's clock went back (a restarted simulator): the same flight again, on older stamps."""
    rows = flight(x8.name)
    monitor = FlightMonitor(x8, [])
    first = replay(monitor, rows[: len(rows) // 2])
    learnt = monitor.identifier.n_samples
    monitor.restart()
    second = replay(monitor, rows)
    assert not alarms(first + second)
    times = [r.t for r in first + second]
    assert np.all(np.diff(times) > 0)
    assert monitor.identifier.n_samples > learnt  # the identifier learns on the new time line


def test_samples_without_rotor_speeds_of_their_time_are_missing_data(x8):
    """motor_speeds silent for 2 s in flight while the state keeps coming: skipped, then a gap."""
    rows = flight(x8.name)
    silent = range(900, 1100)
    monitor = FlightMonitor(x8, [])
    results = replay(monitor, rows, speeds_kept=lost(rows, silent))
    skipped = [r for r in results if r.skipped == "no recent motor_speeds"]
    assert len(skipped) >= len(silent) - 2
    gaps = [float(w.split()[2]) for r in results for w in r.warnings if w.startswith("gap of")]
    assert gaps == [pytest.approx(2.0, abs=0.03)]
    assert not alarms(results)


@pytest.mark.parametrize("late_rows", [45, 52, 53])
def test_rotor_speeds_that_come_late_go_with_their_own_time_or_with_none(x8, late_rows):
    """The speeds stream half a second behind the states, as a loaded node got it (test_soak in CI).

    Reports at 50 Hz, each delivered ``late_rows`` rows (10 ms each) after the state of its time. Within
    ``max_wait_s`` (0.5 s) a state waits for the report after it and gets interpolated speeds; a state
    that waited longer has none of its time and is skipped. Pairing it with the report before it, up to
    25 ms old, as the monitor did, raised stopped-rotor alarms on this flight's steps at 52 and 53 rows.
    """
    rows = flight(x8.name)
    deliveries = []
    for k, (stamp, p, v, q, w, omega) in enumerate(rows):
        deliveries.append((k, 1, lambda m, a=(stamp, p, v, q, w): m.state(*a)))
        if k % 2 == 0:
            deliveries.append((k + late_rows, 0, lambda m, a=(stamp, omega): m.rotor_speeds(*a)))
    monitor = FlightMonitor(x8, [])
    results: list[StepResult] = []
    for _, _, deliver in sorted(deliveries, key=lambda d: d[:2]):
        outcome = deliver(monitor)
        results += outcome if isinstance(outcome, list) else []
    assert not alarms(results)
    waited_s = late_rows * (rows[1][0] - rows[0][0]) / NS
    if waited_s <= monitor.settings.max_wait_s:
        assert judged_share(results, rows) > 0.6
    else:
        landing_s = SETPOINTS[-1][0]
        flying = [r for r in results if TAKE_OFF_S <= (r.stamp_ns - ORIGIN_NS) / NS < landing_s]
        assert flying and {r.skipped for r in flying} == {"no recent motor_speeds"}, {
            r.skipped for r in flying
        }


# ------------------------------------------------------------------ real faults are still found


FAULT_FLIGHT_S = 6.0


@pytest.fixture(scope="module")
def stopped_rotor_3(x8) -> Callable[[float], list[Row]]:
    """Rows of an X8 flight at altitude whose rotor 3 stops at the given time (flown once per onset)."""
    flown: dict[float, list[Row]] = {}

    def rows(onset_s: float) -> list[Row]:
        if onset_s not in flown:
            log = fly_case(x8, FaultCase(3, 0.0, onset_s, seed=21), duration_s=FAULT_FLIGHT_S)
            flown[onset_s] = list(samples(log))
        return flown[onset_s]

    return rows


def relearnt_after(monitor: FlightMonitor) -> float:
    """[s] from the first sample after a gap until alarms may come again: settling, then the noise."""
    return monitor.diagnoser.settle_s + monitor.diagnoser.detector.settings.relearn_s


def first_alarm(results: list[StepResult]) -> tuple[float, int]:
    """(t [s of the flight], rotor 1..N) of the first alarm; fails the test without one."""
    alarmed = [r for r in results if r.detection is not None and r.detection.alarm[0]]
    assert alarmed, "no alarm"
    return (alarmed[0].stamp_ns - ORIGIN_NS) * 1e-9, int(alarmed[0].detection.rotor[0]) + 1


def test_a_fault_after_a_gap_is_found_once_the_noise_is_learnt_again(x8, stopped_rotor_3):
    gap = range(250, 280)  # 2.5-2.8 s, both streams
    monitor = FlightMonitor(x8, ["quadratic_drag"])
    onset_s = 2.8 + relearnt_after(monitor) + 0.3
    rows = stopped_rotor_3(onset_s)
    results = replay(monitor, rows, lost(rows, gap), lost(rows, gap))
    gaps = [float(w.split()[2]) for r in results for w in r.warnings if w.startswith("gap of")]
    assert gaps == [pytest.approx(0.31)]
    detected_s, rotor = first_alarm(results)
    assert rotor == 3 and 0.0 < detected_s - onset_s <= 0.2


def test_a_fault_that_came_during_a_gap_is_found_when_the_noise_is_learnt_again(x8, stopped_rotor_3):
    """Rotor 3 stops in the middle of the gap: not taken for noise, found as soon as alarms may come."""
    monitor = FlightMonitor(x8, ["quadratic_drag"])
    rows = stopped_rotor_3(2.65)
    results = replay(monitor, rows[:250])
    learnt = monitor.identifier.n_samples
    results += replay(monitor, rows[280:])  # 2.5-2.8 s lost, both streams
    detected_s, rotor = first_alarm(results)
    assert rotor == 3
    # Nor was the fault learnt as a thrust constant meanwhile: blind, the identifier learns nothing.
    assert monitor.identifier.n_samples == learnt
    # Alarms may come again 2.8 s + settling + relearning: this one comes with the first sample allowed.
    assert detected_s == pytest.approx(2.8 + relearnt_after(monitor), abs=0.015)


def test_a_fault_without_breaks_is_found_as_fast_as_before(x8, stopped_rotor_3):
    monitor = FlightMonitor(x8, ["quadratic_drag"])
    results = replay(monitor, stopped_rotor_3(4.0))
    detected_s, rotor = first_alarm(results)
    assert rotor == 3 and 0.0 < detected_s - 4.0 <= 0.2


# ------------------------------------------------------------------ the input watch


MS = 1_000_000


def test_a_silent_input_is_named_once_with_the_ones_still_coming_and_its_return_is_said():
    watch = InputWatch(["motor_speeds", "odom"], timeout_s=1.0)
    assert watch.status().level == "OK" and "waiting for the first message" in watch.status().message
    lines = []
    for k in range(300):  # 3 s of checks every 10 ms; motor_speeds stops at 0.5 s
        now = k * 10 * MS
        watch.heard("odom", now, now)
        if k < 50:
            watch.heard("motor_speeds", now, now)
        lines += watch.check(now, now)
    assert len(lines) == 1
    assert lines[0].startswith("no motor_speeds for 1.0") and "while odom keep" in lines[0]
    status = watch.status()
    assert status.level == "WARN" and status.message.startswith("silent: motor_speeds for 2.5 s")
    assert "odom still coming" in status.message and status.values["silent"] == "motor_speeds"
    back = watch.heard("motor_speeds", 3000 * MS, 3000 * MS)
    assert back == "motor_speeds is back after 2.5 s of silence"
    watch.check(3010 * MS, 3010 * MS)
    assert watch.status().level == "OK" and watch.status().message == "receiving motor_speeds, odom"


def test_when_everything_stops_the_stopped_clock_is_said_and_wall_time_counts():
    """The simulator stalls: no message and no clock; silence is measured in wall time."""
    watch = InputWatch(["motor_speeds", "pose", "imu"], timeout_s=0.5)
    for name in ("motor_speeds", "pose", "imu"):
        watch.heard(name, 5 * NS, 0)
    lines = []
    for k in range(1, 12):  # checks every 0.1 s of wall time; the clock stands at 5 s
        lines += watch.check(5 * NS, k * 100 * MS)
    assert len(lines) == 3
    assert "nor any other input" in lines[-1] and "the clock has not moved for" in lines[-1]
    assert "the clock has not moved" in watch.status().message


def test_an_input_never_heard_is_silent_once_another_comes_and_a_late_check_judges_nothing():
    watch = InputWatch(["motor_speeds", "odom"], timeout_s=1.0)
    assert watch.check(0, 0) == []  # nothing heard yet: peers still starting
    watch.heard("odom", 0, 0)
    # This node stalled for 2 s (its executor did not run): the check cannot tell silence from that.
    assert watch.check(2 * NS, 2 * NS) == []
    watch.heard("odom", 2 * NS + 10 * MS, 2 * NS + 10 * MS)
    lines = watch.check(2 * NS + 200 * MS, 2 * NS + 200 * MS)
    assert len(lines) == 1 and lines[0].startswith("no motor_speeds for 2.2 s")


def test_resends_are_counted_do_not_end_a_silence_and_the_silence_says_its_publisher_waits():
    """A lockstep simulator waiting for a command: no new data, its newest odometry again every 0.25 s."""
    watch = InputWatch(["motor_speeds", "odom"], timeout_s=1.0)
    for name in ("motor_speeds", "odom"):
        watch.heard(name, 5 * NS, 0)
    lines = []
    for k in range(1, 16):  # checks every 0.1 s of wall time; the clock stands at 5 s
        if k % 3 == 0:
            watch.resent("odom")
        lines += watch.check(5 * NS, k * 100 * MS)
    assert len(lines) == 2
    odom = next(line for line in lines if line.startswith("no odom"))
    assert "only its last message came again (3 times): its publisher is alive and waits" in odom
    assert "may be stalled" not in odom
    assert watch.status().values["odom_resent"] == "5" and watch.status().values["motor_speeds_resent"] == "0"
    assert watch.heard("odom", 5 * NS + 4 * MS, 1600 * MS) == "odom is back after 1.6 s of silence"


def test_a_clock_that_goes_back_gives_no_negative_silence():
    watch = InputWatch(["motor_speeds", "odom"], timeout_s=1.0)
    for name in ("motor_speeds", "odom"):
        watch.heard(name, 100 * NS, 0)
    assert watch.check(1 * NS, 200 * MS) == []  # simulated time restarted from 1 s
    assert watch.status().values["odom_silent_s"] == "0.20"


def test_input_watch_refuses_a_timeout_that_is_not_positive():
    with pytest.raises(ValueError, match="timeout_s must be > 0"):
        InputWatch(["odom"], timeout_s=0.0)
    with pytest.raises(ValueError, match="timeout_s must be > 0"):
        InputWatch(["odom"], timeout_s=math.nan)


# ------------------------------------------------------------------ the per-sample arithmetic


@given(
    values=st.lists(st.floats(-1e9, 1e9, allow_nan=False), min_size=1, max_size=80),
    sizes=st.lists(st.lists(st.floats(0.0, 1e3), min_size=6, max_size=6), min_size=1, max_size=260),
)
def test_the_monitors_fast_quartile_and_the_gates_ring_give_numpys_numbers_to_the_bit(values, sizes):
    """Both run once per sample (the identifier keeps up with a lockstep simulator with them)."""
    assert lower_quartile(np.array(values)) == float(np.quantile(values, 0.25))
    gate, recent = InnovationGate(memory=20), []
    for size in sizes:
        verdict = gate.judge(np.array(size))
        recent = [*recent, np.array(size)][-20:]
        if len(recent) >= 5:
            noise = _MEDIAN_ABS_TO_SIGMA * np.median(np.stack(recent), axis=0)
            surprised = np.any(np.array(size) > np.maximum(gate.sigma * noise, gate.floor))
            assert (verdict == "usual") == (not surprised)


# ------------------------------------------------------------------ support or free flight


def one_sample(airframe: Airframe, z_m: float, thrust_share: float, v_z: float = 0.0, roll_deg: float = 0.0):
    omega = math.sqrt(thrust_share * airframe.mass_kg * 9.81 / (airframe.k_f_N_s2 * airframe.n_rotors))
    x = S.make_state(airframe.n_rotors, position_m=(0.0, 0.0, z_m), velocity_m_s=(0.0, 0.0, v_z))
    half = math.radians(roll_deg) / 2
    x[0, S.QUATERNION] = (math.cos(half), math.sin(half), 0.0, 0.0)
    return S.StateBatch.from_flat(0.0, x, np.full((1, airframe.n_rotors), omega))


def test_on_the_ground_at_hover_thrust_is_support_and_the_same_in_the_air_is_flight(x8):
    watch = SupportWatch(x8, 9.81)
    assert watch.support(0, one_sample(x8, 0.0, 1.0, v_z=-0.3)) is None  # coming down, not there yet
    assert watch.support(0, one_sample(x8, 0.0, 1.0)).startswith("on the ground at z = 0.00 m")
    # Once there, a vertical speed without the thrust to leave is the sensors' noise.
    assert watch.support(0, one_sample(x8, 0.01, 1.0, v_z=0.15)) is not None
    assert watch.support(0, one_sample(x8, 0.0, 1.2)) is None  # more than the weight: it lifts off
    assert watch.support(0, one_sample(x8, 0.2, 1.0, v_z=0.5)) is None  # climbing away
    assert watch.support(0, one_sample(x8, 3.0, 1.0)) is None  # hovering


def test_a_moment_of_stillness_with_low_thrust_in_the_air_is_flight_a_longer_one_support(x8):
    """The top of a descent step is still and below the weight for a moment; held, it stays so."""
    watch = SupportWatch(x8, 9.81)
    period_ns = 10_000_000
    confirm = round(HELD_CONFIRM_S * NS / period_ns)
    verdicts = [watch.support(k * period_ns, one_sample(x8, 3.0, 0.7)) for k in range(confirm + 2)]
    assert verdicts[:confirm] == [None] * confirm
    assert verdicts[confirm].startswith("not moving for 0.2 s, thrust 70 % of the weight")
    # Held there, that height is now the ground: hovering within two rotor radii of it is support.
    assert watch.support(0, one_sample(x8, 3.1, 1.0)) is not None
    assert watch.support(0, one_sample(x8, 3.5, 1.0)) is None


def test_lying_on_its_side_with_rotors_running_is_support(x8):
    watch = SupportWatch(x8, 9.81)
    assert "tilted 90 deg" in watch.support(0, one_sample(x8, 0.0, 3.0, roll_deg=90.0))


# ------------------------------------------------------------------ over ROS 2, in lockstep


def inputs_status(message: DiagnosticArray) -> DiagnosticStatus | None:
    return next((s for s in message.status if s.name == "inputs"), None)


def resends(message: DiagnosticArray) -> int:
    """How many odometry resends the identifier counted, by its ``inputs`` status (0 without one)."""
    status = inputs_status(message)
    return 0 if status is None else int({kv.key: kv.value for kv in status.values}.get("odom_resent", 0))


@pytest.mark.ros
def test_in_lockstep_from_the_ground_through_steps_and_resends_no_alarm_then_a_fault_is_named(
    tmp_path, ros_probe: RosProbe
) -> None:
    """Simulator, controller and identifier as the launch file starts them (lockstep, use_sim_time).

    The controller starts last: until its first command the simulator waits at t = 0 and resends its
    odometry, which the identifier counts without a word. Then the X8 waits on the ground with no
    setpoint, takes off and flies the issue's steps: no alarm. Then rotor 3 stops and is named.
    """
    diagnostics = ros_probe.subscribe("/g1/diagnostics", DiagnosticArray)
    truth = ros_probe.subscribe("/g1/injected_faults", DiagnosticArray)
    odom = ros_probe.subscribe("/g1/odom", Odometry)
    simulator = NodeProcess(
        "simulator",
        tmp_path / "simulator.log",
        namespace="/g1",
        parameters={"real_time_factor": 0.0, "publish_clock": True, "seed": 5, "initial_z": 0.0},
    )
    identifier = NodeProcess(
        "identifier", tmp_path / "identifier.log", namespace="/g1", parameters={"use_sim_time": True}
    )
    controller = None
    try:
        diagnostics.wait_for(lambda m: resends(m) >= 3, timeout=120.0)
        controller = NodeProcess(
            "controller", tmp_path / "controller.log", namespace="/g1", parameters={"use_sim_time": True}
        )
        vehicle = Vehicle("/g1", simulator, controller, odom, ros_probe)
        vehicle.until(3.0)  # on the ground, rotors at hover thrust, no setpoint
        vehicle.fly_to(0.0, 0.0, 2.0)
        vehicle.until(stamp_s(vehicle.latest()) + 4.0)
        vehicle.fly_to(1.0, 2.0, 3.0)
        vehicle.until(stamp_s(vehicle.latest()) + 4.0)
        vehicle.fly_to(-1.0, -2.0, 2.0, yaw=math.pi / 2)
        vehicle.until(stamp_s(vehicle.latest()) + 5.0)

        def settled(message: DiagnosticArray) -> bool:
            statuses = rotor_statuses(message)
            return len(statuses) == 8 and all("no verdict" not in s.message for s in statuses)

        diagnostics.wait_for(settled, timeout=60.0)
        flown = [s for m in diagnostics.messages for s in rotor_statuses(m)]
        assert flown and all(s.level == DiagnosticStatus.OK for s in flown), {
            s.message for s in flown if s.level != DiagnosticStatus.OK
        }
        log = identifier.log_text()
        assert "rotor fault" not in log and "duplicated stamp" not in log, log[-3000:]
        # While it waited for the controller: the simulator is alive, only waiting.
        assert "only its last message came again" in log

        (result,) = ros_probe.set_parameters("/g1/simulator", {"fault_motor": 3}).values()
        assert result.successful

        def rotor_3_error(message: DiagnosticArray) -> bool:
            return any(s.name == "rotor_3" and s.level == DiagnosticStatus.ERROR for s in message.status)

        named = diagnostics.wait_for(rotor_3_error, timeout=60.0)[-1]
        assert all(s.level == DiagnosticStatus.OK for s in rotor_statuses(named) if s.name != "rotor_3")
        injected_at = stamp_to_ns(truth.wait_for(rotor_3_error, timeout=30.0)[0].header.stamp) * 1e-9
        faulty = next(s for s in named.status if s.name == "rotor_3")
        detected_at = float(next(kv.value for kv in faulty.values if kv.key == "detected_at_s"))
        assert 0.0 < detected_at - injected_at <= 0.3, (injected_at, detected_at)
        identifier.assert_running()
    finally:
        failures = []
        for process in (controller, identifier, simulator):
            try:
                if process is not None:
                    process.stop()
            except AssertionError as error:
                failures.append(str(error))
        assert not failures, "\n\n".join(failures)
