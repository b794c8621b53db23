"""One in-process trial: an Episode (viva_sitl.evaluation.episode: the scenario set up on a Vehicle, its control
schedule, the judged step, the score row) with a Python pilot acting on it. Pure function of (spec, scenario, pilot).

    result = run_inprocess_trial(spec, scenario, "descend", trial_dir)   # dict: scores + end + files

Footage sources and world models are cached per process (a worker runs many trials over the same footage; each
vehicle keeps its own footage clock, Simulator.footage_offset_s, so sharing a source is safe).
"""

from __future__ import annotations

import logging
import time
import traceback
from pathlib import Path
from typing import Any

import cv2

from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavCommand
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.episode import Episode, limits_of, scenario_config
from viva_sitl.evaluation.pilots import Control, Observation, make_pilot
from viva_sitl.evaluation.scoring import ScoreRow
from viva_sitl.evaluation.spec import Scenario, TrialSpec
from viva_sitl.flightlog import LOG_FILE, FlightLog
from viva_sitl.footage import FootageSource, open_footage
from viva_sitl.vehicle import Vehicle
from viva_sitl.world import WorldModel, world_from_source

log = logging.getLogger(__name__)
_SOURCES: dict[str, FootageSource] = {}
_WORLDS: dict[str, WorldModel] = {}


def footage_source(name: str) -> FootageSource:
    if name not in _SOURCES:
        _SOURCES[name] = open_footage(name)
    return _SOURCES[name]


def world_of(name: str) -> WorldModel:
    if name not in _WORLDS:
        _WORLDS[name] = world_from_source(footage_source(name))
    return _WORLDS[name]


def run_inprocess_trial(
    spec: TrialSpec,
    scenario: Scenario,
    pilot_name: str,
    trial_dir: Path,
    *,
    video: bool = False,
    wall_limit_s: float | None = None,
) -> ScoreRow:
    """Fly one trial; write trial_trajectory.csv, events.jsonl, end.json, log.ulg (+ vac.mp4 with `video`) to
    trial_dir; return the result row (scores). Never raises for a pilot's fault: the trial ends with end = pilot_error."""
    wall0 = time.perf_counter()
    trial_dir.mkdir(parents=True, exist_ok=True)
    pilot = make_pilot(pilot_name)
    src = footage_source(scenario.footage)
    world = world_of(scenario.footage)
    vehicle = Vehicle(scenario_config(SimConfig(), scenario), footage=src)
    ep = Episode(vehicle, scenario, limits_of(spec), gcs=True)
    monitor = ep.monitor
    ap = vehicle.autopilot
    ctl = Control(ap, lambda: vehicle.time_s)
    schedule = ep.schedule(float(pilot.control_hz))
    frame_hz = float(pilot.frame_hz)
    want_frames = frame_hz > 0 or video
    frame_period_s = 1.0 / (frame_hz if frame_hz > 0 else 30.0)
    next_frame_s = 0.0
    writer: cv2.VideoWriter | None = None
    # the trial's PX4 ULog (log.ulg), as `viva-sitl run` writes one, unless the spec's trials.ulog is false
    flog = _open_flight_log(trial_dir, vehicle) if spec.ulog else None
    frame = None
    cmd: EavCommand | None = None
    try:
        pilot.reset(scenario, world if pilot.uses_ground_truth else None)
    except Exception as exc:  # noqa: BLE001 - the pilot's code
        ep.end(TrialEnd.PILOT_ERROR, f"reset raised {type(exc).__name__}: {exc}")
    k = 0  # control steps
    left = 0  # physics steps left in this control step
    try:
        while not ep.done:
            t = vehicle.time_s
            if want_frames and t + 1e-9 >= next_frame_s:  # the camera runs at its own rate, not the pilot's
                next_frame_s += frame_period_s
                frame = vehicle.render(wall_time_s=0.0)
                if video:
                    writer = _write_video(
                        writer, trial_dir / "vac.mp4", frame.image_bgr, 1.0 / frame_period_s
                    )
            if left == 0:
                left = schedule.steps(k)
                k += 1
                events, monitor.new_events = monitor.new_events, []
                obs = Observation(
                    t_s=t, state=vehicle.state, armed=ap.armed, mode=ap.mode, landed_state=ap.landed_state,
                    land_now=monitor.land_now, events=events, frame=frame if frame_hz > 0 else None,
                    scenario=scenario, battery_remaining=ap.battery_remaining,
                )  # fmt: skip
                try:
                    cmd = pilot.act(obs, ctl)
                except Exception as exc:  # noqa: BLE001 - the pilot's code
                    tb = traceback.format_exception_only(type(exc), exc)[-1].strip()
                    ep.end(TrialEnd.PILOT_ERROR, f"act raised {tb}")
                    break
                if cmd is not None and not isinstance(cmd, EavCommand):
                    ep.end(TrialEnd.PILOT_ERROR, f"act returned {type(cmd).__name__}, not EavCommand/None")
                    break
                if wall_limit_s is not None and time.perf_counter() - wall0 > wall_limit_s:
                    ep.end(TrialEnd.WALL_TIMEOUT, f"trial took more than {wall_limit_s:g} s of wall time")
                    break
            ep.step(cmd)
            if flog is not None:
                flog.step(vehicle.state, ap, cmd)
            left -= 1
    finally:
        if writer is not None:
            writer.release()
        if flog is not None:
            flog.close()
    ep.log.write(trial_dir)
    row = ep.row(world, spec)
    row["wall_s"] = round(time.perf_counter() - wall0, 3)
    return row


def _open_flight_log(trial_dir: Path, vehicle: Vehicle) -> FlightLog | None:
    try:
        return FlightLog(trial_dir / LOG_FILE, vehicle.geo, vehicle.params, start_time_s=vehicle.time_s)
    except OSError as exc:  # the trial goes on without a ULog
        log.warning("cannot write %s: %s (no ULog of this trial)", trial_dir / LOG_FILE, exc.strerror or exc)
        return None


def _write_video(writer: cv2.VideoWriter | None, path: Path, img: Any, fps: float) -> cv2.VideoWriter:
    if writer is None:
        h, w = img.shape[:2]
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), fps, (w, h))
    writer.write(img)
    return writer
