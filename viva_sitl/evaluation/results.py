"""A campaign's results on disk: OUT/trials/NNNN/result.json per finished trial (its row and scenario), and what ran
(the run record results.json and the report carry). campaign.py runs trials into it; report.py reads it.

The run record (results.json "run"): spec_hash (the spec as run, its file path, n, seed and default pilot left
out: those are recorded on their own), seed, n, pilot, pilot_kind, timing, speed, versions. `--resume` continues a
run only when spec_hash, seed, n, pilot and timing are the same (`check_out_dir`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import platform
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from viva_sitl.evaluation.ends import INFRA_ENDS
from viva_sitl.evaluation.scoring import SCHEMA, ScoreRow
from viva_sitl.evaluation.spec import Scenario, TrialSpec

# a row as stored and read back (results.json, result.json; any schema version: older ones lack columns). What
# this version produces is scoring.ScoreRow; as_row hands one over to the code that reads rows by any key.
Row = dict[str, Any]


def as_row(row: ScoreRow) -> Row:
    """The typed row as a plain row (a copy, in column order)."""
    return dict(row)


# what `--resume` must find equal in the run record of OUT
RESUME_KEYS = ("spec_hash", "seed", "n", "pilot", "timing")
# the pilot-side packages whose versions the run record names when this interpreter has them
KEY_PACKAGES = ("mavsdk", "pymavlink")


def is_infra(row: Row) -> bool:
    return row.get("end") in INFRA_ENDS


def mark_infra(row: Row) -> Row:
    """An infrastructure error judges nothing: success unknown (null), no failed check named."""
    if is_infra(row):
        row["success"] = None
        row["criterion_failures"] = ""
    return row


@dataclass
class Campaign:
    spec: TrialSpec  # as run: its n and seed are the ones drawn from (--n / --seed applied)
    pilot: str
    scenarios: list[Scenario]
    out_dir: Path
    rows: dict[int, Row] = field(default_factory=dict)
    interrupted: bool = False
    backend: str = "local"
    jobs: int = 1
    timing: str | None = None  # what clock the trials ran on (None: from the pilot's kind and the spec)

    @property
    def complete(self) -> bool:
        return len(self.rows) == len(self.scenarios)

    def ordered_rows(self) -> list[Row]:
        return [self.rows[s.index] for s in self.scenarios if s.index in self.rows]

    def infra_errors(self) -> list[Row]:
        """The finished trials that failed in the harness (INFRA_ENDS), in trial order."""
        return [r for r in self.ordered_rows() if is_infra(r)]

    def run_record(self) -> dict[str, Any]:
        return run_record(self.spec, self.pilot, self.timing, human=self.backend == "human")


def spec_hash(spec: TrialSpec) -> str:
    """sha256 of the spec as run, less what is recorded on its own (n, seed, default pilot) and its file path."""
    d = dataclasses.asdict(spec)
    for key in ("source", "n", "seed", "pilot"):
        d.pop(key, None)
    d.pop("ulog", None)  # whether trials write a ULog changes no result (and keeps older runs' hashes)
    text = json.dumps(d, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _dist_version(name: str) -> str | None:
    from importlib import metadata

    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None
    except Exception:  # noqa: BLE001 - a broken installation's metadata: unknown, not a failed run
        return None


def _pilot_package(pilot: str) -> tuple[str, str] | None:
    """An in-process `package.module:Class` pilot's installed distribution and version (None: not installed)."""
    from importlib import metadata

    mod = pilot.partition(":")[0].split(".")[0]
    if not mod or mod == "viva_sitl":
        return None
    try:
        dists = metadata.packages_distributions().get(mod, [])
    except Exception:  # noqa: BLE001
        return None
    for dist in dists:
        v = _dist_version(dist)
        if v is not None:
            return dist, v
    return None


def versions(pilot: str) -> dict[str, str]:
    """viva-sitl, Python and the pilot's key packages as this interpreter has them (external pilots started with
    {python} use these; another interpreter may have others)."""
    from viva_sitl import __version__
    from viva_sitl.evaluation.pilots import is_inprocess

    out = {"viva-sitl": __version__, "python": platform.python_version()}
    for name in KEY_PACKAGES:
        v = _dist_version(name)
        if v is not None:
            out[name] = v
    if is_inprocess(pilot):
        pkg = _pilot_package(pilot)
        if pkg is not None:
            out[pkg[0]] = pkg[1]
    return out


def run_record(
    spec: TrialSpec, pilot: str, timing: str | None = None, *, human: bool = False
) -> dict[str, Any]:
    """timing: the clock the trials ran on (None: an in-process pilot is stepped in lockstep, its computing not
    billed; an external one runs on the spec's trials.timing; a person flies in realtime)."""
    from viva_sitl.evaluation.pilots import is_inprocess

    kind = "human" if human else "in-process" if is_inprocess(pilot) else "external"
    if timing is None:
        timing = "realtime" if human else "lockstep" if kind == "in-process" else spec.timing
    return {
        "spec_name": spec.name, "spec_hash": spec_hash(spec), "seed": spec.seed, "n": spec.n, "pilot": pilot, "pilot_kind": kind,
        "timing": timing, "pilot_cpu_factor": spec.pilot_cpu_factor if timing == "charged" else None,
        "pilot_latency_ms": spec.pilot_latency_ms if timing == "charged" else None,
        "speed": spec.speed, "versions": versions(pilot), "python_executable": sys.executable,
    }  # fmt: skip


def trial_dir(out_dir: Path, index: int) -> Path:
    return out_dir / "trials" / f"{index:04d}"


def finished_trials(out_dir: Path) -> list[int]:
    """Indices of the trials with a result.json under OUT/trials (the folders trial_dir names), sorted."""
    try:
        dirs = list((out_dir / "trials").iterdir())
    except OSError:
        return []
    return sorted(int(d.name) for d in dirs if d.name.isdigit() and (d / "result.json").is_file())


def load_finished(
    out_dir: Path, scenarios: list[Scenario], pilot: str, *, keep_infra: bool = False
) -> dict[int, Row]:
    """Rows already on disk whose scenario and pilot match (for --resume); infrastructure errors are left out, so
    --resume runs those trials again (keep_infra: kept, for trials this run does not run again)."""
    out: dict[int, Row] = {}
    for sc in scenarios:
        d = trial_dir(out_dir, sc.index)
        try:
            res = json.loads((d / "result.json").read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            continue
        row = res.get("row", {})
        if (
            res.get("scenario") == sc.to_dict()
            and row.get("pilot") == pilot
            and (keep_infra or not is_infra(row))
        ):
            out[sc.index] = row
    return out


def _save_row(out_dir: Path, sc: Scenario, row: Row) -> None:
    d = trial_dir(out_dir, sc.index)
    d.mkdir(parents=True, exist_ok=True)
    tmp = d / "result.json.tmp"
    tmp.write_text(json.dumps({"schema": SCHEMA, "scenario": sc.to_dict(), "row": row}, indent=1))
    os.replace(tmp, d / "result.json")  # atomic: an interrupted write never leaves half a result


# ----------------------------------------------------------------------------------------- what OUT holds

REPORT_FILES = ("results.json", "results.csv", "report.html")


def _held(out: Path) -> tuple[bool, dict[str, Any] | None]:
    """(OUT holds results, its results.json when readable)."""
    doc: dict[str, Any] | None = None
    try:
        loaded = json.loads((out / "results.json").read_text())
        doc = loaded if isinstance(loaded, dict) else None
        present = True
    except FileNotFoundError:
        present = False
    except (OSError, ValueError):
        present = (out / "results.json").is_file()  # there but unreadable: still someone's results
    return present or bool(finished_trials(out)), doc


def _describe(doc: dict[str, Any] | None) -> str:
    if doc is None:
        return "results"
    run = doc.get("run") if isinstance(doc.get("run"), dict) else {}
    spec = doc.get("spec") if isinstance(doc.get("spec"), dict) else {}
    assert isinstance(run, dict) and isinstance(spec, dict)
    seed = run.get("seed", spec.get("seed"))
    n = run.get("n", spec.get("n"))
    return (f"the results of pilot {doc.get('pilot')!r} on spec {spec.get('name')!r} (seed {seed}, n {n}; "
            f"{doc.get('trials_done')} of {doc.get('trials_total')} trials)")  # fmt: skip


def _differences(doc: dict[str, Any], record: dict[str, Any]) -> str:
    """'' when the run in OUT (its results.json) is the run of `record`, else what differs, in words."""
    held = doc.get("run")
    if isinstance(held, dict):
        keys: tuple[str, ...] = RESUME_KEYS
        now = record
    else:  # written before run records: the pilot and the spec name are all there is
        spec = doc.get("spec") if isinstance(doc.get("spec"), dict) else {}
        held = {"pilot": doc.get("pilot"), "spec_name": spec.get("name") if isinstance(spec, dict) else None}
        keys, now = ("pilot", "spec_name"), record
    return "; ".join(
        f"{k} {held.get(k)!r} there, {now.get(k)!r} here" for k in keys if held.get(k) != now.get(k)
    )


def check_out_dir(out: Path, record: dict[str, Any], *, resume: bool, force: bool) -> None:
    """ValueError (one line) when OUT holds results this run must not overwrite: any results without --resume or
    --force; with --resume, a run whose spec_hash, seed, n, pilot or timing differ from `record`."""
    present, doc = _held(out)
    if not present or force:
        return
    diff = _differences(doc, record) if doc is not None else None
    if not resume:
        if diff == "":
            raise ValueError(
                f"{out} holds this run already ({doc.get('trials_done')} of {doc.get('trials_total')} trials): "  # type: ignore[union-attr]
                "--resume completes it, --force runs it again"
            )
        raise ValueError(
            f"{out} holds {_describe(doc)}{f' ({diff})' if diff else ''}: --force replaces it, or give this run "
            "its own -o"
        )
    if diff:
        raise ValueError(
            f"--resume: {out} holds a different run ({diff}): --force replaces it, or give this run its own -o"
        )
    # diff None: trial folders without a readable results.json: each trial's scenario and pilot are checked


def clear_results(out: Path) -> None:
    """--force: remove what a previous run left in OUT (its reports and trials/NNNN folders), nothing else."""
    for name in REPORT_FILES:
        (out / name).unlink(missing_ok=True)
    try:
        dirs = list((out / "trials").iterdir())
    except OSError:
        return
    for d in dirs:
        if d.name.isdigit() and d.is_dir():
            shutil.rmtree(d)


__all__ = [
    "INFRA_ENDS",
    "Campaign",
    "Row",
    "as_row",
    "check_out_dir",
    "clear_results",
    "finished_trials",
    "is_infra",
    "load_finished",
    "mark_infra",
    "run_record",
    "spec_hash",
    "trial_dir",
]
