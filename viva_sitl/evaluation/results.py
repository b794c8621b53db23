"""A campaign's results on disk: OUT/trials/NNNN/result.json per finished trial (its row and scenario).
campaign.py runs trials into it; report.py reads it.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from viva_sitl.evaluation.scoring import SCHEMA
from viva_sitl.evaluation.spec import Scenario, TrialSpec

Row = dict[str, Any]


@dataclass
class Campaign:
    spec: TrialSpec
    pilot: str
    scenarios: list[Scenario]
    out_dir: Path
    rows: dict[int, Row] = field(default_factory=dict)
    interrupted: bool = False
    backend: str = "local"
    jobs: int = 1

    @property
    def complete(self) -> bool:
        return len(self.rows) == len(self.scenarios)

    def ordered_rows(self) -> list[Row]:
        return [self.rows[s.index] for s in self.scenarios if s.index in self.rows]


def trial_dir(out_dir: Path, index: int) -> Path:
    return out_dir / "trials" / f"{index:04d}"


def finished_trials(out_dir: Path) -> list[int]:
    """Indices of the trials with a result.json under OUT/trials (the folders trial_dir names), sorted."""
    try:
        dirs = list((out_dir / "trials").iterdir())
    except OSError:
        return []
    return sorted(int(d.name) for d in dirs if d.name.isdigit() and (d / "result.json").is_file())


def load_finished(out_dir: Path, scenarios: list[Scenario], pilot: str) -> dict[int, Row]:
    """Rows already on disk whose scenario and pilot match (for --resume)."""
    out: dict[int, Row] = {}
    for sc in scenarios:
        d = trial_dir(out_dir, sc.index)
        try:
            res = json.loads((d / "result.json").read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            continue
        if res.get("scenario") == sc.to_dict() and res.get("row", {}).get("pilot") == pilot:
            out[sc.index] = res["row"]
    return out


def _save_row(out_dir: Path, sc: Scenario, row: Row) -> None:
    d = trial_dir(out_dir, sc.index)
    d.mkdir(parents=True, exist_ok=True)
    tmp = d / "result.json.tmp"
    tmp.write_text(json.dumps({"schema": SCHEMA, "scenario": sc.to_dict(), "row": row}, indent=1))
    os.replace(tmp, d / "result.json")  # atomic: an interrupted write never leaves half a result


__all__ = ["Campaign", "Row", "finished_trials", "load_finished", "trial_dir"]
