"""``results.csv`` of an experiment: one row per run, appended and flushed as each run completes."""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

RESULTS_FILE = "results.csv"


FIXED_COLUMNS = (
    "run",
    "variant",
    "seed",
    "label",
    "group",
    "preset",
    "status",
    "error",
    "timing_mode",
    "duration_s",
    "task_wall_s",
    "worker",
    "finished",
    "config_hash",
    "run_command",
)
"""The first columns of ``results.csv``; the experiment's fields and metrics follow."""


_TEXT_COLUMNS = frozenset(FIXED_COLUMNS) - {"seed", "duration_s", "task_wall_s"}


# ------------------------------------------------------------------------------------------ results.csv
def _encode(column: str, value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    return json.dumps(value)


def _decode(column: str, text: str) -> Any:
    if column in _TEXT_COLUMNS:
        return text if text != "" else None
    if text == "":
        return None
    try:
        return json.loads(text)
    except ValueError:
        return text


class ResultsTable:
    """``results.csv``: one row per run, appended and flushed as each run completes.

    Columns: ``FIXED_COLUMNS``, then every other key in the order first seen. A row with a new key rewrites
    the file with the wider header (atomically: a temporary file renamed over it). Values: numbers and
    booleans as JSON (``true``, ``0.25``), lists and dicts as JSON, strings as they are, None as empty.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.columns: list[str] = list(FIXED_COLUMNS)
        self.rows: list[dict] = []

    @classmethod
    def load(cls, path: Path) -> ResultsTable:
        table = cls(path)
        if table.path.is_file():
            with open(table.path, newline="") as handle:
                reader = csv.DictReader(handle)
                for column in reader.fieldnames or []:
                    if column not in table.columns:
                        table.columns.append(column)
                for raw in reader:
                    table.rows.append({key: _decode(key, text or "") for key, text in raw.items() if key})
        return table

    def _line(self, row: Mapping[str, Any]) -> list[str]:
        return [_encode(column, row.get(column)) for column in self.columns]

    def rewrite(self) -> None:
        """Write every row (atomically)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        temporary = self.path.with_name(f".{self.path.name}.tmp")
        with open(temporary, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(self.columns)
            for row in self.rows:
                writer.writerow(self._line(row))
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, self.path)

    def add(self, row: Mapping[str, Any]) -> None:
        """Append one row: a plain append (flushed and synced) unless it brings a new column."""
        row = dict(row)
        self.rows.append(row)
        new = [key for key in row if key not in self.columns]
        if new or not self.path.is_file():
            self.columns += new
            self.rewrite()
            return
        with open(self.path, "a", newline="") as handle:
            csv.writer(handle).writerow(self._line(row))
            handle.flush()
            os.fsync(handle.fileno())
