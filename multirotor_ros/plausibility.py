"""Physical plausibility of incoming data: what a multirotor can report, and when it can report it.

A finite number is not yet a plausible one: 1e308 m, a body rate of 1e200 rad/s or a stamp an hour ahead
pass a finiteness check and then poison a controller's output or an estimator's state. Every node checks
its inputs here before they touch anything, and refuses (with the reason) what fails; nothing here keeps a
refused value. No ROS: nodes, the MAVLink bridge and the offline tools share it.

The limits are generous on purpose: they separate the physically impossible from the merely unusual, so a
hard manoeuvre is never refused. Each one is the largest value any vehicle of this toolkit's kind can show,
with the reason beside it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from multirotor_ros.refusals import Refusal

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class StateLimits:
    """Largest plausible magnitudes of a multirotor's state (see the module docstring)."""

    position_m: float = 10_000.0  # the MAVLink path's 10 km geofence: beyond it a position is an error
    speed_m_s: float = 100.0  # racing quadrotors reach about 50 m/s
    body_rate_rad_s: float = 35.0  # 2000 deg/s, the full scale of MEMS gyros in flight controllers
    acceleration_m_s2: float = 160.0  # 16 g, the full scale of flight-controller accelerometers
    quaternion_norm_tolerance: float = 1e-3  # float32 rounding leaves a unit quaternion within 1e-6 of 1

    def check(
        self,
        p_WB_W: ArrayLike | None = None,
        v_WB_W: ArrayLike | None = None,
        w_WB_B: ArrayLike | None = None,
        a_WB_W: ArrayLike | None = None,
        what: str = "state",
    ) -> Refusal | None:
        """None if every given quantity is finite and within its limit, else the first that is not."""
        for name, values, limit, unit in (
            ("position", p_WB_W, self.position_m, "m"),
            ("velocity", v_WB_W, self.speed_m_s, "m/s"),
            ("body rate", w_WB_B, self.body_rate_rad_s, "rad/s"),
            ("acceleration", a_WB_W, self.acceleration_m_s2, "m/s^2"),
        ):
            if values is None:
                continue
            array = np.asarray(values, dtype=float)
            # Fast path, every message of a flight: NaN fails the comparison, an overflow gives inf.
            flat = array.ravel().tolist()
            if math.sumprod(flat, flat) <= limit * limit:
                continue
            if not np.all(np.isfinite(array)):
                return Refusal(f"non-finite {name}", f"{what} {name} {format_vector(array)}")
            # The largest component first: the norm of 1e308-sized components overflows.
            largest = float(np.max(np.abs(array), initial=0.0))
            magnitude = largest if largest > limit else float(np.linalg.norm(array))
            if magnitude > limit:
                return Refusal(
                    f"implausible {name}",
                    f"{what} {name} of magnitude {magnitude:.6g} {unit} exceeds {limit:g} {unit}",
                )
        return None


def format_vector(values: ArrayLike) -> str:
    """A vector as a person reads it: (1, 2.5, nan), no numpy repr."""
    return "(" + ", ".join(f"{float(v):.6g}" for v in np.ravel(np.asarray(values, dtype=float))) + ")"


@dataclass
class StampGate:
    """Refuses stamps from the future or older than the newest one accepted; a refused stamp is not kept.

    ``future_tolerance_s``: how far ahead of the node's own clock a stamp may be (clocks of two processes
    differ by a little; an hour is an error). ``reordering_tolerance_s``: how far behind the newest accepted
    stamp a message may be and still be used (transports reorder a little). When the node's clock itself
    goes back (simulated time restarted), the gate forgets its newest stamp.
    """

    future_tolerance_s: float = 0.5
    reordering_tolerance_s: float = 0.0
    newest_ns: int | None = None
    # The tolerances in ns, converted once: the gate judges every message of a 250 Hz topic.
    _future_ns: int = field(init=False, repr=False)
    _reordering_ns: int = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._future_ns = round(self.future_tolerance_s * NS_PER_S)
        self._reordering_ns = round(self.reordering_tolerance_s * NS_PER_S)

    def check(self, stamp_ns: int, now_ns: int, what: str = "message") -> Refusal | None:
        """None and remember ``stamp_ns`` if it is acceptable at ``now_ns``; else why not (nothing kept)."""
        if self.newest_ns is not None and now_ns < self.newest_ns - self._future_ns:
            self.newest_ns = None  # the clock went back: a restart, not a late message
        if stamp_ns > now_ns + self._future_ns:
            ahead = (stamp_ns - now_ns) / NS_PER_S
            return Refusal(
                "stamp in the future",
                f"{what} stamped {ahead:.3f} s ahead of this node's clock "
                f"(tolerance {self.future_tolerance_s:g} s)",
            )
        if self.newest_ns is not None and stamp_ns < self.newest_ns - self._reordering_ns:
            behind = (self.newest_ns - stamp_ns) / NS_PER_S
            return Refusal(
                "stamp out of order", f"{what} stamped {behind:.3f} s before the newest accepted one"
            )
        self.newest_ns = stamp_ns if self.newest_ns is None else max(self.newest_ns, stamp_ns)
        return None

    def reset(self) -> None:
        """Forget the newest stamp (after a reset of the data source)."""
        self.newest_ns = None


def jump_refusal(
    previous_m: ArrayLike,
    current_m: ArrayLike,
    dt_s: float,
    limits: StateLimits,
    what: str = "position",
    margin_m: float = 0.5,
) -> Refusal | None:
    """Refuse a position that moved farther than the speed limit allows since the last accepted one.

    ``margin_m`` covers measurement noise and a first sample after a short gap.
    """
    # math.dist scales before squaring: 1e308-sized coordinates give their distance, or inf, never NaN.
    distance = math.dist(
        np.asarray(previous_m, dtype=float).ravel().tolist(),
        np.asarray(current_m, dtype=float).ravel().tolist(),
    )
    allowed = limits.speed_m_s * max(dt_s, 0.0) + margin_m
    if not math.isfinite(distance) or distance > allowed:
        return Refusal(
            f"implausible {what} jump",
            f"{what} moved {distance:.6g} m in {dt_s:.3f} s (at most {allowed:.6g} m is physical)",
        )
    return None
