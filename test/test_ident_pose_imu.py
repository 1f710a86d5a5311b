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


def fused(estimator: PoseImuFusion, stamp_ns: int, w_WB_B=None, f_B=None):
    """The one sample (or Unpaired) of an IMU message whose pose is already known."""
    w_WB_B, f_B = (np.zeros(3) if value is None else value for value in (w_WB_B, f_B))
    assert estimator.imu(stamp_ns, w_WB_B, f_B) is None
    (decided,) = estimator.decided()
    return decided


def test_velocity_converges_to_the_motion_and_acceleration_is_the_specific_force_plus_gravity() -> None:
    # Constant velocity (1, -2, 0.5) m/s, yawed and tilted, sampled at 100 Hz for 1 s (20 time constants).
    v_W = np.array([1.0, -2.0, 0.5])
    q_WB = euler_to_quat(np.array([0.1, -0.2, 1.0]))
    estimator = fusion()
    for k in range(101):
        assert estimator.pose(k * 10 * MS, v_W * k * 0.01, q_WB) is None
    # At constant velocity the accelerometer reads -g in body axes: f_B = R^T (0 - g_W).
    f_B = quat_to_matrix(q_WB).T @ np.array([0.0, 0.0, G])
    sample = fused(estimator, 1000 * MS, [0.1, 0.2, 0.3], f_B)
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
    sample = fused(estimator, 10 * MS, f_B=np.array([0.0, 0.0, G]))
    assert sample.v_WB_W[0] == pytest.approx(1.0 - math.exp(-0.01 / 0.05))


def test_the_first_pose_and_a_pose_after_a_gap_start_at_rest() -> None:
    estimator = fusion(max_gap_s=0.1)
    estimator.pose(0, np.zeros(3), LEVEL)
    assert np.all(fused(estimator, 0).v_WB_W == 0)
    estimator.pose(500 * MS, np.array([5.0, 0.0, 0.0]), LEVEL)  # 0.5 s later: a gap, not 10 m/s
    assert np.all(fused(estimator, 500 * MS).v_WB_W == 0)


def test_a_repeated_or_older_pose_stamp_is_refused_and_changes_nothing() -> None:
    estimator = fusion()
    estimator.pose(10 * MS, np.zeros(3), LEVEL)
    repeated = estimator.pose(10 * MS, np.ones(3), LEVEL)
    older = estimator.pose(5 * MS, np.ones(3), LEVEL)
    assert isinstance(repeated, Refusal) and repeated.reason == "duplicated stamp"
    assert isinstance(older, Refusal) and older.reason == "stamp out of order"
    np.testing.assert_array_equal(fused(estimator, 10 * MS).p_WB_W, np.zeros(3))


def test_an_imu_message_without_a_pose_close_in_time_makes_no_sample() -> None:
    estimator = fusion(max_gap_s=0.1, max_pose_age_s=0.02)
    assert estimator.imu(0, np.zeros(3), np.zeros(3)) is None
    assert estimator.decided() == []  # its pose may still come
    assert estimator.imu(101 * MS, np.zeros(3), np.zeros(3)) is None  # more than max_gap_s later
    (first,) = estimator.decided()
    assert isinstance(first, Unpaired) and first.reason == "no pose yet"
    estimator.pose(100 * MS, np.zeros(3), LEVEL)
    assert estimator.decided() == []  # 101 ms: a nearer pose may still come
    estimator.pose(200 * MS, np.ones(3), LEVEL)
    (paired,) = estimator.decided()
    assert isinstance(paired, StateSample) and np.all(paired.p_WB_W == 0.0)  # the pose of 100 ms, 1 ms away
    assert isinstance(fused(estimator, 119 * MS), StateSample)
    assert isinstance(fused(estimator, 181 * MS), StateSample)
    assert isinstance(fused(estimator, 200 * MS), StateSample)
    estimator.pose(300 * MS, np.ones(3), LEVEL)
    late = fused(estimator, 250 * MS)
    assert isinstance(late, Unpaired) and late.reason == "no recent pose"


def test_imu_messages_that_arrive_before_their_poses_still_get_their_own_pose() -> None:
    """Order of arrival between the topics is not the order of stamps (a burst after a stall)."""
    estimator = fusion(max_gap_s=0.1, max_pose_age_s=0.025)
    estimator.pose(0, np.zeros(3), LEVEL)
    for k in range(1, 6):  # IMU messages of 10..50 ms first, then their poses
        assert estimator.imu(k * 10 * MS, np.zeros(3), np.zeros(3)) is None
    assert estimator.decided() == []
    released = []
    for k in range(1, 6):
        estimator.pose(k * 10 * MS, np.array([k * 0.01, 0.0, 0.0]), LEVEL)
        released += estimator.decided()
    assert [s.stamp_ns for s in released] == [k * 10 * MS for k in range(1, 6)]
    np.testing.assert_allclose([s.p_WB_W[0] for s in released], [0.01, 0.02, 0.03, 0.04, 0.05])


def test_an_imu_message_whose_pose_never_comes_is_decided_after_max_gap_s_of_imu_stamps() -> None:
    estimator = fusion(max_gap_s=0.05, max_pose_age_s=0.025)
    estimator.pose(0, np.zeros(3), LEVEL)
    for k in range(1, 7):
        estimator.imu(k * 10 * MS, np.zeros(3), np.zeros(3))
    assert estimator.decided() == []  # the 10 ms one has waited 50 ms: not longer than max_gap_s yet
    estimator.imu(80 * MS, np.zeros(3), np.zeros(3))
    decided = estimator.decided()
    # 10 and 20 ms waited longer: paired with the pose of 0 ms, 10 and 20 ms away.
    assert [(type(s), s.stamp_ns) for s in decided] == [(StateSample, 10 * MS), (StateSample, 20 * MS)]
    estimator.imu(90 * MS, np.zeros(3), np.zeros(3))
    (unpaired,) = estimator.decided()
    assert isinstance(unpaired, Unpaired) and unpaired.reason == "no recent pose"  # 30 ms from the pose


@pytest.mark.parametrize("name", ["gravity_m_s2", "max_gap_s", "max_pose_age_s", "velocity_time_constant_s"])
@pytest.mark.parametrize("value", [0.0, -1.0, math.nan])
def test_settings_that_are_not_positive_are_an_error_naming_them(name: str, value: float) -> None:
    settings = {"gravity_m_s2": G, "max_gap_s": 0.1, "max_pose_age_s": 0.02, name: value}
    with pytest.raises(ValueError, match=name):
        PoseImuFusion(**settings)
