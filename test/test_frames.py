"""multirotor_ros.frames: ENU/FLU <-> NED/FRD, checked on known cases and as round trips."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from multirotor_ros import frames
from multirotor_ros.model.rotation import euler_to_quat, matrix_to_quat, quat_to_euler, quat_to_matrix

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
vectors = arrays(np.float64, 3, elements=finite)
vector_batches = arrays(np.float64, st.tuples(st.integers(1, 5), st.just(3)), elements=finite)
angles = st.floats(-math.pi, math.pi, allow_nan=False)


@st.composite
def unit_quaternions(draw: st.DrawFn) -> np.ndarray:
    q = draw(arrays(np.float64, 4, elements=st.floats(-1.0, 1.0, allow_nan=False)))
    if np.linalg.norm(q) < 1e-3:
        q = np.array([1.0, 0.0, 0.0, 0.0])
    return q / np.linalg.norm(q)


# ---------------------------------------------------------------- known cases


def test_world_axes_known_cases():
    east, north, up = np.eye(3)
    np.testing.assert_array_equal(frames.enu_to_ned(east), [0.0, 1.0, 0.0])  # east is NED y
    np.testing.assert_array_equal(frames.enu_to_ned(north), [1.0, 0.0, 0.0])  # north is NED x
    np.testing.assert_array_equal(frames.enu_to_ned(up), [0.0, 0.0, -1.0])  # up is minus down
    np.testing.assert_array_equal(frames.ned_to_enu([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])


def test_body_axes_known_cases():
    np.testing.assert_array_equal(frames.flu_to_frd([1.0, 2.0, 3.0]), [1.0, -2.0, -3.0])
    # An accelerometer at rest reads +g up in FLU, which is -g along FRD z.
    np.testing.assert_allclose(frames.flu_to_frd([0.0, 0.0, 9.81]), [0.0, 0.0, -9.81])


def test_level_vehicle_facing_east_has_ned_yaw_of_90_degrees():
    q_NED_FRD = frames.quat_enu_flu_to_ned_frd([1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(quat_to_euler(q_NED_FRD), [0.0, 0.0, math.pi / 2], atol=1e-12)


def test_level_vehicle_facing_north_is_the_ned_identity():
    q_WB = euler_to_quat([0.0, 0.0, math.pi / 2])  # ENU yaw 90 deg: nose north
    np.testing.assert_allclose(frames.quat_enu_flu_to_ned_frd(q_WB), [1.0, 0.0, 0.0, 0.0], atol=1e-12)


def test_roll_right_is_positive_in_both_conventions():
    # A positive rotation about +x (forward) turns body +y (left) upwards: the right side drops, a roll
    # to the right, which FRD also calls positive.
    q_WB = euler_to_quat([math.radians(10.0), 0.0, math.pi / 2])  # nose north, rolled
    roll, pitch, yaw = quat_to_euler(frames.quat_enu_flu_to_ned_frd(q_WB))
    assert roll == pytest.approx(math.radians(10.0))
    assert pitch == pytest.approx(0.0, abs=1e-12)
    assert yaw == pytest.approx(0.0, abs=1e-12)


def test_nose_up_is_negative_flu_pitch_and_positive_frd_pitch():
    # FLU: a positive rotation about +y (left) turns the nose (+x) down; FRD calls nose-up positive.
    q_WB = euler_to_quat([0.0, math.radians(-15.0), math.pi / 2])  # nose north, nose up
    _, pitch, _ = quat_to_euler(frames.quat_enu_flu_to_ned_frd(q_WB))
    assert pitch == pytest.approx(math.radians(15.0))


def test_yaw_known_cases():
    assert frames.yaw_enu_to_ned(0.0) == pytest.approx(math.pi / 2)  # east
    assert frames.yaw_enu_to_ned(math.pi / 2) == pytest.approx(0.0)  # north
    assert frames.yaw_enu_to_ned(math.pi) == pytest.approx(-math.pi / 2)  # west


def test_ros_quaternion_field_order():
    assert frames.wxyz_to_ros_quat([1.0, 2.0, 3.0, 4.0]) == (2.0, 3.0, 4.0, 1.0)
    np.testing.assert_array_equal(frames.ros_quat_to_wxyz(2.0, 3.0, 4.0, 1.0), [1.0, 2.0, 3.0, 4.0])


# ---------------------------------------------------------------- round trips and consistency


@given(vectors)
def test_world_conversion_round_trips(v):
    np.testing.assert_allclose(frames.ned_to_enu(frames.enu_to_ned(v)), v)


@given(vector_batches)
def test_body_conversion_round_trips_batched(v):
    np.testing.assert_allclose(frames.frd_to_flu(frames.flu_to_frd(v)), v)


@given(unit_quaternions())
def test_quaternion_round_trip(q):
    back = frames.quat_ned_frd_to_enu_flu(frames.quat_enu_flu_to_ned_frd(q))
    # q and -q are the same rotation; the conversion returns w >= 0.
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-12


@settings(max_examples=200)
@given(unit_quaternions())
def test_quaternion_conversion_equals_the_matrix_conversion(q):
    q_fast = frames.quat_enu_flu_to_ned_frd(q)
    q_matrix = matrix_to_quat(frames.rotation_enu_flu_to_ned_frd(quat_to_matrix(q)))
    assert q_fast[0] >= 0.0
    # Same rotation (q and -q are one rotation; both have w >= 0 except at w = 0 exactly).
    np.testing.assert_allclose(quat_to_matrix(q_fast), quat_to_matrix(q_matrix), atol=1e-12)


@given(unit_quaternions(), vectors)
def test_rotating_then_converting_equals_converting_then_rotating(q, v_B):
    # A body vector rotated to the world and converted must equal the converted vector rotated with the
    # converted attitude: the definition of R_NED_FRD.
    R_WB = quat_to_matrix(q)
    R_NED_FRD = quat_to_matrix(frames.quat_enu_flu_to_ned_frd(q))
    np.testing.assert_allclose(
        frames.enu_to_ned(R_WB @ v_B), R_NED_FRD @ frames.flu_to_frd(v_B), atol=1e-9 * (1 + np.abs(v_B).max())
    )


@given(unit_quaternions())
def test_converted_rotation_is_a_rotation(q):
    R = frames.rotation_enu_flu_to_ned_frd(quat_to_matrix(q))
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


@given(angles, angles, angles)
def test_yaw_conversion_matches_the_attitude_conversion(roll, pitch, yaw):
    q_WB = euler_to_quat([roll * 0.4, pitch * 0.4, yaw])  # |pitch| < 90 deg: yaw well defined
    yaw_ned = quat_to_euler(frames.quat_enu_flu_to_ned_frd(q_WB))[2]
    expected = frames.yaw_enu_to_ned(quat_to_euler(q_WB)[2])
    assert math.cos(yaw_ned - expected) == pytest.approx(1.0, abs=1e-9)


@given(angles)
def test_yaw_conversion_is_an_involution(yaw):
    back = frames.yaw_ned_to_enu(frames.yaw_enu_to_ned(yaw))
    assert math.cos(back - yaw) == pytest.approx(1.0, abs=1e-12)
    assert -math.pi < frames.yaw_enu_to_ned(yaw) <= math.pi


def test_batched_quaternions_convert_row_by_row():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(7, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    batch = frames.quat_enu_flu_to_ned_frd(q)
    for row, converted in zip(q, batch, strict=True):
        np.testing.assert_allclose(frames.quat_enu_flu_to_ned_frd(row), converted)
