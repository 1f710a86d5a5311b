"""Which logged actuator channel drives which of our rotors.

Our rotors are numbered as in conventions.md and the airframe YAML (quad_x: 1 front-right,
2 rear-right, 3 rear-left, 4 front-left). Flight stacks number their motors differently and put
motor m on some output channel. Three steps give, for each of our rotors k, a 1-based channel:

1. ``--rotor-channels 1,4,2,3`` (channel of rotor 1, of rotor 2, ...) wins when given.
2. Otherwise our rotors are matched to a flight-stack motor order by geometry: each rotor's
   azimuth and spin direction must match one motor of a known layout (:data:`LAYOUTS`). PX4
   (``quad_x.toml``: front_right, rear_left, front_left, rear_right; ``hex_x.toml``) and ArduPilot
   (``AP_MotorsMatrix`` quad X: 45°, -135°, -45°, 135°; hexa X) share these orders. For PX4 quad X
   and our quad_x this gives motors 1, 4, 2, 3, i.e. channels "1,4,2,3".
3. The flight stack's motor-to-channel assignment comes from the log's parameters when present
   (PX4 ``VT_MOT_ID`` such as 5678 or ``PWM_MAIN_FUNCn`` = 100 + m; ArduPilot ``SERVOn_FUNCTION`` =
   32 + m); otherwise motor m is on channel m.

Coaxial airframes (two rotors per arm) match no layout here: give ``--rotor-channels``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from multirotor_ros.model.airframe import Airframe


class RotorChannelError(ValueError):
    """Rotor channels that cannot be used or found; the message says what to give instead."""


@dataclass(frozen=True)
class MotorLayout:
    """A flight stack's motor order: azimuth (degrees clockwise from the nose) and spin of motor 1..N."""

    name: str
    azimuth_deg: tuple[float, ...]
    spin: tuple[str, ...]


LAYOUTS = (
    MotorLayout(
        "quad X (PX4 and ArduPilot motor order)", (45.0, -135.0, -45.0, 135.0), ("ccw", "ccw", "cw", "cw")
    ),
    MotorLayout(
        "hexa X (PX4 and ArduPilot motor order)",
        (90.0, -90.0, -30.0, 150.0, 30.0, -150.0),
        ("cw", "ccw", "cw", "ccw", "ccw", "cw"),
    ),
)


# Bitcraze's numbering (power_distribution_quadrotor.c mixes motor 1 front-right, 2 rear-right,
# 3 rear-left, 4 front-left; 1 and 3 turn ccw): the same places as PX4's quad X, other numbers.
CRAZYFLIE_LAYOUT = MotorLayout(
    "Crazyflie (Bitcraze motor order M1..M4)", (45.0, 135.0, -135.0, -45.0), ("ccw", "cw", "ccw", "cw")
)


def parse_rotor_channels(text: str, n_rotors: int) -> list[int]:
    """``"1,4,2,3"`` -> [1, 4, 2, 3], checked: N distinct channels >= 1."""
    try:
        channels = [int(part) for part in text.split(",")]
    except ValueError:
        raise RotorChannelError(
            f"--rotor-channels {text!r}: expected comma-separated channel numbers"
        ) from None
    if len(channels) != n_rotors:
        raise RotorChannelError(f"--rotor-channels {text!r}: {len(channels)} channels for {n_rotors} rotors")
    if min(channels) < 1:
        raise RotorChannelError(f"--rotor-channels {text!r}: channels are numbered from 1")
    if len(set(channels)) != len(channels):
        raise RotorChannelError(f"--rotor-channels {text!r}: a channel is used twice")
    return channels


def _angle_difference(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def match_layout(
    airframe: Airframe, layouts: Sequence[MotorLayout] = LAYOUTS
) -> tuple[MotorLayout, list[int]] | None:
    """The first of ``layouts`` whose motors sit where our rotors are (same spin), and rotor k's motor."""
    azimuths = [math.degrees(math.atan2(-r.position_m[1], r.position_m[0])) for r in airframe.rotors]
    for layout in layouts:
        if len(layout.azimuth_deg) != airframe.n_rotors:
            continue
        spacing = min(
            _angle_difference(a, b)
            for i, a in enumerate(layout.azimuth_deg)
            for b in layout.azimuth_deg[i + 1 :]
        )
        motors = []
        for azimuth, rotor in zip(azimuths, airframe.rotors, strict=True):
            errors = [_angle_difference(azimuth, a) for a in layout.azimuth_deg]
            motor = min(range(len(errors)), key=errors.__getitem__)
            if errors[motor] >= spacing / 2 or layout.spin[motor] != rotor.spin:
                break
            motors.append(motor + 1)
        else:
            if len(set(motors)) == len(motors):
                return layout, motors
    return None


def motor_channels_from_parameters(
    parameters: Mapping[str, float], n_motors: int
) -> tuple[dict[int, int], str]:
    """Flight-stack motor m -> 1-based output channel, from PX4 or ArduPilot parameters if they say."""
    vt_mot_id = int(parameters.get("VT_MOT_ID", 0) or 0)
    if vt_mot_id > 0 and len(str(vt_mot_id)) >= n_motors:
        digits = [int(d) for d in str(vt_mot_id)]
        return {m + 1: digits[m] for m in range(n_motors)}, f"PX4 VT_MOT_ID={vt_mot_id}"
    for prefix, offset, label in (
        ("PWM_MAIN_FUNC", 100, "PX4 PWM_MAIN_FUNCn"),
        ("SERVO", 32, "ArduPilot SERVOn_FUNCTION"),
    ):
        suffix = "_FUNCTION" if prefix == "SERVO" else ""
        found: dict[int, int] = {}
        for channel in range(1, 33):
            function = int(parameters.get(f"{prefix}{channel}{suffix}", 0) or 0)
            if offset < function <= offset + n_motors:
                found.setdefault(function - offset, channel)
        if len(found) == n_motors:
            return found, label
    return {
        m: m for m in range(1, n_motors + 1)
    }, "motor m on channel m (no motor assignment in the log's parameters)"


def resolve_rotor_channels(
    airframe: Airframe,
    explicit: str | None,
    parameters: Mapping[str, float] | None = None,
    n_channels: int | None = None,
    channel_names: Sequence[str] | None = None,
    layouts: Sequence[MotorLayout] = LAYOUTS,
) -> tuple[list[int], str]:
    """1-based channel of each of our rotors, and a line for ``# rotor_channels:`` saying why.

    ``n_channels`` is how many channels the log has (checked); ``channel_names`` names them in the
    note (``u0``..``u3`` for a CSV whose first column is channel 1); ``layouts`` are the motor orders
    the log's flight stack may use.
    """
    if explicit is not None:
        channels = parse_rotor_channels(explicit, airframe.n_rotors)
        why = "given with --rotor-channels"
    else:
        matched = match_layout(airframe, layouts)
        if matched is None:
            known = "; ".join(layout.name for layout in layouts)
            raise RotorChannelError(
                f"airframe {airframe.name!r} ({airframe.n_rotors} rotors) matches no known motor order "
                f"({known}); give --rotor-channels with the channel of rotor 1, 2, ... "
                "in the airframe's numbering"
            )
        layout, motors = matched
        motor_channel, source = motor_channels_from_parameters(parameters or {}, airframe.n_rotors)
        channels = [motor_channel[m] for m in motors]
        why = f"{layout.name}: rotor k is motor {','.join(map(str, motors))}; {source}"
    if n_channels is not None and max(channels) > n_channels:
        raise RotorChannelError(f"rotor channels {channels} but the log has only {n_channels} channels")
    listed = ",".join(map(str, channels))
    if channel_names is not None:
        listed += f" ({', '.join(channel_names[c - 1] for c in channels)})"
    return channels, f"{listed}; {why}"
