"""ListenerGate and StateTopic: unheard topics are skipped, a subscriber is seen within RECHECK_S."""

from __future__ import annotations

import pytest

from multirotor_ros.nodes import listeners
from multirotor_ros.nodes.listeners import RECHECK_S, ListenerGate, StateTopic


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


class RecordingPublisher(CountingPublisher):
    def __init__(self) -> None:
        super().__init__()
        self.published: list[object] = []

    def publish(self, message: object) -> None:
        self.published.append(message)


def test_a_state_nobody_heard_is_built_when_a_subscriber_comes_and_sent_again(clock):
    publisher = RecordingPublisher()
    topic = StateTopic(publisher)
    built: list[int] = []

    def build(value: int):
        def make() -> tuple[str, int]:
            built.append(value)
            return ("state", value)

        return make

    assert topic.send(build(1)) is None  # nobody listens: neither built nor published
    assert topic.send(build(2)) is None
    topic.resend()
    assert built == [] and publisher.published == []
    publisher.subscriptions = 1  # a controller starts while lockstep waits
    clock[0] += RECHECK_S
    topic.resend()
    topic.resend()
    assert built == [2], "the newest state only, built once"
    assert publisher.published == [("state", 2), ("state", 2)]
    assert topic.send(build(3)) == ("state", 3)
    assert publisher.published[-1] == ("state", 3) and built == [2, 3]


def test_nothing_is_resent_before_a_first_state():
    publisher = RecordingPublisher()
    publisher.subscriptions = 1
    StateTopic(publisher).resend()
    assert publisher.published == []
