"""The pure vehicle simulation, setpoint files and the ``multirotor simulate`` command.

Ground contact, command clamp, rotor lag, watchdog, fault injection, sensor statistics, pacing rules;
fleets (several vehicles in one simulator): per-vehicle commands, faults and watchdogs, and each vehicle
reading exactly what it reads when simulated alone.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from multirotor_ros.cli import main as cli_main
from multirotor_ros.io.flight_log import read_flight_log
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import airframe_from_dict, load_airframe
from multirotor_ros.model.rotation import euler_to_quat, quat_multiply, quat_to_matrix
from multirotor_ros.simulation.flight import (
    ControlTrace,
    FaultTolerance,
    ReportedFault,
    SetpointError,
    read_setpoints,
    simulate_flight,
)
from multirotor_ros.simulation.pacing import RealTimePacer
from multirotor_ros.simulation.sensors import (
    Imu,
    ImuReading,
    SensorConfig,
    range_readings,
    sensor_config_from_section,
)
from multirotor_ros.simulation.vehicle import NS_PER_S, Reading, VehicleSimulator, vehicle_generators

MS = 1_000_000


@pytest.fixture(scope="module")
def x8():
    return load_airframe("x8_octorotor")


def make_sim(airframe, **options) -> VehicleSimulator:
    options.setdefault("rng", np.random.default_rng(0))
    return VehicleSimulator(airframe, **options)


# ------------------------------------------------------------------ ground contact


def test_a_vehicle_with_rotors_off_rests_on_the_ground(x8) -> None:
    sim = make_sim(x8)
    sim.run_until(2 * NS_PER_S)
    np.testing.assert_array_equal(sim.state[S.POSITION], 0.0)
    np.testing.assert_array_equal(sim.state[S.VELOCITY], 0.0)


@pytest.mark.parametrize(("thrust_ratio", "lifts"), [(0.98, False), (1.02, True)])
def test_it_takes_off_only_when_thrust_exceeds_weight(x8, thrust_ratio: float, lifts: bool) -> None:
    sim = make_sim(x8, effects=[], motor_lag=False, command_timeout_s=0.0)
    sim.set_command(np.full(8, sim.hover_speed_rad_s * math.sqrt(thrust_ratio)))
    sim.run_until(NS_PER_S)
    assert (sim.state[2] > 0.05) == lifts
    assert sim.state[2] >= 0.0
    if not lifts:
        assert sim.acceleration_W()[2] == 0.0  # the ground holds it: the IMU feels 1 g, not free fall


def test_a_vehicle_placed_in_the_air_starts_at_hover_speed(x8) -> None:
    sim = make_sim(x8, initial_position_m=(1.0, 2.0, 3.0), command_timeout_s=0.0)
    sim.run_until(NS_PER_S // 2)
    assert sim.state[2] == pytest.approx(3.0, abs=0.02)
    np.testing.assert_allclose(sim.state[S.ROTORS_START :], sim.hover_speed_rad_s, rtol=1e-6)


# ------------------------------------------------------------------ commands


def test_commands_are_clamped_to_the_speed_range(x8) -> None:
    sim = make_sim(x8)
    applied = sim.set_command([-5.0, 0.0, 100.0, 650.0, 700.0, 1e4, 300.0, 1.0])
    np.testing.assert_array_equal(applied, [0.0, 0.0, 100.0, 650.0, 650.0, 650.0, 300.0, 1.0])


@pytest.mark.parametrize("bad", [[1.0] * 7, [math.nan] + [1.0] * 7, [math.inf] * 8])
def test_commands_that_are_not_n_finite_speeds_raise(x8, bad) -> None:
    with pytest.raises(ValueError, match="8 finite rotor speeds"):
        make_sim(x8).set_command(bad)


def test_rotor_speed_follows_its_command_with_the_motor_time_constant(x8) -> None:
    sim = make_sim(x8, command_timeout_s=0.0)
    sim.set_command(np.full(8, 400.0))
    sim.run_until(round(x8.motor_time_constant_s * NS_PER_S))
    np.testing.assert_allclose(sim.state[S.ROTORS_START :], 400.0 * (1 - math.exp(-1)), rtol=1e-3)


def test_without_motor_lag_rotors_take_the_command_at_once(x8) -> None:
    sim = make_sim(x8, motor_lag=False)
    sim.set_command(np.full(8, 400.0))
    sim.run_until(MS)
    np.testing.assert_array_equal(sim.state[S.ROTORS_START :], 400.0)


# ------------------------------------------------------------------ watchdog


def test_the_watchdog_stops_the_rotors_once_per_silence(x8) -> None:
    sim = make_sim(x8, command_timeout_s=0.2, motor_lag=False)
    sim.set_command(np.full(8, 300.0))
    readings = sim.run_until(NS_PER_S // 10)
    assert not any(r.kind == "watchdog" for r in readings)
    readings = sim.run_until(NS_PER_S)
    notices = [r for r in readings if r.kind == "watchdog"]
    assert [r.t_ns for r in notices] == [200 * MS]
    assert notices[0].data == pytest.approx(0.2)
    np.testing.assert_array_equal(sim.command_rad_s, 0.0)
    sim.set_command(np.full(8, 300.0))
    assert sum(r.kind == "watchdog" for r in sim.run_until(2 * NS_PER_S)) == 1


def test_a_zero_timeout_disables_the_watchdog(x8) -> None:
    sim = make_sim(x8, command_timeout_s=0.0)
    sim.set_command(np.full(8, 300.0))
    assert not any(r.kind == "watchdog" for r in sim.run_until(5 * NS_PER_S))


# ------------------------------------------------------------------ fault injection


def test_an_injected_fault_removes_that_rotors_thrust(x8) -> None:
    sim = make_sim(x8, effects=[], motor_lag=False, initial_position_m=(0, 0, 5), command_timeout_s=0.0)
    sim.run_until(10 * MS)
    sim.inject_fault(3, 0.0)
    np.testing.assert_array_equal(sim.injected_effectiveness(), [1, 1, 0, 1, 1, 1, 1, 1])
    sim.run_until(20 * MS)
    # One rotor of eight lost at hover: 1/8 of g missing, and rotor 3 (rear right) tips the vehicle.
    assert sim.acceleration_W()[2] == pytest.approx(-9.81 / 8, rel=0.02)
    # Rear right lost: the right side drops (positive roll about +x, FLU) and the tail drops (nose up:
    # negative pitch about +y).
    assert sim.state[S.BODY_RATE][0] > 0
    assert sim.state[S.BODY_RATE][1] < 0
    sim.inject_fault(0, 0.0)
    np.testing.assert_array_equal(sim.injected_effectiveness(), 1.0)


@pytest.mark.parametrize(("motor", "effectiveness"), [(9, 0.5), (-1, 0.5), (1, 1.5), (1, -0.1)])
def test_impossible_faults_are_refused(x8, motor: int, effectiveness: float) -> None:
    with pytest.raises(ValueError, match="fault"):
        make_sim(x8).inject_fault(motor, effectiveness)


def test_a_hidden_fault_in_the_effects_is_reported_from_its_time_on(x8) -> None:
    fault = {"id": "actuator_fault", "motor": 2, "effectiveness": 0.5, "t_fault_s": 0.5}
    sim = make_sim(x8, effects=[fault])
    assert sim.injected_effectiveness()[1] == 1.0
    sim.run_until(NS_PER_S)
    assert sim.injected_effectiveness()[1] == 0.5


# ------------------------------------------------------------------ sensors


def _readings(sim, kind, until_ns):
    return [r.data for r in sim.run_until(until_ns) if r.kind == kind]


def test_the_imu_at_rest_reads_one_g_up_with_datasheet_noise(x8) -> None:
    config = SensorConfig()
    sim = make_sim(x8, rng=np.random.default_rng(7))
    readings = _readings(sim, "imu", 20 * NS_PER_S)
    assert len(readings) == 2001  # 100 Hz, t = 0 included
    force = np.array([r.specific_force_B for r in readings])
    gyro = np.array([r.w_WB_B for r in readings])
    white_accel = config.accel_noise_density_m_s2_sqrt_hz * math.sqrt(config.imu_rate_hz)
    white_gyro = config.gyro_noise_density_rad_s_sqrt_hz * math.sqrt(config.imu_rate_hz)
    # Differences of successive samples remove the slowly walking bias: their std is sqrt(2) x white noise.
    assert np.std(np.diff(force, axis=0)) / math.sqrt(2) == pytest.approx(white_accel, rel=0.1)
    assert np.std(np.diff(gyro, axis=0)) / math.sqrt(2) == pytest.approx(white_gyro, rel=0.1)
    # The mean is 1 g up plus a bias of the datasheet's initial size (a few sigma at most).
    np.testing.assert_allclose(force.mean(axis=0), [0, 0, 9.81], atol=4 * config.accel_bias_initial_m_s2)
    assert np.all(np.abs(gyro.mean(axis=0)) < 4 * config.gyro_bias_initial_rad_s)


def test_without_noise_the_imu_reads_the_truth(x8) -> None:
    sim = make_sim(x8, noise=False, initial_position_m=(0, 0, 2), command_timeout_s=0.0, motor_lag=False)
    sim.set_command(np.full(8, sim.hover_speed_rad_s * 1.1))
    reading = _readings(sim, "imu", 100 * MS)[-1]
    thrust_acceleration = 8 * x8.k_f_N_s2 * (sim.hover_speed_rad_s * 1.1) ** 2 / x8.mass_kg
    np.testing.assert_allclose(reading.specific_force_B, [0, 0, thrust_acceleration], rtol=1e-6, atol=1e-9)


finite = st.floats(-20.0, 20.0)


@settings(max_examples=60, deadline=None)
@given(
    attitude=st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
    acceleration=st.lists(finite, min_size=3, max_size=3),
    rate=st.lists(finite, min_size=3, max_size=3),
    normals=st.lists(st.floats(-4.0, 4.0), min_size=15, max_size=15),
)
def test_the_compiled_imu_is_its_numpy_definition(attitude, acceleration, rate, normals) -> None:
    """Bias walk, specific force R(q)^T (a + g e_z), white noise and the turned attitude, draw for draw."""
    config = SensorConfig(imu_rate_hz=400.0)
    q = np.array([attitude]) / np.linalg.norm(attitude)
    a, w, z = np.array([acceleration]), np.array([rate]), np.array([normals])
    initial = np.random.default_rng(0).standard_normal((1, Imu.INITIAL_DRAWS))
    imu = Imu(config, initial, 9.81)
    imu.sample(1.0, q, a, w, np.zeros((1, Imu.draws(config))))  # the first sample has no interval: no walk
    (reading,) = imu.sample(1.0025, q, a, w, z)
    walk = math.sqrt(0.0025 / config.BIAS_STABILITY_TIME_S)
    accel_bias = (
        config.accel_bias_initial_m_s2 * initial[0, 0:3] + config.accel_bias_stability_m_s2 * walk * z[0, 0:3]
    )
    gyro_bias = (
        config.gyro_bias_initial_rad_s * initial[0, 3:6] + config.gyro_bias_stability_rad_s * walk * z[0, 3:6]
    )
    np.testing.assert_allclose(imu.accel_bias[0], accel_bias, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(imu.gyro_bias[0], gyro_bias, rtol=1e-12, atol=1e-15)
    force = (
        quat_to_matrix(q[0]).T @ (a[0] + [0.0, 0.0, 9.81])
        + accel_bias
        + config.accel_sample_std_m_s2 * z[0, 6:9]
    )
    np.testing.assert_allclose(reading.specific_force_B, force, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(
        reading.w_WB_B, w[0] + gyro_bias + config.gyro_sample_std_rad_s * z[0, 9:12], atol=1e-12
    )
    turned = quat_multiply(q[0], euler_to_quat(config.orientation_noise_rad * z[0, 12:15]))
    np.testing.assert_allclose(reading.q_WB, turned / np.linalg.norm(turned), atol=1e-12)


def test_motion_capture_noise_is_about_a_millimetre(x8) -> None:
    sim = make_sim(x8, rng=np.random.default_rng(8))
    positions = np.array([p for p, _ in _readings(sim, "pose", 10 * NS_PER_S)])
    assert positions.std(axis=0) == pytest.approx([0.001] * 3, rel=0.15)


def _range(config: SensorConfig, height_m: float, roll_rad: float = 0.0) -> float:
    (distance,) = range_readings(config, np.array([[0.0, 0.0, height_m]]), euler_to_quat([[roll_rad, 0, 0]]))
    return float(distance)


def test_the_range_sensor_reads_height_plus_its_mount_offset() -> None:
    config = SensorConfig()
    assert _range(config, 0.0) == pytest.approx(0.09)  # 0.10 on a 3 cm grid
    assert _range(config, 1.0) == pytest.approx(1.11)
    assert _range(config, 1.0, roll_rad=0.3) == pytest.approx(1.14)  # 1/cos(0.3) + 0.1
    assert _range(config, 7.0) == math.inf
    assert _range(config, 1.0, roll_rad=0.6) == math.inf  # tilted beyond half the beam: no echo
    assert _range(config, 1.0, roll_rad=math.pi) == math.inf  # upside down: no echo, and no warning
    exact = dataclasses.replace(config, range_resolution_m=0.0)
    assert _range(exact, 0.5) == pytest.approx(0.6)
    # A batch of vehicles: each reads its own height.
    heights = np.array([[0, 0, 1.0], [5, 5, 2.0], [0, 0, 9.0]])
    level = np.tile([1.0, 0.0, 0.0, 0.0], (3, 1))
    np.testing.assert_allclose(range_readings(exact, heights, level), [1.1, 2.1, math.inf])


# Readings of one X8 in [0, 1 s] at its rates, both ends included; the range at 15 Hz has no 16th (it
# would fall at 1.000000005 s).
READINGS_IN_THE_FIRST_SECOND = {"odom": 251, "imu": 101, "pose": 101, "motor_speeds": 101, "range": 15}


def test_readings_come_at_their_rates(x8) -> None:
    sim = make_sim(x8)
    kinds = [r.kind for r in sim.run_until(NS_PER_S)]
    assert {kind: kinds.count(kind) for kind in set(kinds)} == READINGS_IN_THE_FIRST_SECOND


def test_the_same_generator_state_gives_the_same_readings(x8) -> None:
    first = [
        r.data for r in make_sim(x8, rng=np.random.default_rng(5)).run_until(NS_PER_S) if r.kind == "imu"
    ]
    second = [
        r.data for r in make_sim(x8, rng=np.random.default_rng(5)).run_until(NS_PER_S) if r.kind == "imu"
    ]
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a.specific_force_B, b.specific_force_B)


def test_a_sensors_section_overrides_defaults_and_refuses_unknown_keys() -> None:
    config = sensor_config_from_section({"imu_rate_hz": 200}, "a.yaml")
    assert config.imu_rate_hz == 200.0 and config.range_rate_hz == SensorConfig().range_rate_hz
    with pytest.raises(ValueError, match=r"a\.yaml: sensors\.imu_rate: unknown key"):
        sensor_config_from_section({"imu_rate": 200}, "a.yaml")
    with pytest.raises(ValueError, match=r"a\.yaml: sensors\.imu_rate_hz: must be a finite number > 0"):
        sensor_config_from_section({"imu_rate_hz": 0}, "a.yaml")
    with pytest.raises(ValueError, match=r"a\.yaml: sensors\.range_max_m: expected a number"):
        sensor_config_from_section({"range_max_m": "far"}, "a.yaml")


def test_every_shipped_airframe_has_a_valid_sensors_section() -> None:
    from multirotor_ros.resources import available_airframes
    from multirotor_ros.simulation.sensors import airframe_sensor_config

    for name in available_airframes():
        assert airframe_sensor_config(load_airframe(name)).imu_rate_hz > 0


# ------------------------------------------------------------------ fleets

POSES = [((0.0, 0.0, 2.0), 0.0), ((3.0, 0.0, 0.0), 1.0), ((0.0, 4.0, 1.5), -2.0)]


def _fleet(airframe, seed: int, poses=POSES, **options) -> VehicleSimulator:
    return VehicleSimulator(
        airframe,
        rng=vehicle_generators(seed, len(poses)),
        initial_position_m=[p for p, _ in poses],
        initial_yaw_rad=[yaw for _, yaw in poses],
        **options,
    )


def _alone(airframe, seed: int, k: int, poses=POSES, **options) -> VehicleSimulator:
    """Vehicle k of ``_fleet(airframe, seed, poses)``, simulated on its own with the same generator."""
    position, yaw = poses[k]
    return VehicleSimulator(
        airframe,
        rng=vehicle_generators(seed, len(poses))[k],
        initial_position_m=position,
        initial_yaw_rad=yaw,
        **options,
    )


def _fly(sim: VehicleSimulator, vehicles: dict[int, int], plan, until_ns: int, period_ns: int) -> list:
    """Fly ``plan(vehicle, t_ns)`` -> ("command", speeds) | ("fault", (motor, effectiveness)) | None.

    ``vehicles``: the plan's vehicle number -> the index in ``sim`` (a fleet: the same; alone: 0).
    """
    readings = sim.run_until(0)
    for t_ns in range(period_ns, until_ns + 1, period_ns):
        for vehicle, index in vehicles.items():
            action = plan(vehicle, t_ns)
            if action is not None and action[0] == "command":
                sim.set_command(action[1], vehicle=index)
            elif action is not None:
                sim.inject_fault(*action[1], vehicle=index)
        readings += sim.run_until(t_ns)
    return readings


def _values(reading: Reading) -> np.ndarray:
    data = reading.data
    if isinstance(data, ImuReading):
        return np.concatenate([data.q_WB, data.specific_force_B, data.w_WB_B])
    if isinstance(data, tuple):
        return np.concatenate(data)
    return np.atleast_1d(np.asarray(data, dtype=float))


def _assert_same_readings(fleet_readings: list, k: int, alone_readings: list) -> None:
    mine = [r for r in fleet_readings if r.vehicle == k]
    assert [(r.kind, r.t_ns) for r in mine] == [(r.kind, r.t_ns) for r in alone_readings]
    assert all(r.vehicle == 0 for r in alone_readings)
    for a, b in zip(mine, alone_readings, strict=True):
        np.testing.assert_array_equal(_values(a), _values(b), err_msg=f"vehicle {k}, {a.kind} at {a.t_ns}")


def _plan(hover: float):
    """Each vehicle its own command wave; vehicle 1 loses 60 % of rotor 3 at 0.4 s; 2 goes silent at 0.3 s."""

    def plan(vehicle: int, t_ns: int):
        if vehicle == 1 and t_ns == 400 * MS:
            return ("fault", (3, 0.4))
        if vehicle == 2 and t_ns > 300 * MS:
            return None
        return ("command", np.full(8, hover * (1.0 + 0.02 * math.sin(t_ns / 1e8 + vehicle))))

    return plan


def test_each_vehicle_of_a_fleet_reads_exactly_what_it_reads_alone(x8) -> None:
    # Three vehicles in different places, each with its own commands; one gets a fault, one loses its
    # commands (its watchdog trips): vehicle k's readings are those of vehicle k simulated alone with the
    # same generator, bit for bit.
    fleet = _fleet(x8, seed=7)
    plan = _plan(fleet.hover_speed_rad_s)
    together = _fly(fleet, {0: 0, 1: 1, 2: 2}, plan, 1200 * MS, 4 * MS)
    assert {r.vehicle for r in together} == {0, 1, 2}
    for k in range(3):
        alone = _fly(_alone(x8, 7, k), {k: 0}, plan, 1200 * MS, 4 * MS)
        _assert_same_readings(together, k, alone)
    assert [(r.vehicle, r.t_ns) for r in together if r.kind == "watchdog"] == [(2, 796 * MS)]


@settings(max_examples=12, deadline=None)
@given(
    count=st.integers(1, 4),
    seed=st.integers(0, 2**32 - 1),
    speeds=st.lists(st.floats(0.0, 650.0), min_size=8, max_size=8),
    fault=st.tuples(st.integers(0, 8), st.floats(0.0, 1.0), st.integers(1, 20)),
    data=st.data(),
)
def test_a_vehicle_reads_the_same_in_any_fleet(count, seed, speeds, fault, data) -> None:
    # Whatever the fleet's size, the vehicle looked at, its commands and its fault, vehicle k flies and
    # reads as it does alone; the other vehicles (commanded differently, or not at all) change nothing.
    x8 = load_airframe("x8_octorotor")
    k = data.draw(st.integers(0, count - 1), label="vehicle")
    poses = [((float(i), 0.0, 1.0 + 0.5 * i), 0.3 * i) for i in range(count)]
    motor, effectiveness, fault_period = fault

    def plan(vehicle: int, t_ns: int):
        if vehicle == k and t_ns == fault_period * 5 * MS:
            return ("fault", (motor, effectiveness))
        if vehicle != k and vehicle % 2:
            return None  # silent: its watchdog trips
        scale = 1.0 if vehicle == k else 0.9 + 0.05 * vehicle
        return ("command", np.asarray(speeds) * scale)

    options = {"command_timeout_s": 0.05}
    fleet = VehicleSimulator(
        x8,
        rng=vehicle_generators(seed, count),
        initial_position_m=[p for p, _ in poses],
        initial_yaw_rad=[yaw for _, yaw in poses],
        **options,
    )
    together = _fly(fleet, {i: i for i in range(count)}, plan, 150 * MS, 5 * MS)
    alone = _fly(_alone(x8, seed, k, poses, **options), {k: 0}, plan, 150 * MS, 5 * MS)
    _assert_same_readings(together, k, alone)


def test_a_fleet_reads_every_vehicle_at_the_same_times(x8) -> None:
    fleet = _fleet(x8, seed=1, command_timeout_s=0.0)
    readings = fleet.run_until(NS_PER_S)
    for k in range(3):
        kinds = [r.kind for r in readings if r.vehicle == k]
        assert {kind: kinds.count(kind) for kind in set(kinds)} == READINGS_IN_THE_FIRST_SECOND
    # Within one time, kind after kind, vehicle 0 first.
    first = [(r.kind, r.vehicle) for r in readings if r.t_ns == 0]
    assert first[:6] == [("odom", 0), ("odom", 1), ("odom", 2), ("imu", 0), ("imu", 1), ("imu", 2)]
    # Each vehicle where it was placed: 0 and 2 hover in the air, 1 rests on the ground.
    odom = {r.vehicle: r.data for r in readings if r.kind == "odom" and r.t_ns == NS_PER_S}
    for k, (position, _) in enumerate(POSES):
        np.testing.assert_allclose(odom[k][S.POSITION], position, atol=0.05)
    np.testing.assert_allclose(
        fleet.x[:, S.ROTORS_START], [fleet.hover_speed_rad_s, 0.0, fleet.hover_speed_rad_s]
    )


def test_a_vehicle_losing_its_commands_stops_only_its_own_rotors(x8) -> None:
    fleet = _fleet(x8, seed=2, command_timeout_s=0.2, motor_lag=False)
    hover = np.full(8, fleet.hover_speed_rad_s)
    readings = []
    for t_ns in range(0, 600 * MS, 10 * MS):
        for k in (0, 1) if t_ns > 100 * MS else (0, 1, 2):
            fleet.set_command(hover, vehicle=k)  # vehicle 2's last command: at 0.1 s
        readings += fleet.run_until(t_ns + 10 * MS)
    notices = [r for r in readings if r.kind == "watchdog"]
    assert [(r.vehicle, r.t_ns) for r in notices] == [(2, 300 * MS)]
    assert notices[0].data == pytest.approx(0.2)
    np.testing.assert_array_equal(fleet.watchdog_tripped, [False, False, True])
    np.testing.assert_array_equal(fleet.commands_rad_s[2], 0.0)
    np.testing.assert_array_equal(fleet.x[2, S.ROTORS_START :], 0.0)
    np.testing.assert_array_equal(fleet.commands_rad_s[:2], [hover, hover])
    np.testing.assert_array_equal(fleet.x[:2, S.ROTORS_START :], [hover, hover])
    # Commanded again, it is re-armed: one notice per silence.
    fleet.set_command(hover, vehicle=2)
    assert not fleet.watchdog_tripped[2]


def test_a_fault_acts_on_its_own_vehicle_only(x8) -> None:
    poses = [((0.0, 0.0, 5.0), 0.0)] * 3
    fleet = _fleet(x8, seed=3, poses=poses, effects=[], motor_lag=False, command_timeout_s=0.0)
    fleet.run_until(10 * MS)
    fleet.inject_fault(3, 0.0, vehicle=1)
    np.testing.assert_array_equal(fleet.injected_effectiveness(vehicle=1), [1, 1, 0, 1, 1, 1, 1, 1])
    np.testing.assert_array_equal(fleet.injected_effectiveness(vehicle=0), 1.0)
    np.testing.assert_array_equal(fleet.injected_effectiveness(vehicle=2), 1.0)
    fleet.run_until(20 * MS)
    assert fleet.acceleration_W(vehicle=1)[2] == pytest.approx(-9.81 / 8, rel=0.02)
    for k in (0, 2):
        assert fleet.acceleration_W(vehicle=k)[2] == pytest.approx(0.0, abs=1e-6)
        np.testing.assert_allclose(fleet.x[k, S.BODY_RATE], 0.0, atol=1e-9)
    assert fleet.x[1, S.BODY_RATE][0] > 0
    fleet.inject_fault(0, 0.0, vehicle=1)
    np.testing.assert_array_equal(fleet.injected_effectiveness(vehicle=1), 1.0)


def test_a_hidden_fault_of_the_effects_acts_on_every_vehicle_until_replaced(x8) -> None:
    fault = {"id": "actuator_fault", "motor": 2, "effectiveness": 0.5, "t_fault_s": 0.5}
    fleet = _fleet(x8, seed=4, effects=[fault])
    fleet.inject_fault(0, 0.0, vehicle=2)  # repaired before it strikes
    fleet.run_until(NS_PER_S)
    assert [fleet.injected_effectiveness(vehicle=k)[1] for k in range(3)] == [0.5, 0.5, 1.0]


def test_every_vehicle_has_its_own_noise_and_imu_bias(x8) -> None:
    poses = [((0.0, 0.0, 0.0), 0.0)] * 3
    readings = _fleet(x8, seed=5, poses=poses).run_until(NS_PER_S)
    forces = [
        np.array([r.data.specific_force_B for r in readings if r.kind == "imu" and r.vehicle == k])
        for k in range(3)
    ]
    # The same truth (all at rest), three different biases and noise sequences.
    means = [f.mean(axis=0) for f in forces]
    assert len({tuple(np.round(m, 6)) for m in means}) == 3
    assert not np.any(np.isclose(forces[0] - means[0], forces[1] - means[1]))


def test_vehicle_generators_do_not_depend_on_the_fleet_size() -> None:
    few, many = vehicle_generators(11, 2), vehicle_generators(11, 5)
    for a, b in zip(few, many, strict=False):
        np.testing.assert_array_equal(a.standard_normal(4), b.standard_normal(4))
    draws = [g.standard_normal(4) for g in vehicle_generators(11, 5)]
    assert len({tuple(d) for d in draws}) == 5
    with pytest.raises(ValueError, match="at least one vehicle"):
        vehicle_generators(11, 0)


@pytest.mark.parametrize("vehicle", [-1, 3, 1.0, True, "0", None])
def test_a_bad_vehicle_index_is_a_clear_value_error(x8, vehicle) -> None:
    fleet = _fleet(x8, seed=6)
    calls = [
        lambda: fleet.set_command(np.full(8, 300.0), vehicle=vehicle),
        lambda: fleet.inject_fault(1, 0.5, vehicle=vehicle),
        lambda: fleet.injected_effectiveness(vehicle=vehicle),
        lambda: fleet.acceleration_W(vehicle=vehicle),
    ]
    for call in calls:
        with pytest.raises(ValueError, match=r"vehicle .*0\.\.2"):
            call()
    np.testing.assert_array_equal(fleet.last_command_ns, [0, -1, 0])  # nothing was taken


def test_a_fleet_has_no_single_state_or_command(x8) -> None:
    fleet = _fleet(x8, seed=6)
    with pytest.raises(ValueError, match=r"use x\[k\]"):
        fleet.state  # noqa: B018
    with pytest.raises(ValueError, match=r"use commands_rad_s\[k\]"):
        fleet.command_rad_s  # noqa: B018
    alone = make_sim(x8)
    np.testing.assert_array_equal(alone.state, alone.x[0])


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"rng": []}, "at least one vehicle"),
        ({"rng": vehicle_generators(0, 2), "initial_position_m": [(0, 0, 0)] * 3}, "initial_position_m"),
        ({"rng": vehicle_generators(0, 2), "initial_yaw_rad": [0.0, 1.0, 2.0]}, "initial_yaw_rad"),
        ({"rng": np.random.default_rng(0), "initial_position_m": [(0, 0, 0)] * 2}, "initial_position_m"),
    ],
)
def test_a_fleet_needs_one_generator_and_pose_per_vehicle(x8, options, message) -> None:
    with pytest.raises(ValueError, match=message):
        VehicleSimulator(x8, **options)


# ------------------------------------------------------------------ pacing


def test_the_pacer_follows_the_real_time_factor() -> None:
    pacer = RealTimePacer(2.0)
    pacer.anchor(wall_ns=1_000, sim_ns=0)
    assert pacer.target(1_000 + 100 * MS, 0) == 200 * MS


def test_the_pacer_slows_down_instead_of_bursting_when_behind() -> None:
    pacer = RealTimePacer(1.0, max_lag_s=0.25)
    pacer.anchor(0, 0)
    assert pacer.target(2 * NS_PER_S, 10 * MS) == 10 * MS + 250 * MS
    assert pacer.fell_behind == 1
    assert pacer.target(2 * NS_PER_S + 10 * MS, 260 * MS) == 270 * MS  # re-anchored at (2 s, 260 ms)


# ------------------------------------------------------------------ setpoints and the command line


def test_setpoint_files_are_read_and_errors_name_file_line_and_column(tmp_path) -> None:
    good = tmp_path / "good.csv"
    good.write_text("# a square\nt,x,y,z,yaw\n0,0,0,1,0\n2.5,1,0,1,0.5\n", encoding="utf-8")
    np.testing.assert_array_equal(read_setpoints(good), [[0, 0, 0, 1, 0], [2.5, 1, 0, 1, 0.5]])
    cases = {
        "t,x,y,z\n0,0,0,1\n": "good|header must be t,x,y,z,yaw",
        "t,x,y,z,yaw\n0,0,zero,1,0\n": ":2: column 'y': not a number",
        "t,x,y,z,yaw\n0,0,0,1,nan\n": ":2: column 'yaw': not finite",
        "t,x,y,z,yaw\n1,0,0,1,0\n1,0,0,2,0\n": "strictly increase",
        "t,x,y,z,yaw\n": "no setpoints",
        "t,x,y,z,yaw\n0,0,0,1\n": ":2: expected 5 cells",
    }
    for index, (text, message) in enumerate(cases.items()):
        path = tmp_path / f"bad{index}.csv"
        path.write_text(text, encoding="utf-8")
        with pytest.raises(SetpointError, match=message.split("|")[-1]) as error:
            read_setpoints(path)
        assert str(path) in str(error.value)


def test_simulate_writes_a_flight_log_that_reads_back(tmp_path, capsys) -> None:
    setpoints = tmp_path / "sp.csv"
    setpoints.write_text("t,x,y,z,yaw\n0,0,0,1,0\n1.5,0.5,0,1,0\n", encoding="utf-8")
    out = tmp_path / "flight.csv"
    status = cli_main(
        [
            "simulate",
            "--airframe",
            "quad_x",
            "--duration",
            "3",
            "--setpoints",
            str(setpoints),
            "--out",
            str(out),
            "--seed",
            "2",
        ]
    )
    assert status == 0
    log = read_flight_log(out, n_rotors=4)
    assert log.metadata["airframe"] == "quad_x"
    assert len(log) == 301  # t = 0 to 3 s at 100 Hz, both ends included
    assert {"omega_4", "omega_cmd_4", "range", "p", "ax"} <= set(log.columns)
    assert log.columns["z"][-1] == pytest.approx(1.0, abs=0.1)
    assert "final position" in capsys.readouterr().out


def test_simulate_reports_a_bad_airframe_as_a_user_error(tmp_path, capsys) -> None:
    setpoints = tmp_path / "sp.csv"
    setpoints.write_text("t,x,y,z,yaw\n0,0,0,1,0\n", encoding="utf-8")
    status = cli_main(
        [
            "simulate",
            "--airframe",
            "no_such_frame",
            "--duration",
            "1",
            "--setpoints",
            str(setpoints),
            "--out",
            str(tmp_path / "f.csv"),
        ]
    )
    assert status == 2
    assert "unknown airframe 'no_such_frame'" in capsys.readouterr().err


def test_an_airframe_without_a_sensors_section_uses_the_defaults(x8) -> None:
    document = {k: v for k, v in _yaml(x8).items() if k != "sensors"}
    airframe = airframe_from_dict(document, origin="x.yaml")
    sim = make_sim(airframe)
    assert sim.sensor_config == SensorConfig()


def _yaml(airframe):
    import yaml

    return yaml.safe_load(airframe.source_path.read_text(encoding="utf-8"))


# ------------------------------------------------------------------ fault-tolerant flight


def _hover(airframe, **options):
    trace = ControlTrace()
    log = simulate_flight(
        airframe,
        setpoints=[(0.0, 0.0, 0.0, 2.0, 0.0)],
        duration_s=3.0,
        rng=np.random.default_rng(3),
        initial_position_m=(0.0, 0.0, 2.0),
        trace=trace,
        **options,
    )
    return log, trace


def test_in_the_loop_diagnosis_leaves_a_healthy_flight_as_it_was(x8) -> None:
    plain, plain_trace = _hover(x8)
    diagnosed, trace = _hover(x8, fault_tolerance=FaultTolerance())
    for name, column in plain.columns.items():
        np.testing.assert_array_equal(diagnosed.columns[name], column, err_msg=name)
    assert math.isnan(trace.detection_t_s) and trace.detected_motor == 0
    assert len(trace.t) == 3 * 250  # one row per control step
    np.testing.assert_array_equal(trace.effectiveness, np.ones((750, 8)))
    np.testing.assert_array_equal(trace.position_error_W, plain_trace.position_error_W)


def test_a_fault_is_detected_in_the_loop_and_reallocated_only_when_asked(x8) -> None:
    fault = [*x8.effect_specs(), {"id": "actuator_fault", "motor": 2, "effectiveness": 0.0, "t_fault_s": 2.0}]
    _, on = _hover(x8, effects=fault, fault_tolerance=FaultTolerance())
    _, off = _hover(x8, effects=fault, fault_tolerance=FaultTolerance(reallocation=False))
    for trace in (on, off):
        assert trace.detected_motor == 2
        assert 2.0 < trace.detection_t_s < 2.2
    assert on.effectiveness[-1, 1] < 0.5 and np.all(on.effectiveness[-1, [0, *range(2, 8)]] == 1.0)
    np.testing.assert_array_equal(off.effectiveness, 1.0)
    # The filter moves smoothly: no step of the effectiveness in use is a jump.
    assert np.abs(np.diff(on.effectiveness, axis=0)).max() < 0.1


def test_a_reported_diagnosis_replaces_the_diagnosers(x8) -> None:
    _, trace = _hover(x8, fault_tolerance=FaultTolerance(reported=ReportedFault(4, 0.7, 1.0)))
    assert trace.effectiveness[trace.t < 1.0, 3].min() == 1.0
    assert trace.effectiveness[-1, 3] == pytest.approx(0.7, abs=0.01)


def test_impossible_fault_tolerance_settings_are_refused(x8) -> None:
    with pytest.raises(ValueError, match="motor must be in 1..8"):
        _hover(x8, fault_tolerance=FaultTolerance(reported=ReportedFault(9, 0.5, 1.0)))
    with pytest.raises(ValueError, match="velocity_noise_m_s"):
        FaultTolerance(velocity_noise_m_s=-1.0)
