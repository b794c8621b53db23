"""What a run leaves behind for replay and analysis: `run.json` (what was flown) and `trajectory.csv` (how).

run.json (written at start):
    {"format": "viva-sitl-run", "version": 1, "started_utc": "...", "footage": NAME,
     "config": {...the SimConfig as a config table (SimConfig.from_dict reads it back)...},
     "trajectory": {"file": "trajectory.csv", "format_version": 1, "rate_hz": 30.0}}

trajectory.csv (format_version 1): a header row, then one row per sample, every `1 / rate_hz` seconds of SIM time
(the first physics step at or after each sample time; its exact sim time is the first column):
    sim_time_s, north_m, east_m, down_m          position, local NED (m)
    vn_m_s, ve_m_s, vd_m_s                       velocity, NED (m/s)
    roll_rad, pitch_rad, yaw_rad                 attitude (FRD -> NED)
    mode                                         PX4 mode name (POSCTL, AUTO_TAKEOFF, OFFBOARD, ...)
    armed                                        0 / 1
    landed_state                                 ON_GROUND, TAKEOFF, IN_AIR, LANDING
    footage_frame                                footage frame index the camera sees at sim_time_s
    battery_pct, battery_v                       remaining (0..100) and voltage

Off the physics hot path: `sample` (called after every physics step) only appends a tuple when a sample is due;
rows are formatted and written by one writer thread, flushed about once a wall second and at `close`.
"""

from __future__ import annotations

import asyncio
import contextlib
import csv
import dataclasses
import enum
import json
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from viva_sitl.config import SimConfig

RUN_FILE = "run.json"
TRAJECTORY_FILE = "trajectory.csv"
RUN_FORMAT = "viva-sitl-run"
RUN_VERSION = 1
TRAJECTORY_VERSION = 1
DEFAULT_RATE_HZ = 30.0
FLUSH_PERIOD_S = 1.0
COLUMNS = (
    "sim_time_s", "north_m", "east_m", "down_m", "vn_m_s", "ve_m_s", "vd_m_s", "roll_rad", "pitch_rad", "yaw_rad",
    "mode", "armed", "landed_state", "footage_frame", "battery_pct", "battery_v",
)  # fmt: skip
_SECTIONS = ("physics", "camera", "mavlink", "video", "perception")


@dataclass(frozen=True)
class Sample:
    """One trajectory row."""

    sim_time_s: float
    pos_ned_m: tuple[float, float, float]
    vel_ned_m_s: tuple[float, float, float]
    att_rpy_rad: tuple[float, float, float]
    mode: str
    armed: bool
    landed_state: str
    footage_frame: int
    battery_pct: float
    battery_v: float

    def row(self) -> list[str]:
        def f(v: float, nd: int = 6) -> str:
            return f"{v:.{nd}f}" if math.isfinite(v) else "nan"

        return [f(self.sim_time_s), *(f(v, 4) for v in self.pos_ned_m), *(f(v, 4) for v in self.vel_ned_m_s),
                *(f(v, 6) for v in self.att_rpy_rad), self.mode, "1" if self.armed else "0", self.landed_state,
                str(self.footage_frame), f(self.battery_pct, 2), f(self.battery_v, 3)]  # fmt: skip

    @classmethod
    def from_row(cls, row: dict[str, str]) -> Sample:
        """A csv.DictReader row; ValueError / KeyError on a malformed one."""
        g = float
        return cls(
            g(row["sim_time_s"]),
            (g(row["north_m"]), g(row["east_m"]), g(row["down_m"])),
            (g(row["vn_m_s"]), g(row["ve_m_s"]), g(row["vd_m_s"])),
            (g(row["roll_rad"]), g(row["pitch_rad"]), g(row["yaw_rad"])),
            row["mode"],
            row["armed"] == "1",
            row["landed_state"],
            int(row["footage_frame"]),
            g(row["battery_pct"]),
            g(row["battery_v"]),
        )


def config_to_dict(cfg: SimConfig) -> dict[str, Any]:
    """The config as a table `SimConfig.from_dict` reads back to an equal config."""
    d = dataclasses.asdict(cfg)

    def clean(x: Any) -> Any:
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items() if v is not None}
        if isinstance(x, list | tuple):
            return [clean(v) for v in x]
        if isinstance(x, enum.Enum):
            return x.name.lower()
        return x

    out: dict[str, Any] = {"sim": {k: v for k, v in d.items() if k not in (*_SECTIONS, "params")}}
    out.update({k: d[k] for k in _SECTIONS})
    out["params"] = {name: value for name, value in cfg.params}
    return dict(clean(out))


def write_run_info(run_dir: Path, cfg: SimConfig, footage_name: str, rate_hz: float | None) -> Path:
    info: dict[str, Any] = {
        "format": RUN_FORMAT,
        "version": RUN_VERSION,
        "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "footage": footage_name,
        "config": config_to_dict(cfg),
    }
    if rate_hz is not None:
        info["trajectory"] = {
            "file": TRAJECTORY_FILE,
            "format_version": TRAJECTORY_VERSION,
            "rate_hz": rate_hz,
        }
    run_dir.mkdir(parents=True, exist_ok=True)
    path = run_dir / RUN_FILE
    path.write_text(json.dumps(info, indent=1), encoding="utf-8")
    return path


def read_run_info(run_dir: Path) -> dict[str, Any] | None:
    """run.json of a run directory (None: absent); ValueError with a one-line reason when it is not readable."""
    path = run_dir / RUN_FILE
    if not path.is_file():
        return None
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable run file ({exc})") from None
    if not isinstance(info, dict) or info.get("format") != RUN_FORMAT:
        raise ValueError(f"{path}: not a viva-sitl run file")
    if int(info.get("version", 0)) > RUN_VERSION:
        raise ValueError(
            f"{path}: version {info.get('version')} is newer than this viva-sitl reads ({RUN_VERSION})"
        )
    return info


def read_trajectory(path: Path) -> list[Sample]:
    """All rows of a trajectory.csv (a torn last row, from a killed run, is skipped); ValueError when unreadable."""
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            if reader.fieldnames is None or tuple(reader.fieldnames) != COLUMNS:
                raise ValueError(
                    f"{path}: not a trajectory.csv (format_version {TRAJECTORY_VERSION} columns)"
                )
            out = []
            for row in reader:
                try:
                    out.append(Sample.from_row(row))
                except (ValueError, KeyError, TypeError):
                    continue
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    return out


class TrajectoryRecorder:
    """Samples the vehicle at `rate_hz` of sim time into `path` (buffered; written by one worker thread)."""

    def __init__(self, path: Path, rate_hz: float = DEFAULT_RATE_HZ) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"trajectory rate must be a positive number, got {rate_hz}")
        self.path = path
        self.rate_hz = float(rate_hz)
        self._period_s = 1.0 / self.rate_hz
        self._next_s = -math.inf
        self._last_s = -math.inf
        self._buffer: list[Sample] = []
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="viva-trajectory")
        self._file: Any = None
        self._writer: Any = None
        self.samples = 0
        self.rows_written = 0
        self.write_errors = 0

    def due(self, sim_time_s: float) -> bool:
        """True when a sample is due at this sim time (cheap: the hot path calls it every step)."""
        return sim_time_s >= self._next_s

    def add(self, sample: Sample) -> None:
        """Buffer a sample (one at or before the last sample's sim time is ignored: rows are strictly ordered)."""
        t = sample.sim_time_s
        if t <= self._last_s:
            return
        self._last_s = t
        # the next sample time on the fixed grid (a run that jumped ahead does not write a burst of rows)
        self._next_s = (math.floor(t * self.rate_hz + 1e-9) + 1) * self._period_s
        self._buffer.append(sample)
        self.samples += 1

    def _write(self, rows: list[Sample]) -> None:
        try:
            if self._file is None:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._file = self.path.open("w", newline="", encoding="utf-8")
                self._writer = csv.writer(self._file)
                self._writer.writerow(COLUMNS)
            for s in rows:
                self._writer.writerow(s.row())
            self._file.flush()
            self.rows_written += len(rows)
        except OSError:
            self.write_errors += 1

    def flush(self) -> None:
        """Hand the buffered rows to the writer thread (returns at once)."""
        rows, self._buffer = self._buffer, []
        if rows or self._file is None:
            with contextlib.suppress(RuntimeError):  # closed
                self._pool.submit(self._write, rows)

    async def run(self) -> None:
        """The flush task: about once a wall second."""
        while True:
            await asyncio.sleep(FLUSH_PERIOD_S)
            self.flush()

    def close(self) -> None:
        """Write what is left and close the file (blocks until written)."""
        self.flush()
        self._pool.shutdown(wait=True)
        if self._file is not None:
            with contextlib.suppress(OSError):
                self._file.close()
            self._file = None


__all__ = [
    "COLUMNS",
    "RUN_FILE",
    "TRAJECTORY_FILE",
    "Sample",
    "TrajectoryRecorder",
    "config_to_dict",
    "read_run_info",
    "read_trajectory",
    "write_run_info",
]
