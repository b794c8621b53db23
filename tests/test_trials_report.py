"""The trials reports a benchmark user reads (issue 8 §3): report.html of `trials run` and the output of `trials
compare` show the object-distance scores (schema v3) with the values of results.json, "n/a" (never 0) when
the footage's ground truth cannot answer them; `trials report` rewrites report.html; bad paths and pilots are one-line errors.
Real runs of the CLI over the synthetic field with the in-process `descend` / `oracle` pilots."""

from __future__ import annotations

import json
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import pytest
from dashboard_browser import chromium_paths

REPO = Path(__file__).resolve().parents[1]
SPEC = REPO / "configs" / "trials" / "synthetic_emergency.toml"
OBJ = ("dist_object_m", "min_dist_object_m")


class Tables(HTMLParser):
    """Every <table id=...> as rows of (tr attributes, [(cell attributes, text)])."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.tables: dict[
            str, list[tuple[dict[str, str | None], list[tuple[dict[str, str | None], str]]]]
        ] = {}
        self._t: str | None = None
        self._cell: list[str] | None = None
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "table":
            self._t = a.get("id") or f"table{len(self.tables)}"
            self.tables[self._t] = []
        elif tag == "tr" and self._t is not None:
            self.tables[self._t].append((a, []))
        elif tag in ("td", "th") and self._t is not None:
            self._cell = []
            self.tables[self._t][-1][1].append((a, ""))

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._cell.append(data)

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None and self._t is not None:
            attrs, _ = self.tables[self._t][-1][1][-1]
            self.tables[self._t][-1][1][-1] = (attrs, "".join(self._cell).strip())
            self._cell = None
        elif tag == "table":
            self._t = None

    def records(self, table: str) -> list[dict[str, str]]:
        """A table whose header cells carry data-col, as one dict per body row."""
        head, *body = self.tables[table]
        cols = [str(a.get("data-col")) for a, _ in head[1]]
        return [dict(zip(cols, [t for _, t in cells], strict=True)) for _, cells in body]

    def scores(self, table: str = "scores") -> dict[str, list[str]]:
        return {
            str(tr["data-score"]): [t for _, t in cells]
            for tr, cells in self.tables[table]
            if "data-score" in tr
        }


def _cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "viva_sitl", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip


def _run(spec: Path, pilot: str, out: Path, n: int = 2, seed: int | None = None) -> dict:  # type: ignore[type-arg]
    more = ["--seed", str(seed)] if seed is not None else []
    r = _cli("trials", "run", str(spec), "--pilot", pilot, "--n", str(n), "--jobs", "1", "-o", str(out),
             "--no-progress", *more)  # fmt: skip
    assert r.returncode == 0, r.stderr
    doc: dict = json.loads((out / "results.json").read_text())  # type: ignore[type-arg]
    return doc


def _value(cell: str) -> object:
    """A per-trial cell back to the results.json value it shows."""
    return {"yes": True, "no": False, "n/a": None, "unscored": None, "—": None}.get(cell, cell)


def _same(cell: str, v: object) -> bool:
    if isinstance(v, bool) or v is None:
        return _value(cell) == v and (v is not None or cell in ("n/a", "unscored", "—"))
    if isinstance(v, int | float):
        return float(cell) == v  # exact: the cell is the JSON number
    return cell == str(v)


@pytest.fixture(scope="module")
def oracle_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real 2-trial run of the oracle pilot on the synthetic field (B of `runs`; alone for the fast tier)."""
    out = tmp_path_factory.mktemp("runs") / "oracle"
    _run(SPEC, "oracle", out)
    return out


@pytest.fixture(scope="module")
def runs(oracle_run: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Two real 2-trial runs on the same scenarios of the synthetic field: descend (A) and oracle (B)."""
    a_dir = tmp_path_factory.mktemp("runs") / "descend"
    _run(SPEC, "descend", a_dir)
    return a_dir, oracle_run


@pytest.mark.slow  # two real campaigns
def test_report_and_compare_show_object_distances_as_in_results_json(
    tmp_path: Path, runs: tuple[Path, Path]
) -> None:
    a_dir, b_dir = runs
    a, b = (json.loads((x / "results.json").read_text()) for x in runs)
    for doc, out in ((a, a_dir), (b, b_dir)):
        page = Tables((out / "report.html").read_text())
        trials = page.records("trials")
        assert [int(t["trial"]) for t in trials] == [r["trial"] for r in doc["rows"]] == [0, 1]
        for t, row in zip(trials, doc["rows"], strict=True):
            assert row["gt_objects"] is True and row["objects_present"] is True
            assert all(row[c] is not None for c in OBJ)  # the synthetic field has people and cars
            assert t.pop("ulog") == "log.ulg"  # the link to the trial's PX4 ULog (not a results column)
            for col, cell in t.items():
                assert _same(cell, row[col]), (col, cell, row[col])
            # any object: never farther than the nearest person or vehicle
            assert row["min_dist_object_m"] <= min(row["min_dist_person_m"], row["min_dist_vehicle_m"]) + 1e-9
        sc = page.scores()
        for key in (*OBJ, "min_dist_person_m", "min_dist_vehicle_m"):
            st = doc["aggregate"]["scores"][key]
            cells = sc[key]
            assert int(cells[1]) == st["n"] == 2
            assert float(cells[2]) == pytest.approx(st["mean"], rel=5e-3)  # 3 significant digits
            assert float(cells[7]) == pytest.approx(min(r[key] for r in doc["rows"]), rel=5e-3)
            assert float(cells[8]) == pytest.approx(max(r[key] for r in doc["rows"]), rel=5e-3)
        worst_head = [t for _, t in page.tables["worst"][0][1]]
        assert "min dist object (m)" in worst_head

    # trials compare: text, JSON and HTML carry the paired object distances (B - A) of the same scenarios
    cmp_json, cmp_html = tmp_path / "cmp.json", tmp_path / "cmp.html"
    r = _cli("trials", "compare", str(a_dir), str(b_dir), "-o", str(cmp_json), "--html", str(cmp_html))
    assert r.returncode == 0, r.stderr
    res = json.loads(cmp_json.read_text())
    assert res["same_scenarios"] is True and res["pairs"] == 2
    ra, rb = {x["trial"]: x for x in a["rows"]}, {x["trial"]: x for x in b["rows"]}
    for key in OBJ:
        diffs = [rb[k][key] - ra[k][key] for k in (0, 1)]
        d = res["scores"][key]
        assert d["pairs"] == 2 and d["mean_diff_b_minus_a"] == pytest.approx(sum(diffs) / 2, abs=1e-4)
        line = next(ln for ln in r.stdout.splitlines() if ln.strip().startswith(key + " "))
        assert f"B-A {d['mean_diff_b_minus_a']:>9}" in line and "2 pairs" in line
    page = Tables(cmp_html.read_text())
    pairs = page.records("pairs")
    assert [int(p["trial"]) for p in pairs] == [0, 1]
    for p, e in zip(pairs, res["per_trial"], strict=True):
        k = e["trial"]
        for key in OBJ:
            va, vb, dv = (float(x) for x in p[key].split(" / "))
            assert (va, vb) == (ra[k][key], rb[k][key]) and (e[key + "_a"], e[key + "_b"]) == (va, vb)
            assert dv == e[key + "_diff"] == pytest.approx(vb - va, abs=1e-4)
        assert p["success"] == " / ".join("yes" if s else "no" for s in (ra[k]["success"], rb[k]["success"]))
    sc = page.scores()
    for key in OBJ:
        assert float(sc[key][4]) == pytest.approx(
            res["scores"][key]["mean_diff_b_minus_a"], rel=5e-3, abs=1e-3
        )

    # `trials report` writes the same page again from results.json (e.g. after report.html was lost)
    before = (a_dir / "report.html").read_text()
    (a_dir / "report.html").unlink()
    r = _cli("trials", "report", str(a_dir), timeout=120)
    assert r.returncode == 0, r.stderr
    assert (a_dir / "report.html").read_text() == before
    # a results.json file works where OUT_DIR is expected
    r = _cli("trials", "compare", str(a_dir / "results.json"), str(b_dir), timeout=120)
    assert r.returncode == 0 and "2 paired trials, same scenarios: True" in r.stdout, r.stderr
    # runs over other scenarios (another seed) have nothing to pair: one line, not an empty comparison
    other = tmp_path / "seed5"
    _run(SPEC, "descend", other, n=1, seed=5)
    r = _cli("trials", "compare", str(a_dir), str(other), timeout=120)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"viva-sitl trials: {a_dir} and {other} have no trial in common (pairs match on trial index and scenario "
        "seed): run both pilots on the same spec with the same --seed"
    ], r.stderr
    # another pilot's results are not overwritten by a copy-pasted -o
    before = (b_dir / "results.json").read_text()
    r = _cli("trials", "run", str(SPEC), "--pilot", "descend", "--n", "2", "-o", str(b_dir), timeout=120)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"viva-sitl trials: {b_dir} holds the results of pilot 'oracle' on spec 'synthetic-emergency' (seed 0, n "
        "2; 2 of 2 trials) (pilot 'oracle' there, 'descend' here): --force replaces it, or give this run its own -o"
    ], r.stderr
    r = _cli("trials", "fly", str(SPEC), "--trial", "0", "-o", str(b_dir), timeout=120)
    assert r.returncode == 2 and "holds the results of pilot 'oracle'" in r.stderr and "ready" not in r.stdout
    # the Python API refuses the same (the check lives in run_campaign, which the CLI calls)
    from viva_sitl.evaluation.campaign import run_campaign
    from viva_sitl.evaluation.spec import load_spec

    with pytest.raises(
        ValueError, match=r"holds the results of pilot 'oracle' on spec 'synthetic-emergency'"
    ):
        run_campaign(load_spec(SPEC), "descend", b_dir, n=2, progress=False)
    assert (b_dir / "results.json").read_text() == before
    # an output that cannot be written: one line, no traceback
    r = _cli(
        "trials",
        "compare",
        str(a_dir),
        str(b_dir),
        "-o",
        str(tmp_path / "no" / "such" / "c.json"),
        timeout=120,
    )
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"viva-sitl trials: {tmp_path / 'no' / 'such' / 'c.json'}: No such file or directory"
    ], r.stderr


@pytest.fixture
def nogt_spec(tmp_path: Path) -> Path:
    """A spec over a generated video with a scale but no object tracks and no risk map."""
    from viva_sitl.footage.testclip import write_coded_clip

    clip = write_coded_clip(tmp_path / "nogt.mp4", 60, 640, 480)
    (tmp_path / "nogt.toml").write_text('name = "nogt"\nkind = "video"\npath = "nogt.mp4"\nfps = 30.0\n'
                                        "recording_altitude_m = 100.0\nhfov_deg = 82.1\n")  # fmt: skip
    spec = tmp_path / "spec.toml"
    spec.write_text(
        f'[trials]\nname = "nogt"\nn = 2\nseed = 1\ntimeout_s = 40.0\n[scenario]\nfootage = "{clip}"\n'
        "north_m = [-20.0, 20.0]\neast_m = [-20.0, 20.0]\naltitude_m = 8.0\nland_at_s = 0.5\n"
        '[scoring]\ncriterion = { name = "safe", landed = true, min_dist_object_m = 5.0 }\n'
    )
    return spec


@pytest.mark.slow  # a real campaign
def test_without_ground_truth_object_distances_are_unavailable_not_zero(
    tmp_path: Path, nogt_spec: Path
) -> None:
    a_dir, b_dir = tmp_path / "a", tmp_path / "b"
    a, _ = _run(nogt_spec, "descend", a_dir), _run(nogt_spec, "descend", b_dir)
    page = Tables((a_dir / "report.html").read_text())
    for t, row in zip(page.records("trials"), a["rows"], strict=True):
        assert row["landed"] is True and row["gt_objects"] is False
        for key in (*OBJ, "dist_person_m", "min_dist_person_m", "risk_level"):
            assert row[key] is None and t[key] == "n/a", key
        assert t["success"] == "unscored" and row["success"] is None  # the criterion needs ground truth
        assert t["criterion_unavailable"] == row["criterion_unavailable"] != ""
        assert float(t["touchdown_speed_m_s"]) == row["touchdown_speed_m_s"]
    sc = page.scores()
    for key in OBJ:
        assert sc[key][1:] == ["0", "unavailable"] and a["aggregate"]["scores"][key] == {"n": 0}
    r = _cli("trials", "compare", str(a_dir), str(b_dir), "--html", str(tmp_path / "cmp.html"), timeout=120)
    assert r.returncode == 0, r.stderr
    for key in OBJ:
        line = next(ln for ln in r.stdout.splitlines() if ln.strip().startswith(key + " "))
        assert "unavailable" in line
    assert "success: unavailable" in r.stdout
    page = Tables((tmp_path / "cmp.html").read_text())
    assert page.scores()[OBJ[1]][1:] == ["0", "unavailable"]
    assert all(p[OBJ[1]] == "— / — / —" for p in page.records("pairs"))


def test_report_success_intervals_counts_and_risk_distribution(oracle_run: Path) -> None:
    """The success line gives both 95 % intervals in one format (percent, "a–b %"), counts as counts ("Landed: k
    of n trials"), a per-check table with the n/a count; the risk level is a distribution (trials per level and
    the median), never a mean with an interval."""
    import re

    from viva_sitl.evaluation.report import render_html

    b_dir = oracle_run
    doc = json.loads((b_dir / "results.json").read_text())
    text = (b_dir / "report.html").read_text()
    para = re.search(r"<p id='success'>(.*?)</p>", text, re.S)
    assert para is not None
    line = re.sub(r"<[^>]+>", "", para.group(1))
    assert re.search(r"2 of 2 judged trials = 100\.0 % \(95 % CI \d+\.\d–100\.0 % Wilson; 100\.0–100\.0 % "
                     r"bootstrap\)", line), line  # fmt: skip
    assert "Landed: 2 of 2 trials." in line and "Landed: 1." not in line
    checks = {str(tr["data-check"]): [t for _, t in cells] for tr, cells in Tables(text).tables["checks"]
              if "data-check" in tr}  # fmt: skip
    assert checks["min_dist_person_m"] == [
        "min_dist_person_m",
        "2",
        "2",
        "100.0 %",
        checks["min_dist_person_m"][4],
        "0",
    ]
    risk = Tables(text).scores()["risk_level"]
    levels = doc["aggregate"]["scores"]["risk_level"]
    assert "mean" not in levels and sum(levels["counts"].values()) == levels["n"] == 2
    assert risk[2].startswith("trials per level 1: ") and risk[3] == f"{levels['median']:.3g}"
    # an older results.json (risk level with a mean, no counts or checks) still renders
    old = json.loads(json.dumps(doc))
    old["aggregate"]["scores"]["risk_level"] = {"n": 2, "mean": 1.0, "mean_ci95": [1.0, 1.0], "median": 1.0,
                                                "p10": 1.0, "p90": 1.0, "min": 1.0, "max": 1.0}  # fmt: skip
    for k in ("checks", "landed", "success_unscored"):
        old["aggregate"].pop(k)
    assert "Landed: 2 of 2 trials." in render_html(old, b_dir)


def test_the_touchdown_figure_draws_the_risk_map_at_the_touchdown_times() -> None:
    """One panel per distinct footage frame of a touchdown, at that frame's time; beyond MAX_RISK_PANELS the panel
    times spread over the touchdowns and each touchdown goes to the nearest."""
    from viva_sitl.evaluation.report import MAX_RISK_PANELS, risk_panels, touchdown_footage_time_s

    def row(k: int, t0: float, landed: bool = True) -> dict[str, object]:
        return {"trial": k, "footage_time_s": t0, "land_at_s": 1.0, "time_to_land_s": 4.0 if landed else None,
                "end_t_s": 9.0, "touchdown_north_m": 0.0 if landed else None}  # fmt: skip

    rows = [row(0, 0.0), row(1, 0.05), row(2, 10.0), row(3, 3.0, landed=False)]
    assert touchdown_footage_time_s(rows[2]) == 15.0
    panels = risk_panels(rows, lambda t: int(t * 30))  # 30 fps: trials 0 and 1 touch down 1.5 frames apart
    assert [(t, [r["trial"] for r in rs]) for t, rs in panels] == [(5.0, [0]), (5.05, [1]), (15.0, [2])]
    panels = risk_panels(rows, lambda t: int(t * 10))  # 10 fps: same frame
    assert [(t, [r["trial"] for r in rs]) for t, rs in panels] == [(5.0, [0, 1]), (15.0, [2])]
    many = [row(k, 2.0 * k) for k in range(40)]
    loop = 177  # a 177-frame clip at 25 fps: the panels are frames of the loop, not absolute times

    def frame(t: float) -> int:
        return int(t * 25) % loop

    panels = risk_panels(many, frame)
    assert len(panels) == MAX_RISK_PANELS and sum(len(rs) for _, rs in panels) == 40
    pf = [frame(t) for t, _ in panels]
    for (_, rs), c in zip(panels, pf, strict=True):  # each touchdown on the panel of its nearest frame
        for r in rs:
            f = frame(touchdown_footage_time_s(r))
            assert abs(f - c) == min(abs(f - other) for other in pf)
    assert risk_panels([row(0, 0.0, landed=False)], lambda t: 0) == []


@pytest.mark.slow  # several CLI runs
def test_bad_paths_and_pilots_are_one_line(tmp_path: Path) -> None:
    def one_line(r: subprocess.CompletedProcess[str], needle: str) -> None:
        err = r.stderr.strip()
        assert r.returncode == 2 and "Traceback" not in err and len(err.splitlines()) == 1, err
        assert err.startswith("viva-sitl trials: ") and needle in err, err

    out = tmp_path / "typo"
    one_line(_cli("trials", "run", str(SPEC), "--pilot", "decsend", "-o", str(out), timeout=60),
             "program 'decsend' not found on PATH (built-in pilots: descend, oracle")  # fmt: skip
    assert not out.exists()  # refused before any trial ran
    one_line(_cli("trials", "run", str(SPEC), "--pilot", "./nope.sh --x", "-o", str(out), timeout=60),
             "'./nope.sh' not an executable file")  # fmt: skip
    for n in ("-1", "0"):  # one wording for every count below 1
        r = _cli("trials", "run", str(SPEC), "--n", n, "-o", str(out), timeout=60)
        assert r.returncode == 2 and f"argument --n: expected an integer >= 1, got '{n}'" in r.stderr, (
            r.stderr
        )
    one_line(_cli("trials", "compare", str(tmp_path), str(tmp_path), timeout=60), "no results")
    one_line(_cli("trials", "report", str(tmp_path / "none"), timeout=60), "no results")
    (tmp_path / "results.json").write_text("{")
    one_line(_cli("trials", "report", str(tmp_path), timeout=60), "not valid JSON")
    one_line(_cli("trials", "show", str(tmp_path / "results.json"), timeout=60), "not valid JSON")
    one_line(_cli("trials", "run", str(SPEC), "-o", str(tmp_path / "results.json"), timeout=60),
             f"{tmp_path / 'results.json'}: File exists")  # fmt: skip
    # a reader that stops early (`| head`) is no error
    p = subprocess.Popen([sys.executable, "-m", "viva_sitl", "trials", "scenarios", str(SPEC), "--n", "2000"],
                         cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    assert p.stdout is not None and p.stdout.readline().startswith('{"index": 0,')
    p.stdout.close()
    _, err = p.communicate(timeout=60)
    assert p.returncode == 0 and err == "", err


def test_a_trial_without_flight_log_reports_unavailable_not_zero() -> None:
    """A worker that died or hung leaves no log: its flight time, path, energy are null, and the aggregates
    (means, n) only count the trials that flew."""
    from viva_sitl.evaluation.campaign import failed_row
    from viva_sitl.evaluation.ends import TrialEnd
    from viva_sitl.evaluation.spec import draw_scenarios, load_spec
    from viva_sitl.evaluation.stats import aggregate

    spec = load_spec(SPEC)
    sc = draw_scenarios(spec, 1)[0]
    row = failed_row(spec, sc, TrialEnd.WORKER_DIED, "worker died (exit code -9)")
    # an infrastructure error judges nothing: success unknown, and the aggregate leaves it out (counted apart)
    assert row["end"] == "worker_died" and row["landed"] is False and row["success"] is None
    for key in ("end_t_s", "flight_time_s", "path_length_m", "energy_wh", "time_outside_footage_s", "failsafes",
                "touchdown_speed_m_s", "min_dist_object_m", "risk_level"):  # fmt: skip
        assert row[key] is None, key
    flown = {**row, "end": "landed", "path_length_m": 20.0, "flight_time_s": 30.0, "energy_wh": 1.0}
    agg = aggregate([row, flown], "x")
    assert agg["scores"]["path_length_m"]["n"] == 1 and agg["scores"]["path_length_m"]["mean"] == 20.0
    from viva_sitl.evaluation.report import infra_aggregate

    flown.update(success=False, landed=True)
    agg = infra_aggregate([row, flown], "x")
    assert agg["success_judged"] == 1 and agg["success_rate"] == 0.0 and agg["landed_rate"] == 1.0
    assert agg["ends"] == {"landed": 1, "worker_died": 1} and agg["infra_errors"]["trials"] == [0]
    assert agg["scores"]["flight_time_s"]["mean"] == 30.0


def test_every_result_column_is_documented_with_unit_meaning_and_null() -> None:
    """docs/trials-results.md has one table row per results column (no more, no fewer), each with a unit, a
    meaning and when it is null, and names the current schema."""
    from viva_sitl.evaluation.scoring import COLUMNS, SCHEMA

    text = (REPO / "docs" / "trials-results.md").read_text()
    assert SCHEMA in text
    documented: dict[str, list[str]] = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| `") and len(cells) == 4:
            documented[cells[0].strip("`")] = cells[1:]
    assert list(documented) == list(COLUMNS)  # same names, results.csv order
    for name, (unit, meaning, null) in documented.items():
        assert unit and len(meaning) > 10 and null, name
        suffix = next((u for u in ("_m_s", "_deg", "_wh", "_m", "_s") if name.endswith(u)), None)
        if suffix is not None:  # the unit in the name is the documented one
            assert unit == {"_m_s": "m/s", "_deg": "deg", "_wh": "Wh", "_m": "m", "_s": "s"}[suffix], name


@pytest.mark.slow  # two real campaigns + Chromium
@pytest.mark.skipif(
    chromium_paths() is None, reason="Chromium absent: apt-get install chromium chromium-driver"
)
def test_report_page_looks_right_in_headless_chromium(runs: tuple[Path, Path]) -> None:
    """The page a person opens: every figure decodes, wide tables scroll inside their box instead of widening the
    page, and the all-trials table shows the object distances of results.json."""
    pytest.importorskip("selenium", reason="selenium is in the test extra: pip install -e '.[test]'")
    from dashboard_browser import chromium, screenshot
    from selenium.webdriver.common.by import By

    a_dir = runs[0]
    doc = json.loads((a_dir / "results.json").read_text())
    with chromium() as driver:
        driver.get((a_dir / "report.html").resolve().as_uri())
        imgs = driver.execute_script(
            "return [...document.images].map(i => [i.alt, i.complete, i.naturalWidth, i.getBoundingClientRect().width])"
        )
        assert len(imgs) == 2, imgs  # touchdowns over the synthetic field, distributions
        for alt, complete, natural_w, shown_w in imgs:
            assert complete and natural_w > 300 and shown_w > 300, (alt, natural_w, shown_w)
        page_w, view_w = driver.execute_script(
            "return [document.documentElement.scrollWidth, document.documentElement.clientWidth]"
        )
        assert page_w <= view_w, f"the page is {page_w} px wide in a {view_w} px window"
        head = [c.text for c in driver.find_elements(By.CSS_SELECTOR, "#trials tr:first-child th")]
        for row in doc["rows"]:
            cells = driver.find_elements(By.CSS_SELECTOR, f"#trials tr[data-trial='{row['trial']}'] td")
            shown = dict(zip(head, [c.text for c in cells], strict=True))
            for key in OBJ:
                assert float(shown[key]) == row[key], (key, shown[key], row[key])
        screenshot(driver, a_dir, "report")
        # the compare page: its wide pairs table scrolls inside its box too, and shows B - A per pair
        cmp_html = a_dir.parent / "cmp-browser.html"
        r = _cli("trials", "compare", str(a_dir), str(runs[1]), "--html", str(cmp_html), timeout=120)
        assert r.returncode == 0, r.stderr
        driver.get(cmp_html.resolve().as_uri())
        page_w, view_w = driver.execute_script(
            "return [document.documentElement.scrollWidth, document.documentElement.clientWidth]"
        )
        assert page_w <= view_w, f"the compare page is {page_w} px wide in a {view_w} px window"
        b_rows = {x["trial"]: x for x in json.loads((runs[1] / "results.json").read_text())["rows"]}
        head = [c.text for c in driver.find_elements(By.CSS_SELECTOR, "#pairs tr:first-child th")]
        for row in doc["rows"]:
            cells = driver.find_elements(By.CSS_SELECTOR, f"#pairs tr[data-trial='{row['trial']}'] td")
            va, vb, dv = (float(x) for x in cells[head.index("min_dist_object_m")].text.split(" / "))
            other = b_rows[row["trial"]]["min_dist_object_m"]
            assert (va, vb) == (row["min_dist_object_m"], other) and dv == pytest.approx(vb - va, abs=1e-4)
        screenshot(driver, a_dir, "compare")
