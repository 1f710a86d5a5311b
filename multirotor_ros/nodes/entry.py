"""The entry point every node executable shares: ``main(args)`` is ``run_node(NodeClass, args)``.

``run_node(node_factory, args) -> int`` initialises rclpy in a context of its own (shut down on the
way out), builds the node with ``node_factory(context=context)``, spins it with a single-threaded
executor and returns 0 when the spin ends by Ctrl-C (KeyboardInterrupt) or by an external shutdown
(ExternalShutdownException, e.g. SIGINT handled by rclpy). A node class whose ``__init__`` forwards
``**kwargs`` to ``rclpy.node.Node`` is a valid factory. A bad parameter or airframe while the node is
built (ValueError, ParameterException): one line on stderr, status 2.
"""

from __future__ import annotations

import faulthandler
import io
import os
import signal
import sys
import threading
import time
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
    _stacks_on_sigusr1()
    finished = threading.Event()
    try:
        with initialised_context(args) as context:
            _watch_for_shutdown(context, finished)
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
                # A signal can shut the context down while a callback is publishing or the executor is
                # taking a message (rclpy then fails in the middleware, seen as "Unable to convert call
                # argument"), and the error can surface a moment before the context reads as shut down.
                if not _shutting_down(context):
                    raise
            finally:
                if node is not None:
                    node.destroy_node()
    finally:
        finished.set()
    return 0


# How long an error in the spin waits for a shutdown that may have caused it [s].
SHUTDOWN_RACE_S = 0.5


def _shutting_down(context: Context) -> bool:
    """Whether the context is shut down now or within ``SHUTDOWN_RACE_S`` (a signal being handled)."""
    deadline = time.monotonic() + SHUTDOWN_RACE_S
    while context.ok():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def _stacks_on_sigusr1() -> None:
    """SIGUSR1 prints every thread's stack to stderr: how to see where a node that does not stop is stuck."""
    try:
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    except (AttributeError, ValueError, io.UnsupportedOperation):
        pass  # stderr is not a file (a node built in-process under a test's capture): nothing to print to


# How long a node may take to stop once shut down (Ctrl-C, SIGTERM, rclpy.shutdown) before it is ended.
STOP_GRACE_S = 5.0
SHUTDOWN_POLL_S = 0.2


def _watch_for_shutdown(context: Context, finished: threading.Event) -> None:
    """Once the context is shut down, end the process if it has not ended within ``STOP_GRACE_S``.

    Seen a few times in full test runs: a node (the controller on simulated time) kept running 10 s after
    SIGINT with nothing in its log, once its peers were gone; the middleware's teardown is the suspect. A
    node asked to stop must stop: its stacks go to stderr (the evidence) and it exits with status 0.
    rclpy's signal handler shuts the context down in C, without Python's shutdown callbacks: hence a
    daemon thread that polls ``context.ok()``. ``finished`` is set once ``run_node`` has returned: then
    nothing is forced (the process may be a test that goes on).
    """

    def watch() -> None:
        while context.ok() and not finished.is_set():
            time.sleep(SHUTDOWN_POLL_S)
        if finished.wait(STOP_GRACE_S):
            return
        print(
            f"{Path(sys.argv[0]).name}: still running {STOP_GRACE_S:g} s after shutdown was requested; "
            "ending it (every thread's stack follows)",
            file=sys.stderr,
            flush=True,
        )
        faulthandler.dump_traceback(all_threads=True)
        os._exit(0)

    # A daemon thread: a process that ends normally does not wait for it.
    threading.Thread(target=watch, name="shutdown-watch", daemon=True).start()
