"""Sensor models of the simulated vehicle; every draw comes from a caller's ``numpy.random.Generator``.

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
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from multirotor_ros.model.rotation import FloatArray, euler_to_quat, quat_multiply, quat_to_matrix

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


def _small_rotation(rng: np.random.Generator, sigma_rad: float) -> FloatArray:
    """A random rotation quaternion (w, x, y, z) with each Euler angle ~ N(0, sigma)."""
    return euler_to_quat(rng.normal(0.0, sigma_rad, 3)) if sigma_rad > 0 else np.array([1.0, 0.0, 0.0, 0.0])


@dataclass
class ImuReading:
    """Orientation (w, x, y, z), specific force [m/s^2] and body rate [rad/s], both in body FLU."""

    q_WB: FloatArray
    specific_force_B: FloatArray
    w_WB_B: FloatArray


class Imu:
    """3DM-GX3-25-like IMU: white noise plus a bias that starts at a draw and random-walks."""

    def __init__(self, config: SensorConfig, rng: np.random.Generator, gravity_m_s2: float):
        self.config = config
        self.rng = rng
        self.gravity_m_s2 = gravity_m_s2
        self.accel_bias = rng.normal(0.0, config.accel_bias_initial_m_s2, 3)
        self.gyro_bias = rng.normal(0.0, config.gyro_bias_initial_rad_s, 3)
        self._last_t: float | None = None

    def sample(self, t_s: float, q_WB: FloatArray, a_WB_W: FloatArray, w_WB_B: FloatArray) -> ImuReading:
        """A reading for the true attitude, acceleration (world, gravity excluded) and body rate."""
        c = self.config
        dt = 0.0 if self._last_t is None else max(t_s - self._last_t, 0.0)
        self._last_t = t_s
        walk = math.sqrt(dt / c.BIAS_STABILITY_TIME_S)
        self.accel_bias = self.accel_bias + self.rng.normal(0.0, c.accel_bias_stability_m_s2 * walk, 3)
        self.gyro_bias = self.gyro_bias + self.rng.normal(0.0, c.gyro_bias_stability_rad_s * walk, 3)
        R_WB = quat_to_matrix(q_WB)
        # Specific force: what an accelerometer measures, R^T (a - g_vec) with g_vec = (0, 0, -g).
        f_B = R_WB.T @ (a_WB_W + np.array([0.0, 0.0, self.gravity_m_s2]))
        f_B = f_B + self.accel_bias + self.rng.normal(0.0, c.accel_sample_std_m_s2, 3)
        w_B = w_WB_B + self.gyro_bias + self.rng.normal(0.0, c.gyro_sample_std_rad_s, 3)
        q = quat_multiply(q_WB, _small_rotation(self.rng, c.orientation_noise_rad))
        return ImuReading(q / np.linalg.norm(q), f_B, w_B)


def range_reading(
    config: SensorConfig,
    rng: np.random.Generator,
    p_WB_W: FloatArray,
    R_WB: FloatArray,
    ground_height_m: float = 0.0,
) -> float:
    """SRF08 reading [m]: slant distance along body -z to the ground plus the mount offset; +inf = no echo."""
    cos_tilt = float(R_WB[2, 2])
    if cos_tilt < math.cos(config.range_max_tilt_rad):
        return math.inf
    # The sensor sits range_offset_m above the body origin's ground contact point, so a landed vehicle
    # reads the offset; in flight its beam (body -z) meets the ground after (height / cos tilt).
    distance = max(float(p_WB_W[2]) - ground_height_m, 0.0) / cos_tilt + config.range_offset_m
    if distance > config.range_max_m:
        return math.inf
    if config.range_resolution_m > 0:
        distance = config.range_resolution_m * round(distance / config.range_resolution_m)
    return max(distance, config.range_min_m)


def pose_reading(
    config: SensorConfig, rng: np.random.Generator, p_WB_W: FloatArray, q_WB: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Motion-capture position (world ENU) and attitude (w, x, y, z) with white noise."""
    p = p_WB_W + rng.normal(0.0, config.pose_position_noise_m, 3)
    q = quat_multiply(q_WB, _small_rotation(rng, config.pose_angle_noise_rad))
    return p, q / np.linalg.norm(q)


def rotor_speed_reading(
    config: SensorConfig, rng: np.random.Generator, omega_rad_s: FloatArray
) -> FloatArray:
    """Measured rotor speeds: the true speeds with white noise, never negative."""
    noisy = omega_rad_s + rng.normal(0.0, config.rotor_speed_noise_rad_s, omega_rad_s.shape)
    return np.maximum(noisy, 0.0)
