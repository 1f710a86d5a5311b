"""The vehicle state in flight-stack frames, and the per-message send schedule every link uses.

:func:`ned_view` is the only place where a :class:`~multirotor_ros.mavlink.vehicle.VehicleState`
(world ENU, body FLU) is turned into NED/FRD quantities; it does so through :mod:`multirotor_ros.frames`.

:class:`MessageSchedule` decides when each periodic message is due and answers MAVLink's
SET_MESSAGE_INTERVAL (MAV_CMD 511: param1 = message id, param2 = interval [us], -1 = stop,
0 = back to the default).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from multirotor_ros.frames import enu_to_ned, flu_to_frd, quat_enu_flu_to_ned_frd
from multirotor_ros.mavlink.vehicle import VehicleState
from multirotor_ros.model.rotation import FloatArray, quat_to_euler

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3


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


def ned_view(state: VehicleState) -> NedView:
    """The state's NED/FRD quantities."""
    q_NED_FRD = quat_enu_flu_to_ned_frd(state.q_WB)
    return NedView(
        t_s=state.t_s,
        p_NED_m=enu_to_ned(state.p_WB_W),
        v_NED_m_s=enu_to_ned(state.v_WB_W),
        q_NED_FRD=q_NED_FRD,
        w_FRD_rad_s=flu_to_frd(state.w_WB_B),
        imu_accel_FRD_m_s2=flu_to_frd(state.imu_specific_force_B),
        imu_gyro_FRD_rad_s=flu_to_frd(state.imu_w_WB_B),
    )


def heading_cdeg(yaw_ned_rad: float) -> int:
    """A NED yaw as MAVLink's heading: centidegrees 0..35999."""
    return round(math.degrees(yaw_ned_rad) % 360.0 * 100.0) % 36000


def time_usec(t_s: float) -> int:
    """Simulated seconds as MAVLink microseconds (at least 1: PX4 reads 0 as 'no time')."""
    return max(1, round(t_s * 1e6))


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

    def request(self, message_id_param: float, interval_us: float) -> int:
        """Handle SET_MESSAGE_INTERVAL (param1, param2); returns the MAV_RESULT to acknowledge with."""
        if not (math.isfinite(message_id_param) and message_id_param == int(message_id_param)):
            return MAV_RESULT_DENIED
        message_id = int(message_id_param)
        if message_id not in self._default:
            return MAV_RESULT_UNSUPPORTED
        if not math.isfinite(interval_us):
            return MAV_RESULT_DENIED
        if interval_us == -1:
            self._set_rate(message_id, 0.0)
            return MAV_RESULT_ACCEPTED
        if interval_us == 0:
            self._set_rate(message_id, self._default[message_id])
            return MAV_RESULT_ACCEPTED
        if interval_us < 0:
            return MAV_RESULT_DENIED
        rate = 1e6 / interval_us
        low, high = self._allowed.get(message_id, (0.0, math.inf))
        if not low <= rate <= high:
            return MAV_RESULT_DENIED
        self._set_rate(message_id, rate)
        return MAV_RESULT_ACCEPTED


def as_float_list(values: FloatArray, length: int) -> list[float]:
    """A fixed-length float list for a MAVLink array field, zero-padded."""
    out = np.zeros(length)
    out[: min(length, len(values))] = np.asarray(values, dtype=float)[:length]
    return out.tolist()
