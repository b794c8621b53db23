"""TrialEnd: the end reasons are enum members in code and the plain strings on disk."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from viva_sitl.evaluation.ends import INFRA_ENDS, TrialEnd
from viva_sitl.evaluation.monitor import TrialLog
from viva_sitl.evaluation.results import is_infra


def test_every_end_has_a_message_and_is_flown_or_infra_or_neither() -> None:
    for end in TrialEnd:
        assert end.message and end.message != end.value
        assert not (end.flown and end.infra)
    assert {e.value for e in INFRA_ENDS} == {"trial_error", "worker_died", "sitl_error", "sitl_stopped"}


def test_ends_serialise_as_their_plain_names() -> None:
    assert json.dumps({"end": TrialEnd.LEFT_FOOTAGE}) == '{"end": "left_footage"}'
    buf = io.StringIO()
    csv.writer(buf).writerow([TrialEnd.WALL_TIMEOUT, f"{TrialEnd.CRASH}: x"])
    assert buf.getvalue() == "wall_timeout,crash: x\r\n"


def test_a_row_read_back_from_json_is_judged_as_the_enum_is() -> None:
    row = json.loads(json.dumps({"end": TrialEnd.WORKER_DIED}))
    assert type(row["end"]) is str and is_infra(row) and row["end"] == TrialEnd.WORKER_DIED
    assert not is_infra({"end": "landed"})


def test_end_json_round_trip_gives_the_member(tmp_path: Path) -> None:
    TrialLog(end=TrialEnd.PILOT_ERROR, end_detail="act raised").write(tmp_path)
    assert json.loads((tmp_path / "end.json").read_text())["end"] == "pilot_error"
    log = TrialLog.read(tmp_path)
    assert log.end is TrialEnd.PILOT_ERROR
