"""ListenerGate: a publisher nobody subscribes to is skipped; a new subscriber is seen within RECHECK_S."""

from __future__ import annotations

import pytest

from multirotor_ros.nodes import listeners
from multirotor_ros.nodes.listeners import RECHECK_S, ListenerGate


class CountingPublisher:
    def __init__(self) -> None:
        self.subscriptions = 0
        self.asked = 0

    def get_subscription_count(self) -> int:
        self.asked += 1
        return self.subscriptions


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    now = [100.0]
    monkeypatch.setattr(listeners.time, "monotonic", lambda: now[0])
    return now


def test_the_middleware_is_asked_once_per_recheck_interval_and_a_new_subscriber_is_seen_then(clock):
    publisher = CountingPublisher()
    gate = ListenerGate(publisher)
    assert not gate.heard()  # asked at once: nobody yet
    publisher.subscriptions = 1
    clock[0] += 0.5 * RECHECK_S
    assert [gate.heard() for _ in range(1000)] == [False] * 1000  # the last answer holds meanwhile
    assert publisher.asked == 1
    clock[0] += 0.5 * RECHECK_S
    assert gate.heard()
    assert publisher.asked == 2
    publisher.subscriptions = 0
    clock[0] += RECHECK_S
    assert not gate.heard()  # the last subscriber left
