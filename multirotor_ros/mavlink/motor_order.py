"""Which flight-stack output drives which rotor, derived from the airframe's geometry.

A flight stack's mixer numbers the motors of each frame it knows, and output k (ArduPilot SERVOk, PX4
MAINk: the stacks' default output functions) drives its motor k. The published numbering, transcribed
below from the stacks' sources:

- ArduPilot: ``AP_MotorsMatrix::setup_motors`` (libraries/AP_Motors/AP_MotorsMatrix.cpp), one
  ``add_motor(AP_MOTORS_MOT_k, angle, yaw_factor, testing_order)`` per motor for each FRAME_CLASS and
  FRAME_TYPE: the arm's angle in degrees clockwise from the nose, the yaw factor +1 for a propeller that
  turns counter-clockwise seen from above (AP_MOTORS_MATRIX_YAW_FACTOR_CCW = 1, _CW = -1). The mixer's
  roll and pitch factors of motor k are cos(angle + 90°) and cos(angle).
- PX4: the airframe files' control-allocation geometry (ROMFS/px4fmu_common/init.d/airframes/4001_quad_x,
  6001_hexa_x: CA_ROTORn_PX forward, CA_ROTORn_PY right, CA_ROTORn_KM > 0 counter-clockwise) and, for
  the coaxial octorotor 12001_octo_cox, its mixer geometry (src/lib/mixer/MultirotorMixer/geometries/
  octa_cox.toml: positions and directions in the same order).

Deriving a map: each rotor of the airframe goes to the frame's motor that spins the same way and whose
arm is nearest its own (at most :data:`ARM_TOLERANCE_DEG` away); a frame fits when that pairs every
rotor with its own motor. Of the fitting frames the one whose worst arm is nearest is the flight
stack's frame for the airframe (an X8's pairs are 22.5° from an octa X's arms and on an octaquad X's).

Checking a map given by hand (:func:`torque_mismatches`): each output alone must turn the body the way
the flight stack's mixer expects of that motor: roll, pitch and yaw torques of the rotor it drives with
the signs of the motor's roll, pitch and yaw factors (factors below :data:`FACTOR_NEGLIGIBLE` in size,
a PLUS frame's front motor's roll, are not held to a sign). A map that fails is refused with each
mismatch named: such a map flips the vehicle at lift-off.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from multirotor_ros.frames import flu_to_frd
from multirotor_ros.model.airframe import Airframe, Spin

FlightStackName = Literal["ardupilot", "px4"]
ARM_TOLERANCE_DEG = 30.0  # [deg] farther from every arm of its spin, a rotor is not on that frame
FACTOR_NEGLIGIBLE = 0.1  # a mixer factor this small (of 1) says nothing about the torque's sign
MAX_CHANNEL = 32  # ArduPilot's 32-channel servo packet; PX4 sends 16


@dataclass(frozen=True)
class Motor:
    """One motor of a flight stack's frame: its number (= output channel), arm and spin."""

    number: int
    angle_deg: float  # [deg] arm direction, clockwise from the nose (body FRD, seen from above)
    spin: Spin  # seen from above

    @property
    def mixer_factors_FRD(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) factors: the signs of the body FRD torques this motor alone makes."""
        angle = math.radians(self.angle_deg)
        return math.cos(angle + math.pi / 2), math.cos(angle), 1.0 if self.spin == "ccw" else -1.0

    @property
    def where(self) -> str:
        """The arm in words, e.g. 'front-right' (for messages)."""
        return _direction_words(self.angle_deg)


@dataclass(frozen=True)
class Frame:
    """A frame as a flight stack numbers it."""

    flight_stack: FlightStackName
    name: str  # e.g. "QUAD X"
    parameters: tuple[tuple[str, int], ...]  # what tells the flight stack to fly it, e.g. FRAME_CLASS 1
    source: str  # where the numbering is published
    motors: tuple[Motor, ...]

    @property
    def setting(self) -> str:
        """e.g. 'FRAME_CLASS 1, FRAME_TYPE 1'."""
        return ", ".join(f"{name} {value}" for name, value in self.parameters)

    @property
    def title(self) -> str:
        """e.g. 'ArduPilot QUAD X (FRAME_CLASS 1, FRAME_TYPE 1)'."""
        stack = {"ardupilot": "ArduPilot", "px4": "PX4"}[self.flight_stack]
        return f"{stack} {self.name} ({self.setting})"

    def motor(self, number: int) -> Motor | None:
        """Motor ``number`` of this frame, None if it has none."""
        return next((m for m in self.motors if m.number == number), None)


def _motors(*arms: tuple[float, Spin]) -> tuple[Motor, ...]:
    return tuple(Motor(k, angle, spin) for k, (angle, spin) in enumerate(arms, start=1))


def _px4_motors(*rotors: tuple[float, float, float]) -> tuple[Motor, ...]:
    """PX4 geometry as its sources give it: (forward, right, moment coefficient KM) per rotor, in order."""
    return _motors(*((math.degrees(math.atan2(py, px)), "ccw" if km > 0 else "cw") for px, py, km in rotors))


_AP_SOURCE = "ArduPilot libraries/AP_Motors/AP_MotorsMatrix.cpp, setup_motors"
_PX4_AIRFRAMES = "PX4 ROMFS/px4fmu_common/init.d/airframes/"

FRAMES: tuple[Frame, ...] = (
    Frame("ardupilot", "QUAD X", (("FRAME_CLASS", 1), ("FRAME_TYPE", 1)), _AP_SOURCE,
          _motors((45, "ccw"), (-135, "ccw"), (-45, "cw"), (135, "cw"))),
    Frame("ardupilot", "QUAD PLUS", (("FRAME_CLASS", 1), ("FRAME_TYPE", 0)), _AP_SOURCE,
          _motors((90, "ccw"), (-90, "ccw"), (0, "cw"), (180, "cw"))),
    Frame("ardupilot", "HEXA X", (("FRAME_CLASS", 2), ("FRAME_TYPE", 1)), _AP_SOURCE,
          _motors((90, "cw"), (-90, "ccw"), (-30, "cw"), (150, "ccw"), (30, "ccw"), (-150, "cw"))),
    Frame("ardupilot", "HEXA PLUS", (("FRAME_CLASS", 2), ("FRAME_TYPE", 0)), _AP_SOURCE,
          _motors((0, "cw"), (180, "ccw"), (-120, "cw"), (60, "ccw"), (-60, "ccw"), (120, "cw"))),
    Frame("ardupilot", "OCTA X", (("FRAME_CLASS", 3), ("FRAME_TYPE", 1)), _AP_SOURCE,
          _motors((22.5, "cw"), (-157.5, "cw"), (67.5, "ccw"), (157.5, "ccw"), (-22.5, "ccw"),
                  (-112.5, "ccw"), (-67.5, "cw"), (112.5, "cw"))),
    Frame("ardupilot", "OCTA PLUS", (("FRAME_CLASS", 3), ("FRAME_TYPE", 0)), _AP_SOURCE,
          _motors((0, "cw"), (180, "cw"), (45, "ccw"), (135, "ccw"), (-45, "ccw"), (-135, "ccw"),
                  (-90, "cw"), (90, "cw"))),
    Frame("ardupilot", "OCTAQUAD X", (("FRAME_CLASS", 4), ("FRAME_TYPE", 1)), _AP_SOURCE,
          _motors((45, "ccw"), (-45, "cw"), (-135, "ccw"), (135, "cw"), (-45, "ccw"), (45, "cw"),
                  (135, "ccw"), (-135, "cw"))),
    Frame("ardupilot", "OCTAQUAD PLUS", (("FRAME_CLASS", 4), ("FRAME_TYPE", 0)), _AP_SOURCE,
          _motors((0, "ccw"), (-90, "cw"), (180, "ccw"), (90, "cw"), (-90, "ccw"), (0, "cw"),
                  (90, "ccw"), (180, "cw"))),
    Frame("px4", "Generic Quadcopter (quad x)", (("SYS_AUTOSTART", 4001),), _PX4_AIRFRAMES + "4001_quad_x",
          _px4_motors((0.15, 0.15, 0.05), (-0.15, -0.15, 0.05), (0.15, -0.15, -0.05), (-0.15, 0.15, -0.05))),
    Frame("px4", "Generic Hexarotor x geometry", (("SYS_AUTOSTART", 6001),), _PX4_AIRFRAMES + "6001_hexa_x",
          _px4_motors((0.0, 0.5, -0.05), (0.0, -0.5, 0.05), (0.43, -0.25, -0.05), (-0.43, 0.25, 0.05),
                      (0.43, 0.25, 0.05), (-0.43, -0.25, -0.05))),
    Frame("px4", "Generic 10\" Octo coaxial geometry", (("SYS_AUTOSTART", 12001),),
          "PX4 src/lib/mixer/MultirotorMixer/geometries/octa_cox.toml (12001_octo_cox)",
          _px4_motors((0.707107, 0.707107, 0.05), (0.707107, -0.707107, -0.05), (-0.707107, -0.707107, 0.05),
                      (-0.707107, 0.707107, -0.05), (0.707107, -0.707107, 0.05), (0.707107, 0.707107, -0.05),
                      (-0.707107, 0.707107, 0.05), (-0.707107, -0.707107, -0.05))),
)  # fmt: skip


def _direction_words(angle_deg: float) -> str:
    """'front', 'front-right', 'right', ... for an arm angle clockwise from the nose."""
    names = ("front", "front-right", "right", "rear-right", "rear", "rear-left", "left", "front-left")
    return names[round((angle_deg % 360.0) / 45.0) % 8]


def _angle_between_deg(a_deg: float, b_deg: float) -> float:
    return abs((a_deg - b_deg + 180.0) % 360.0 - 180.0)


def rotor_arms_deg(airframe: Airframe) -> list[float]:
    """Each rotor's arm direction, degrees clockwise from the nose (as the flight stacks give theirs)."""
    positions_FRD = flu_to_frd(airframe.rotor_positions_m)
    return [math.degrees(math.atan2(y, x)) for x, y, _ in positions_FRD]


@dataclass(frozen=True)
class FrameFit:
    """A frame whose motors the airframe's rotors fit: rotor k+1 is driven by ``channels[k]``."""

    frame: Frame
    channels: tuple[int, ...]
    worst_arm_deg: float  # [deg] the largest angle between a rotor's arm and its motor's


def fit(airframe: Airframe, frame: Frame) -> FrameFit | None:
    """How the airframe's rotors sit on the frame's motors, or None if they do not (see the docstring)."""
    if len(frame.motors) != airframe.n_rotors:
        return None
    channels = []
    worst = 0.0
    for arm, rotor in zip(rotor_arms_deg(airframe), airframe.rotors, strict=True):
        same_spin = [m for m in frame.motors if m.spin == rotor.spin]
        nearest = min(same_spin, key=lambda m: _angle_between_deg(arm, m.angle_deg))
        off = _angle_between_deg(arm, nearest.angle_deg)
        if off > ARM_TOLERANCE_DEG:
            return None
        channels.append(nearest.number)
        worst = max(worst, off)
    if len(set(channels)) != len(channels):
        return None  # two rotors on one motor: the layouts differ
    return FrameFit(frame, tuple(channels), worst)


def frame_for(airframe: Airframe, flight_stack: FlightStackName) -> FrameFit | None:
    """The flight stack's frame that the airframe's rotors fit best, None if none fits."""
    fits = [f for frame in FRAMES if frame.flight_stack == flight_stack if (f := fit(airframe, frame))]
    return min(fits, key=lambda f: f.worst_arm_deg, default=None)


def torque_mismatches(airframe: Airframe, frame: Frame, channels: Sequence[int]) -> list[str]:
    """Why ``channels`` (rotor k+1 on channels[k]) cannot drive this airframe as ``frame``; [] if it can.

    Each channel alone: the body FRD torques of the rotor it drives (the allocation's column) must
    have the signs of the motor's mixer factors.
    """
    torques_FRD = flu_to_frd(airframe.allocation[1:].T)  # (N, 3): each rotor's torque per unit omega^2
    arms = rotor_arms_deg(airframe)
    problems = []
    for k, channel in enumerate(channels):
        motor = frame.motor(channel)
        rotor = f"rotor_{k + 1} ({_direction_words(arms[k])}, {airframe.rotors[k].spin})"
        if motor is None:
            problems.append(f"channel {channel} drives {rotor} but is no motor of {frame.title}")
            continue
        wrong = [
            axis
            for axis, factor, torque in zip(
                ("roll", "pitch", "yaw"), motor.mixer_factors_FRD, torques_FRD[k], strict=True
            )
            if abs(factor) >= FACTOR_NEGLIGIBLE and np.sign(factor) != np.sign(torque)
        ]
        if wrong:
            axes = ", ".join(wrong[:-1]) + (" and " if len(wrong) > 1 else "") + wrong[-1]
            problems.append(
                f"channel {channel} is motor {channel} ({motor.where}, {motor.spin}) but drives {rotor}: "
                f"its {axes} torque{'s have' if len(wrong) > 1 else ' has'} the wrong sign"
            )
    return problems


class ChannelMapError(ValueError):
    """A channel map that cannot fly the airframe, with the reason."""


@dataclass(frozen=True)
class ChannelMap:
    """The output channel of each rotor and how it was arrived at."""

    flight_stack: FlightStackName | None  # None: no flight stack, no outputs read
    channels: tuple[int, ...]  # rotor k+1 is driven by output channels[k] (1-based)
    frame: Frame | None  # the flight stack's frame it was derived from or checked against
    derived: bool  # True: derived from the geometry; False: given by hand

    def describe(self, airframe: Airframe) -> str:
        """One line for the log: which frame, which map, derived or given."""
        text = ",".join(map(str, self.channels))
        if self.flight_stack is None:
            return f"rotor_channels {text} (no flight stack: no outputs are read)"
        if self.frame is None:
            return f"rotor_channels {text}, not checked (no {self.flight_stack} frame fits {airframe.name})"
        how = "derived from" if self.derived else "given, torques checked against"
        return f"rotor_channels {text}, {how} {self.frame.title} ({self.frame.source})"


def channel_map(
    airframe: Airframe, flight_stack: FlightStackName | None, rotor_channels: Sequence[int] | None = None
) -> ChannelMap:
    """The channel map for a flight stack: derived when ``rotor_channels`` is None, else checked.

    Raises :class:`ChannelMapError` naming what is wrong: no frame of the flight stack fits and no map
    is given, or a given map has the wrong length, a channel twice or out of range, or torques of the
    wrong sign on the frame the airframe fits. Without a flight stack (``None``: no outputs are read)
    the map is only checked for shape, and is channel k for rotor k unless given.
    """
    n = airframe.n_rotors
    if rotor_channels is not None:
        channels = tuple(int(c) for c in rotor_channels)
        if len(channels) != n:
            raise ChannelMapError(
                f"rotor_channels has {len(channels)} entries, {airframe.name} has {n} rotors"
            )
        if any(not 1 <= c <= MAX_CHANNEL for c in channels):
            raise ChannelMapError(f"rotor_channels {list(channels)}: channels are numbered 1..{MAX_CHANNEL}")
        if len(set(channels)) != n:
            raise ChannelMapError(f"rotor_channels {list(channels)}: a channel drives two rotors")
    if flight_stack is None:
        return ChannelMap(
            None, channels if rotor_channels is not None else tuple(range(1, n + 1)), None, False
        )
    fitted = frame_for(airframe, flight_stack)
    if rotor_channels is None:
        if fitted is None:
            raise ChannelMapError(
                f"no {flight_stack} frame of the published motor tables fits {airframe.name}'s rotors "
                f"(arms {', '.join(f'{a:.0f}°' for a in rotor_arms_deg(airframe))} clockwise from the "
                "nose): set rotor_channels"
            )
        return ChannelMap(flight_stack, fitted.channels, fitted.frame, derived=True)
    if fitted is None:
        return ChannelMap(flight_stack, channels, None, derived=False)
    problems = torque_mismatches(airframe, fitted.frame, channels)
    if problems:
        raise ChannelMapError(
            f"rotor_channels {','.join(map(str, channels))} would flip {airframe.name} on "
            f"{fitted.frame.title}: "
            + "; ".join(problems)
            + f". The map that fits is {','.join(map(str, fitted.channels))} (leave rotor_channels empty)"
        )
    return ChannelMap(flight_stack, channels, fitted.frame, derived=False)
