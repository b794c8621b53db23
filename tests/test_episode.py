"""The episode seam (viva_sitl.evaluation.episode): one set-up, one footage clock, one control schedule, failures and
announcements through the autopilot's public API."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from viva_sitl.autopilot import CommandResult, Severity
from viva_sitl.autopilot.failures import FailureType, FailureUnit
from viva_sitl.config import SimConfig
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.episode import ControlSchedule, Episode, limits_of, scenario_config
from viva_sitl.evaluation.monitor import FAILURES, LAND_NOW_TEXT
from viva_sitl.evaluation.runner import footage_source, run_inprocess_trial
from viva_sitl.evaluation.spec import FAILURE_KINDS, draw_scenarios, spec_from_dict
from viva_sitl.footage.testclip import write_coded_clip
from viva_sitl.vehicle import Vehicle

SPEC = {
    "trials": {"name": "ep", "n": 2, "seed": 11, "timeout_s": 30.0},
    "scenario": {
        "footage": "synthetic", "start": "air", "north_m": [-20.0, 20.0], "east_m": [-20.0, 20.0],
        "altitude_m": [8.0, 10.0], "footage_time_s": [5.0, 40.0], "land_at_s": 0.5,
    },
}  # fmt: skip


def test_control_schedule_keeps_the_rate_exactly() -> None:
    s30 = ControlSchedule(250.0, 30.0)
    steps = [s30.steps(k) for k in range(30)]
    assert set(steps) == {8, 9} and sum(steps) == 250  # 30 control steps = one second of 250 Hz physics
    assert [ControlSchedule(250.0, 5.0).steps(k) for k in range(4)] == [50, 50, 50, 50]
    shifted = ControlSchedule(250.0, 30.0, k0=7)  # a vector env copy that started at global step 7
    assert [shifted.steps(k) for k in range(5)] == [s30.steps(7 + k) for k in range(5)]
    with pytest.raises(ValueError, match="positive rates"):
        ControlSchedule(250.0, 0.0)


def test_failure_kinds_of_specs_all_map_to_an_injection() -> None:
    assert set(FAILURES) == set(FAILURE_KINDS)


def test_inject_failure_is_gated_reversible_and_says_what_it_does_not_support() -> None:
    with Vehicle(SimConfig(), geofence=False) as v:
        ap = v.autopilot
        t = v.time_s
        out = ap.inject_failure(t, FailureUnit.SYSTEM_BATTERY, FailureType.OFF)
        assert out.result is CommandResult.DENIED and "SYS_FAILURE_EN" in out.reason  # PX4's gate
        v.params.set("SYS_FAILURE_EN", 1)
        flow = ap.inject_failure(t, FailureUnit.SENSOR_OPTICAL_FLOW, FailureType.OFF)
        assert flow.result is CommandResult.UNSUPPORTED and "SENSOR_OPTICAL_FLOW" in flow.reason
        assert ap.inject_failure(t, 77, 1).result is CommandResult.UNSUPPORTED  # no such unit
        full = ap.battery_remaining
        assert ap.inject_failure(t, FailureUnit.SYSTEM_BATTERY, FailureType.OFF).ok
        assert ap.battery_remaining == 0.0  # PX4's battery simulator: forced empty
        assert ap.inject_failure(t, FailureUnit.SYSTEM_BATTERY, FailureType.OK).ok
        assert ap.battery_remaining == full
        ap.pop_events()  # "Injected: battery off, ..." / "Cleared: battery, ..." (PX4's announcements)
        ap.announce(Severity.ALERT, LAND_NOW_TEXT)
        assert [(e.severity, e.text) for e in ap.pop_events()] == [(Severity.ALERT, LAND_NOW_TEXT)]


def test_mavlink_signal_failure_silences_the_ground_station_until_ok() -> None:
    cfg = SimConfig(params=(("COM_DL_LOSS_T", 5.0),), initial_pos_ned_m=(0.0, 0.0, -10.0))  # air start, Hold
    with Vehicle(cfg, geofence=False) as v:
        ap = v.autopilot
        ap.gcs_heartbeat(v.time_s)
        assert ap.inject_failure(
            v.time_s, FailureUnit.SYSTEM_MAVLINK_SIGNAL, FailureType.OFF, check_enabled=False
        ).ok
        texts: list[str] = []
        for _ in range(6 * 250):  # 6 s of heartbeats that are not heard
            ap.gcs_heartbeat(v.time_s)
            v.step()
            texts += [e.text for e in ap.pop_events()]
        assert "Connection to ground station lost" in texts and "Data link regained" not in texts
        assert ap.inject_failure(
            v.time_s, FailureUnit.SYSTEM_MAVLINK_SIGNAL, FailureType.OK, check_enabled=False
        ).ok
        ap.gcs_heartbeat(v.time_s)
        assert "Data link regained" in [e.text for e in ap.pop_events()]


def test_one_footage_clock_no_patched_source(tmp_path: Path) -> None:
    """Trials share a per-process FootageSource: each vehicle keeps its own footage clock (Simulator offset), the
    source is never patched, and two vehicles at different footage times over one source see their own frames."""
    clip = write_coded_clip(tmp_path / "clock.mp4", 90, 320, 240)
    (tmp_path / "clock.toml").write_text(
        'name = "clock"\nkind = "video"\npath = "clock.mp4"\nfps = 30.0\nrecording_altitude_m = 100.0\nhfov_deg = 82.1\n'
    )
    d = json.loads(json.dumps(SPEC))
    d["scenario"].update(footage=str(tmp_path / "clock.toml"), north_m=[-5.0, 5.0], east_m=[-5.0, 5.0],
                         footage_time_s=[0.5, 2.5])  # fmt: skip
    spec = spec_from_dict(d, "clock")
    a, b = draw_scenarios(spec)
    assert a.footage_time_s != b.footage_time_s and clip.is_file()
    src = footage_source(a.footage)
    va = Vehicle(scenario_config(SimConfig(), a), footage=src)
    vb = Vehicle(scenario_config(SimConfig(), b), footage=src)
    ea, eb = Episode(va, a, limits_of(spec)), Episode(vb, b, limits_of(spec))
    for _ in range(25):
        ea.step()
        eb.step()
    for ep in (ea, eb):
        want = src.frame_index_at(ep.vehicle.time_s + ep.scenario.footage_time_s)
        assert ep.vehicle.sim.footage_index() == want
        assert ep.vehicle.render().meta.footage_frame_index == want
    assert va.sim.footage_index() != vb.sim.footage_index()
    assert "frame_index_at" not in vars(src)  # nothing patched on the shared source
    row = run_inprocess_trial(spec, a, "descend", tmp_path / "t0")
    assert row["end"] == TrialEnd.LANDED and "frame_index_at" not in vars(src)


def test_land_now_is_repeated_until_the_pilot_acts_and_recorded_once(tmp_path: Path) -> None:
    """The episode tells the vehicle's STATUSTEXT stream about "land now", repeats it every 0.5 s until the pilot's
    first flight command (recorded as the "reaction"), while the trial's events hold "land now" once."""
    spec = spec_from_dict(json.loads(json.dumps(SPEC)), "ep")
    sc = draw_scenarios(spec, 1)[0]
    v = Vehicle(scenario_config(SimConfig(), sc), footage=footage_source(sc.footage))
    ep = Episode(v, sc, limits_of(spec), gcs=False)
    heard: list[float] = []

    def fly(seconds: float) -> None:
        for _ in range(round(seconds * 250)):
            v.step()
            heard.extend(
                ep.t_s for e in v.autopilot.pop_events() if e.text == LAND_NOW_TEXT
            )  # a MAVLink endpoint's
            ep.after_step()

    fly(2.9)  # land_at_s 0.5: said at 0.5, repeated at 1.0, 1.5, 2.0, 2.5
    assert len(heard) == 5 and heard[-1] - heard[0] == pytest.approx(2.0, abs=0.02), heard
    assert v.autopilot.land(v.time_s).ok  # the pilot acts
    fly(2.0)
    assert len(heard) == 5  # no repeat after the reaction
    reaction = [e for e in ep.log.events if e["kind"] == "reaction"]
    assert len(reaction) == 1 and ep.log.reaction_t_s == reaction[0]["t_s"] == pytest.approx(2.9, abs=0.01)
    assert [e["kind"] for e in ep.log.events].count("land_now") == 1
    assert not any(e["text"] == LAND_NOW_TEXT and e["kind"] == "autopilot" for e in ep.log.events)
