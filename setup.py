"""Build script of the ament_python package multirotor_ros (colcon, pip and wheels alike)."""

import importlib.util
import os
import xml.etree.ElementTree as ElementTree
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.develop import develop
from setuptools.command.install_scripts import install_scripts

HERE = Path(__file__).resolve().parent
# scripts/ament_layout.py also makes the editable venv's layout: one definition of the launchers.
_spec = importlib.util.spec_from_file_location("ament_layout", HERE / "scripts" / "ament_layout.py")
ament_layout = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(ament_layout)
PACKAGE = ament_layout.PACKAGE

try:
    from setuptools.command.bdist_wheel import bdist_wheel
except ImportError:  # setuptools < 70.1 (Ubuntu 24.04 has 68): the wheel package provides it
    try:
        from wheel.bdist_wheel import bdist_wheel
    except ImportError:  # colcon with neither: it never builds wheels, so no launcher step is needed
        bdist_wheel = None

# package.xml is the one place for the name, version and license that ROS tools read too.
_manifest = ElementTree.parse(HERE / "package.xml").getroot()
assert _manifest.findtext("name") == PACKAGE, "package.xml <name> must be multirotor_ros"
NODES = ament_layout.node_executables(HERE)


class InstallScriptsWithLaunchers(install_scripts):
    """``setup.py install`` (colcon): the launchers beside the console scripts in lib/multirotor_ros.

    setup.cfg sends the console scripts there, where ``ros2 run`` looks, but they are named
    ``multirotor-NAME``: ``lib/multirotor_ros/NAME`` must exist too. A wheel's build runs this command
    as well, into its ``.data/scripts`` (bin/ once installed), where no launcher belongs.
    """

    def run(self) -> None:
        super().run()
        directory = Path(self.install_dir)
        if ament_layout.is_ros_run_directory(directory):
            self.outfiles += [str(p) for p in ament_layout.write_launchers(directory, NODES)]


class DevelopWithLaunchers(develop):
    """``setup.py develop`` (``colcon build --symlink-install``): the same launchers beside the scripts.

    Only setuptools < 80 has this develop (Ubuntu 24.04, ROS 2 Jazzy's platform, has 68); the later one
    is a wrapper around pip that never calls this method (see setup.cfg).
    """

    def install_wrapper_scripts(self, dist: object) -> None:
        super().install_wrapper_scripts(dist)
        script_dir = getattr(self, "script_dir", None)
        if script_dir and ament_layout.is_ros_run_directory(Path(script_dir)):
            ament_layout.write_launchers(Path(script_dir), NODES)


cmdclass = {"install_scripts": InstallScriptsWithLaunchers, "develop": DevelopWithLaunchers}
if bdist_wheel is not None:

    class BdistWheelWithLaunchers(bdist_wheel):
        """A wheel that also carries ``lib/multirotor_ros/<executable>`` for ``ros2 run``.

        A wheel's console scripts always land in ``<prefix>/bin`` (setup.cfg's install_scripts does
        not apply to wheels), so the launchers are added as data_files for wheels only; colcon's
        ``setup.py install``/``develop`` writes them itself (the two classes above).
        """

        def run(self) -> None:
            build_base = Path(self.get_finalized_command("build").build_base)
            launchers = ament_layout.write_launchers(build_base / "ament_launchers", NODES)
            # distutils opens data_files relative to the working directory and refuses absolute paths.
            self.distribution.data_files.append((f"lib/{PACKAGE}", [os.path.relpath(p) for p in launchers]))
            super().run()

    cmdclass["bdist_wheel"] = BdistWheelWithLaunchers

setup(
    name=PACKAGE,
    version=_manifest.findtext("version"),
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["py.typed"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", sorted(glob("config/*.yaml"))),
        (f"share/{PACKAGE}/config/missions", sorted(glob("config/missions/*.csv"))),
        (f"share/{PACKAGE}/launch", sorted(glob("launch/*.py"))),
        (f"share/{PACKAGE}/rviz", sorted(glob("rviz/*.rviz"))),
    ],
    python_requires=">=3.12",
    # rclpy and the message packages are not here: they come from a ROS 2 Jazzy install (package.xml) or
    # from the ros-jazzy-* wheels that scripts/bootstrap.sh installs; naming them here would make pip
    # install a second ROS over a sourced one.
    # distributed (Dask's scheduler and workers; it brings dask) runs `multirotor campaign` and every batch
    # of cases; pyarrow writes the campaigns' Parquet results.
    install_requires=[
        "numpy",
        "scipy",
        "numba",
        "pyyaml",
        "matplotlib",
        "pymavlink",
        "rosbags",
        "pyulog",
        "distributed",
        "pyarrow",
    ],
    # setuptools: test/test_packaging.py builds the wheel offline, without pip's build isolation
    # (>= 70.1: bdist_wheel built in, even where a system ROS venv sees an older system setuptools).
    # mypy and the PyYAML and pyarrow stubs: test/test_typing.py type-checks the package.
    extras_require={
        "test": [
            "pytest",
            "pytest-timeout",
            "hypothesis",
            "ruff",
            "mypy",
            "types-PyYAML",
            "pyarrow-stubs",
            "setuptools>=70.1",
        ]
    },
    zip_safe=True,
    maintainer=_manifest.findtext("maintainer"),
    maintainer_email=_manifest.find("maintainer").get("email"),
    description=" ".join(_manifest.findtext("description").split()),
    license=_manifest.findtext("license"),
    cmdclass=cmdclass,
    entry_points={
        # Prefixed (multirotor-simulator): generic names in an environment's bin/ would clash with other
        # packages'. `ros2 run multirotor_ros simulator` finds the launchers of scripts/ament_layout.py.
        "console_scripts": [
            f"{ament_layout.console_script_name(name)} = {PACKAGE}.nodes.{name}:main" for name in NODES
        ]
        + [f"multirotor = {PACKAGE}.cli:main"],
    },
)
