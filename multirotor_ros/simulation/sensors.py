"""Sensor models of the simulated vehicles; every draw comes from a caller's ``numpy.random.Generator``.

Defaults are the sensors of seed 1's octorotor (§III-A):

- IMU: MicroStrain 3DM-GX3-25 (datasheet "3DM-GX3-25 Miniature Attitude Heading Reference System"):
  accelerometer noise density 80 ug/sqrt(Hz), in-run bias stability 0.04 mg, initial bias +-0.002 g;
  gyroscope noise density 0.03 deg/s/sqrt(Hz), in-run bias stability 18 deg/h, initial bias +-0.25 deg/s;
  attitude accuracy +-0.5 deg static. Output at 100 Hz as in seed 1. White noise per sample is
  density * sqrt(rate) (the discrete-time form used by Kalibr's IMU noise model); the bias starts at a
  draw of the initial bias error and then walks with the in-run stability reached after 100 s.
- Range: Devantech SRF08 ultrasonic ranger (datasheet: 3 cm to 6 m, 65 ms per ranging, so 15 Hz),
  pointing along body -z, mounted 0.10 m above the ground when landed (seed 1 §III-D: "the sensor is
  placed at an altitude of 10 cm far from the ground"): it reads the slant distance to the ground plus
  0.10 m, in steps of its 3 cm resolution; no echo (beyond 6 m, or tilted by more than half its
  55 deg beam, an assumption: a flat floor then reflects the pulse away) reads +inf.
- Pose: a motion-capture system as used in indoor flight arenas: 1 mm and 0.1 deg white noise, 100 Hz
  (assumption: typical of OptiTrack/Vicon set-ups; seed 1 flew without one).
- Rotor speeds: the ESC's speed report (seed 1's BL-Ctrl V2 give motor speed measurements), white noise
  of 2 rad/s (assumption: seed 1 gives no figure), 100 Hz.

An airframe YAML's ``sensors:`` section may override any field of :class:`SensorConfig` by name.

Every model is batched over V vehicles sampled at the same time (a fleet; one vehicle is V = 1):
arrays carry the vehicle on their first axis. The noise comes in as standard normals ``z`` (V, count),
row k drawn from vehicle k's own generator (:func:`standard_normals`), so that vehicle k's noise is the
same whether it is simulated alone or in a fleet; each model says how many it takes per vehicle and
sample (``*_draws``) and in which order it uses them, so a caller may draw for several sensors due at
the same time in one call per vehicle. The rest is vectorised over the vehicles: elementwise numpy
arithmetic, and compiled kernels for the quaternion arithmetic (imu_kernels.py), none of which makes one
vehicle's result depend on how many others share the arrays.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from types import ModuleType
from typing import Any

import numpy as np

from multirotor_ros.model.rotation import FloatArray

DEG = math.pi / 180.0
G0 = 9.80665  # standard gravity: datasheets give accelerometer figures in g


@dataclass(frozen=True)
class SensorConfig:
    """Noise levels and rates of the simulated sensors (SI units; see the module docstring for sources)."""

    imu_rate_hz: float = 100.0
    accel_noise_density_m_s2_sqrt_hz: float = 80e-6 * G0
    accel_bias_initial_m_s2: float = 0.002 * G0
    accel_bias_stability_m_s2: float = 0.04e-3 * G0
    gyro_noise_density_rad_s_sqrt_hz: float = 0.03 * DEG
    gyro_bias_initial_rad_s: float = 0.25 * DEG
    gyro_bias_stability_rad_s: float = 18.0 * DEG / 3600.0
    orientation_noise_rad: float = 0.5 * DEG
    range_rate_hz: float = 15.0
    range_offset_m: float = 0.10
    range_resolution_m: float = 0.03
    range_min_m: float = 0.03
    range_max_m: float = 6.0
    range_max_tilt_rad: float = 27.5 * DEG
    pose_rate_hz: float = 100.0
    pose_position_noise_m: float = 0.001
    pose_angle_noise_rad: float = 0.1 * DEG
    rotor_speed_rate_hz: float = 100.0
    rotor_speed_noise_rad_s: float = 2.0

    # Bias random walk: the standard deviation the walk reaches after this time equals the in-run stability.
    BIAS_STABILITY_TIME_S = 100.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            rate = f.name.endswith("_rate_hz")
            if not math.isfinite(value) or value < 0 or (rate and value <= 0):
                raise ValueError(
                    f"sensors.{f.name}: must be a finite number {'> 0' if rate else '>= 0'}, got {value!r}"
                )
        if self.range_max_m <= self.range_min_m:
            raise ValueError(
                f"sensors.range_max_m: must exceed range_min_m ({self.range_min_m:g}), "
                f"got {self.range_max_m:g}"
            )

    @property
    def accel_sample_std_m_s2(self) -> float:
        """Standard deviation of one accelerometer sample's white noise: density x root of the rate."""
        return self.accel_noise_density_m_s2_sqrt_hz * math.sqrt(self.imu_rate_hz)

    @property
    def gyro_sample_std_rad_s(self) -> float:
        """Standard deviation of one gyro sample's white noise: density x root of the rate."""
        return self.gyro_noise_density_rad_s_sqrt_hz * math.sqrt(self.imu_rate_hz)

    def without_noise(self) -> SensorConfig:
        """The same rates and geometry with every noise and bias set to zero (and no quantisation)."""
        quiet = {f.name: 0.0 for f in fields(self) if "noise" in f.name or "bias" in f.name}
        return SensorConfig(**{**self.as_dict(), **quiet, "range_resolution_m": 0.0})

    def as_dict(self) -> dict[str, float]:
        """Name -> value."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def sensor_config_from_section(section: Mapping[str, Any] | None, origin: str) -> SensorConfig:
    """A SensorConfig from an airframe YAML's ``sensors:`` mapping; errors name ``origin`` and the key."""
    if section is None:
        return SensorConfig()
    if not isinstance(section, Mapping):
        raise ValueError(f"{origin}: sensors: expected a mapping")
    known = [f.name for f in fields(SensorConfig)]
    for key, value in section.items():
        if key not in known:
            raise ValueError(f"{origin}: sensors.{key}: unknown key; known: {', '.join(known)}")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{origin}: sensors.{key}: expected a number, got {value!r}")
    try:
        return SensorConfig(**{k: float(v) for k, v in section.items()})
    except ValueError as error:
        raise ValueError(f"{origin}: {error}") from error


def airframe_sensor_config(airframe: Any) -> SensorConfig:
    """The sensor configuration of an Airframe (its YAML's ``sensors`` section, or the defaults)."""
    origin = str(airframe.source_path) if airframe.source_path is not None else airframe.name
    return sensor_config_from_section(airframe.sections.get("sensors"), origin)


# ------------------------------------------------------------------ batched helpers


def standard_normals(rngs: Sequence[np.random.Generator], count: int) -> FloatArray:
    """(V, count) standard normal draws, row k from ``rngs[k]``: each vehicle draws from its own stream.

    ``sigma * z`` of these equals ``rng.normal(0, sigma, count)``, draw for draw.
    """
    out = np.empty((len(rngs), count))
    if count:
        for row, rng in zip(out, rngs, strict=True):
            rng.standard_normal(out=row)
    return out


# The quaternion arithmetic of every vehicle is one compiled call (simulation/imu_kernels.py, imported on
# first use: it imports numba); each vehicle is computed by the same scalar code, whatever their number.


@functools.cache  # an import statement in every sample costs a tenth of the sample
def _kernels() -> ModuleType:
    from multirotor_ros.simulation import imu_kernels

    return imu_kernels


def _turned(q_WB: FloatArray, angles_rad: FloatArray) -> FloatArray:
    """(V, 4) unit attitudes q_WB (V, 4) turned by small ZYX angles (V, 3)."""
    out = np.empty((q_WB.shape[0], 4))
    _kernels().turned_lanes(q_WB, angles_rad, out)
    return out


# ------------------------------------------------------------------ sensors


@dataclass
class ImuReading:
    """Orientation (w, x, y, z), specific force [m/s^2] and body rate [rad/s], both in body FLU."""

    q_WB: FloatArray
    specific_force_B: FloatArray
    w_WB_B: FloatArray


# [s] intervals this close share their noise scales (Imu.sample): the bias walk's step changes by 6e-6 of
# itself at 1200 Hz, against a recomputation in every sample.
SAME_INTERVAL_S = 1e-8


class Imu:
    """3DM-GX3-25-like IMUs of V vehicles: white noise plus a bias that starts at a draw and walks.

    ``z`` (V, :data:`Imu.INITIAL_DRAWS`): standard normals of the initial biases, accelerometer then gyro.
    Per vehicle k: its bias (``accel_bias[k]``, ``gyro_bias[k]``).
    """

    INITIAL_DRAWS = 6

    def __init__(self, config: SensorConfig, z: FloatArray, gravity_m_s2: float):
        self.config = config
        self.gravity_m_s2 = gravity_m_s2
        # (V, 6): accelerometer then gyro, walked in place by each sample.
        self._biases = np.concatenate(
            (config.accel_bias_initial_m_s2 * z[:, 0:3], config.gyro_bias_initial_rad_s * z[:, 3:6]), axis=1
        )
        self._last_t: float | None = None
        # The kernel's constants (imu_kernels.imu_lanes) for the last sample's config and interval.
        self._scaled_config: SensorConfig | None = None
        self._scaled_dt = math.nan
        self._constants = np.zeros(6)

    @property
    def accel_bias(self) -> FloatArray:
        """(V, 3) the accelerometers' biases now [m/s^2] (a copy)."""
        return self._biases[:, 0:3].copy()

    @property
    def gyro_bias(self) -> FloatArray:
        """(V, 3) the gyros' biases now [rad/s] (a copy)."""
        return self._biases[:, 3:6].copy()

    @staticmethod
    def draws(config: SensorConfig) -> int:
        """Standard normals per vehicle and sample, in their order of use.

        Bias walk of the accelerometer, of the gyro, white noise of each (3 each), then 3 for the
        orientation noise when it is not zero.
        """
        return 15 if config.orientation_noise_rad > 0 else 12

    def sample(
        self, t_s: float, q_WB: FloatArray, a_WB_W: FloatArray, w_WB_B: FloatArray, z: FloatArray
    ) -> list[ImuReading]:
        """One reading per vehicle from the true attitudes, accelerations and body rates.

        ``q_WB`` (V, 4); ``a_WB_W`` (V, 3) in world, gravity excluded; ``w_WB_B`` (V, 3); ``z`` (V,
        :meth:`draws`) standard normals.
        """
        c = self.config
        dt = 0.0 if self._last_t is None else max(t_s - self._last_t, 0.0)
        self._last_t = t_s
        kernels = _kernels()
        # Intervals differ in their last bits (differences of float times; ArduPilot's 1200 Hz frames
        # alternate 833,333 and 833,334 ns): within SAME_INTERVAL_S the scales stay.
        if c is not self._scaled_config or abs(dt - self._scaled_dt) > SAME_INTERVAL_S:
            walk = math.sqrt(dt / c.BIAS_STABILITY_TIME_S)
            constants = self._constants
            constants[kernels.ACCEL_BIAS_STEP] = c.accel_bias_stability_m_s2 * walk
            constants[kernels.GYRO_BIAS_STEP] = c.gyro_bias_stability_rad_s * walk
            constants[kernels.ACCEL_SIGMA] = c.accel_sample_std_m_s2
            constants[kernels.GYRO_SIGMA] = c.gyro_sample_std_rad_s
            constants[kernels.ORIENTATION_SIGMA] = c.orientation_noise_rad
            constants[kernels.GRAVITY] = self.gravity_m_s2
            self._scaled_config, self._scaled_dt = c, dt
        # A new array each sample: the readings handed out are views of it.
        out = np.empty((q_WB.shape[0], kernels.OUT_COLUMNS))
        kernels.imu_lanes(q_WB, a_WB_W, w_WB_B, z, self._constants, self._biases, out)
        q, f, w = kernels.OUT_QUATERNION, kernels.OUT_SPECIFIC_FORCE, kernels.OUT_RATE
        # Rows by index: iterating arrays row by row (zip) costs three times as much for one vehicle.
        return [ImuReading(out[k, q], out[k, f], out[k, w]) for k in range(len(out))]


def range_readings(
    config: SensorConfig, p_WB_W: FloatArray, q_WB: FloatArray, ground_height_m: float = 0.0
) -> FloatArray:
    """(V,) SRF08 readings [m]: slant distance along body -z to the ground plus the mount offset.

    +inf = no echo. ``p_WB_W`` (V, 3), ``q_WB`` (V, 4). The SRF08 model draws no noise.
    """
    qx, qy = q_WB[:, 1], q_WB[:, 2]
    cos_tilt = 1 - 2 * (qx * qx + qy * qy)  # R_WB[2, 2]: body z against world z
    echo = cos_tilt >= math.cos(config.range_max_tilt_rad)
    # The sensor sits range_offset_m above the body origin's ground contact point, so a landed vehicle
    # reads the offset; in flight its beam (body -z) meets the ground after (height / cos tilt).
    height = np.maximum(p_WB_W[:, 2] - ground_height_m, 0.0)
    distance = np.divide(height, cos_tilt, out=np.full_like(height, math.inf), where=echo)
    distance += config.range_offset_m
    echo &= distance <= config.range_max_m
    if config.range_resolution_m > 0:
        distance = config.range_resolution_m * np.round(distance / config.range_resolution_m)
    return np.where(echo, np.maximum(distance, config.range_min_m), math.inf)


def pose_draws(config: SensorConfig) -> int:
    """Standard normals per vehicle and motion-capture sample.

    3 for the position, then 3 for the attitude when its noise is not zero.
    """
    return 6 if config.pose_angle_noise_rad > 0 else 3


def pose_readings(
    config: SensorConfig, p_WB_W: FloatArray, q_WB: FloatArray, z: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Motion-capture positions (V, 3; world ENU) and attitudes (V, 4; w, x, y, z) with white noise.

    ``z`` (V, :func:`pose_draws`): standard normals.
    """
    p = p_WB_W + config.pose_position_noise_m * z[:, 0:3]
    rotate = config.pose_angle_noise_rad > 0
    angles = config.pose_angle_noise_rad * z[:, 3:6] if rotate else np.zeros_like(p)
    return p, _turned(q_WB, angles)


def rotor_speed_draws(n_rotors: int) -> int:
    """Standard normals per vehicle and ESC report: one per rotor."""
    return n_rotors


def rotor_speed_readings(config: SensorConfig, omega_rad_s: FloatArray, z: FloatArray) -> FloatArray:
    """(V, N) measured rotor speeds: the true speeds (V, N) with white noise, never negative.

    ``z`` (V, N): standard normals.
    """
    return np.maximum(omega_rad_s + config.rotor_speed_noise_rad_s * z, 0.0)
