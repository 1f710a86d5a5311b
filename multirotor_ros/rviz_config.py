"""The RViz 2 configuration of share/multirotor_ros/rviz/multirotor.rviz, moved to a vehicle's namespace.

RViz configurations name absolute topics and frames, and RViz has no namespace of its own: a launch file
that starts RViz for ``/uav1`` writes ``namespaced_rviz_config(text, "/uav1", "uav1/")`` to a file and
passes that. Only the topics (``Topic: Value``), the fixed frame and the view's target frame change.
"""

from __future__ import annotations

from typing import Any

import yaml


def namespaced_rviz_config(text: str, namespace: str, frame_prefix: str) -> str:
    """``text`` (an RViz config for the root namespace) for a vehicle under ``namespace``."""
    config = yaml.safe_load(text)
    if not isinstance(config, dict) or "Visualization Manager" not in config:
        raise ValueError("not an RViz 2 configuration: no 'Visualization Manager' section")
    manager = config["Visualization Manager"]
    prefix = "/" + namespace.strip("/") if namespace.strip("/") else ""
    for display in manager.get("Displays", []):
        topic: dict[str, Any] | None = display.get("Topic")
        if topic and str(topic.get("Value", "")).startswith("/"):
            topic["Value"] = prefix + topic["Value"]
    options = manager.setdefault("Global Options", {})
    options["Fixed Frame"] = frame_prefix + str(options.get("Fixed Frame", "odom"))
    view = manager.get("Views", {}).get("Current", {})
    if "Target Frame" in view:
        view["Target Frame"] = frame_prefix + str(view["Target Frame"])
    return yaml.safe_dump(config, sort_keys=False)
