"""The vehicle state in flight-stack frames, and the per-message send schedule every link uses.

:func:`ned_view` is the only place where a :class:`~multirotor_ros.mavlink.vehicle.VehicleState`
(world ENU, body FLU) is turned into NED/FRD quantities; it does so through :mod:`multirotor_ros.frames`.

:class:`MessageSchedule` decides when each periodic message is due and answers MAVLink's
SET_MESSAGE_INTERVAL (MAV_CMD 511: param1 = message id, param2 = interval [us], -1 = stop,
0 = back to the default). Requested rates are bounded: at most 50 Hz and at least 0.05 Hz per
message unless a link sets other bounds for a message (the PX4 link lets its flight stack ask for
HIL_STATE_QUATERNION at up to 1 kHz); a request outside them is answered DENIED with
``result_param2 = 2`` (the interval is the refused parameter) and counted, the rate stays as it was.

:func:`wire_value` and :func:`fit_to_wire` are the one place where a value meets a MAVLink field's range:
every message the links send goes through :meth:`~multirotor_ros.mavlink.wire.MavlinkCodec.encode`,
which fits it, so that no value (1e308 m, a NaN heading, an hour of rpm) can make packing raise.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from multirotor_ros.frames import enu_to_ned, flu_to_frd, quat_enu_flu_to_ned_frd
from multirotor_ros.mavlink.vehicle import VehicleState
from multirotor_ros.model.rotation import FloatArray, quat_to_euler

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
HEADING_UNKNOWN = 65535  # UINT16_MAX: MAVLink's "heading unknown"

# Requested rates (SET_MESSAGE_INTERVAL) of a message without bounds of its own: at most 50 Hz (ATTITUDE
# at 50 Hz is what ground stations ask for; faster only floods the link) and at least one message every
# 20 s (slower is "stop", which -1 asks for). A link with a flight stack on the other end gives its own.
REQUEST_RATE_BOUNDS_HZ = (0.05, 50.0)

FLOAT32_MAX = 3.4028234663852886e38
INTEGER_FIELD_RANGES = {
    f"{sign}int{bits}_t": ((0, 2**bits - 1) if sign else (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1))
    for sign in ("", "u")
    for bits in (8, 16, 32, 64)
}


@dataclass(frozen=True)
class NedView:
    """A :class:`VehicleState` as flight stacks and ground stations want it: world NED, body FRD."""

    t_s: float
    p_NED_m: FloatArray
    v_NED_m_s: FloatArray
    q_NED_FRD: FloatArray  # (w, x, y, z), body FRD -> world NED
    w_FRD_rad_s: FloatArray  # true body rate
    imu_accel_FRD_m_s2: FloatArray  # specific force the accelerometer reads
    imu_gyro_FRD_rad_s: FloatArray

    @property
    def euler_NED_rad(self) -> FloatArray:
        """Roll, pitch, yaw (ZYX) of q_NED_FRD; yaw from north, clockwise (only ground stations need it)."""
        return quat_to_euler(self.q_NED_FRD)


def _axis_changes() -> FloatArray:
    """The 19 numbers of a :class:`NedView` from the state's 19 in ENU/FLU, as one matrix.

    Order: position, velocity (world), attitude quaternion, body rate, accelerometer, gyroscope (body).
    The conversions of :mod:`multirotor_ros.frames` are changes of axes, linear in what they convert (the
    quaternion's up to its sign, which frames.py makes w >= 0 and the unit quaternions need no change
    of): applied to the unit vectors they give their matrices, so every number still goes through
    frames.py, and a state costs one product where a dozen small numpy calls cost more than the physics
    step (this runs for every frame a flight stack gets, 1,200 a second from ArduPilot).
    """
    world, body = enu_to_ned(np.eye(3)).T, flu_to_frd(np.eye(3)).T
    blocks = (world, world, quat_enu_flu_to_ned_frd(np.eye(4)).T, body, body, body)
    matrix = np.zeros((19, 19))
    start = 0
    for block in blocks:
        matrix[start : start + len(block), start : start + len(block)] = block
        start += len(block)
    return matrix


_AXIS_CHANGES = _axis_changes()


def ned_axes(state: VehicleState) -> FloatArray:
    """A :class:`NedView`'s 19 numbers in one array, in :func:`_axis_changes`' order.

    The attitude's sign not yet made w >= 0: for a caller that wants plain numbers (ArduPilot's answer
    line) without the view's arrays. Every row mixes in all of the state through the product (0 x inf
    is NaN), so one number not finite in the state makes every number here NaN: test any of them.
    :func:`ned_view` converts such a state elementwise.
    """
    inside = np.concatenate(
        (state.p_WB_W, state.v_WB_W, state.q_WB, state.w_WB_B, state.imu_specific_force_B, state.imu_w_WB_B)
    )
    return _AXIS_CHANGES.dot(inside)


def ned_view(state: VehicleState) -> NedView:
    """The state's NED/FRD quantities."""
    out = ned_axes(state)
    if not np.isfinite(out).all():
        return _ned_view_elementwise(state)
    q_NED_FRD = out[6:10] if out[6] >= 0.0 else -out[6:10]  # the same attitude, w >= 0 as frames.py gives
    return NedView(state.t_s, out[0:3], out[3:6], q_NED_FRD, out[10:13], out[13:16], out[16:19])


def _ned_view_elementwise(state: VehicleState) -> NedView:
    return NedView(
        t_s=state.t_s,
        p_NED_m=enu_to_ned(state.p_WB_W),
        v_NED_m_s=enu_to_ned(state.v_WB_W),
        q_NED_FRD=quat_enu_flu_to_ned_frd(state.q_WB),
        w_FRD_rad_s=flu_to_frd(state.w_WB_B),
        imu_accel_FRD_m_s2=flu_to_frd(state.imu_specific_force_B),
        imu_gyro_FRD_rad_s=flu_to_frd(state.imu_w_WB_B),
    )


def heading_cdeg(yaw_ned_rad: float) -> int:
    """A NED yaw as MAVLink's heading: centidegrees 0..35999, 65535 (unknown) when not finite."""
    if not math.isfinite(yaw_ned_rad):
        return HEADING_UNKNOWN
    return round(math.degrees(yaw_ned_rad) % 360.0 * 100.0) % 36000


def time_usec(t_s: float) -> int:
    """Simulated seconds as MAVLink microseconds (at least 1: PX4 reads 0 as 'no time')."""
    return max(1, wire_value(t_s * 1e6, "uint64_t"))


class MessageSchedule:
    """When each periodic message is next due, on one clock (simulated or wall time, the caller's)."""

    def __init__(
        self,
        default_rates_hz: dict[int, float],
        allowed_rates_hz: dict[int, tuple[float, float]] | None = None,
    ):
        self._default = dict(default_rates_hz)
        self._allowed = dict(allowed_rates_hz or {})
        self._period_s: dict[int, float] = {}
        self._next_s: dict[int, float] = {}
        for message_id, rate in self._default.items():
            self._set_rate(message_id, rate)

    def _set_rate(self, message_id: int, rate_hz: float) -> None:
        self._period_s[message_id] = 1.0 / rate_hz if rate_hz > 0 else math.inf
        self._next_s[message_id] = -math.inf

    def rate_hz(self, message_id: int) -> float:
        """The current rate of a message (0 = not sent)."""
        period = self._period_s.get(message_id, math.inf)
        return 0.0 if math.isinf(period) else 1.0 / period

    def due(self, message_id: int, now_s: float) -> bool:
        """Whether the message should go out now; if so, the next one is scheduled one period later."""
        next_s = self._next_s[message_id]
        if now_s < next_s:
            return False
        period = self._period_s[message_id]
        if math.isinf(period):
            return False
        # Keep the phase when on time; after a gap (or the first time), restart from now.
        self._next_s[message_id] = next_s + period if now_s - next_s < period else now_s + period
        return True

    def next_due_s(self) -> float:
        """The earliest time any scheduled message is due."""
        finite = [n for m, n in self._next_s.items() if not math.isinf(self._period_s[m])]
        return min(finite, default=math.inf)

    def restart(self) -> None:
        """Make every message due at once (the clock was reset)."""
        for message_id in self._next_s:
            self._next_s[message_id] = -math.inf

    def request(self, message_id_param: float, interval_us: float) -> IntervalAnswer:
        """Handle SET_MESSAGE_INTERVAL (param1, param2): change the rate if allowed, say how it went.

        A rate outside the message's bounds (its own, else :data:`REQUEST_RATE_BOUNDS_HZ`) is refused,
        not clamped: the requester learns from the DENIED answer that it did not get what it asked for.
        """
        if not (math.isfinite(message_id_param) and message_id_param == int(message_id_param)):
            return IntervalAnswer(MAV_RESULT_DENIED, f"message id {message_id_param} is not an integer", 1)
        message_id = int(message_id_param)
        if message_id not in self._default:
            return IntervalAnswer(MAV_RESULT_UNSUPPORTED, f"message id {message_id} is not sent here", 1)
        if interval_us == -1:
            self._set_rate(message_id, 0.0)
            return IntervalAnswer(MAV_RESULT_ACCEPTED)
        if interval_us == 0:
            self._set_rate(message_id, self._default[message_id])
            return IntervalAnswer(MAV_RESULT_ACCEPTED)
        low, high = self._allowed.get(message_id, REQUEST_RATE_BOUNDS_HZ)
        rate = 1e6 / interval_us if math.isfinite(interval_us) and interval_us > 0 else math.nan
        if not low <= rate <= high:
            return IntervalAnswer(
                MAV_RESULT_DENIED,
                f"message {message_id} at an interval of {interval_us:g} us: "
                f"allowed {1e6 / high:g}..{1e6 / low:g} us ({low:g}..{high:g} Hz), -1 or 0",
                2,
            )
        self._set_rate(message_id, rate)
        return IntervalAnswer(MAV_RESULT_ACCEPTED)


@dataclass(frozen=True)
class IntervalAnswer:
    """What a SET_MESSAGE_INTERVAL gets: a MAV_RESULT and, when refused, why and which parameter."""

    result: int
    detail: str = ""
    refused_param: int = 0  # 1 = message id, 2 = interval; sent as COMMAND_ACK.result_param2


def answer_command(
    mav: Any, message: Any, schedule: MessageSchedule, refuse: Callable[[str, str], None]
) -> Any:
    """The COMMAND_ACK for a COMMAND_LONG: SET_MESSAGE_INTERVAL goes to ``schedule``, others are unsupported.

    A refused interval is counted through ``refuse`` (reason "message interval refused").
    """
    if message.command == MAV_CMD_SET_MESSAGE_INTERVAL:
        answer = schedule.request(message.param1, message.param2)
        if answer.result != MAV_RESULT_ACCEPTED:
            refuse("message interval refused", answer.detail)
    else:
        answer = IntervalAnswer(MAV_RESULT_UNSUPPORTED)
    return mav.command_ack_encode(
        message.command,
        answer.result,
        result_param2=answer.refused_param,
        target_system=message.get_srcSystem(),
        target_component=message.get_srcComponent(),
    )


def wire_value(value: Any, wire_type: str) -> Any:
    """``value`` as a field of MAVLink type ``wire_type`` can carry it (e.g. ``int16_t``, ``float``).

    Integer fields: rounded and clamped to the type's range, NaN sent as 0 (an integer field has no
    "unknown"; the links refuse non-finite input before it gets here, so this only keeps a value that
    slipped through from raising). ``float``: clamped to the float32 range, NaN kept (MAVLink's "unknown").
    ``double`` and ``char``: unchanged, they carry anything.
    """
    return _fit(value, wire_type)[0]


def _fit(value: Any, wire_type: str) -> tuple[Any, bool]:
    """:func:`wire_value`, and whether the value had to be clamped."""
    integer_range = INTEGER_FIELD_RANGES.get(wire_type)
    if integer_range is not None:
        low, high = integer_range
        if not isinstance(value, (int, np.integer)):
            if math.isnan(value):
                return 0, True
            inside = low <= value <= high
            # Clamped before rounding: round(inf) raises.
            return (round(value) if inside else max(low, min(high, value))), not inside
        return (value, False) if low <= value <= high else (max(low, min(high, int(value))), True)
    if wire_type == "float" and abs(value) > FLOAT32_MAX:
        return math.copysign(FLOAT32_MAX, value), True
    return value, False


_FieldSpec = tuple[str, str, int]  # name, MAVLink type, array length (0 = scalar)
_FIELD_SPECS: dict[type, list[_FieldSpec]] = {}


def _field_specs(message_class: type) -> list[_FieldSpec]:
    specs = _FIELD_SPECS.get(message_class)
    if specs is None:
        specs = [
            (name, wire_type, length)
            for name, wire_type, length in zip(
                message_class.fieldnames,  # type: ignore[attr-defined]
                message_class.fieldtypes,  # type: ignore[attr-defined]
                message_class.array_lengths,  # type: ignore[attr-defined]
                strict=True,
            )
            if wire_type not in ("char", "double")
        ]
        _FIELD_SPECS[message_class] = specs
    return specs


def fit_to_wire(message: Any) -> int:
    """Fit every field of a pymavlink message into its type's range (:func:`wire_value`), in place.

    Returns how many values had to be clamped.
    """
    clamped = 0
    for name, wire_type, length in _field_specs(type(message)):
        value = getattr(message, name)
        if length:
            fitted = [_fit(element, wire_type) for element in value]
            setattr(message, name, [element for element, _ in fitted])
            clamped += sum(was_clamped for _, was_clamped in fitted)
        else:
            fitted_value, was_clamped = _fit(value, wire_type)
            setattr(message, name, fitted_value)
            clamped += was_clamped
    return clamped


def as_float_list(values: FloatArray, length: int) -> list[float]:
    """A fixed-length float list for a MAVLink array field, zero-padded."""
    out = np.zeros(length)
    out[: min(length, len(values))] = np.asarray(values, dtype=float)[:length]
    return out.tolist()
