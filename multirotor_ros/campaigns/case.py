"""What a campaign is: a kind and its cases, each a key and a JSON description that fixes its result."""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import Any

# The kinds of campaign, by the name the command line and campaign.json use. Each module has
# run_case(description) -> row, summary(rows) -> lines and figures(rows) -> [(title, png bytes)].
KINDS = {
    "fault": "multirotor_ros.campaigns.fault",
    "recovery": "multirotor_ros.campaigns.recovery",
    "sweep": "multirotor_ros.campaigns.sweep",
    "logs": "multirotor_ros.campaigns.logs",
}
# Columns that say how a case ran, not what it found: they differ between runs of the same case.
RUN_COLUMNS = ("elapsed_s", "worker", "traceback")


@dataclass(frozen=True)
class Case:
    """One case: ``key`` names it in its campaign (stable across reruns); ``description`` fixes its result.

    The description holds plain JSON values and its own seed, so that any worker computes the same row.
    """

    key: str
    description: Mapping[str, Any]


@dataclass(frozen=True)
class Campaign:
    """A kind (one of :data:`KINDS`), a title for the reports, and the cases."""

    kind: str
    title: str
    cases: tuple[Case, ...]

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown kind of campaign {self.kind!r}; one of {', '.join(KINDS)}")
        keys = [case.key for case in self.cases]
        if len(set(keys)) != len(keys):
            raise ValueError("case keys must be unique within a campaign")

    def to_json(self) -> dict[str, Any]:
        """campaign.json."""
        return {
            "kind": self.kind,
            "title": self.title,
            "cases": [{"key": case.key, "description": dict(case.description)} for case in self.cases],
        }

    def table(self, rows: Mapping[str, Mapping[str, Any]]) -> list[dict[str, Any]]:
        """This campaign's rows in case order without the run columns: what a rerun reproduces."""
        return [
            {name: value for name, value in rows[case.key].items() if name not in RUN_COLUMNS}
            for case in self.cases
            if case.key in rows
        ]


def kind_module(kind: str) -> ModuleType:
    """The module that runs and reports cases of ``kind``."""
    return importlib.import_module(KINDS[kind])


def keyed(prefix: str, descriptions: Sequence[Mapping[str, Any]]) -> tuple[Case, ...]:
    """Cases keyed ``prefix-0001``, ``prefix-0002``, ... in the order given."""
    return tuple(
        Case(f"{prefix}-{index:04d}", description) for index, description in enumerate(descriptions, 1)
    )
