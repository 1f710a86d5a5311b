"""Rotation helpers: properties over random attitudes (hypothesis)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from multirotor_ros.model.rotation import (
    euler_rates_matrix,
    euler_to_matrix,
    euler_to_quat,
    matrix_to_quat,
    quat_conjugate,
    quat_multiply,
    quat_to_euler,
    quat_to_matrix,
)

angles = st.tuples(st.floats(-3.1, 3.1), st.floats(-1.55, 1.55), st.floats(-3.1, 3.1))


@given(angles)
def test_euler_quaternion_matrix_agree(euler: tuple[float, float, float]) -> None:
    e = np.array(euler)
    R = euler_to_matrix(e)
    np.testing.assert_allclose(quat_to_matrix(euler_to_quat(e)), R, atol=1e-12)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0)
    np.testing.assert_allclose(quat_to_euler(euler_to_quat(e)), e, atol=1e-7)


@given(angles)
def test_matrix_to_quat_inverts_quat_to_matrix(euler: tuple[float, float, float]) -> None:
    q = euler_to_quat(np.array(euler))
    q_back = matrix_to_quat(quat_to_matrix(q))
    np.testing.assert_allclose(q_back, q * np.sign(q[0]), atol=1e-12)


@given(angles, angles)
def test_quaternion_product_composes_rotations(a: tuple, b: tuple) -> None:
    qa, qb = euler_to_quat(np.array(a)), euler_to_quat(np.array(b))
    np.testing.assert_allclose(
        quat_to_matrix(quat_multiply(qa, qb)), quat_to_matrix(qa) @ quat_to_matrix(qb), atol=1e-12
    )
    np.testing.assert_allclose(quat_multiply(qa, quat_conjugate(qa)), [1, 0, 0, 0], atol=1e-12)


def test_euler_rates_matrix_maps_rates_to_body_rates() -> None:
    """w_B = W(eta) deta/dt, checked by differentiating R numerically: [w_B]x = R^T dR/dt."""
    eta = np.array([0.3, -0.4, 1.2])
    eta_dot = np.array([0.5, -0.2, 0.8])
    h = 1e-6
    dR = (euler_to_matrix(eta + h * eta_dot) - euler_to_matrix(eta - h * eta_dot)) / (2 * h)
    skew = euler_to_matrix(eta).T @ dR
    w_B = np.array([skew[2, 1], skew[0, 2], skew[1, 0]])
    np.testing.assert_allclose(euler_rates_matrix(eta) @ eta_dot, w_B, atol=1e-8)


def test_batched_shapes() -> None:
    e = np.zeros((5, 7, 3))
    assert euler_to_matrix(e).shape == (5, 7, 3, 3)
    assert euler_to_quat(e).shape == (5, 7, 4)
    assert matrix_to_quat(euler_to_matrix(e)).shape == (5, 7, 4)
