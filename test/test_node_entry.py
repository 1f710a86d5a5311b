"""The node entry point: executors, signals, simulated time, parameters, and a node that does not stop.

Each case runs in a fresh interpreter: ``run_node`` installs signal handlers, and the EventsExecutor
enables ``faulthandler``, neither of which should leak into the test process.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from multirotor_ros.nodes.entry import EXECUTOR_ENV, PROFILE_ENV, STOP_GRACE_S

EXECUTORS = ("events", "single")


def run_after_shutdown(then: str) -> tuple[subprocess.CompletedProcess[str], float]:
    """Shut a watched context down, then run ``then`` (Python lines) in a fresh interpreter."""
    script = textwrap.dedent(
        """
        import threading, time
        import rclpy
        from rclpy.context import Context
        from multirotor_ros.nodes.entry import _watch_for_shutdown

        finished = threading.Event()
        context = Context()
        rclpy.init(context=context)
        _watch_for_shutdown(context, finished)
        context.shutdown()
        """
    ) + textwrap.dedent(then)
    start = time.monotonic()
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    return done, time.monotonic() - start


def test_a_process_stuck_after_shutdown_is_ended_with_its_stacks() -> None:
    done, took = run_after_shutdown("time.sleep(60)  # a teardown that never returns\n")
    assert done.returncode == 0
    assert f"still running {STOP_GRACE_S:g} s after shutdown was requested" in done.stderr
    assert "File" in done.stderr and "line" in done.stderr  # the stuck thread's stack is shown
    assert STOP_GRACE_S <= took < STOP_GRACE_S + 20


def test_a_process_whose_node_ended_is_left_to_go_on() -> None:
    done, _ = run_after_shutdown(f"finished.set()\ntime.sleep({STOP_GRACE_S + 2})\nprint('went on')\n")
    assert done.returncode == 0 and "went on" in done.stdout, done.stderr


# ------------------------------------------------------------------ executors

# A node on simulated time (a 4 ms timer publishing its clock's time on ``tick``, a parameter whose
# values must be > 0) run by run_node in the main thread; a driver in a context of its own steps
# ``clock``, sets parameters through the node's services, then signals the process.
SIM_TIME_NODE = """
import json, os, signal, sys, threading, time
import rclpy
from builtin_interfaces.msg import Time
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock
from multirotor_ros.nodes.entry import make_executor, run_node

PERIOD_NS, STEPS, NS = 4_000_000, 200, f"/entry_test_{os.getpid()}"
result = {}


class Ticker(Node):
    def __init__(self, **kwargs):
        super().__init__("ticker", **kwargs)
        self.declare_parameter("gain", 1.0)
        self.add_on_set_parameters_callback(
            lambda ps: SetParametersResult(successful=all(p.value > 0 for p in ps), reason="must be > 0")
        )
        publisher = self.create_publisher(Time, "tick", 100)
        self.create_timer(PERIOD_NS / 1e9, lambda: publisher.publish(self.get_clock().now().to_msg()))
        result["executor"] = type(make_executor(self.context, self)).__name__


def drive():
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("driver", namespace=NS, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    ticks, ticked = [], threading.Event()

    def on_tick(message):
        ticks.append(message.sec * 10**9 + message.nanosec)
        ticked.set()

    node.create_subscription(Time, "tick", on_tick, 100)
    best_effort = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
    clock = node.create_publisher(Clock, "clock", best_effort)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    while clock.get_subscription_count() == 0 or node.count_publishers("tick") == 0:
        time.sleep(0.05)
    time.sleep(0.5)
    sent, now = [], [10**9]

    def step(dt, expect_tick=True):
        now[0] += dt
        sent.append(now[0])
        count = len(ticks)
        for _ in range(100 if expect_tick else 10):  # clock is best effort: send again until it ticks
            ticked.clear()
            clock.publish(Clock(clock=Time(sec=now[0] // 10**9, nanosec=now[0] % 10**9)))
            if ticked.wait(0.02) and len(ticks) > count:
                break

    for _ in range(STEPS):
        step(PERIOD_NS)
    step(3 * PERIOD_NS)  # three periods at once: one tick
    step(PERIOD_NS // 2, expect_tick=False)  # half a period: none
    step(PERIOD_NS // 2)
    time.sleep(0.2)
    result["ticks_are_the_whole_periods"] = ticks == [t for t in sent if t % PERIOD_NS == 0]
    result["ticks"] = len(ticks)
    set_parameters = node.create_client(SetParameters, NS + "/ticker/set_parameters")
    get_parameters = node.create_client(GetParameters, NS + "/ticker/get_parameters")
    assert set_parameters.wait_for_service(10.0) and get_parameters.wait_for_service(10.0)
    answers = []
    for value in (2.5, -1.0):
        request = SetParameters.Request(parameters=[Parameter("gain", value=value).to_parameter_msg()])
        answers.append(set_parameters.call(request, timeout_sec=10.0).results[0])
    result["set"] = [[a.successful, a.reason] for a in answers]
    values = get_parameters.call(GetParameters.Request(names=["gain"]), timeout_sec=10.0).values
    result["gain"] = values[0].double_value
    executor.shutdown()
    spinner.join()
    node.destroy_node()
    context.try_shutdown()
    print(json.dumps(result), flush=True)  # what was measured, should the teardown after the signal hang
    result["signalled"] = time.monotonic()
    os.kill(os.getpid(), getattr(signal, sys.argv[1]))


threading.Thread(target=drive, daemon=True).start()
arguments = ["--ros-args", "-r", f"__ns:={NS}", "-r", f"/clock:={NS}/clock", "-p", "use_sim_time:=true"]
result["status"] = run_node(Ticker, ["ticker", *arguments])
result["stop_s"] = time.monotonic() - result.pop("signalled", float("nan"))
print(json.dumps(result))
"""

# ``case`` from argv: a node whose timer shuts the context down, raises, or signals its own process
# (whose teardown then hangs), that has a guard condition, or that is on simulated time and says it keeps
# that time itself, its timer on the steady clock (as the controller, which ticks from /clock).
EDGE_NODE = """
import os, signal, sys, time
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from multirotor_ros.nodes.entry import make_executor, run_node


class Edge(Node):
    def __init__(self, **kwargs):
        super().__init__("edge", **kwargs)
        if sys.argv[1] == "hang":
            self.create_timer(0.2, lambda: os.kill(os.getpid(), signal.SIGINT))
        elif sys.argv[1] == "raise":
            def boom():
                raise RuntimeError("boom in a timer")
            self.create_timer(0.05, boom)
        elif sys.argv[1] == "simulated":
            self.KEEPS_ITS_OWN_SIMULATED_TIME = True
            self.create_timer(0.05, self.context.shutdown, clock=Clock(clock_type=ClockType.STEADY_TIME))
        else:
            if sys.argv[1] == "guard":
                self.create_guard_condition(lambda: None)
            self.create_timer(0.05, self.context.shutdown)
        print("executor", type(make_executor(self.context, self)).__name__, flush=True)

    def destroy_node(self):
        if sys.argv[1] == "hang":
            time.sleep(60)  # a middleware teardown that never returns
        super().destroy_node()


start = time.monotonic()
simulated = ["--ros-args", "-p", "use_sim_time:=true"] if sys.argv[1] == "simulated" else []
status = run_node(Edge, ["edge", *simulated])
print(f"status {status} after {time.monotonic() - start:.2f} s", flush=True)
"""


def run_script(script: str, *argv: str, executor: str = "", **env: str) -> subprocess.CompletedProcess[str]:
    environment = {**os.environ, EXECUTOR_ENV: executor, **env}
    return subprocess.run(
        [sys.executable, "-c", script, *argv], capture_output=True, text=True, timeout=120, env=environment
    )


@pytest.mark.ros
@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"])
def test_a_node_on_simulated_time_ticks_once_per_clock_period_takes_parameters_and_stops_on_a_signal(
    signal_name: str,
) -> None:
    done = run_script(SIM_TIME_NODE, signal_name, executor="events")
    assert done.returncode == 0 and done.stdout.strip(), done.stderr[-3000:]
    result = json.loads(done.stdout.splitlines()[-1])
    # Asked for the events executor, a node on simulated time gets the single-threaded one.
    assert result["executor"] == "SingleThreadedExecutor"
    # One tick per period of simulated time, at that time: none skipped, none repeated; a clock that
    # jumps three periods at once gives one tick, half a period none until the period is complete.
    assert result["ticks_are_the_whole_periods"] and result["ticks"] == 202, result
    assert result["set"] == [[True, ""], [False, "must be > 0"]] and result["gain"] == 2.5
    if "status" in result:
        assert result["status"] == 0 and result["stop_s"] < 2.0
    else:
        # The middleware's teardown hung after the signal (seen once in a clean-clone run): the process
        # was ended by run_node's shutdown watch, which is what it is for (see the tests above).
        assert f"still running {STOP_GRACE_S:g} s after shutdown was requested" in done.stderr, done.stderr
    assert "Error occurred" not in done.stderr and "FATAL" not in done.stderr, done.stderr[-3000:]


@pytest.mark.ros
@pytest.mark.parametrize("executor", EXECUTORS)
def test_a_shut_down_context_ends_the_spin(executor: str, tmp_path: Path) -> None:
    done = run_script(EDGE_NODE, "shutdown", executor=executor, **{PROFILE_ENV: str(tmp_path)})
    assert done.returncode == 0 and "status 0" in done.stdout, done.stderr[-3000:]
    assert [p.name.split("-")[0] for p in tmp_path.glob("*.prof")] == ["edge"]  # the profile hook


@pytest.mark.ros
@pytest.mark.parametrize("executor", EXECUTORS)
def test_an_exception_in_a_callback_ends_the_node_with_its_traceback(executor: str) -> None:
    done = run_script(EDGE_NODE, "raise", executor=executor)
    assert done.returncode == 1 and "RuntimeError: boom in a timer" in done.stderr, done.stderr[-3000:]


@pytest.mark.ros
def test_events_is_the_default_and_a_node_with_guards_gets_the_other_unless_it_keeps_its_own_time() -> None:
    assert "executor EventsExecutor" in run_script(EDGE_NODE, "shutdown").stdout
    done = run_script(EDGE_NODE, "guard", executor="events")
    assert done.returncode == 0 and "executor SingleThreadedExecutor" in done.stdout, done.stderr[-3000:]
    done = run_script(EDGE_NODE, "simulated", executor="events")
    assert done.returncode == 0 and "executor EventsExecutor" in done.stdout, done.stderr[-3000:]
    done = run_script(EDGE_NODE, "shutdown", executor="fastest")
    assert done.returncode == 0 and "executor EventsExecutor" in done.stdout
    assert f"{EXECUTOR_ENV}='fastest' is none of events, single" in done.stderr


@pytest.mark.ros
@pytest.mark.parametrize("executor", EXECUTORS)
def test_a_node_whose_teardown_hangs_after_a_signal_is_ended_by_the_watchdog(executor: str) -> None:
    start = time.monotonic()
    done = run_script(EDGE_NODE, "hang", executor=executor)
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"still running {STOP_GRACE_S:g} s after shutdown was requested" in done.stderr
    assert time.monotonic() - start < STOP_GRACE_S + 30
