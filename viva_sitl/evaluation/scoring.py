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
                                                        touchdown (null: no ground truth; -1 never: none present
                                                        -> null too, see gt_objects and the *_present columns)
    min_dist_person_m, min_dist_vehicle_m               minimum over the final descent (below
                                                        final_descent_below_m above ground, to touchdown or end)
    dist_object_m, min_dist_object_m                    the same to the nearest tracked object of any class:
                                                        people, vehicles, "other" and the motion-derived tracks
                                                        of `footage annotate --method motion` ("moving object",
                                                        class unknown: counted here, not as people or vehicles)
    risk_level                                          1..5 under the touchdown point at touchdown time
    time_to_land_s                                      touchdown - "land now" (null: no touchdown)
    flight_time_s, path_length_m, energy_wh, time_outside_footage_s
    failsafes, failsafe_texts                           count and "; "-joined texts of failsafe events
    gt_objects, gt_risk                                 the footage has object tracks / a risk map
    persons_present, vehicles_present, objects_present  any person / vehicle / object in the footage's tracks
    success                                             the criterion (null when a score it needs is unavailable)
    criterion_failures                                  which checks failed ("; "-joined)
    wall_s                                              wall time of the trial (the only non-deterministic column)

v2 (from v1): + dist_object_m, min_dist_object_m, objects_present. report.read_results reads v1 files too (the new
columns null).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from viva_sitl.evaluation.monitor import TRAJECTORY_COLUMNS, TrialLog
from viva_sitl.evaluation.spec import Criterion, Scenario, TrialSpec
from viva_sitl.world import ALL, PEOPLE, VEHICLES, WorldModel

SCHEMA = "vivasitl.trials.v2"
OLDER_SCHEMAS = ("vivasitl.trials.v1",)  # readable: rows lack the columns added since
COLUMNS = (
    "trial", "pilot", "seed", "footage", "start", "start_north_m", "start_east_m", "start_altitude_m",
    "start_yaw_deg", "footage_time_s", "land_at_s", "wind_speed_m_s", "failures", "end", "end_detail", "end_t_s",
    "landed", "touchdown_north_m", "touchdown_east_m", "touchdown_vertical_speed_m_s",
    "touchdown_horizontal_speed_m_s", "touchdown_speed_m_s", "dist_person_m", "dist_vehicle_m", "min_dist_person_m",
    "min_dist_vehicle_m", "dist_object_m", "min_dist_object_m", "risk_level", "time_to_land_s", "flight_time_s",
    "path_length_m", "energy_wh", "time_outside_footage_s", "failsafes", "failsafe_texts", "gt_objects", "gt_risk", "persons_present",
    "vehicles_present", "objects_present", "success", "criterion_failures", "wall_s",
)  # fmt: skip
_I = {c: k for k, c in enumerate(TRAJECTORY_COLUMNS)}


def _r(x: float | None, nd: int = 4) -> float | None:
    if x is None or not math.isfinite(x):
        return None
    return round(float(x), nd)


def _dist(world: WorldModel, n: np.ndarray, e: np.ndarray, t: np.ndarray, classes: Any) -> float:
    return float(np.min(world.tracks.distances_along(n, e, t, classes))) if n.size else math.inf


def score_trial(
    scenario: Scenario, log: TrialLog, world: WorldModel | None, spec: TrialSpec
) -> dict[str, Any]:
    sc = scenario
    row: dict[str, Any] = {c: None for c in COLUMNS}
    row.update(
        trial=sc.index, seed=sc.seed, footage=sc.footage, start=sc.start, start_north_m=sc.north_m,
        start_east_m=sc.east_m, start_altitude_m=sc.altitude_m, start_yaw_deg=sc.yaw_deg,
        footage_time_s=sc.footage_time_s, land_at_s=sc.land_at_s,
        wind_speed_m_s=_r(math.hypot(sc.wind_ned_m_s[0], sc.wind_ned_m_s[1])),
        failures=";".join(f"{f.kind}@{f.at_s:g}" for f in sc.failures),
        end=log.end, end_detail=log.end_detail, end_t_s=_r(log.end_t_s), landed=log.end == "landed",
        flight_time_s=_r(log.end_t_s), path_length_m=_r(log.path_m, 3), energy_wh=_r(log.energy_wh, 5),
        time_outside_footage_s=_r(log.outside_s, 3),
    )  # fmt: skip
    fs = [e["text"] for e in log.events if e["kind"] == "failsafe"]
    row["failsafes"], row["failsafe_texts"] = len(fs), "; ".join(fs)
    gt_obj = world is not None and world.has_objects
    gt_risk = world is not None and world.has_risk_map
    row["gt_objects"], row["gt_risk"] = gt_obj, gt_risk
    if gt_obj:
        assert world is not None
        counts = world.tracks.count_by_class()
        row["persons_present"] = any(k in ("person", "bicycle") and v > 0 for k, v in counts.items())
        row["vehicles_present"] = any(k in ("car", "bus", "truck") and v > 0 for k, v in counts.items())
        row["objects_present"] = any(v > 0 for v in counts.values())
    td = log.touchdown
    if td is not None:
        row.update(
            touchdown_north_m=_r(td.north_m), touchdown_east_m=_r(td.east_m),
            touchdown_vertical_speed_m_s=_r(td.vertical_speed_m_s),
            touchdown_horizontal_speed_m_s=_r(td.horizontal_speed_m_s),
            touchdown_speed_m_s=_r(math.hypot(td.vertical_speed_m_s, td.horizontal_speed_m_s)),
        )  # fmt: skip
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
        if gt_obj and seg.size:
            row["min_dist_person_m"] = _r(_dist(world, seg[:, 1], seg[:, 2], ft, PEOPLE), 3)
            row["min_dist_vehicle_m"] = _r(_dist(world, seg[:, 1], seg[:, 2], ft, VEHICLES), 3)
            row["min_dist_object_m"] = _r(_dist(world, seg[:, 1], seg[:, 2], ft, ALL), 3)
        if td is not None:
            tft = td.t_s + sc.footage_time_s
            if gt_obj:
                row["dist_person_m"] = _r(world.tracks.distance_m(td.north_m, td.east_m, tft, PEOPLE), 3)
                row["dist_vehicle_m"] = _r(world.tracks.distance_m(td.north_m, td.east_m, tft, VEHICLES), 3)
                row["dist_object_m"] = _r(world.tracks.distance_m(td.north_m, td.east_m, tft, ALL), 3)
            if gt_risk:
                row["risk_level"] = int(world.risk_at(td.north_m, td.east_m, tft))
    row["success"], fails = judge(row, spec.criterion)
    row["criterion_failures"] = "; ".join(fails)
    return row


def judge(row: dict[str, Any], c: Criterion) -> tuple[bool | None, list[str]]:
    """(success, failed checks) of one row under a criterion; success None when a needed score is unavailable
    (ground truth missing) and nothing else failed."""
    fails: list[str] = []
    unknown = False
    if c.landed and not row["landed"]:
        fails.append(f"not landed ({row['end']})")
    if c.max_touchdown_speed_m_s is not None:
        v = row["touchdown_speed_m_s"]
        if v is None or v >= c.max_touchdown_speed_m_s:
            fails.append(
                f"touchdown speed {v} >= {c.max_touchdown_speed_m_s:g} m/s"
                if v is not None
                else "no touchdown"
            )
    for key, lim, present in (("dist_person_m", c.min_dist_person_m, "persons_present"),
                              ("dist_vehicle_m", c.min_dist_vehicle_m, "vehicles_present"),
                              ("dist_object_m", c.min_dist_object_m, "objects_present")):  # fmt: skip
        if lim is None:
            continue
        mkey = "min_" + key
        if not row["gt_objects"]:
            unknown = True
        elif row[present] is False:
            pass  # nobody of that class in the footage: satisfied
        elif row[mkey] is not None and row[mkey] < lim:
            fails.append(f"{mkey} {row[mkey]} < {lim:g}")
        elif row[key] is not None and row[key] < lim:
            fails.append(f"{key} {row[key]} < {lim:g}")
    if c.max_risk_level is not None:
        if not row["gt_risk"]:
            unknown = True
        elif row["risk_level"] is not None and row["risk_level"] > c.max_risk_level:
            fails.append(f"risk_level {row['risk_level']} > {c.max_risk_level}")
    if fails:
        return False, fails
    return (None if unknown else True), fails
