"""The lane kernel of multirotor_ros.model.compiled: chunks of vehicles, partial chunks, threads.

test_model.py and test_effects.py pin the physics on small batches; these tests cover what only a
batch larger than one chunk (compiled.LANES vehicles) exercises: the parallel kernel, the last, partial
chunk, per-vehicle parameters spread over chunks and a failure in a later chunk.
"""

from __future__ import annotations

import numpy as np
import pytest

from multirotor_ros.model import compiled
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.integrator import Integrator
from multirotor_ros.model.model import Model

BATCH = 2 * compiled.LANES + 5  # two full chunks and a partial one: the parallel kernel
X8 = load_airframe("x8_octorotor")


def _effects(b: slice | int) -> list[dict]:
    """Every effect, with parameters that differ from vehicle to vehicle (vehicles ``b``)."""
    vehicles = np.arange(BATCH)
    return [
        {"id": "quadratic_drag", "c_x": np.linspace(0.1, 0.9, BATCH)[b], "c_y": 0.4, "c_z": 0.2},
        {"id": "rotor_drag", "k_h": 2e-4},
        {"id": "thrust_speed_dependence", "k_f1": 2e-9},
        {"id": "coaxial_loss", "eta_lower": 0.8},
        {"id": "ground_effect", "rotor_radius_m": 0.127},
        {"id": "inflow_thrust_loss", "k_v": 1e-4},
        {"id": "motor_lag", "tau_s": np.linspace(0.02, 0.05, BATCH)[b]},
        {"id": "mass_offset", "dm_kg": 0.3},
        {"id": "constant_force", "f_x": 1.0, "f_y": -0.5, "f_z": 0.2},
        {
            "id": "actuator_fault",
            "motor": (1 + vehicles % 8)[b].astype(float),
            "effectiveness": 0.4,
            "t_fault_s": (0.05 + 0.001 * (vehicles % 50))[b],
        },
        {"id": "gyroscopic", "j_r": 1e-4},
        {"id": "cg_offset", "r_x": 0.01, "r_y": -0.02},
    ]


def _start() -> tuple[np.ndarray, np.ndarray]:
    """Vehicles from resting on the ground to flying, with commands from sinking to climbing."""
    rng = np.random.default_rng(3)
    x0 = S.make_state(8, batch=BATCH, rotor_speed_rad_s=340.0)
    x0[:, S.POSITION] = rng.uniform([-1, -1, 0.0], [1, 1, 0.6], (BATCH, 3))
    x0[:, S.VELOCITY] = rng.normal(0, 0.5, (BATCH, 3))
    x0[:, S.BODY_RATE] = rng.normal(0, 0.3, (BATCH, 3))
    u = rng.uniform(300, 380, (BATCH, 8))
    return x0, u


def test_a_batch_of_several_chunks_equals_the_reference_and_separate_runs() -> None:
    x0, u = _start()
    batched = Model(X8, _effects(slice(None)))
    assert compiled.supports(batched) and BATCH >= compiled.PARALLEL_MIN_BATCH
    x = Integrator(batched, 1e-3, backend="compiled").advance(0.0, x0, u, 150)
    reference = Integrator(batched, 1e-3, backend="numpy").advance(0.0, x0, u, 150)
    np.testing.assert_allclose(x, reference, rtol=1e-10, atol=1e-10)
    assert np.any(x[:, 2] == 0.0) and np.any(x[:, 2] > 0.1), "some vehicles rest on the ground, some fly"
    # One lane of a vector instruction computes what a single vehicle's scalar run does, bit for bit.
    for b in (0, compiled.LANES - 1, compiled.LANES, BATCH - 1):
        alone = Integrator(Model(X8, _effects(b)), 1e-3, backend="compiled")
        single = alone.advance(0.0, x0[b : b + 1], u[b], 150)
        assert np.array_equal(single[0], x[b]), f"vehicle {b}"


def test_the_derivative_of_several_chunks_matches_the_reference() -> None:
    x0, u = _start()
    model = Model(X8, _effects(slice(None)))
    for t in (0.0, 0.2):
        np.testing.assert_allclose(
            compiled.CompiledStepper(model, BATCH).derivative(t, x0, u),
            model.derivative(t, x0, u),
            rtol=1e-11,
            atol=1e-11,
        )


@pytest.mark.parametrize("vehicle", [compiled.LANES + 7, BATCH - 1])
def test_a_vehicle_blowing_up_in_a_later_chunk_is_named(vehicle: int) -> None:
    model = Model(X8)
    x = S.make_state(8, batch=BATCH, position_m=(0, 0, 5), rotor_speed_rad_s=340.0)
    x[vehicle, S.VELOCITY] = np.inf
    with pytest.raises(FloatingPointError, match=rf"vehicle {vehicle} became non-finite at t = 0\.001000 s"):
        Integrator(model, 1e-3).advance(0.0, x, np.full(8, 340.0), 10)


def test_the_input_state_is_left_untouched() -> None:
    x0, u = _start()
    before = x0.copy()
    Integrator(Model(X8), 1e-3).advance(0.0, x0, u, 5)
    assert np.array_equal(x0, before)
