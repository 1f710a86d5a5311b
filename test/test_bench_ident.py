"""Seed 2 bench identification: the paper's numbers, and known constants recovered from noisy bench data."""

from __future__ import annotations

import numpy as np
import pytest

from multirotor_ros.ident import bench
from multirotor_ros.model.airframe import MotorMap, load_airframe


def test_inertia_from_table1_reproduces_table2_ixx_iyy_to_four_digits():
    i_xx, i_yy, i_zz = bench.inertia_from_geometry(bench.SEED2_TABLE1)
    table_xx, table_yy, table_zz = bench.SEED2_TABLE2_INERTIA_KG_M2
    assert f"{i_xx:.4g}" == f"{table_xx:.4g}" == "0.02197"
    assert f"{i_yy:.4g}" == f"{table_yy:.4g}" == "0.02162"
    # The discrepancy the module documents: eq. 22 gives 0.04439, Table 2 0.04366, Table 3 0.04904.
    assert i_zz == pytest.approx(0.044390, abs=5e-7)
    assert abs(i_zz - table_zz) / table_zz == pytest.approx(0.0167, abs=5e-4)
    assert abs(i_zz - bench.SEED2_TABLE3_IZZ_KG_M2) / bench.SEED2_TABLE3_IZZ_KG_M2 > 0.09


def test_hexarotor_config_takes_table2_inertia():
    airframe = load_airframe("hexarotor_f550")
    np.testing.assert_allclose(np.diag(airframe.inertia_kg_m2), bench.SEED2_TABLE2_INERTIA_KG_M2)


def test_geometry_refuses_non_physical_values():
    with pytest.raises(bench.BenchError, match="chord_m"):
        bench.HexarotorGeometry(**{**vars(bench.SEED2_TABLE1), "chord_m": -0.01})


def test_paper_equations_25_to_30():
    b = bench.thrust_constant_at_point(7.671, 746.0)  # eq. 25
    assert f"{b:.4g}" == "1.378e-05"
    assert f"{bench.paper_thrust_factor(0.8301, b):.3f}" == "0.830"  # eqs. 26-28, Table 3 a_1
    assert f"{bench.seed2_torque_constant(8.683e-5, 0.275):.4g}" == "2.388e-05"  # eq. 30 with eq. 29


def test_eq25_and_eq29_disagree_by_more_than_six_times():
    # Recorded so that nobody takes Table 3's C_T for the bench's: see the module notes.
    assert 8.683e-5 / bench.thrust_constant_at_point(7.671, 746.0) == pytest.approx(6.30, abs=0.01)


def _synthetic_bench(rng: np.random.Generator, k_f: float, k_t: float, noise: float):
    """Seed 2's protocol: program speed 0..180 by 10, the motor starts at 40, tops at 130, then slows."""
    command = np.arange(0.0, 190.0, 10.0)
    x = np.clip((command - 40.0) / 90.0, 0.0, 1.0)
    speed = np.where(command < 40.0, 0.0, 746.0 * x)
    speed = np.where(command > 130.0, 746.0 - 2.0 * (command - 130.0), speed)
    thrust = k_f * speed**2 * (1 + noise * rng.standard_normal(speed.size))
    torque = k_t * speed**2 * (1 + noise * rng.standard_normal(speed.size))
    speed_measured = speed * (1 + 0.005 * rng.standard_normal(speed.size))
    return command, thrust, speed_measured, torque


def test_recovers_known_constants_and_motor_map_from_noisy_bench_data():
    rng = np.random.default_rng(7)
    k_f, k_t = 1.378e-5, 2.03e-7
    command, thrust, speed, torque = _synthetic_bench(rng, k_f, k_t, noise=0.02)
    result = bench.identify_bench(bench.BenchData(command, thrust, speed, torque, "normalized"))
    assert result.k_f_N_s2.value == pytest.approx(k_f, rel=0.03)
    assert abs(result.k_f_N_s2.value - k_f) < 4 * result.k_f_N_s2.std
    assert result.k_t_N_m_s2 is not None
    assert result.k_t_N_m_s2.value == pytest.approx(k_t, rel=0.03)
    assert result.k_f_at_top_speed_N_s2 == pytest.approx(k_f, rel=0.08)
    motor_map = result.speed_map.motor_map
    assert motor_map.input_min == pytest.approx(40.0, abs=2.0)
    assert motor_map.input_max == 130.0
    assert motor_map.speed_max_rad_s == pytest.approx(746.0, rel=0.01)
    assert motor_map.speed_min_rad_s == 0.0
    np.testing.assert_allclose(motor_map.speed_from_command([85.0]), [373.0], rtol=0.02)
    assert any("left out" in note for note in result.speed_map.notes)
    # Thrust line (eq. 23) over the active range only: quadratic thrust gives a positive slope.
    assert result.thrust_line.slope > 0


def test_quadratic_law_recovers_a_thrust_linearised_esc():
    truth = MotorMap("pwm_us", 1100.0, 1900.0, 0.0, 800.0, "quadratic")
    command = np.linspace(1000.0, 1900.0, 19)
    speed = truth.speed_from_command(command)
    speed = np.where(command < 1100.0, 0.0, speed)
    fit = bench.fit_speed_map(command, speed, "pwm_us", "quadratic").motor_map
    assert fit.law == "quadratic"
    assert fit.input_min == pytest.approx(1100.0, abs=1.0)
    assert fit.speed_max_rad_s == pytest.approx(800.0, rel=1e-6)


def test_idle_jump_is_reported():
    command = np.arange(0.0, 11.0)
    speed = np.where(command < 3, 0.0, 200.0 + 50.0 * (command - 3))
    fit = bench.fit_speed_map(command, speed)
    assert fit.motor_map.input_min == 3.0
    assert fit.motor_map.speed_min_rad_s == pytest.approx(200.0)
    assert any("jumps from stopped" in note for note in fit.notes)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("thrust_N", [1.0, float("nan"), 2.0, 3.0], "thrust_N: sample 1 is nan"),
        ("thrust_N", [1.0, 2.0, 3.0], "thrust_N: 3 samples, expected 4"),
        ("speed_rad_s", [0.0, 100.0, -5.0, 300.0], "speed_rad_s: sample 2 is negative"),
    ],
)
def test_bad_bench_data_names_the_array_and_sample(field, value, message):
    data = {
        "command": [0.0, 1.0, 2.0, 3.0],
        "thrust_N": [0.0, 1.0, 2.0, 3.0],
        "speed_rad_s": [0.0, 100.0, 200.0, 300.0],
    }
    data[field] = value
    with pytest.raises(bench.BenchError, match=message):
        bench.identify_bench(bench.BenchData(**data))


def test_line_fit_needs_different_commands():
    with pytest.raises(bench.BenchError, match="all samples are equal"):
        bench.fit_line([1.0, 1.0, 1.0], [1.0, 2.0, 3.0])


def test_no_torque_measurement_says_why_no_drag_constant():
    rng = np.random.default_rng(1)
    command, thrust, speed, _ = _synthetic_bench(rng, 1.378e-5, 2.03e-7, noise=0.01)
    result = bench.identify_bench(bench.BenchData(command, thrust, speed))
    assert result.k_t_N_m_s2 is None
    assert any("C_Q = C_T L" in note for note in result.notes)
