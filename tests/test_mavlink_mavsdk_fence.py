"""Real MAVSDK 4 (native API) against the endpoint: geofence plugin upload / download / clear, a QGroundControl
.plan with a geofence and rally points imported and uploaded by mission_raw (as MAVSDK's mission_import example),
and action.do_orbit flown (as the do_orbit example)."""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path

import pytest
from mav_client import VehicleThread
from test_mavlink_mavsdk import _first, _free_udp_port

from viva_sitl.autopilot import FlightMode
from viva_sitl.geo import GeoOrigin
from viva_sitl.mavlink import MavlinkConfig

mavsdk_asyncio = pytest.importorskip(
    "mavsdk.asyncio", reason="MAVSDK 4.x (pip install mavsdk>=4) not installed"
)
GEO = GeoOrigin()


def _ll(north: float, east: float) -> tuple[float, float]:
    lat, lon, _ = GEO.ned_to_global(north, east, 0.0)
    return lat, lon


def _plan() -> str:
    """A QGroundControl plan: take-off, two waypoints, RTL; a square inclusion fence, an exclusion circle; 2 rally
    points."""
    home = [*_ll(0, 0), GEO.alt_amsl_m]

    def simple(seq: int, cmd: int, frame: int, lat: float, lon: float, alt: float) -> dict[str, object]:
        return {"autoContinue": True, "command": cmd, "doJumpId": seq + 1, "frame": frame, "type": "SimpleItem",
                "params": [0, 0, 0, None, lat, lon, alt], "Altitude": alt, "AltitudeMode": 1,
                "AMSLAltAboveTerrain": None}  # fmt: skip

    items = [
        simple(0, 22, 3, *_ll(0, 0), 5),
        simple(1, 16, 3, *_ll(20, 0), 5),
        simple(2, 16, 3, *_ll(20, 20), 5),
        simple(3, 20, 2, 0, 0, 0),
    ]
    square = [list(_ll(n, e)) for n, e in ((-40, -40), (40, -40), (40, 40), (-40, 40))]
    plan = {
        "fileType": "Plan",
        "groundStation": "QGroundControl",
        "version": 1,
        "mission": {
            "cruiseSpeed": 15,
            "hoverSpeed": 5,
            "firmwareType": 12,
            "vehicleType": 2,
            "version": 2,
            "plannedHomePosition": home,
            "items": items,
        },  # fmt: skip
        "geoFence": {
            "version": 2,
            "polygons": [{"inclusion": True, "polygon": square, "version": 1}],
            "circles": [
                {"circle": {"center": list(_ll(-20, -20)), "radius": 5.0}, "inclusion": False, "version": 1}
            ],
        },
        "rallyPoints": {"version": 2, "points": [[*_ll(30, 30), 10.0], [*_ll(-30, 0), 10.0]]},
    }
    return json.dumps(plan)


@pytest.mark.slow  # a MAVSDK flight
def test_mavsdk_geofence_plan_import_and_do_orbit() -> None:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action.action import ActionAsync
    from mavsdk.asyncio.plugins.geofence.geofence import GeofenceAsync
    from mavsdk.asyncio.plugins.mission_raw.mission_raw import MissionRawAsync
    from mavsdk.asyncio.plugins.telemetry.telemetry import TelemetryAsync
    from mavsdk.plugins.action.action import OrbitYawBehavior
    from mavsdk.plugins.geofence.geofence import Circle, FenceType, GeofenceData, Point, Polygon

    port = _free_udp_port()
    cfg = MavlinkConfig(api_remote_port=port, gcs_remote_port=0, api_local_port=0, gcs_local_port=0)

    async def scenario(vt: VehicleThread) -> None:
        ap = vt.vehicle.autopilot  # type: ignore[union-attr]
        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(config) as mavsdk:
            await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
            system = await mavsdk.first_autopilot(timeout_s=10.0)
            tel, act = TelemetryAsync(system), ActionAsync(system)
            assert await _first(tel.subscribe_health(), lambda h: h.is_armable, 10.0) is not None

            # geofence plugin (MAVSDK's geofence.py example): polygon inclusion + circle exclusion
            gf = GeofenceAsync(system)
            pts = [Point(*_ll(n, e)) for n, e in ((-50, -50), (50, -50), (50, 50), (-50, 50))]
            data = GeofenceData([Polygon(pts, FenceType.INCLUSION)],
                                [Circle(Point(*_ll(10, 10)), 4.0, FenceType.EXCLUSION)])  # fmt: skip
            await gf.upload_geofence(data)
            fence = vt.call(lambda: ap.geofence)
            assert len(fence.polygons) == 1 and len(fence.circles) == 1
            assert (
                fence.contains(0.0, 0.0) and not fence.contains(10.0, 11.0) and not fence.contains(60.0, 0.0)
            )
            down = await gf.download_geofence()
            assert len(down.polygons) == 1 and len(down.polygons[0].points) == 4 and len(down.circles) == 1
            await gf.clear_geofence()
            assert vt.call(lambda: ap.geofence.empty)

            # a QGC .plan with fence and rally points (MAVSDK's mission_import example)
            mr = MissionRawAsync(system)
            imported = await mr.import_qgroundcontrol_mission_from_string(_plan())
            assert len(imported.geofence_items) == 5 and len(imported.rally_items) == 2
            await mr.upload_mission(imported.mission_items)
            await mr.upload_geofence(imported.geofence_items)
            await mr.upload_rally_points(imported.rally_items)
            assert vt.call(lambda: len(ap.rally_points)) == 2
            assert vt.call(lambda: not ap.geofence.contains(-20.0, -21.0))  # the exclusion circle
            assert len(await mr.download_rallypoints()) == 2

            # do_orbit (MAVSDK's do_orbit example): take off, orbit 10 m around a point 15 m north
            await act.set_takeoff_altitude(6.0)
            await act.arm()
            await act.takeoff()
            assert await _first(tel.subscribe_position(), lambda p: p.relative_altitude_m > 5.7, 20.0)
            lat, lon = _ll(15.0, 0.0)
            await act.do_orbit(10.0, 2.0, OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER, lat, lon,
                               GEO.alt_amsl_m + 8.0)  # fmt: skip
            assert vt.call(lambda: ap.mode) == FlightMode.ORBIT
            on = await _first(
                tel.subscribe_position_velocity_ned(),
                lambda pv: abs(math.hypot(pv.position.north_m - 15.0, pv.position.east_m) - 10.0) < 0.5
                and abs(pv.position.down_m + 8.0) < 0.5 and math.hypot(pv.velocity.north_m_s, pv.velocity.east_m_s) > 1.5,
                40.0,
            )  # fmt: skip
            assert on is not None
            await act.return_to_launch()
            # RTL goes to the nearest of home and the two rally points: from the orbit that is home (0, 0)
            landed = await _first(tel.subscribe_landed_state(), lambda s: int(s.value) == 1, 60.0)
            assert landed is not None
            pv = await _first(tel.subscribe_position_velocity_ned(), lambda pv: True, 5.0)
            assert math.hypot(pv.position.north_m, pv.position.east_m) < 1.5

    with VehicleThread(cfg, speed=4.0) as vt:
        asyncio.run(asyncio.wait_for(scenario(vt), 150.0))


@pytest.mark.slow  # a MAVSDK flight
def test_mavsdk_goto_beyond_the_footage_with_the_default_footage_fence(tmp_path: Path) -> None:
    """MAVSDK's goto example, unchanged, on a finite field: the default SIM_FTG_FENCE (1, warning) lets it fly past
    the footage edge and land there."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action.action import ActionAsync
    from mavsdk.asyncio.plugins.telemetry.telemetry import TelemetryAsync

    finite = tmp_path / "finite-synthetic.toml"
    finite.write_text('name = "finite"\nkind = "synthetic"\n[synthetic]\nunbounded = false\n')
    port = _free_udp_port()
    cfg = MavlinkConfig(api_remote_port=port, gcs_remote_port=0, api_local_port=0, gcs_local_port=0)

    async def scenario(vt: VehicleThread) -> None:
        ap = vt.vehicle.autopilot  # type: ignore[union-attr]
        edge_inside = vt.call(lambda: vt.vehicle.vehicle.inside_footage)  # type: ignore[union-attr]
        assert edge_inside(100.0, 0.0) and not edge_inside(130.0, 0.0)  # the field ends at 102.4 m
        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(config) as mavsdk:
            await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
            system = await mavsdk.first_autopilot(timeout_s=10.0)
            tel, act = TelemetryAsync(system), ActionAsync(system)
            assert await _first(tel.subscribe_health(), lambda h: h.is_armable, 10.0) is not None
            await act.set_takeoff_altitude(6.0)
            await act.arm()
            await act.takeoff()
            assert await _first(tel.subscribe_position(), lambda p: p.relative_altitude_m > 5.7, 20.0)
            lat, lon = _ll(130.0, 0.0)
            await act.goto_location(lat, lon, GEO.alt_amsl_m + 6.0, 0.0)
            there = await _first(tel.subscribe_position_velocity_ned(),
                                 lambda pv: pv.position.north_m > 129.0, 60.0)  # fmt: skip
            assert there is not None
            assert vt.call(lambda: ap.mode) == FlightMode.AUTO_LOITER
            await act.land()
            assert await _first(tel.subscribe_landed_state(), lambda s: int(s.value) == 1, 60.0) is not None
            pv = await _first(tel.subscribe_position_velocity_ned(), lambda pv: True, 5.0)
            assert pv.position.north_m > 125.0  # landed beyond the footage

    with VehicleThread(cfg, speed=4.0, footage=finite) as vt:
        asyncio.run(asyncio.wait_for(scenario(vt), 150.0))
