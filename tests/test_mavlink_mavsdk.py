"""The endpoint against the real MAVSDK 4 (native API): discovery, health, params, arm/takeoff/land, mission_raw,
offboard and the camera plugin, on the minimal vehicle (Autopilot + EAV) over UDP on 127.0.0.1.

The full product path (viva-sitl run + mission scripts, both MAVSDK APIs) is tested end to end elsewhere; this file
pins the MAVLink layer alone against MAVSDK's expectations."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import pytest
from mav_client import MavClient, VehicleThread

from viva_sitl.mavlink import MavlinkConfig
from viva_sitl.selftest import SnapshotCamera

mavsdk_asyncio = pytest.importorskip(
    "mavsdk.asyncio", reason="MAVSDK 4.x (pip install mavsdk>=4) not installed"
)


def _free_udp_port() -> int:
    c = MavClient()
    port = c.port
    c.close()
    return port


async def _first(gen, pred, timeout_s: float):  # type: ignore[no-untyped-def]
    async def run():  # type: ignore[no-untyped-def]
        async for item in gen:
            if pred(item):
                return item
        return None

    return await asyncio.wait_for(run(), timeout_s)


@pytest.mark.slow  # a MAVSDK flight (the camera tests keep MAVSDK in the fast tier)
def test_mavsdk_native_api_flies_the_endpoint(tmp_path: Path) -> None:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action.action import ActionAsync
    from mavsdk.asyncio.plugins.camera.camera import CameraAsync
    from mavsdk.asyncio.plugins.mission_raw.mission_raw import MissionRawAsync
    from mavsdk.asyncio.plugins.offboard.offboard import OffboardAsync
    from mavsdk.asyncio.plugins.param.param import ParamAsync
    from mavsdk.asyncio.plugins.telemetry.telemetry import TelemetryAsync
    from mavsdk.plugins.mission_raw.mission_raw import MissionItem
    from mavsdk.plugins.offboard.offboard import PositionNedYaw

    port = _free_udp_port()
    camera = SnapshotCamera(tmp_path / "captures")
    cfg = MavlinkConfig(api_remote_port=port, gcs_remote_port=0, api_local_port=0, gcs_local_port=0)

    async def scenario(vt: VehicleThread) -> None:
        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(config) as mavsdk:
            await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
            system = await mavsdk.first_autopilot(timeout_s=10.0)
            tel, act, par = TelemetryAsync(system), ActionAsync(system), ParamAsync(system)
            health = await _first(
                tel.subscribe_health(),
                lambda h: h.is_global_position_ok and h.is_home_position_ok and h.is_armable,
                10.0,
            )
            assert health is not None
            await par.set_param_int("NAV_DLL_ACT", 0)
            assert await par.get_param_int("NAV_DLL_ACT") == 0
            await act.set_takeoff_altitude(3.5)
            assert await act.get_takeoff_altitude() == pytest.approx(3.5)

            # mission_raw: takeoff (frame 3), waypoint and land (frame 6) 8 m north
            dlat = math.degrees(8.0 / 6371000.0)
            lat, lon = round((47.397742 + dlat) * 1e7), round(8.545594 * 1e7)
            nan = float("nan")
            items = [
                MissionItem(0, 3, 22, 1, 1, 0, 0, 0, nan, 0, 0, 3.0, 0),
                MissionItem(1, 6, 16, 0, 1, 0, 1.0, 0, nan, lat, lon, 4.0, 0),
                MissionItem(2, 6, 21, 0, 1, 0, 0, 0, nan, lat, lon, 0.0, 0),
            ]
            mr = MissionRawAsync(system)
            await mr.upload_mission(items)
            got = await mr.download_mission()
            assert [(i.frame, i.command, i.x, i.y) for i in got] == [
                (3, 22, 0, 0),
                (6, 16, lat, lon),
                (6, 21, lat, lon),
            ]
            await act.arm()
            await mr.start_mission()
            landed = await _first(tel.subscribe_position(), lambda p: abs(p.latitude_deg * 1e7 - lat) < 30
                                  and p.relative_altitude_m < 0.1, 30.0)  # fmt: skip
            assert landed is not None
            await _first(tel.subscribe_armed(), lambda a: not a, 10.0)  # auto-disarm after landing

            # action: takeoff to MIS_TAKEOFF_ALT, then offboard position, then land
            await act.arm()
            await act.takeoff()
            top = await _first(tel.subscribe_position(), lambda p: p.relative_altitude_m > 3.3, 15.0)
            assert top is not None
            off = OffboardAsync(system)
            await off.set_position_ned(PositionNedYaw(10.0, 3.0, -5.0, 0.0))
            await off.start()
            pv = await _first(
                tel.subscribe_position_velocity_ned(),
                lambda pv: abs(pv.position.north_m - 10.0) < 0.5 and abs(pv.position.down_m + 5.0) < 0.5,
                15.0,
            )
            assert pv is not None
            await off.stop()
            await act.land()
            ls = await _first(tel.subscribe_landed_state(), lambda s: int(s.value) == 1, 20.0)
            assert ls is not None

            # camera plugin discovers compid 100 and takes a picture
            cam = CameraAsync(system)
            cams = await _first(cam.subscribe_camera_list(), lambda cl: len(cl.cameras) > 0, 10.0)
            assert cams.cameras[0].component_id == 100 and cams.cameras[0].horizontal_resolution_px == 640
            await cam.take_photo(100)
            for _ in range(50):
                if camera.captured:
                    break
                await asyncio.sleep(0.1)
            assert camera.captured == [0]
        st = vt.stats()
        assert (
            st["handler_errors"] == 0
            and st["mission_uploads_completed"] == 1
            and st["setpoints_handled"] >= 5
        )

    with VehicleThread(cfg, speed=3.0, camera=camera) as vt:
        asyncio.run(asyncio.wait_for(scenario(vt), 120.0))
