"""An rclpy node that a command line tool uses while it does other work: spun by a thread of its own."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


@contextmanager
def background_node(name: str, namespace: str = "") -> Iterator[Any]:
    """A node in an rclpy context of its own, spun by a daemon thread, torn down on exit.

    Subscriptions and publishers may be created on it while it spins (rclpy wakes the executor).
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    context = rclpy.Context()
    rclpy.init(args=[name], context=context)
    node = rclpy.create_node(name, namespace=namespace, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)

    def spin() -> None:
        try:
            executor.spin()
        except ExternalShutdownException:
            pass

    thread = threading.Thread(target=spin, name=f"{name}_spin", daemon=True)
    thread.start()
    try:
        yield node
    finally:
        executor.shutdown()
        thread.join(timeout=10.0)
        node.destroy_node()
        context.try_shutdown()
