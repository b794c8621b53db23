"""Telemetry: message builders from the vehicle state, and per-link stream rates (SET_MESSAGE_INTERVAL).

Rates follow PX4's mavlink modes: by default both links run PX4's "onboard" profile (ATTITUDE 100 Hz, ...) as the
issue asks; PX4's lighter "normal" profile (what PX4 SITL runs on its GCS link) is available per link. Each link
keeps its own intervals, changed by SET_MESSAGE_INTERVAL received on that link (0 = back to the default, -1 = off).
Scheduling is on simulation time (the endpoint passes the physics clock): rates are per simulated second, as in PX4
lockstep SITL, whatever the --speed factor.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.failures import FailureType, FailureUnit
from viva_sitl.autopilot.types import FlightMode, LandedState
from viva_sitl.dynamics import EavState, quat_from_euler
from viva_sitl.mavlink.base import UINT16_MAX, MavMessage, VehicleLink, clamp_int, time_boot_ms, time_boot_us
from viva_sitl.mavlink.config import StreamProfile
from viva_sitl.mavlink.version import FLIGHT_SW_VERSION, flight_custom_version

M = mavlink2
MAX_STREAM_HZ = 500.0  # SET_MESSAGE_INTERVAL requests faster than this are capped (CPU of a 2-core machine)

# MAV_SYS_STATUS_SENSOR bits this vehicle reports present + enabled + healthy (simulated sensors never fail)
SENSORS_ALWAYS = (
    M.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | M.MAV_SYS_STATUS_SENSOR_3D_MAG
    | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_GPS
    | M.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | M.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | M.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | M.MAV_SYS_STATUS_AHRS
    | M.MAV_SYS_STATUS_SENSOR_BATTERY
)
SENSOR_RC = M.MAV_SYS_STATUS_SENSOR_RC_RECEIVER
SENSOR_PREARM = M.MAV_SYS_STATUS_PREARM_CHECK
# HIGHRES_IMU fields_updated bits of each sensor unit (accel xyz, gyro xyz, mag xyz, abs/diff pressure, pressure
# altitude, temperature)
_IMU_FIELD_BITS: dict[FailureUnit, int] = {
    FailureUnit.SENSOR_ACCEL: 0x7,
    FailureUnit.SENSOR_GYRO: 0x38,
    FailureUnit.SENSOR_MAG: 0x1C0,
    FailureUnit.SENSOR_BARO: 0x1E00,
}

AUTOPILOT_CAPABILITIES = (
    M.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | M.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | M.MAV_PROTOCOL_CAPABILITY_FLIGHT_TERMINATION
    | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
)


_MI = M.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
_ST = M.MAV_MODE_FLAG_STABILIZE_ENABLED
_GU = M.MAV_MODE_FLAG_GUIDED_ENABLED
_AU = M.MAV_MODE_FLAG_AUTO_ENABLED
# PX4 main mode -> extra HEARTBEAT.base_mode flags (MANUAL, ALTCTL, POSCTL, AUTO, ACRO, OFFBOARD, STABILIZED)
_MODE_FLAGS = {
    1: _MI | _ST,
    2: _MI | _ST,
    3: _MI | _ST | _GU,
    4: _AU | _ST | _GU,
    5: _MI,
    6: _AU | _ST | _GU,
    7: _MI | _ST,
}


# message id -> default rate (Hz) per profile; absent = not streamed by default (SET_MESSAGE_INTERVAL can enable it)
PROFILE_RATES_HZ: dict[StreamProfile, dict[int, float]] = {
    StreamProfile.ONBOARD: {
        M.MAVLINK_MSG_ID_ATTITUDE: 100.0,
        M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
        M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 50.0,
        M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
        M.MAVLINK_MSG_ID_ALTITUDE: 10.0,
        M.MAVLINK_MSG_ID_GPS_RAW_INT: 10.0,
        M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
        M.MAVLINK_MSG_ID_SYS_STATUS: 5.0,
        M.MAVLINK_MSG_ID_VFR_HUD: 4.0,
        M.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
        M.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
        M.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
        M.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
        M.MAVLINK_MSG_ID_ORBIT_EXECUTION_STATUS: 5.0,  # sent only while orbiting
    },
    StreamProfile.NORMAL: {
        M.MAVLINK_MSG_ID_ATTITUDE: 15.0,
        M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 5.0,
        M.MAVLINK_MSG_ID_VFR_HUD: 4.0,
        M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 1.0,
        M.MAVLINK_MSG_ID_ALTITUDE: 1.0,
        M.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
        M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
        M.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
        M.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
        M.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
        M.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
        M.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
        M.MAVLINK_MSG_ID_ORBIT_EXECUTION_STATUS: 2.0,  # sent only while orbiting
    },
}


def battery_charge_state(remaining: float, params: object) -> int:
    """MAV_BATTERY_CHARGE_STATE from the remaining fraction and PX4's BAT_LOW_THR / BAT_CRIT_THR /
    BAT_EMERGEN_THR (the parameters when the store has them, PX4's defaults otherwise)."""

    def thr(name: str, default: float) -> float:
        get = getattr(params, "get", None)
        try:
            value = float(get(name)) if callable(get) else default
        except Exception:  # a store without this parameter: PX4's default
            value = default
        return value if math.isfinite(value) else default

    if not math.isfinite(remaining):
        return int(M.MAV_BATTERY_CHARGE_STATE_UNDEFINED)
    if remaining <= thr("BAT_EMERGEN_THR", 0.05):
        return int(M.MAV_BATTERY_CHARGE_STATE_EMERGENCY)
    if remaining <= thr("BAT_CRIT_THR", 0.07):
        return int(M.MAV_BATTERY_CHARGE_STATE_CRITICAL)
    if remaining <= thr("BAT_LOW_THR", 0.15):
        return int(M.MAV_BATTERY_CHARGE_STATE_LOW)
    return int(M.MAV_BATTERY_CHARGE_STATE_OK)


def _euler_rates_to_body(
    roll: float, pitch: float, d_roll: float, d_pitch: float, d_yaw: float
) -> tuple[float, float, float]:
    """ZYX Euler angle rates -> FRD body rates (p, q, r)."""
    sr, cr = math.sin(roll), math.cos(roll)
    sp, cp = math.sin(pitch), math.cos(pitch)
    return (d_roll - d_yaw * sp, d_pitch * cr + d_yaw * cp * sr, -d_pitch * sr + d_yaw * cp * cr)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _f(x: float) -> float:
    """A wire float: non-finite values (which a sane state never has) become 0 so clients never see NaN garbage."""
    return float(x) if math.isfinite(x) else 0.0


@dataclass(frozen=True)
class Snapshot:
    """Derived quantities of one physics state (computed once per state, shared by every message built from it)."""

    pos_ned_m: tuple[float, float, float]
    vel_ned_m_s: tuple[float, float, float]
    rpy_rad: tuple[float, float, float]
    body_rates_rad_s: tuple[float, float, float]
    q_wxyz: tuple[float, float, float, float]
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    home_ned_m: tuple[float, float, float]
    home_lat_deg: float
    home_lon_deg: float
    home_alt_amsl_m: float
    thrust_n: float

    @property
    def relative_alt_m(self) -> float:
        return self.home_ned_m[2] - self.pos_ned_m[2]

    @property
    def heading_deg(self) -> float:
        return math.degrees(self.rpy_rad[2]) % 360.0

    @property
    def ground_speed_m_s(self) -> float:
        return math.hypot(self.vel_ned_m_s[0], self.vel_ned_m_s[1])


def _finite3(v: object) -> tuple[float, float, float]:
    a = [float(x) for x in v]  # type: ignore[attr-defined]
    return (_f(a[0]), _f(a[1]), _f(a[2]))


class TelemetryBuilder:
    """Builds every telemetry message from the vehicle (autopilot + latest state)."""

    def __init__(self, vehicle: VehicleLink, sysid: int) -> None:
        self.vehicle = vehicle
        self.sysid = sysid
        self._state: EavState | None = None
        self._home: tuple[float, float, float] | None = None
        self._snap: Snapshot | None = None
        self._prev_att: tuple[float, float, float, float] | None = None  # (t, roll, pitch, yaw)
        self._rates = (0.0, 0.0, 0.0)
        self.last_manual_input_s = -math.inf  # sim time of the last MANUAL_CONTROL (RC "present" bit)
        self.prearm_ok: Callable[[], bool] = lambda: not self.vehicle.autopilot.armed
        # the last good raw readings, repeated while an injected STUCK failure holds that sensor (as PX4's simulated
        # sensors repeat their last sample): GPS_RAW_INT's fields, HIGHRES_IMU's accel / gyro / mag / baro triples
        self._gps_last: tuple[int, ...] | None = None
        self._imu_last: dict[FailureUnit, tuple[float, ...]] = {}
        self.builders: dict[int, Callable[[], MavMessage | None]] = {
            M.MAVLINK_MSG_ID_HEARTBEAT: self.heartbeat,
            M.MAVLINK_MSG_ID_SYS_STATUS: self.sys_status,
            M.MAVLINK_MSG_ID_SYSTEM_TIME: self.system_time,
            M.MAVLINK_MSG_ID_ATTITUDE: self.attitude,
            M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self.attitude_quaternion,
            M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self.global_position_int,
            M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.local_position_ned,
            M.MAVLINK_MSG_ID_GPS_RAW_INT: self.gps_raw_int,
            M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.extended_sys_state,
            M.MAVLINK_MSG_ID_BATTERY_STATUS: self.battery_status,
            M.MAVLINK_MSG_ID_HOME_POSITION: self.home_position,
            M.MAVLINK_MSG_ID_VFR_HUD: self.vfr_hud,
            M.MAVLINK_MSG_ID_MISSION_CURRENT: self.mission_current,
            M.MAVLINK_MSG_ID_ALTITUDE: self.altitude,
            M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self.autopilot_version,
            M.MAVLINK_MSG_ID_ORBIT_EXECUTION_STATUS: self.orbit_execution_status,
            M.MAVLINK_MSG_ID_HIGHRES_IMU: self.highres_imu,  # on request (MAVSDK set_rate_imu), as PX4
        }

    # --- snapshot ---------------------------------------------------------------------------
    def snapshot(self) -> Snapshot:
        state = self.vehicle.state
        home = tuple(float(v) for v in self.vehicle.autopilot.home_ned_m)
        if self._snap is not None and state is self._state and home == self._home:
            return self._snap
        pos = _finite3(state.pos_ned_m)
        vel = _finite3(state.vel_ned_m_s)
        roll, pitch, yaw = _finite3(state.att_rpy_rad)
        t = float(state.time_s)
        if self._prev_att is not None and state is not self._state:
            t0, r0, p0, y0 = self._prev_att
            dt = t - t0
            if dt > 1e-6:
                self._rates = _euler_rates_to_body(
                    roll, pitch, (roll - r0) / dt, (pitch - p0) / dt, _wrap(yaw - y0) / dt
                )
                self._rates = _finite3(self._rates)
        self._prev_att = (t, roll, pitch, yaw)
        geo = self.vehicle.geo
        lat, lon, alt = geo.ned_to_global(*pos)
        home3 = (
            (home[0], home[1], home[2])
            if len(home) == 3 and all(math.isfinite(v) for v in home)
            else (0.0, 0.0, 0.0)
        )
        hlat, hlon, halt = geo.ned_to_global(*home3)
        self._snap = Snapshot(
            pos_ned_m=pos,
            vel_ned_m_s=vel,
            rpy_rad=(roll, pitch, yaw),
            body_rates_rad_s=self._rates,
            q_wxyz=quat_from_euler(roll, pitch, yaw),
            lat_deg=lat,
            lon_deg=lon,
            alt_amsl_m=alt,
            home_ned_m=home3,
            home_lat_deg=hlat,
            home_lon_deg=hlon,
            home_alt_amsl_m=halt,
            thrust_n=_f(float(state.thrust_n)),
        )
        self._state = state
        self._home = home  # type: ignore[assignment]
        return self._snap

    def build(self, msgid: int) -> MavMessage | None:
        builder = self.builders.get(msgid)
        return builder() if builder is not None else None

    # --- messages ---------------------------------------------------------------------------
    def heartbeat(self) -> MavMessage:
        ap = self.vehicle.autopilot
        mode: FlightMode = ap.mode
        base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if ap.armed:
            base |= M.MAV_MODE_FLAG_SAFETY_ARMED
        # PX4's base_mode flags per main mode (mavlink heartbeat: get_mavlink_navigation_mode)
        base |= _MODE_FLAGS.get(int(mode.value[0]), 0)
        status = M.MAV_STATE_ACTIVE if ap.armed else M.MAV_STATE_STANDBY
        return M.MAVLink_heartbeat_message(
            M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, base, mode.custom_mode, status, 3
        )

    def orbit_execution_status(self) -> MavMessage | None:
        """ORBIT_EXECUTION_STATUS while in Orbit (PX4: frame GLOBAL, centre lat/lon degE7, z = AMSL altitude)."""
        orbit = self.vehicle.autopilot.orbit_status
        if orbit is None:
            return None
        geo = self.vehicle.geo
        lat, lon, _ = geo.ned_to_global(orbit.center_n_m, orbit.center_e_m, 0.0)
        return M.MAVLink_orbit_execution_status_message(
            time_boot_us(self.vehicle), orbit.signed_radius_m, M.MAV_FRAME_GLOBAL,
            round(lat * 1e7), round(lon * 1e7), geo.alt_amsl_m - orbit.center_down_m,
        )  # fmt: skip

    def sys_status(self) -> MavMessage:
        ap = self.vehicle.autopilot
        present = SENSORS_ALWAYS | SENSOR_PREARM
        enabled = SENSORS_ALWAYS | SENSOR_PREARM
        health = SENSORS_ALWAYS
        if math.isfinite(self.last_manual_input_s):
            present |= SENSOR_RC
            enabled |= SENSOR_RC
            if float(self.vehicle.time_s) - self.last_manual_input_s < 1.0:
                health |= SENSOR_RC
        try:
            if self.prearm_ok():
                health |= SENSOR_PREARM
        except Exception:  # a failing check is a failed check, never a dead telemetry stream
            pass
        # injected sensor failures (MAV_CMD_INJECT_FAILURE) clear their health bits
        health &= ~int(getattr(ap, "failed_health_bits", 0))
        volt_mv = clamp_int(ap.battery_voltage_v * 1000.0, 0, UINT16_MAX - 1)
        remaining = clamp_int(ap.battery_remaining * 100.0, 0, 100)
        return M.MAVLink_sys_status_message(
            present, enabled, health, 200, volt_mv, self._current_ca(), remaining, 0, 0, 0, 0, 0, 0
        )

    def _current_ca(self) -> int:
        """Battery current in cA (-1: unknown); battery_current_a is optional in the autopilot contract."""
        amps = getattr(self.vehicle.autopilot, "battery_current_a", None)
        if amps is None or not math.isfinite(float(amps)):
            return -1
        return clamp_int(float(amps) * 100.0, 0, 32767)

    def system_time(self) -> MavMessage:
        return M.MAVLink_system_time_message(int(time.time() * 1e6), time_boot_ms(self.vehicle))

    def highres_imu(self) -> MavMessage:
        """HIGHRES_IMU, FRD body frame, from the ideal sensors: the accelerometer reads the thrust's specific force
        (-thrust/mass on z; drag neglected), or -g rotated into the body on the ground; the gyro the body rates; the
        magnetometer a fixed NED field (PX4 SITL's default location, gauss); ISA pressure and temperature."""
        s = self.snapshot()
        ap = self.vehicle.autopilot
        eav_params = getattr(ap, "eav_params", None)
        params = eav_params() if callable(eav_params) else ap.eav
        mass_kg = float(getattr(params, "mass_kg", 0.0)) or 1.0
        g = float(getattr(params, "gravity_m_s2", 9.80665))
        roll, pitch, yaw = s.rpy_rad
        sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
        sy, cy = math.sin(yaw), math.cos(yaw)

        def to_body(n: float, e: float, d: float) -> tuple[float, float, float]:  # R^T (ZYX) applied to NED
            return (
                cp * cy * n + cp * sy * e - sp * d,
                (sr * sp * cy - cr * sy) * n + (sr * sp * sy + cr * cy) * e + sr * cp * d,
                (cr * sp * cy + sr * sy) * n + (cr * sp * sy - sr * cy) * e + cr * cp * d,
            )

        lifted = s.thrust_n / mass_kg
        if ap.landed_state == LandedState.ON_GROUND and lifted < g:
            acc = to_body(0.0, 0.0, -g)
        else:
            acc = (0.0, 0.0, -lifted)
        mag = to_body(0.21, 0.01, 0.42)
        alt = s.alt_amsl_m
        pressure_hpa = 1013.25 * max(1.0 - 2.25577e-5 * alt, 1e-6) ** 5.25588
        live: dict[FailureUnit, tuple[float, ...]] = {
            FailureUnit.SENSOR_ACCEL: tuple(_f(v) for v in acc),
            FailureUnit.SENSOR_GYRO: tuple(_f(v) for v in s.body_rates_rad_s),
            FailureUnit.SENSOR_MAG: tuple(_f(v) for v in mag),
            FailureUnit.SENSOR_BARO: (_f(pressure_hpa), 0.0, _f(alt), _f(15.0 - 0.0065 * alt)),
        }
        updated = 0x1FFF
        fault_of = getattr(ap, "sensor_fault", None)
        for unit, bits in _IMU_FIELD_BITS.items():
            fault = fault_of(unit) if callable(fault_of) else None
            if fault is FailureType.OFF:  # no new sample: PX4 sends the last one it had, its bits not set
                live[unit] = self._imu_last.get(unit, (0.0,) * len(live[unit]))
                updated &= ~bits
            elif fault is FailureType.STUCK:  # the last sample repeated
                live[unit] = self._imu_last.setdefault(unit, live[unit])
            else:
                self._imu_last[unit] = live[unit]
        return M.MAVLink_highres_imu_message(
            time_boot_us(self.vehicle),
            *live[FailureUnit.SENSOR_ACCEL],
            *live[FailureUnit.SENSOR_GYRO],
            *live[FailureUnit.SENSOR_MAG],
            *live[FailureUnit.SENSOR_BARO],
            updated,
            0,
        )

    def attitude(self) -> MavMessage:
        s = self.snapshot()
        return M.MAVLink_attitude_message(time_boot_ms(self.vehicle), *s.rpy_rad, *s.body_rates_rad_s)

    def attitude_quaternion(self) -> MavMessage:
        s = self.snapshot()
        return M.MAVLink_attitude_quaternion_message(
            time_boot_ms(self.vehicle), *s.q_wxyz, *s.body_rates_rad_s, (0.0, 0.0, 0.0, 0.0)
        )

    def global_position_int(self) -> MavMessage | None:
        if not getattr(self.vehicle.autopilot, "global_position_valid", True):
            return None  # PX4 publishes no global position while the estimate is invalid (a lost GPS)
        s = self.snapshot()
        vn, ve, vd = s.vel_ned_m_s
        return M.MAVLink_global_position_int_message(
            time_boot_ms(self.vehicle),
            clamp_int(s.lat_deg * 1e7, -900000000, 900000000),
            clamp_int(s.lon_deg * 1e7, -1800000000, 1800000000),
            clamp_int(s.alt_amsl_m * 1000.0, -(2**31), 2**31 - 1),
            clamp_int(s.relative_alt_m * 1000.0, -(2**31), 2**31 - 1),
            clamp_int(vn * 100.0, -32768, 32767),
            clamp_int(ve * 100.0, -32768, 32767),
            clamp_int(vd * 100.0, -32768, 32767),
            clamp_int(s.heading_deg * 100.0, 0, 35999),
        )

    def local_position_ned(self) -> MavMessage:
        s = self.snapshot()
        return M.MAVLink_local_position_ned_message(time_boot_ms(self.vehicle), *s.pos_ned_m, *s.vel_ned_m_s)

    def gps_raw_int(self) -> MavMessage:
        # an injected GPS failure: no fix, no satellites
        if not getattr(self.vehicle.autopilot, "gps_fix", True):
            return M.MAVLink_gps_raw_int_message(
                time_boot_us(self.vehicle), M.GPS_FIX_TYPE_NO_GPS, 0, 0, 0, UINT16_MAX, UINT16_MAX,
                UINT16_MAX, UINT16_MAX, 0, 0, 0, 0, 0, 0, 0,
            )  # fmt: skip
        fault_of = getattr(self.vehicle.autopilot, "sensor_fault", None)
        fault = fault_of(FailureUnit.SENSOR_GPS) if callable(fault_of) else None
        if fault is FailureType.STUCK:  # PX4 main re-publishes the last fix, its time included
            if self._gps_last is None:
                self._gps_last = self._gps_fields(0.0, 0.0, 0.0)
            return M.MAVLink_gps_raw_int_message(*self._gps_last)
        if fault is FailureType.WRONG:  # PX4 main: lat/lon +1 deg, altitude +100 m, ground speed -1 m/s
            return M.MAVLink_gps_raw_int_message(*self._gps_fields(1.0, 1.0, 100.0, speed_off_m_s=-1.0))
        self._gps_last = fields = self._gps_fields(0.0, 0.0, 0.0)
        return M.MAVLink_gps_raw_int_message(*fields)

    def _gps_fields(
        self, dlat_deg: float, dlon_deg: float, dalt_m: float, *, speed_off_m_s: float = 0.0
    ) -> tuple[int, ...]:
        """GPS_RAW_INT's fields from the true state, offset as an injected WRONG GPS does."""
        s = self.snapshot()
        cog = (
            math.degrees(math.atan2(s.vel_ned_m_s[1], s.vel_ned_m_s[0])) % 360.0
            if s.ground_speed_m_s > 0.1
            else 0.0
        )
        lat = s.lat_deg + dlat_deg
        lon = (s.lon_deg + dlon_deg + 180.0) % 360.0 - 180.0
        alt_mm = clamp_int((s.alt_amsl_m + dalt_m) * 1000.0, -(2**31), 2**31 - 1)
        return (
            time_boot_us(self.vehicle),
            M.GPS_FIX_TYPE_3D_FIX,
            clamp_int(lat * 1e7, -900000000, 900000000),
            clamp_int(lon * 1e7, -1800000000, 1800000000),
            alt_mm,
            80,  # HDOP 0.8
            120,  # VDOP 1.2
            clamp_int((s.ground_speed_m_s + speed_off_m_s) * 100.0, 0, UINT16_MAX - 1),
            clamp_int(cog * 100.0, 0, 35999),  # PX4 leaves cog_rad as it was
            12,
            alt_mm,
            300,  # h_acc mm
            500,  # v_acc mm
            100,  # vel_acc mm/s
            0,
            0,
        )

    def extended_sys_state(self) -> MavMessage:
        landed: LandedState = self.vehicle.autopilot.landed_state
        return M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_UNDEFINED, int(landed))

    def battery_status(self) -> MavMessage:
        ap = self.vehicle.autopilot
        volt_mv = clamp_int(ap.battery_voltage_v * 1000.0, 0, UINT16_MAX - 1)
        remaining = ap.battery_remaining
        charge = battery_charge_state(remaining, ap.params)
        return M.MAVLink_battery_status_message(
            0,
            M.MAV_BATTERY_FUNCTION_ALL,
            M.MAV_BATTERY_TYPE_LIPO,
            0x7FFF,  # temperature unknown
            [volt_mv] + [UINT16_MAX] * 9,
            self._current_ca(),
            -1,
            -1,
            clamp_int(remaining * 100.0, 0, 100),
            0,
            charge,
            [0, 0, 0, 0],
            0,
            0,
        )

    def home_position(self) -> MavMessage:
        s = self.snapshot()
        h = s.home_ned_m
        return M.MAVLink_home_position_message(
            clamp_int(s.home_lat_deg * 1e7, -900000000, 900000000),
            clamp_int(s.home_lon_deg * 1e7, -1800000000, 1800000000),
            clamp_int(s.home_alt_amsl_m * 1000.0, -(2**31), 2**31 - 1),
            h[0],
            h[1],
            h[2],
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            0.0,
            0.0,
            time_boot_us(self.vehicle),
        )

    def vfr_hud(self) -> MavMessage:
        s = self.snapshot()
        ap = self.vehicle.autopilot
        eav_params = getattr(ap, "eav_params", None)  # the live airframe (SIM_MASS), optional in the contract
        max_thrust_n = float(eav_params().max_thrust_n if callable(eav_params) else ap.eav.max_thrust_n)
        throttle = clamp_int(100.0 * s.thrust_n / max_thrust_n, 0, 100) if max_thrust_n > 0 else 0
        return M.MAVLink_vfr_hud_message(
            self.airspeed_m_s(s),
            s.ground_speed_m_s,
            clamp_int(s.heading_deg, 0, 359),
            throttle,
            s.alt_amsl_m,
            -s.vel_ned_m_s[2],
        )

    def airspeed_m_s(self, s: Snapshot) -> float:
        """|v_ground - v_wind|: the air-relative speed (mean wind from the live airframe + the current gust)."""
        ap = self.vehicle.autopilot
        eav_params = getattr(ap, "eav_params", None)
        wind_params = eav_params().wind if callable(eav_params) else ap.eav.wind
        mean = tuple(float(v) for v in wind_params.mean_wind_ned_m_s)
        gust = getattr(self.vehicle.state, "gust_ned_m_s", (0.0, 0.0, 0.0))
        rel = [s.vel_ned_m_s[i] - mean[i] - float(gust[i]) for i in range(3)]
        return _f(math.sqrt(rel[0] ** 2 + rel[1] ** 2 + rel[2] ** 2))

    def mission_current(self) -> MavMessage:
        ap = self.vehicle.autopilot
        total = len(ap.mission_items)
        seq = max(0, int(ap.mission_current_seq))
        in_mission = ap.mode == FlightMode.AUTO_MISSION
        finished = bool(getattr(ap, "mission_finished", False))  # optional in the autopilot contract
        if total == 0:
            state = M.MISSION_STATE_NO_MISSION
        elif finished or seq >= total:
            state = M.MISSION_STATE_COMPLETE
        elif in_mission:
            state = M.MISSION_STATE_ACTIVE
        elif seq == 0:
            state = M.MISSION_STATE_NOT_STARTED
        else:
            state = M.MISSION_STATE_PAUSED
        mission_mode = 1 if in_mission else 2
        return M.MAVLink_mission_current_message(min(seq, 0xFFFF), min(total, 0xFFFF), state, mission_mode)

    def altitude(self) -> MavMessage:
        s = self.snapshot()
        up = -s.pos_ned_m[2]
        return M.MAVLink_altitude_message(
            time_boot_us(self.vehicle), s.alt_amsl_m, s.alt_amsl_m, up, s.relative_alt_m, up, up
        )

    def autopilot_version(self) -> MavMessage:
        uid = 0x56495641_00000000 | self.sysid  # "VIVA" + sysid: unique per instance
        custom = flight_custom_version()  # git hash bytes as PX4 (zeros outside a source checkout)
        return M.MAVLink_autopilot_version_message(
            AUTOPILOT_CAPABILITIES,
            FLIGHT_SW_VERSION,
            FLIGHT_SW_VERSION,  # middleware_sw_version: PX4 reports its firmware version here too
            0,
            0,
            list(custom),
            list(custom),
            [0] * 8,
            0,
            0,
            uid,
            [0] * 18,
        )


@dataclass
class Stream:
    msgid: int
    default_interval_s: float | None  # None: not streamed unless requested
    interval_s: float | None
    next_due_s: float = 0.0


class LinkStreams:
    """The stream table of one link: which messages go out, how often, and when next."""

    def __init__(self, profile: StreamProfile, overrides_hz: dict[int, float], builders: set[int]) -> None:
        rates = dict(PROFILE_RATES_HZ[profile])
        rates.update(overrides_hz)
        self.builders = builders
        self.skipped = 0  # due messages not sent because one step crossed several periods (read and reset)
        self.streams: dict[int, Stream] = {}
        for msgid, hz in rates.items():
            interval = 1.0 / hz if hz > 0 else None
            self.streams[msgid] = Stream(msgid, interval, interval)

    def set_interval(self, msgid: int, interval_us: float, now_s: float) -> bool:
        """SET_MESSAGE_INTERVAL semantics. False when the message cannot be streamed by this vehicle."""
        if msgid not in self.builders or msgid == M.MAVLINK_MSG_ID_HEARTBEAT:
            return False
        stream = self.streams.get(msgid)
        if stream is None:
            stream = self.streams[msgid] = Stream(msgid, None, None)
        if not math.isfinite(interval_us):
            return False
        if interval_us == 0:
            stream.interval_s = stream.default_interval_s
        elif interval_us < 0:
            stream.interval_s = None
        else:
            stream.interval_s = max(interval_us * 1e-6, 1.0 / MAX_STREAM_HZ)
        stream.next_due_s = now_s
        return True

    def interval_us(self, msgid: int) -> int:
        """MESSAGE_INTERVAL.interval_us: -1 off, 0 unavailable."""
        if msgid not in self.builders:
            return 0
        stream = self.streams.get(msgid)
        if stream is None or stream.interval_s is None:
            return -1
        return int(round(stream.interval_s * 1e6))

    def due(self, now_s: float) -> list[int]:
        """Message ids due at `now_s`; advances their schedule (no bursts after a stall)."""
        out = []
        for stream in self.streams.values():
            if stream.interval_s is None or now_s < stream.next_due_s:
                continue
            out.append(stream.msgid)
            stream.next_due_s += stream.interval_s
            if stream.next_due_s <= now_s:
                self.skipped += int((now_s - stream.next_due_s) / stream.interval_s) + 1
                stream.next_due_s = now_s + stream.interval_s
        return out

    def next_due_s(self) -> float:
        return min(
            (s.next_due_s for s in self.streams.values() if s.interval_s is not None), default=math.inf
        )
