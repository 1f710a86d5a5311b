"""ClockClaim (nodes/clock.py): of two nodes publishing the clock, the one that claimed it second yields.

Real rclpy nodes in this process over DDS, on a claim topic of their own (so nothing else of the session
interferes). Both claim before either has discovered the other, as two simulators whose start-up checks
both passed on a slow discovery do: the claims alone must settle it, the same way on both sides.
"""

from __future__ import annotations

import time

import pytest
from rclpy.context import Context
from rclpy.node import Node
from ros_harness import spin_until

from multirotor_ros.nodes.clock import CLOCK_CLAIM_TOPIC, ClockClaim

pytestmark = pytest.mark.ros
OWN_CLAIM_TOPIC = "/clock_claim_of_test_clock_claim"


@pytest.fixture
def context(rclpy_context: Context) -> Context:
    return rclpy_context


def claimant(context: Context, name: str) -> tuple[Node, ClockClaim, list[tuple[str, float]]]:
    remap = ["--ros-args", "-r", f"{CLOCK_CLAIM_TOPIC}:={OWN_CLAIM_TOPIC}"]
    node = Node(name, context=context, cli_args=remap)
    yields: list[tuple[str, float]] = []
    return node, ClockClaim(node, lambda other, earlier_by_s: yields.append((other, earlier_by_s))), yields


def test_the_second_claim_yields_to_the_first_and_the_first_keeps_the_clock(context: Context) -> None:
    first, first_claim, first_yields = claimant(context, "first")
    second, second_claim, second_yields = claimant(context, "second")
    first_claim.stake()
    time.sleep(0.01)
    second_claim.stake()
    spin_until(context, [first, second], lambda: bool(second_yields) and "/second" in first_claim.heard)
    assert [name for name, _ in second_yields] == ["/first"]
    assert 0.005 < second_yields[0][1] < 5.0  # how much earlier the first claimed [s]
    assert first_yields == []  # it heard the later claim and keeps the clock
    assert first_claim.heard["/second"] > second_claim.heard["/first"]


def test_a_node_that_has_not_claimed_only_records_the_claims_it_hears(context: Context) -> None:
    owner, owner_claim, _ = claimant(context, "owner")
    listener, listener_claim, listener_yields = claimant(context, "listener")
    owner_claim.stake()
    spin_until(context, [owner, listener], lambda: bool(listener_claim.heard))
    assert list(listener_claim.heard) == ["/owner"]
    assert listener_yields == []
    # Claiming after hearing an earlier claim yields at once, without waiting for anything more.
    listener_claim.stake()
    assert [name for name, _ in listener_yields] == ["/owner"]
