"""nodes/subscriptions.py: one callback takes every message waiting, in order, up to the queue's depth.

Real rclpy pub/sub in one process (the session's isolated domain). The SingleThreadedExecutor takes one
message per ready subscription and wait, which stands in for an executor that was told of fewer messages
than are waiting (what the EventsExecutor is under load: the module docstring's measurement).
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.publisher import Publisher
from std_msgs.msg import Header

from multirotor_ros.nodes.messages import stamp_from_ns, stamp_to_ns
from multirotor_ros.nodes.subscriptions import subscribe

pytestmark = pytest.mark.ros

DEPTH = 20


@pytest.fixture
def node() -> Iterator[rclpy.node.Node]:
    context = rclpy.Context()
    rclpy.init(args=["subscriptions_test"], context=context)
    node = rclpy.create_node("subscriptions_test", context=context)
    yield node
    node.destroy_node()
    context.try_shutdown()


def matched(node, topic: str) -> tuple[Publisher, SingleThreadedExecutor]:
    """A publisher on ``topic`` once it sees the node's subscription, and an executor for the node."""
    publisher = node.create_publisher(Header, topic, DEPTH)
    deadline = time.monotonic() + 10.0
    while publisher.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    return publisher, executor


def test_one_callback_takes_what_is_waiting_in_order_and_never_more_than_the_depth(node) -> None:
    received: list[int] = []
    subscribe(node, Header, "waiting", lambda m: received.append(stamp_to_ns(m.stamp)), DEPTH)
    publisher, executor = matched(node, "waiting")
    for count in (5, 2 * DEPTH + 1):
        received.clear()
        for k in range(count):
            publisher.publish(Header(stamp=stamp_from_ns(k)))
        time.sleep(0.2)  # delivered to the subscription's queue, not yet taken
        executor.spin_once(timeout_sec=1.0)
        # The queue keeps the newest DEPTH; the first message and then at most DEPTH more in one callback.
        first = max(0, count - DEPTH)
        assert received == list(range(first, count)), received
    executor.shutdown()


def test_a_raw_subscription_gets_the_waiting_messages_serialised(node) -> None:
    received: list[bytes] = []
    subscribe(node, Header, "raw", received.append, DEPTH, raw=True)
    publisher, executor = matched(node, "raw")
    for k in range(3):
        publisher.publish(Header(frame_id=f"f{k}"))
    time.sleep(0.2)
    executor.spin_once(timeout_sec=1.0)
    assert len(received) == 3 and all(isinstance(data, bytes) for data in received)
    assert [data.rstrip(b"\0")[-2:] for data in received] == [b"f0", b"f1", b"f2"]
    executor.shutdown()
