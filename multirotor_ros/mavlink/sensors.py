"""What a flight stack's sensors would read on the simulated vehicle: barometer, magnetometer, GPS.

The physics knows a position in the world ENU frame ``odom`` (origin = home) and an attitude; a flight
stack wants absolute pressure, a magnetic field in its body frame and a latitude/longitude/altitude.

- Barometer: the International Standard Atmosphere (ISO 2533) troposphere, valid below 11 km:
  T = T0 - L h, p = p0 (T / T0)^(g0 / (R L)). ``pressure_altitude_m`` inverts it.
- Magnetometer: a constant Earth field at home, given as declination, inclination and strength
  (what a world magnetic model gives for one place), rotated into the body frame.
- GPS: home latitude, longitude and altitude define the local tangent plane (ENU) whose origin is
  the ``odom`` origin; positions go through WGS-84 Earth-centred coordinates, so the conversion is
  exact (no flat-Earth error). Altitudes are above mean sea level and the geoid is taken as the
  ellipsoid: the few tens of metres between them shift every altitude equally and change nothing here.

Frames: world ENU / body FLU in, NED / FRD out, through :mod:`multirotor_ros.frames`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.frames import enu_to_ned, flu_to_frd, ned_to_enu
from multirotor_ros.mavlink.messages import heading_cdeg, wire_value
from multirotor_ros.model.rotation import FloatArray

# ISA sea-level reference and troposphere lapse rate (ISO 2533).
ISA_PRESSURE_PA = 101325.0  # [Pa]
ISA_TEMPERATURE_K = 288.15  # [K]
ISA_LAPSE_RATE_K_M = 0.0065  # [K/m]
ISA_GAS_CONSTANT_J_KG_K = 287.05287  # [J/(kg K)] dry air
STANDARD_GRAVITY_M_S2 = 9.80665  # [m/s^2]
ISA_TROPOPAUSE_M = 11000.0  # [m] the model is only valid below
ISA_LOWEST_M = -2000.0  # [m] below any place on land (Dead Sea shore: -430 m)
_ISA_EXPONENT = STANDARD_GRAVITY_M_S2 / (ISA_GAS_CONSTANT_J_KG_K * ISA_LAPSE_RATE_K_M)  # ~5.2559

# WGS-84 ellipsoid.
WGS84_A_M = 6378137.0  # [m] semi-major axis
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)


class SensorConfigError(ValueError):
    """A home position or magnetic field that the models cannot use."""


def isa_temperature_k(altitude_m: ArrayLike) -> FloatArray:
    """ISA air temperature [K] at a geopotential altitude above mean sea level [m]."""
    return ISA_TEMPERATURE_K - ISA_LAPSE_RATE_K_M * np.asarray(altitude_m, dtype=float)


def isa_pressure_pa(altitude_m: ArrayLike) -> FloatArray:
    """ISA static pressure [Pa] at an altitude above mean sea level [m] (troposphere)."""
    return ISA_PRESSURE_PA * (isa_temperature_k(altitude_m) / ISA_TEMPERATURE_K) ** _ISA_EXPONENT


def pressure_altitude_m(pressure_pa: ArrayLike) -> FloatArray:
    """Altitude [m] at which the ISA has this static pressure [Pa]: the inverse of :func:`isa_pressure_pa`."""
    ratio = np.asarray(pressure_pa, dtype=float) / ISA_PRESSURE_PA
    return ISA_TEMPERATURE_K / ISA_LAPSE_RATE_K_M * (1.0 - ratio ** (1.0 / _ISA_EXPONENT))


def magnetic_field_ned_gauss(
    declination_deg: float, inclination_deg: float, strength_gauss: float
) -> FloatArray:
    """Earth field in NED [gauss]: declination east of north, inclination positive downwards."""
    declination = math.radians(declination_deg)
    inclination = math.radians(inclination_deg)
    horizontal = strength_gauss * math.cos(inclination)
    return np.array(
        [
            horizontal * math.cos(declination),
            horizontal * math.sin(declination),
            strength_gauss * math.sin(inclination),
        ]
    )


def geodetic_to_ecef(
    latitude_deg: float, longitude_deg: float, altitude_m: float
) -> tuple[float, float, float]:
    """WGS-84 geodetic coordinates -> Earth-centred, Earth-fixed position [m]."""
    lat = math.radians(latitude_deg)
    lon = math.radians(longitude_deg)
    n = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * math.sin(lat) ** 2)
    return (
        (n + altitude_m) * math.cos(lat) * math.cos(lon),
        (n + altitude_m) * math.cos(lat) * math.sin(lon),
        (n * (1.0 - WGS84_E2) + altitude_m) * math.sin(lat),
    )


def ecef_to_geodetic(x: float, y: float, z: float) -> tuple[float, float, float]:
    """Earth-fixed position [m] -> (latitude [deg], longitude [deg], altitude [m]), WGS-84.

    Bowring's method with two refinements: sub-millimetre anywhere near the Earth's surface. Scalar
    ``math`` on purpose: it runs for every GPS and state message, where numpy's per-call cost dominates.
    """
    lon = math.atan2(y, x)
    p = math.hypot(x, y)
    second_e2 = (WGS84_A_M**2 - WGS84_B_M**2) / WGS84_B_M**2
    beta = math.atan2(WGS84_A_M * z, WGS84_B_M * p)
    lat = 0.0
    for _ in range(3):
        lat = math.atan2(
            z + second_e2 * WGS84_B_M * math.sin(beta) ** 3, p - WGS84_E2 * WGS84_A_M * math.cos(beta) ** 3
        )
        beta = math.atan2((1.0 - WGS84_F) * math.sin(lat), math.cos(lat))
    n = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * math.sin(lat) ** 2)
    # h = p cos(lat) + z sin(lat) - a^2 / N: well conditioned at every latitude.
    altitude = p * math.cos(lat) + z * math.sin(lat) - WGS84_A_M**2 / n
    return math.degrees(lat), math.degrees(lon), altitude


@dataclass(frozen=True)
class Home:
    """Where the ``odom`` origin is on Earth and what the magnetic field is there.

    Defaults: PX4's SITL home (Zurich Irchel park) and its field (WMM: declination +3.0 deg,
    inclination +63.3 deg, 0.48 gauss), so a stock PX4 accepts the sensors without calibration.
    """

    latitude_deg: float = 47.397742  # [deg] WGS-84
    longitude_deg: float = 8.545594  # [deg] WGS-84
    altitude_m: float = 488.0  # [m] above mean sea level
    mag_declination_deg: float = 3.0  # [deg] east of true north
    mag_inclination_deg: float = 63.3  # [deg] positive downwards
    mag_strength_gauss: float = 0.48  # [gauss]

    def __post_init__(self) -> None:
        checks = {
            "home_latitude_deg": (self.latitude_deg, -90.0, 90.0),
            "home_longitude_deg": (self.longitude_deg, -180.0, 180.0),
            "home_altitude_m": (self.altitude_m, -400.0, ISA_TROPOPAUSE_M - 1000.0),
            "mag_declination_deg": (self.mag_declination_deg, -180.0, 180.0),
            "mag_inclination_deg": (self.mag_inclination_deg, -90.0, 90.0),
            "mag_strength_gauss": (self.mag_strength_gauss, 0.0, 1.0),
        }
        for name, (value, low, high) in checks.items():
            if not (math.isfinite(value) and low <= value <= high):
                raise SensorConfigError(f"{name} = {value!r} is outside [{low:g}, {high:g}]")
        # A pole makes east and north undefined: the tangent plane has no heading there.
        if abs(self.latitude_deg) > 89.9:
            raise SensorConfigError(f"home_latitude_deg = {self.latitude_deg} is too close to a pole")


class LocalTangentPlane:
    """ENU offsets from home [m] <-> WGS-84 latitude, longitude, altitude."""

    def __init__(self, home: Home):
        self.home = home
        lat = math.radians(home.latitude_deg)
        lon = math.radians(home.longitude_deg)
        self._origin_ecef = np.array(geodetic_to_ecef(home.latitude_deg, home.longitude_deg, home.altitude_m))
        # Columns: east, north, up unit vectors in Earth-fixed coordinates.
        self._R_ecef_enu = np.array(
            [
                [-math.sin(lon), -math.sin(lat) * math.cos(lon), math.cos(lat) * math.cos(lon)],
                [math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat) * math.sin(lon)],
                [0.0, math.cos(lat), math.sin(lat)],
            ]
        )

    def geodetic(self, p_enu_m: ArrayLike) -> tuple[float, float, float]:
        """(latitude [deg], longitude [deg], altitude AMSL [m]) of an ENU position."""
        x, y, z = (self._origin_ecef + self._R_ecef_enu @ np.asarray(p_enu_m, dtype=float)).tolist()
        return ecef_to_geodetic(x, y, z)

    def enu(self, latitude_deg: float, longitude_deg: float, altitude_m: float) -> FloatArray:
        """ENU position [m] of geodetic coordinates: the inverse of :meth:`geodetic`."""
        r = np.array(geodetic_to_ecef(latitude_deg, longitude_deg, altitude_m))
        return self._R_ecef_enu.T @ (r - self._origin_ecef)


@dataclass(frozen=True)
class Barometer:
    """What the barometer reads: absolute pressure [hPa], pressure altitude [m], temperature [degC]."""

    pressure_hpa: float
    pressure_altitude_m: float
    temperature_degc: float


@dataclass(frozen=True)
class GpsFix:
    """A GPS solution in MAVLink's units: degE7, mm, cm/s NED, cdeg."""

    latitude_e7: int
    longitude_e7: int
    altitude_mm: int
    v_ned_cm_s: tuple[int, int, int]
    ground_speed_cm_s: int
    course_cdeg: int  # 65535 when not moving: the course over ground is undefined


class SensorModel:
    """Barometer, magnetometer and GPS of a vehicle flying over ``home`` (noise-free, like ground truth)."""

    def __init__(self, home: Home):
        self.home = home
        self.plane = LocalTangentPlane(home)
        self.B_NED_gauss = magnetic_field_ned_gauss(
            home.mag_declination_deg, home.mag_inclination_deg, home.mag_strength_gauss
        )
        self._B_ENU_gauss = tuple(ned_to_enu(self.B_NED_gauss).tolist())

    def altitude_m(self, p_WB_W: ArrayLike) -> float:
        """Altitude above mean sea level [m] of an ENU position."""
        return self.home.altitude_m + float(np.asarray(p_WB_W, dtype=float)[2])

    def barometer(self, p_WB_W: ArrayLike) -> Barometer:
        """Static pressure, pressure altitude and air temperature at an ENU position."""
        # Within the model's range: 1e63 m below the sea would overflow the power law.
        altitude = max(min(self.altitude_m(p_WB_W), ISA_TROPOPAUSE_M), ISA_LOWEST_M)
        # Scalar math (the ISA functions above, for one altitude): this runs at every physics step.
        temperature_k = ISA_TEMPERATURE_K - ISA_LAPSE_RATE_K_M * altitude
        pressure = ISA_PRESSURE_PA * (temperature_k / ISA_TEMPERATURE_K) ** _ISA_EXPONENT
        return Barometer(pressure / 100.0, altitude, temperature_k - 273.15)

    def magnetometer_frd_gauss(self, q_WB: ArrayLike) -> FloatArray:
        """The home field seen by a magnetometer on body FRD axes, for an attitude q_WB (FLU -> ENU)."""
        # B_FRD = R_NED_FRD^T B_NED, R_NED_FRD = ENU_TO_NED R_WB FLU_TO_FRD (frames.py), i.e.
        # FLU_TO_FRD R_WB^T B_ENU with B_ENU fixed. R_WB^T v is written out in floats: numpy's per-call
        # cost would be most of the time for one 3-vector, at every physics step.
        w, x, y, z = (float(c) for c in np.asarray(q_WB, dtype=float))
        bx, by, bz = self._B_ENU_gauss
        body_flu = (
            (1 - 2 * (y * y + z * z)) * bx + 2 * (x * y + w * z) * by + 2 * (x * z - w * y) * bz,
            2 * (x * y - w * z) * bx + (1 - 2 * (x * x + z * z)) * by + 2 * (y * z + w * x) * bz,
            2 * (x * z + w * y) * bx + 2 * (y * z - w * x) * by + (1 - 2 * (x * x + y * y)) * bz,
        )
        return flu_to_frd(body_flu)

    def gps(self, p_WB_W: ArrayLike, v_WB_W: ArrayLike) -> GpsFix:
        """Position and velocity as a GPS receiver reports them."""
        latitude, longitude, altitude = self.plane.geodetic(p_WB_W)
        v_ned = enu_to_ned(v_WB_W)
        ground_speed = float(math.hypot(v_ned[0], v_ned[1]))
        course = 65535
        if ground_speed > 0.05:
            course = heading_cdeg(math.atan2(v_ned[1], v_ned[0]))
        # Integers fitted to their fields: a position or speed no GPS reports must not raise here.
        north_cm_s, east_cm_s, down_cm_s = (wire_value(v * 100.0, "int16_t") for v in v_ned)
        return GpsFix(
            latitude_e7=wire_value(latitude * 1e7, "int32_t"),
            longitude_e7=wire_value(longitude * 1e7, "int32_t"),
            altitude_mm=wire_value(altitude * 1000.0, "int32_t"),
            v_ned_cm_s=(north_cm_s, east_cm_s, down_cm_s),
            ground_speed_cm_s=min(wire_value(ground_speed * 100.0, "uint16_t"), 65534),
            course_cdeg=course,
        )
