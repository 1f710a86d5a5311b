"""multirotor_ros/realtime.py: start-up is out of the garbage collector's sight while a node runs."""

from __future__ import annotations

import gc

import pytest

from multirotor_ros.realtime import start_up_frozen


def seen_by_the_collector(thing: object) -> bool:
    return any(candidate is thing for candidate in gc.get_objects())  # frozen ones are in none of its lists


def test_what_lives_at_the_start_is_frozen_for_the_block_and_what_is_made_in_it_is_not() -> None:
    from_start_up = [[] for _ in range(3)]
    with start_up_frozen():
        assert gc.get_freeze_count() >= len(from_start_up)
        made_in_flight = [[] for _ in range(3)]
        assert not seen_by_the_collector(from_start_up) and seen_by_the_collector(made_in_flight)
    assert gc.get_freeze_count() == 0 and seen_by_the_collector(from_start_up)


def test_the_collector_sees_everything_again_when_the_block_fails() -> None:
    with pytest.raises(RuntimeError), start_up_frozen():
        assert gc.get_freeze_count() > 0
        raise RuntimeError("a node's spin ended by an error")
    assert gc.get_freeze_count() == 0
