"""The one integrator: fixed-step classical Runge-Kutta (RK4), batched over vehicles.

Each step holds the rotor command constant (zero-order hold, as a flight controller's output is),
renormalises the attitude quaternions, applies ground contact, and refuses to produce a non-finite
state. Randomness (sensor noise) is never drawn here: callers pass their own ``numpy.random.Generator``.

Two backends compute the same steps: ``numpy`` (the reference :class:`Model`, any effect, any form)
and ``compiled`` (multirotor_ros.model.compiled, the effects of effects.md, Newton-Euler form), chosen
automatically; ``advance`` runs many steps in one call, which is where the compiled backend shines.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.model.hamiltonian import HamiltonianModel
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray

Derivative = Callable[[float, FloatArray, FloatArray], FloatArray]
Backend = Literal["auto", "numpy", "compiled"]


def rk4_step(f: Derivative, t: float, x: FloatArray, u: FloatArray, dt: float) -> FloatArray:
    """One classical RK4 step of dx/dt = f(t, x, u) with u held over the step."""
    k1 = f(t, x, u)
    k2 = f(t + dt / 2, x + dt / 2 * k1, u)
    k3 = f(t + dt / 2, x + dt / 2 * k2, u)
    k4 = f(t + dt, x + dt * k3, u)
    return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


class Integrator:
    """Steps a model (:class:`Model`, or its Hamiltonian form) at a fixed ``dt`` for a batch of vehicles.

    ``ground_height_m`` (None = no ground): a vehicle cannot sink below it; while it rests there the
    ground holds it still (velocity and body rate zero) until thrust lifts it.
    """

    def __init__(
        self,
        model: Model | HamiltonianModel,
        dt_s: float,
        ground_height_m: float | None = 0.0,
        backend: Backend = "auto",
    ):
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"integration step must be a positive number of seconds, got {dt_s}")
        self.model = model
        self.dt_s = float(dt_s)
        self.ground_height_m = ground_height_m
        self.backend = self._choose_backend(backend)
        self._steppers: dict[int, object] = {}

    def _choose_backend(self, requested: Backend) -> Literal["numpy", "compiled"]:
        if requested == "numpy":
            return "numpy"
        from multirotor_ros.model import compiled

        possible = isinstance(self.model, Model) and compiled.supports(self.model)
        if requested == "compiled" and not possible:
            raise ValueError(f"the compiled backend does not support {self.model!r}")
        return "compiled" if possible else "numpy"

    def _stepper(self, batch: int):  # noqa: ANN202 - CompiledStepper, imported lazily (numba start-up)
        if batch not in self._steppers:
            from multirotor_ros.model.compiled import CompiledStepper

            assert isinstance(self.model, Model)
            self._steppers[batch] = CompiledStepper(self.model, batch)
        return self._steppers[batch]

    def advance(self, t: float, x: FloatArray, u: ArrayLike, steps: int = 1) -> FloatArray:
        """State after ``steps`` steps of ``dt_s`` from (t, x) with rotor commands u (B, N) [rad/s] held."""
        command = self.model.check_command(u, x.shape[0])
        if self.backend == "compiled":
            return self._stepper(x.shape[0]).advance(t, x, command, self.dt_s, steps, self.ground_height_m)
        for k in range(steps):
            x = rk4_step(self.model.derivative, t + k * self.dt_s, x, command, self.dt_s)
            self.model.post_step(x, command)
            if self.ground_height_m is not None:
                self.model.rest_on_ground(x, self.ground_height_m)
            if not np.all(np.isfinite(x)):
                vehicle = int(np.argwhere(~np.isfinite(x))[0, 0])
                raise FloatingPointError(
                    f"the state of vehicle {vehicle} became non-finite at t = {t + (k + 1) * self.dt_s:.6f} s"
                )
        return x

    def step(self, t: float, x: FloatArray, u: ArrayLike) -> FloatArray:
        """State after one step of ``dt_s``."""
        return self.advance(t, x, u, 1)
