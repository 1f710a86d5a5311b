"""Flight-stack actuator outputs -> rotor speed commands [rad/s], through the channel map and the motor map.

A flight stack numbers its outputs by channel (PX4 ``HIL_ACTUATOR_CONTROLS.controls[16]``, ArduPilot's
``pwm[16]`` or ``pwm[32]``); ``rotor_channels[k-1]`` is the channel (1-based, as flight stacks number
them: PX4 MAIN1.., ArduPilot SERVO1..) that drives rotor k of the airframe. Without one, the map is
derived from the airframe's rotor geometry and the flight stack's published motor numbering, and a map
given by hand is checked against it (:mod:`.motor_order`): ``quad_x`` (1 front-right, 2 rear-right,
3 rear-left, 4 front-left) on ArduPilot's or PX4's quad X is 1,4,2,3; ``hexarotor_f550`` on HEXA X
5,1,4,6,2,3; ``x8_octorotor`` on OCTAQUAD X / PX4's coaxial octo 1,6,4,7,3,8,2,5.

Values become rotor speeds through :class:`multirotor_ros.model.airframe.MotorMap`:
- PX4 sends motors as a normalised thrust command 0..1 in a field whose range is -1..1: x = clip(c, 0, 1)
  is placed on the motor map's input range, input = input_min + x (input_max - input_min).
  Disarmed (mode bit 128 clear) means input_min.
- ArduPilot sends pulse widths [us]. A ``pwm_us`` motor map takes them as they are; a ``normalized``
  one gets x = (pwm - pwm_min_us) / (pwm_max_us - pwm_min_us), clipped to 0..1. 0 us means an
  unassigned output: input_min.

A value a flight stack cannot mean (beyond -1..1, a pulse outside 800..2200 us other than 0) is clamped
and reported; a non-finite one makes the whole message unusable (the caller holds the previous command).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.mavlink.motor_order import FlightStackName, channel_map
from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import FloatArray

PWM_VALID_US = (800, 2200)  # [us] pulses outside (except 0 = output off) are not servo pulses


@dataclass(frozen=True)
class Problem:
    """Something wrong with one actuator message: a counting reason and the specifics."""

    reason: str
    detail: str


@dataclass(frozen=True)
class RotorCommand:
    """Rotor speed commands [rad/s] in rotor order 1..N, or None when the message could not be used."""

    speeds_rad_s: FloatArray | None
    problems: tuple[Problem, ...] = ()


class RotorChannels:
    """Which output channel drives which rotor, and the conversion to rotor speeds.

    ``rotor_channels`` None: the map the flight stack's numbering gives this airframe (the default
    stack, ArduPilot, numbers the frames of config/ as PX4 does); given: checked against it. Raises
    :class:`~.motor_order.ChannelMapError` (a ValueError) with the reason when the map cannot fly.
    ``flight_stack`` None: no flight stack sends outputs (a ground station only), nothing to check.
    """

    def __init__(
        self,
        airframe: Airframe,
        rotor_channels: Sequence[int] | None = None,
        pwm_min_us: float = 1000.0,
        pwm_max_us: float = 2000.0,
        flight_stack: FlightStackName | None = "ardupilot",
    ):
        if not pwm_min_us < pwm_max_us:
            raise ValueError(f"pwm_min_us {pwm_min_us} must be below pwm_max_us {pwm_max_us}")
        self.map = channel_map(airframe, flight_stack, rotor_channels)
        self.airframe = airframe
        self.motor_map = airframe.motor_map
        self.channels = self.map.channels
        self._index = np.array(self.channels) - 1
        self._index_list = self._index.tolist()
        self._channels_needed = int(self._index.max()) + 1
        self.pwm_min_us = pwm_min_us
        self.pwm_max_us = pwm_max_us
        self.idle_speeds_rad_s: FloatArray = np.full(
            airframe.n_rotors, self.motor_map.speed_from_command(self.motor_map.input_min)
        )
        # The speed of every whole servo pulse, from the same conversion (from_servo_packet).
        self._speed_of_servo_pulse = self._speeds_from_pwm(np.arange(PWM_VALID_US[0], PWM_VALID_US[1] + 1.0))

    def describe(self) -> str:
        """Which map, and where it comes from (for the log)."""
        return self.map.describe(self.airframe)

    def _from_fraction(self, x: FloatArray) -> FloatArray:
        mm = self.motor_map
        return mm.speed_from_command(mm.input_min + np.clip(x, 0.0, 1.0) * (mm.input_max - mm.input_min))

    def _pick(self, values: ArrayLike) -> tuple[FloatArray | None, Problem | None]:
        array = np.asarray(values, dtype=float)
        if array.shape[0] < self._channels_needed:
            return None, Problem(
                "missing channel", f"{array.shape[0]} channels, rotor channels are {list(self.channels)}"
            )
        picked = array[self._index]
        if not np.all(np.isfinite(picked)):
            k = int(np.argmax(~np.isfinite(picked)))
            return None, Problem(
                "non-finite control", f"rotor_{k + 1} (channel {self.channels[k]}) = {picked[k]}"
            )
        return picked, None

    def from_px4_controls(self, controls: ArrayLike, armed: bool) -> RotorCommand:
        """Speeds for HIL_ACTUATOR_CONTROLS ``controls`` (see the module docstring)."""
        picked, problem = self._pick(controls)
        if picked is None:
            return RotorCommand(None, (problem,) if problem else ())
        problems = []
        outside = np.abs(picked) > 1.0
        if outside.any():
            k = int(np.argmax(outside))
            problems.append(
                Problem(
                    "out-of-range control",
                    f"rotor_{k + 1} (channel {self.channels[k]}) = {picked[k]:g}, not in -1..1",
                )
            )
        if not armed:
            return RotorCommand(self.idle_speeds_rad_s.copy(), tuple(problems))
        return RotorCommand(self._from_fraction(picked), tuple(problems))

    def from_servo_packet(self, pulses_us: Sequence[int]) -> RotorCommand:
        """:meth:`from_pwm` for an ArduPilot servo packet's pulses (whole microseconds).

        When every rotor's pulse is a servo pulse (the usual case, 1,200 times a second and more), its
        speed comes from a table made by the same conversion, picked with plain ints: a few numpy calls
        on 16 values cost more than the whole lookup.
        """
        if len(pulses_us) >= self._channels_needed:
            above_lowest = [pulses_us[i] - PWM_VALID_US[0] for i in self._index_list]
            if min(above_lowest) >= 0 and max(above_lowest) <= PWM_VALID_US[1] - PWM_VALID_US[0]:
                return RotorCommand(self._speed_of_servo_pulse.take(above_lowest))
        return self.from_pwm(pulses_us)

    def from_pwm(self, pwm_us: ArrayLike) -> RotorCommand:
        """Speeds for ArduPilot servo pulses [us] (see the module docstring)."""
        picked, problem = self._pick(pwm_us)
        if picked is None:
            return RotorCommand(None, (problem,) if problem else ())
        if PWM_VALID_US[0] <= picked.min() and picked.max() <= PWM_VALID_US[1]:
            return RotorCommand(self._speeds_from_pwm(picked))  # every rotor driven by a servo pulse
        off = picked == 0.0
        outside = ~off & ((picked < PWM_VALID_US[0]) | (picked > PWM_VALID_US[1]))
        problems = []
        if outside.any():
            k = int(np.argmax(outside))
            problems.append(
                Problem(
                    "out-of-range pwm",
                    f"rotor_{k + 1} (channel {self.channels[k]}) = {picked[k]:g} us, not in "
                    f"{PWM_VALID_US[0]:g}..{PWM_VALID_US[1]:g}",
                )
            )
        speeds = np.where(off, self.idle_speeds_rad_s, self._speeds_from_pwm(picked))
        return RotorCommand(speeds, tuple(problems))

    def _speeds_from_pwm(self, pwm_us: FloatArray) -> FloatArray:
        mm = self.motor_map
        if mm.input_unit == "pwm_us":
            return mm.speed_from_command(pwm_us)
        return self._from_fraction((pwm_us - self.pwm_min_us) / (self.pwm_max_us - self.pwm_min_us))

    def px4_controls_for_speeds(self, speeds_rad_s: ArrayLike, n_channels: int = 16) -> FloatArray:
        """The HIL_ACTUATOR_CONTROLS vector that commands these rotor speeds (for peers and tests)."""
        mm = self.motor_map
        command = mm.command_from_speed(speeds_rad_s)
        controls = np.zeros(n_channels)
        controls[self._index] = (command - mm.input_min) / (mm.input_max - mm.input_min)
        return controls

    def pwm_for_speeds(self, speeds_rad_s: ArrayLike, n_channels: int = 16) -> FloatArray:
        """ArduPilot pulses [us] that command these rotor speeds (for peers and tests)."""
        mm = self.motor_map
        command = mm.command_from_speed(speeds_rad_s)
        pwm = np.zeros(n_channels)
        if mm.input_unit == "pwm_us":
            pwm[self._index] = command
        else:
            fraction = (command - mm.input_min) / (mm.input_max - mm.input_min)
            pwm[self._index] = self.pwm_min_us + fraction * (self.pwm_max_us - self.pwm_min_us)
        return pwm
