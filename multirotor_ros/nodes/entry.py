"""The entry point every node executable shares: ``main(args)`` is ``run_node(NodeClass, args)``.

``run_node(node_factory, args) -> int`` initialises rclpy in a context of its own (shut down on the
way out), builds the node with ``node_factory(context=context)``, spins it with a single-threaded
executor and returns 0 when the spin ends by Ctrl-C (KeyboardInterrupt) or by an external shutdown
(ExternalShutdownException, e.g. SIGINT handled by rclpy). A node class whose ``__init__`` forwards
``**kwargs`` to ``rclpy.node.Node`` is a valid factory. A bad parameter or airframe while the node is
built (ValueError, ParameterException): one line on stderr, status 2.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions


@contextmanager
def initialised_context(args: Sequence[str] | None) -> Iterator[Context]:
    """A new rclpy context initialised with ``args`` (ROS arguments), shut down on exit.

    A context of our own so that several nodes (or a test's probe) can share a process; rclpy installs
    its SIGINT/SIGTERM handlers only for the default context unless asked, and Ctrl-C must end the spin.
    (Context's own ``with`` initialises it without arguments, so the ROS arguments need init() here.)
    """
    context = Context()
    rclpy.init(
        args=None if args is None else list(args),
        context=context,
        signal_handler_options=SignalHandlerOptions.ALL,
    )
    try:
        yield context
    finally:
        context.try_shutdown()


def run_node(node_factory: Callable[..., Node], args: Sequence[str] | None = None) -> int:
    """Initialise rclpy, spin the node made by ``node_factory(context=...)``, return the exit status.

    A ValueError or rclpy ParameterException raised while the node is built (a bad parameter value or
    airframe) is printed as one line and gives exit status 2: the node cannot run, and a traceback
    would hide the reason.
    """
    with initialised_context(args) as context:
        node: Node | None = None
        try:
            try:
                node = node_factory(context=context)
            except (ValueError, ParameterException) as error:
                print(f"{Path(sys.argv[0] if args is None else args[0]).name}: {error}", file=sys.stderr)
                return 2
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            executor.spin()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except Exception:
            # A signal can shut the context down while a callback is publishing; that is a normal end too.
            if context.ok():
                raise
        finally:
            if node is not None:
                node.destroy_node()
    return 0
