"""The one integrator: fixed-step classical Runge-Kutta (RK4), batched over vehicles.

Each step holds the rotor command constant (zero-order hold, as a flight controller's output is),
renormalises the attitude quaternions, applies ground contact, and refuses to produce a non-finite
state. Randomness (sensor noise) is never drawn here: callers pass their own ``numpy.random.Generator``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model import state as S
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray

Derivative = Callable[[float, FloatArray, FloatArray], FloatArray]


def rk4_step(f: Derivative, t: float, x: FloatArray, u: FloatArray, dt: float) -> FloatArray:
    """One classical RK4 step of dx/dt = f(t, x, u) with u held over the step."""
    k1 = f(t, x, u)
    k2 = f(t + dt / 2, x + dt / 2 * k1, u)
    k3 = f(t + dt / 2, x + dt / 2 * k2, u)
    k4 = f(t + dt, x + dt * k3, u)
    return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


class Integrator:
    """Steps a :class:`Model` at a fixed ``dt`` for a batch of vehicles.

    ``ground_height_m`` (None = no ground): a vehicle cannot sink below it; while it rests there the
    ground holds it still (velocity and body rate zero) until thrust lifts it.
    """

    def __init__(self, model: Model, dt_s: float, ground_height_m: float | None = 0.0):
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"integration step must be a positive number of seconds, got {dt_s}")
        self.model = model
        self.dt_s = float(dt_s)
        self.ground_height_m = ground_height_m

    def step(self, t: float, x: FloatArray, u: ArrayLike) -> FloatArray:
        """State after one step of ``dt_s`` from (t, x) with rotor commands u (B, N) [rad/s]."""
        command = self.model.check_command(u, x.shape[0])
        x_next = rk4_step(self.model.derivative, t, x, command, self.dt_s)
        q = x_next[:, S.QUATERNION]
        x_next[:, S.QUATERNION] = q / np.linalg.norm(q, axis=1, keepdims=True)
        if self.model.rotor_time_constant_s is None:
            x_next[:, S.ROTORS_START :] = command
        if self.ground_height_m is not None:
            self._ground_contact(x_next)
        if not np.all(np.isfinite(x_next)):
            vehicle = int(np.argwhere(~np.isfinite(x_next))[0, 0])
            raise FloatingPointError(f"the state of vehicle {vehicle} became non-finite at t = {t + self.dt_s:.6f} s")
        return x_next

    def _ground_contact(self, x: FloatArray) -> None:
        below = x[:, 2] < self.ground_height_m
        if np.any(below):
            x[below, 2] = self.ground_height_m
            x[below, 3:6] = 0.0
            x[below, S.BODY_RATE] = 0.0

    def simulate(self, x0: FloatArray, commands: Callable[[float, FloatArray], ArrayLike] | ArrayLike, steps: int,
                 t0: float = 0.0, record_every: int = 1) -> tuple[FloatArray, FloatArray]:
        """Run ``steps`` steps; ``commands`` is a constant (B, N) array or a function u(t, x).

        Returns the recorded times (K,) and states (K, B, 13 + N), the initial state included.
        """
        policy = commands if callable(commands) else (lambda _t, _x, _u=np.asarray(commands, float): _u)
        x = np.array(x0, dtype=float)
        times, states = [t0], [x.copy()]
        t = t0
        for k in range(1, steps + 1):
            x = self.step(t, x, policy(t, x))
            t = t0 + k * self.dt_s
            if k % record_every == 0:
                times.append(t)
                states.append(x.copy())
        return np.array(times), np.stack(states)
