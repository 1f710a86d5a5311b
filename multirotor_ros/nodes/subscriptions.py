"""Subscriptions that take every message waiting, not only the ones the executor was told of.

rclpy's EventsExecutor (the nodes' default, nodes/entry.py) takes from a subscription as many messages as
the middleware announced with its new-message callback. Under load some announcements are lost, and the
messages they stood for stay in the subscription's queue, taken one per later announcement: the stream
then runs late by that many messages for good. Measured in the identifier in real time beside the
simulator and controller (a trace of each message's arrival in its callbacks): its ``motor_speeds`` ran
a steady 0.5 s (50 messages) behind its ``odom`` within seconds, beside five busy-loop processes and
beside none (that run's own tracing stalled the node now and then), while a probe subscribing to both in
another process got them on time. Taking what is left after each message found 1,065 such messages in
40 s; in 150 s beside two busy-loop processes both streams then came with a median lag of 0 ms. An
identifier whose rotor speeds come half a second after the states pairs states with speeds of another
moment or drops them, and a controller or simulator whose input runs late acts on old news.

:func:`subscribe` hands each message to the callback and then takes whatever else is waiting, at most the
queue's depth (one callback does not starve the others when a publisher outruns the node: what is beyond
the depth is lost anyway). With nothing waiting, that costs one empty take (3.8 us). The executor then
finds nothing for announcements whose messages were taken here, which it handles as an empty take. A queue
of depth 1 (the controller's odometry, every ``/clock``) gets a plain subscription: what waits there is
replaced by the next message, whose own announcement takes it, so nothing can stay behind for good and an
empty take per message would be pure cost on the lockstep loop's path.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription


def subscribe(
    node: Node,
    msg_type: Any,
    topic: str,
    callback: Callable[[Any], None],
    qos: QoSProfile | int,
    raw: bool = False,
) -> Subscription:
    """``node.create_subscription`` whose callback also takes what is left in the queue (module docstring)."""
    depth = qos if isinstance(qos, int) else qos.depth
    if depth <= 1:
        return node.create_subscription(msg_type, topic, callback, qos, raw=raw)
    subscription: Subscription | None = None

    def take_all(message: Any) -> None:
        callback(message)
        assert subscription is not None  # created before any message can come
        for _ in range(depth):
            taken = take_waiting(subscription, msg_type, raw)
            if taken is None:
                return
            callback(taken)

    subscription = node.create_subscription(msg_type, topic, take_all, qos, raw=raw)
    return subscription


def take_waiting(subscription: Subscription, msg_type: Any, raw: bool = False) -> Any:
    """The oldest message waiting in ``subscription``'s queue, taken now, or None (the executor not asked)."""
    with subscription.handle:
        taken = subscription.handle.take_message(msg_type, raw)
    return None if taken is None else taken[0]
