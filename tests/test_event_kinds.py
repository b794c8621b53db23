"""EventKind: trial event kinds are enum members in code and the plain strings on disk (events.jsonl unchanged);
a kind read back that this version does not write is one clear error, as an unknown end reason is (an external
trial whose log cannot be read ends sitl_error, naming the event)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.events import EventKind
from viva_sitl.evaluation.monitor import TrialLog
from viva_sitl.evaluation.runner import run_inprocess_trial
from viva_sitl.evaluation.spec import draw_scenarios, spec_from_dict

SPEC = {
    "trials": {"name": "kinds", "n": 1, "seed": 3, "timeout_s": 40.0},
    "scenario": {
        "footage": "synthetic", "start": "air", "north_m": [-10.0, 10.0], "east_m": [-10.0, 10.0],
        "altitude_m": [9.0, 10.0], "land_at_s": 1.0, "params": {"NAV_DLL_ACT": 3, "COM_DL_LOSS_T": 5},
        "failures": [{"kind": "battery_critical", "at_s": 0.5}, {"kind": "gcs_link_lost", "at_s": 0.6}],
    },
}  # fmt: skip


def test_every_kind_a_real_trial_writes_is_a_member(tmp_path: Path) -> None:
    """A real short in-process trial (descend pilot, land now, two injected failures, a failsafe): every kind in
    its events.jsonl is an EventKind value written as the plain string, read back as the member, and writing the
    read log again gives the same bytes."""
    spec = spec_from_dict(json.loads(json.dumps(SPEC)), "kinds")
    sc = draw_scenarios(spec, 1)[0]
    row = run_inprocess_trial(spec, sc, "descend", tmp_path)
    assert row["end"] == "landed", row
    raw = (tmp_path / "events.jsonl").read_bytes()
    kinds = [json.loads(x)["kind"] for x in raw.decode().splitlines()]
    assert all(type(k) is str for k in kinds)
    assert set(kinds) <= {k.value for k in EventKind}, set(kinds) - {k.value for k in EventKind}
    expected = {EventKind.START, EventKind.LAND_NOW, EventKind.FAILURE, EventKind.FAILSAFE, EventKind.MODE}
    expected |= {EventKind.AUTOPILOT, EventKind.TOUCHDOWN, EventKind.END}
    assert expected <= set(kinds), set(kinds)
    log = TrialLog.read(tmp_path)
    assert all(type(e["kind"]) is EventKind for e in log.events)
    out = tmp_path / "again"
    log.write(out)
    assert (out / "events.jsonl").read_bytes() == raw


def test_kinds_serialise_as_their_plain_names() -> None:
    assert json.dumps({"kind": EventKind.LAND_NOW}) == '{"kind": "land_now"}'
    assert f"{EventKind.FAILSAFE:10s}|" == "failsafe  |"  # `trials show`'s column
    assert EventKind.FAILSAFE == "failsafe" and "failsafe" in (
        EventKind.FAILSAFE,
    )  # old pilot code still matches
    assert len({k.value for k in EventKind}) == len(EventKind)


def test_an_unknown_kind_read_back_is_one_clear_error(tmp_path: Path) -> None:
    TrialLog(end=TrialEnd.LANDED, end_detail="x").write(tmp_path)
    events = [
        {"t_s": 0.0, "kind": "start", "text": "s", "severity": 6},
        {"t_s": 1.0, "kind": "teleport", "text": "t", "severity": 6},
    ]
    (tmp_path / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events))
    with pytest.raises(
        ValueError, match=r"events.jsonl event 2: unknown event kind 'teleport' \(known: start, "
    ) as err:
        TrialLog.read(tmp_path)
    assert "\n" not in str(err.value)
    (tmp_path / "events.jsonl").write_text(json.dumps({"t_s": 0.0, "text": "no kind", "severity": 6}) + "\n")
    with pytest.raises(ValueError, match="event 1: unknown event kind None"):
        TrialLog.read(tmp_path)
