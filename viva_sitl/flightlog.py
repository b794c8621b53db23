"""The PX4 ULog of a flight: the topics PX4 users open first, fed once per physics step.

    flog = FlightLog(run_dir / "log.ulg", geo, params)       # opens the file, starts the writer thread
    flog.step(vehicle.state, vehicle.autopilot)               # after every physics step (cheap: rate-limited
                                                              #  tuples on a bounded queue, see ulog.ULogWriter)
    flog.camera_capture(seq, time_s, lat, lon, alt, ...)      # when an image is taken
    flog.text(severity, time_s, text)                          # STATUSTEXTs as logged strings, as PX4 logs them
    flog.close()

Topics and fields carry PX4's names (uORB message definitions), so Flight Review, PlotJuggler and pyulog scripts
written for PX4 logs read them: vehicle_local_position, vehicle_global_position, vehicle_attitude, vehicle_status,
battery_status, trajectory_setpoint, vehicle_attitude_setpoint (the step's attitude/thrust command: the
autopilot's output, or the one the caller passes), failsafe_flags, camera_capture. Timestamps are simulation
microseconds (PX4 SITL in lockstep logs simulation time too). Samples whose time does not advance (a reset Vehicle) are skipped: one file, one clock.

Each topic is logged at most at its rate (simulation time), vehicle_status and failsafe_flags also at every change.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping
from typing import Any

from viva_sitl.autopilot.autopilot import Autopilot
from viva_sitl.autopilot.failsafe import battery_level
from viva_sitl.autopilot.types import FlightMode
from viva_sitl.dynamics import EavCommand, EavState
from viva_sitl.dynamics.rotation import quat_from_euler
from viva_sitl.geo import GeoOrigin
from viva_sitl.ulog import Topic, ULogWriter

LOG_FILE = "log.ulg"

F = "float"
LOCAL_POSITION = Topic(
    "vehicle_local_position",
    (
        ("uint64_t", "timestamp_sample"),
        ("bool", "xy_valid"), ("bool", "z_valid"), ("bool", "v_xy_valid"), ("bool", "v_z_valid"),
        (F, "x"), (F, "y"), (F, "z"), (F, "vx"), (F, "vy"), (F, "vz"), (F, "ax"), (F, "ay"), (F, "az"),
        (F, "heading"), ("bool", "xy_global"), ("bool", "z_global"),
        ("double", "ref_lat"), ("double", "ref_lon"), (F, "ref_alt"),
        (F, "dist_bottom"), ("bool", "dist_bottom_valid"),
    ),
)  # fmt: skip
GLOBAL_POSITION = Topic(
    "vehicle_global_position",
    (
        ("uint64_t", "timestamp_sample"), ("double", "lat"), ("double", "lon"), (F, "alt"),
        (F, "alt_ellipsoid"), (F, "eph"), (F, "epv"), (F, "terrain_alt"), ("bool", "terrain_alt_valid"),
        ("bool", "dead_reckoning"),
    ),
)  # fmt: skip
ATTITUDE = Topic(
    "vehicle_attitude",
    (
        ("uint64_t", "timestamp_sample"),
        ("float[4]", "q"),
        ("float[4]", "delta_q_reset"),
        ("uint8_t", "quat_reset_counter"),
    ),
)
STATUS = Topic(
    "vehicle_status",
    (
        ("uint64_t", "armed_time"), ("uint64_t", "takeoff_time"), ("uint64_t", "nav_state_timestamp"),
        ("uint8_t", "arming_state"), ("uint8_t", "nav_state"), ("uint8_t", "vehicle_type"),
        ("uint8_t", "system_type"), ("uint8_t", "system_id"), ("uint8_t", "component_id"),
        ("bool", "failsafe"), ("bool", "pre_flight_checks_pass"), ("bool", "is_vtol"),
    ),
)  # fmt: skip
BATTERY = Topic(
    "battery_status",
    (
        ("bool", "connected"), (F, "voltage_v"), (F, "current_a"), (F, "remaining"),
        ("uint8_t", "warning"), ("uint8_t", "id"),
    ),
)  # fmt: skip
TRAJECTORY_SETPOINT = Topic(
    "trajectory_setpoint",
    (("float[3]", "position"), ("float[3]", "velocity"), ("float[3]", "acceleration"), ("float[3]", "jerk"),
     (F, "yaw"), (F, "yawspeed")),
)  # fmt: skip
ATTITUDE_SETPOINT = Topic(
    "vehicle_attitude_setpoint",
    ((F, "yaw_sp_move_rate"), ("float[4]", "q_d"), ("float[3]", "thrust_body")),
)
FAILSAFE_FLAGS = Topic(
    "failsafe_flags",
    (
        ("bool", "manual_control_signal_lost"), ("bool", "gcs_connection_lost"),
        ("bool", "offboard_control_signal_lost"), ("bool", "geofence_breached"),
        ("uint8_t", "battery_warning"), ("bool", "local_position_invalid"), ("bool", "global_position_invalid"),
        ("bool", "home_position_invalid"),
    ),
)  # fmt: skip
CAMERA_CAPTURE = Topic(
    "camera_capture",
    (
        ("uint64_t", "timestamp_utc"), ("uint32_t", "seq"), ("double", "lat"), ("double", "lon"), (F, "alt"),
        (F, "ground_distance"), ("float[4]", "q"), ("int8_t", "result"),
    ),
)  # fmt: skip

TOPICS = (LOCAL_POSITION, GLOBAL_POSITION, ATTITUDE, STATUS, BATTERY, TRAJECTORY_SETPOINT, ATTITUDE_SETPOINT,
          FAILSAFE_FLAGS, CAMERA_CAPTURE)  # fmt: skip

# Hz of simulation time (PX4's default logger profile logs these between 5 and 50 Hz)
DEFAULT_RATES_HZ: Mapping[str, float] = {
    "vehicle_local_position": 50.0,
    "vehicle_global_position": 10.0,
    "vehicle_attitude": 50.0,
    "vehicle_status": 2.0,
    "battery_status": 5.0,
    "trajectory_setpoint": 50.0,
    "vehicle_attitude_setpoint": 50.0,
    "failsafe_flags": 2.0,
}

# PX4 vehicle_status.nav_state values
NAV_STATE = {
    FlightMode.MANUAL: 0,
    FlightMode.ALTCTL: 1,
    FlightMode.POSCTL: 2,
    FlightMode.AUTO_MISSION: 3,
    FlightMode.AUTO_LOITER: 4,
    FlightMode.AUTO_RTL: 5,
    FlightMode.OFFBOARD: 14,
    FlightMode.STABILIZED: 15,
    FlightMode.AUTO_TAKEOFF: 17,
    FlightMode.AUTO_LAND: 18,
    FlightMode.ORBIT: 21,
    FlightMode.AUTO_FOLLOW_TARGET: 19,
    FlightMode.AUTO_READY: 4,
}
ARMING_STATE_DISARMED = 1  # vehicle_status.arming_state (PX4 >= 1.14)
ARMING_STATE_ARMED = 2
VEHICLE_TYPE_ROTARY_WING = 1
MAV_TYPE_QUADROTOR = 2
_NAN3 = (math.nan, math.nan, math.nan)

# PX4's logging levels for 'L' messages: MAVLink severities map one to one (0 emergency .. 7 debug)


def _us(time_s: float) -> int:
    return int(round(time_s * 1e6)) if math.isfinite(time_s) and time_s > 0 else 0


def _f3(v: Any) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def param_values(params: Any) -> dict[str, float | int]:
    """A ParamStore's values as ULog parameters (int32 for PX4's INT32 parameters, float otherwise)."""
    out: dict[str, float | int] = {}
    for name in params.names():
        value = float(params.stored(name))
        is_int = "INT" in str(getattr(params.spec(name), "type", "")).upper()
        out[name] = int(value) if is_int and math.isfinite(value) else value
    return out


class FlightLog:
    """The ULog of one flight. All calls come from the physics loop's thread; the file is written on its own."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        geo: GeoOrigin,
        params: Any | None = None,
        *,
        start_time_s: float = 0.0,
        system_id: int = 1,
        rates_hz: Mapping[str, float] | None = None,
        info: Mapping[str, Any] | None = None,
        max_queue: int = 20000,
    ) -> None:
        self.geo = geo
        self.system_id = int(system_id)
        rates = dict(DEFAULT_RATES_HZ)
        rates.update(rates_hz or {})
        self._period_s = {name: (1.0 / hz if hz > 0 else math.inf) for name, hz in rates.items()}
        self._next_s: dict[str, float] = {name: -math.inf for name in rates}
        header: dict[str, Any] = {
            "sys_name": "viva-sitl",
            "ver_hw": "SITL",
            "sys_os_name": "viva-sitl (PX4 look-alike)",
            "sys_mcu": "Python",
            "time_ref_utc": 0,
            "sys_uuid": f"viva-sitl-{self.system_id}",
        }
        header.update(info or {})
        self.writer = ULogWriter(
            path,
            TOPICS,
            info=header,
            params=param_values(params) if params is not None else None,
            start_us=_us(start_time_s),
            max_queue=max_queue,
        )
        self.path = self.writer.path
        self.boot_wall_s = time.time() - max(0.0, start_time_s)
        self._last_us = -1
        self._last_vel: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._last_vel_s = math.inf  # no sample yet: the first acceleration is 0
        self._next_any_s = -math.inf  # the earliest due time of any topic
        self._last_key: tuple[Any, ...] | None = None
        self._bat_warn = 0
        self._last_status: tuple[Any, ...] | None = None
        self._last_flags: tuple[Any, ...] | None = None
        self._armed_since_us = 0
        self._takeoff_us = 0
        self._nav_since_us = 0
        self._last_mode: FlightMode | None = None
        self._was_armed = False
        self._was_airborne = False
        self.skipped_steps = 0  # steps whose time did not advance (a reset)

    def _due(self, name: str, now_s: float) -> bool:
        if now_s >= self._next_s[name]:
            nxt = self._next_s[name] + self._period_s[name]
            self._next_s[name] = nxt if nxt > now_s else now_s + self._period_s[name]
            return True
        return False

    def step(
        self, state: EavState, autopilot: Autopilot, attitude_setpoint: EavCommand | None = None
    ) -> None:
        """Log what is due at `state.time_s`. `attitude_setpoint`: the attitude/thrust command that flew this step
        (a pilot's own command when it bypassed the autopilot); None: the autopilot's last output, when it has one."""
        if attitude_setpoint is None:
            attitude_setpoint = getattr(autopilot, "last_command", None)
        now_s = float(state.time_s)
        us = _us(now_s)
        if us <= self._last_us:
            self.skipped_steps += 1
            return
        self._last_us = us
        armed = bool(autopilot.armed)
        mode = autopilot.mode
        flags = autopilot.commander.failsafe_flags  # a frozen dataclass, replaced when a flag changes
        offboard_lost = mode == FlightMode.OFFBOARD and not autopilot.tasks.offboard.fresh(now_s)
        key = (armed, mode, bool(state.landed), id(flags), offboard_lost, autopilot.ctx.position_valid)
        if now_s < self._next_any_s and key == self._last_key:
            return  # the common step: nothing due, nothing changed (a few attribute reads)
        self._last_key = key
        w = self.writer
        due = self._due
        ground_z = float(autopilot.eav.ground_z_ned_m)
        if due("vehicle_local_position", now_s):
            pos = _f3(state.pos_ned_m)
            vel = _f3(state.vel_ned_m_s)
            dt = now_s - self._last_vel_s
            acc = (
                tuple((v - p) / dt for v, p in zip(vel, self._last_vel, strict=True))
                if dt > 0
                else (0.0,) * 3
            )
            self._last_vel, self._last_vel_s = vel, now_s
            w.log(LOCAL_POSITION, us, (
                us, True, True, True, True, *pos, *vel, *acc, float(state.att_rpy_rad[2]), True, True,
                self.geo.lat_deg, self.geo.lon_deg, self.geo.alt_amsl_m,
                max(0.0, ground_z - pos[2]), True,
            ))  # fmt: skip
        if due("vehicle_global_position", now_s):
            lat, lon, alt = self.geo.ned_to_global(*_f3(state.pos_ned_m))
            terrain = self.geo.alt_amsl_m - ground_z
            w.log(GLOBAL_POSITION, us, (us, lat, lon, alt, alt, 0.5, 0.8, terrain, True, False))
        if due("vehicle_attitude", now_s):
            q = quat_from_euler(*_f3(state.att_rpy_rad))
            w.log(ATTITUDE, us, (us, q, (0.0, 0.0, 0.0, 0.0), 0))
        if armed and not self._was_armed:
            self._armed_since_us = us
        if not armed:
            self._armed_since_us = 0
            self._takeoff_us = 0
        airborne = not state.landed
        if armed and airborne and not self._was_airborne and self._takeoff_us == 0:
            self._takeoff_us = us
        self._was_armed, self._was_airborne = armed, airborne
        if mode != self._last_mode:
            self._last_mode, self._nav_since_us = mode, us
        battery_due = due("battery_status", now_s)
        if battery_due:
            self._bat_warn = battery_level(float(autopilot.battery_remaining), autopilot.params)
            w.log(BATTERY, us, (
                True, float(autopilot.battery_voltage_v), float(autopilot.battery_current_a),
                float(autopilot.battery_remaining), self._bat_warn, 0,
            ))  # fmt: skip
        bat_warn = self._bat_warn
        no_pos = not autopilot.ctx.position_valid  # an injected GPS failure past the dead-reckoning time
        flag_values = (
            bool(flags.rc_lost_handled), bool(flags.dll_lost), offboard_lost,
            bool(flags.fence_breached or flags.gf_outside), bat_warn, no_pos, no_pos, False,
        )  # fmt: skip
        failsafe = any(flag_values[:4]) or bat_warn >= 2
        status = (
            self._armed_since_us, self._takeoff_us, self._nav_since_us,
            ARMING_STATE_ARMED if armed else ARMING_STATE_DISARMED, NAV_STATE.get(mode, 4),
            VEHICLE_TYPE_ROTARY_WING, MAV_TYPE_QUADROTOR, self.system_id & 0xFF, 1, failsafe, True, False,
        )  # fmt: skip
        if due("vehicle_status", now_s) or status != self._last_status:
            self._last_status = status
            w.log(STATUS, us, status)
        if due("failsafe_flags", now_s) or flag_values != self._last_flags:
            self._last_flags = flag_values
            w.log(FAILSAFE_FLAGS, us, flag_values)
        if due("trajectory_setpoint", now_s):
            ctx = autopilot.ctx
            vel_sp = _f3(ctx.ctrl.last_vel_sp_ned_m_s) if armed else _NAN3
            w.log(TRAJECTORY_SETPOINT, us, (_NAN3, vel_sp, _NAN3, _NAN3, float(ctx.yaw_sp), math.nan))
        if attitude_setpoint is not None and due("vehicle_attitude_setpoint", now_s):
            cmd = attitude_setpoint
            max_thrust = float(autopilot.eav_params().max_thrust_n)
            thrust = -float(cmd.thrust_n) / max_thrust if max_thrust > 0 else math.nan
            w.log(ATTITUDE_SETPOINT, us, (
                math.nan, quat_from_euler(cmd.roll_rad, cmd.pitch_rad, cmd.yaw_rad), (0.0, 0.0, thrust),
            ))  # fmt: skip
        self._next_any_s = min(
            t
            for name, t in self._next_s.items()
            if attitude_setpoint is not None or name != "vehicle_attitude_setpoint"
        )

    def camera_capture(
        self,
        seq: int,
        time_s: float,
        lat_deg: float,
        lon_deg: float,
        alt_amsl_m: float,
        ground_distance_m: float,
        q: tuple[float, float, float, float],
        ok: bool,
    ) -> None:
        us = max(_us(time_s), self._last_us if self._last_us > 0 else 0)
        utc_us = int((self.boot_wall_s + time_s) * 1e6)
        self.writer.log(CAMERA_CAPTURE, us, (
            utc_us, int(seq) & 0xFFFFFFFF, lat_deg, lon_deg, alt_amsl_m, ground_distance_m, q, 1 if ok else 0,
        ))  # fmt: skip

    def text(self, severity: int, time_s: float, text: str) -> None:
        """A logged string ('L' message; PX4 logs its mavlink_log texts the same way)."""
        self.writer.text(int(severity), max(_us(time_s), max(self._last_us, 0)), text)

    @property
    def stats(self) -> dict[str, Any]:
        w = self.writer
        return {"path": str(self.path), "bytes": w.bytes_written, "samples": w.samples, "dropped": w.dropped,
                "write_errors": w.write_errors}  # fmt: skip

    def close(self) -> None:
        self.writer.close()


__all__ = ["LOG_FILE", "TOPICS", "FlightLog"]
