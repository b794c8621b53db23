"""Landing trials (issue 8 §2-5): spec validation, scenario drawing, scores against hand-computed cases on the
synthetic field, in-process pilots end to end on the one Vehicle loop, pool determinism, resume, bad pilots."""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from viva_sitl.config import ConfigError
from viva_sitl.evaluation.campaign import rows_equal, run_campaign
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.monitor import TRAJECTORY_COLUMNS, Touchdown, TrialLog
from viva_sitl.evaluation.scoring import COLUMNS, score_trial
from viva_sitl.evaluation.spec import Scenario, TrialSpec, draw_scenarios, load_spec, spec_from_dict
from viva_sitl.evaluation.stats import aggregate, mcnemar_exact, paired, wilson_ci
from viva_sitl.footage.synthetic_actors import DEFAULT_ACTORS, actor_position_ne_m
from viva_sitl.world import load_world

REPO = Path(__file__).resolve().parents[1]
SPEC_DIR = REPO / "configs" / "trials"

# A short emergency landing over the synthetic field: air start 8-12 m, "land now" at 0.5 s.
SHORT = {
    "trials": {"name": "short", "n": 3, "seed": 7, "timeout_s": 40.0},
    "scenario": {
        "footage": "synthetic", "start": "air", "north_m": [-40.0, 40.0], "east_m": [-40.0, 40.0],
        "altitude_m": [8.0, 12.0], "footage_time_s": [0.0, 60.0], "land_at_s": 0.5, "wind_speed_m_s": [0.0, 2.0],
        "params": {"MPC_LAND_SPEED": [0.7, 1.0]},
    },
}  # fmt: skip


def short_spec(**trials: object) -> TrialSpec:
    d = json.loads(json.dumps(SHORT))
    d["trials"].update(trials)
    return spec_from_dict(d, "short")


# ------------------------------------------------------------------------------------------- spec


def test_example_specs_load_and_draw() -> None:
    shared = REPO.parent / "shared" / "footage"
    for path in sorted(SPEC_DIR.glob("*.toml")):
        spec = load_spec(path)
        if any(f != "synthetic" for f in spec.footage) and not shared.is_dir():
            continue  # real footage lives in ../shared (absent here)
        scen = draw_scenarios(spec, 3)
        assert len(scen) == 3 and all(s.footage in spec.footage for s in scen), path


@pytest.mark.parametrize(
    ("patch", "needle"),
    [
        ({"trials": {"nn": 3}}, "short.trials.nn: unknown key (did you mean 'n'?)"),
        ({"scenery": {}}, "short.scenery: unknown key"),
        ({"scenario": {"altitude_m": [30.0, 10.0]}}, "short.scenario.altitude_m: empty range [30, 10]"),
        ({"scenario": {"altitude_m": [-5.0, 10.0]}}, "short.scenario.altitude_m: [-5, 10] is outside"),
        ({"scenario": {"start": "water"}}, "short.scenario.start: 'water' is not one of air, ground"),
        (
            {"scenario": {"params": {"MPC_LAND_SPED": 1.0}}},
            "unknown PX4 parameter (did you mean MPC_LAND_SPEED",
        ),
        ({"scenario": {"params": {"MPC_LAND_SPEED": [0.1, 1.0]}}}, "MPC_LAND_SPEED: [0.1, 1] is outside"),
        (
            {"scenario": {"failures": [{"kind": "engine_fire", "at_s": 1.0}]}},
            "failures[0].kind: 'engine_fire'",
        ),
        (
            {"scenario": {"failures": [{"kind": "battery_critical", "at_s": 1, "probability": 2}]}},
            "probability",
        ),
        ({"scenario": {"land_at_s": 50.0}}, "land_at_s: 50 s is not before trials.timeout_s 40"),
        ({"trials": {"timeout_s": -1}}, "short.trials.timeout_s: expected a positive number"),
        ({"scoring": {"criterion": {"max_risk_level": 9}}}, "max_risk_level: expected an integer 1..5"),
        ({"scoring": {"criterion": {"min_dist_peeple_m": 5}}}, "criterion.min_dist_peeple_m: unknown key"),
    ],
)
def test_bad_spec_is_one_line_naming_the_key(patch: dict[str, dict[str, object]], needle: str) -> None:
    d = json.loads(json.dumps(SHORT))
    for table, values in patch.items():
        d.setdefault(table, {}).update(values)
    with pytest.raises(ConfigError) as exc:
        spec_from_dict(d, "short")
    msg = str(exc.value)
    assert needle in msg and "\n" not in msg, msg


def test_start_range_outside_footage_is_refused() -> None:
    d = json.loads(json.dumps(SHORT))
    d["scenario"]["north_m"] = [-150.0, 0.0]  # the synthetic field spans +-102.4 m
    spec = spec_from_dict(d, "short")
    with pytest.raises(ConfigError, match=r"short.scenario.north_m: \[-150, 0\] leaves footage 'synthetic'"):
        draw_scenarios(spec)


def test_bad_spec_file_from_cli_is_one_line(tmp_path: Path) -> None:
    p = tmp_path / "bad.toml"
    p.write_text('[trials]\nn = 3\ncolour = "red"\n')
    r = subprocess.run([sys.executable, "-m", "viva_sitl", "trials", "run", str(p), "-o", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=120, cwd=REPO)  # fmt: skip
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"viva-sitl trials: {p}.trials.colour: unknown key (known: name, n, "
                                              "seed, timeout_s, pilot, speed, end_outside_s, crash_speed_m_s, log_hz, frames, timing, pilot_cpu_factor, pilot_latency_ms, ulog)"]  # fmt: skip


@pytest.mark.parametrize(
    ("var", "value"), [("VIVA_SITL_TILE_CACHE_MB", "lots"), ("VIVA_SITL_TILE_DECODE_THREADS", "0")]
)
def test_bad_tile_environment_fails_the_campaign_up_front(tmp_path: Path, var: str, value: str) -> None:
    spec = tmp_path / "short.toml"
    spec.write_text('[trials]\nn = 2\npilot = "descend"\n')
    out = tmp_path / "o"
    r = subprocess.run([sys.executable, "-m", "viva_sitl", "trials", "run", str(spec), "-o", str(out)],
                       capture_output=True, text=True, timeout=120, cwd=REPO,
                       env={**os.environ, var: value})  # fmt: skip
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"viva-sitl trials: ${var}={value!r}: give "), r.stderr
    assert not (out / "results.json").exists()  # no trial ran, none was recorded as failed


def test_scenarios_are_a_function_of_seed_and_index() -> None:
    spec = load_spec(SPEC_DIR / "synthetic_emergency.toml")
    a, b = draw_scenarios(spec, 12, 3), draw_scenarios(spec, 12, 3)
    assert a == b
    assert draw_scenarios(spec, 5, 3) == a[:5]  # trial K does not depend on N
    assert draw_scenarios(spec, 12, 4) != a
    assert len({s.seed for s in a}) == 12
    for s in a:  # inside the ranges, "land now" before the timeout, JSON round trip exact
        assert -45 <= s.north_m <= 45 and -45 <= s.east_m <= 45 and 15 <= s.altitude_m <= 30
        assert 0.6 <= dict(s.params)["MPC_LAND_SPEED"] <= 1.0 and s.land_at_s < s.timeout_s
        assert Scenario.from_dict(json.loads(json.dumps(s.to_dict()))) == s
    kinds = {f.kind for s in draw_scenarios(spec, 40, 0) for f in s.failures}
    assert kinds == {"battery_critical"}  # probability 0.3 over 40 draws


# ------------------------------------------------------------------------------------------- scores


def _walker(name: str):  # type: ignore[no-untyped-def]
    return next(a for a in DEFAULT_ACTORS if a.name == name)


def test_scores_hand_computed_on_the_synthetic_field() -> None:
    """walker-1 walks east along N = 10 from E = -30 to E = 9 and back, one round trip per 60 s: at footage time
    tau < 30 s it is at E = -30 + 1.3 tau. The vehicle descends straight down over (N 10, E -16.5) from 20 m at
    4 m/s between trial time 0 and 5 s, with the footage clock starting at 10 s: at touchdown (tau = 15 s) the walker
    is at E -10.5, 6.0 m away; the final descent below 10 m starts at trial time 2.5 s (tau = 12.5 s: walker at
    E -13.75), 2.75 m away, the closest it gets. Nobody else is within 25 m; the cars are on the ring road (r >= 46 m);
    the ground there is lawn (level 1) and 6 m is outside a person's 5 m + 0.35 m risk buffer."""
    w1 = _walker("walker-1")
    assert actor_position_ne_m(w1, 15.0) == pytest.approx((10.0, -10.5))
    assert actor_position_ne_m(w1, 12.5) == pytest.approx((10.0, -13.75))
    world = load_world("synthetic")
    spec = TrialSpec(final_descent_below_m=10.0)
    sc = Scenario(index=0, seed=1, footage="synthetic", start="air", north_m=10.0, east_m=-16.5, altitude_m=20.0,
                  yaw_deg=0.0, footage_time_s=10.0, land_at_s=1.0, wind_ned_m_s=(0.0, 0.0, 0.0), gust_std_m_s=0.0,
                  params=(), failures=(), timeout_s=60.0)  # fmt: skip
    log = TrialLog(
        end=TrialEnd.LANDED, end_detail="touchdown and disarm", end_t_s=7.0, energy_wh=0.5, path_m=20.0
    )
    for k in range(11):
        t = 0.5 * k
        row = dict.fromkeys(TRAJECTORY_COLUMNS, 0)
        row.update(t_s=t, sim_time_s=t, north_m=10.0, east_m=-16.5, down_m=-(20.0 - 4.0 * t), vd_m_s=4.0,
                   mode="AUTO_LAND", armed=1)  # fmt: skip
        log.rows.append(tuple(row[c] for c in TRAJECTORY_COLUMNS))
    log.touchdown = Touchdown(5.0, 10.0, -16.5, 0.8, 0.3)
    log.land_now_t_s = 1.0
    r = score_trial(sc, log, world, spec)
    assert r["dist_person_m"] == pytest.approx(6.0, abs=1e-3)
    assert r["min_dist_person_m"] == pytest.approx(2.75, abs=1e-3)
    assert r["dist_vehicle_m"] > 25.0 and r["risk_level"] == 1
    assert r["touchdown_speed_m_s"] == pytest.approx(math.hypot(0.8, 0.3), abs=1e-4)
    assert r["time_to_land_s"] == pytest.approx(4.0)
    assert r["landed"] is True and r["success"] is False
    assert r["criterion_failures"] == "min_dist_person_m 2.75 < 5"
    # the final descent counted below 2 m only (from t = 4.5 s, tau 14.5 s: walker at E -11.15): 5.35 m, a success
    r2 = score_trial(sc, log, world, TrialSpec(final_descent_below_m=2.0))
    assert r2["min_dist_person_m"] == pytest.approx(5.35, abs=1e-3)
    assert r2["success"] is True and r2["criterion_failures"] == ""
    # no touchdown (timeout in the air): no touchdown scores, no success, never zeros
    log.touchdown, log.end = None, "timeout"
    r3 = score_trial(sc, log, world, spec)
    assert r3["landed"] is False and r3["touchdown_speed_m_s"] is None and r3["dist_person_m"] is None
    assert (
        r3["risk_level"] is None
        and r3["success"] is False
        and r3["criterion_failures"].startswith("not landed")
    )


def test_motion_derived_objects_count_in_the_object_distance() -> None:
    """A `footage annotate --method motion` track (class "moving object", derived) parked 3 m east of the touchdown:
    not a person nor a vehicle, so dist_person_m / dist_vehicle_m ignore it, but dist_object_m and
    min_dist_object_m (any tracked object) see it, and a criterion on min_dist_object_m fails on it."""
    import numpy as np

    from viva_sitl.world import ObjectClass, WorldModel
    from viva_sitl.world.tracks import TrackInfo, analytic_tracks

    synth = load_world("synthetic")
    fps, frames = 30.0, 900
    infos = [TrackInfo(0, "motion", 1, ObjectClass.MOVING, "moving object", True),
             TrackInfo(1, "motion", 2, ObjectClass.PERSON, "person", False)]  # fmt: skip
    pos = np.zeros((frames, 2, 2))
    pos[:, 0] = (0.0, 3.0)  # the derived object: still, 3 m east of the touchdown point (0, 0)
    pos[:, 1, 0] = 40.0  # a person 40 m north: far
    # and the derived object passes 1 m from the descent path while the vehicle is at 5 m (t = 2 s, footage 2 s)
    pos[60, 0] = (0.0, 1.0)
    world = WorldModel("derived", synth.geometry, analytic_tracks(infos, pos, np.full((2, 2), 0.6), fps),
                       synth.risk_map, annotated=frozenset({"person", "vehicle"}))  # fmt: skip
    sc = Scenario(index=0, seed=1, footage="synthetic", start="air", north_m=0.0, east_m=0.0, altitude_m=10.0,
                  yaw_deg=0.0, footage_time_s=0.0, land_at_s=0.0, wind_ned_m_s=(0.0, 0.0, 0.0), gust_std_m_s=0.0,
                  params=(), failures=(), timeout_s=60.0)  # fmt: skip
    log = TrialLog(end=TrialEnd.LANDED, end_detail="touchdown and disarm", end_t_s=5.0)
    for k in range(9):
        t = 0.5 * k
        row = dict.fromkeys(TRAJECTORY_COLUMNS, 0)
        row.update(t_s=t, sim_time_s=t, down_m=-(9.0 - 2.0 * t), vd_m_s=2.0, mode="AUTO_LAND", armed=1)
        log.rows.append(tuple(row[c] for c in TRAJECTORY_COLUMNS))
    log.touchdown = Touchdown(4.5, 0.0, 0.0, 0.5, 0.0)
    crit = spec_from_dict(
        {"scoring": {"final_descent_below_m": 6.0, "criterion": {"min_dist_object_m": 2.0}}}, "x"
    )
    r = score_trial(sc, log, world, crit)
    assert r["dist_object_m"] == pytest.approx(3.0, abs=1e-3)
    # at t = 2 s, 5 m up: inside the final descent
    assert r["min_dist_object_m"] == pytest.approx(1.0, abs=1e-3)
    assert r["dist_person_m"] == pytest.approx(40.0, abs=1e-3) and r["dist_vehicle_m"] is None
    assert r["objects_present"] is True and r["vehicles_present"] is False
    assert r["success"] is False and r["criterion_failures"] == "min_dist_object_m 1.0 < 2"
    assert set(COLUMNS) >= {"dist_object_m", "min_dist_object_m", "objects_present"}


def test_a_class_not_annotated_is_unavailable_not_absent() -> None:
    """Footage whose truth annotates vehicles only (as Songdo): "nobody of that class" is unknown for people, so
    the person scores and persons_present are null, the person check is unjudged (success null, "unscored", with
    the reason), a failure elsewhere still fails, and the aggregate counts the check as unavailable, not passed."""
    from viva_sitl.world import WorldModel

    synth = load_world("synthetic")
    world = WorldModel("vehicles-only", synth.geometry, synth.tracks, synth.risk_map,
                       annotated=frozenset({"vehicle"}))  # fmt: skip
    sc = Scenario(index=0, seed=1, footage="synthetic", start="air", north_m=0.0, east_m=0.0, altitude_m=5.0,
                  yaw_deg=0.0, footage_time_s=0.0, land_at_s=0.0, wind_ned_m_s=(0.0, 0.0, 0.0), gust_std_m_s=0.0,
                  params=(), failures=(), timeout_s=60.0)  # fmt: skip
    log = TrialLog(end=TrialEnd.LANDED, end_detail="touchdown and disarm", end_t_s=6.0)
    for k in range(11):
        row = dict.fromkeys(TRAJECTORY_COLUMNS, 0)
        row.update(t_s=0.5 * k, down_m=-(5.0 - 0.5 * k), armed=1)
        log.rows.append(tuple(row[c] for c in TRAJECTORY_COLUMNS))
    log.touchdown = Touchdown(5.0, 0.0, 0.0, 0.5, 0.0)
    spec = spec_from_dict({"scoring": {"criterion": {"min_dist_person_m": 5.0, "min_dist_vehicle_m": 3.0,
                                                      "max_risk_level": 5, "max_touchdown_speed_m_s": 1.0}}}, "x")  # fmt: skip
    r = score_trial(sc, log, world, spec)
    for key in ("dist_person_m", "min_dist_person_m", "persons_present", "dist_object_m", "objects_present"):
        assert r[key] is None, key
    assert r["vehicles_present"] is True and r["dist_vehicle_m"] > 3.0 and r["min_dist_vehicle_m"] > 3.0
    assert r["success"] is None and r["criterion_failures"] == ""
    assert r["criterion_unavailable"] == "min_dist_person_m: people not annotated in this footage"
    # the same trial with the people annotated (the synthetic truth): judged, and a pass
    full = score_trial(sc, log, synth, spec)
    assert full["persons_present"] is True and full["dist_person_m"] > 5.0 and full["success"] is True
    # a failed check stands even when another is unavailable
    log.touchdown = Touchdown(5.0, 0.0, 0.0, 2.5, 0.0)
    bad = score_trial(sc, log, world, spec)
    assert bad["success"] is False and bad["criterion_failures"] == "touchdown speed 2.5 >= 1 m/s"
    assert bad["criterion_unavailable"] == r["criterion_unavailable"]
    agg = aggregate([r, bad, full], "x", spec.criterion)
    assert agg["success_judged"] == 2 and agg["success"] == 1 and agg["success_unscored"] == 1
    assert agg["checks"]["min_dist_person_m"] == {"passed": 1, "judged": 1, "unavailable": 2, "rate": 1.0,
                                                  "rate_ci95_wilson": [0.2065, 1.0]}  # fmt: skip
    assert (
        agg["checks"]["touchdown_speed_m_s"]["judged"] == 3
        and agg["checks"]["touchdown_speed_m_s"]["passed"] == 2
    )
    assert agg["scores"]["min_dist_person_m"]["n"] == 1 and agg["landed"] == 3


def test_results_of_schema_v1_still_read(tmp_path: Path) -> None:
    from viva_sitl.evaluation.report import read_results

    v1 = {c: 1.0 for c in COLUMNS if c not in ("dist_object_m", "min_dist_object_m", "objects_present")}
    (tmp_path / "results.json").write_text(json.dumps({"schema": "vivasitl.trials.v1", "rows": [v1]}))
    row = read_results(tmp_path)["rows"][0]
    assert row["min_dist_object_m"] is None and row["min_dist_person_m"] == 1.0  # unavailable, not zero
    (tmp_path / "results.json").write_text(json.dumps({"schema": "vivasitl.trials.v0", "rows": []}))
    with pytest.raises(ValueError, match="schema 'vivasitl.trials.v0', expected vivasitl.trials.v4"):
        read_results(tmp_path)


def test_scores_without_ground_truth_are_unavailable_not_zero(nogt_clip: Path) -> None:
    world = load_world(str(nogt_clip))
    assert not world.has_objects and not world.has_risk_map
    sc = Scenario(index=0, seed=1, footage=str(nogt_clip), start="air", north_m=0.0, east_m=0.0, altitude_m=10.0,
                  yaw_deg=0.0, footage_time_s=0.0, land_at_s=1.0, wind_ned_m_s=(0.0, 0.0, 0.0), gust_std_m_s=0.0,
                  params=(), failures=(), timeout_s=60.0)  # fmt: skip
    log = TrialLog(
        end=TrialEnd.LANDED, end_t_s=9.0, rows=[tuple(dict.fromkeys(TRAJECTORY_COLUMNS, 0.0).values())]
    )
    log.touchdown = Touchdown(8.0, 0.0, 0.0, 0.5, 0.0)
    r = score_trial(sc, log, world, TrialSpec())
    for key in ("dist_person_m", "min_dist_person_m", "dist_vehicle_m", "min_dist_vehicle_m", "risk_level"):
        assert r[key] is None, key
    assert r["touchdown_speed_m_s"] == 0.5 and r["gt_objects"] is False and r["gt_risk"] is False
    assert r["success"] is None  # the criterion needs ground truth: unjudged, not a success nor a failure
    agg = aggregate([r], "safe")
    assert agg["success_rate"] is None and agg["scores"]["min_dist_person_m"] == {"n": 0}


def test_stats() -> None:
    assert mcnemar_exact(0, 0) == 1.0
    assert mcnemar_exact(0, 6) == pytest.approx(2 * 0.5**6)
    lo, hi = wilson_ci(8, 10)
    assert lo == pytest.approx(0.4902, abs=1e-3) and hi == pytest.approx(0.9433, abs=1e-3)
    a = [{"trial": k, "seed": k, "success": k < 5, "touchdown_speed_m_s": 1.0} for k in range(10)]
    b = [{"trial": k, "seed": k, "success": k < 9, "touchdown_speed_m_s": 0.5} for k in range(10)]
    res = paired(a, b)
    assert res["pairs"] == 10 and res["success"]["only_b"] == 4 and res["success"]["only_a"] == 0
    assert res["success"]["rate_a"] == 0.5 and res["success"]["rate_b"] == 0.9
    assert res["scores"]["touchdown_speed_m_s"]["mean_diff_b_minus_a"] == -0.5


# ------------------------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def nogt_clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A generated video with a metadata file giving its scale but no objects and no risk map."""
    from viva_sitl.footage.testclip import write_coded_clip

    d = tmp_path_factory.mktemp("nogt")
    clip = write_coded_clip(d / "nogt.mp4", 60, 640, 480)
    (d / "nogt.toml").write_text('name = "nogt"\nkind = "video"\npath = "nogt.mp4"\nfps = 30.0\n'
                                 "recording_altitude_m = 100.0\nhfov_deg = 82.1\n")  # fmt: skip
    return clip


def _csv_rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow  # ~22 s of trials in a pool
def test_inprocess_pilots_end_to_end_pool_determinism_and_single_trial(tmp_path: Path) -> None:
    spec = short_spec()
    scen = draw_scenarios(spec)
    d = run_campaign(spec, "descend", tmp_path / "descend", jobs=2, progress=False)
    o = run_campaign(spec, "oracle", tmp_path / "oracle", jobs=2, progress=False)
    for camp in (d, o):
        rows = camp.ordered_rows()
        assert [r["trial"] for r in rows] == [0, 1, 2]
        for r, s in zip(rows, scen, strict=True):
            assert r["end"] == "landed", r
            assert r["touchdown_speed_m_s"] < 1.2 and r["time_to_land_s"] > 0 and r["energy_wh"] > 0
            assert r["seed"] == s.seed and r["land_at_s"] == 0.5
            t = _csv_rows(camp.out_dir / "trials" / f"{s.index:04d}" / "trial_trajectory.csv")
            assert -float(t[0]["down_m"]) == pytest.approx(s.altitude_m, abs=0.05)  # the air start pose
            assert t[-1]["landed"] == "1" and t[-1]["armed"] == "0"
            kinds = [json.loads(x)["kind"] for x in
                     (camp.out_dir / "trials" / f"{s.index:04d}" / "events.jsonl").read_text().splitlines()]  # fmt: skip
            assert kinds.index("land_now") < kinds.index("touchdown") < kinds.index("end")
        doc = json.loads((camp.out_dir / "results.json").read_text())
        assert doc["schema"] == "vivasitl.trials.v4" and doc["scenarios"] == [s.to_dict() for s in scen]
        assert list(_csv_rows(camp.out_dir / "results.csv")[0]) == list(COLUMNS)
        assert "data:image/png;base64," in (camp.out_dir / "report.html").read_text()
    for r, s in zip(d.ordered_rows(), scen, strict=True):  # descend lands where it was told to land
        assert math.hypot(r["touchdown_north_m"] - s.north_m, r["touchdown_east_m"] - s.east_m) < 2.0
    for r in o.ordered_rows():  # the oracle picks a safe spot: low risk, away from people
        assert r["risk_level"] <= 2 and r["min_dist_person_m"] >= 5.0 and r["success"] is True
    # trials compare: paired on the same scenarios, the oracle at least as good as descend
    from viva_sitl.evaluation.cli import trials_main

    cmp_path = tmp_path / "cmp.json"
    assert trials_main(["compare", str(d.out_dir), str(o.out_dir), "-o", str(cmp_path)]) == 0
    cmp = json.loads(cmp_path.read_text())
    assert cmp["pairs"] == 3 and cmp["same_scenarios"] is True and cmp["success"]["only_a"] == 0
    assert (
        cmp["success"]["rate_b"] == 1.0 and cmp["a"]["pilot"] == "descend" and cmp["b"]["pilot"] == "oracle"
    )
    # same scenarios, one worker: identical results; trial 2 alone reproduces trial 2
    d1 = run_campaign(spec, "descend", tmp_path / "descend-1job", jobs=1, progress=False)
    assert rows_equal(d1.ordered_rows(), d.ordered_rows())
    k2 = run_campaign(spec, "descend", tmp_path / "descend-k2", jobs=1, only=[2], progress=False)
    assert rows_equal(k2.ordered_rows(), d.ordered_rows()[2:])


SHARED = REPO.parent / "shared"


@pytest.mark.skipif(
    not (SHARED / "footage" / "interchange").is_dir(),
    reason=f"{SHARED / 'footage' / 'interchange'} is absent",
)
def test_the_oracle_keeps_a_margin_off_the_ramps_of_interchange(tmp_path: Path) -> None:
    """Trials 0 and 15 of the interchange spec: the oracle planned risk-3 cells at the edge of a risk-5 ramp and
    touched down a few decimetres off, on the ramp. Planning on the map eroded by its landing error plus the
    map's stated accuracy, it lands off risk >= 4 there (and on the synthetic field it still succeeds: the end to
    end test above)."""
    from viva_sitl.evaluation.pilots import OraclePilot

    oracle = OraclePilot()
    oracle.reset(draw_scenarios(short_spec())[0], load_world("interchange", shared_dir=SHARED))
    assert oracle.margin_m() == pytest.approx(1.0 + 2.0)  # landing error + the map's stated accuracy_m
    oracle.reset(draw_scenarios(short_spec())[0], load_world("synthetic"))
    assert oracle.margin_m() == pytest.approx(1.0)  # the synthetic map is exact
    spec = load_spec(SPEC_DIR / "interchange_emergency.toml")
    camp = run_campaign(spec, "oracle", tmp_path / "oracle", jobs=1, only=[0, 15], progress=False)
    rows = camp.ordered_rows()
    assert [r["trial"] for r in rows] == [0, 15]
    for r in rows:
        assert r["end"] == "landed" and r["risk_level"] is not None and r["risk_level"] <= 3, r


class MisbehavingPilot:
    """Trial 0: raises; trial 1: hangs inside act(); trial 2: never lands; trial 3: a good descend."""

    name, control_hz, frame_hz, uses_ground_truth = "misbehaving", 5.0, 0.0, False

    def reset(self, scenario: Scenario, truth: object) -> None:
        self.k = scenario.index

    def act(self, obs, ctl):  # type: ignore[no-untyped-def]
        if self.k == 0 and obs.t_s > 1.0:
            raise RuntimeError("division by zero in my landing code")
        if self.k == 1 and obs.t_s > 1.0:
            time.sleep(3600)
        if self.k == 3 and obs.land_now and obs.mode.name != "AUTO_LAND":
            ctl.land()
        return None


@pytest.mark.slow  # ~24 s of trials
def test_bad_inprocess_pilots_fail_their_trial_only(tmp_path: Path) -> None:
    spec = short_spec(n=4, timeout_s=20.0)
    camp = run_campaign(spec, "tests.test_trials:MisbehavingPilot", tmp_path, jobs=2, progress=False,
                        wall_limit_s=20.0)  # fmt: skip
    rows = camp.ordered_rows()
    assert [r["end"] for r in rows] == ["pilot_error", "wall_timeout", "timeout", "landed"], rows
    assert "RuntimeError: division by zero in my landing code" in rows[0]["end_detail"]
    assert "more than 20 s of wall time" in rows[1]["end_detail"]
    assert rows[2]["end_detail"] == "not landed and disarmed after 20 s"
    assert all(r["success"] is False for r in rows[:3]) and rows[3]["landed"] is True
    doc = json.loads((tmp_path / "results.json").read_text())
    assert doc["trials_done"] == 4 and doc["aggregate"]["ends"] == {
        "landed": 1, "pilot_error": 1, "timeout": 1, "wall_timeout": 1}  # fmt: skip
    with pytest.raises(ValueError, match="pilot 'tests.test_trials:NoSuchPilot': cannot load"):
        run_campaign(spec, "tests.test_trials:NoSuchPilot", tmp_path / "x", jobs=1, progress=False)


def test_footage_without_ground_truth_end_to_end(tmp_path: Path, nogt_clip: Path) -> None:
    d = json.loads(json.dumps(SHORT))
    d["scenario"].update(footage=str(nogt_clip), north_m=[-20.0, 20.0], east_m=[-20.0, 20.0])
    spec = spec_from_dict(d, "nogt")
    camp = run_campaign(spec, "descend", tmp_path, n=2, jobs=1, progress=False)
    for r in camp.ordered_rows():
        assert r["end"] == "landed" and r["touchdown_speed_m_s"] is not None
        assert r["min_dist_person_m"] is None and r["risk_level"] is None and r["success"] is None
    row = _csv_rows(tmp_path / "results.csv")[0]
    assert row["min_dist_person_m"] == "" and row["risk_level"] == ""  # empty, not 0
    assert "unavailable" in (tmp_path / "report.html").read_text()


@pytest.mark.slow  # Ctrl-C of a campaign
def test_cli_interrupt_keeps_finished_trials_and_resume_completes(tmp_path: Path) -> None:
    import signal

    spec_path = tmp_path / "spec.toml"
    spec_path.write_text(
        '[trials]\nname = "cli"\nn = 4\nseed = 3\ntimeout_s = 40.0\n[scenario]\nfootage = "synthetic"\n'
        "north_m = [-30.0, 30.0]\neast_m = [-30.0, 30.0]\naltitude_m = 8.0\nland_at_s = 0.5\n"
    )
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "viva_sitl", "trials", "run", str(spec_path), "--jobs", "1", "-o", str(out),
           "--no-progress"]  # fmt: skip
    p = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = out / "trials" / "0000" / "result.json"
    deadline = time.monotonic() + 180
    while not first.exists() and time.monotonic() < deadline and p.poll() is None:
        time.sleep(0.2)
    assert first.exists(), p.communicate(timeout=30)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    doc = json.loads((out / "results.json").read_text())
    assert 1 <= doc["trials_done"] < 4 and doc["complete"] is False
    assert "rerun with --resume" in err
    kept = {r["trial"]: r for r in doc["rows"]}
    r = subprocess.run([*cmd, "--resume"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    doc2 = json.loads((out / "results.json").read_text())
    assert doc2["complete"] is True and [x["trial"] for x in doc2["rows"]] == [0, 1, 2, 3]
    for k, row in kept.items():  # finished trials were kept as they were, not run again
        assert doc2["rows"][k] == row
    # OUT holds a run now: the same command again, or --resume with another seed / n, is refused (one line)
    # and nothing is overwritten
    before = (out / "results.json").read_text()
    for more, needle in (
        ([], f"{out} holds this run already (4 of 4 trials): --resume completes it, --force runs it again"),
        (["--resume", "--seed", "5"], f"--resume: {out} holds a different run (seed 3 there, 5 here): --force "
                                      "replaces it, or give this run its own -o"),
        (["--resume", "--n", "2"], "holds a different run (n 4 there, 2 here)"),
    ):  # fmt: skip
        r = subprocess.run([*cmd, *more], cwd=REPO, capture_output=True, text=True, timeout=120)
        err = r.stderr.strip()
        assert r.returncode == 2 and len(err.splitlines()) == 1 and needle in err, (more, err)
    assert (out / "results.json").read_text() == before
    # --force replaces it: what ran (--n 2 --seed 4) is what results.json and the report say; the old trials go
    r = subprocess.run([*cmd, "--force", "--n", "2", "--seed", "4"], cwd=REPO, capture_output=True, text=True,
                       timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    doc3 = json.loads((out / "results.json").read_text())
    assert [x["trial"] for x in doc3["rows"]] == [0, 1] and sorted(os.listdir(out / "trials")) == [
        "0000",
        "0001",
    ]
    assert doc3["spec"]["n"] == 2 and doc3["spec"]["seed"] == 4 and doc3["trials_total"] == 2
    run = doc3["run"]
    assert {k: run[k] for k in ("seed", "n", "pilot", "pilot_kind", "timing", "speed")} == {
        "seed": 4,
        "n": 2,
        "pilot": "descend",
        "pilot_kind": "in-process",
        "timing": "lockstep",
        "speed": 4.0,
    }
    assert (
        run["spec_hash"] == doc2["run"]["spec_hash"] and len(run["spec_hash"]) == 64
    )  # same spec, other seed
    assert run["versions"]["viva-sitl"] and run["versions"]["pymavlink"] and run["versions"]["mavsdk"]
    assert [s["seed"] for s in doc3["scenarios"]] != [s["seed"] for s in doc2["scenarios"][:2]]
    page = (out / "report.html").read_text()
    assert (
        "; seed 4;" in page
        and f"spec hash <code>{run['spec_hash'][:16]}</code>; seed 4; n 2; timing "
        "lockstep; speed 4.0; versions: viva-sitl"
        in page
    )
    show = subprocess.run([sys.executable, "-m", "viva_sitl", "trials", "show", str(out), "--trial", "1"],
                          cwd=REPO, capture_output=True, text=True, timeout=60)  # fmt: skip
    assert show.returncode == 0 and "land_now" in show.stdout and "touchdown" in show.stdout


# a pilot module in the user's current directory: trial 0's worker dies the first time (an infrastructure error:
# the harness cannot tell it from a segfault in the simulator), and flies the next time
DYING_PILOT = """
import os
from pathlib import Path

from viva_sitl.evaluation.pilots import DescendPilot


class DiesOnce(DescendPilot):
    def reset(self, scenario, truth):
        if scenario.index == 0 and not Path("died-once").exists():
            Path("died-once").write_text("")
            os._exit(3)
        super().reset(scenario, truth)
"""


def test_infrastructure_errors_exit_3_stay_out_of_the_success_rate_and_resume_reruns_them(
    tmp_path: Path,
) -> None:
    (tmp_path / "mypilot.py").write_text(DYING_PILOT)
    spec_path = tmp_path / "spec.toml"
    spec_path.write_text(
        '[trials]\nname = "infra"\nn = 2\nseed = 3\ntimeout_s = 40.0\n[scenario]\nfootage = "synthetic"\n'
        "north_m = [-30.0, 30.0]\neast_m = [-30.0, 30.0]\naltitude_m = 8.0\nland_at_s = 0.5\n"
    )
    # the installed `viva-sitl` script (not `python -m`, which puts the current directory on sys.path itself)
    exe = Path(sys.executable).parent / "viva-sitl"
    cmd = [str(exe), "trials", "run", str(spec_path), "--pilot", "mypilot:DiesOnce", "--jobs", "1", "-o", "out",
           "--no-progress"]  # fmt: skip
    r = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 3, r.stdout + r.stderr
    assert (
        "1 trial failed in the harness, not the pilot (worker_died 1: trial 0): left out of the success "
        "rate and the scores; --resume runs them again" in r.stdout
    )
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    r0, r1 = doc["rows"]
    assert r0["end"] == "worker_died" and r0["success"] is None and r1["end"] == "landed"
    agg = doc["aggregate"]
    assert agg["infra_errors"] == {"n": 1, "trials": [0], "ends": {"worker_died": 1}}
    assert agg["n"] == 1 and agg["success_judged"] == 1 and agg["landed_rate"] == 1.0
    assert agg["ends"] == {"landed": 1, "worker_died": 1}
    assert "id='infra'>1 trial failed in the harness" in (tmp_path / "out" / "report.html").read_text()
    # --resume runs the infrastructure error again (the finished trial stays as it was)
    r = subprocess.run([*cmd, "--resume"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    doc2 = json.loads((tmp_path / "out" / "results.json").read_text())
    assert [x["end"] for x in doc2["rows"]] == ["landed", "landed"] and doc2["rows"][1] == r1
    assert doc2["aggregate"]["infra_errors"]["n"] == 0 and "failed in the harness" not in r.stdout


class HoldPilot:
    """Does nothing: whatever happens is the autopilot's failsafes."""

    name, control_hz, frame_hz, uses_ground_truth = "hold", 2.0, 0.0, False

    def reset(self, scenario: Scenario, truth: object) -> None:
        pass

    def act(self, obs, ctl):  # type: ignore[no-untyped-def]
        return None


def test_injected_failures_reach_the_autopilot(tmp_path: Path) -> None:
    """battery_critical drains the pack below BAT_CRIT_THR (PX4's warning); gcs_link_lost silences the ground
    station: after COM_DL_LOSS_T the NAV_DLL_ACT = 3 failsafe lands the vehicle, which the scores count."""
    from viva_sitl.evaluation.runner import run_inprocess_trial

    d = json.loads(json.dumps(SHORT))
    d["scenario"].update(land_at_s=35.0, params={"NAV_DLL_ACT": 3, "COM_DL_LOSS_T": 5},
                         failures=[{"kind": "battery_critical", "at_s": 1.0}, {"kind": "gcs_link_lost", "at_s": 2.0}])  # fmt: skip
    spec = spec_from_dict(d, "fail")
    sc = draw_scenarios(spec, 1)[0]
    assert [(f.kind, f.at_s) for f in sc.failures] == [("battery_critical", 1.0), ("gcs_link_lost", 2.0)]
    row = run_inprocess_trial(spec, sc, "tests.test_trials:HoldPilot", tmp_path)
    ev = [json.loads(x) for x in (tmp_path / "events.jsonl").read_text().splitlines()]
    texts = [(e["kind"], e["text"]) for e in ev]
    crit = next(e for e in ev if "Critical battery level" in e["text"])
    lost = next(e for e in ev if e["text"] == "Connection to ground station lost")
    # heartbeats at 0, 1 s; cut at 2 s before the next one: last heard at 1 s, lost COM_DL_LOSS_T = 5 s later
    assert 1.0 <= crit["t_s"] < 1.1 and 6.0 <= lost["t_s"] < 6.1, texts
    assert ("failsafe", "Failsafe activated (no GCS): switching to Land") in texts
    assert row["end"] == "landed" and row["failsafes"] == 1 and "switching to Land" in row["failsafe_texts"]
    assert row["time_to_land_s"] is None  # it landed before being told to: no "time to land" to report


def test_trial_video_at_the_camera_rate(tmp_path: Path) -> None:
    import av

    from viva_sitl.evaluation.runner import run_inprocess_trial

    spec = spec_from_dict({"trials": {"timeout_s": 6.0}, "scenario": {"north_m": [-5.0, 5.0], "east_m": [-5.0, 5.0],
                                                                      "altitude_m": 10.0, "land_at_s": 1.0}}, "v")  # fmt: skip
    row = run_inprocess_trial(spec, draw_scenarios(spec, 1)[0], "descend", tmp_path, video=True)
    assert row["end"] == "timeout"  # 6 s is too short to land from 10 m
    with av.open(str(tmp_path / "vac.mp4")) as c:
        st = c.streams.video[0]
        assert (st.width, st.height) == (640, 480) and st.frames == 180  # 6 s at 30 fps, descend acts at 5 Hz


class FrameReader:
    """An in-process pilot that reads every 640x480 VAC frame (as a vision pilot would) and lands when told."""

    name, control_hz, frame_hz, uses_ground_truth = "frame-reader", 30.0, 30.0, False

    def reset(self, scenario: object, truth: object) -> None:
        self.landing = False

    def act(self, obs: object, ctl: object) -> None:
        assert obs.frame is not None and obs.frame.image_bgr.shape == (480, 640, 3)  # type: ignore[attr-defined]
        if obs.land_now and not self.landing:  # type: ignore[attr-defined]
            self.landing = ctl.land().ok  # type: ignore[attr-defined]


def test_a_trial_flies_the_same_over_a_lossless_tile_cache_of_its_footage(
    nogt_clip: Path, tmp_path: Path
) -> None:
    """The faster footage form (`footage ingest --tiles`) is a drop-in: same trajectory, same scores, same frames."""
    from viva_sitl.evaluation.runner import run_inprocess_trial
    from viva_sitl.footage.ingest import ingest_tiles

    tiles = tmp_path / "nogt_tiles"
    ingest_tiles(str(nogt_clip.with_suffix(".toml")), out_dir=tiles, codec="raw", show_progress=False)
    rows, videos = [], []
    for k, footage in enumerate((str(nogt_clip), str(tiles))):
        spec = spec_from_dict(
            {"trials": {"name": "t", "n": 1, "seed": 3, "timeout_s": 30.0},
             "scenario": {"footage": footage, "start": "air", "north_m": [-5.0, 5.0], "east_m": [-5.0, 5.0],
                          "altitude_m": 4.0, "land_at_s": 0.5}},
            "t",
        )  # fmt: skip
        sc = draw_scenarios(spec)[0]
        d = tmp_path / f"t{k}"
        row = run_inprocess_trial(spec, sc, f"{__name__}:FrameReader", d, video=True)
        rows.append({k2: v for k2, v in row.items() if k2 not in ("wall_s", "footage")})
        videos.append((d / "vac.mp4").read_bytes())
    assert rows[0]["end"] == "landed", rows[0]
    assert rows[0] == rows[1]
    assert len(videos[0]) > 10_000 and videos[0] == videos[1]  # the VAC frames the pilot saw: identical


@pytest.mark.slow
def test_trials_run_says_when_an_external_pilots_wall_timers_may_trip_failsafes(tmp_path: Path) -> None:
    """Above 8x an external pilot's own wall-clock timers (MAVSDK's 1 Hz heartbeat, 20 Hz offboard re-send) can
    trip PX4's link-loss / offboard-loss failsafes (measured: bench/results_trials.md §7): `trials run` says so in
    one line before flying, and says nothing at 8x or for in-process pilots (whose clock has no wall timers)."""
    from viva_sitl.evaluation.cli import fast_external_note

    external = "{python} -c pass"
    assert fast_external_note(external, 8.0) is None
    assert fast_external_note("descend", 32.0) is None
    note = fast_external_note(external, 16.0)
    assert note is not None and "16x" in note and "COM_DL_LOSS_T" in note
    # the real command: an external pilot that exits at once, one trial at --speed 16
    proc = subprocess.run(
        [sys.executable, "-m", "viva_sitl", "trials", "run", str(SPEC_DIR / "synthetic_emergency.toml"),
         "--pilot", external, "--n", "1", "--speed", "16", "--no-progress", "-o", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=120, cwd=REPO,
    )  # fmt: skip
    lines = [ln for ln in proc.stderr.splitlines() if "wall-clock timers" in ln]
    assert lines == [f"viva-sitl trials: {note}"], proc.stderr
    assert (tmp_path / "out" / "results.csv").is_file()  # it still flies: a note, not a refusal
