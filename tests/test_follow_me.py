"""Follow Me (AUTO.FOLLOW_TARGET) on a Vehicle, no MAVLink: PX4's geometry (distance, angle from the target's course,
height above home), the lost-target hold, bad targets, and the footage ground-truth track (FLW_TGT_TRACK).
MAVSDK's follow_me plugin end to end: test_e2e_follow_me."""

from __future__ import annotations

import math

import pytest

from viva_sitl.autopilot.types import CommandResult, FlightMode
from viva_sitl.vehicle import Vehicle

STEPS_PER_S = 250


@pytest.fixture
def flying() -> Vehicle:
    v = Vehicle(geofence=False)
    ap = v.autopilot
    assert ap.arm(v.time_s).ok and ap.takeoff(v.time_s, 10.0).ok
    v.step(STEPS_PER_S * 8)
    assert ap.mode == FlightMode.AUTO_LOITER and -v.state.pos_ned_m[2] > 9.0
    return v


def walk(
    v: Vehicle, start: tuple[float, float], vel: tuple[float, float], seconds: int
) -> tuple[float, float]:
    """Stream a target walking at `vel` (1 Hz, as MAVSDK) and fly; returns where the target is at the end."""
    n = e = 0.0
    for k in range(seconds):
        n, e = start[0] + vel[0] * k, start[1] + vel[1] * k
        assert v.autopilot.set_follow_target(v.time_s, (n, e, 0.0), (vel[0], vel[1], 0.0)).ok
        v.step(STEPS_PER_S)
    return n + vel[0], e + vel[1]  # one more second of walking since the last message


def test_mode_is_px4s_auto_follow_target() -> None:
    assert FlightMode.from_px4(4, 8) == FlightMode.AUTO_FOLLOW_TARGET
    assert FlightMode.AUTO_FOLLOW_TARGET.custom_mode == (4 << 16) | (8 << 24)


def test_follows_behind_at_distance_and_height(flying: Vehicle) -> None:
    v, ap = flying, flying.autopilot
    assert ap.set_mode(v.time_s, FlightMode.AUTO_FOLLOW_TARGET).ok
    n, e = walk(v, (20.0, 0.0), (0.0, 2.0), 30)  # walking east
    p = v.state.pos_ned_m
    # FLW_TGT_FA 180: behind the target's course, FLW_TGT_DST 8 m; FLW_TGT_HT 8 m above home; facing the target
    assert (p[0], p[1]) == pytest.approx((n, e - 8.0), abs=0.3)
    assert float(ap.home_ned_m[2]) - p[2] == pytest.approx(8.0, abs=0.2)
    assert math.degrees(v.state.yaw_rad) == pytest.approx(90.0, abs=2.0)


def test_follow_angle_distance_and_height_parameters(flying: Vehicle) -> None:
    v, ap = flying, flying.autopilot
    v.params.set("FLW_TGT_FA", 90.0)  # on the target's right
    v.params.set("FLW_TGT_DST", 12.0)
    v.params.set("FLW_TGT_HT", 15.0)
    assert ap.set_mode(v.time_s, FlightMode.AUTO_FOLLOW_TARGET).ok
    n, e = walk(v, (0.0, 10.0), (2.0, 0.0), 35)  # walking north: its right is east
    p = v.state.pos_ned_m
    assert (p[0], p[1]) == pytest.approx((n, e + 12.0), abs=0.3)
    assert -p[2] == pytest.approx(15.0, abs=0.2)


def test_lost_target_holds_and_says_so(flying: Vehicle) -> None:
    v, ap = flying, flying.autopilot
    assert ap.set_mode(v.time_s, FlightMode.AUTO_FOLLOW_TARGET).ok
    walk(v, (10.0, 0.0), (1.0, 0.0), 10)
    ap.pop_events()
    v.step(STEPS_PER_S * 4)  # no message for > 3 s
    here = v.state.pos_ned_m.copy()
    v.step(STEPS_PER_S * 5)
    assert float(math.dist(here[:2], v.state.pos_ned_m[:2])) < 0.5
    assert any("Follow target: no target position" in e.text for e in ap.pop_events())
    assert ap.mode == FlightMode.AUTO_FOLLOW_TARGET  # PX4 stays in the mode, hovering


def test_bad_targets_are_refused(flying: Vehicle) -> None:
    ap = flying.autopilot
    t = flying.time_s
    out = ap.set_follow_target(t, (math.nan, 0.0, 0.0))
    assert out.result == CommandResult.DENIED and "not finite" in out.reason
    assert not ap.set_follow_target(t, (1e9, 0.0, 0.0)).ok
    # NaN down (2D target) and NaN velocity: accepted, velocity unknown
    assert ap.set_follow_target(t, (5.0, 5.0, math.nan), (math.nan, math.inf, 0.0)).ok
    target = ap.tasks.follow.target
    assert target is not None and math.isnan(target.down_m) and target.vel_ned_m_s == (0.0, 0.0, 0.0)


def test_follows_a_footage_ground_truth_track(flying: Vehicle) -> None:
    """FLW_TGT_TRACK = 0: the synthetic field's walker-1 (world track 0), from the ground truth, no messages."""
    v, ap = flying, flying.autopilot
    v.params.set("FLW_TGT_TRACK", 0)
    assert ap.set_mode(v.time_s, FlightMode.AUTO_FOLLOW_TARGET).ok
    v.step(STEPS_PER_S * 30)
    hit = v.track_position(0, v.time_s)
    assert hit is not None
    n, e, vn, ve = hit
    speed = math.hypot(vn, ve)
    assert speed > 0.5  # the walker walks
    p = v.state.pos_ned_m
    behind = (n - vn / speed * 8.0, e - ve / speed * 8.0)
    assert float(math.dist(behind, (p[0], p[1]))) < 1.5, (behind, p)
    # a track that is not there: hold, and say which
    v.params.set("FLW_TGT_TRACK", 99999)
    ap.pop_events()
    v.step(STEPS_PER_S)
    assert any("track 99999 absent now" in e.text for e in ap.pop_events())


def test_gimbal_looks_at_the_target_while_following() -> None:
    """With a gimbal mount, Follow Me points the camera at the target (PX4's follow task drives the gimbal)."""
    import dataclasses

    from viva_sitl.camera import Mount
    from viva_sitl.config import SimConfig

    base = SimConfig()
    v = Vehicle(
        dataclasses.replace(base, camera=dataclasses.replace(base.camera, mount=Mount.GIMBAL)), geofence=False
    )
    ap = v.autopilot
    assert ap.arm(v.time_s).ok and ap.takeoff(v.time_s, 10.0).ok
    v.step(STEPS_PER_S * 8)
    assert ap.gimbal_pitch_yaw_deg is None  # at rest: the nadir mount
    assert ap.set_mode(v.time_s, FlightMode.AUTO_FOLLOW_TARGET).ok
    walk(v, (20.0, 0.0), (0.0, 2.0), 25)
    angles = ap.gimbal_pitch_yaw_deg
    assert angles is not None
    # 8 m behind, 8 m up: 45 deg down, straight ahead (the vehicle faces the target)
    assert angles[0] == pytest.approx(-45.0, abs=3.0) and angles[1] == pytest.approx(0.0, abs=3.0)
    assert ap.set_mode(v.time_s, FlightMode.AUTO_LOITER).ok
    assert ap.gimbal_pitch_yaw_deg is None  # back to the mount after the mode
