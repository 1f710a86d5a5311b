"""Results of a campaign on disk: one Parquet part per flush, read back as one table, resumable.

``DIR/campaign.json`` is the campaign (its kind and every case's description): a later run may add cases
(a larger campaign with the same seed) but not change a stored one; ``DIR/results/`` holds
``part-*.parquet`` files, each a batch of finished cases. A part is written under a temporary name and
renamed, so a campaign killed at any instant leaves only whole parts: what it loses is the batch not yet
flushed, which the next run computes again. Parquet files cannot be appended to; parts are what lets
results stream to disk while the campaign runs.
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from multirotor_ros.campaigns.case import Campaign


class CampaignMismatch(ValueError):
    """The output directory holds another campaign's results."""


class ResultStore:
    """The results directory of one campaign (module docstring)."""

    def __init__(self, out_dir: str | Path, campaign: Campaign) -> None:
        self.out_dir = Path(out_dir)
        self.parts_dir = self.out_dir / "results"
        self.parts_dir.mkdir(parents=True, exist_ok=True)
        described = self.out_dir / "campaign.json"
        document = campaign.to_json()
        if described.is_file():
            _check_same_cases(json.loads(described.read_text(encoding="utf-8")), document, self.out_dir)
        _write_atomically(described, json.dumps(document, indent=1).encode())
        self._run = uuid.uuid4().hex[:8]
        self._parts_written = 0

    def rows(self) -> dict[str, dict[str, Any]]:
        """Every stored row by case key; a key stored twice (a failed case run again) keeps the newest."""
        parts = sorted(
            self.parts_dir.glob("part-*.parquet"), key=lambda path: (path.stat().st_mtime_ns, path.name)
        )
        rows: dict[str, dict[str, Any]] = {}
        for part in parts:
            for row in pq.read_table(part).to_pylist():
                rows[row["key"]] = {name: value for name, value in row.items() if value is not None}
        return rows

    def append(self, rows: Sequence[Mapping[str, Any]]) -> None:
        """Write ``rows`` as a new part."""
        if not rows:
            return
        self._parts_written += 1
        name = f"part-{self._run}-{self._parts_written:06d}.parquet"
        # Rows of one part may differ in columns (a failed case has no results): the part has them all.
        names = list(dict.fromkeys(name for row in rows for name in row))
        table = pa.table({name: [row.get(name) for row in rows] for name in names})
        temporary = self.parts_dir / f".{name}.tmp"
        pq.write_table(table, temporary)
        os.replace(temporary, self.parts_dir / name)


def _check_same_cases(stored: Mapping[str, Any], new: Mapping[str, Any], out_dir: Path) -> None:
    """A campaign may grow (more cases) but a stored key must still mean the same case."""
    before = {case["key"]: case["description"] for case in stored["cases"]}
    changed = [
        case["key"]
        for case in new["cases"]
        if case["key"] in before and before[case["key"]] != case["description"]
    ]
    if stored["kind"] != new["kind"] or changed:
        raise CampaignMismatch(
            f"{out_dir} holds the results of another campaign ("
            + (f"kind {stored['kind']}" if stored["kind"] != new["kind"] else f"case {changed[0]} differs")
            + "): give another output directory, or delete this one to start over"
        )


def _write_atomically(path: Path, data: bytes) -> None:
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_bytes(data)
    os.replace(temporary, path)
