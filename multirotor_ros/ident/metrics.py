"""How well a model matches a log: acceleration error, position over short re-initialised horizons.

- Acceleration (the equation-error residual): measured minus modelled world acceleration per sample,
  the model driven by the log's attitude, rotor speeds, velocity and height; mean square per axis.
- Position over horizons (seed 1 §III-D compares positions, and notes that open-loop double integration
  drifts): the log is cut into windows of ``horizon_s``; in each the model's acceleration is integrated
  twice from the *measured* position and velocity at the window's start, and compared with the measured
  position. The model's velocity-dependent terms see the measured velocity (a one-step-ahead, "series-
  parallel" simulation), so a window's error is the drift the model's force error alone causes.
"""

from __future__ import annotations

import numpy as np

from multirotor_ros.ident.samples import FlightSamples
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import FloatArray

AXES = ("x", "y", "z")
DEFAULT_HORIZON_S = 1.0


def per_axis(values: FloatArray) -> dict[str, float]:
    """{"x": v0, "y": v1, "z": v2}."""
    return {axis: float(v) for axis, v in zip(AXES, values, strict=True)}


def model_acceleration(samples: FlightSamples, model: Model) -> FloatArray:
    """(T, 3) world acceleration [m/s^2] the model gives along the log (no measurement chain)."""
    return model.accelerations(samples.model_context(model))[0]


def horizon_windows(samples: FlightSamples, horizon_s: float) -> list[tuple[int, int]]:
    """[start, stop) index ranges of whole windows of ``horizon_s`` inside usable segments."""
    length = max(2, int(round(horizon_s / samples.dt)) + 1)
    windows = []
    for start, stop in samples.segments:
        k = start
        while k + length <= stop:
            if np.all(samples.valid[k : k + length]):
                windows.append((k, k + length))
            k += length - 1
    return windows


def horizon_position_error(
    samples: FlightSamples, acceleration: FloatArray, horizon_s: float = DEFAULT_HORIZON_S
) -> tuple[FloatArray | None, FloatArray]:
    """(mse per axis [m^2], None without measured position; predicted positions (T, 3), NaN off windows)."""
    predicted = np.full((samples.t.size, 3), np.nan)
    if not samples.position_measured:
        return None, predicted
    windows = horizon_windows(samples, horizon_s)
    if not windows:
        return None, predicted
    errors = []
    for start, stop in windows:
        t = samples.t[start:stop] - samples.t[start]
        a = acceleration[start:stop]
        dt = np.diff(t)[:, None]
        v = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (a[1:] + a[:-1]) * dt, axis=0)])
        p = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (v[1:] + v[:-1]) * dt, axis=0)])
        p += samples.p_WB_W[start] + samples.v_WB_W[start] * t[:, None]
        # The first sample of each window is the measurement itself: not an error.
        predicted[start + 1 : stop] = p[1:]
        errors.append(p[1:] - samples.p_WB_W[start + 1 : stop])
    stacked = np.concatenate(errors)
    return np.mean(stacked**2, axis=0), predicted
