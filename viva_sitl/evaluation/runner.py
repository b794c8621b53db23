"""One in-process trial: a Vehicle (the one simulator + autopilot loop) set up from a Scenario, a Python pilot
stepped on it, a TrialMonitor judging it, the scores computed. Pure function of (spec, scenario, pilot name).

    result = run_inprocess_trial(spec, scenario, "descend", trial_dir)   # dict: scores + end + files

Footage sources and world models are cached per process (a worker runs many trials over the same footage).
"""

from __future__ import annotations

import math
import time
import traceback
from pathlib import Path
from typing import Any

import cv2

from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavCommand
from viva_sitl.evaluation.monitor import Limits, TrialMonitor
from viva_sitl.evaluation.pilots import Control, Observation, make_pilot
from viva_sitl.evaluation.scoring import score_trial
from viva_sitl.evaluation.spec import Scenario, TrialSpec
from viva_sitl.footage import FootageSource, open_footage
from viva_sitl.vehicle import Vehicle
from viva_sitl.world import WorldModel, world_from_source

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


def shift_footage_clock(src: FootageSource, offset_s: float) -> None:
    """Show footage time t + offset_s at sim time t (the scenario's footage start time) on this source instance;
    the class's own frame_index_at does the mapping, so looping and stills behave as always."""
    base = type(src).frame_index_at
    if offset_s == 0.0:
        if "frame_index_at" in vars(src):
            delattr(src, "frame_index_at")
        return
    setattr(src, "frame_index_at", lambda t_s: base(src, t_s + offset_s))  # noqa: B010 - instance override


def limits_of(spec: TrialSpec) -> Limits:
    return Limits(spec.timeout_s, spec.end_outside_s, spec.crash_speed_m_s, spec.log_hz)


def make_vehicle(scenario: Scenario, src: FootageSource) -> Vehicle:
    """A Vehicle in the scenario's start situation: PX4 parameters (drawn + wind), pose, seed, footage clock."""
    cfg = SimConfig(
        footage=scenario.footage, seed=scenario.seed, params=scenario.all_params(),
        initial_pos_ned_m=scenario.start_pos_ned_m, initial_yaw_deg=scenario.yaw_deg,
    )  # fmt: skip
    shift_footage_clock(src, scenario.footage_time_s)
    v = Vehicle(cfg, footage=src)
    v.reset(seed=scenario.seed, pos_ned_m=scenario.start_pos_ned_m, yaw_rad=math.radians(scenario.yaw_deg))
    return v


def monitored_step(vehicle: Vehicle, monitor: TrialMonitor, cmd: EavCommand | None) -> None:
    """One physics step of a trial (the autopilot's, or `cmd` with the autopilot bypassed), its autopilot events
    into the trial's events, then the monitor's judgement. The trials runner and the gym environments step this."""
    if cmd is None:
        vehicle.step()
    else:
        vehicle.step_command(cmd)
    for e in vehicle.autopilot.pop_events():
        monitor.record_autopilot_event(vehicle.time_s, int(e.severity), e.text)
    monitor.after_step(vehicle)


def run_inprocess_trial(
    spec: TrialSpec,
    scenario: Scenario,
    pilot_name: str,
    trial_dir: Path,
    *,
    video: bool = False,
    wall_limit_s: float | None = None,
) -> dict[str, Any]:
    """Fly one trial; write trial_trajectory.csv, events.jsonl, end.json (+ vac.mp4 with `video`) to trial_dir; return
    the result row (scores). Never raises for a pilot's fault: the trial ends with end = pilot_error."""
    wall0 = time.perf_counter()
    trial_dir.mkdir(parents=True, exist_ok=True)
    pilot = make_pilot(pilot_name)
    src = footage_source(scenario.footage)
    world = world_of(scenario.footage)
    vehicle = make_vehicle(scenario, src)
    monitor = TrialMonitor(scenario, limits_of(spec), gcs=True)
    ap = vehicle.autopilot
    ctl = Control(ap, lambda: vehicle.time_s)
    dt = vehicle.dt_s
    steps_per_act = max(1, round(1.0 / (float(pilot.control_hz) * dt)))
    frame_hz = float(pilot.frame_hz)
    want_frames = frame_hz > 0 or video
    frame_period_s = 1.0 / (frame_hz if frame_hz > 0 else 30.0)
    next_frame_s = 0.0
    writer: cv2.VideoWriter | None = None
    frame = None
    cmd: EavCommand | None = None
    monitor.start(vehicle)
    try:
        pilot.reset(scenario, world if pilot.uses_ground_truth else None)
    except Exception as exc:  # noqa: BLE001 - the pilot's code
        monitor.end(vehicle, "pilot_error", f"reset raised {type(exc).__name__}: {exc}")
    step = 0
    log = monitor.log
    try:
        while log.end is None:
            t = vehicle.time_s
            if want_frames and t + 1e-9 >= next_frame_s:  # the camera runs at its own rate, not the pilot's
                next_frame_s += frame_period_s
                frame = vehicle.render(wall_time_s=0.0)
                if video:
                    writer = _write_video(
                        writer, trial_dir / "vac.mp4", frame.image_bgr, 1.0 / frame_period_s
                    )
            if step % steps_per_act == 0:
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
                    monitor.end(vehicle, "pilot_error", f"act raised {tb}")
                    break
                if cmd is not None and not isinstance(cmd, EavCommand):
                    monitor.end(
                        vehicle, "pilot_error", f"act returned {type(cmd).__name__}, not EavCommand/None"
                    )
                    break
                if wall_limit_s is not None and time.perf_counter() - wall0 > wall_limit_s:
                    monitor.end(
                        vehicle, "wall_timeout", f"trial took more than {wall_limit_s:g} s of wall time"
                    )
                    break
            monitored_step(vehicle, monitor, cmd)
            step += 1
    finally:
        if writer is not None:
            writer.release()
    log.write(trial_dir)
    row = score_trial(scenario, log, world, spec)
    row["wall_s"] = round(time.perf_counter() - wall0, 3)
    return row


def _write_video(writer: cv2.VideoWriter | None, path: Path, img: Any, fps: float) -> cv2.VideoWriter:
    if writer is None:
        h, w = img.shape[:2]
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), fps, (w, h))
    writer.write(img)
    return writer
