"""Pure geofence / rally / orbit / DO_JUMP logic, then flown closed-loop on the EAV (no network): point-in-polygon
against an independent brute-force raster, self-intersection, PX4's inclusion/exclusion semantics, GF_ACTION
reactions, RTL to the nearest rally point, orbit radius and direction, DO_JUMP visit counts, NAV_DELAY, camera items,
relative altitudes resolved when the item runs, DO_REPOSITION's change-mode flag."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_autopilot import Flight

from viva_sitl.autopilot import CommandResult, FlightMode, MissionCommand, MissionItem
from viva_sitl.autopilot.geofence import (
    CircleFence,
    FenceLimits,
    Geofence,
    PolygonFence,
    RallyPoint,
    breach_reason,
    point_in_polygon,
    polygon_self_intersects,
    rtl_destination,
    validate_polygon,
)
from viva_sitl.autopilot.mission import resolve_jumps, validate_mission
from viva_sitl.autopilot.orbit import Orbit, OrbitYaw, apply_command, orbit_step
from viva_sitl.autopilot.payload import DistanceTrigger

NAN = math.nan


# --- geometry -------------------------------------------------------------------------------------
def _inside_by_winding(n: float, e: float, verts: list[tuple[float, float]]) -> bool:
    """Independent reference: the angle swept around the point (winding number) for simple polygons."""
    total = 0.0
    for i in range(len(verts)):
        a = math.atan2(verts[i][1] - e, verts[i][0] - n)
        b = math.atan2(verts[(i + 1) % len(verts)][1] - e, verts[(i + 1) % len(verts)][0] - n)
        d = b - a
        while d > math.pi:
            d -= 2 * math.pi
        while d < -math.pi:
            d += 2 * math.pi
        total += d
    return abs(total) > math.pi


def test_point_in_polygon_matches_winding_reference_on_random_star_polygons() -> None:
    rng = np.random.default_rng(7)
    for _ in range(20):
        k = int(rng.integers(3, 12))
        angles = np.sort(rng.uniform(0, 2 * math.pi, k))
        radii = rng.uniform(5, 50, k)
        verts = [(float(r * math.cos(a)), float(r * math.sin(a))) for a, r in zip(angles, radii, strict=True)]
        assert not polygon_self_intersects(verts)  # star-shaped around the origin, sorted by angle: simple
        for n, e in rng.uniform(-60, 60, (200, 2)):
            assert point_in_polygon(n, e, verts) == _inside_by_winding(n, e, verts), (verts, n, e)


def test_self_intersection_and_bad_polygons_are_refused() -> None:
    bowtie = [(0.0, 0.0), (10.0, 10.0), (10.0, 0.0), (0.0, 10.0)]
    square = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)]
    assert polygon_self_intersects(bowtie) and not polygon_self_intersects(square)
    with pytest.raises(ValueError, match="self-intersects"):
        validate_polygon(bowtie)
    with pytest.raises(ValueError, match="at least 3"):
        validate_polygon(square[:2])
    with pytest.raises(ValueError, match="not finite"):
        validate_polygon([(0.0, 0.0), (NAN, 1.0), (1.0, 1.0)])
    with pytest.raises(ValueError, match="degenerate"):
        validate_polygon([(0.0, 0.0), (0.0, 0.0), (1.0, 1.0)])
    validate_polygon(square)


def test_px4_fence_semantics_inclusions_union_exclusions_cut_out() -> None:
    fence = Geofence(
        polygons=(PolygonFence(((-50.0, -50.0), (50.0, -50.0), (50.0, 50.0), (-50.0, 50.0))),),
        circles=(CircleFence((100.0, 0.0), 20.0), CircleFence((0.0, 0.0), 10.0, inclusion=False)),
    )
    assert fence.contains(30.0, 30.0)  # in the square
    assert fence.contains(110.0, 0.0)  # in the second inclusion (union)
    assert not fence.contains(0.0, 5.0)  # in the exclusion circle
    assert not fence.contains(75.0, 0.0)  # in no inclusion
    exclusion_only = Geofence(circles=(CircleFence((0.0, 0.0), 10.0, inclusion=False),))
    assert exclusion_only.contains(500.0, 500.0) and not exclusion_only.contains(1.0, 1.0)
    home = (0.0, 0.0, 0.0)
    assert breach_reason(Geofence(), (300.0, 0.0, -10.0), home) is None
    assert breach_reason(Geofence(), (300.0, 0.0, -10.0), home, FenceLimits(max_hor_dist_m=200.0)) is not None
    assert breach_reason(Geofence(), (0.0, 0.0, -60.0), home, FenceLimits(max_ver_dist_m=50.0)) is not None
    assert breach_reason(fence, (75.0, 0.0, -5.0), home) == "outside the fence"


def test_rtl_destination_is_the_closest_of_home_and_rally_points() -> None:
    rally = [RallyPoint(100.0, 0.0, -5.0), RallyPoint(-40.0, 0.0, -6.0)]
    assert rtl_destination((90.0, 0.0, -10.0), (0.0, 0.0, 0.0), rally) == ((100.0, 0.0, -5.0), 0)
    assert rtl_destination((-30.0, 0.0, -10.0), (0.0, 0.0, 0.0), rally) == ((-40.0, 0.0, -6.0), 1)
    assert rtl_destination((5.0, 0.0, -10.0), (0.0, 0.0, 0.0), rally) == ((0.0, 0.0, 0.0), None)


def test_orbit_command_parameters_as_px4() -> None:
    o = apply_command(None, (1.0, 2.0, -10.0), 0.3, -15.0, 3.0, NAN, None, None, 1000.0)
    assert (o.center_n_m, o.center_e_m, o.center_down_m) == (1.0, 2.0, -10.0)  # NaN centre/alt: the vehicle
    assert o.radius_m == 15.0 and o.velocity_m_s == -3.0 and not o.clockwise and o.signed_radius_m == -15.0
    o2 = apply_command(
        o, (0.0, 0.0, 0.0), 0.0, NAN, NAN, 3, (5.0, 5.0), -20.0, 1000.0
    )  # NaN keeps radius/speed
    assert o2.radius_m == 15.0 and o2.velocity_m_s == -3.0 and o2.yaw_behaviour == OrbitYaw(3)
    with pytest.raises(ValueError, match="radius limit"):
        apply_command(None, (0.0, 0.0, 0.0), 0.0, 2000.0, 1.0, NAN, None, None, 1000.0)
    with pytest.raises(ValueError, match="radius limit"):
        apply_command(None, (0.0, 0.0, 0.0), 0.0, 0.2, 1.0, NAN, None, None, 1000.0)
    fast = apply_command(None, (0.0, 0.0, 0.0), 0.0, 2.0, 50.0, NAN, None, None, 1000.0)
    assert fast.velocity_m_s**2 <= 2.0 * 2.0 + 1e-9  # centripetal limit reduces the speed, not the radius
    # on the circle, north of the centre, clockwise: the velocity setpoint points east
    on = Orbit(0.0, 0.0, -10.0, 10.0, 2.0, OrbitYaw.HOLD_FRONT_TO_CIRCLE_CENTER, 0.0)
    st = orbit_step(on, (10.0, 0.0, -10.0), approaching=False, alt_acc_rad_m=0.8)
    assert st.setpoint.vel_ned_m_s[1] == pytest.approx(2.0)
    assert st.yaw_rad is not None and abs(math.remainder(st.yaw_rad - math.pi, 2 * math.pi)) < 1e-9


def test_do_jump_resolution_is_bounded_and_counts() -> None:
    def it(seq: int, cmd: MissionCommand, p1: float = 0.0, p2: float = 0.0) -> MissionItem:
        return MissionItem(seq, cmd, 0.0, 0.0, -5.0, param1=p1, param2=p2)

    items = [it(0, MissionCommand.NAV_WAYPOINT), it(1, MissionCommand.DO_JUMP, 0, 2)]
    seq, done, warn = resolve_jumps(items, 1, {})
    assert (seq, done, warn) == (0, {1: 1}, None)
    seq, done, _ = resolve_jumps(items, 1, done)
    assert (seq, done) == (0, {1: 2})
    seq, done, _ = resolve_jumps(items, 1, done)
    assert seq == 2  # repeats used up: past the end
    # a jump chain that never reaches another item gives up instead of hanging (huge repeat count)
    loop = [it(0, MissionCommand.DO_JUMP, 1, 1e9), it(1, MissionCommand.DO_JUMP, 0, 1e9)]
    seq, _, warn = resolve_jumps(loop, 0, {})
    assert seq == 2 and warn == "DO JUMP is cycling, giving up"
    home = (0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="loops without a waypoint"):
        validate_mission(loop, home, lambda n, e: True, 0.0)
    with pytest.raises(ValueError, match="does not exist"):
        validate_mission([it(0, MissionCommand.NAV_WAYPOINT), it(1, MissionCommand.DO_JUMP, 7, 1)], home,
                         lambda n, e: True, 0.0)  # fmt: skip
    with pytest.raises(ValueError, match="Geofence violation for waypoint 1"):
        validate_mission([MissionItem(0, MissionCommand.NAV_WAYPOINT, 80.0, 0.0, -5.0)], home,
                         lambda n, e: True, 0.0, fence_ok=lambda n, e: n < 50)  # fmt: skip


# --- closed loop ------------------------------------------------------------------------------------
def _square(half: float) -> Geofence:
    return Geofence(polygons=(PolygonFence(((-half, -half), (half, -half), (half, half), (-half, half))),))


@pytest.mark.parametrize(
    ("action", "mode"),
    [(2, FlightMode.AUTO_LOITER), (3, FlightMode.AUTO_RTL), (5, FlightMode.AUTO_LAND)],
)
def test_fence_breach_triggers_gf_action(action: int, mode: FlightMode) -> None:
    f = Flight(GF_ACTION=action)
    f.take_off(5.0)
    assert f.ap.set_geofence(_square(20.0)).ok
    assert f.ap.reposition(f.t, 40.0, 0.0, -5.0, None).ok  # the footage check is off here: only the fence
    assert f.run(30.0, until=lambda f: any(t.startswith("Geofence breached") for t in f.texts()))
    assert f.ap.mode == mode
    assert f.pos[0] > 19.0, "reacted before crossing the fence"
    assert any(t.startswith("Geofence breached") for t in f.texts())
    if mode == FlightMode.AUTO_LOITER:
        f.run(5.0)
        assert f.pos[0] < 30.0  # holds near the edge, does not continue to 40 m


def test_fence_warning_only_and_mission_outside_fence_refused() -> None:
    f = Flight(GF_ACTION=1)
    f.take_off(5.0)
    f.ap.set_geofence(_square(20.0))
    assert f.ap.reposition(f.t, 30.0, 0.0, -5.0, None).ok
    assert f.run(20.0, until=lambda f: f.pos[0] > 29.0)
    assert f.ap.mode == FlightMode.AUTO_LOITER and sum(t.startswith("Geofence") for t in f.texts()) == 1
    out = f.ap.set_mission([MissionItem(0, MissionCommand.NAV_WAYPOINT, 5.0, 0.0, -5.0),
                            MissionItem(1, MissionCommand.NAV_WAYPOINT, 60.0, 0.0, -5.0)])  # fmt: skip
    assert out.result == CommandResult.DENIED and out.reason == "Geofence violation for waypoint 2"


def test_rtl_goes_to_the_nearest_rally_point_and_lands_there() -> None:
    f = Flight(RTL_RETURN_ALT=8.0, RTL_DESCEND_ALT=4.0)
    f.take_off(5.0)
    f.ap.set_rally_points([RallyPoint(30.0, 10.0, 0.0), RallyPoint(-50.0, 0.0, 0.0)])
    assert f.ap.reposition(f.t, 25.0, 5.0, -6.0, None).ok
    assert f.run(25.0, until=lambda f: math.hypot(f.pos[0] - 25, f.pos[1] - 5) < 0.5)
    assert f.ap.return_to_launch(f.t).ok
    assert f.run(60.0, until=lambda f: not f.ap.armed)
    assert math.hypot(f.pos[0] - 30.0, f.pos[1] - 10.0) < 1.0, f.pos  # the rally point, not home (0, 0)
    assert "RTL: returning to rally point 0" in f.texts()


@pytest.mark.parametrize("radius", [12.0, -12.0])
def test_orbit_holds_radius_and_direction(radius: float) -> None:
    f = Flight()
    f.take_off(6.0)
    assert f.ap.orbit(f.t, radius, 3.0, 0, (5.0, 0.0), -8.0).ok
    assert f.ap.mode == FlightMode.ORBIT
    assert f.run(30.0, until=lambda f: f.ap.orbit_status is not None and not f.ap.orbit_approaching)
    start = len(f.trace)
    f.run(25.0)
    pts = np.array([p for _, p, _ in f.trace[start:]])
    dist = np.hypot(pts[:, 0] - 5.0, pts[:, 1])
    assert np.all(np.abs(dist - 12.0) < 1.2), (dist.min(), dist.max())  # from the end of the approach on
    settled = dist[int(5.0 / f.eav.dt_s) :]
    assert np.all(np.abs(settled - 12.0) < 0.3), (settled.min(), settled.max())  # after 5 s
    assert np.all(np.abs(pts[:, 2] + 8.0) < 0.5)
    bearing = np.unwrap(np.arctan2(pts[:, 1], pts[:, 0] - 5.0))
    swept = bearing[-1] - bearing[0]
    # 25 s at 3 m/s on r = 12 m: ~6.25 rad, clockwise (bearing increasing) for a positive radius
    assert swept * math.copysign(1.0, radius) > 5.0, swept
    # yaw faces the centre (ORBIT_YAW_BEHAVIOUR 0)
    n, e = pts[-1, 0] - 5.0, pts[-1, 1]
    yaw_err = math.remainder(f.state.yaw_rad - math.atan2(-e, -n), 2 * math.pi)
    assert abs(yaw_err) < math.radians(15)
    assert f.ap.orbit(f.t, 5000.0, 1.0, 0, None, None).result == CommandResult.DENIED


def test_do_jump_mission_visits_and_delay_and_camera_items() -> None:
    f = Flight(MIS_DIST_1WP=0.0)
    wp = MissionCommand.NAV_WAYPOINT
    items = [
        MissionItem(0, MissionCommand.NAV_TAKEOFF, NAN, NAN, -5.0),
        MissionItem(1, wp, 10.0, 0.0, -5.0),
        MissionItem(2, MissionCommand.IMAGE_START_CAPTURE, NAN, NAN, NAN, param1=0, param2=0, param3=1),
        MissionItem(3, wp, 0.0, 8.0, -5.0),
        MissionItem(4, MissionCommand.DO_JUMP, NAN, NAN, NAN, param1=1, param2=2),
        MissionItem(5, MissionCommand.NAV_DELAY, NAN, NAN, NAN, param1=3.0),
        MissionItem(6, MissionCommand.OTHER, NAN, NAN, NAN, raw_command=3000),  # DO_VTOL_TRANSITION: skipped
        MissionItem(7, MissionCommand.NAV_LAND, NAN, NAN, NAN),
    ]
    assert f.ap.set_mission(items).ok
    f.run(0.1)
    assert f.ap.arm(f.t).ok and f.ap.mission_start(f.t).ok
    actions: list[str] = []
    f.each = lambda fl: actions.extend(a.kind for a in fl.ap.pop_payload_actions())
    assert f.run(150.0, until=lambda f: not f.ap.armed)
    visits: dict[int, int] = {}
    reached_at: dict[int, float] = {}
    for e in f.events:
        if e.mission_item_reached is not None:
            visits[e.mission_item_reached] = visits.get(e.mission_item_reached, 0) + 1
            reached_at[e.mission_item_reached] = e.time_s
    assert visits[1] == 3 and visits[3] == 3  # first pass + 2 jumps
    assert visits[5] == 1 and visits[7] == 1
    assert reached_at[5] - reached_at[3] >= 3.0  # NAV_DELAY waited its 3 s after the last waypoint
    assert actions == ["capture_once"] * 3
    assert "Mission item 6: command 3000 not supported, skipped" in f.texts()


def test_relative_altitude_resolved_when_the_item_runs() -> None:
    f = Flight(MIS_DIST_1WP=0.0)
    # uploaded while home is at 0; home then moves 3 m up (DO_SET_HOME): 5 m above home is now down -8
    item = MissionItem(0, MissionCommand.NAV_WAYPOINT, 0.0, 0.0, -5.0, alt_rel_home_m=5.0)
    assert f.ap.set_mission([item]).ok
    f.take_off(4.0)
    assert f.ap.set_home(f.t, (0.0, 0.0, -3.0)).ok
    assert f.ap.mission_start(f.t).ok
    assert f.run(20.0, until=lambda f: f.ap.mission_finished)
    f.run(3.0)
    assert f.pos[2] == pytest.approx(-8.0, abs=0.4)


def test_reposition_without_change_mode_only_moves_an_active_hold() -> None:
    f = Flight()
    f.take_off(5.0)
    assert f.ap.orbit(f.t, 6.0, 2.0, 0, None, None).ok
    assert f.ap.reposition(f.t, 20.0, 0.0, -5.0, None, change_mode=False).ok
    f.run(3.0)
    assert f.ap.mode == FlightMode.ORBIT  # not switched
    assert f.ap.set_mode(f.t, FlightMode.AUTO_LOITER).ok  # the kept target is flown on the next Hold
    assert f.run(25.0, until=lambda f: abs(f.pos[0] - 20.0) < 0.5 and abs(f.pos[1]) < 0.5)
    assert f.ap.reposition(f.t, 20.0, 10.0, -5.0, None, change_mode=False).ok  # in Hold: moves at once
    assert f.run(20.0, until=lambda f: abs(f.pos[1] - 10.0) < 0.5)


def test_arming_outside_the_fence_is_refused_unless_gf_action_is_none() -> None:
    f = Flight()
    f.run(0.1)
    f.ap.set_geofence(Geofence(circles=(CircleFence((100.0, 0.0), 10.0),)))
    out = f.ap.arm(f.t)
    assert out.result == CommandResult.DENIED and out.reason == "Arming denied: vehicle outside geofence"
    f.params.set("GF_ACTION", 0)
    assert f.ap.arm(f.t).ok


def test_a_new_fence_invalidates_a_stored_mission_outside_it() -> None:
    f = Flight(MIS_DIST_1WP=0.0)
    f.run(0.1)
    assert f.ap.set_mission([MissionItem(0, MissionCommand.NAV_WAYPOINT, 60.0, 0.0, -5.0)]).ok
    f.ap.set_geofence(_square(20.0))
    assert "Geofence violation for waypoint 1" in [e.text for e in f.ap.pop_events()]
    assert f.ap.set_mode(f.t, FlightMode.AUTO_MISSION).result == CommandResult.TEMPORARILY_REJECTED
    f.ap.set_geofence(Geofence())
    assert f.ap.set_mode(f.t, FlightMode.AUTO_MISSION).ok


def test_distance_trigger_fires_every_distance_and_stops_at_zero() -> None:
    trig = DistanceTrigger()
    trig.set(5.0, 0.0, 0.0)
    fired = [n for n in np.arange(0.0, 23.0, 0.1) if trig.update(float(n), 0.0)]
    assert fired == pytest.approx([5.0, 10.0, 15.0, 20.0], abs=0.11)
    trig.set(0.0, 0.0, 0.0)
    assert not any(trig.update(float(n), 0.0) for n in np.arange(0.0, 50.0, 1.0))
