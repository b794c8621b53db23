"""Per-trial scores from a TrialLog and the footage's ground truth (WorldModel). Pure.

Result row, schema `vivasitl.trials.v2` (one row per trial in results.csv / results.json; units in the names;
null = unavailable, never zero):

    trial, pilot, seed, footage, start                  the scenario (the full scenario is in results.json)
    start_north_m, start_east_m, start_altitude_m, start_yaw_deg, footage_time_s, land_at_s, wind_speed_m_s,
    failures                                            injected failures, "kind@t_s;..."
    end                                                 landed | crash | left_footage | timeout | pilot_error |
                                                        wall_timeout | sitl_error | sitl_stopped | aborted |
                                                        worker_died | trial_error (docs/trials-results.md)
    end_detail, end_t_s                                 why, and when (s after the start)
    landed                                              true when end == landed (touchdown + disarm)
    touchdown_north_m, touchdown_east_m                 the last touchdown (null: none)
    touchdown_vertical_speed_m_s, touchdown_horizontal_speed_m_s, touchdown_speed_m_s   the step before contact
    dist_person_m, dist_vehicle_m                       horizontal distance to the nearest person / vehicle at
                                                        touchdown (null: no touchdown, nobody of that class in the
                                                        footage, or the class was not annotated: the footage
                                                        metadata's `annotated` list does not name it)
    min_dist_person_m, min_dist_vehicle_m               minimum over the final descent (below
                                                        final_descent_below_m above ground, to touchdown or end)
    dist_object_m, min_dist_object_m                    the same to the nearest tracked object of any class:
                                                        people, vehicles, "other" and the motion-derived tracks
                                                        of `footage annotate --method motion` ("moving object");
                                                        available only where people and vehicles were both
                                                        annotated (or "all")
    risk_level                                          1..5 under the touchdown point at touchdown time
    time_to_land_s                                      touchdown - "land now" (null: no touchdown)
    flight_time_s, path_length_m, energy_wh, time_outside_footage_s
    failsafes, failsafe_texts                           count and "; "-joined texts of failsafe events
    gt_objects, gt_risk                                 the footage has object tracks / a risk map
    persons_present, vehicles_present, objects_present  any person / vehicle / object in the footage's tracks (null:
                                                        no tracks, or that class was not annotated: unknown)
    success                                             the criterion: false when a check it could judge failed;
                                                        null ("unscored") when none failed but one could not be
                                                        judged (its score unavailable); true only when every check
                                                        was judged and passed
    criterion_failures                                  which checks failed ("; "-joined)
    criterion_unavailable                               which checks could not be judged, and why ("; "-joined)
    timing                                              the trial's clock: lockstep (in-process pilots, and
                                                        external ones with timing = "lockstep"), charged, realtime
    pilot_cpu_factor                                    charged: sim s billed per CPU s of the pilot (else null)
    pilot_latency_ms                                    charged: the fixed latency per frame (else null)
    pilot_cpu_s, pilot_run_delay_s                      external pilots: CPU seconds its processes used, and
                                                        seconds they were runnable with no CPU (machine load)
    timing_ok                                           false: the result depended on the machine (realtime: the
                                                        pilot was starved of CPU; lockstep/charged: the pilot was
                                                        never idle, or no pilot process could be watched)
    wall_s                                              wall time of the trial (the only non-deterministic column
                                                        of in-process trials; external: see timing.py)

v2 (from v1): + dist_object_m, min_dist_object_m, objects_present. v3 (from v2): + criterion_unavailable; person /
vehicle / object scores and *_present are null where the footage did not annotate the class (v2 said "none
present" and passed the criterion). v4 (from v3): + timing, pilot_cpu_factor, pilot_latency_ms, pilot_cpu_s, pilot_run_delay_s,
timing_ok. report.read_results reads v1-v3 files too (the new columns null).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Literal, TypedDict

import numpy as np

from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.events import EventKind
from viva_sitl.evaluation.monitor import TRAJECTORY_COLUMNS, TrialLog
from viva_sitl.evaluation.spec import Criterion, Scenario, TrialSpec
from viva_sitl.world import ALL, PEOPLE, VEHICLES, WorldModel

SCHEMA = "vivasitl.trials.v4"
# readable: rows lack the columns added since
OLDER_SCHEMAS = ("vivasitl.trials.v1", "vivasitl.trials.v2", "vivasitl.trials.v3")
COLUMNS = (
    "trial", "pilot", "seed", "footage", "start", "start_north_m", "start_east_m", "start_altitude_m",
    "start_yaw_deg", "footage_time_s", "land_at_s", "wind_speed_m_s", "failures", "end", "end_detail", "end_t_s",
    "landed", "touchdown_north_m", "touchdown_east_m", "touchdown_vertical_speed_m_s",
    "touchdown_horizontal_speed_m_s", "touchdown_speed_m_s", "dist_person_m", "dist_vehicle_m", "min_dist_person_m",
    "min_dist_vehicle_m", "dist_object_m", "min_dist_object_m", "risk_level", "time_to_land_s", "flight_time_s",
    "path_length_m", "energy_wh", "time_outside_footage_s", "failsafes", "failsafe_texts", "gt_objects", "gt_risk", "persons_present",
    "vehicles_present", "objects_present", "success", "criterion_failures", "criterion_unavailable", "timing", "pilot_cpu_factor", "pilot_latency_ms", "pilot_cpu_s",
    "pilot_run_delay_s", "timing_ok", "wall_s",
)  # fmt: skip
_I = {c: k for k, c in enumerate(TRAJECTORY_COLUMNS)}


class ScoreRow(TypedDict):
    """One trial's row as this version writes it: the keys are COLUMNS, in order (a test holds them equal), so
    mypy checks every producer's keys and values. At run time a plain dict: results.json / results.csv are what
    the untyped dict gave. Rows read back from disk (any schema version) are results.Row (dict[str, Any])."""

    trial: int
    pilot: str | None  # set by whoever ran the trial (campaign, human, gym); None from score_trial
    seed: int
    footage: str
    start: str
    start_north_m: float
    start_east_m: float
    start_altitude_m: float
    start_yaw_deg: float
    footage_time_s: float
    land_at_s: float
    wind_speed_m_s: float | None
    failures: str
    end: TrialEnd | None
    end_detail: str
    end_t_s: float | None
    landed: bool
    touchdown_north_m: float | None
    touchdown_east_m: float | None
    touchdown_vertical_speed_m_s: float | None
    touchdown_horizontal_speed_m_s: float | None
    touchdown_speed_m_s: float | None
    dist_person_m: float | None
    dist_vehicle_m: float | None
    min_dist_person_m: float | None
    min_dist_vehicle_m: float | None
    dist_object_m: float | None
    min_dist_object_m: float | None
    risk_level: int | None
    time_to_land_s: float | None
    flight_time_s: float | None
    path_length_m: float | None
    energy_wh: float | None
    time_outside_footage_s: float | None
    failsafes: int | None
    failsafe_texts: str
    gt_objects: bool
    gt_risk: bool
    persons_present: bool | None
    vehicles_present: bool | None
    objects_present: bool | None
    success: bool | None
    criterion_failures: str
    criterion_unavailable: str
    timing: str
    pilot_cpu_factor: float | None
    pilot_latency_ms: float | None
    pilot_cpu_s: float | None
    pilot_run_delay_s: float | None
    timing_ok: bool | None
    wall_s: float | None


# the distance scores of each ground-truth group: (touchdown, minimum over the final descent)
_DIST_KEYS: dict[str, tuple[Literal["dist_person_m", "dist_vehicle_m", "dist_object_m"],
                            Literal["min_dist_person_m", "min_dist_vehicle_m", "min_dist_object_m"]]] = {
    "person": ("dist_person_m", "min_dist_person_m"),
    "vehicle": ("dist_vehicle_m", "min_dist_vehicle_m"),
    "object": ("dist_object_m", "min_dist_object_m"),
}  # fmt: skip


def _r(x: float | None, nd: int = 4) -> float | None:
    if x is None or not math.isfinite(x):
        return None
    return round(float(x), nd)


def _dist(world: WorldModel, n: np.ndarray, e: np.ndarray, t: np.ndarray, classes: Any) -> float:
    return float(np.min(world.tracks.distances_along(n, e, t, classes))) if n.size else math.inf


def score_trial(scenario: Scenario, log: TrialLog, world: WorldModel | None, spec: TrialSpec) -> ScoreRow:
    sc = scenario
    fs = [e["text"] for e in log.events if e["kind"] == EventKind.FAILSAFE]
    gt_obj = world is not None and world.has_objects
    gt_risk = world is not None and world.has_risk_map
    row = ScoreRow(
        trial=sc.index, pilot=None, seed=sc.seed, footage=sc.footage, start=sc.start, start_north_m=sc.north_m,
        start_east_m=sc.east_m, start_altitude_m=sc.altitude_m, start_yaw_deg=sc.yaw_deg,
        footage_time_s=sc.footage_time_s, land_at_s=sc.land_at_s,
        wind_speed_m_s=_r(math.hypot(sc.wind_ned_m_s[0], sc.wind_ned_m_s[1])),
        failures=";".join(f"{f.kind}@{f.at_s:g}" for f in sc.failures),
        end=log.end, end_detail=log.end_detail, end_t_s=_r(log.end_t_s), landed=log.end == TrialEnd.LANDED,
        touchdown_north_m=None, touchdown_east_m=None, touchdown_vertical_speed_m_s=None,
        touchdown_horizontal_speed_m_s=None, touchdown_speed_m_s=None, dist_person_m=None, dist_vehicle_m=None,
        min_dist_person_m=None, min_dist_vehicle_m=None, dist_object_m=None, min_dist_object_m=None,
        risk_level=None, time_to_land_s=None,
        flight_time_s=_r(log.end_t_s), path_length_m=_r(log.path_m, 3), energy_wh=_r(log.energy_wh, 5),
        time_outside_footage_s=_r(log.outside_s, 3), failsafes=len(fs), failsafe_texts="; ".join(fs),
        gt_objects=gt_obj, gt_risk=gt_risk, persons_present=None, vehicles_present=None, objects_present=None,
        success=None, criterion_failures="", criterion_unavailable="",
        timing="lockstep", pilot_cpu_factor=None, pilot_latency_ms=None, pilot_cpu_s=None, pilot_run_delay_s=None, timing_ok=True,
        wall_s=None,
    )  # fmt: skip
    # which groups the object ground truth can answer (annotated classes): the others stay null (unknown)
    ans = {g: gt_obj and world is not None and world.answers(g) for g in ("person", "vehicle", "object")}
    if gt_obj:
        assert world is not None
        counts = world.tracks.count_by_class()
        if ans["person"]:
            row["persons_present"] = any(k in ("person", "bicycle") and v > 0 for k, v in counts.items())
        if ans["vehicle"]:
            row["vehicles_present"] = any(k in ("car", "bus", "truck") and v > 0 for k, v in counts.items())
        if ans["object"]:
            row["objects_present"] = any(v > 0 for v in counts.values())
    td = log.touchdown
    if td is not None:
        row["touchdown_north_m"], row["touchdown_east_m"] = _r(td.north_m), _r(td.east_m)
        row["touchdown_vertical_speed_m_s"] = _r(td.vertical_speed_m_s)
        row["touchdown_horizontal_speed_m_s"] = _r(td.horizontal_speed_m_s)
        row["touchdown_speed_m_s"] = _r(math.hypot(td.vertical_speed_m_s, td.horizontal_speed_m_s))
        if log.land_now_t_s is not None and td.t_s >= log.land_now_t_s:
            row["time_to_land_s"] = _r(td.t_s - log.land_now_t_s)
    # the final descent: samples below the height after the last time above it, up to touchdown (or the end)
    rows = log.rows
    if rows and world is not None:
        arr = np.array(
            [[r[_I["t_s"]], r[_I["north_m"]], r[_I["east_m"]], r[_I["down_m"]]] for r in rows], float
        )
        t_end = td.t_s if td is not None else log.end_t_s
        arr = arr[arr[:, 0] <= t_end + 1e-9]
        alt = -arr[:, 3]
        above = np.nonzero(alt > spec.final_descent_below_m)[0]
        first = int(above[-1]) + 1 if above.size else 0
        seg = arr[first:]
        if td is not None:
            seg = np.vstack([seg, [[td.t_s, td.north_m, td.east_m, 0.0]]])
        ft = seg[:, 0] + sc.footage_time_s  # footage clock
        groups = [
            (g, cls) for g, cls in (("person", PEOPLE), ("vehicle", VEHICLES), ("object", ALL)) if ans[g]
        ]
        if seg.size:
            for g, cls in groups:
                row[_DIST_KEYS[g][1]] = _r(_dist(world, seg[:, 1], seg[:, 2], ft, cls), 3)
        if td is not None:
            tft = td.t_s + sc.footage_time_s
            for g, cls in groups:
                row[_DIST_KEYS[g][0]] = _r(world.tracks.distance_m(td.north_m, td.east_m, tft, cls), 3)
            if gt_risk:
                row["risk_level"] = int(world.risk_at(td.north_m, td.east_m, tft))
    row["success"], fails, unknown = judge_checks(row, spec.criterion)
    row["criterion_failures"] = "; ".join(fails)
    row["criterion_unavailable"] = "; ".join(unknown)
    return row


# the checks a criterion makes: (name, the row's score, the *_present column, the ground-truth class group)
DIST_CHECKS = (("min_dist_person_m", "dist_person_m", "persons_present", "people"),
               ("min_dist_vehicle_m", "dist_vehicle_m", "vehicles_present", "vehicles"),
               ("min_dist_object_m", "dist_object_m", "objects_present", "objects"))  # fmt: skip


def check_outcomes(row: Mapping[str, Any], c: Criterion) -> list[tuple[str, bool | None, str]]:
    """Every check of the criterion on one row: (check, passed | None when it cannot be judged, why). A check
    cannot be judged when the score it needs is unavailable: no ground truth of that kind, or the class was not
    annotated in the footage (then "nobody of that class" is unknown, not true)."""
    out: list[tuple[str, bool | None, str]] = []
    if c.landed:
        out.append(("landed", bool(row["landed"]), "" if row["landed"] else f"not landed ({row['end']})"))
    if c.max_touchdown_speed_m_s is not None:
        v = row["touchdown_speed_m_s"]
        ok = v is not None and v < c.max_touchdown_speed_m_s
        why = "" if ok else (f"touchdown speed {v} >= {c.max_touchdown_speed_m_s:g} m/s" if v is not None
                             else "no touchdown")  # fmt: skip
        out.append(("touchdown_speed_m_s", ok, why))
    for (mkey, key, present, group), lim in zip(
        DIST_CHECKS, (c.min_dist_person_m, c.min_dist_vehicle_m, c.min_dist_object_m), strict=True
    ):
        if lim is None:
            continue
        if not row["gt_objects"]:
            out.append((mkey, None, f"{mkey}: the footage has no object tracks"))
        elif row.get(present) is None:
            out.append((mkey, None, f"{mkey}: {group} not annotated in this footage"))
        elif row[present] is False:
            out.append((mkey, True, ""))  # annotated, and nobody of that class in the footage: satisfied
        elif row[mkey] is not None and row[mkey] < lim:
            out.append((mkey, False, f"{mkey} {row[mkey]} < {lim:g}"))
        elif row[key] is not None and row[key] < lim:
            out.append((mkey, False, f"{key} {row[key]} < {lim:g}"))
        else:
            out.append((mkey, True, ""))
    if c.max_risk_level is not None:
        lv = row["risk_level"]
        if not row["gt_risk"]:
            out.append(("risk_level", None, "risk_level: the footage has no risk map"))
        elif lv is not None and lv > c.max_risk_level:
            out.append(("risk_level", False, f"risk_level {lv} > {c.max_risk_level}"))
        else:  # (no touchdown: the landed / touchdown speed checks fail instead)
            out.append(("risk_level", True, ""))
    return out


def judge_checks(row: Mapping[str, Any], c: Criterion) -> tuple[bool | None, list[str], list[str]]:
    """(success, failed checks, checks that could not be judged). Success is False when any judged check failed
    (a failure stands whatever the others say), None ("unscored") when none failed but one could not be judged
    (a success that rests on an unanswerable check is no success), True only when every check passed."""
    res = check_outcomes(row, c)
    fails = [why for _, ok, why in res if ok is False]
    unknown = [why for _, ok, why in res if ok is None]
    if fails:
        return False, fails, unknown
    return (None if unknown else True), fails, unknown


def judge(row: Mapping[str, Any], c: Criterion) -> tuple[bool | None, list[str]]:
    """(success, failed checks) of one row under a criterion (judge_checks without the unjudged list)."""
    ok, fails, _ = judge_checks(row, c)
    return ok, fails
