"""`viva-sitl trials fly SPEC --trial K`: a person flies trial K, on the external-program path with no program.

    viva-sitl trials fly configs/trials/synthetic_emergency.toml --trial 3 -o out/me
    viva-sitl trials compare out/me out/descend        # paired with a program's campaign over the same spec/seed

Scenario K is drawn from (spec, seed) exactly as `trials run` draws it; the trial is `run_external_trial` (its own
`viva-sitl run --scenario`, the same TrialMonitor end conditions, the same scorer) with its dashboard, VAC video and
MAVLink ports open to the person instead of a pilot process: the dashboard page (buttons, keys, gamepad), or
QGroundControl on the ground-station port. Real time by default (speed 1). OUT_DIR gets what a one-trial campaign
gets (results.json / results.csv / report.html with one row, pilot "human"; trials/NNNN/ with the trial logs) plus
the run recording (run.json, trajectory.csv, telemetry.tlog) that `viva-sitl replay OUT_DIR/trials/NNNN` opens.
Ctrl-C ends the trial as "aborted": the logs are written and the row is scored all the same.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from viva_sitl.evaluation.campaign import Campaign, _save_row, trial_dir
from viva_sitl.evaluation.external import run_external_trial
from viva_sitl.evaluation.report import write_reports
from viva_sitl.evaluation.results import as_row
from viva_sitl.evaluation.spec import Scenario, TrialSpec, draw_scenarios

HUMAN_READY_PREFIX = "viva-sitl trials fly ready:"
QGC_GCS_PORT = 14550  # where QGroundControl listens by default: it connects by itself
MAVSDK_API_PORT = 14540  # where a MAVSDK app listens by default (udpin://0.0.0.0:14540)
QGC_VIDEO_PORT = 5600  # where QGroundControl's video widget listens for H.264 RTP by default


def pick_scenario(spec: TrialSpec, index: int, n: int | None = None, seed: int | None = None) -> Scenario:
    """Scenario `index` of (spec, n, seed): the one `trials run --trial index` flies."""
    scenarios = draw_scenarios(spec, n, seed)
    if not 0 <= index < len(scenarios):
        raise ValueError(f"--trial {index}: no such trial (0..{len(scenarios) - 1})")
    return scenarios[index]


def describe(sc: Scenario) -> str:
    where = f"N{sc.north_m:.1f} E{sc.east_m:.1f}"
    if sc.start == "air":
        what = f"air start at {where} alt {sc.altitude_m:.1f} m holding; land now at {sc.land_at_s:.1f} s"
    else:
        what = f"ground start at {where}; take off to {sc.altitude_m:.1f} m, land when told ({sc.land_at_s:.1f} s)"
    fails = ", ".join(f"{f.kind} at {f.at_s:.1f} s" for f in sc.failures)
    return f"{what}{'; ' + fails if fails else ''}; timeout {sc.timeout_s:g} s"


def _ready_line(spec: TrialSpec, sc: Scenario, sitl_ready: str) -> str:
    # the vehicle's own ready line minus its head: mavlink/gcs ports, tlog, video SDPs, frames, dashboard URL
    parts = sitl_ready.split(" | ")[1:]
    return " | ".join(
        [f"{HUMAN_READY_PREFIX} trial {sc.index} of {spec.name} (seed {sc.seed}, footage {sc.footage}): "
         f"{describe(sc)}", f"speed {spec.speed:g}", *parts]
    )  # fmt: skip


def fly_trial(
    spec: TrialSpec,
    index: int,
    out_dir: Path | str,
    *,
    n: int | None = None,
    seed: int | None = None,
    speed: float = 1.0,
    pilot: str = "human",
    dashboard_port: int | None = None,
    api_port: int | None = MAVSDK_API_PORT,
    gcs_port: int | None = QGC_GCS_PORT,
    video_port: int | None = QGC_VIDEO_PORT,
    say: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Fly scenario `index` with a person as the pilot; write OUT_DIR as a one-trial campaign; return the row."""
    sc = pick_scenario(spec, index, n, seed)
    out = Path(out_dir)
    if (out / "results.json").exists():
        raise ValueError(f"{out} holds a result already: give this flight its own output directory (-o)")
    out.mkdir(parents=True, exist_ok=True)
    # a person flies on the wall clock: there is no pilot process whose computing lockstep could wait for
    flown = dataclasses.replace(spec, speed=speed, timing="realtime")
    tdir = trial_dir(out, sc.index)
    tdir.mkdir(parents=True, exist_ok=True)
    sc.write(tdir / "scenario.json")
    sitl_args = ["--dashboard-port", str(dashboard_port)] if dashboard_port is not None else []

    def ready(line: str) -> None:
        say(_ready_line(flown, sc, line))
        say("  open the dashboard, Take control (key C) and fly: the buttons, the keys listed on the page (M arm, "
            "T take off, L land, H hold, 1-4 modes, W/S A/D Q/E R/F sticks), a gamepad, or QGroundControl on the "
            "gcs port. The trial ends on touchdown + disarm, a crash, leaving the footage or the timeout; "
            "Ctrl-C aborts it (logs and score kept).", )  # fmt: skip

    scored = run_external_trial(
        flown, sc, None, tdir, frames=True, api_port=api_port, gcs_port=gcs_port, video_port=video_port, sitl_args=sitl_args,
        on_ready=ready, abort_on_interrupt=True,
        wall_limit_s=90.0 + 3.0 * spec.timeout_s / speed,
    )  # fmt: skip
    scored["pilot"] = pilot
    row = as_row(scored)
    camp = Campaign(flown, pilot, [sc], out, backend="human", jobs=1)
    camp.rows[sc.index] = row
    _save_row(out, sc, row)
    write_reports(camp)
    return row


__all__ = ["HUMAN_READY_PREFIX", "describe", "fly_trial", "pick_scenario"]
