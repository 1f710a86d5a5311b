"""Whether anybody listens to a publisher: messages nobody subscribes to are neither filled nor published.

A publish costs 3-10 us with no subscriber (rclpy converts the message to C, Fast DDS serialises it and
keeps it in the writer's history) and about 66 us with a subscriber in another process; the MAVLink
bridge's own physics publishes about 950 messages per simulated second, at up to 6x real time, from the
thread that answers the flight stack. For a volatile topic (no history kept for late joiners) a message
nobody receives has no effect, so skipping it changes nothing a subscriber can see: one that joins later
gets the messages from then on, as it would anyway. The count of matched subscriptions is asked at most
every :data:`RECHECK_S` of wall time (about 0.7 us a call), which delays a new subscriber's first message
by at most that, less than discovery itself takes. Latched (transient-local) topics must not be gated: a
late joiner receives their last message.
"""

from __future__ import annotations

import time
from typing import Any

RECHECK_S = 0.1  # [s] wall time between two questions to the middleware


class ListenerGate:
    """``heard()``: whether ``publisher`` had a matched subscription when last asked (see the module)."""

    def __init__(self, publisher: Any):
        self.publisher = publisher
        self._heard = True
        self._next_check_s = -1.0

    def heard(self) -> bool:
        """True when somebody subscribes (asked again when the last answer is RECHECK_S old)."""
        now_s = time.monotonic()
        if now_s >= self._next_check_s:
            self._heard = self.publisher.get_subscription_count() > 0
            self._next_check_s = now_s + RECHECK_S
        return self._heard
