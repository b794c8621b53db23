"""`viva-sitl replay RUN_DIR`: a recorded run in the dashboard page, with a time slider and play / pause.

The recording is the run directory's trajectory.csv (recording.py), or without one its telemetry.tlog (read with
pymavlink: LOCAL_POSITION_NED, ATTITUDE, HEARTBEAT, EXTENDED_SYS_STATE, SYS_STATUS), or a trial's
trial_trajectory.csv (`trials run` of an in-process pilot: trials/NNNN/ has no run.json either). run.json names the
footage and the config, or a trial's scenario.json does (footage, seed, parameters, and the footage clock at the
start: the replay shows the footage frames the trial saw); the VAC view at each moment is re-rendered from the
recorded pose with the same Simulator (same footage, camera and seed as the run). `ReplayApp` stands where SitlApp stands for the Dashboard (the same server,
overview, HUD and layers); flying is disabled (no autopilot: commands and sticks are refused with a reason).

Page messages (JSON on /ws): {"t": "replay", "action": "seek", "time_s": T} | {"action": "play"} |
{"action": "pause"} | {"action": "rate", "rate": R} (0.1..16, replay seconds per wall second).
"""

from __future__ import annotations

import asyncio
import bisect
import contextlib
import csv
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from viva_sitl.autopilot import FlightMode
from viva_sitl.config import SimConfig
from viva_sitl.dashboard.vac import VacOutput
from viva_sitl.dynamics import EavState
from viva_sitl.frame import RenderedFrame
from viva_sitl.recording import TRAJECTORY_FILE, Sample, read_run_info, read_trajectory
from viva_sitl.sim import Simulator

TLOG_FILE = "telemetry.tlog"
MAX_RATE = 16.0


class ReplayError(ValueError):
    """A run directory that cannot be replayed (one-line reason)."""


@dataclass
class Recording:
    samples: list[Sample]
    config: SimConfig
    source: str  # "trajectory" | "tlog" | "trial"
    path: Path
    times_s: list[float] = field(default_factory=list)
    footage_offset_s: float = 0.0  # footage time = sim time + this (a trial's scenario footage_time_s)

    def __post_init__(self) -> None:
        self.times_s = [s.sim_time_s for s in self.samples]

    @property
    def start_s(self) -> float:
        return self.times_s[0]

    @property
    def end_s(self) -> float:
        return self.times_s[-1]

    def at(self, t_s: float) -> Sample:
        """The last sample at or before t (the first one before the start)."""
        i = bisect.bisect_right(self.times_s, t_s) - 1
        return self.samples[max(0, min(i, len(self.samples) - 1))]


def _samples_from_tlog(path: Path) -> list[Sample]:
    from pymavlink import mavutil

    try:
        mlog = mavutil.mavlink_connection(str(path), dialect="common", robust_parsing=True)
    except OSError as exc:
        raise ReplayError(f"cannot read {path}: {exc.strerror or exc}") from None
    att = (0.0, 0.0, 0.0)
    mode, armed, landed, pct, volt = "UNKNOWN", False, "UNDEFINED", math.nan, math.nan
    out: list[Sample] = []
    types = ["LOCAL_POSITION_NED", "ATTITUDE", "HEARTBEAT", "EXTENDED_SYS_STATE", "SYS_STATUS"]
    try:
        while True:
            m = mlog.recv_match(type=types)
            if m is None:
                break
            if (
                m.get_srcComponent() != 1
            ):  # the autopilot's own messages (the tlog also holds what peers sent)
                continue
            kind = m.get_type()
            if kind == "ATTITUDE":
                att = (float(m.roll), float(m.pitch), float(m.yaw))
            elif kind == "HEARTBEAT":
                with contextlib.suppress(ValueError):
                    mode = FlightMode.from_custom_mode(int(m.custom_mode)).name
                armed = bool(m.base_mode & 128)
            elif kind == "EXTENDED_SYS_STATE":
                landed = {0: "UNDEFINED", 1: "ON_GROUND", 2: "IN_AIR", 3: "TAKEOFF", 4: "LANDING"}.get(
                    int(m.landed_state), "UNDEFINED"
                )
            elif kind == "SYS_STATUS":
                pct = float(m.battery_remaining) if m.battery_remaining >= 0 else math.nan
                volt = float(m.voltage_battery) / 1000.0 if m.voltage_battery != 65535 else math.nan
            else:
                t = float(m.time_boot_ms) / 1000.0
                if out and t <= out[-1].sim_time_s:
                    continue  # the same instant on both links
                out.append(
                    Sample(t, (m.x, m.y, m.z), (m.vx, m.vy, m.vz), att, mode, armed, landed, -1, pct, volt)
                )
    finally:
        mlog.close()
    return _backfill(out)


def _backfill(samples: list[Sample]) -> list[Sample]:
    """Samples before the first HEARTBEAT / SYS_STATUS / EXTENDED_SYS_STATE get the first values the log has."""
    import dataclasses

    def first(pred: Any) -> Sample | None:
        return next((s for s in samples if pred(s)), None)

    mode = first(lambda s: s.mode != "UNKNOWN")
    bat = first(lambda s: math.isfinite(s.battery_pct))
    landed = first(lambda s: s.landed_state != "UNDEFINED")
    out = []
    for s in samples:
        if mode is not None and s.mode == "UNKNOWN":
            s = dataclasses.replace(s, mode=mode.mode, armed=mode.armed)
        if bat is not None and not math.isfinite(s.battery_pct):
            s = dataclasses.replace(s, battery_pct=bat.battery_pct, battery_v=bat.battery_v)
        if landed is not None and s.landed_state == "UNDEFINED":
            s = dataclasses.replace(s, landed_state=landed.landed_state)
        out.append(s)
    return out


def _samples_from_trial_log(path: Path) -> list[Sample]:
    """A trial's own trajectory (evaluation/monitor.py TRAJECTORY_COLUMNS) as replay samples."""
    out: list[Sample] = []
    try:
        with path.open(newline="") as f:
            for row in csv.DictReader(f):
                g = float
                out.append(Sample(
                    g(row["sim_time_s"]), (g(row["north_m"]), g(row["east_m"]), g(row["down_m"])),
                    (g(row["vn_m_s"]), g(row["ve_m_s"]), g(row["vd_m_s"])),
                    (g(row["roll_rad"]), g(row["pitch_rad"]), g(row["yaw_rad"])), row["mode"],
                    row["armed"] in ("1", "1.0"), "ON_GROUND" if row["landed"] in ("1", "1.0") else "IN_AIR", -1,
                    100.0 * g(row["battery_remaining"]), math.nan,
                ))  # fmt: skip
    except OSError as exc:
        raise ReplayError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (KeyError, ValueError, TypeError):
        raise ReplayError(f"{path}: not a trial trajectory (trial_trajectory.csv columns)") from None
    return out


def _scenario_of(run_dir: Path) -> Any:
    """The trial's scenario.json (a `trials run` trial folder), or None."""
    from viva_sitl.config import ConfigError
    from viva_sitl.evaluation.spec import Scenario

    path = run_dir / "scenario.json"
    if not path.is_file():
        return None
    try:
        return Scenario.read(path)
    except (ConfigError, ValueError, KeyError, TypeError) as exc:
        raise ReplayError(f"{path}: {exc}") from None


def load_recording(run_dir: Path, footage: str | None = None) -> Recording:
    """The recording of a run directory (or a trial folder); ReplayError with a one-line reason when there is
    none."""
    from viva_sitl.evaluation.monitor import TRIAL_TRAJECTORY_FILE

    if not run_dir.is_dir():
        raise ReplayError(f"{run_dir}: no such run directory")
    try:
        info = read_run_info(run_dir)
    except ValueError as exc:
        raise ReplayError(str(exc)) from None
    scenario = _scenario_of(run_dir)
    if info is not None:
        try:
            config = SimConfig.from_dict(dict(info.get("config") or {}), str(run_dir / "run.json"))
        except ValueError as exc:
            raise ReplayError(str(exc)) from None
    elif scenario is not None:  # an in-process trial: the vehicle the runner made from its scenario
        config = SimConfig(
            footage=scenario.footage, seed=scenario.seed, params=scenario.all_params(),
            initial_pos_ned_m=scenario.start_pos_ned_m, initial_yaw_deg=scenario.yaw_deg,
        )  # fmt: skip
    else:
        config = SimConfig()
    if footage:
        import dataclasses

        config = dataclasses.replace(config, footage=footage)
    traj = run_dir / TRAJECTORY_FILE
    tlog = run_dir / TLOG_FILE
    trial = run_dir / TRIAL_TRAJECTORY_FILE
    if traj.is_file():
        try:
            samples, source, path = read_trajectory(traj), "trajectory", traj
        except ValueError as exc:
            raise ReplayError(str(exc)) from None
    elif tlog.is_file():
        samples, source, path = _samples_from_tlog(tlog), "tlog", tlog
    elif trial.is_file():
        samples, source, path = _samples_from_trial_log(trial), "trial", trial
    else:
        raise ReplayError(
            f"{run_dir}: none of {TRAJECTORY_FILE}, {TLOG_FILE}, {TRIAL_TRAJECTORY_FILE} (not a viva-sitl run "
            "directory or trial folder?)"
        )
    if not samples:
        raise ReplayError(f"{path}: no samples")
    # a trial's footage clock starts at its scenario's footage_time_s (both trial kinds start the sim at 0)
    offset = float(scenario.footage_time_s) if scenario is not None else 0.0
    return Recording(samples, config, source, path, footage_offset_s=offset)


@dataclass
class _Named:
    name: str


class _Eav:
    ground_z_ned_m = 0.0


class ReplayAutopilot:
    """What the Dashboard reads from an autopilot, from the recorded sample (read-only)."""

    def __init__(self, app: ReplayApp) -> None:
        self._app = app
        self.eav = _Eav()
        self.mission_items: list[Any] = []
        self.mission_current_seq = 0
        self.home_ned_m = app.recording.samples[0].pos_ned_m

    @property
    def mode(self) -> Any:
        name = self._app.sample.mode
        return FlightMode[name] if name in FlightMode.__members__ else _Named(name)

    @property
    def armed(self) -> bool:
        return self._app.sample.armed

    @property
    def landed_state(self) -> _Named:
        return _Named(self._app.sample.landed_state)

    @property
    def battery_remaining(self) -> float:
        return self._app.sample.battery_pct / 100.0

    @property
    def battery_voltage_v(self) -> float:
        return self._app.sample.battery_v


class ReplayState:
    def __init__(self, app: ReplayApp) -> None:
        self._app = app

    @property
    def pos_ned_m(self) -> np.ndarray:  # type: ignore[type-arg]
        return np.array(self._app.sample.pos_ned_m)

    @property
    def vel_ned_m_s(self) -> np.ndarray:  # type: ignore[type-arg]
        return np.array(self._app.sample.vel_ned_m_s)

    @property
    def att_rpy_rad(self) -> np.ndarray:  # type: ignore[type-arg]
        return np.array(self._app.sample.att_rpy_rad)

    @property
    def yaw_rad(self) -> float:
        return float(self._app.sample.att_rpy_rad[2])


def eav_state_of(sample: Sample, dt_s: float) -> EavState:
    """An EavState with the recorded pose and velocity (what the renderer reads), for re-rendering the VAC."""
    pos = np.array(sample.pos_ned_m, np.float64)
    vel = np.array(sample.vel_ned_m_s, np.float64)
    return EavState(
        time_s=sample.sim_time_s,
        step=round(sample.sim_time_s / dt_s),
        pos_ned_m=pos,
        prev_pos_ned_m=pos - vel * dt_s,
        att_rpy_rad=np.array(sample.att_rpy_rad, np.float64),
        thrust_n=0.0,
        gust_ned_m_s=np.zeros(3),
        landed=sample.landed_state == "ON_GROUND",
        touchdown_speed_m_s=None,
        dt_s=dt_s,
    )


class ReplayApp:
    """Stands where SitlApp stands for the Dashboard: the recorded sample at the replay time."""

    endpoint = None
    scheduler = None
    video = None

    def __init__(self, recording: Recording) -> None:
        self.recording = recording
        self.config = recording.config
        self.sim = Simulator(recording.config)
        self.sim.footage_offset_s = recording.footage_offset_s
        self.time_s = recording.start_s
        self.sample = recording.at(self.time_s)
        self.autopilot = ReplayAutopilot(self)
        self.state = ReplayState(self)
        self.playing = False
        self.rate = 1.0
        self._render_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="viva-replay-render")
        self._render_lock = threading.Lock()
        self._render_wanted: float | None = None
        self.vac: VacOutput | None = None
        self.renders = 0

    # --- time ----------------------------------------------------------------------------------
    def seek(self, t_s: float) -> None:
        if not math.isfinite(t_s):
            raise ValueError("time_s must be a finite number")
        self.time_s = min(max(t_s, self.recording.start_s), self.recording.end_s)
        self.sample = self.recording.at(self.time_s)
        self.request_render()

    def info(self) -> dict[str, Any]:
        r = self.recording
        return {"start_s": r.start_s, "end_s": r.end_s, "source": r.source, "path": str(r.path),
                "samples": len(r.samples)}  # fmt: skip

    def trail_ned(self, max_points: int) -> list[tuple[float, float]]:
        step = max(1, len(self.recording.samples) // max_points)
        return [(s.pos_ned_m[0], s.pos_ned_m[1]) for s in self.recording.samples[::step]]

    # --- VAC ------------------------------------------------------------------------------------
    def render_at(self, sample: Sample) -> RenderedFrame:
        """The VAC view at a recorded sample (the Simulator's own render; on the render thread)."""
        return self.sim.render(eav_state_of(sample, self.sim.params.dt_s), wall_time_s=time.time())

    def request_render(self) -> None:
        """Re-render the VAC at the current time on the render thread (latest request wins)."""
        with self._render_lock:
            busy = self._render_wanted is not None
            self._render_wanted = self.time_s
        if not busy:
            with contextlib.suppress(RuntimeError):
                self._render_pool.submit(self._render_loop)

    def _render_loop(self) -> None:
        while True:
            with self._render_lock:
                t = self._render_wanted
            if t is None:
                return
            frame = self.render_at(self.recording.at(t))
            self.renders += 1
            if self.vac is not None:
                self.vac.write(frame)
            with self._render_lock:
                if self._render_wanted == t:
                    self._render_wanted = None
                    return

    async def play_loop(self) -> None:
        """Advances the replay time while playing (wall time x rate); stops at the end."""
        last = time.monotonic()
        while True:
            await asyncio.sleep(0.05)
            now = time.monotonic()
            if self.playing:
                t = self.time_s + (now - last) * self.rate
                if t >= self.recording.end_s:
                    t, self.playing = self.recording.end_s, False
                self.seek(t)
            last = now

    def close(self) -> None:
        self._render_pool.shutdown(wait=True, cancel_futures=True)
        self.sim.close()


__all__ = ["Recording", "ReplayApp", "ReplayError", "eav_state_of", "load_recording"]
