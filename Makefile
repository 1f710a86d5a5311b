# Two commands for people:
#   make demo   the whole loop (simulator, controller, identifier) flying and diagnosing a fault
#   make test   the test suite, including the gates: ruff check (test/test_packaging.py), ruff format
#               (test/test_formatting.py), mypy (test/test_typing.py, mypy.ini), the README examples run as
#               tests (test/test_readme_examples.py)
# Both first run scripts/bootstrap.sh, which builds .venv on first use and again only after
# setup.py, setup.cfg, package.xml or the bootstrap scripts change.
# PYTEST_ARGS passes options to pytest, e.g. `make test PYTEST_ARGS='-k packaging'`.

VENV := .venv
PYTEST_ARGS ?=

# The ROS wheels do not set AMENT_PREFIX_PATH; the venv holds this package's ament layout.
export AMENT_PREFIX_PATH := $(abspath $(VENV))$(if $(AMENT_PREFIX_PATH),:$(AMENT_PREFIX_PATH))

.PHONY: demo test venv

demo: venv
	$(VENV)/bin/multirotor demo

test: venv
	$(VENV)/bin/python -m pytest $(PYTEST_ARGS)

venv:
	@bash scripts/bootstrap.sh --if-needed
