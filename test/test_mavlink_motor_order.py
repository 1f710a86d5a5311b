"""Channel maps from the rotor geometry and the flight stacks' motor numbering, and the torque check."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from multirotor_ros.frames import flu_to_frd
from multirotor_ros.mavlink.actuators import RotorChannels
from multirotor_ros.mavlink.motor_order import FACTOR_NEGLIGIBLE, FRAMES, ChannelMapError, fit, frame_for
from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.model import Model

# The maps the issue flew ArduCopter with (worked out by hand from ArduPilot's motor tables).
FLOWN = {
    "quad_x": ((1, 4, 2, 3), "QUAD X", "FRAME_CLASS 1, FRAME_TYPE 1"),
    "hexarotor_f550": ((5, 1, 4, 6, 2, 3), "HEXA X", "FRAME_CLASS 2, FRAME_TYPE 1"),
    "x8_octorotor": ((1, 6, 4, 7, 3, 8, 2, 5), "OCTAQUAD X", "FRAME_CLASS 4, FRAME_TYPE 1"),
}
PX4_AIRFRAMES = {"quad_x": "SYS_AUTOSTART 4001", "hexarotor_f550": "SYS_AUTOSTART 6001",
                 "x8_octorotor": "SYS_AUTOSTART 12001"}  # fmt: skip


@pytest.mark.parametrize("name", FLOWN)
def test_the_derived_maps_are_the_ones_arducopter_flew_and_px4_numbers_alike(name):
    airframe = load_airframe(name)
    channels, frame_name, setting = FLOWN[name]
    ardupilot = RotorChannels(airframe, flight_stack="ardupilot")
    assert ardupilot.channels == channels
    assert (ardupilot.map.frame.name, ardupilot.map.frame.setting) == (frame_name, setting)
    assert ardupilot.describe().startswith(f"rotor_channels {','.join(map(str, channels))}, derived from")
    px4 = RotorChannels(airframe, flight_stack="px4")
    assert px4.channels == channels and px4.map.frame.setting == PX4_AIRFRAMES[name]


@pytest.mark.parametrize("frame", FRAMES, ids=lambda f: f"{f.flight_stack} {f.name}")
def test_every_transcribed_frame_is_balanced_and_numbered_one_to_n(frame):
    # A spin or an angle copied wrong from the sources would leave a torque the hover cannot trim.
    assert [m.number for m in frame.motors] == list(range(1, len(frame.motors) + 1))
    np.testing.assert_allclose(np.sum([m.mixer_factors_FRD for m in frame.motors], axis=0), 0.0, atol=1e-5)


@pytest.mark.parametrize("stack", ["ardupilot", "px4"])
@pytest.mark.parametrize("name", FLOWN)
def test_each_output_alone_turns_the_simulated_body_the_way_the_flight_stacks_mixer_expects(name, stack):
    airframe = load_airframe(name)
    channels = RotorChannels(airframe, flight_stack=stack)
    model = Model(airframe)
    for motor in channels.map.frame.motors:
        if stack == "ardupilot":
            pwm = [1000] * 16
            pwm[motor.number - 1] = 1600
            speeds = channels.from_pwm(pwm).speeds_rad_s
        else:
            controls = np.zeros(16)
            controls[motor.number - 1] = 0.6
            speeds = channels.from_px4_controls(controls, armed=True).speeds_rad_s
        assert np.count_nonzero(speeds) == 1  # one rotor spins
        x = S.make_state(airframe.n_rotors, position_m=(0.0, 0.0, 10.0))
        x[:, S.ROTORS_START :] = speeds
        w_dot_FRD = flu_to_frd(model.derivative(0.0, x, speeds)[0, S.BODY_RATE])
        for axis, factor, turn in zip("rpy", motor.mixer_factors_FRD, w_dot_FRD, strict=True):
            if abs(factor) >= FACTOR_NEGLIGIBLE:
                assert np.sign(turn) == np.sign(factor), f"motor {motor.number} ({motor.where}): {axis}"


def test_the_x8_is_an_octaquad_x_not_an_octa_x_whose_arms_are_22_5_degrees_off():
    x8 = load_airframe("x8_octorotor")
    octa_x = next(f for f in FRAMES if f.name == "OCTA X")
    assert fit(x8, octa_x).worst_arm_deg == pytest.approx(22.5)  # it fits, worse
    best = frame_for(x8, "ardupilot")
    assert best.frame.name == "OCTAQUAD X" and best.worst_arm_deg == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(
    ("name", "given", "reasons"),
    [
        ("quad_x", [1, 2, 3, 4], ["channel 2 is motor 2 (rear-left, ccw) but drives rotor_2 (rear-right, "
                                  "cw): its roll and yaw torques have the wrong sign",
                                  "The map that fits is 1,4,2,3"]),
        ("hexarotor_f550", [1, 2, 3, 4, 5, 6], ["would flip hexarotor_f550 on ArduPilot HEXA X",
                                                "The map that fits is 5,1,4,6,2,3"]),
        # The upper and lower rotors of the front-right pair swapped: right place, wrong spins.
        ("x8_octorotor", [6, 1, 4, 7, 3, 8, 2, 5], ["channel 6 is motor 6 (front-right, cw) but "
                                                    "drives rotor_1 (front-right, ccw): its yaw torque "
                                                    "has the wrong sign"]),
    ],
)  # fmt: skip
def test_a_map_that_does_not_fit_the_geometry_is_refused_with_the_reason(name, given, reasons):
    with pytest.raises(ChannelMapError) as refused:
        RotorChannels(load_airframe(name), rotor_channels=given)
    for reason in reasons:
        assert reason in str(refused.value)


def test_an_airframe_no_published_frame_fits_needs_its_map_and_gets_it_unchecked():
    quad = load_airframe("quad_x")
    tricopter = dataclasses.replace(quad, name="tricopter", rotors=quad.rotors[:3])
    with pytest.raises(
        ChannelMapError, match="no ardupilot frame .* fits tricopter's rotors .*set rotor_channels"
    ):
        RotorChannels(tricopter)
    given = RotorChannels(tricopter, rotor_channels=[3, 1, 2])
    assert given.channels == (3, 1, 2) and "not checked" in given.describe()


def test_without_a_flight_stack_nothing_is_derived_or_checked():
    channels = RotorChannels(load_airframe("quad_x"), flight_stack=None)
    assert channels.channels == (1, 2, 3, 4) and "no flight stack" in channels.describe()
