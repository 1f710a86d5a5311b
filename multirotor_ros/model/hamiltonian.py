"""Seed 2's Hamiltonian form of the rigid body, written once more without its shortcuts.

Seed 2 (eqs. 16-19) takes generalised coordinates q = (xi, eta) — position and ZYX Euler angles —
and momenta p = (p_xi, p_eta) with p_xi = m dxi/dt and, in its eq. 19, p_eta = I deta/dt. The latter
holds only when Euler rates equal body rates (small angles). Here the momentum is the exact one,
p_eta = J(eta) deta/dt with J = W^T I W and w_B = W(eta) deta/dt, so that

    H(q, p) = |p_xi|^2 / (2 m) + p_eta^T J^-1 p_eta / 2 + m g z
    dq/dt = dH/dp,   dp/dt = -dH/dq + (F_W, W^T tau_B)

which reduces to seed 2's eqs. 18-19 when W = identity, and is written in ENU (seed 2's FRD has
z down, hence its "+m g" in eq. 18). The forces are the same effect pipeline as the Newton-Euler
model, so both forms must give the same trajectory (test_hamiltonian.py shows it).

State layout (B, 12 + N): xi (0:3) [m], eta (3:6) [rad], p_xi (6:9) [kg m/s], p_eta (9:12) [kg m^2/s],
rotor speeds (12:12+N) [rad/s].
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model import state as S
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray, euler_rates_matrix, euler_to_matrix, quat_to_euler
from multirotor_ros.model.state import StateBatch

if TYPE_CHECKING:
    from multirotor_ros.model.integrator import CrashLatch

ROTORS_START = 12


def _euler_rate_matrix_derivatives(eta: FloatArray) -> tuple[FloatArray, FloatArray]:
    """dW/droll and dW/dpitch, each (B, 3, 3); W does not depend on yaw."""
    cf, sf = np.cos(eta[:, 0]), np.sin(eta[:, 0])
    ct, st = np.cos(eta[:, 1]), np.sin(eta[:, 1])
    d_roll = np.zeros(eta.shape[:1] + (3, 3))
    d_roll[:, 1, 1] = -sf
    d_roll[:, 1, 2] = cf * ct
    d_roll[:, 2, 1] = -cf
    d_roll[:, 2, 2] = -sf * ct
    d_pitch = np.zeros_like(d_roll)
    d_pitch[:, 0, 2] = -ct
    d_pitch[:, 1, 2] = -sf * st
    d_pitch[:, 2, 2] = -cf * st
    return d_roll, d_pitch


class HamiltonianModel:
    """The same physics as a :class:`Model`, in canonical coordinates; steps with the same Integrator."""

    def __init__(self, model: Model):
        self.model = model

    @property
    def rotor_time_constant_s(self) -> FloatArray | None:
        """As the wrapped model's (motor_lag)."""
        return self.model.rotor_time_constant_s

    def check_command(self, u: ArrayLike, batch: int) -> FloatArray:
        """As :meth:`Model.check_command`."""
        return self.model.check_command(u, batch)

    def from_newton_euler(self, x: FloatArray) -> FloatArray:
        """Canonical state of a Newton-Euler state (B, 13 + N)."""
        eta = quat_to_euler(x[:, S.QUATERNION])
        W = euler_rates_matrix(eta)
        eta_dot = np.linalg.solve(W, x[:, S.BODY_RATE][..., None])[..., 0]
        J = np.einsum("bki,kl,blj->bij", W, self.model.inertia_kg_m2, W)
        X = np.empty((x.shape[0], ROTORS_START + self.model.n_rotors))
        X[:, 0:3] = x[:, S.POSITION]
        X[:, 3:6] = eta
        X[:, 6:9] = self.model.mass_kg[..., None] * x[:, S.VELOCITY]
        X[:, 9:12] = np.einsum("bij,bj->bi", J, eta_dot)
        X[:, ROTORS_START:] = x[:, S.ROTORS_START :]
        return X

    def velocities(self, X: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """(v_W, eta_dot, w_B, W) from the canonical state: dq/dt = dH/dp."""
        eta = X[:, 3:6]
        W = euler_rates_matrix(eta)
        J = np.einsum("bki,kl,blj->bij", W, self.model.inertia_kg_m2, W)
        eta_dot = np.linalg.solve(J, X[:, 9:12][..., None])[..., 0]
        w_B = np.einsum("bij,bj->bi", W, eta_dot)
        return X[:, 6:9] / self.model.mass_kg[..., None], eta_dot, w_B, W

    def energy(self, X: FloatArray) -> FloatArray:
        """The Hamiltonian H(q, p) [J]."""
        v_W, eta_dot, w_B, _ = self.velocities(X)
        m = self.model.mass_kg
        rotational = 0.5 * np.einsum("bi,ij,bj->b", w_B, self.model.inertia_kg_m2, w_B)
        return 0.5 * m * np.sum(v_W * v_W, axis=1) + rotational + m * self.model.gravity_m_s2 * X[:, 2]

    def derivative(self, t: float, X: FloatArray, u: FloatArray) -> FloatArray:
        """dX/dt of the canonical state for rotor-speed inputs u (B, N)."""
        model = self.model
        v_W, eta_dot, w_B, W = self.velocities(X)
        omega = X[:, ROTORS_START:] if model.rotor_time_constant_s is not None else u
        states = StateBatch(
            np.asarray(t, dtype=float), X[:, 0:3], v_W, euler_to_matrix(X[:, 3:6]), w_B, omega
        )
        ctx = model.context(states)
        F_W, tau_B, _ = model.wrench(ctx)
        # -dH/deta_k = (1/2) eta_dot^T dJ/deta_k eta_dot = (dW/deta_k eta_dot) . (I w_B).
        angular_momentum_B = w_B @ model.inertia_kg_m2.T
        d_roll, d_pitch = _euler_rate_matrix_derivatives(X[:, 3:6])
        minus_dH_deta = np.zeros_like(eta_dot)
        minus_dH_deta[:, 0] = np.einsum("bij,bj,bi->b", d_roll, eta_dot, angular_momentum_B)
        minus_dH_deta[:, 1] = np.einsum("bij,bj,bi->b", d_pitch, eta_dot, angular_momentum_B)
        dX = np.empty_like(X)
        dX[:, 0:3] = v_W
        dX[:, 3:6] = eta_dot
        dX[:, 6:9] = F_W
        dX[:, 8] -= model.mass_kg * model.gravity_m_s2
        dX[:, 9:12] = minus_dH_deta + np.einsum("bji,bj->bi", W, tau_B)
        if model.rotor_time_constant_s is None:
            dX[:, ROTORS_START:] = 0.0
        else:
            dX[:, ROTORS_START:] = (u - omega) / model.rotor_time_constant_s[..., None]
        return dX

    def post_step(self, X: FloatArray, command: FloatArray) -> None:
        """After an integration step: algebraic rotor speeds when there is no motor lag."""
        if self.model.rotor_time_constant_s is None:
            X[:, ROTORS_START:] = command

    def rest_on_ground(
        self, X_before: FloatArray, X: FloatArray, height_m: float, latch: CrashLatch | None, step: int
    ) -> None:
        """Ground contact of :func:`~multirotor_ros.model.integrator.hold_on_ground` in canonical coordinates.

        Resting means the pose before the step, on the ground, and no momentum.
        """
        touching = X[:, 2] < height_m
        held = touching
        if latch is not None:
            roll, pitch = X_before[:, 3], X_before[:, 4]
            falling_m_s = -X[:, 8] / self.model.mass_kg
            held = latch.held(touching, falling_m_s, np.cos(roll) * np.cos(pitch), step)
        X[held, 0:2] = X_before[held, 0:2]
        X[held, 2] = height_m
        X[held, 3:6] = X_before[held, 3:6]
        X[held, 6:12] = 0.0
