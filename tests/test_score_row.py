"""The typed score row (scoring.ScoreRow) is the schema: its keys are COLUMNS in order, and a campaign's results.csv
is what the untyped dict rows gave (tests/data/results_synthetic_emergency_descend_n3.csv: `viva-sitl trials run
configs/trials/synthetic_emergency.toml --pilot descend --n 3 --jobs 1` recorded before the row was typed, the
wall_s column left out). A change of the scores on purpose regenerates that file the same way, and says so."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from viva_sitl.evaluation.campaign import run_campaign
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.monitor import TrialLog
from viva_sitl.evaluation.scoring import COLUMNS, ScoreRow, score_trial
from viva_sitl.evaluation.spec import TrialSpec, draw_scenarios, load_spec

REPO = Path(__file__).resolve().parents[1]
GOLDEN = REPO / "tests" / "data" / "results_synthetic_emergency_descend_n3.csv"


def test_the_typed_row_has_the_schema_columns_in_order() -> None:
    assert tuple(ScoreRow.__annotations__) == COLUMNS
    assert ScoreRow.__required_keys__ == frozenset(COLUMNS)  # total: a producer cannot leave a column out


def test_score_trial_gives_every_column_in_order_and_json_as_before() -> None:
    spec = TrialSpec()
    sc = draw_scenarios(spec, 1)[0]
    row = score_trial(sc, TrialLog(end=TrialEnd.TIMEOUT, end_detail="x", end_t_s=3.0), None, spec)
    assert list(row) == list(COLUMNS)
    doc = json.loads(json.dumps(row))
    assert (
        doc["end"] == "timeout" and doc["landed"] is False and doc["pilot"] is None and doc["wall_s"] is None
    )


def _without_wall_s(rows: list[list[str]]) -> list[list[str]]:
    k = rows[0].index("wall_s")
    return [r[:k] + r[k + 1 :] for r in rows]


@pytest.mark.slow  # ~10 s: three in-process trials in a worker process
def test_a_campaign_results_csv_is_the_recorded_one(tmp_path: Path) -> None:
    spec = load_spec(REPO / "configs" / "trials" / "synthetic_emergency.toml")
    run_campaign(spec, "descend", tmp_path, n=3, jobs=1, progress=False)
    with (tmp_path / "results.csv").open(newline="") as f:
        got = _without_wall_s(list(csv.reader(f)))
    with GOLDEN.open(newline="") as f:
        want = list(csv.reader(f))
    assert got[0] == want[0]
    for g, w in zip(got[1:], want[1:], strict=True):
        assert g == w, [(c, a, b) for c, a, b in zip(want[0], g, w, strict=True) if a != b]
