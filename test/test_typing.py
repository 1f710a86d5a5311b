"""The package type-checks: mypy with mypy.ini, whose only exemptions are untyped third-party modules.

A test rather than a Makefile step, for the reason test_formatting.py gives: `make test` runs this gate.
"""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

REPOSITORY = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_mypy_finds_nothing(tmp_path: Path) -> None:
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed (it is in the test extras: pip install -e '.[test]')")
    # A cache of its own: runs started together must not write one cache at once.
    command = [sys.executable, "-m", "mypy", "--config-file", "mypy.ini", "--cache-dir", str(tmp_path)]
    result = subprocess.run(command + ["multirotor_ros"], cwd=REPOSITORY, capture_output=True, text=True)
    if result.returncode != 0:
        pytest.fail(
            "mypy errors (run `.venv/bin/mypy` in the repository):\n" + result.stdout[-8000:] + result.stderr,
            pytrace=False,
        )
