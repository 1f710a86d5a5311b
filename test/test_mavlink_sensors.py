"""Sensor synthesis for flight stacks: ISA barometer, magnetometer, GPS on a local tangent plane."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from multirotor_ros.mavlink import sensors
from multirotor_ros.mavlink.sensors import Home, LocalTangentPlane, SensorConfigError, SensorModel
from multirotor_ros.model.rotation import euler_to_quat


def test_isa_table_values():
    # ISO 2533 / ICAO standard atmosphere tables.
    assert sensors.isa_pressure_pa(0.0) == pytest.approx(101325.0)
    assert sensors.isa_pressure_pa(1000.0) == pytest.approx(89874.6, abs=1.0)
    assert sensors.isa_pressure_pa(11000.0) == pytest.approx(22632.1, abs=2.0)
    assert sensors.isa_temperature_k(1000.0) == pytest.approx(281.65)


@given(st.floats(-400.0, 10999.0))
def test_pressure_altitude_inverts_the_isa(altitude):
    assert sensors.pressure_altitude_m(sensors.isa_pressure_pa(altitude)) == pytest.approx(altitude, abs=1e-6)


def test_barometer_reads_hpa_and_pressure_altitude_of_home_plus_height():
    model = SensorModel(Home(altitude_m=488.0))
    ground = model.barometer([0.0, 0.0, 0.0])
    assert ground.pressure_hpa == pytest.approx(955.98, abs=0.01)
    assert ground.pressure_altitude_m == pytest.approx(488.0)
    assert ground.temperature_degc == pytest.approx(15.0 - 0.0065 * 488.0)
    ten_up = model.barometer([5.0, -3.0, 10.0])
    assert ten_up.pressure_altitude_m == pytest.approx(498.0)
    # About 12 Pa per metre near sea level: 10 m up is roughly 1.15 hPa less.
    assert ground.pressure_hpa - ten_up.pressure_hpa == pytest.approx(1.15, abs=0.05)


def test_ecef_known_points():
    np.testing.assert_allclose(sensors.geodetic_to_ecef(0.0, 0.0, 0.0), [sensors.WGS84_A_M, 0.0, 0.0])
    np.testing.assert_allclose(
        sensors.geodetic_to_ecef(90.0, 0.0, 0.0), [0.0, 0.0, sensors.WGS84_B_M], atol=1e-6
    )
    np.testing.assert_allclose(
        sensors.ecef_to_geodetic(0.0, sensors.WGS84_A_M + 100.0, 0.0), [0.0, 90.0, 100.0], atol=1e-9
    )


@given(st.floats(-89.0, 89.0), st.floats(-180.0, 180.0), st.floats(-400.0, 10000.0))
def test_geodetic_round_trip(latitude, longitude, altitude):
    back = sensors.ecef_to_geodetic(*sensors.geodetic_to_ecef(latitude, longitude, altitude))
    assert back[0] == pytest.approx(latitude, abs=1e-9)
    assert math.cos(math.radians(back[1] - longitude)) == pytest.approx(1.0, abs=1e-15)
    assert back[2] == pytest.approx(altitude, abs=1e-4)


@given(
    st.floats(-80.0, 80.0),
    st.floats(-179.0, 179.0),
    st.lists(st.floats(-5000.0, 5000.0), min_size=3, max_size=3),
)
def test_local_tangent_plane_round_trip(latitude, longitude, p_enu):
    plane = LocalTangentPlane(Home(latitude_deg=latitude, longitude_deg=longitude, altitude_m=100.0))
    np.testing.assert_allclose(plane.enu(*plane.geodetic(p_enu)), p_enu, atol=1e-4)


def test_one_kilometre_north_and_east_match_the_radii_of_curvature():
    home = Home()
    plane = LocalTangentPlane(home)
    lat = math.radians(home.latitude_deg)
    e2 = sensors.WGS84_E2
    # Radii of curvature of the ellipsoid, plus home's own height above it (the radius changes by about
    # 1e-6 over 1 km of latitude, hence the tolerance).
    meridian_radius = sensors.WGS84_A_M * (1 - e2) / (1 - e2 * math.sin(lat) ** 2) ** 1.5 + home.altitude_m
    normal_radius = sensors.WGS84_A_M / math.sqrt(1 - e2 * math.sin(lat) ** 2) + home.altitude_m
    north = plane.geodetic([0.0, 1000.0, 0.0])
    east = plane.geodetic([1000.0, 0.0, 0.0])
    assert north[0] - home.latitude_deg == pytest.approx(math.degrees(1000.0 / meridian_radius), rel=2e-6)
    assert east[1] - home.longitude_deg == pytest.approx(
        math.degrees(1000.0 / (normal_radius * math.cos(lat))), rel=1e-7
    )
    # A straight tangent line leaves the curved surface: d^2 / (2 R) = 7.8 cm after 1 km.
    assert north[2] - home.altitude_m == pytest.approx(1000.0**2 / (2 * meridian_radius), rel=0.01)


def test_magnetometer_facing_north_reads_the_ned_field_and_facing_east_rotates_it():
    model = SensorModel(Home(mag_declination_deg=0.0, mag_inclination_deg=60.0, mag_strength_gauss=0.5))
    field_ned = [0.25, 0.0, 0.5 * math.sin(math.radians(60.0))]
    np.testing.assert_allclose(model.B_NED_gauss, field_ned, atol=1e-12)
    north = euler_to_quat([0.0, 0.0, math.pi / 2])  # ENU yaw 90 deg: nose north
    np.testing.assert_allclose(model.magnetometer_frd_gauss(north), field_ned, atol=1e-12)
    east = euler_to_quat([0.0, 0.0, 0.0])  # nose east: north is on the left, i.e. -y in FRD
    np.testing.assert_allclose(model.magnetometer_frd_gauss(east), [0.0, -0.25, field_ned[2]], atol=1e-12)


def test_gps_fix_units():
    model = SensorModel(Home())
    fix = model.gps([0.0, 0.0, 2.5], [1.0, 0.0, -0.5])  # flying east, sinking
    assert fix.v_ned_cm_s == (0, 100, 50)
    assert fix.ground_speed_cm_s == 100
    assert fix.course_cdeg == 9000
    assert fix.altitude_mm == round((Home().altitude_m + 2.5) * 1000)
    assert fix.latitude_e7 == round(Home().latitude_deg * 1e7)
    assert model.gps([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]).course_cdeg == 65535  # no course when not moving


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("latitude_deg", 91.0),
        ("latitude_deg", 89.95),
        ("longitude_deg", -200.0),
        ("altitude_m", 20000.0),
        ("mag_strength_gauss", -0.1),
        ("mag_inclination_deg", float("nan")),
    ],
)
def test_home_refuses_values_the_models_cannot_use(field, value):
    with pytest.raises(SensorConfigError, match=field.split("_")[0]):
        Home(**{field: value})
