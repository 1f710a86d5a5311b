"""RefusalCounter (multirotor_ros/refusals.py): counted per reason, logged once, then throttled summaries."""

from __future__ import annotations

import threading

from multirotor_ros.refusals import RefusalCounter


def test_refusals_are_counted_logged_once_per_reason_then_summarised() -> None:
    now = [0.0]
    lines: list[str] = []
    counter = RefusalCounter(lines.append, "commands", summary_period_s=10.0, clock=lambda: now[0])
    for _ in range(5):
        counter.refuse("negative speed", "rotor_1 = -1")
    counter.refuse("non-finite speed", "rotor_2 = nan")
    assert counter.counts == {"negative speed": 5, "non-finite speed": 1}
    assert counter.total == 6
    assert len(lines) == 2
    assert lines[0].startswith("refused commands: negative speed: rotor_1 = -1")
    now[0] = 11.0
    counter.refuse("negative speed", "rotor_1 = -1")
    assert len(lines) == 3
    assert "5 more" in lines[-1] and "negative speed: 5" in lines[-1] and "total 7" in lines[-1]


def test_a_summary_only_comes_with_new_refusals_after_a_quiet_period() -> None:
    now = [0.0]
    lines: list[str] = []
    counter = RefusalCounter(lines.append, summary_period_s=10.0, clock=lambda: now[0])
    counter.refuse("bad CRC", "first")
    now[0] = 20.0
    counter.refuse("bad CRC", "second")  # the only one since the first was logged
    assert len(lines) == 2 and "1 more input" in lines[-1]
    now[0] = 25.0
    counter.refuse("bad CRC", "third")  # within the period: counted, not logged
    assert len(lines) == 2 and counter.counts == {"bad CRC": 3}


def test_the_counts_given_out_are_a_copy() -> None:
    counter = RefusalCounter(lambda line: None)
    counter.refuse("bad CRC", "")
    counter.counts["bad CRC"] = 99
    assert counter.counts == {"bad CRC": 1}


def test_two_threads_may_refuse_into_one_counter() -> None:
    counter = RefusalCounter(lambda line: None)

    def refuse_many(reason: str) -> None:
        for k in range(2000):
            counter.refuse(f"{reason} {k % 50}", "")
            assert counter.total >= 1

    threads = [threading.Thread(target=refuse_many, args=(name,)) for name in ("link", "topic")]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert counter.total == 4000 and len(counter.counts) == 100
