"""One trial's referee: applies the scenario's event schedule to a vehicle, samples its trajectory, decides the end.

The same TrialMonitor serves the in-process runner (runner.py steps a Vehicle and calls `after_step`) and
`viva-sitl run --scenario FILE` (app.py calls it after every physics step of the paced loop), so both forms of
pilot are judged by one piece of code.

A trial ends on: touchdown + disarm ("landed"), a touchdown faster than crash_speed_m_s ("crash"), the ground
point outside the footage for longer than end_outside_s ("left_footage"), the timeout ("timeout"), or an error of
the pilot (set by the runner).

Event schedule (times in s after the start): "land now" at land_at_s (an event the pilot sees: in-process in the
observation, over MAVLink as a STATUSTEXT "Emergency: land now"); failures: gcs_link_lost (the virtual ground station
stops being heard: PX4's NAV_DLL_ACT link-loss failsafe after COM_DL_LOSS_T), battery_critical (the battery
drops below BAT_CRIT_THR: PX4's "Critical battery level! Land now" warning), gps_loss, motor_failure (motor 1),
rc_loss and camera_blackout / camera_frozen / camera_dropped (autopilot/failures.py says what each does); each through
Autopilot.inject_failure, as MAV_CMD_INJECT_FAILURE (FAILURES maps a kind to its unit and type).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from viva_sitl.autopilot import Autopilot, ParamStore, Severity
from viva_sitl.autopilot.failures import FailureType, FailureUnit
from viva_sitl.dynamics import EavState
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.events import EventKind
from viva_sitl.evaluation.spec import Scenario

# The trial log (its own columns, for scoring); `run`'s 30 Hz trajectory.csv (viva_sitl/recording.py, for replay)
# is a different file in the same run directory.
TRIAL_TRAJECTORY_FILE = "trial_trajectory.csv"

TRAJECTORY_COLUMNS = (
    "t_s", "sim_time_s", "north_m", "east_m", "down_m", "vn_m_s", "ve_m_s", "vd_m_s", "roll_rad", "pitch_rad",
    "yaw_rad", "thrust_n", "mode", "armed", "landed", "battery_remaining", "inside_footage",
)  # fmt: skip
LAND_NOW_TEXT = "Emergency: land now"
INJECTED_PREFIX = (
    "injected:"  # the trial's failure events ("injected: GCS link lost"), also sent as STATUSTEXT
)
# a scenario's failure kind -> the MAV_CMD_INJECT_FAILURE it is (autopilot/failures.py) and the event's text
FAILURES: dict[str, tuple[FailureUnit, FailureType, str]] = {
    "gcs_link_lost": (FailureUnit.SYSTEM_MAVLINK_SIGNAL, FailureType.OFF, "GCS link lost"),
    "battery_critical": (FailureUnit.SYSTEM_BATTERY, FailureType.WRONG, "battery critical"),
    "gps_loss": (FailureUnit.SENSOR_GPS, FailureType.OFF, "GPS lost"),
    "motor_failure": (FailureUnit.SYSTEM_MOTOR, FailureType.OFF, "motor 1 failed"),
    "rc_loss": (FailureUnit.SYSTEM_RC_SIGNAL, FailureType.OFF, "RC signal lost"),
    "camera_blackout": (FailureUnit.SENSOR_CAMERA, FailureType.WRONG, "camera blackout"),
    "camera_frozen": (FailureUnit.SENSOR_CAMERA, FailureType.STUCK, "camera frozen"),
    "camera_dropped": (FailureUnit.SENSOR_CAMERA, FailureType.OFF, "camera frames dropped"),
}
FAILURE_INSTANCE = {"motor_failure": 1}  # the injection's instance where it is not 0 (all)
GCS_HEARTBEAT_PERIOD_S = 1.0


class MonitoredVehicle(Protocol):
    """What the monitor reads: viva_sitl.vehicle.Vehicle satisfies it."""

    @property
    def state(self) -> EavState: ...

    autopilot: Autopilot
    params: ParamStore

    def inside_footage(self, north_m: float, east_m: float) -> bool: ...


@dataclass(frozen=True)
class Limits:
    timeout_s: float = 60.0
    end_outside_s: float = 2.0
    crash_speed_m_s: float = 3.0
    log_hz: float = 25.0


@dataclass
class Touchdown:
    t_s: float
    north_m: float
    east_m: float
    vertical_speed_m_s: float  # down positive, the step before contact
    horizontal_speed_m_s: float


@dataclass
class TrialLog:
    """What a trial leaves: trajectory rows, events, the end and its reason."""

    rows: list[tuple[Any, ...]] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    touchdown: Touchdown | None = None
    end: TrialEnd | None = None
    end_detail: str = ""
    end_t_s: float = 0.0
    energy_wh: float = 0.0
    outside_s: float = 0.0
    path_m: float = 0.0
    land_now_t_s: float | None = None
    reaction_t_s: float | None = (
        None  # the pilot's first action after "land now" (external pilots; see episode.py)
    )
    timing: dict[str, Any] | None = None  # external pilots: the trial's clock and the pilot's CPU (timing.py)

    def write(self, trial_dir: Path) -> None:
        trial_dir.mkdir(parents=True, exist_ok=True)
        with (trial_dir / TRIAL_TRAJECTORY_FILE).open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(TRAJECTORY_COLUMNS)
            w.writerows(self.rows)
        with (trial_dir / "events.jsonl").open("w") as f:
            for e in self.events:
                f.write(json.dumps(e) + "\n")
        (trial_dir / "end.json").write_text(json.dumps(self.summary(), indent=1))

    def summary(self) -> dict[str, Any]:
        td = self.touchdown
        return {
            "end": self.end, "end_detail": self.end_detail, "end_t_s": round(self.end_t_s, 6),
            "touchdown": None if td is None else {k: round(v, 6) for k, v in td.__dict__.items()},
            "energy_wh": round(self.energy_wh, 6), "outside_s": round(self.outside_s, 6),
            "path_m": round(self.path_m, 6), "land_now_t_s": self.land_now_t_s,
            **({} if self.reaction_t_s is None else {"reaction_t_s": self.reaction_t_s}),
            **({} if self.timing is None else {"timing": self.timing}),
        }  # fmt: skip

    @classmethod
    def read(cls, trial_dir: Path) -> TrialLog:
        """Reload what `write` left (used for external pilots, whose vehicle runs in `viva-sitl run`)."""
        log = cls()
        with (trial_dir / TRIAL_TRAJECTORY_FILE).open(newline="") as f:
            r = csv.reader(f)
            next(r)
            for row in r:
                log.rows.append(
                    tuple(float(x) if k not in (12,) else x for k, x in enumerate(row))  # mode stays a string
                )
        with (trial_dir / "events.jsonl").open() as f:
            log.events = [json.loads(line) for line in f if line.strip()]
        for k, e in enumerate(log.events, 1):  # ValueError: not a kind this version writes
            e["kind"] = EventKind.parse(e.get("kind"), f"events.jsonl event {k}")
        s = json.loads((trial_dir / "end.json").read_text())
        log.end = (
            None if s["end"] is None else TrialEnd(s["end"])
        )  # ValueError: not an end this version writes
        log.end_detail, log.end_t_s = s["end_detail"], s["end_t_s"]
        log.touchdown = None if s["touchdown"] is None else Touchdown(**s["touchdown"])
        log.energy_wh, log.outside_s, log.path_m = s["energy_wh"], s["outside_s"], s["path_m"]
        log.land_now_t_s = s["land_now_t_s"]
        log.reaction_t_s = s.get("reaction_t_s")
        log.timing = s.get("timing")
        return log


class TrialMonitor:
    """Call `start(vehicle)` once, then `after_step(vehicle)` after every physics step; `log.end` is set when the
    trial is over. `gcs=True`: act as the ground station whose link a gcs_link_lost failure cuts (in-process only;
    over MAVLink the pilot is the ground station)."""

    def __init__(self, scenario: Scenario, limits: Limits, *, gcs: bool = True) -> None:
        self.scenario = scenario
        self.limits = limits
        self.log = TrialLog()
        self.gcs = gcs
        self.t0_s = (
            0.0  # sim time at the start (Vehicle.reset starts at 0; the footage clock is shifted instead)
        )
        self._log_period_s = 1.0 / limits.log_hz
        self._next_log_s = 0.0
        self._next_hb_s = 0.0
        self._pending = sorted(
            [(scenario.land_at_s, "land_now")] + [(f.at_s, f.kind) for f in scenario.failures]
        )
        self._prev: EavState | None = None
        self._prev_pos: tuple[float, ...] = (0.0, 0.0, 0.0)  # _prev's position as floats
        self._mode = ""
        self._armed = False
        self._flown = False
        self._outside_since: float | None = None
        self._inside = True
        self.land_now = False
        self._volts = 0.0  # battery voltage, refreshed at the log rate (energy = sum of V I dt)
        self.new_events: list[dict[str, Any]] = []  # since the pilot last looked (in-process observation)

    def t_of(self, state: EavState) -> float:
        return float(state.time_s) - self.t0_s

    def event(self, t_s: float, kind: EventKind, text: str, severity: int = int(Severity.INFO)) -> None:
        e = {"t_s": round(t_s, 6), "kind": kind, "text": text, "severity": severity}
        self.log.events.append(e)
        self.new_events.append(e)

    def start(self, v: MonitoredVehicle) -> None:
        s = v.state
        self._prev = s
        self._prev_pos = tuple(s.pos_ned_m.tolist())
        self._flown = not s.landed
        self._armed = v.autopilot.armed
        self._mode = v.autopilot.mode.name
        self.event(0.0, EventKind.START, f"{self.scenario.start} start at N{s.pos_ned_m[0]:.1f} E{s.pos_ned_m[1]:.1f} "
                   f"alt {-s.pos_ned_m[2]:.1f} m, mode {self._mode}, armed {self._armed}")  # fmt: skip
        self._sample(v, s, 0.0)

    def record_autopilot_event(self, t_s: float, severity: int, text: str) -> None:
        """An autopilot STATUSTEXT (its owner pops them: the runner, or the MAVLink endpoint's listener)."""
        kind = EventKind.FAILSAFE if "ailsafe" in text else EventKind.AUTOPILOT
        self.event(t_s, kind, text, severity)

    def _apply(self, v: MonitoredVehicle, t: float, kind: str) -> None:
        if kind == "land_now":
            self.land_now = True
            self.log.land_now_t_s = round(t, 6)
            self.event(t, EventKind.LAND_NOW, LAND_NOW_TEXT, int(Severity.ALERT))
            return
        unit, ftype, what = FAILURES[kind]
        # the simulator's own injection: through the autopilot's MAV_CMD_INJECT_FAILURE path, not gated by
        # SYS_FAILURE_EN (which gates a pilot's or ground station's command)
        out = v.autopilot.inject_failure(
            float(v.state.time_s), unit, ftype, FAILURE_INSTANCE.get(kind, 0), check_enabled=False
        )
        if out.ok:
            self.event(t, EventKind.FAILURE, f"{INJECTED_PREFIX} {what}", int(Severity.CRITICAL))
        else:
            self.event(
                t,
                EventKind.FAILURE,
                f"{INJECTED_PREFIX} {what} refused: {out.reason}",
                int(Severity.CRITICAL),
            )

    def after_step(self, v: MonitoredVehicle) -> None:
        s = v.state
        prev = self._prev if self._prev is not None else s
        self._prev = s
        t = float(s.time_s) - self.t0_s
        dt = s.dt_s
        ap = v.autopilot
        while self._pending and self._pending[0][0] <= t:
            _, kind = self._pending.pop(0)
            self._apply(v, t, kind)
        if self.gcs and t >= self._next_hb_s:
            ap.gcs_heartbeat(float(s.time_s))
            self._next_hb_s = t + GCS_HEARTBEAT_PERIOD_S
        # path and energy at the physics rate (plain floats: the same IEEE operations as on the arrays' elements,
        # without numpy's per-call cost 250 times a second; the previous position is kept as floats)
        n, e, dn = s.pos_ned_m.tolist()
        pn, pe, pd = self._prev_pos if prev is not s else (n, e, dn)
        self._prev_pos = (n, e, dn)
        dx, dy, dz = n - pn, e - pe, dn - pd
        self.log.path_m += math.sqrt(dx * dx + dy * dy + dz * dz)
        if ap.armed:
            self.log.energy_wh += ap.battery_current_a * self._volts * dt / 3600.0
        mode, armed = ap.mode.name, ap.armed
        if mode != self._mode:
            self.event(t, EventKind.MODE, f"mode {self._mode} -> {mode}")
            self._mode = mode
        if armed != self._armed:
            self.event(t, EventKind.ARMED if armed else EventKind.DISARMED, "armed" if armed else "disarmed")
            self._armed = armed
        if not s.landed:
            self._flown = True
        if s.landed and not prev.landed:
            vel = prev.vel_ned_m_s
            td = Touchdown(t, float(s.pos_ned_m[0]), float(s.pos_ned_m[1]), float(vel[2]),
                           math.hypot(float(vel[0]), float(vel[1])))  # fmt: skip
            self.log.touchdown = td
            self.event(t, EventKind.TOUCHDOWN, f"touchdown at N{td.north_m:.2f} E{td.east_m:.2f}: vertical "
                       f"{td.vertical_speed_m_s:.2f} m/s, horizontal {td.horizontal_speed_m_s:.2f} m/s")  # fmt: skip
            if math.hypot(td.vertical_speed_m_s, td.horizontal_speed_m_s) > self.limits.crash_speed_m_s:
                self._end(v, s, t, TrialEnd.CRASH, f"touchdown at {math.hypot(td.vertical_speed_m_s, td.horizontal_speed_m_s):.2f} m/s "
                          f"> crash_speed_m_s {self.limits.crash_speed_m_s:g}")  # fmt: skip
                return
        elif not s.landed and prev.landed and self.log.touchdown is not None:
            self.event(t, EventKind.LIFTOFF, "lift-off")
            self.log.touchdown = None  # a touch-and-go is not a landing
        if t >= self._next_log_s:
            self._next_log_s += self._log_period_s
            self._inside = bool(v.inside_footage(float(s.pos_ned_m[0]), float(s.pos_ned_m[1])))
            self._volts = ap.battery_voltage_v
            self._sample(v, s, t)
            if not self._inside:
                if self._outside_since is None:
                    self._outside_since = t
                    self.event(t, EventKind.OUTSIDE, "ground point left the footage")
                elif t - self._outside_since >= self.limits.end_outside_s:
                    self._end(
                        v,
                        s,
                        t,
                        TrialEnd.LEFT_FOOTAGE,
                        f"outside the footage for {self.limits.end_outside_s:g} s",
                    )
                    return
            elif self._outside_since is not None:
                self._outside_since = None
                self.event(t, EventKind.INSIDE, "ground point back over the footage")
        if not self._inside:
            self.log.outside_s += dt
        if self._flown and s.landed and not armed:
            self._end(v, s, t, TrialEnd.LANDED, "touchdown and disarm")
        elif t >= self.limits.timeout_s - 1e-9:
            self._end(v, s, t, TrialEnd.TIMEOUT, f"not landed and disarmed after {self.limits.timeout_s:g} s")

    def _sample(self, v: MonitoredVehicle, s: EavState, t: float) -> None:
        p, vel, att = s.pos_ned_m, s.vel_ned_m_s, s.att_rpy_rad
        ap = v.autopilot
        if self._volts == 0.0:
            self._volts = ap.battery_voltage_v
        self.log.rows.append((
            round(t, 4), round(float(s.time_s), 4), round(float(p[0]), 4), round(float(p[1]), 4),
            round(float(p[2]), 4), round(float(vel[0]), 4), round(float(vel[1]), 4), round(float(vel[2]), 4),
            round(float(att[0]), 5), round(float(att[1]), 5), round(float(att[2]), 5), round(float(s.thrust_n), 4),
            ap.mode.name, int(ap.armed), int(bool(s.landed)), round(ap.battery_remaining, 5), int(self._inside),
        ))  # fmt: skip

    def end(self, v: MonitoredVehicle, end: TrialEnd, detail: str) -> None:
        """End the trial from outside (a pilot error, an interrupted run)."""
        if self.log.end is None:
            s = v.state
            self._end(v, s, float(s.time_s) - self.t0_s, end, detail)

    def _end(self, v: MonitoredVehicle, s: EavState, t: float, end: TrialEnd, detail: str) -> None:
        self._sample(v, s, t)
        self.log.end, self.log.end_detail, self.log.end_t_s = end, detail, t
        self.event(t, EventKind.END, f"{end}: {detail}")
