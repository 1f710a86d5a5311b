"""The node entry point: a node that does not stop after shutdown is ended, with its stacks as evidence."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

from multirotor_ros.nodes.entry import STOP_GRACE_S


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
