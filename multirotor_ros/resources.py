"""Where the installed data files (airframe YAML, launch files) are, in every kind of install.

A colcon or ROS install puts them under ``<prefix>/share/multirotor_ros`` on AMENT_PREFIX_PATH; a
wheel puts the same ``data_files`` under ``sys.prefix``; an editable install installs none, so the
repository's own ``config/`` beside the package is used. The first directory that exists wins.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

PACKAGE_NAME = "multirotor_ros"
_REPOSITORY_ROOT = Path(__file__).resolve().parent.parent


def share_directories() -> list[Path]:
    """Candidate ``share/multirotor_ros`` directories, most specific first."""
    prefixes = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes += [Path(sys.prefix), Path(sys.base_prefix)]
    in_repository = (_REPOSITORY_ROOT / "package.xml").is_file() or (
        _REPOSITORY_ROOT / "config" / "x8_octorotor.yaml"
    ).is_file()
    candidates = [_REPOSITORY_ROOT] if in_repository else []
    candidates += [prefix / "share" / PACKAGE_NAME for prefix in prefixes]
    return [c for c in candidates if c.is_dir()]


def config_directory() -> Path:
    """The directory holding the airframe YAML files."""
    for share in share_directories():
        if (share / "config").is_dir():
            return share / "config"
    searched = ", ".join(str(s / "config") for s in share_directories()) or "(no share directory found)"
    raise FileNotFoundError(f"multirotor_ros config directory not found; searched {searched}")


def available_airframes() -> list[str]:
    """Names of the airframes shipped with the package (YAML file stems)."""
    return sorted(p.stem for p in config_directory().glob("*.yaml"))
