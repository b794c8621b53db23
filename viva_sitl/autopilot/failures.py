"""Failure injection, as PX4's MAV_CMD_INJECT_FAILURE: a (unit, type) pair switched on until FAILURE_TYPE_OK.

The enums carry MAVLink's FAILURE_UNIT / FAILURE_TYPE values, so the MAVLink command handler, the trials' scenario
failures and tests all name a failure the same way and reach it through one call, `Autopilot.inject_failure`.

Acknowledgement, as PX4 (MavlinkReceiver and its failure-injection manager): DENIED while SYS_FAILURE_EN = 0;
UNSUPPORTED for a unit/type pair this vehicle does not implement (PX4 answers the same for what its simulator does
not implement) or an instance that does not exist; ACCEPTED otherwise, with a WARNING STATUSTEXT
"Injected: <unit> <type>, <instances>" (or "Cleared: <unit>, <instances>" for OK). Instance 0 is every instance;
1..n one of them (the sensors exist once, as instance 1; motors are 1..4, PX4's quad-X numbering).

What each supported failure does (PX4 SITL's consequence; where this vehicle simplifies, it says so):
- SENSOR_GPS, OFF: no GPS data. GPS_RAW_INT reports fix 0 and no satellites at once and SYS_STATUS clears the GPS
  health bit; after EKF2_NOAID_TOUT (PX4's default 5 s of dead reckoning, a constant here) the global position is
  invalid: GLOBAL_POSITION_INT stops, the position modes (Hold, Mission, Return, Takeoff, Position, Orbit) are
  refused, arming is refused, and in the air PX4's mode fallback acts: Position with fresh manual control falls back
  to Altitude (COM_POSCTL_NAVL = 0), everything else to Descend (PX4's navigation state that reports AUTO.LAND: level,
  down at MPC_LAND_SPEED, drifting with the wind). OK: the position is valid again at once and a vehicle that was
  put into Descend by this failsafe returns to the mode it flew (PX4 clears a mode-fallback failsafe when its
  condition clears). Simplified: Offboard keeps flying its setpoints on the true state (PX4 would also fall back).
- SENSOR_BARO / SENSOR_MAG, OFF: SYS_STATUS health bit cleared, "Baro #0 fail: TIMEOUT!" / "Mag #0 fail: TIMEOUT!",
  arming refused, and HIGHRES_IMU stops updating the sensor (below). In the air, as PX4: no mode change and no
  further message (EKF2 keeps its height from GNSS, PX4's default height reference, and its yaw from the gyro and,
  when moving, GNSS; neither triggers a failsafe). Baro and GPS both lost: the GPS failsafe (Descend) covers it.
- SENSOR_ACCEL / SENSOR_GYRO, OFF: health bit cleared, "Accel #0 fail: TIMEOUT!" / "Gyro #0 fail: TIMEOUT!",
  arming refused; in the air there is no attitude estimate, no mode can run, and PX4's fallback chain ends in flight
  termination: the motors stop. Simplified: immediate, where PX4 first sees the sensor time out.
- SYSTEM_MOTOR, OFF (instance = motor 1..4, 0 all): that motor gives no thrust. Simplified mixer model: to balance
  roll and pitch the diagonal partner idles too, so at most half the thrust remains, the vehicle tilts toward the
  dead motor and spins about yaw (no yaw authority): it cannot hold and comes down. SYS_STATUS clears the motor
  outputs health bit.
- SYSTEM_RC_SIGNAL, OFF: MANUAL_CONTROL is no longer heard (the RC receiver lost its link): the RC health bit clears
  and, in a manual mode, PX4's RC-loss failsafe (COM_RC_LOSS_T, NAV_RCL_ACT) follows.
- SYSTEM_MAVLINK_SIGNAL, OFF: the ground station's heartbeats are no longer heard (the radio link is gone; an onboard
  API link keeps working), so PX4's data-link-loss failsafe (COM_DL_LOSS_T, NAV_DLL_ACT) follows as on a vehicle.
  OK: heard again ("Data link regained" at the next heartbeat).
- SYSTEM_BATTERY, OFF: the battery reads empty (PX4's battery simulator forces the empty voltage: remaining 0 %, the
  emergency level and its failsafe). OK: the battery reads its real charge again.
- SYSTEM_BATTERY, WRONG (PX4 reports the charge just below the critical threshold): the pack is drained to just
  below BAT_CRIT_THR now (SIM_BAT_MIN_PCT set to 0 so that it may go that low): PX4's "Critical battery level! Land
  now" warning and BAT_CRIT action follow at the next control step. A drain is not undone by OK.
- SENSOR_CAMERA (viva-sitl's extension, unit 200: MAVLink's FAILURE_UNIT has no camera): the VAC on every video
  output, the frame socket and the in-process pilots' frames. OFF: no frames are delivered (callers that must get a
  frame get black); STUCK: the last good image is repeated (frozen; the frame metadata keeps telling the true pose);
  WRONG: black frames. OK: live frames again.
- SENSOR_ACCEL / SENSOR_GYRO / SENSOR_MAG / SENSOR_BARO, STUCK (PX4 SITL: the simulated sensor repeats its last
  sample): HIGHRES_IMU repeats the last reading of that sensor; PX4's sensor voter flags a sensor whose values stop
  changing as stale: "<Name> #0 fail: STALE!", SYS_STATUS health bit cleared, arming refused. In the air the
  consequence is that of OFF (accel/gyro: no usable attitude estimate, flight termination, simplified: immediate;
  mag/baro: EKF2 goes on with GNSS yaw / GNSS height, no mode change).
- SENSOR_ACCEL / SENSOR_GYRO / SENSOR_MAG / SENSOR_BARO, OFF: HIGHRES_IMU stops updating that sensor (its
  fields_updated bits cleared, its fields keep the last reading), as PX4's HIGHRES_IMU stream does when the sensor
  topic stops.
- SENSOR_GPS, STUCK (PX4 main: the last sensor_gps message is re-published, timestamp included): GPS_RAW_INT repeats
  the last fix (3D fix, same position, speed and time_usec). SENSOR_GPS, WRONG (PX4 main: latitude and longitude
  +1 deg, altitude +100 m, ground speed -1 m/s, velocity north +5 / east -8 / down +2 m/s): GPS_RAW_INT reports
  that offset fix. For the estimate both act as OFF: a stuck fix brings EKF2 no new sample, a wrong one fails every
  innovation check, so the GPS health bit clears and the global position is lost after EKF2_NOAID_TOUT with
  the same failsafe. Simplified: PX4's EKF2 may later reset its position onto the wrong fix; here it stays lost.
Every other pair is UNSUPPORTED, as in PX4 SITL: GARBAGE, SLOW, DELAYED and INTERMITTENT for every unit (no PX4
simulation module handles them), WRONG for accel/gyro/mag/baro, and the other units' types not listed above
(e.g. motor STUCK/WRONG, which PX4 maps to ESC telemetry this vehicle does not send). Where PX4 SITL sets several
flags for one unit (GPS STUCK then WRONG), the last injected type wins here.

Where the supported pairs come from (PX4-Autopilot's source, read for its facts):
- src/modules/simulation/simulator_mavlink/SimulatorMavlink.cpp, check_failure_injections() (Gazebo Classic SITL,
  the versions before the 2025 failure_injection module): GPS OFF/OK; accel, gyro, mag OFF/STUCK/OK; baro OFF/STUCK/OK; airspeed OFF/WRONG; VIO OFF; any
  other type of these units is acknowledged UNSUPPORTED.
- src/modules/simulation/failure_injection/failureInjection.cpp (main, used by sensor_sim_manager for gz/SIH): the
  same plus GPS STUCK (the previous sensor_gps re-published), WRONG (+1 deg, +100 m, velocity offsets) and DRIFT
  (PX4's own FAILURE_TYPE_DRIFT, not in MAVLink's FAILURE_TYPE: unknown, so UNSUPPORTED here), a GPS_ALT unit (not in MAVLink), distance
  sensor and AGP; SensorSimManager.cpp repeats the last baro/mag/IMU sample while STUCK.
- src/modules/commander/failure_detector/FailureInjector.cpp (main): motor OFF/OK; STUCK / WRONG only block or
  falsify ESC telemetry (ESC_STATUS), which this vehicle does not send: UNSUPPORTED here.
- PX4's sensor voter (DataValidator) calls a sensor whose value stops changing STALE, one without data TIMEOUT.
"""

from __future__ import annotations

import enum
import math

from viva_sitl.autopilot.battery import Battery
from viva_sitl.autopilot.params import ParamStore
from viva_sitl.autopilot.types import ACCEPTED, CommandResult, Outcome
from viva_sitl.dynamics import EavCommand, wrap_pi


class FailureUnit(enum.IntEnum):
    """MAVLink FAILURE_UNIT, plus viva-sitl's SENSOR_CAMERA (not in MAVLink)."""

    SENSOR_GYRO = 0
    SENSOR_ACCEL = 1
    SENSOR_MAG = 2
    SENSOR_BARO = 3
    SENSOR_GPS = 4
    SENSOR_OPTICAL_FLOW = 5
    SENSOR_VIO = 6
    SENSOR_DISTANCE_SENSOR = 7
    SENSOR_AIRSPEED = 8
    SYSTEM_BATTERY = 100
    SYSTEM_MOTOR = 101
    SYSTEM_SERVO = 102
    SYSTEM_AVOIDANCE = 103
    SYSTEM_RC_SIGNAL = 104
    SYSTEM_MAVLINK_SIGNAL = 105
    SENSOR_CAMERA = 200  # viva-sitl extension: the VAC (frozen, black or dropped frames)


class FailureType(enum.IntEnum):
    """MAVLink FAILURE_TYPE."""

    OK = 0
    OFF = 1
    STUCK = 2
    GARBAGE = 3
    WRONG = 4
    SLOW = 5
    DELAYED = 6
    INTERMITTENT = 7


_OK_OFF = (FailureType.OK, FailureType.OFF)
SUPPORTED: frozenset[tuple[FailureUnit, FailureType]] = frozenset(
    {
        (u, t)
        for u in (
            FailureUnit.SENSOR_GYRO,
            FailureUnit.SENSOR_ACCEL,
            FailureUnit.SENSOR_MAG,
            FailureUnit.SENSOR_BARO,
            FailureUnit.SENSOR_GPS,
            FailureUnit.SYSTEM_MOTOR,
            FailureUnit.SYSTEM_RC_SIGNAL,
            FailureUnit.SYSTEM_MAVLINK_SIGNAL,
            FailureUnit.SYSTEM_BATTERY,
        )
        for t in _OK_OFF
    }  # fmt: skip
    | {(FailureUnit.SYSTEM_BATTERY, FailureType.WRONG)}
    # PX4 SITL's simulated sensors also honour STUCK (the last sample repeated) for the IMU, mag and baro, and
    # STUCK / WRONG for the GPS (PX4 main's simulation/failure_injection); nothing honours GARBAGE, SLOW, DELAYED
    # or INTERMITTENT
    | {
        (u, FailureType.STUCK)
        for u in (
            FailureUnit.SENSOR_GYRO,
            FailureUnit.SENSOR_ACCEL,
            FailureUnit.SENSOR_MAG,
            FailureUnit.SENSOR_BARO,
            FailureUnit.SENSOR_GPS,
        )
    }
    | {(FailureUnit.SENSOR_GPS, FailureType.WRONG)}
    | {(FailureUnit.SENSOR_CAMERA, t) for t in (*_OK_OFF, FailureType.STUCK, FailureType.WRONG)}
)

N_MOTORS = 4  # a quadrotor (HEARTBEAT type 2)
# PX4's quad X: motor -> (forward, right) sign of its arm; diagonal partners (1, 2) and (3, 4) turn the same way
MOTOR_ARMS: dict[int, tuple[int, int]] = {1: (1, 1), 2: (-1, -1), 3: (1, -1), 4: (-1, 1)}
_PAIRS = ((1, 2), (3, 4))
MOTOR_FAIL_TILT_RAD = math.radians(55.0)  # how far the vehicle rolls over toward a dead motor (simplified)
GPS_NOAID_TIMEOUT_S = 5.0  # PX4's EKF2_NOAID_TOUT default: dead reckoning before the position is invalid
# SYS_STATUS sensor bit per sensor unit (MAV_SYS_STATUS_SENSOR_*)
HEALTH_BITS: dict[FailureUnit, int] = {
    FailureUnit.SENSOR_GYRO: 0x1,
    FailureUnit.SENSOR_ACCEL: 0x2,
    FailureUnit.SENSOR_MAG: 0x4,
    FailureUnit.SENSOR_BARO: 0x8,
    FailureUnit.SENSOR_GPS: 0x20,
    FailureUnit.SYSTEM_MOTOR: 0x8000,  # MOTOR_OUTPUTS
    FailureUnit.SYSTEM_RC_SIGNAL: 0x10000,  # RC_RECEIVER
}
# the name PX4's sensor voter gives a failed sensor ("Accel #0 fail: TIMEOUT!")
SENSOR_NAMES: dict[FailureUnit, str] = {
    FailureUnit.SENSOR_GYRO: "Gyro",
    FailureUnit.SENSOR_ACCEL: "Accel",
    FailureUnit.SENSOR_MAG: "Mag",
    FailureUnit.SENSOR_BARO: "Baro",
}
_UNIT_TEXT = {
    FailureUnit.SENSOR_GYRO: "gyro", FailureUnit.SENSOR_ACCEL: "accel", FailureUnit.SENSOR_MAG: "mag",
    FailureUnit.SENSOR_BARO: "baro", FailureUnit.SENSOR_GPS: "gps", FailureUnit.SYSTEM_BATTERY: "battery",
    FailureUnit.SYSTEM_MOTOR: "motor", FailureUnit.SYSTEM_RC_SIGNAL: "rc signal",
    FailureUnit.SYSTEM_MAVLINK_SIGNAL: "mavlink signal", FailureUnit.SENSOR_CAMERA: "camera",
}  # fmt: skip


def describe(unit: FailureUnit, ftype: FailureType, instance: int) -> str:
    """The STATUSTEXT PX4's failure-injection manager sends for an accepted injection."""
    name = _UNIT_TEXT.get(unit, unit.name.lower())
    which = "all instances" if instance <= 0 else f"instance {instance}"
    if ftype is FailureType.OK:
        return f"Cleared: {name}, {which}"
    return f"Injected: {name} {ftype.name.lower()}, {which}"


def parse(unit: object, ftype: object, instance: object) -> tuple[FailureUnit, FailureType, int] | Outcome:
    """Validate a request (numbers as MAV_CMD_INJECT_FAILURE carries them): the typed triple, or the refusal.
    Non-finite or non-numeric values are DENIED; unknown units/types and missing instances UNSUPPORTED."""
    try:
        values = [float(v) for v in (unit, ftype, instance)]  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return Outcome(CommandResult.DENIED, "Failure injection: parameters not numbers")
    if not all(math.isfinite(v) for v in values):
        return Outcome(CommandResult.DENIED, "Failure injection: parameters not finite")
    iu, it, inst = (round(v) for v in values)
    try:
        u, t = FailureUnit(iu), FailureType(it)
    except ValueError:
        return Outcome(CommandResult.UNSUPPORTED, f"Failure injection: unknown unit {iu} / type {it}")
    n = N_MOTORS if u is FailureUnit.SYSTEM_MOTOR else 1
    if not -1 <= inst <= n:  # -1: all, as 0 (older callers)
        return Outcome(
            CommandResult.UNSUPPORTED, f"Failure injection: {u.name} instance {inst} does not exist (0..{n})"
        )
    return u, t, max(inst, 0)


class Failures:
    """The failures switched on now: unit -> type (motors: also which ones). Pure state; the autopilot reads it where
    a failure acts."""

    def __init__(self) -> None:
        self.active: dict[FailureUnit, FailureType] = {}
        self.motors_off: frozenset[int] = frozenset()  # 1-based motor numbers

    def is_active(self, unit: FailureUnit, ftype: FailureType | None = None) -> bool:
        t = self.active.get(unit)
        return t is not None and (ftype is None or t == ftype)

    def health_mask(self) -> int:
        """SYS_STATUS sensor bits that are unhealthy because of an injected failure."""
        return sum(bit for u, bit in HEALTH_BITS.items() if u in self.active)

    def inject(
        self,
        unit: FailureUnit | int,
        ftype: FailureType | int,
        instance: int,
        params: ParamStore,
        battery: Battery,
        *,
        check_enabled: bool = True,
    ) -> Outcome:
        """Switch a failure on (or off with OK). `check_enabled`: refuse unless SYS_FAILURE_EN = 1 (PX4's gate on
        MAV_CMD_INJECT_FAILURE); the simulator's own scenario failures pass False."""
        if check_enabled and params.get("SYS_FAILURE_EN") < 0.5:  # PX4 refuses before looking at the unit
            return Outcome(CommandResult.DENIED, "Failure injection disabled (SYS_FAILURE_EN = 0)")
        parsed = parse(unit, ftype, instance)
        if isinstance(parsed, Outcome):
            return parsed
        u, t, inst = parsed
        if (u, t) not in SUPPORTED:
            return Outcome(CommandResult.UNSUPPORTED, f"Failure injection: {u.name} {t.name} not supported")
        if u is FailureUnit.SYSTEM_MOTOR:
            which = frozenset(range(1, N_MOTORS + 1)) if inst == 0 else frozenset({inst})
            self.motors_off = self.motors_off - which if t is FailureType.OK else self.motors_off | which
            if self.motors_off:
                self.active[u] = FailureType.OFF
            else:
                self.active.pop(u, None)
            return ACCEPTED
        if t is FailureType.OK:
            self.active.pop(u, None)
            if u is FailureUnit.SYSTEM_BATTERY:
                battery.forced_empty = False
            return ACCEPTED
        if u is FailureUnit.SYSTEM_BATTERY and t is FailureType.WRONG:
            drain_to_critical(params, battery)
            return ACCEPTED  # a one-time drain, not a lasting state
        self.active[u] = t
        if u is FailureUnit.SYSTEM_BATTERY:
            battery.forced_empty = True
        return ACCEPTED


def motor_failure_command(cmd: EavCommand, motors_off: frozenset[int], yaw_rad: float, max_thrust_n: float
                          ) -> EavCommand:  # fmt: skip
    """What the airframe does with the autopilot's command while motors are dead (a simplified quad-X mixer): a
    diagonal pair with a dead motor gives no thrust (its partner idles to keep roll/pitch balanced), so the thrust is
    capped at the intact pairs' share; the vehicle leans MOTOR_FAIL_TILT_RAD toward the dead motor(s) and, with one
    pair left, spins about yaw (the pair turns one way: no yaw authority)."""
    if not motors_off:
        return cmd
    intact = [pair for pair in _PAIRS if not (set(pair) & motors_off)]
    thrust = min(cmd.thrust_n, max_thrust_n * len(intact) / len(_PAIRS))
    fwd = sum(MOTOR_ARMS[m][0] for m in motors_off if m in MOTOR_ARMS)
    right = sum(MOTOR_ARMS[m][1] for m in motors_off if m in MOTOR_ARMS)
    roll, pitch, yaw = cmd.roll_rad, cmd.pitch_rad, cmd.yaw_rad
    if fwd or right:
        n = math.hypot(fwd, right)
        roll = MOTOR_FAIL_TILT_RAD * right / n  # a dead motor on the right: the right side drops (roll right)
        pitch = -MOTOR_FAIL_TILT_RAD * fwd / n  # a dead motor in front: the nose drops (pitch down)
    if len(intact) == 1:
        yaw = wrap_pi(yaw_rad + (3.0 if intact[0] == (3, 4) else -3.0))  # always turning, at the max yaw rate
    return EavCommand(roll, pitch, yaw, thrust)


def drain_to_critical(params: ParamStore, battery: Battery) -> None:
    """Drain the pack to just below BAT_CRIT_THR now (SIM_BAT_MIN_PCT 0 so that it may go that low)."""
    target = max(0.0, params.get("BAT_CRIT_THR") - 0.01)
    params.set("SIM_BAT_MIN_PCT", 0.0)
    battery.used_mah = max(battery.used_mah, params.get("BAT1_CAPACITY") * (1.0 - target))


__all__ = [
    "GPS_NOAID_TIMEOUT_S",
    "HEALTH_BITS",
    "MOTOR_ARMS",
    "N_MOTORS",
    "SENSOR_NAMES",
    "SUPPORTED",
    "FailureType",
    "FailureUnit",
    "Failures",
    "describe",
    "drain_to_critical",
    "motor_failure_command",
    "parse",
]
