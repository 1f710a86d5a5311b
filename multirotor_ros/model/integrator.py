"""The one integrator: fixed-step classical Runge-Kutta (RK4), batched over vehicles.

Each step holds the rotor command constant (zero-order hold, as a flight controller's output is),
renormalises the attitude quaternions, applies ground contact, and refuses to produce a non-finite
state. Randomness (sensor noise) is never drawn here: callers pass their own ``numpy.random.Generator``.

Ground contact: a flat ground that holds what rests on it. A step that would end below the ground ends
on it, at the pose the vehicle had before the step, at rest: the normal force stops the fall and static
friction stops sliding and turning for as long as the thrust does not lift the vehicle (a step that ends
above the ground is free flight). The pose must be held, not only the velocities zeroed: otherwise each
step keeps the motion gained within it, so that a torque of alpha [rad/s^2] turns a grounded vehicle at
alpha dt / 2 [rad/s] (an artefact of the step size); an upside-down X8 with full thrust and a roll torque
turned over in about a minute and took off once its thrust pointed up enough.
A :class:`CrashLatch` adds crashes: a touchdown too fast or too tilted latches the vehicle, which then
stays where it lies whatever its rotors do, until the latch is cleared (stopping its rotors, by their
command, is the caller's part).

Two backends compute the same steps: ``numpy`` (the reference :class:`Model`, any effect, any form)
and ``compiled`` (multirotor_ros.model.compiled, the effects of effects.md, Newton-Euler form), chosen
automatically; ``advance`` runs many steps in one call, which is where the compiled backend shines.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from multirotor_ros.model import state as S
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


class CrashLatch:
    """Which vehicles of a batch have crashed, and the touchdown that makes a crash; filled by the integrator.

    A vehicle crashes when it touches the ground falling faster than ``crash_speed_m_s`` [m/s] or tilted
    (body z axis from world up) by more than ``crash_tilt_rad`` [rad]; ``math.inf`` and ``math.pi``
    turn either test off. Per vehicle: ``crashed`` (latched until :meth:`clear`), the falling speed of
    its crash ``touchdown_speed_m_s`` [m/s] (NaN: none), and ``crash_step``, the step of the last
    ``advance`` call in which it crashed (-1: not in that call), which is how a caller learns of a crash.
    """

    def __init__(self, batch: int, crash_speed_m_s: float, crash_tilt_rad: float):
        if not crash_speed_m_s > 0:
            raise ValueError(f"crash_speed_m_s must be > 0 (inf: never by speed), got {crash_speed_m_s}")
        if not 0 < crash_tilt_rad <= math.pi:
            raise ValueError(f"crash_tilt_rad must be in (0, pi] (pi: never by tilt), got {crash_tilt_rad}")
        self.crash_speed_m_s = float(crash_speed_m_s)
        self.crash_tilt_rad = float(crash_tilt_rad)
        # The test compares cos(tilt) of the attitude with this, so that no step takes an arccos.
        self.cos_crash_tilt = -math.inf if crash_tilt_rad == math.pi else math.cos(crash_tilt_rad)
        self.crashed: NDArray[np.bool_] = np.zeros(batch, dtype=bool)
        self.touchdown_speed_m_s: FloatArray = np.full(batch, np.nan)
        self.crash_step: NDArray[np.int64] = np.full(batch, -1, dtype=np.int64)

    def clear(self, vehicles: int | slice = slice(None)) -> None:
        """Forget the crashes of ``vehicles`` (an index or a slice; all by default)."""
        self.crashed[vehicles] = False
        self.touchdown_speed_m_s[vehicles] = np.nan
        self.crash_step[vehicles] = -1

    def held(
        self, touching: NDArray[np.bool_], falling_m_s: FloatArray, cos_tilt: FloatArray, step: int
    ) -> NDArray[np.bool_]:
        """Latch the vehicles whose touchdown is a crash; returns those the ground holds.

        ``touching``: below the ground after the step; ``falling_m_s``: downward speed at its end;
        ``cos_tilt``: of the attitude held. Held: touching or crashed.
        """
        crash = (
            touching
            & ~self.crashed
            & ((falling_m_s > self.crash_speed_m_s) | (cos_tilt < self.cos_crash_tilt))
        )
        self.crashed |= crash
        self.touchdown_speed_m_s[crash] = falling_m_s[crash]
        self.crash_step[crash] = step
        return touching | self.crashed


def hold_on_ground(
    x_before: FloatArray, x: FloatArray, height_m: float, latch: CrashLatch | None, step: int
) -> None:
    """Ground contact of Newton-Euler states ``x`` after a step from ``x_before`` (module docstring)."""
    touching = x[:, 2] < height_m
    held = touching
    if latch is not None:
        q = x_before[:, S.QUATERNION]
        cos_tilt = 1.0 - 2.0 * (q[:, 1] ** 2 + q[:, 2] ** 2)
        held = latch.held(touching, -x[:, 5], cos_tilt, step)
    x[held, 0:2] = x_before[held, 0:2]
    x[held, 2] = height_m
    x[held, S.QUATERNION] = x_before[held, S.QUATERNION]
    x[held, S.VELOCITY] = 0.0
    x[held, S.BODY_RATE] = 0.0


class Integrator:
    """Steps a model (:class:`Model`, or its Hamiltonian form) at a fixed ``dt`` for a batch of vehicles.

    ``ground_height_m`` (None = no ground): a vehicle cannot sink below it; while it rests there the
    ground holds it still (its pose kept, velocity and body rate zero) until thrust lifts it. ``advance``
    with a :class:`CrashLatch` latches crashes too (see the module docstring).
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

    def advance(
        self, t: float, x: FloatArray, u: ArrayLike, steps: int = 1, crashes: CrashLatch | None = None
    ) -> FloatArray:
        """State after ``steps`` steps of ``dt_s`` from (t, x) with rotor commands u (B, N) [rad/s] held.

        ``crashes`` (one entry per vehicle; needs a ground): latches crashes and holds crashed vehicles.
        """
        command = self.model.check_command(u, x.shape[0])
        if crashes is not None:
            if self.ground_height_m is None:
                raise ValueError("crashes need a ground: this integrator has ground_height_m None")
            if crashes.crashed.shape != (x.shape[0],):
                raise ValueError(
                    f"the crash latch has {crashes.crashed.size} vehicles, the state {x.shape[0]}"
                )
        if self.backend == "compiled":
            stepper = self._stepper(x.shape[0])
            return stepper.advance(t, x, command, self.dt_s, steps, self.ground_height_m, crashes)
        if crashes is not None:
            crashes.crash_step[:] = -1
        for k in range(steps):
            x_before = x
            x = rk4_step(self.model.derivative, t + k * self.dt_s, x, command, self.dt_s)
            self.model.post_step(x, command)
            if self.ground_height_m is not None:
                self._ground_contact(x_before, x, self.ground_height_m, crashes, k)
            if not np.all(np.isfinite(x)):
                vehicle = int(np.argwhere(~np.isfinite(x))[0, 0])
                raise FloatingPointError(
                    f"the state of vehicle {vehicle} became non-finite at t = {t + (k + 1) * self.dt_s:.6f} s"
                )
        return x

    def _ground_contact(
        self, x_before: FloatArray, x: FloatArray, height_m: float, crashes: CrashLatch | None, step: int
    ) -> None:
        if isinstance(self.model, HamiltonianModel):
            self.model.rest_on_ground(x_before, x, height_m, crashes, step)
        else:
            hold_on_ground(x_before, x, height_m, crashes, step)

    def step(self, t: float, x: FloatArray, u: ArrayLike) -> FloatArray:
        """State after one step of ``dt_s``."""
        return self.advance(t, x, u, 1)
