"""The package as ROS and pip see it: package.xml, dependencies, entry points, the ament layout, lint.

The wheel is built once per session from a copy of the files setup.py reads (so that concurrent runs
do not share a build/ directory) and inspected, not installed: ``pip install .`` puts its
``.data/data/`` entries under the install prefix, which is what ``ros2 run`` searches.
"""

import ast
import configparser
import importlib.metadata
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import pytest

import multirotor_ros
from multirotor_ros.cli.node import NODE_EXECUTABLES

REPOSITORY = Path(__file__).resolve().parent.parent
PACKAGE_DIR = REPOSITORY / "multirotor_ros"
# Only the ROS wrappers may import rclpy: nodes/, and cli/, whose commands start nodes.
ROS_WRAPPERS = ("nodes", "cli")
# rosdep keys of package.xml whose PyPI distribution has another name.
ROSDEP_TO_PYPI = {"python3-yaml": "pyyaml"}


def _load_ament_layout():
    spec = importlib.util.spec_from_file_location("ament_layout", REPOSITORY / "scripts" / "ament_layout.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


ament_layout = _load_ament_layout()


def _manifest() -> ElementTree.Element:
    return ElementTree.parse(REPOSITORY / "package.xml").getroot()


def _exec_depends() -> set[str]:
    root = _manifest()
    return {e.text.strip() for tag in ("exec_depend", "depend") for e in root.iter(tag)}


def _python_files(*roots: Path) -> list[Path]:
    files = []
    for root in roots:
        files += [root] if root.is_file() else sorted(root.rglob("*.py"))
    return files


def _imports(path: Path) -> list[tuple[str, int]]:
    """Absolute module names imported anywhere in a file (also inside functions), with line numbers."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.module, node.lineno))
    return found


def _copy_sources(source: Path) -> Path:
    """The files setup.py reads, copied (concurrent runs must not share a build/ directory)."""
    source.mkdir(parents=True, exist_ok=True)
    for name in ("setup.py", "setup.cfg", "package.xml", "MANIFEST.in"):
        shutil.copy2(REPOSITORY / name, source / name)
    for name in ("resource", "config", "launch", "rviz", "scripts", "multirotor_ros"):
        if (REPOSITORY / name).is_dir():
            shutil.copytree(REPOSITORY / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
    return source


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> zipfile.ZipFile:
    source = _copy_sources(tmp_path_factory.mktemp("wheel_source"))
    out = tmp_path_factory.mktemp("wheel")
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(out),
            str(source),
        ],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert result.returncode == 0, f"pip wheel failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    (path,) = out.glob("multirotor_ros-*.whl")
    with zipfile.ZipFile(path) as archive:
        yield archive


def _wheel_data(wheel: zipfile.ZipFile) -> dict[str, zipfile.ZipInfo]:
    """Entries that pip installs relative to the prefix, keyed by that relative path."""
    prefix = f"multirotor_ros-{multirotor_ros.__version__}.data/data/"
    return {i.filename.removeprefix(prefix): i for i in wheel.infolist() if i.filename.startswith(prefix)}


def _requires(wheel: zipfile.ZipFile) -> set[str]:
    """The distributions the wheel requires outside extras, normalised."""
    metadata = wheel.read(f"multirotor_ros-{multirotor_ros.__version__}.dist-info/METADATA").decode()
    names = set()
    for line in metadata.splitlines():
        if line.startswith("Requires-Dist:") and "extra ==" not in line:
            names.add(_normalise(re.split(r"[\s;<>=!~\[(]", line.removeprefix("Requires-Dist:").strip())[0]))
    return names


def _normalise(distribution: str) -> str:
    return re.sub(r"[-_.]+", "-", distribution).lower()


def test_package_xml_is_a_format_3_ament_python_manifest():
    root = _manifest()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == "multirotor_ros"
    assert root.findtext("version") == multirotor_ros.__version__ == "0.1.0"
    assert root.findtext("license") == "Apache-2.0"
    assert root.findtext("export/build_type") == "ament_python"
    assert root.find("maintainer").get("email")


def test_exec_depends_cover_the_ros_packages_the_code_imports():
    missing = []
    for path in _python_files(PACKAGE_DIR):
        for module, line in _imports(path):
            top, _, rest = module.partition(".")
            is_interface = rest.split(".")[0] in ("msg", "srv", "action")
            if (is_interface or top == "rclpy") and top not in _exec_depends():
                missing.append(f"{path.relative_to(REPOSITORY)}:{line}: {module}")
    assert not missing, "imported but not an <exec_depend> of package.xml:\n" + "\n".join(missing)


def test_third_party_imports_are_declared(wheel):
    """Every import the package makes resolves to the stdlib, ROS (package.xml) or install_requires."""
    requires = _requires(wheel)
    ros_packages = {d for d in _exec_depends() if not d.startswith("python3-")}
    providers = importlib.metadata.packages_distributions()
    undeclared = []
    for path in _python_files(PACKAGE_DIR):
        for module, line in _imports(path):
            top = module.split(".")[0]
            if top in sys.stdlib_module_names or top == "multirotor_ros" or top in ros_packages:
                continue
            distributions = {_normalise(d) for d in providers.get(top, [])}
            if not distributions & requires:
                undeclared.append(
                    f"{path.relative_to(REPOSITORY)}:{line}: {module} (from {distributions or '?'})"
                )
    assert not undeclared, (
        "imports that are not stdlib, a package.xml <exec_depend>, or in setup.py install_requires:\n"
        + "\n".join(undeclared)
    )


def test_python_exec_depends_are_also_install_requires(wheel):
    rosdep_keys = {d for d in _exec_depends() if d.startswith("python3-")}
    expected = {_normalise(ROSDEP_TO_PYPI.get(k, k.removeprefix("python3-"))) for k in rosdep_keys}
    assert expected <= _requires(wheel)


def test_wheel_console_scripts_are_the_node_executables_and_multirotor(wheel):
    entry_points = configparser.ConfigParser()
    entry_points.read_string(
        wheel.read(f"multirotor_ros-{multirotor_ros.__version__}.dist-info/entry_points.txt").decode()
    )
    # Every name the package puts on PATH carries its prefix: no `simulator` clashing with another package's.
    expected = {
        f"multirotor-{name.replace('_', '-')}": f"multirotor_ros.nodes.{name}:main"
        for name in NODE_EXECUTABLES
    }
    expected["multirotor"] = "multirotor_ros.cli:main"
    assert dict(entry_points["console_scripts"]) == expected


def test_wheel_installs_the_ament_layout_under_the_prefix(wheel):
    data = _wheel_data(wheel)
    assert "share/ament_index/resource_index/packages/multirotor_ros" in data
    assert wheel.read(data["share/multirotor_ros/package.xml"]) == (REPOSITORY / "package.xml").read_bytes()
    for directory, pattern in [
        ("config", "*.yaml"),
        ("config/missions", "*.csv"),
        ("launch", "*.py"),
        ("rviz", "*.rviz"),
    ]:
        shipped = {
            p
            for p in data
            if p.startswith(f"share/multirotor_ros/{directory}/")
            and "/" not in p.removeprefix(f"share/multirotor_ros/{directory}/")
        }
        assert shipped == {
            f"share/multirotor_ros/{directory}/{p.name}" for p in (REPOSITORY / directory).glob(pattern)
        }
    assert "share/multirotor_ros/config/missions/square.csv" in data
    launchers = {
        p.removeprefix("lib/multirotor_ros/"): i
        for p, i in data.items()
        if p.startswith("lib/multirotor_ros/")
    }
    assert set(launchers) == set(NODE_EXECUTABLES)
    for name, info in launchers.items():
        assert (info.external_attr >> 16) & 0o111 == 0o111, f"lib/multirotor_ros/{name} is not executable"
        assert wheel.read(info).decode() == ament_layout.launcher_text(name)
    assert "multirotor_ros/py.typed" in wheel.namelist()
    assert not [n for n in wheel.namelist() if n.startswith("test/")]


def test_colcon_installs_console_scripts_where_ros2_run_looks():
    config = configparser.ConfigParser(interpolation=None)
    config.read(REPOSITORY / "setup.cfg")
    assert config["install"]["install_scripts"] == "$base/lib/multirotor_ros"
    assert config["develop"]["script_dir"] == "$base/lib/multirotor_ros"
    assert (REPOSITORY / "resource" / "multirotor_ros").is_file()


def test_colcons_setup_py_install_puts_a_launcher_beside_each_prefixed_console_script(tmp_path):
    """The command colcon-core runs for `colcon build` (task/python/build.py), offline, into a prefix."""
    source = _copy_sources(tmp_path / "source")
    build, prefix = tmp_path / "build", tmp_path / "install"
    build.mkdir()
    result = subprocess.run(
        [
            sys.executable,
            "setup.py",
            "egg_info",
            "--egg-base",
            str(build),
            "build",
            "--build-base",
            str(build / "build"),
            "install",
            "--prefix",
            str(prefix),
            "--record",
            str(build / "install.log"),
            "--single-version-externally-managed",
        ],
        cwd=source,
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert result.returncode == 0, (
        f"setup.py install failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    )
    lib = prefix / "lib" / "multirotor_ros"
    scripts = {ament_layout.console_script_name(name) for name in NODE_EXECUTABLES}
    assert {p.name for p in lib.iterdir()} == set(NODE_EXECUTABLES) | scripts | {"multirotor"}
    assert not (prefix / "bin").exists()
    for name in NODE_EXECUTABLES:
        assert (lib / name).read_text() == ament_layout.launcher_text(name)
        assert (lib / name).stat().st_mode & 0o111 == 0o111
    recorded = set((build / "install.log").read_text().splitlines())
    assert {str(lib / name) for name in NODE_EXECUTABLES} <= recorded  # colcon removes what it recorded
    # `ros2 run multirotor_ros mission` runs this launcher: it reaches the node through multirotor-mission.
    missing = tmp_path / "no_such_mission.csv"
    (site_packages,) = prefix.glob("lib/python3*/site-packages")
    ran = subprocess.run(
        [str(lib / "mission"), "--ros-args", "-p", f"mission_file:={missing}"],
        capture_output=True,
        text=True,
        timeout=60,
        # What sourcing colcon's install/setup.bash does: the installed package first.
        env=dict(
            os.environ, PYTHONPATH=os.pathsep.join([str(site_packages), os.environ.get("PYTHONPATH", "")])
        ),
    )
    assert ran.returncode == 2 and f"{missing}: cannot read" in ran.stderr, ran.stderr[-2000:]


def test_editable_layout_lets_ament_find_package_and_executables(tmp_path, monkeypatch):
    ament_index = pytest.importorskip("ament_index_python")
    result = subprocess.run([sys.executable, str(REPOSITORY / "scripts" / "ament_layout.py"), str(tmp_path)])
    assert result.returncode == 0
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path))
    assert Path(ament_index.get_package_prefix("multirotor_ros")) == tmp_path
    share = Path(ament_index.get_package_share_directory("multirotor_ros"))
    assert (share / "package.xml").resolve() == REPOSITORY / "package.xml"
    for directory in ("config", "launch", "rviz"):
        assert (share / directory).resolve() == REPOSITORY / directory
    # ros2 run's rule: an executable file in <prefix>/lib/<package>.
    executables = {
        p.name for p in (tmp_path / "lib" / "multirotor_ros").iterdir() if p.stat().st_mode & 0o111
    }
    assert executables == set(NODE_EXECUTABLES)


@pytest.mark.parametrize("scripts_in", ["bin", "lib/multirotor_ros"], ids=["pip", "colcon"])
def test_launcher_hands_over_to_the_prefixed_console_script_of_its_install(tmp_path, scripts_in):
    (launcher,) = ament_layout.write_launchers(tmp_path / "lib" / "multirotor_ros", ("mavlink_bridge",))
    console_script = tmp_path / scripts_in / "multirotor-mavlink-bridge"
    console_script.parent.mkdir(parents=True, exist_ok=True)
    console_script.write_text('#!/bin/sh\necho "console script: $*"\n')
    console_script.chmod(0o755)
    result = subprocess.run(
        [str(launcher), "--ros-args", "-r", "__ns:=/uav1"], capture_output=True, text=True
    )
    assert result.stdout == "console script: --ros-args -r __ns:=/uav1\n"


def test_launcher_without_a_console_script_runs_the_cli_module(tmp_path):
    (launcher,) = ament_layout.write_launchers(tmp_path / "lib" / "multirotor_ros", ("controller",))
    fake_python = tmp_path / "path" / "python3"
    fake_python.parent.mkdir()
    fake_python.write_text('#!/bin/sh\necho "python3 $*"\n')
    fake_python.chmod(0o755)
    result = subprocess.run(
        [str(launcher), "--ros-args"],
        capture_output=True,
        text=True,
        env={"PATH": f"{fake_python.parent}:/usr/bin:/bin"},
    )
    assert result.stdout == "python3 -m multirotor_ros.cli node controller --ros-args\n"


def test_python_m_cli_is_the_multirotor_command():
    shown = subprocess.run(
        [sys.executable, "-m", "multirotor_ros.cli", "--help"], capture_output=True, text=True
    )
    assert shown.returncode == 0 and " node " in shown.stdout
    refused = subprocess.run(
        [sys.executable, "-m", "multirotor_ros.cli", "node", "no_such_node"], capture_output=True, text=True
    )
    assert refused.returncode == 2 and "unknown node 'no_such_node'" in refused.stderr


def test_pure_libraries_do_not_import_rclpy():
    libraries = [p for p in PACKAGE_DIR.iterdir() if p.name not in ROS_WRAPPERS and p.suffix in ("", ".py")]
    assert {"model", "frames.py"} <= {p.name for p in libraries}
    offenders = [
        f"{path.relative_to(REPOSITORY)}:{line}: {module}"
        for path in _python_files(*libraries)
        for module, line in _imports(path)
        if module.split(".")[0] == "rclpy"
    ]
    assert not offenders, "only multirotor_ros/nodes and cli may import rclpy:\n" + "\n".join(offenders)


def test_ruff_finds_nothing():
    if importlib.util.find_spec("ruff") is None:
        pytest.skip("ruff is not installed (it is in the test extras: pip install -e '.[test]')")
    paths = [
        p for p in ("multirotor_ros", "test", "bench", "scripts", "setup.py") if (REPOSITORY / p).exists()
    ]
    result = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--no-cache", *paths],
        cwd=REPOSITORY,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stdout[-5000:] + result.stderr[-2000:]
