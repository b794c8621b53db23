"""`viva-sitl trials search`: real in-process trials of `descend` on the synthetic field (small budgets)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from viva_sitl.evaluation.cli import trials_main
from viva_sitl.evaluation.search import fixed_spec, nominal_point, space_of, spec_to_toml
from viva_sitl.evaluation.spec import draw_scenarios, footage_box, load_spec, spec_from_dict

REPO = Path(__file__).resolve().parents[1]
SPEC = REPO / "configs" / "trials" / "synthetic_emergency.toml"


def _cli(*args: str, cwd: Path = REPO, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "viva_sitl", "trials", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout)  # fmt: skip


def test_space_is_the_specs_free_ranges_and_a_fixed_spec_round_trips_through_toml() -> None:
    spec = load_spec(SPEC)
    names = [d.name for d in space_of(spec)]
    # every [lo, hi] range, the battery failure (probability 0.3: present or not) and its time; nothing fixed
    assert names == ["failures[0]", "gust_std_m_s", "wind_speed_m_s", "params.MPC_LAND_SPEED", "failures[0].at_s",
                     "land_at_s", "footage_time_s", "yaw_deg", "wind_dir_deg", "altitude_m", "north_m", "east_m"]  # fmt: skip
    # the spec itself and a fixed one read back equal from the TOML written
    back = spec_from_dict(tomllib.loads(spec_to_toml(spec)), "x")
    assert back == dataclasses.replace(spec, source="x")
    dims = space_of(spec)
    boxes = {"synthetic": footage_box("synthetic")}
    pt = {**nominal_point(dims), "failures[0]": 1, "north_m": 0.9}
    fs = fixed_spec(spec, pt, dims, 7, boxes)
    assert fs is not None and fs.n == 1 and fs.seed == 7 and space_of(fs) == []
    assert fs.north_m == (36.0, 36.0) and fs.wind_speed_m_s == (0.0, 0.0)  # -45 + 0.9 * 90; calm at nominal
    assert fs.failures[0].probability == 1.0 and fs.failures[0].at_s[0] == fs.failures[0].at_s[1]
    back = spec_from_dict(tomllib.loads(spec_to_toml(fs)), "y")
    assert back == dataclasses.replace(fs, source="y")
    sc = draw_scenarios(back)[0]
    assert (sc.north_m, sc.east_m, [f.kind for f in sc.failures]) == (36.0, 0.0, ["battery_critical"])


def test_bad_input_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = str(tmp_path / "o")
    fixed = tmp_path / "fixed.toml"
    fixed.write_text('[trials]\nname = "f"\n[scenario]\nnorth_m = 0.0\neast_m = 0.0\naltitude_m = 20.0\n'
                     "yaw_deg = 0.0\nwind_dir_deg = 0.0\n")  # fmt: skip
    cases = [
        (
            ["search", str(SPEC), "--pilot", "descend", "--budget", "0", "-o", out],
            "--budget must be an integer >= 1",
        ),
        (["search", str(SPEC), "--pilot", "nosuchmod:Pilot", "--budget", "4", "-o", out], "cannot load"),
        (
            ["search", str(SPEC), "--pilot", "python3 my_pilot.py", "--budget", "4", "-o", out],
            "in-process pilots",
        ),
        (
            ["search", str(fixed), "--pilot", "descend", "--budget", "4", "-o", out],
            "no free parameters to search",
        ),
        (["search", str(tmp_path / "nope.toml"), "--budget", "4", "-o", out], "trial spec not found"),
    ]
    for argv, want in cases:
        assert trials_main(argv) == 2
        cap = capsys.readouterr()
        lines = cap.err.strip().splitlines()
        assert len(lines) == 1 and want in lines[0], (argv, cap.err)
        assert "Traceback" not in cap.err + cap.out
    assert not (tmp_path / "o").exists()  # nothing written for a refused search


@pytest.mark.slow  # ~40 s: three small searches and one rerun, real trials
def test_search_finds_descend_failure_reproducible_by_trials_run_and_deterministic(tmp_path: Path) -> None:
    args = [str(SPEC), "--pilot", "descend", "--budget", "8", "--seed", "0", "--max-failures", "1",
            "--shrink-budget", "4"]  # fmt: skip
    r = _cli("search", *args, "-o", str(tmp_path / "a"))
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "a" / "search.json").read_text())
    assert doc["search_trials"] == 8 and doc["failures_found"] >= 1 and len(doc["minimal"]) == 1
    m = doc["minimal"][0]
    assert m["result"]["success"] is False and m["failed_checks"]
    failing = tmp_path / "a" / "failure-01.toml"
    assert str(failing) in r.stdout
    # the written spec reruns unchanged with `trials run` and fails the same way at the same spot
    rr = _cli("run", str(failing), "-o", str(tmp_path / "rerun"), "--jobs", "1", "--no-progress")
    assert rr.returncode == 0, rr.stderr
    row = json.loads((tmp_path / "rerun" / "results.json").read_text())["rows"][0]
    assert row["pilot"] == "descend" and row["success"] is False
    for key in ("end", "criterion_failures", "touchdown_north_m", "touchdown_east_m", "risk_level",
                "min_dist_person_m"):  # fmt: skip
        assert row[key] == m["result"][key], key
    # same seed -> the same bytes, whatever the job count; another seed -> other scenarios
    r2 = _cli("search", *args, "--jobs", "2", "-o", str(tmp_path / "b"))
    assert r2.returncode == 0, r2.stderr
    for name in ("search.json", "failure-01.toml"):
        a = (tmp_path / "a" / name).read_text().replace(str(tmp_path / "a"), "OUT")
        b = (tmp_path / "b" / name).read_text().replace(str(tmp_path / "b"), "OUT")
        assert a == b, name
    r3 = _cli("search", *args[:-4], "--seed", "1", "--max-failures", "0", "-o", str(tmp_path / "c"))
    assert r3.returncode == 0, r3.stderr
    other = json.loads((tmp_path / "c" / "search.json").read_text())
    assert [t["values"] for t in other["trials"]] != [t["values"] for t in doc["trials"]]
    # an OUT that holds a search is refused (one line) unless --force
    r4 = _cli("search", *args, "-o", str(tmp_path / "a"))
    assert (
        r4.returncode == 2
        and "holds a search already" in r4.stderr
        and len(r4.stderr.strip().splitlines()) == 1
    )


def test_failure_score_is_positive_exactly_when_a_check_fails() -> None:
    from viva_sitl.evaluation.scoring import COLUMNS
    from viva_sitl.evaluation.search import failure_score

    spec = load_spec(SPEC)  # landed, touchdown < 1 m/s, >= 5 m from people, risk <= 2
    base = {c: None for c in COLUMNS}
    ok = {**base, "end": "landed", "landed": True, "touchdown_speed_m_s": 0.6, "gt_objects": True, "gt_risk": True,
          "persons_present": True, "min_dist_person_m": 12.0, "dist_person_m": 12.5, "risk_level": 1}  # fmt: skip
    s_ok, failed = failure_score(ok, spec)
    assert s_ok is not None and s_ok < 0 and failed == ()
    closer, _ = failure_score({**ok, "min_dist_person_m": 6.0}, spec)
    assert closer is not None and s_ok < closer < 0  # a near miss ranks above a clear pass
    for change, check in (({"min_dist_person_m": 3.0}, "min_dist_person_m"), ({"risk_level": 4}, "risk_level"),
                          ({"touchdown_speed_m_s": 1.5}, "touchdown_speed_m_s"),
                          ({"end": "timeout", "landed": False, "touchdown_speed_m_s": None}, "landed")):  # fmt: skip
        s, failed = failure_score({**ok, **change}, spec)
        assert s is not None and s > 0 and check in failed, change
    assert failure_score({**ok, "end": "trial_error"}, spec) == (
        None,
        (),
    )  # the harness failed, not the pilot


def test_search_shrinks_a_found_failure_towards_nominal_and_writes_a_spec_that_draws_it_back(
    tmp_path: Path,
) -> None:
    from viva_sitl.evaluation.search import search, write_search

    spec = load_spec(SPEC)
    res = search(spec, "descend", 8, seed=0, max_failures=1, shrink_budget=6)
    assert len(res.search_evals) == 8 and res.trials_to_failures(1) is not None
    assert len(res.minimal) == 1 and len(res.evaluations) <= 8 + 6
    found, best = res.evaluations[res.minimal[0]["found_at"]], res.evaluations[res.minimal[0]["minimal"]]
    assert best.failed and set(best.failed_checks) & set(found.failed_checks)  # still fails the same way
    dims = space_of(spec)
    nominal = nominal_point(dims)
    moved = [d.name for d in dims if best.point[d.name] != found.point[d.name]]
    assert moved and all(best.point[k] == nominal[k] or abs(best.point[k] - nominal[k]) < abs(found.point[k] - nominal[k])
                         for k in moved)  # fmt: skip
    (path,) = write_search(res, tmp_path / "o")
    back = load_spec(path)
    assert back.n == 1 and back.pilot == "descend" and space_of(back) == []
    sc = draw_scenarios(back)[0]
    vals = best.values
    assert (sc.north_m, sc.east_m, sc.altitude_m, sc.land_at_s) == (
        vals["north_m"],
        vals["east_m"],
        vals["altitude_m"],
        vals["land_at_s"],
    )
    doc = json.loads((tmp_path / "o" / "search.json").read_text())
    assert doc["schema"] == "vivasitl.search.v1" and len(doc["trials"]) == len(res.evaluations)
    assert doc["minimal"][0]["spec"] == "failure-01.toml" and doc["minimal"][0]["result"]["success"] is False


def test_an_integer_parameter_is_searched_over_whole_numbers(tmp_path: Path) -> None:
    p = tmp_path / "int.toml"
    p.write_text('[trials]\nname = "i"\n[scenario]\nnorth_m = 0.0\neast_m = 0.0\naltitude_m = 20.0\nyaw_deg = 0.0\n'
                 'wind_dir_deg = 0.0\n[scenario.params]\nBAT1_N_CELLS = [2, 6]\n')  # fmt: skip
    spec = load_spec(p)
    dims = space_of(spec)
    assert [(d.name, d.integer) for d in dims] == [("params.BAT1_N_CELLS", True)]
    boxes = {"synthetic": footage_box("synthetic")}
    got = set()
    for u in (0.0, 0.1, 0.37, 0.5, 0.99, 1.0):
        fs = fixed_spec(spec, {"params.BAT1_N_CELLS": u}, dims, 0, boxes)
        assert fs is not None
        ((name, (lo, hi)),) = fs.params
        assert lo == hi and lo == int(lo) and 2 <= lo <= 6
        got.add(lo)
        assert spec_from_dict(tomllib.loads(spec_to_toml(fs)), "x").params == fs.params  # loads: an integer
    assert got == {2.0, 3.0, 4.0, 6.0}
