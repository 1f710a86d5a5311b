"""Test session set-up: DDS isolation first, then the ROS fixtures of ros_harness.

The environment is set at import time, before any test module imports rclpy, and the node processes
the tests start inherit it. A variable the caller already set is left alone, so a run can be pinned
to a domain with ``ROS_DOMAIN_ID=42 make test``.
"""

import os
import random
import shutil
import sys
import tempfile
from pathlib import Path

# Concurrent test sessions (two developers, CI) on one machine must not hear each other's nodes.
os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 200)))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
_OWN_LOG_DIR = "ROS_LOG_DIR" not in os.environ
if _OWN_LOG_DIR:
    os.environ["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="multirotor_ros_test_ros_logs_")

# A venv made by scripts/bootstrap.sh holds the package's ament layout; the ROS wheels do not put the
# venv on AMENT_PREFIX_PATH, and a plain `python -m pytest` should find the package as `make test` does.
_PREFIX_MARKER = Path(sys.prefix, "share", "ament_index", "resource_index", "packages", "multirotor_ros")
_AMENT_PATH = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
if _PREFIX_MARKER.is_file() and sys.prefix not in _AMENT_PATH:
    os.environ["AMENT_PREFIX_PATH"] = os.pathsep.join([sys.prefix, *_AMENT_PATH])

from ros_harness import rclpy_context, ros_probe, start_node  # noqa: E402, F401  (fixtures, registered by import)


def pytest_report_header() -> list[str]:
    """Say which isolated DDS domain this session uses, to find its traffic or rerun with it."""
    return [
        f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} "
        f"ROS_AUTOMATIC_DISCOVERY_RANGE={os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']} "
        f"ROS_LOG_DIR={os.environ['ROS_LOG_DIR']}"
    ]


def pytest_unconfigure() -> None:
    """Remove the ROS log directory this session made (node output is kept in each test's tmp_path)."""
    if _OWN_LOG_DIR:
        shutil.rmtree(os.environ["ROS_LOG_DIR"], ignore_errors=True)
