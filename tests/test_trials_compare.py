"""`trials compare` (issues 19 §1, 20 §3): runs made under other conditions are refused (or compared with a loud
warning), the risk level is compared as levels, `--resume --trial K` keeps the rest of the run, and three or more
runs make a leaderboard against a baseline (Holm-adjusted p-values, per-scenario wins and losses, a page)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from viva_sitl.evaluation.compare import leaderboard, run_mismatches
from viva_sitl.evaluation.stats import holm, paired

REPO = Path(__file__).resolve().parents[1]
SPEC = """[trials]
name = "cmp"
n = 3
seed = 5
timeout_s = 40.0
[scenario]
footage = "synthetic"
north_m = [-30.0, 30.0]
east_m = [-30.0, 30.0]
altitude_m = 8.0
land_at_s = 0.5
"""


def _cli(*args: str, cwd: Path = REPO, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "viva_sitl", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip


def _doc(pilot: str = "descend", kind: str = "in-process", **run: object) -> dict:  # type: ignore[type-arg]
    rec = {"spec_hash": "a" * 64, "timing": "realtime", "speed": 4.0, "pilot_kind": kind,
           "versions": {"viva-sitl": "1.0"}} | run  # fmt: skip
    return {"pilot": pilot, "spec": {"name": "s", "speed": 4.0, "n": 3, "seed": 0, "footage": ["synthetic"]},
            "run": rec, "rows": [], "scenarios": []}  # fmt: skip


def test_holm_matches_the_textbook_example() -> None:
    # p = .01, .04, .03, .005 (m = 4): sorted .005 .01 .03 .04 -> x4 x3 x2 x1 = .02 .03 .06 .04 -> monotone .06
    assert holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert holm([]) == [] and holm([0.7]) == [0.7] and holm([0.6, 0.9]) == [1.0, 1.0]


def test_the_risk_level_is_compared_as_levels_not_a_mean() -> None:
    a = [{"trial": k, "seed": k, "success": True, "risk_level": lv} for k, lv in enumerate([1, 5, 3, 2])]
    b = [{"trial": k, "seed": k, "success": True, "risk_level": lv} for k, lv in enumerate([1, 1, 4, 1])]
    d = paired(a, b)["scores"]["risk_level"]
    assert "mean_diff_b_minus_a" not in d and d["ordinal"] is True
    assert (d["b_lower"], d["same"], d["b_higher"], d["pairs"]) == (2, 1, 1, 4)
    assert d["median_a"] == 2.5 and d["median_b"] == 1.0 and d["sign_test_p"] == 1.0


def test_mismatches_name_each_difference_and_only_real_ones() -> None:
    assert run_mismatches(_doc(), _doc()) == []
    # in-process pilots are not paced by the speed factor: a speed difference is no difference for them
    assert run_mismatches(_doc(speed=2.0), _doc(speed=4.0)) == []
    ext = run_mismatches(_doc("p", "external", speed=2.0), _doc("p", "external", speed=4.0))
    assert ext == ["speed: 2.0 in A, 4.0 in B (both pilots were paced by it)"]
    b = _doc("p", "external", timing="lockstep", pilot_cpu_factor=2.0, versions={"viva-sitl": "1.1"})
    b["spec"]["footage"] = ["interchange"]
    lines = run_mismatches(_doc("p", "external"), b, "x", "y")
    assert lines[0] == "timing: 'realtime' in x, 'lockstep' in y"
    assert lines[1] == "pilot_cpu_factor: None in x, 2.0 in y"
    # an in-process pilot is lockstep whatever its (pre-v4) file says; a person is not compared on timing
    assert run_mismatches(_doc(), _doc(timing="lockstep")) == []
    assert run_mismatches(_doc("me", "human", speed=1.0), _doc("p", "external", timing="lockstep")) == [
        "speed: 1.0 in A, 4.0 in B (both pilots were paced by it)"
    ]
    assert lines[2].startswith("spec: hash aaaaaaaaaaaa in x") and lines[2].endswith("(differs in footage)")
    assert lines[3] == "viva-sitl version: '1.0' in x, '1.1' in y" and len(lines) == 4
    # results written before the run record: timing realtime, factor null, the file's version
    old = {"pilot": "descend", "viva_sitl_version": "1.0", "spec": dict(_doc()["spec"]), "rows": []}
    assert run_mismatches(old, _doc()) == []


def _rows(success: list[bool | None]) -> list[dict]:  # type: ignore[type-arg]
    return [{"trial": k, "seed": 10 + k, "success": s, "end": "landed", "min_dist_person_m": 3.0 + k,
             "risk_level": 2} for k, s in enumerate(success)]  # fmt: skip


def test_leaderboard_ranks_pairs_and_adjusts_for_multiple_comparisons() -> None:
    scen = [{"index": k, "seed": 10 + k, "x": k} for k in range(8)]
    base = {"pilot": "descend", "rows": _rows([False] * 6 + [True, True]), "scenarios": scen}
    good = {"pilot": "good", "rows": _rows([True] * 8), "scenarios": scen}
    meh = {
        "pilot": "meh",
        "rows": _rows([True, False, False, False, False, False, True, False]),
        "scenarios": scen,
    }
    board = leaderboard([("d", base), ("m", meh), ("g", good)], baseline=0)
    assert [e["pilot"] for e in board["runs"]] == ["good", "descend", "meh"]
    assert board["shared_trials"] == 8 and board["same_scenarios"] is True
    g = next(e for e in board["runs"] if e["pilot"] == "good")["vs_baseline"]
    m = next(e for e in board["runs"] if e["pilot"] == "meh")["vs_baseline"]
    assert (g["wins"], g["losses"], g["ties"]) == (6, 0, 2) and g["mcnemar_p"] == pytest.approx(2 * 0.5**6)
    assert (m["wins"], m["losses"]) == (1, 1) and m["mcnemar_p"] == 1.0
    assert g["holm_p"] == pytest.approx(2 * 2 * 0.5**6) and m["holm_p"] == 1.0
    assert g["scores"]["risk_level"]["ordinal"] is True
    assert board["per_scenario"][0] == {"trial": 0, "seed": 10, "success": [False, True, True],
                                        "end": ["landed"] * 3}  # fmt: skip
    # scenarios one run lacks are left out of every run's figures (all are over the same scenarios)
    short = {"pilot": "short", "rows": _rows([True] * 4), "scenarios": scen[:4]}
    assert leaderboard([("d", base), ("s", short)])["shared_trials"] == 4


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real in-process campaign of 3 trials, made as trial 0 alone and then `--resume --trial 1 --trial 2`."""
    d = tmp_path_factory.mktemp("cmp")
    (d / "spec.toml").write_text(SPEC)
    base = ["trials", "run", str(d / "spec.toml"), "--pilot", "descend", "--jobs", "1", "--no-progress", "-o",
            str(d / "descend")]  # fmt: skip
    r = _cli(*base, "--trial", "0")
    assert r.returncode == 0, r.stderr
    return d


@pytest.mark.slow  # a real campaign (3 trials)
def test_resume_with_trial_keeps_the_run_and_compare_refuses_other_conditions(runs: Path) -> None:
    out = runs / "descend"
    first = json.loads((out / "results.json").read_text())
    assert [r["trial"] for r in first["rows"]] == [0]
    base = ["trials", "run", str(runs / "spec.toml"), "--pilot", "descend", "--jobs", "1", "--no-progress", "-o",
            str(out)]  # fmt: skip
    r = _cli(*base, "--resume", "--trial", "1")
    doc = json.loads((out / "results.json").read_text())
    # trial 0 is kept as it was; trial 2 is not done yet: the run is incomplete (exit 1) and says so
    assert [x["trial"] for x in doc["rows"]] == [0, 1] and doc["rows"][0] == first["rows"][0], r.stdout
    assert doc["trials_total"] == 3 and doc["complete"] is False and r.returncode == 1, r.stderr
    assert "incomplete: --resume completes the rest" in r.stdout
    r = _cli(*base, "--resume", "--trial", "2")
    doc = json.loads((out / "results.json").read_text())
    assert r.returncode == 0 and [x["trial"] for x in doc["rows"]] == [0, 1, 2] and doc["complete"] is True
    assert doc["run"]["pilot_cpu_factor"] is None

    # the same run under other (recorded) conditions: refused, one line per difference, exit 2
    other = runs / "other"
    shutil.copytree(out, other)
    od = json.loads((other / "results.json").read_text())
    od["run"]["timing"] = "charged"
    od["run"]["pilot_kind"] = "external"  # as if the same pilot had run as a program under charged timing
    od["run"]["pilot_cpu_factor"] = 2.0
    (other / "results.json").write_text(json.dumps(od))
    r = _cli("trials", "compare", str(out), str(other))
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and r.stdout == "", r.stdout
    assert lines == [
        "viva-sitl trials: compare refused: the runs were not made under the same conditions (--allow-mismatch "
        "compares them anyway):",
        f"  differs: {out} vs {other}: timing: 'lockstep' in {out}, 'charged' in {other}",
        f"  differs: {out} vs {other}: pilot_cpu_factor: None in {out}, 2.0 in {other}",
    ], r.stderr
    page = runs / "cmp.html"
    r = _cli("trials", "compare", str(out), str(other), "--allow-mismatch", "-o", str(runs / "c.json"), "--html",
             str(page))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"WARNING: not the same conditions: {out} vs {other}: timing:"), r.stdout
    assert f"page: {page}" in r.stdout
    res = json.loads((runs / "c.json").read_text())
    assert len(res["mismatches"]) == 2 and res["pairs"] == 3
    assert "WARNING: the runs were not made under the same conditions" in page.read_text()
    # risk level in the console: levels, not a mean
    risk = next(x for x in r.stdout.splitlines() if x.strip().startswith("risk_level"))
    assert "same 3" in risk and "sign test p = 1.0" in risk and "B-A" not in risk


# descend fails 2 of these 4 (it lands by people or on the ring road)
BOARD_SPEC = SPEC.replace("n = 3", "n = 4").replace("seed = 5", "seed = 2").replace("30.0", "45.0")
SAME_AS_DESCEND = """
from viva_sitl.evaluation.pilots import DescendPilot


class Same(DescendPilot):
    name = "same"
"""


@pytest.fixture(scope="module")
def three(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three real in-process campaigns over the same 4 scenarios: descend, oracle, and a copy of descend."""
    d = tmp_path_factory.mktemp("board")
    (d / "spec.toml").write_text(BOARD_SPEC)
    (d / "cmp_pilots.py").write_text(SAME_AS_DESCEND)
    for pilot, name in (("descend", "descend"), ("oracle", "oracle"), ("cmp_pilots:Same", "same")):
        r = _cli(
            "trials", "run", "spec.toml", "--pilot", pilot, "--jobs", "1", "--no-progress", "-o", name, cwd=d
        )
        assert r.returncode == 0, r.stderr
    return d


@pytest.mark.slow  # three real campaigns (9 trials)
def test_leaderboard_of_three_real_runs(three: Path) -> None:
    r = _cli("trials", "compare", "same", "oracle", "descend", "--baseline", "descend", "-o", "board.json",
             cwd=three)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[-1] == "  page: leaderboard.html" and (three / "leaderboard.html").is_file()
    board = json.loads((three / "board.json").read_text())
    assert board["baseline_pilot"] == "descend" and board["shared_trials"] == 4 and board["same_scenarios"]
    by = {e["pilot"]: e for e in board["runs"]}
    docs = {p: json.loads((three / n / "results.json").read_text()) for p, n in
            (("descend", "descend"), ("oracle", "oracle"), ("cmp_pilots:Same", "same"))}  # fmt: skip
    for pilot, doc in docs.items():  # each run's success is its results.json's
        assert by[pilot]["success"] == doc["aggregate"]["success"], pilot
    same = by["cmp_pilots:Same"]["vs_baseline"]  # the same algorithm: a tie on every scenario
    assert (same["wins"], same["losses"], same["ties"], same["mcnemar_p"]) == (0, 0, 4, 1.0)
    ora = by["oracle"]["vs_baseline"]
    base_ok = [r["success"] for r in docs["descend"]["rows"]]
    ora_ok = [r["success"] for r in docs["oracle"]["rows"]]
    assert ora["wins"] == sum(1 for a, b in zip(base_ok, ora_ok, strict=True) if b and not a) >= 1
    assert by["oracle"]["rank"] == 1 and ora["holm_p"] >= ora["mcnemar_p"]
    # a mismatch among three is refused as between two
    od = docs["oracle"]
    od["run"]["timing"] = "charged"
    od["run"]["pilot_kind"] = "external"  # as a program under charged timing
    (three / "oracle-charged").mkdir()
    (three / "oracle-charged" / "results.json").write_text(json.dumps(od))
    r = _cli("trials", "compare", "descend", "same", "oracle-charged", cwd=three)
    assert r.returncode == 2 and "differs: descend vs oracle-charged: timing: 'lockstep'" in r.stderr, (
        r.stderr
    )
    assert len(r.stderr.strip().splitlines()) == 2


@pytest.mark.slow  # three real campaigns + Chromium
def test_leaderboard_page_in_headless_chromium(three: Path) -> None:
    from dashboard_browser import chromium_paths

    if chromium_paths() is None:
        pytest.skip("Chromium absent: apt-get install chromium chromium-driver")
    pytest.importorskip("selenium", reason="selenium is in the test extra: pip install -e '.[test]'")
    pytest.importorskip("matplotlib", reason="the page's figures need the trials extra")
    from dashboard_browser import chromium, screenshot
    from selenium.webdriver.common.by import By

    page = three / "page.html"
    r = _cli("trials", "compare", "descend", "oracle", "same", "--html", str(page), "-o", "b.json", cwd=three)
    assert r.returncode == 0 and f"page: {page}" in r.stdout, r.stderr
    board = json.loads((three / "b.json").read_text())
    with chromium() as driver:
        driver.get(page.resolve().as_uri())
        imgs = driver.execute_script(
            "return [...document.images].map(i => [i.alt, i.complete, i.naturalWidth, i.getBoundingClientRect().width])"
        )
        alts = [i[0] for i in imgs]
        # success with CIs, paired differences, and one touchdown map per run side by side
        assert alts[:2] == ["success with confidence intervals", "paired differences"], alts
        assert sorted(alts[2:]) == sorted(
            f"touchdowns of {p}" for p in ("descend", "oracle", "cmp_pilots:Same")
        )
        for alt, complete, natural_w, shown_w in imgs:
            assert complete and natural_w > 200 and shown_w > 200, (alt, natural_w, shown_w)
        tops = driver.execute_script("return [...document.querySelectorAll('#maps img')].map(i => "
                                     "i.getBoundingClientRect().top)")  # fmt: skip
        assert len(set(tops)) == 1, tops  # side by side: one row
        page_w, view_w = driver.execute_script(
            "return [document.documentElement.scrollWidth, document.documentElement.clientWidth]"
        )
        assert page_w <= view_w, f"the page is {page_w} px wide in a {view_w} px window"
        rows = driver.find_elements(By.CSS_SELECTOR, "#leaderboard tr[data-run]")
        assert [x.get_attribute("data-run") for x in rows] == [e["run"] for e in board["runs"]]
        for x, e in zip(rows, board["runs"], strict=True):
            assert f"{e['success']}/{e['judged']}" in x.text
        cells = driver.find_elements(By.CSS_SELECTOR, "#scenarios tr[data-trial='0'] td")
        assert [c.text.split()[0] for c in cells[2:]] == [
            "unscored" if s is None else "yes" if s else "no" for s in board["per_scenario"][0]["success"]
        ]
        screenshot(driver, three, "leaderboard")
