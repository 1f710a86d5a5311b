"""Flight-stack actuator outputs -> rotor speed commands [rad/s], through the airframe's motor map.

A flight stack numbers its outputs by channel (PX4 ``HIL_ACTUATOR_CONTROLS.controls[16]``, ArduPilot's
``pwm[16]`` or ``pwm[32]``); ``rotor_channels[k-1]`` is the channel (1-based, as flight stacks number
them: PX4 MAIN1.., ArduPilot SERVO1..) that drives rotor k of the airframe. The default is channel k
for rotor k. A flight stack with another motor order needs its own list: PX4's and ArduPilot's quad X
order (1 front-right, 2 rear-left, 3 front-left, 4 rear-right) on ``quad_x`` (1 front-right, 2 rear-right,
3 rear-left, 4 front-left) is ``rotor_channels: [1, 4, 2, 3]``.

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

from multirotor_ros.model.airframe import Airframe
from multirotor_ros.model.rotation import FloatArray

PWM_VALID_US = (800.0, 2200.0)  # pulses outside (except 0 = output off) are not servo pulses


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
    """Which output channel drives which rotor, and the conversion to rotor speeds."""

    def __init__(
        self,
        airframe: Airframe,
        rotor_channels: Sequence[int] | None = None,
        pwm_min_us: float = 1000.0,
        pwm_max_us: float = 2000.0,
    ):
        n = airframe.n_rotors
        channels = list(range(1, n + 1)) if not rotor_channels else [int(c) for c in rotor_channels]
        if len(channels) != n:
            raise ValueError(f"rotor_channels has {len(channels)} entries, {airframe.name} has {n} rotors")
        if any(not 1 <= c <= 32 for c in channels):
            raise ValueError(f"rotor_channels {channels}: channels are numbered 1..32")
        if len(set(channels)) != n:
            raise ValueError(f"rotor_channels {channels}: a channel drives two rotors")
        if not pwm_min_us < pwm_max_us:
            raise ValueError(f"pwm_min_us {pwm_min_us} must be below pwm_max_us {pwm_max_us}")
        self.airframe = airframe
        self.motor_map = airframe.motor_map
        self.channels = tuple(channels)
        self._index = np.array(channels) - 1
        self.pwm_min_us = pwm_min_us
        self.pwm_max_us = pwm_max_us
        self.idle_speeds_rad_s: FloatArray = np.full(
            n, self.motor_map.speed_from_command(self.motor_map.input_min)
        )

    def _from_fraction(self, x: FloatArray) -> FloatArray:
        mm = self.motor_map
        return mm.speed_from_command(mm.input_min + np.clip(x, 0.0, 1.0) * (mm.input_max - mm.input_min))

    def _pick(self, values: ArrayLike) -> tuple[FloatArray | None, Problem | None]:
        array = np.asarray(values, dtype=float)
        if array.shape[0] <= int(self._index.max()):
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

    def from_pwm(self, pwm_us: ArrayLike) -> RotorCommand:
        """Speeds for ArduPilot servo pulses [us] (see the module docstring)."""
        picked, problem = self._pick(pwm_us)
        if picked is None:
            return RotorCommand(None, (problem,) if problem else ())
        problems = []
        off = picked == 0.0
        outside = ~off & ((picked < PWM_VALID_US[0]) | (picked > PWM_VALID_US[1]))
        if outside.any():
            k = int(np.argmax(outside))
            problems.append(
                Problem(
                    "out-of-range pwm",
                    f"rotor_{k + 1} (channel {self.channels[k]}) = {picked[k]:g} us, not in "
                    f"{PWM_VALID_US[0]:g}..{PWM_VALID_US[1]:g}",
                )
            )
        mm = self.motor_map
        if mm.input_unit == "pwm_us":
            speeds = mm.speed_from_command(np.where(off, mm.input_min, picked))
        else:
            speeds = self._from_fraction((picked - self.pwm_min_us) / (self.pwm_max_us - self.pwm_min_us))
            speeds = np.where(off, self.idle_speeds_rad_s, speeds)
        return RotorCommand(speeds, tuple(problems))

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
