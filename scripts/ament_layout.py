#!/usr/bin/env python3
"""The ament layout of an install prefix: what ``ros2 run multirotor_ros NAME`` looks for.

``ros2 run`` finds a package by its marker ``<prefix>/share/ament_index/resource_index/packages/
multirotor_ros`` on AMENT_PREFIX_PATH and runs the executable file ``<prefix>/lib/multirotor_ros/NAME``.
The console scripts carry the package's prefix, ``multirotor-NAME`` (:func:`console_script_name`), so
that a pip install puts no generic name (``simulator``) on PATH; ``lib/multirotor_ros/NAME`` is then a
small launcher (:func:`launcher_text`) that hands over to ``multirotor-NAME`` of the same install. It is
written in every kind of install:

- a wheel (``pip install .``): ``setup.py`` calls :func:`write_launchers` while building it and ships
  the launchers as data_files, so they land in ``<prefix>/lib/multirotor_ros`` with the marker and
  ``share/multirotor_ros``; the console scripts go to ``<prefix>/bin``;
- colcon (``setup.py install`` or, with ``--symlink-install``, ``develop``): setup.cfg puts the console
  scripts in ``<prefix>/lib/multirotor_ros`` and ``setup.py`` writes the launchers beside them
  (:func:`is_ros_run_directory`);
- the editable venv: ``scripts/bootstrap.sh`` runs this file after ``pip install -e``, which installs no
  data_files at all: ``python scripts/ament_layout.py PREFIX`` creates the marker, links
  ``share/multirotor_ros`` to the repository's package.xml, config/, launch/ and rviz/, and writes the
  launchers.

Standard library only: it runs inside setuptools' isolated build environment.
"""

from __future__ import annotations

import argparse
import ast
import os
import sys
from pathlib import Path

PACKAGE = "multirotor_ros"
REPOSITORY = Path(__file__).resolve().parent.parent

# POSIX sh rather than python: the console script pip wrote into <prefix>/bin already names the right
# interpreter in its shebang, whereas `#!/usr/bin/env python3` would pick whatever python3 is first on
# PATH when `ros2 run` is called from a shell where the venv is not activated.
LAUNCHER_TEMPLATE = """\
#!/bin/sh
# `ros2 run {package} {name}` runs this file, installed as <prefix>/lib/{package}/{name}.
# It hands over to the console script {script} of the same install: beside this file after colcon
# (setup.cfg puts the console scripts in lib/{package}), in <prefix>/bin after pip.
here=$(dirname -- "$0")
for script in "$here/{script}" "$here/../../bin/{script}"; do
    if [ -x "$script" ]; then
        exec "$script" "$@"
    fi
done
exec python3 -m {package}.cli node {name} "$@"
"""


def node_executables(repository: Path = REPOSITORY) -> tuple[str, ...]:
    """NODE_EXECUTABLES of ``multirotor_ros/cli/node.py``, read without importing the package."""
    path = repository / PACKAGE / "cli" / "node.py"
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for statement in tree.body:
        if isinstance(statement, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "NODE_EXECUTABLES" for t in statement.targets
        ):
            names = ast.literal_eval(statement.value)
            if isinstance(names, tuple) and names and all(isinstance(n, str) for n in names):
                return names
            raise ValueError(f"{path}:{statement.lineno}: NODE_EXECUTABLES must be a tuple of strings")
    raise ValueError(f"{path}: no NODE_EXECUTABLES = (...) assignment at module level")


def console_script_name(name: str) -> str:
    """The console script of executable ``name``: ``mavlink_bridge`` -> ``multirotor-mavlink-bridge``."""
    return "multirotor-" + name.replace("_", "-")


def launcher_text(name: str) -> str:
    """The launcher script for executable ``name``."""
    return LAUNCHER_TEMPLATE.format(package=PACKAGE, name=name, script=console_script_name(name))


def is_ros_run_directory(directory: Path) -> bool:
    """Whether ``directory`` is ``<prefix>/lib/multirotor_ros``, where ``ros2 run`` looks."""
    return directory.name == PACKAGE and directory.parent.name == "lib"


def write_launchers(directory: Path, names: tuple[str, ...]) -> list[Path]:
    """Write one executable launcher per name into ``directory``; return their paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in names:
        path = directory / name
        if path.is_symlink():
            path.unlink()
        path.write_text(launcher_text(name), encoding="utf-8")
        path.chmod(0o755)
        paths.append(path)
    return paths


def _replace_with_symlink(link: Path, target: Path) -> None:
    if link.is_symlink() or link.is_file():
        link.unlink()
    elif link.exists():
        raise FileExistsError(f"{link} exists and is not a symlink; remove it to refresh the ament layout")
    link.symlink_to(target)


def make_editable_layout(prefix: Path, repository: Path = REPOSITORY) -> None:
    """Give ``prefix`` the ament layout, pointing back at the repository's files."""
    marker = prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.touch()
    share = prefix / "share" / PACKAGE
    share.mkdir(parents=True, exist_ok=True)
    # Links, not copies, so that a new airframe YAML or launch file is visible without re-bootstrapping.
    _replace_with_symlink(share / "package.xml", repository / "package.xml")
    for directory in ("config", "launch", "rviz"):
        _replace_with_symlink(share / directory, repository / directory)
    write_launchers(prefix / "lib" / PACKAGE, node_executables(repository))


def main(argv: list[str] | None = None) -> int:
    """Command line: ``python scripts/ament_layout.py PREFIX``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("prefix", type=Path, help="install prefix, e.g. the virtual environment .venv")
    args = parser.parse_args(argv)
    if not args.prefix.is_dir():
        print(f"ament_layout: prefix {args.prefix} is not a directory", file=sys.stderr)
        return 2
    make_editable_layout(Path(os.path.abspath(args.prefix)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
