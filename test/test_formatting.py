"""The code is as `ruff format` writes it (ruff.toml); test_packaging.py runs `ruff check` on the same paths.

A test rather than a Makefile step, so that `make test PYTEST_ARGS=...` still runs the tests asked for
while a file elsewhere waits to be formatted; the whole suite, as CI runs it, includes this gate.
"""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

REPOSITORY = Path(__file__).resolve().parent.parent
CHECKED_PATHS = ("multirotor_ros", "test", "bench", "scripts", "setup.py", "launch")


def test_ruff_format_finds_nothing() -> None:
    if importlib.util.find_spec("ruff") is None:
        pytest.skip("ruff is not installed (it is in the test extras: pip install -e '.[test]')")
    paths = [p for p in CHECKED_PATHS if (REPOSITORY / p).exists()]
    result = subprocess.run(
        [sys.executable, "-m", "ruff", "format", "--check", "--diff", "--no-cache", *paths],
        cwd=REPOSITORY,
        capture_output=True,
        text=True,
    )
    if result.returncode != 0:
        pytest.fail(
            "files that `ruff format` would change (run `.venv/bin/ruff format <file>`):\n"
            + result.stderr[-2000:]
            + result.stdout[-6000:],
            pytrace=False,
        )
