"""`[trials] ulog = false` / `trials run --no-ulog`: in-process trials write no per-trial PX4 ULog (it costs +26-39 %
wall per trial), the trial's results are the same, and the spec's identity (spec_hash, compare's spec identity) does
not change with it."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from viva_sitl.config import ConfigError
from viva_sitl.evaluation.compare import spec_identity
from viva_sitl.evaluation.results import spec_hash
from viva_sitl.evaluation.runner import LOG_FILE, run_inprocess_trial
from viva_sitl.evaluation.spec import draw_scenarios, spec_from_dict

SPEC = {
    "trials": {"name": "ulog", "n": 1, "seed": 3, "timeout_s": 20.0},
    "scenario": {"footage": "synthetic", "start": "air", "north_m": [-10.0, 10.0], "east_m": [-10.0, 10.0],
                 "altitude_m": [6.0, 7.0], "land_at_s": 0.5},
}  # fmt: skip


def _spec(ulog: bool | None) -> dict:
    d = json.loads(json.dumps(SPEC))
    if ulog is not None:
        d["trials"]["ulog"] = ulog
    return d


def test_spec_key_parses_defaults_to_true_and_refuses_non_booleans() -> None:
    assert spec_from_dict(_spec(None), "s").ulog is True
    assert spec_from_dict(_spec(False), "s").ulog is False
    with pytest.raises(ConfigError, match=r"trials\.ulog: expected true/false"):
        spec_from_dict({**_spec(None), "trials": {"ulog": "no"}}, "s")


def test_the_switch_is_not_part_of_the_spec_identity() -> None:
    on, off = spec_from_dict(_spec(True), "s"), spec_from_dict(_spec(False), "s")
    assert spec_hash(on) == spec_hash(off) == spec_hash(spec_from_dict(_spec(None), "s"))
    doc = lambda s: {"spec": dataclasses.asdict(s)}  # noqa: E731 - results.json's spec, as compare reads it
    assert spec_identity(doc(on))[0] == spec_identity(doc(off))[0]


def test_no_ulog_trial_writes_no_log_and_flies_the_same(tmp_path: Path) -> None:
    rows = {}
    for ulog in (True, False):
        spec = spec_from_dict(_spec(ulog), "s")
        sc = draw_scenarios(spec, 1)[0]
        rows[ulog] = run_inprocess_trial(spec, sc, "descend", tmp_path / str(ulog))
        assert (tmp_path / str(ulog) / LOG_FILE).exists() is ulog
    for r in rows.values():
        r.pop("wall_s")
    assert rows[True] == rows[False]  # the ULog is a record, never an input: the same trial, row for row


@pytest.mark.slow  # ~12 s: a whole `trials run` (one trial, its report)
def test_cli_no_ulog_runs_trials_without_their_ulog(tmp_path: Path) -> None:
    from viva_sitl.evaluation.cli import build_parser, trials_main

    assert build_parser().parse_args(["run", "spec.toml"]).no_ulog is False  # default: keep writing it
    spec = tmp_path / "s.toml"
    spec.write_text(
        '[trials]\nname = "u"\nn = 1\ntimeout_s = 20.0\n[scenario]\nfootage = "synthetic"\nstart = "air"\n'
        "north_m = [-5.0, 5.0]\neast_m = [-5.0, 5.0]\naltitude_m = 6.0\nland_at_s = 0.5\n"
    )
    out = tmp_path / "out"
    assert (
        trials_main(["run", str(spec), "--pilot", "descend", "--out", str(out), "--no-ulog", "--no-progress"])
        == 0
    )
    trial = out / "trials" / "0000"
    assert (trial / "end.json").exists() and not (trial / LOG_FILE).exists()
