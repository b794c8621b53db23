"""MAV_CMD_INJECT_FAILURE at the autopilot level (issue 24 §1): each unit PX4 SITL honours on a multicopter, its
consequence, its acknowledgement (ACCEPTED / UNSUPPORTED / DENIED) and FAILURE_TYPE_OK undoing it; the camera
(viva-sitl's extension) on the rendered frames; every trial failure kind reaching a supported injection."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from viva_sitl.autopilot import ManualInput
from viva_sitl.autopilot.failures import (
    GPS_NOAID_TIMEOUT_S,
    HEALTH_BITS,
    MOTOR_FAIL_TILT_RAD,
    FailureType,
    FailureUnit,
    motor_failure_command,
)
from viva_sitl.autopilot.types import CommandResult, FlightMode, Severity
from viva_sitl.camera import CameraParams
from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavCommand
from viva_sitl.evaluation.monitor import FAILURE_INSTANCE, FAILURES
from viva_sitl.evaluation.spec import FAILURE_KINDS
from viva_sitl.vehicle import Vehicle

U, T = FailureUnit, FailureType
HZ = 250  # physics steps per second (SimConfig's default dt)


def air_vehicle(alt_m: float = 20.0, **kw: object) -> Vehicle:
    """An air start (armed, Hold) with failure injection enabled."""
    cfg = SimConfig(initial_pos_ned_m=(0.0, 0.0, -alt_m), **kw)  # type: ignore[arg-type]
    v = Vehicle(cfg, geofence=False)
    v.params.set("SYS_FAILURE_EN", 1)
    return v


def run(v: Vehicle, seconds: float) -> list[tuple[Severity, str]]:
    out: list[tuple[Severity, str]] = []
    for _ in range(round(seconds * HZ)):
        v.step()
        out += [(e.severity, e.text) for e in v.autopilot.pop_events()]
    return out


def test_acknowledgements_as_px4() -> None:
    with Vehicle(SimConfig(), geofence=False) as v:
        ap, t = v.autopilot, v.time_s
        # SYS_FAILURE_EN = 0: PX4's MAVLink receiver refuses every injection, known or not
        for unit, ftype in ((U.SENSOR_GPS, T.OFF), (77, 1), (U.SYSTEM_MOTOR, T.OK)):
            out = ap.inject_failure(t, unit, ftype)
            assert out.result is CommandResult.DENIED and "SYS_FAILURE_EN" in out.reason
        assert not ap.failures.active
        v.params.set("SYS_FAILURE_EN", 1)
        unsupported = [
            (77, 1, 0),  # no such unit
            (U.SENSOR_GPS, 9, 0),  # no such type
            (U.SENSOR_OPTICAL_FLOW, T.OFF, 0),  # no optical flow on this vehicle
            (
                U.SENSOR_GPS,
                T.GARBAGE,
                0,
            ),  # no PX4 simulation module handles GARBAGE, SLOW, DELAYED, INTERMITTENT
            (U.SENSOR_ACCEL, T.SLOW, 0),
            (U.SENSOR_MAG, T.DELAYED, 0),
            (U.SENSOR_GYRO, T.INTERMITTENT, 0),
            (U.SENSOR_BARO, T.WRONG, 0),  # PX4 SITL's baro honours OFF and STUCK only
            (U.SENSOR_CAMERA, T.GARBAGE, 0),
            (U.SYSTEM_MOTOR, T.OFF, 5),  # a quad has motors 1..4
            (U.SENSOR_BARO, T.OFF, 2),  # one baro: instance 1 (0 = all)
        ]
        for unit, ftype, inst in unsupported:
            assert ap.inject_failure(t, unit, ftype, inst).result is CommandResult.UNSUPPORTED, (
                unit,
                ftype,
                inst,
            )
        for bad in ((math.nan, 1, 0), (4, math.inf, 0), (4, 1, math.nan)):
            out = ap.inject_failure(t, *bad)  # type: ignore[arg-type]
            assert out.result is CommandResult.DENIED and "not finite" in out.reason
        assert not ap.failures.active and not ap.pop_events()
        assert ap.inject_failure(t, U.SENSOR_GPS, T.OFF).ok
        assert ap.inject_failure(t, U.SYSTEM_MOTOR, T.OFF, 3).ok
        assert (Severity.WARNING, "Injected: gps off, all instances") in [
            (e.severity, e.text) for e in ap.pop_events()
        ]
        assert ap.inject_failure(t, U.SENSOR_GPS, T.OK).ok
        assert [e.text for e in ap.pop_events()] == ["Cleared: gps, all instances"]


def test_gps_off_loses_the_position_then_descends_and_ok_restores() -> None:
    with air_vehicle(20.0) as v:
        ap = v.autopilot
        run(v, 1.0)
        assert ap.inject_failure(v.time_s, U.SENSOR_GPS, T.OFF).ok
        assert not ap.gps_fix and ap.failed_health_bits & HEALTH_BITS[U.SENSOR_GPS]
        events = run(v, GPS_NOAID_TIMEOUT_S - 0.5)  # EKF2 dead-reckons: still a position, still Hold
        assert ap.global_position_valid and ap.mode is FlightMode.AUTO_LOITER
        z0 = float(v.state.pos_ned_m[2])
        events = run(v, 1.0)
        assert not ap.global_position_valid and ap.mode is FlightMode.AUTO_LAND  # Descend reports AUTO.LAND
        assert (Severity.WARNING, "Failsafe activated (no GPS): switching to Descend") in events
        # position modes are refused while lost (TEMPORARILY_REJECTED, as PX4 Commander)
        for refused in (
            ap.set_mode(v.time_s, FlightMode.AUTO_LOITER),
            ap.return_to_launch(v.time_s),
            ap.reposition(v.time_s, 5.0, 5.0, -20.0, None),
            ap.set_mode(v.time_s, FlightMode.AUTO_MISSION),
        ):
            assert refused.result in (CommandResult.TEMPORARILY_REJECTED, CommandResult.DENIED), refused
        run(v, 4.0)
        s = v.state
        assert float(s.pos_ned_m[2]) > z0 + 2.0  # coming down (MPC_LAND_SPEED)
        assert abs(s.att_rpy_rad[0]) < 0.1 and abs(s.att_rpy_rad[1]) < 0.1  # level: no horizontal control
        assert ap.inject_failure(v.time_s, U.SENSOR_GPS, T.OK).ok
        events = run(v, 0.2)
        assert ap.global_position_valid and ap.gps_fix and not ap.failed_health_bits
        assert ap.mode is FlightMode.AUTO_LOITER  # PX4 clears the mode fallback: back to the mode it flew
        assert any("Global position regained" in text for _, text in events)


def test_gps_off_on_the_ground_refuses_arming_until_ok() -> None:
    with Vehicle(SimConfig(), geofence=False) as v:
        ap = v.autopilot
        v.params.set("SYS_FAILURE_EN", 1)
        assert ap.inject_failure(v.time_s, U.SENSOR_GPS, T.OFF).ok
        out = ap.arm(v.time_s)
        assert out.result is CommandResult.DENIED and "GPS" in out.reason
        run(v, GPS_NOAID_TIMEOUT_S + 0.1)
        assert not ap.global_position_valid
        assert ap.inject_failure(v.time_s, U.SENSOR_GPS, T.OK).ok
        run(v, 0.1)
        assert ap.arm(v.time_s).ok


@pytest.mark.parametrize(("unit", "name"), [(U.SENSOR_BARO, "Baro"), (U.SENSOR_MAG, "Mag")])
def test_baro_and_mag_off_flag_health_and_refuse_arming(unit: FailureUnit, name: str) -> None:
    with Vehicle(SimConfig(), geofence=False) as v:
        ap = v.autopilot
        v.params.set("SYS_FAILURE_EN", 1)
        assert ap.inject_failure(v.time_s, unit, T.OFF, 1).ok
        texts = [(e.severity, e.text) for e in ap.pop_events()]
        assert (Severity.EMERGENCY, f"{name} #0 fail: TIMEOUT!") in texts
        assert ap.failed_health_bits == HEALTH_BITS[unit]
        out = ap.arm(v.time_s)
        assert out.result is CommandResult.DENIED and "sensor 0 missing" in out.reason
        assert ap.inject_failure(v.time_s, unit, T.OK).ok
        assert not ap.failed_health_bits and ap.arm(v.time_s).ok


@pytest.mark.parametrize("unit", [U.SENSOR_ACCEL, U.SENSOR_GYRO])
def test_accel_or_gyro_off_in_the_air_terminates(unit: FailureUnit) -> None:
    with air_vehicle(30.0) as v:
        ap = v.autopilot
        run(v, 0.5)
        assert ap.armed
        assert ap.inject_failure(v.time_s, unit, T.OFF).ok
        events = run(v, 0.1)
        assert not ap.armed  # no attitude estimate: no mode can run, PX4's fallback ends in termination
        assert any(sev is Severity.EMERGENCY and "termination" in text for sev, text in events)
        run(v, 1.0)
        assert float(v.state.vel_ned_m_s[2]) > 5.0  # falling


def test_motor_failure_mixer_model() -> None:
    cmd = EavCommand(0.0, 0.0, 0.0, 10.0)
    assert motor_failure_command(cmd, frozenset(), 0.0, 12.0) is cmd
    one = motor_failure_command(cmd, frozenset({1}), 0.0, 12.0)  # front right (PX4 quad X motor 1)
    assert one.thrust_n == pytest.approx(6.0)  # its diagonal pair is gone: half the thrust at most
    assert one.roll_rad > 0.0 and one.pitch_rad < 0.0  # leans right and nose down
    assert math.hypot(one.roll_rad, one.pitch_rad) == pytest.approx(MOTOR_FAIL_TILT_RAD)
    assert abs(one.yaw_rad) > 2.0  # spinning: the remaining pair turns one way
    assert motor_failure_command(cmd, frozenset({1, 2, 3, 4}), 0.0, 12.0).thrust_n == 0.0


def test_motor_off_brings_the_vehicle_down_and_ok_restores_health() -> None:
    with air_vehicle(40.0) as v:
        ap = v.autopilot
        run(v, 1.0)
        z0 = float(v.state.pos_ned_m[2])
        assert ap.inject_failure(v.time_s, U.SYSTEM_MOTOR, T.OFF, 1).ok
        assert ap.failures.motors_off == {1} and ap.failed_health_bits & HEALTH_BITS[U.SYSTEM_MOTOR]
        run(v, 3.0)
        assert float(v.state.pos_ned_m[2]) > z0 + 5.0  # cannot hold: coming down
        assert ap.inject_failure(v.time_s, U.SYSTEM_MOTOR, T.OK, 1).ok
        assert not ap.failures.motors_off and not ap.failed_health_bits


def test_rc_signal_off_is_not_heard_and_triggers_rc_loss() -> None:
    with air_vehicle(20.0, params=(("COM_RC_LOSS_T", 0.5),)) as v:
        ap = v.autopilot
        centred = ManualInput(0.0, 0.0, 0.5, 0.0)
        assert ap.set_manual_input(v.time_s, centred).ok
        assert ap.set_mode(v.time_s, FlightMode.POSCTL).ok
        assert ap.inject_failure(v.time_s, U.SYSTEM_RC_SIGNAL, T.OFF).ok
        assert ap.failed_health_bits == HEALTH_BITS[U.SYSTEM_RC_SIGNAL]
        events: list[tuple[Severity, str]] = []
        for _ in range(2 * HZ):  # the pilot keeps sending; the receiver hears nothing
            assert not ap.set_manual_input(v.time_s, centred).ok
            v.step()
            events += [(e.severity, e.text) for e in ap.pop_events()]
        assert any("manual control lost" in text for _, text in events)  # NAV_RCL_ACT
        assert ap.mode is not FlightMode.POSCTL
        assert ap.inject_failure(v.time_s, U.SYSTEM_RC_SIGNAL, T.OK).ok
        assert ap.set_manual_input(v.time_s, centred).ok


def test_camera_failures_freeze_black_out_and_drop_frames() -> None:
    cfg = SimConfig(camera=CameraParams(width_px=160, height_px=120), initial_pos_ned_m=(0.0, 0.0, -20.0))
    with Vehicle(cfg, geofence=False) as v:
        ap = v.autopilot
        live = v.render()
        assert live.image_bgr.any() and not v.camera_dropped
        assert ap.inject_failure(v.time_s, U.SENSOR_CAMERA, T.STUCK, check_enabled=False).ok
        assert ap.reposition(v.time_s, 15.0, 10.0, -20.0, None).ok
        run(v, 3.0)
        frozen = v.render()
        assert np.array_equal(frozen.image_bgr, live.image_bgr)  # the same image ...
        assert frozen.meta.pos_ned_m != live.meta.pos_ned_m  # ... while the ground truth moved on
        assert ap.inject_failure(v.time_s, U.SENSOR_CAMERA, T.WRONG, check_enabled=False).ok
        assert not v.render().image_bgr.any()  # black
        assert ap.inject_failure(v.time_s, U.SENSOR_CAMERA, T.OFF, check_enabled=False).ok
        assert v.camera_dropped  # the app's render step delivers nothing
        assert ap.inject_failure(v.time_s, U.SENSOR_CAMERA, T.OK, check_enabled=False).ok
        again = v.render()
        assert not v.camera_dropped and again.image_bgr.any()
        assert not np.array_equal(again.image_bgr, live.image_bgr)  # live: the new place


@pytest.mark.parametrize("kind", FAILURE_KINDS)
def test_every_trial_failure_kind_is_a_supported_injection(kind: str) -> None:
    unit, ftype, _ = FAILURES[kind]
    with air_vehicle(20.0) as v:
        out = v.autopilot.inject_failure(
            v.time_s, unit, ftype, FAILURE_INSTANCE.get(kind, 0), check_enabled=False
        )
        assert out.ok, (kind, out)


class BlackoutWatcher:
    """An in-process vision pilot that only looks: records (t, frame all black) for every frame it is given."""

    name, control_hz, frame_hz, uses_ground_truth = "blackout-watcher", 10.0, 10.0, False
    seen: list[tuple[float, bool]] = []

    def reset(self, scenario: object, truth: object) -> None:
        BlackoutWatcher.seen = []

    def act(self, obs, ctl):  # type: ignore[no-untyped-def]
        BlackoutWatcher.seen.append((obs.t_s, not obs.frame.image_bgr.any()))


def test_trial_spec_failures_gps_loss_and_camera_blackout(tmp_path: Path) -> None:
    """A spec's gps_loss and camera_blackout go through Autopilot.inject_failure: PX4's Descend failsafe follows
    the lost GPS, and the pilot's frames turn black from the blackout on."""
    from viva_sitl.evaluation.runner import run_inprocess_trial
    from viva_sitl.evaluation.spec import draw_scenarios, spec_from_dict

    spec = spec_from_dict(
        {"trials": {"name": "f", "n": 1, "seed": 1, "timeout_s": 9.0},
         "scenario": {"footage": "synthetic", "start": "air", "north_m": [-5.0, 5.0], "east_m": [-5.0, 5.0],
                      "altitude_m": 10.0, "land_at_s": 8.0,
                      "failures": [{"kind": "gps_loss", "at_s": 1.0}, {"kind": "camera_blackout", "at_s": 2.0}]}},
        "f",
    )  # fmt: skip
    run_inprocess_trial(spec, draw_scenarios(spec, 1)[0], f"{__name__}:BlackoutWatcher", tmp_path)
    texts = [json.loads(x)["text"] for x in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert "injected: GPS lost" in texts and "injected: camera blackout" in texts, texts
    assert "Failsafe activated (no GPS): switching to Descend" in texts, texts
    seen = BlackoutWatcher.seen
    assert (
        seen and not any(black for t, black in seen if t < 1.9) and all(black for t, black in seen if t > 2.2)
    )


def test_ulog_failsafe_flags_record_the_lost_position(tmp_path: Path) -> None:
    """The run's ULog (flightlog.py) carries the lost global position in failsafe_flags, as PX4 logs it."""
    pyulog = pytest.importorskip("pyulog")
    from viva_sitl.flightlog import FlightLog

    with air_vehicle(20.0) as v:
        flog = FlightLog(tmp_path / "log.ulg", v.geo, v.params, start_time_s=v.time_s)
        assert v.autopilot.inject_failure(v.time_s, U.SENSOR_GPS, T.OFF).ok
        for _ in range(round((GPS_NOAID_TIMEOUT_S + 1.0) * HZ)):
            flog.step(v.step(), v.autopilot)
        flog.close()
    flags = pyulog.ULog(str(tmp_path / "log.ulg")).get_dataset("failsafe_flags").data
    invalid = flags["global_position_invalid"]
    assert invalid[0] == 0 and invalid[-1] == 1 and flags["local_position_invalid"][-1] == 1


class _Link:
    """The vehicle as TelemetryBuilder reads it (what the app's VehicleLink gives the MAVLink endpoint)."""

    def __init__(self, v: Vehicle) -> None:
        self.v, self.boot_wall_time_s, self.camera = v, 0.0, None

    autopilot = property(lambda self: self.v.autopilot)
    state = property(lambda self: self.v.state)
    time_s = property(lambda self: self.v.time_s)
    geo = property(lambda self: self.v.geo)


_IMU_FIELDS = {
    U.SENSOR_ACCEL: ("xacc", "yacc", "zacc"),
    U.SENSOR_GYRO: ("xgyro", "ygyro", "zgyro"),
    U.SENSOR_MAG: ("xmag", "ymag", "zmag"),
    U.SENSOR_BARO: ("abs_pressure", "pressure_alt", "temperature"),
}


@pytest.mark.parametrize(
    ("unit", "name"),
    [(U.SENSOR_ACCEL, "Accel"), (U.SENSOR_GYRO, "Gyro"), (U.SENSOR_MAG, "Mag"), (U.SENSOR_BARO, "Baro")],
)
def test_sensor_stuck_repeats_the_last_sample_goes_stale_and_ok_restores(
    unit: FailureUnit, name: str
) -> None:
    """PX4 SITL's STUCK: the simulated sensor repeats its last sample; PX4's voter calls it stale."""
    from viva_sitl.mavlink.telemetry import TelemetryBuilder

    with air_vehicle(20.0) as v:
        ap, tb = v.autopilot, TelemetryBuilder(_Link(v), 1)  # type: ignore[arg-type]
        v.params.set("MPC_XY_VEL_MAX", 12.0)
        run(v, 0.5)
        assert ap.reposition(
            v.time_s, 40.0, 30.0, -5.0, math.radians(120.0)
        ).ok  # moving, turning, descending
        run(v, 1.0)
        fields = _IMU_FIELDS[unit]
        assert ap.inject_failure(v.time_s, unit, T.STUCK).ok
        texts = [(e.severity, e.text) for e in ap.pop_events()]
        assert (Severity.EMERGENCY, f"{name} #0 fail: STALE!") in texts
        assert (Severity.WARNING, f"Injected: {name.lower()} stuck, all instances") in texts
        assert ap.failed_health_bits == HEALTH_BITS[unit]
        first = tb.highres_imu()
        frozen = [getattr(first, f) for f in fields]
        run(v, 1.0)
        later = tb.highres_imu()
        assert [getattr(later, f) for f in fields] == frozen  # the same sample, repeated
        assert later.fields_updated == 0x1FFF  # a stuck sensor still publishes
        if unit in (U.SENSOR_ACCEL, U.SENSOR_GYRO):
            assert not ap.armed  # no usable attitude estimate in the air: flight termination (as for OFF)
        else:
            assert ap.armed and ap.mode is FlightMode.AUTO_LOITER  # EKF2 goes on with GNSS height / yaw
        assert ap.inject_failure(v.time_s, unit, T.OK).ok
        run(v, 0.5)
        live = tb.highres_imu()
        assert [getattr(live, f) for f in fields] != frozen and not ap.failed_health_bits


@pytest.mark.parametrize("unit", [U.SENSOR_BARO, U.SENSOR_MAG])
def test_baro_or_mag_off_in_flight_keeps_flying_without_that_sensor(unit: FailureUnit) -> None:
    """PX4's EKF2 falls back to GNSS height (baro) / keeps its yaw from the gyro and GNSS (mag): no mode change in
    Hold; what shows is the sensor's TIMEOUT, its health bit and HIGHRES_IMU no longer carrying it."""
    from viva_sitl.mavlink.telemetry import TelemetryBuilder

    with air_vehicle(20.0) as v:
        ap, tb = v.autopilot, TelemetryBuilder(_Link(v), 1)  # type: ignore[arg-type]
        run(v, 0.5)
        before = tb.highres_imu()
        assert before.fields_updated == 0x1FFF
        z0 = float(v.state.pos_ned_m[2])
        assert ap.inject_failure(v.time_s, unit, T.OFF).ok
        events = run(v, 3.0)
        assert any("fail: TIMEOUT!" in text for _, text in events)
        assert ap.armed and ap.mode is FlightMode.AUTO_LOITER and abs(float(v.state.pos_ned_m[2]) - z0) < 1.0
        imu = tb.highres_imu()
        bits = {U.SENSOR_BARO: 0x1E00, U.SENSOR_MAG: 0x1C0}[unit]
        assert imu.fields_updated == 0x1FFF & ~bits
        # no new sample: the last reading, its fields_updated bits cleared (PX4's HIGHRES_IMU stream)
        assert [getattr(imu, f) for f in _IMU_FIELDS[unit]] == [getattr(before, f) for f in _IMU_FIELDS[unit]]
        assert ap.inject_failure(v.time_s, unit, T.OK).ok
        assert tb.highres_imu().fields_updated == 0x1FFF


@pytest.mark.parametrize("ftype", [T.STUCK, T.WRONG])
def test_gps_stuck_or_wrong_reports_that_fix_and_loses_the_position_as_off(ftype: FailureType) -> None:
    """PX4 main: STUCK re-publishes the last fix, WRONG offsets it (+1 deg lat/lon, +100 m); EKF2 gets no usable
    sample either way, so the global position is lost after EKF2_NOAID_TOUT and the Descend failsafe follows."""
    from viva_sitl.mavlink.telemetry import TelemetryBuilder

    with air_vehicle(20.0) as v:
        ap, tb = v.autopilot, TelemetryBuilder(_Link(v), 1)  # type: ignore[arg-type]
        run(v, 0.5)
        assert ap.reposition(v.time_s, 30.0, 0.0, -20.0, None).ok
        run(v, 1.0)
        before = tb.gps_raw_int()
        assert ap.inject_failure(v.time_s, U.SENSOR_GPS, ftype).ok
        assert ap.gps_fix and ap.failed_health_bits & HEALTH_BITS[U.SENSOR_GPS]  # a fix, but not a usable one
        run(v, 1.0)
        gps = tb.gps_raw_int()
        assert gps.fix_type == 3
        s = v.state
        true_lat = v.geo.ned_to_global(*(float(x) for x in s.pos_ned_m))[0]
        if ftype is T.STUCK:
            assert (gps.time_usec, gps.lat, gps.lon, gps.alt) == (
                before.time_usec,
                before.lat,
                before.lon,
                before.alt,
            )
        else:
            assert gps.lat - before.lat > 0.99e7 and gps.lon - before.lon > 0.99e7
            assert 99_000 < gps.alt - before.alt < 101_000
            assert abs(gps.lat / 1e7 - true_lat - 1.0) < 1e-5
        events = run(v, GPS_NOAID_TIMEOUT_S)
        assert not ap.global_position_valid and ap.mode is FlightMode.AUTO_LAND
        assert (Severity.WARNING, "Failsafe activated (no GPS): switching to Descend") in events
        assert ap.inject_failure(v.time_s, U.SENSOR_GPS, T.OK).ok
        run(v, 0.2)
        assert ap.global_position_valid and ap.mode is FlightMode.AUTO_LOITER
        assert tb.gps_raw_int().time_usec > before.time_usec
