"""Flight-stack outputs -> rotor speeds, through the channel map and the airframe's motor map."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.model.airframe import load_airframe

QUAD = load_airframe("quad_x")  # motor map: pwm_us 1000..2000 -> 0..1100 rad/s, linear
HEXA = load_airframe("hexarotor_f550")  # motor map: normalized 0..1 -> 0..746 rad/s, linear


def test_px4_controls_go_through_the_motor_map_in_channel_order():
    channels = RotorChannels(QUAD, rotor_channels=[1, 4, 2, 3], flight_stack="px4")  # PX4's quad X order
    controls = np.zeros(16)
    controls[[0, 1, 2, 3]] = [0.1, 0.2, 0.3, 0.4]  # PX4 motors 1..4
    command = channels.from_px4_controls(controls, armed=True)
    # rotor 1 <- channel 1, rotor 2 <- channel 4, rotor 3 <- channel 2, rotor 4 <- channel 3
    np.testing.assert_allclose(command.speeds_rad_s, [110.0, 440.0, 220.0, 330.0])
    assert command.problems == ()


def test_disarmed_means_idle_whatever_the_controls():
    channels = RotorChannels(QUAD)
    command = channels.from_px4_controls(np.full(16, 0.8), armed=False)
    np.testing.assert_allclose(command.speeds_rad_s, [0.0] * 4)


def test_negative_controls_stop_a_motor_and_values_beyond_one_are_clamped_and_reported():
    channels = RotorChannels(QUAD)  # derived: rotors 1..4 on channels 1, 4, 2, 3
    command = channels.from_px4_controls([-0.5, 1.3, 0.5, 1.0] + [0.0] * 12, armed=True)
    np.testing.assert_allclose(command.speeds_rad_s, [0.0, 1100.0, 1100.0, 550.0])
    assert [p.reason for p in command.problems] == ["out-of-range control"]
    assert "rotor_3 (channel 2)" in command.problems[0].detail


def test_non_finite_or_missing_rotor_channels_make_the_message_unusable():
    channels = RotorChannels(QUAD)
    nan = channels.from_px4_controls([0.5, float("nan"), 0.5, 0.5] + [0.0] * 12, armed=True)
    assert nan.speeds_rad_s is None and nan.problems[0].reason == "non-finite control"
    assert "rotor_3 (channel 2) = nan" in nan.problems[0].detail
    short = RotorChannels(HEXA).from_px4_controls([0.5] * 5, armed=True)  # HEXA X needs channels 1..6
    assert short.speeds_rad_s is None and short.problems[0].reason == "missing channel"
    # A NaN on a channel that drives no rotor does not matter.
    assert (
        channels.from_px4_controls([0.5] * 4 + [float("nan")] * 4 + [0.5] * 8, armed=True).speeds_rad_s
        is not None
    )


def test_pwm_on_a_pwm_motor_map_is_taken_in_microseconds():
    command = RotorChannels(QUAD).from_pwm([1000, 1500, 2000, 0] + [0] * 12)
    np.testing.assert_allclose(command.speeds_rad_s, [0.0, 0.0, 550.0, 1100.0])  # 0 us: output off
    assert command.problems == ()


def test_pwm_on_a_normalized_motor_map_uses_the_pwm_range():
    channels = RotorChannels(HEXA, pwm_min_us=1100.0, pwm_max_us=1900.0)  # rotors on 5, 1, 4, 6, 2, 3
    command = channels.from_pwm([1100, 1500, 1900, 2100, 1000, 0] + [0] * 10)
    np.testing.assert_allclose(command.speeds_rad_s, [0.0, 0.0, 746.0, 0.0, 373.0, 746.0])
    assert command.problems == ()


def test_pulses_no_servo_makes_are_reported():
    command = RotorChannels(QUAD).from_pwm([1500, 65535, 1500, 300] + [0] * 12)
    assert [p.reason for p in command.problems] == ["out-of-range pwm"]
    assert "rotor_2 (channel 4) = 300 us" in command.problems[0].detail  # the first one named
    np.testing.assert_allclose(command.speeds_rad_s[2], 1100.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"rotor_channels": [1, 2, 3]}, "3 entries"),
        ({"rotor_channels": [1, 2, 3, 3]}, "two rotors"),
        ({"rotor_channels": [0, 1, 2, 3]}, "1..32"),
        ({"rotor_channels": [1, 2, 3, 4]}, "would flip quad_x"),
        ({"pwm_min_us": 2000.0, "pwm_max_us": 1000.0}, "below"),
    ],
)
def test_channel_maps_that_cannot_work_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        RotorChannels(QUAD, **kwargs)


@pytest.mark.parametrize("airframe", [QUAD, HEXA], ids=lambda a: a.name)
@given(data=st.data())
def test_px4_and_pwm_inverses_give_back_the_speeds(airframe, data):
    n = airframe.n_rotors
    top = airframe.motor_map.speed_max_rad_s
    speeds = data.draw(st.lists(st.floats(0.0, top), min_size=n, max_size=n))
    channels = RotorChannels(airframe)
    back = channels.from_px4_controls(channels.px4_controls_for_speeds(speeds), armed=True).speeds_rad_s
    np.testing.assert_allclose(back, speeds, atol=1e-9)
    np.testing.assert_allclose(
        channels.from_pwm(channels.pwm_for_speeds(speeds)).speeds_rad_s, speeds, atol=1e-9
    )
