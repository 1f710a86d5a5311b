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

A lockstep simulator sends its newest state again while it waits (a controller that starts needs one):
:class:`StateTopic` keeps how to build that message, so the state first sent while nobody listened can
still be built and sent when somebody does.
"""

from __future__ import annotations

import time
from collections.abc import Callable
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


class StateTopic:
    """A volatile state topic: its newest message published while heard, and sent again on request."""

    def __init__(self, publisher: Any):
        self.publisher = publisher
        self.gate = ListenerGate(publisher)
        self._build: Callable[[], Any] | None = None
        self._message: Any = None

    def send(self, build: Callable[[], Any]) -> Any:
        """The newest state, as a builder of its message (called only if heard); the message or None.

        What the builder reads must not change afterwards: the message may be built later, by
        :meth:`resend`.
        """
        self._build, self._message = build, None
        if self.gate.heard():
            self._message = build()
            self.publisher.publish(self._message)
        return self._message

    def resend(self) -> None:
        """The newest state again (same stamp), built now if nobody heard it when it was new."""
        if self._build is None or not self.gate.heard():
            return
        if self._message is None:
            self._message = self._build()
        self.publisher.publish(self._message)
