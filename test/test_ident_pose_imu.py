"""PoseImuFusion (multirotor_ros/ident/pose_imu.py): pose + IMU messages as state samples, synthetic data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from multirotor_ros.ident.pose_imu import PoseImuFusion, StateSample, Unpaired
from multirotor_ros.model.rotation import euler_to_quat, quat_to_matrix
from multirotor_ros.refusals import Refusal

G = 9.81
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])
MS = 1_000_000  # ns


def fusion(max_gap_s: float = 0.1, max_pose_age_s: float = 0.02) -> PoseImuFusion:
    return PoseImuFusion(G, max_gap_s=max_gap_s, max_pose_age_s=max_pose_age_s)


def test_velocity_converges_to_the_motion_and_acceleration_is_the_specific_force_plus_gravity() -> None:
    # Constant velocity (1, -2, 0.5) m/s, yawed and tilted, sampled at 100 Hz for 1 s (20 time constants).
    v_W = np.array([1.0, -2.0, 0.5])
    q_WB = euler_to_quat(np.array([0.1, -0.2, 1.0]))
    estimator = fusion()
    for k in range(101):
        assert estimator.pose(k * 10 * MS, v_W * k * 0.01, q_WB) is None
    # At constant velocity the accelerometer reads -g in body axes: f_B = R^T (0 - g_W).
    f_B = quat_to_matrix(q_WB).T @ np.array([0.0, 0.0, G])
    sample = estimator.imu(1000 * MS, [0.1, 0.2, 0.3], f_B)
    assert isinstance(sample, StateSample)
    assert sample.stamp_ns == 1000 * MS
    np.testing.assert_allclose(sample.v_WB_W, v_W, rtol=1e-6)
    np.testing.assert_allclose(sample.a_WB_W, 0.0, atol=1e-12)
    np.testing.assert_array_equal(sample.q_WB, q_WB)
    np.testing.assert_array_equal(sample.w_WB_B, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(sample.p_WB_W, v_W)


def test_velocity_is_a_first_order_low_pass_of_the_position_differences() -> None:
    estimator = fusion()
    estimator.pose(0, np.zeros(3), LEVEL)
    estimator.pose(10 * MS, np.array([0.01, 0.0, 0.0]), LEVEL)  # 1 m/s over 10 ms
    sample = estimator.imu(10 * MS, np.zeros(3), np.array([0.0, 0.0, G]))
    assert sample.v_WB_W[0] == pytest.approx(1.0 - math.exp(-0.01 / 0.05))


def test_the_first_pose_and_a_pose_after_a_gap_start_at_rest() -> None:
    estimator = fusion(max_gap_s=0.1)
    estimator.pose(0, np.zeros(3), LEVEL)
    assert np.all(estimator.imu(0, np.zeros(3), np.zeros(3)).v_WB_W == 0)
    estimator.pose(500 * MS, np.array([5.0, 0.0, 0.0]), LEVEL)  # 0.5 s later: a gap, not 10 m/s
    assert np.all(estimator.imu(500 * MS, np.zeros(3), np.zeros(3)).v_WB_W == 0)


def test_a_repeated_or_older_pose_stamp_is_refused_and_changes_nothing() -> None:
    estimator = fusion()
    estimator.pose(10 * MS, np.zeros(3), LEVEL)
    repeated = estimator.pose(10 * MS, np.ones(3), LEVEL)
    older = estimator.pose(5 * MS, np.ones(3), LEVEL)
    assert isinstance(repeated, Refusal) and repeated.reason == "duplicated stamp"
    assert isinstance(older, Refusal) and older.reason == "stamp out of order"
    np.testing.assert_array_equal(estimator.imu(10 * MS, np.zeros(3), np.zeros(3)).p_WB_W, np.zeros(3))


def test_an_imu_message_without_a_pose_close_in_time_makes_no_sample() -> None:
    estimator = fusion(max_pose_age_s=0.02)
    first = estimator.imu(0, np.zeros(3), np.zeros(3))
    assert isinstance(first, Unpaired) and first.reason == "no pose yet"
    estimator.pose(100 * MS, np.zeros(3), LEVEL)
    assert isinstance(estimator.imu(119 * MS, np.zeros(3), np.zeros(3)), StateSample)
    assert isinstance(estimator.imu(81 * MS, np.zeros(3), np.zeros(3)), StateSample)
    late = estimator.imu(121 * MS, np.zeros(3), np.zeros(3))
    assert isinstance(late, Unpaired) and late.reason == "no recent pose"


@pytest.mark.parametrize("name", ["gravity_m_s2", "max_gap_s", "max_pose_age_s", "velocity_time_constant_s"])
@pytest.mark.parametrize("value", [0.0, -1.0, math.nan])
def test_settings_that_are_not_positive_are_an_error_naming_them(name: str, value: float) -> None:
    settings = {"gravity_m_s2": G, "max_gap_s": 0.1, "max_pose_age_s": 0.02, name: value}
    with pytest.raises(ValueError, match=name):
        PoseImuFusion(**settings)
