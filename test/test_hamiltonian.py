"""Seed 2's Hamiltonian form and the Newton-Euler form give the same motion and the same energy."""

from __future__ import annotations

import numpy as np
import pytest

from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.hamiltonian import HamiltonianModel
from multirotor_ros.model.integrator import Integrator
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import euler_rates_matrix


@pytest.mark.parametrize("name", ["hexarotor_f550", "x8_octorotor"])
def test_hamiltonian_and_newton_euler_trajectories_agree(name: str) -> None:
    airframe = load_airframe(name)
    n = airframe.n_rotors
    model = Model(
        airframe,
        [
            {"id": "quadratic_drag", "c_x": 0.3, "c_y": 0.3, "c_z": 0.1},
            {"id": "gyroscopic", "j_r": 1e-4},
            {"id": "rotor_drag", "k_h": 1e-4},
        ],
    )
    hamiltonian = HamiltonianModel(model)
    x = S.make_state(
        n,
        position_m=(0, 0, 5),
        velocity_m_s=(1, 0.5, 0),
        euler_rad=(0.2, -0.3, 1.0),
        body_rate_rad_s=(0.5, -0.4, 0.3),
        rotor_speed_rad_s=330,
    )
    X = hamiltonian.from_newton_euler(x)
    hover = model.hover_speed_rad_s()
    u = hover * (1 + 0.02 * np.sin(np.arange(n)))[None]
    newton_euler = Integrator(model, 1e-3, ground_height_m=None, backend="numpy")
    canonical = Integrator(hamiltonian, 1e-3, ground_height_m=None)
    for k in range(1500):
        x = newton_euler.step(k * 1e-3, x, u)
        X = canonical.step(k * 1e-3, X, u)
    converted = hamiltonian.from_newton_euler(x)
    np.testing.assert_allclose(converted[:, 0:3], X[:, 0:3], atol=1e-8)  # position
    wrapped = np.angle(np.exp(1j * (converted[:, 3:6] - X[:, 3:6])))
    np.testing.assert_allclose(wrapped, 0.0, atol=1e-8)  # attitude
    np.testing.assert_allclose(converted[:, 6:12], X[:, 6:12], atol=1e-8)  # momenta


def test_hamiltonian_is_conserved_in_free_flight() -> None:
    model = Model(load_airframe("hexarotor_f550"), [])
    hamiltonian = HamiltonianModel(model)
    X = hamiltonian.from_newton_euler(
        S.make_state(
            6,
            position_m=(0, 0, 10),
            velocity_m_s=(1, 2, 3),
            euler_rad=(0.3, 0.2, 0.1),
            body_rate_rad_s=(1.5, -1.4, 2.3),
        )
    )
    integrator = Integrator(hamiltonian, 1e-3, ground_height_m=None)
    energy = hamiltonian.energy(X)
    for k in range(3000):
        X = integrator.step(k * 1e-3, X, np.zeros(6))
    assert abs(hamiltonian.energy(X) - energy)[0] / energy[0] < 1e-9


def test_reduces_to_seed2_eq19_at_level_attitude() -> None:
    """At zero roll and pitch W = I, so p_eta = I deta/dt exactly as seed 2 eq. 19 writes it."""
    model = Model(load_airframe("hexarotor_f550"), [])
    rates = np.array([0.3, -0.2, 0.5])
    X = HamiltonianModel(model).from_newton_euler(
        S.make_state(6, euler_rad=(0, 0, 0.7), body_rate_rad_s=rates)
    )
    np.testing.assert_allclose(euler_rates_matrix(np.zeros(3)), np.eye(3))
    np.testing.assert_allclose(X[0, 9:12], model.inertia_kg_m2 @ rates, atol=1e-15)
    np.testing.assert_allclose(X[0, 6:9], 0.0)
