"""Topic-level test harness: run the package's nodes as processes and watch them from the test.

The fixtures are registered in ``test/conftest.py``, which also isolates the session's DDS traffic
(random ROS_DOMAIN_ID, localhost-only discovery) before anything imports rclpy. Mark such tests
``@pytest.mark.ros``.

Fixtures
    ``start_node(name, *, namespace=None, parameters=None, remaps=None, ros_args=())``
        Start ``python -m multirotor_ros.cli node NAME --ros-args ...`` and return its
        :class:`NodeProcess`; its output goes to ``tmp_path/NAME-<n>.log``. At teardown every node
        still running gets SIGINT and must exit with status 0 (else the teardown fails with the log).
    ``ros_probe``
        A :class:`RosProbe`: an rclpy node in its own context, spun by a background thread.

:class:`RosProbe`
    ``subscribe(topic, msg_type, qos=10, read=None, lockstep_progress=None) -> Recorder`` (``read``: what to
    keep of each serialised message; ``lockstep_progress``: the probe follows a lockstep simulator and
    loses nothing); ``publisher(topic, msg_type, qos=10)``;
    ``wait_for_subscribers(publisher, count=1, timeout=10.0)``; ``wait_for_node(fqn, timeout=10.0)``;
    ``set_parameters(node_fqn, {name: value}, timeout=10.0) -> {name: SetParametersResult}``
    (``.successful``, ``.reason``; the Python type picks the ROS type: pass 2.0 for a double);
    ``get_parameters(node_fqn, [names], timeout=10.0) -> {name: value}`` (None for a declared parameter
    without a value; a name that is not declared fails the test).
    Topic names are resolved in the root namespace: write ``/uav1/odom`` for a namespaced node.
    Publishers of sensor data often use best-effort QoS; subscribe with
    ``rclpy.qos.qos_profile_sensor_data`` to those.

:class:`Recorder`
    ``messages`` (a snapshot list), ``wait_for(predicate=None, count=1, timeout=10.0)`` returns the
    messages received so far that satisfy ``predicate`` once there are ``count`` of them, or fails the
    test on timeout saying how many arrived and how many publishers were seen; ``clear()``.

:class:`CpuHog`
    Context manager: one busy-looping process per core (``processes`` to choose), each ending by itself
    after ``max_seconds`` even if the test dies, all killed on exit: a machine as loaded as a user's.

:class:`NodeProcess` (and its base :class:`ManagedProcess`, for any command)
    Context manager; ``stop(timeout=10.0, check=True) -> int`` sends SIGINT, waits, fails the test
    with the log's tail if the exit status is not 0 or the process does not end; ``log_text()``;
    ``running``; ``assert_running()``.

Example::

    @pytest.mark.ros
    def test_simulator_publishes_odometry(start_node, ros_probe):
        odom = ros_probe.subscribe("/uav1/odom", Odometry)
        start_node("simulator", namespace="/uav1", parameters={"real_time_factor": 0.0})
        odom.wait_for(count=5, timeout=20.0)
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from itertools import count as counter
from pathlib import Path
from typing import Any

import pytest
import yaml

LOG_TAIL_LINES = 40


def format_parameter(value: Any) -> str:
    """A value as rcl parses it after ``-p name:=`` (YAML), keeping strings strings."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        # "42" or "true" would otherwise come back as a number or a bool.
        return value if yaml.safe_load(value) == value else json.dumps(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(format_parameter(item) for item in value) + "]"
    raise TypeError(f"parameter value {value!r} of type {type(value).__name__} has no ROS type")


def ros_arguments(
    namespace: str | None = None,
    parameters: Mapping[str, Any] | None = None,
    remaps: Mapping[str, str] | None = None,
    extra: Sequence[str] = (),
) -> list[str]:
    """``--ros-args`` and what follows it, for a namespace, parameters and remappings."""
    arguments = ["--ros-args"]
    if namespace is not None:
        arguments += ["-r", f"__ns:={namespace}"]
    for source, target in (remaps or {}).items():
        arguments += ["-r", f"{source}:={target}"]
    for name, value in (parameters or {}).items():
        arguments += ["-p", f"{name}:={format_parameter(value)}"]
    return arguments + list(extra)


class ManagedProcess:
    """A subprocess whose stdout and stderr go to a log file, stopped with SIGINT like Ctrl-C."""

    def __init__(self, argv: Sequence[str], log_path: Path, cwd: Path | None = None) -> None:
        self.argv = list(argv)
        self.log_path = log_path
        log_path.parent.mkdir(parents=True, exist_ok=True)
        environment = dict(os.environ, PYTHONUNBUFFERED="1", RCUTILS_COLORIZED_OUTPUT="0")
        with open(log_path, "wb") as log:
            self.process = subprocess.Popen(
                self.argv,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                cwd=cwd or log_path.parent,
                env=environment,
            )

    @property
    def running(self) -> bool:
        """Whether the process has not exited yet."""
        return self.process.poll() is None

    def log_text(self) -> str:
        """Everything the process printed so far."""
        return self.log_path.read_text(encoding="utf-8", errors="replace")

    def wait_for_log(self, text: str, timeout: float) -> str:
        """The log once it holds ``text``; after ``timeout`` s without it, the log as it is."""
        deadline = time.monotonic() + timeout
        while text not in (log := self.log_text()) and time.monotonic() < deadline:
            time.sleep(0.1)
        return log

    def log_tail(self, lines: int = LOG_TAIL_LINES) -> str:
        """The last lines of the log, for failure messages."""
        return "\n".join(self.log_text().splitlines()[-lines:])

    def describe(self) -> str:
        """The command line, shortened for messages."""
        return " ".join(self.argv)[:200]

    def assert_running(self) -> None:
        """Fail the test with the log if the process has already exited."""
        status = self.process.poll()
        if status is not None:
            raise AssertionError(
                f"{self.describe()} exited early with status {status}; "
                f"log {self.log_path}:\n{self.log_tail()}"
            )

    def stop(self, timeout: float = 10.0, check: bool = True) -> int:
        """Send SIGINT, wait up to ``timeout`` s and return the exit status (asserted 0 if ``check``)."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                # Its stacks into the log first (nodes register faulthandler on SIGUSR1): where it is stuck.
                self.process.send_signal(signal.SIGUSR1)
                time.sleep(1.0)
                self.process.kill()
                self.process.wait()
                raise AssertionError(
                    f"{self.describe()} still ran {timeout} s after SIGINT and was killed; "
                    f"log {self.log_path}:\n{self.log_tail()}"
                ) from None
        status = self.process.returncode
        if check and status != 0:
            raise AssertionError(
                f"{self.describe()} exited with status {status}; log {self.log_path}:\n{self.log_tail()}"
            )
        return status

    def __enter__(self) -> ManagedProcess:
        return self

    def __exit__(self, exc_type: object, exc: object, traceback: object) -> None:
        # When the body failed, that failure is the news: stop without adding a second one.
        self.stop(check=exc_type is None)


class NodeProcess(ManagedProcess):
    """One of the package's executables, run as ``python -m multirotor_ros.cli node NAME``."""

    def __init__(
        self,
        name: str,
        log_path: Path,
        *,
        namespace: str | None = None,
        parameters: Mapping[str, Any] | None = None,
        remaps: Mapping[str, str] | None = None,
        ros_args: Sequence[str] = (),
    ) -> None:
        self.name = name
        argv = [sys.executable, "-m", "multirotor_ros.cli", "node", name]
        super().__init__(argv + ros_arguments(namespace, parameters, remaps, ros_args), log_path)


class CpuHog:
    """Busy-loop processes beside a test (see the module docstring)."""

    def __init__(self, processes: int | None = None, max_seconds: float = 1800.0) -> None:
        self.count = processes or os.cpu_count() or 1
        self.max_seconds = max_seconds
        self._processes: list[subprocess.Popen] = []

    def __enter__(self) -> CpuHog:
        loop = f"import time\nend = time.monotonic() + {self.max_seconds}\nwhile time.monotonic() < end: pass"
        self._processes = [
            subprocess.Popen([sys.executable, "-S", "-c", loop], stdin=subprocess.DEVNULL)
            for _ in range(self.count)
        ]
        return self

    def __exit__(self, *_: object) -> None:
        for process in self._processes:
            process.kill()
        for process in self._processes:
            process.wait()


class Recorder:
    """The messages one subscription of the probe received, safe to read from the test thread."""

    def __init__(self, topic: str, count_publishers: Callable[[], int]) -> None:
        self.topic = topic
        self._count_publishers = count_publishers
        self._messages: list[Any] = []
        self._condition = threading.Condition()

    def _receive(self, message: Any) -> None:
        with self._condition:
            self._messages.append(message)
            self._condition.notify_all()

    @property
    def messages(self) -> list[Any]:
        """A snapshot of the messages received so far, oldest first."""
        with self._condition:
            return list(self._messages)

    def clear(self) -> None:
        """Forget the messages received so far."""
        with self._condition:
            self._messages.clear()

    def wait_for(
        self, predicate: Callable[[Any], bool] | None = None, count: int = 1, timeout: float = 10.0
    ) -> list[Any]:
        """Wait until ``count`` received messages satisfy ``predicate``; return all that do.

        Each wake-up tests only the messages that arrived since the last: rescanning all of them held the
        lock the spinning thread needs for every new message, and a lockstep burst of thousands then
        starved it until the publishers' bounded histories dropped states.
        """
        matching: list[Any] = []
        tested = 0

        def enough() -> bool:
            nonlocal tested
            matching.extend(m for m in self._messages[tested:] if predicate is None or predicate(m))
            tested = len(self._messages)
            return len(matching) >= count

        with self._condition:
            if self._condition.wait_for(enough, timeout):
                return matching
            total = len(self._messages)
            last = repr(self._messages[-1])[:600] if self._messages else "none"
        raise AssertionError(
            f"{self.topic}: {len(matching)} of the {count} wanted messages within {timeout} s "
            f"({total} received in all, {self._count_publishers()} publishers seen; the last: {last})"
        )


class RosProbe:
    """An rclpy node in a context of its own, spinning in a background thread."""

    _instances = counter(1)

    def __init__(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self._rclpy = rclpy
        self.context = rclpy.Context()
        # args: rcl would otherwise parse pytest's command line for --ros-args.
        rclpy.init(args=["ros_probe"], context=self.context)
        self.node = rclpy.create_node(
            f"test_probe_{os.getpid()}_{next(self._instances)}", context=self.context
        )
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients: dict[tuple[type, str], Any] = {}
        self._thread = threading.Thread(target=self._spin, name="ros_probe", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def close(self) -> None:
        """Stop spinning and shut the context down."""
        self.executor.shutdown()
        self._thread.join(timeout=10.0)
        self.node.destroy_node()
        self.context.try_shutdown()

    def subscribe(
        self,
        topic: str,
        msg_type: type,
        qos: Any = 10,
        read: Callable[[bytes], Any] | None = None,
        lockstep_progress: str | None = None,
    ) -> Recorder:
        """Record every message on ``topic``; with ``read``, what it reads of each serialised message.

        A lockstep loop publishes faster than this process takes typed messages (an Odometry costs about
        45 us to convert), and the writer's history is bounded: ``read`` keeps up (nodes/cdr.py).

        ``lockstep_progress`` makes the probe a lockstep follower of the simulator (its
        ``lockstep_followers`` parameter names the same topic): after each message it publishes a
        std_msgs/Header stamped with the message's ``stamp_ns`` (what ``read`` gives) on that topic, and a
        lockstep simulator runs at most 10 ms of simulated time ahead of it. Without it a probe that falls
        behind a lockstep burst loses the messages the publisher's bounded history drops (seen under load).
        """
        recorder = Recorder(topic, lambda: self.node.count_publishers(topic))
        if read is None:
            if lockstep_progress is not None:
                raise ValueError("lockstep_progress needs read (the stamp of each serialised message)")
            self.node.create_subscription(msg_type, topic, recorder._receive, qos)
            return recorder
        if lockstep_progress is None:

            def receive(data: bytes) -> None:
                recorder._receive(read(data))

        else:
            from std_msgs.msg import Header

            from multirotor_ros.nodes.messages import stamp_from_ns

            progress = self.node.create_publisher(Header, lockstep_progress, 10)

            def receive(data: bytes) -> None:
                fields = read(data)
                recorder._receive(fields)
                stamp_ns = getattr(fields, "stamp_ns", None)
                if stamp_ns is not None:  # a refusal (damaged bytes) has no stamp to report
                    progress.publish(Header(stamp=stamp_from_ns(stamp_ns)))

        self.node.create_subscription(msg_type, topic, receive, qos, raw=True)
        return recorder

    def publisher(self, topic: str, msg_type: type, qos: Any = 10) -> Any:
        """A publisher of the probe node."""
        return self.node.create_publisher(msg_type, topic, qos)

    def wait_for_subscribers(self, publisher: Any, count: int = 1, timeout: float = 10.0) -> None:
        """Wait until ``count`` subscriptions match ``publisher``, so a message is not lost to discovery."""
        self._poll(
            lambda: publisher.get_subscription_count() >= count,
            timeout,
            lambda: f"{publisher.topic_name}: {publisher.get_subscription_count()} of {count} subscribers",
        )

    def wait_for_node(self, fully_qualified_name: str, timeout: float = 10.0) -> None:
        """Wait until a node, e.g. ``/uav1/simulator``, is in the ROS graph."""
        namespace, _, name = fully_qualified_name.rpartition("/")
        wanted = (name, namespace or "/")
        self._poll(
            lambda: wanted in self.node.get_node_names_and_namespaces(),
            timeout,
            lambda: (
                f"node {fully_qualified_name} not in the graph; nodes seen: "
                + ", ".join(f"{ns.rstrip('/')}/{n}" for n, ns in self.node.get_node_names_and_namespaces())
            ),
        )

    def set_parameters(
        self, node_fqn: str, values: Mapping[str, Any], timeout: float = 10.0
    ) -> dict[str, Any]:
        """Set parameters of another node as ``ros2 param set`` does; return each name's result."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        request = SetParameters.Request()
        request.parameters = [
            Parameter(name, value=value).to_parameter_msg() for name, value in values.items()
        ]
        response = self._call(SetParameters, f"{node_fqn}/set_parameters", request, timeout)
        return dict(zip(values, response.results, strict=True))

    def get_parameters(self, node_fqn: str, names: Sequence[str], timeout: float = 10.0) -> dict[str, Any]:
        """Get declared parameters of another node as Python values (None for one without a value)."""
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python

        request = GetParameters.Request()
        request.names = list(names)
        response = self._call(GetParameters, f"{node_fqn}/get_parameters", request, timeout)
        if len(response.values) != len(request.names):
            # rclpy and rclcpp answer with no values at all when any name is not declared.
            raise AssertionError(
                f"{node_fqn} returned no values for {list(names)}: one of them is not declared"
            )
        return {
            name: parameter_value_to_python(value) for name, value in zip(names, response.values, strict=True)
        }

    def _call(self, service_type: type, service: str, request: Any, timeout: float) -> Any:
        key = (service_type, service)
        if key not in self._clients:
            self._clients[key] = self.node.create_client(service_type, service)
        client = self._clients[key]
        deadline = time.monotonic() + timeout
        if not client.wait_for_service(timeout_sec=timeout):
            raise AssertionError(f"service {service} not available within {timeout} s")
        done = threading.Event()
        future = client.call_async(request)
        future.add_done_callback(lambda _: done.set())
        if not done.wait(max(0.0, deadline - time.monotonic())):
            raise AssertionError(f"service {service} did not answer within {timeout} s")
        return future.result()

    @staticmethod
    def _poll(condition: Callable[[], bool], timeout: float, explain: Callable[[], str]) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(f"after {timeout} s: {explain()}")
            time.sleep(0.05)


@pytest.fixture
def rclpy_context() -> Iterator[Any]:
    """An rclpy context of its own for nodes built in the test's process (shut down at teardown)."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    yield context
    context.try_shutdown()


def spin_until(context: Any, nodes: Sequence[Any], done: Callable[[], bool], timeout_s: float = 20.0) -> None:
    """Spin ``nodes`` of ``context`` (made in this process) until ``done()``, at most ``timeout_s`` [s]."""
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=context)
    for node in nodes:
        executor.add_node(node)
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    executor.shutdown()


@pytest.fixture
def ros_probe() -> Iterator[RosProbe]:
    """An in-process ROS node to subscribe, publish and call parameter services with."""
    probe = RosProbe()
    try:
        yield probe
    finally:
        probe.close()


@pytest.fixture
def start_node(tmp_path: Path) -> Iterator[Callable[..., NodeProcess]]:
    """Factory starting package executables; all are stopped (and must exit 0) at teardown."""
    started: list[NodeProcess] = []

    def start(name: str, **options: Any) -> NodeProcess:
        process = NodeProcess(name, tmp_path / f"{name}-{len(started) + 1}.log", **options)
        started.append(process)
        return process

    yield start
    failures = []
    for process in started:
        try:
            process.stop()
        except AssertionError as error:
            failures.append(str(error))
    if failures:
        raise AssertionError("\n\n".join(failures))
