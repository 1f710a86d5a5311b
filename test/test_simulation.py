"""The pure vehicle simulation, setpoint files and the ``multirotor simulate`` command.

Ground contact, command clamp, rotor lag, watchdog, fault injection, sensor statistics, pacing rules.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from multirotor_ros.cli import main as cli_main
from multirotor_ros.io.flight_log import read_flight_log
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import airframe_from_dict, load_airframe
from multirotor_ros.model.rotation import euler_to_matrix
from multirotor_ros.simulation.flight import (
    ControlTrace,
    FaultTolerance,
    ReportedFault,
    SetpointError,
    read_setpoints,
    simulate_flight,
)
from multirotor_ros.simulation.pacing import Lockstep, RealTimePacer
from multirotor_ros.simulation.sensors import SensorConfig, range_reading, sensor_config_from_section
from multirotor_ros.simulation.vehicle import NS_PER_S, VehicleSimulator

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


def test_motion_capture_noise_is_about_a_millimetre(x8) -> None:
    sim = make_sim(x8, rng=np.random.default_rng(8))
    positions = np.array([p for p, _ in _readings(sim, "pose", 10 * NS_PER_S)])
    assert positions.std(axis=0) == pytest.approx([0.001] * 3, rel=0.15)


def test_the_range_sensor_reads_height_plus_its_mount_offset() -> None:
    config = SensorConfig()
    rng = np.random.default_rng(0)
    level = np.eye(3)
    assert range_reading(config, rng, np.array([0, 0, 0.0]), level) == pytest.approx(
        0.09
    )  # 0.10 on a 3 cm grid
    assert range_reading(config, rng, np.array([0, 0, 1.0]), level) == pytest.approx(1.11)
    tilted = euler_to_matrix([0.3, 0.0, 0.0])
    assert range_reading(config, rng, np.array([0, 0, 1.0]), tilted) == pytest.approx(
        1.14
    )  # 1/cos(0.3) + 0.1
    assert range_reading(config, rng, np.array([0, 0, 7.0]), level) == math.inf
    assert range_reading(config, rng, np.array([0, 0, 1.0]), euler_to_matrix([0.6, 0.0, 0.0])) == math.inf
    exact = dataclasses.replace(config, range_resolution_m=0.0)
    assert range_reading(exact, rng, np.array([0, 0, 0.5]), level) == pytest.approx(0.6)


def test_readings_come_at_their_rates(x8) -> None:
    sim = make_sim(x8)
    kinds = [r.kind for r in sim.run_until(NS_PER_S)]
    assert {kind: kinds.count(kind) for kind in set(kinds)} == {
        "odom": 251,
        "imu": 101,
        "pose": 101,
        "motor_speeds": 101,
        "range": 15,
    }  # 15 Hz: the 16th is at 1.000000005 s


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


def test_lockstep_lets_the_physics_run_one_lead_past_the_newest_command() -> None:
    lockstep = Lockstep(lead_ns=4 * MS, fallback_after_s=0.5, last_command_wall_s=10.0)
    assert lockstep.limit_ns() == 4 * MS
    lockstep.command(8 * MS, wall_s=10.1)
    lockstep.command(6 * MS, wall_s=10.2)  # an older stamp never moves the limit back
    assert lockstep.limit_ns() == 12 * MS
    assert not lockstep.stalled(10.6)
    assert lockstep.stalled(10.8)


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
