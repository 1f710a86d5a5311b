"""Setpoint schedules that make a flight informative for identification.

Effects that look alike are told apart by the regimes in which they act (effects.md), so an
identification flight must visit them all: horizontal speed along both axes (drag, linear in speed for
rotor drag and quadratic for fuselage drag), climbs and descents (inflow), hovering close to the ground
(ground effect), a spread of rotor speeds (thrust coefficient growing with speed against a mass offset),
and yaw turns (upper and lower coaxial rotors then spin at different speeds). The schedule is a list of
``(t, x, y, z, yaw)`` rows for :func:`multirotor_ros.simulation.simulate_flight`.
"""

from __future__ import annotations

import numpy as np

from multirotor_ros.model.rotation import FloatArray

# One lap of manoeuvres: (dwell [s], x, y, z [m], yaw [rad]); lengths chosen for a 1.5-3 kg multirotor.
_LAP: tuple[tuple[float, float, float, float, float], ...] = (
    (3.0, 0.0, 0.0, 1.5, 0.0),  # take off
    (3.0, 4.0, 0.0, 1.5, 0.0),  # fast leg along x
    (3.0, -4.0, 0.0, 1.5, 0.8),  # back, turning (coaxial rotors split)
    (3.0, 0.0, 4.0, 2.5, 0.0),  # diagonal, climbing
    (3.0, 0.0, -4.0, 1.0, -0.8),  # along y, descending, turning
    (3.0, 0.0, 0.0, 4.0, 0.0),  # climb
    (3.0, 0.0, 0.0, 0.5, 0.0),  # descent
    (3.0, 0.0, 0.0, 0.2, 0.0),  # close to the ground
    (2.0, 0.0, 0.0, 0.35, 0.6),
    (3.0, 3.0, 3.0, 2.0, 0.0),
    (3.0, -3.0, -3.0, 2.0, -0.6),
)


def excitation_setpoints(
    duration_s: float, rng: np.random.Generator | None = None, scale: float = 1.0
) -> FloatArray:
    """(K, 5) setpoints covering ``duration_s``: laps of the manoeuvres above.

    ``rng`` (optional) jitters positions by up to 30 % and dwell times by up to 20 % so that repeated
    flights differ; ``scale`` multiplies the horizontal distances (speed).
    """
    rows: list[tuple[float, float, float, float, float]] = []
    t = 0.5
    while t < duration_s:
        for dwell, x, y, z, yaw in _LAP:
            if rng is not None:
                dwell *= 1.0 + 0.2 * rng.uniform(-1, 1)
                x *= 1.0 + 0.3 * rng.uniform(-1, 1)
                y *= 1.0 + 0.3 * rng.uniform(-1, 1)
                yaw += 0.2 * rng.uniform(-1, 1)
            rows.append((t, scale * x, scale * y, z, yaw))
            t += dwell
            if t >= duration_s:
                break
    return np.array(rows, dtype=float)
