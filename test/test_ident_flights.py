"""Simulated identification flights shared by the ident and discrepancy tests, and checks of their design.

``flight(...)`` flies the closed loop of multirotor_ros.simulation with effects hidden from the models
under test, along multirotor_ros.ident.excitation's schedule, and caches the log for the whole session
(the tests only read logs). Noise levels: ``low`` is the airframe's sensor set (seed 1's IMU, motion
capture, ESC speeds, with the IMU's biases), ``high`` multiplies every white noise (not the biases) by
the sweep's NOISE_HIGH, ``none`` is noise-free.
"""

import functools
from pathlib import Path

import numpy as np

from multirotor_ros.discrepancy.sweep import hidden_effect_flight
from multirotor_ros.io.flight_log import FlightLog, write_flight_log


def effect(effect_id: str, **parameters: float) -> tuple:
    """A hashable effect spec for :func:`flight`."""
    return (effect_id, tuple(sorted(parameters.items())))


@functools.cache
def flight(
    airframe: str,
    effects: tuple | None = (),
    duration_s: float = 40.0,
    seed: int = 1,
    noise: str = "low",
    setpoints: tuple | None = None,
) -> FlightLog:
    """The log of a closed-loop flight of ``airframe`` with true ``effects`` (None: the airframe's own).

    Effects are given as effect(...) tuples so that the call can be cached; the flight is the sweep's
    (multirotor_ros.discrepancy.sweep.hidden_effect_flight).
    """
    specs = None if effects is None else [{"id": effect_id, **dict(params)} for effect_id, params in effects]
    schedule = None if setpoints is None else np.array(setpoints)
    return hidden_effect_flight(airframe, specs, duration_s, seed, noise, schedule)


def flight_csv(directory: Path, name: str, log: FlightLog) -> Path:
    """Write ``log`` as a flight-log CSV in ``directory``."""
    path = directory / f"{name}.csv"
    write_flight_log(path, log)
    return path


def test_excitation_flight_visits_the_regimes_that_separate_lookalikes():
    log = flight("x8_octorotor")
    v = np.column_stack([log.columns[c] for c in ("vx", "vy", "vz")])
    horizontal = np.linalg.norm(v[:, :2], axis=1)
    omega = np.column_stack([log.columns[f"omega_{k}"] for k in range(1, 9)])
    assert horizontal.max() > 1.5  # drag
    assert v[:, 2].max() > 1.0 and v[:, 2].min() < -1.0  # inflow: climbs and descents
    airborne = log.columns["z"] > 0.05
    assert np.min(log.columns["z"][airborne & (log.t > 5)]) < 0.3  # ground effect: hovering low
    mean_speed = omega.mean(axis=1)[airborne]
    assert np.percentile(mean_speed, 95) - np.percentile(mean_speed, 5) > 30  # k_f1 against a mass offset
    assert np.ptp(np.unwrap(log.columns["yaw"])) > 1.0


def test_flights_are_reproducible_and_cached():
    first = flight("hexarotor_f550", duration_s=8.0, seed=3)
    assert flight("hexarotor_f550", duration_s=8.0, seed=3) is first
    again = flight.__wrapped__("hexarotor_f550", duration_s=8.0, seed=3)
    np.testing.assert_array_equal(again.columns["az"], first.columns["az"])
