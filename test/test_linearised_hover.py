"""Oracle: near hover, the nonlinear model matches the textbook linear hover model to second order.

The linear model is written here from first principles, not from the code: with a small rotation
vector dtheta (roll, pitch, yaw), body rates dw and rotor speed changes domega about hover speed omega_0,

    dp/dt = dv
    dv/dt = g (dtheta_y, -dtheta_x, 0) + (2 k_f omega_0 sum domega_i / m) e_z
    dq/dt = (0, dw / 2)                         (unit quaternion about identity)
    dw/dt = I^-1 2 omega_0 sum (y_i k_f, -x_i k_f, s_i k_t) domega_i
            (s_i = +1 for a cw rotor, -1 for a ccw one: the drag's reaction turns the body the other way)

so a pitch theta accelerates the vehicle along +x at g theta and a roll phi along -y at g phi (ENU/FLU).
The rigid body alone is linearised (effects=[]): each effect has its own tests, and some change the hover
linearisation on purpose (motor_lag adds rotor states). A wrong linear term would leave an error of
first order in the perturbation size; the test asks that halving it quarters the error.
"""

from __future__ import annotations

import numpy as np
import pytest

from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import GRAVITY_M_S2, Airframe, load_airframe
from multirotor_ros.model.model import Model
from multirotor_ros.resources import available_airframes

HOVER_HEIGHT_M = 10.0
# Perturbation sizes: eps times a direction of unit scale (1 m, 1 m/s, 1 rad, 1 rad/s, 20 % of hover speed).
EPSILONS = (1e-2, 5e-3, 2.5e-3)
DIRECTIONS = 8


def _quaternion_from_rotation_vector(rotation: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(rotation))
    axis = rotation / angle if angle > 0 else np.zeros(3)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


class HoverPoint:
    """One airframe's base model at hover, perturbed in minimal coordinates (p, v, rotation, w, omega)."""

    def __init__(self, airframe: Airframe):
        self.airframe = airframe
        self.model = Model(airframe, effects=[])
        self.n_rotors = airframe.n_rotors
        self.omega_0 = self.model.hover_speed_rad_s(HOVER_HEIGHT_M)

    @property
    def size(self) -> int:
        return 12 + self.n_rotors

    def nonlinear(self, perturbation: np.ndarray) -> np.ndarray:
        """Model.derivative at hover plus ``perturbation``: flat (13 + N,) derivative."""
        dp, dv, rotation, dw, domega = np.split(perturbation, [3, 6, 9, 12])
        x = S.make_state(self.n_rotors, position_m=(0.0, 0.0, HOVER_HEIGHT_M))
        x[0, S.POSITION] += dp
        x[0, S.VELOCITY] = dv
        x[0, S.QUATERNION] = _quaternion_from_rotation_vector(rotation)
        x[0, S.BODY_RATE] = dw
        x[0, S.ROTORS_START :] = self.omega_0 + domega
        return self.model.derivative(0.0, x, self.omega_0 + domega)[0]

    def linear(self, perturbation: np.ndarray) -> np.ndarray:
        """The linear hover model of the module docstring, in the same flat layout."""
        _, dv, rotation, dw, domega = np.split(perturbation, [3, 6, 9, 12])
        airframe = self.airframe
        positions = np.array([rotor.position_m for rotor in airframe.rotors])
        spins = np.array([1.0 if rotor.spin == "cw" else -1.0 for rotor in airframe.rotors])
        thrust_change = 2.0 * airframe.k_f_N_s2 * self.omega_0 * domega
        drag_torque_change = 2.0 * airframe.k_t_N_m_s2 * self.omega_0 * domega
        torque = np.array(
            [positions[:, 1] @ thrust_change, -positions[:, 0] @ thrust_change, spins @ drag_torque_change]
        )
        dx = np.zeros(13 + self.n_rotors)
        dx[S.POSITION] = dv
        dx[S.VELOCITY] = GRAVITY_M_S2 * np.array([rotation[1], -rotation[0], 0.0])
        dx[S.VELOCITY][2] += thrust_change.sum() / airframe.mass_kg
        dx[S.QUATERNION][1:] = 0.5 * dw
        dx[S.BODY_RATE] = np.linalg.solve(airframe.inertia_kg_m2, torque)
        return dx

    def direction(self, rng: np.random.Generator) -> np.ndarray:
        scales = np.concatenate([np.ones(12), np.full(self.n_rotors, 0.2 * self.omega_0)])
        return rng.standard_normal(self.size) * scales


@pytest.fixture(scope="module", params=available_airframes())
def hover(request) -> HoverPoint:
    return HoverPoint(load_airframe(request.param))


def test_hover_is_an_equilibrium(hover: HoverPoint) -> None:
    np.testing.assert_allclose(hover.nonlinear(np.zeros(hover.size)), 0.0, atol=1e-9)


def test_nonlinear_response_matches_the_linear_model_to_second_order(hover: HoverPoint) -> None:
    rng = np.random.default_rng(9)
    for _ in range(DIRECTIONS):
        direction = hover.direction(rng)
        errors = []
        for eps in EPSILONS:
            step = eps * direction
            response = hover.nonlinear(step)
            errors.append(np.linalg.norm(response - hover.linear(step)))
            # The linear part dominates: what is left is small beside the response itself.
            assert errors[-1] < 0.05 * np.linalg.norm(response)
        # Second order: halving the perturbation quarters what the linear model misses.
        ratios = np.array(errors[:-1]) / np.array(errors[1:])
        np.testing.assert_allclose(ratios, 4.0, rtol=0.1)


@pytest.mark.parametrize(("axis", "acceleration_axis", "sign"), [(1, 0, 1.0), (0, 1, -1.0)])
def test_a_small_tilt_accelerates_at_g_times_the_angle(
    hover: HoverPoint, axis: int, acceleration_axis: int, sign: float
) -> None:
    # Pitch theta along +x at g theta, roll phi along -y at g phi (seed 1 eq. 7 at psi = 0, small angles).
    angle = 0.01
    perturbation = np.zeros(hover.size)
    perturbation[6 + axis] = angle
    acceleration = hover.nonlinear(perturbation)[S.VELOCITY]
    assert acceleration[acceleration_axis] == pytest.approx(sign * GRAVITY_M_S2 * angle, rel=angle)
    assert abs(acceleration[2]) < GRAVITY_M_S2 * angle**2
