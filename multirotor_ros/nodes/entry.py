"""The entry point every node executable shares: ``main(args)`` is ``run_node(NodeClass, args)``.

``run_node(node_factory, args) -> int`` initialises rclpy in a context of its own (shut down on the way
out), builds the node with ``node_factory(context=context)``, spins it (``spin``) with the executor
``make_executor`` picks (with the nodes of its ``members`` attribute, if it has one: several nodes composed
in one process, nodes/fleet_controller.py), and returns 0 when the spin ends by Ctrl-C (KeyboardInterrupt),
by SIGINT/SIGTERM (rclpy shuts the context down) or by any other shutdown of the context. A node class whose
``__init__`` forwards ``**kwargs`` to ``rclpy.node.Node`` is a valid factory. A bad parameter or airframe
while the node is built (ValueError, ParameterException): one line on stderr, status 2. An exception raised
by a callback ends the spin and propagates (a traceback, status 1).

Environment:
    ``MULTIROTOR_ROS_EXECUTOR``: ``events`` (default; rclpy.experimental.EventsExecutor) or ``single``
        (rclpy's SingleThreadedExecutor); see ``make_executor``.
    ``MULTIROTOR_ROS_PROFILE``: a directory; each node writes a cProfile of its spin there when it
        stops (``<node>-<pid>.prof``; see ``_profiled``).
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
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import rclpy
from rclpy.clock import ClockType
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from multirotor_ros.realtime import start_up_frozen


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
    stop = threading.Event()  # SIGINT or SIGTERM while an EventsExecutor spins (see spin)
    try:
        with initialised_context(args) as context, ExitStack() as signals:
            _watch_for_shutdown(context, finished)
            node: Node | None = None
            executor: Executor | None = None
            try:
                try:
                    node = node_factory(context=context)
                except (ValueError, ParameterException) as error:
                    print(f"{Path(sys.argv[0] if args is None else args[0]).name}: {error}", file=sys.stderr)
                    return 2
                executor = make_executor(context, node)
                for spun in _with_members(node):
                    executor.add_node(spun)
                if not isinstance(executor, SingleThreadedExecutor):
                    signals.enter_context(_signals_set(stop))  # until the node is torn down
                with _profiled(node), start_up_frozen():
                    spin(executor, context, stop)
            except (KeyboardInterrupt, ExternalShutdownException):
                pass
            except Exception:
                # A signal can shut the context down while a callback is publishing or the executor is
                # taking a message (rclpy then fails in the middleware, seen as "Unable to convert call
                # argument"), and the error can surface a moment before the context reads as shut down.
                if not _shutting_down(context):
                    raise
            finally:
                if executor is not None and not isinstance(executor, SingleThreadedExecutor):
                    # Detach the EventsExecutor's middleware callbacks before the node's entities go.
                    executor.shutdown(timeout_sec=STOP_GRACE_S)
                if node is not None:
                    for spun in _with_members(node):
                        spun.destroy_node()
    finally:
        finished.set()
    return 0


def _with_members(node: Node) -> list[Node]:
    """``node`` and the nodes it holds (``members``), spun and destroyed together."""
    return [node, *getattr(node, "members", ())]


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


EXECUTOR_ENV = "MULTIROTOR_ROS_EXECUTOR"
EXECUTORS = ("events", "single")
# The EventsExecutor is spun in slices of this wall time [s]: how soon a shut-down context ends the spin.
SPIN_SLICE_S = 0.1


def make_executor(context: Context, node: Node | None = None) -> Executor:
    """The executor ``$MULTIROTOR_ROS_EXECUTOR`` names: ``events`` (the default) or ``single``.

    ``events`` is ``rclpy.experimental.EventsExecutor``, which dispatches in C++: the single-threaded
    executor's Python wait-set machinery costs the lockstep simulator about 0.5 ms of CPU per control
    period (bench/bench_closed_loop.py); ``single`` is rclpy's ``SingleThreadedExecutor``. The
    single-threaded one is used instead of the events one when ``node`` runs on simulated time
    (``use_sim_time`` true when it is built) without keeping that time itself (below), when it has
    guard conditions (which the EventsExecutor refuses: a guard condition created later ends the spin
    with a RuntimeError), without an EventsExecutor (rclpy before 7.1.4), or where it cannot be made
    (its constructor enables ``faulthandler`` on stderr, which fails when stderr is not a file). Another
    value of the variable: one line on stderr, and the default.

    Simulated time, two failures of the EventsExecutor: rclcpp's events executor does not support a
    clock driven by ``/clock`` in its timers manager (ros2/rclcpp#2457: it sleeps in wall time until a
    timer's next call), and under rclpy's the time source's ``/clock`` subscription, made when the node
    is constructed, often never delivers when the clock was already running before the node spun: 7
    controllers of 12 that joined a running lockstep simulator read time 0 for good and refused every
    state as "in the future". A node class that sets ``KEEPS_ITS_OWN_SIMULATED_TIME`` (the controller
    and the identifier: they read ``/clock`` on a subscription of their own, nodes/clock.py
    ``NodeTime``) and has no timer on ROS time spins on the EventsExecutor anyway.

    Under the EventsExecutor an exception that escapes a callback is logged by rclpy at FATAL, with
    its traceback, before it reaches ``run_node``; it ignores callback groups (one thread anyway).
    """
    choice = os.environ.get(EXECUTOR_ENV) or EXECUTORS[0]
    if choice not in EXECUTORS:
        print(f"{EXECUTOR_ENV}={choice!r} is none of {', '.join(EXECUTORS)}: using events", file=sys.stderr)
        choice = EXECUTORS[0]
    spun = [] if node is None else _with_members(node)
    if choice == "events" and not any(list(n.guards) or _needs_the_time_source(n) for n in spun):
        try:
            from rclpy.experimental import EventsExecutor

            return EventsExecutor(context=context)
        except (ImportError, AttributeError, ValueError, io.UnsupportedOperation):
            pass
    return SingleThreadedExecutor(context=context)


def _needs_the_time_source(node: Node) -> bool:
    """Whether ``node`` on simulated time relies on rclpy's time source or timers (make_executor)."""
    if not node.get_parameter("use_sim_time").value:
        return False
    return not getattr(node, "KEEPS_ITS_OWN_SIMULATED_TIME", False) or any(
        timer.clock.clock_type == ClockType.ROS_TIME for timer in node.timers
    )


def spin(executor: Executor, context: Context, stop: threading.Event | None = None) -> None:
    """Spin until the context is shut down or ``stop`` is set (a callback's exception propagates).

    The single-threaded executor spins as rclpy does: rclpy's signal handler shuts the context down,
    in C, even in the middle of a callback (whose publish then fails; ``run_node`` ignores that).

    The EventsExecutor of the rclpy 7.1 wheels must not be spun with ``spin()``: that waits for its
    queue with a deadline of ``steady_clock::time_point::max()``, which the wheels' libstdc++ (built
    without ``pthread_cond_clockwait``) converts to the system clock with an overflow, so the wait
    never blocks (a core at 100 %); and a context shut down by rclpy's signal handler (in C, without
    the Python callback that would wake it) does not end it, so Ctrl-C would not stop the node.
    ``spin_once`` with a finite timeout waits correctly and returns after one event: it is called (a
    timeout of ``SPIN_SLICE_S``) until the context is shut down or ``stop`` is set; then the context is
    shut down. (``spin_until_future_complete`` with a timeout would not do: it checks its deadline only
    when the queue is empty, which in lockstep it never is, so it would never return.) ``run_node``
    has SIGINT and SIGTERM set ``stop`` (``_signals_set``), so that a signal ends the spin between two
    callbacks: rclpy's own handler would shut the context down in the middle of one, and the
    EventsExecutor logs the failing publish that follows as a FATAL error with its traceback.
    """
    if isinstance(executor, SingleThreadedExecutor):
        executor.spin()
        return
    stop = stop or threading.Event()
    # context.ok() takes a lock and a call into C (about 1 us) and a control period has several events:
    # it is asked at most every SPIN_SLICE_S / 2 instead of after each one.
    next_check_s = 0.0
    try:
        while not stop.is_set():
            now_s = time.monotonic()
            if now_s >= next_check_s:
                if not context.ok():
                    break
                next_check_s = now_s + SPIN_SLICE_S / 2
            executor.spin_once(timeout_sec=SPIN_SLICE_S)
    finally:
        if stop.is_set():
            context.try_shutdown()


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def _signals_set(stop: threading.Event) -> Iterator[None]:
    """SIGINT and SIGTERM set ``stop`` while inside (Python handlers in place of rclpy's).

    Outside the main thread (where Python cannot set handlers) nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {number: signal.signal(number, lambda *_: stop.set()) for number in STOP_SIGNALS}
    try:
        yield
    finally:
        # rclpy's handler was installed from C (getsignal gives None): Python's defaults take its place.
        defaults: dict[int, Any] = {signal.SIGINT: signal.default_int_handler, signal.SIGTERM: signal.SIG_DFL}
        for number, handler in previous.items():
            signal.signal(number, defaults[number] if handler is None else handler)


PROFILE_ENV = "MULTIROTOR_ROS_PROFILE"


@contextmanager
def _profiled(node: Node) -> Iterator[None]:
    """With ``$MULTIROTOR_ROS_PROFILE`` set to a directory: a cProfile of the spin, written there on exit.

    The file is ``<node name>-<pid>.prof`` (read it with ``python -m pstats``). The call counts are exact;
    the times are wall time (Python 3.12's cProfile watches every thread, so a per-thread CPU clock
    would mix threads up): a function in which the process is preempted, typically ``publish`` waking
    the receiving process on a busy machine, is charged for the wait. Profiling slows Python down.
    Callbacks that the EventsExecutor calls from C++ are not counted reliably (functions they call are):
    for CPU time per function, ``perf record --call-graph dwarf`` with ``PYTHONPERFSUPPORT=1`` is better.
    """
    directory = os.environ.get(PROFILE_ENV)
    if not directory:
        yield
        return
    import cProfile

    profile = cProfile.Profile()
    profile.enable()
    try:
        yield
    finally:
        profile.disable()
        Path(directory).mkdir(parents=True, exist_ok=True)
        profile.dump_stats(Path(directory) / f"{node.get_name()}-{os.getpid()}.prof")


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
