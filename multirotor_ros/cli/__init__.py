"""The ``multirotor`` command line.

Each sub-command lives in its own module of this package and exposes three names:
``COMMAND`` (the word typed after ``multirotor``), ``HELP`` (one line), ``configure(parser)``
and ``run(args) -> int``. Modules are discovered, so adding a command touches no shared file.
Heavy imports (rclpy, scipy, matplotlib) belong inside ``run`` so that ``multirotor --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence
from types import ModuleType


class CommandError(Exception):
    """A user error: printed as one line on stderr, exit status 2, no traceback."""


def _command_modules() -> dict[str, ModuleType]:
    modules: dict[str, ModuleType] = {}
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        command = getattr(module, "COMMAND", None)
        if command is not None:
            modules[command] = module
    return dict(sorted(modules.items()))


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every discovered sub-command."""
    parser = argparse.ArgumentParser(
        prog="multirotor",
        description="Simulate, control, identify and diagnose multirotors (ROS 2 toolkit).",
    )
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command, module in _command_modules().items():
        sub = subparsers.add_parser(command, help=module.HELP, description=module.HELP)
        module.configure(sub)
        sub.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``multirotor`` console script; returns the exit status."""
    arguments = list(sys.argv[1:] if argv is None else argv)
    # `multirotor node NAME --ros-args ...` hands everything after NAME to rclpy untouched.
    if len(arguments) >= 2 and arguments[0] == "node":
        from multirotor_ros.cli.node import run_node

        return run_node(arguments[1], arguments[2:])
    args = build_parser().parse_args(arguments)
    try:
        return int(args._run(args) or 0)
    except CommandError as error:
        print(f"multirotor {args.command}: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
