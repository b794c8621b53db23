"""End to end: MAVSDK's gimbal plugin (MAVSDK-Python 4.x) against a `viva-sitl run` whose camera has a gimbal mount
(`[camera] mount = "gimbal"`, as PX4's gz_x500_gimbal): the gimbal is discovered, control is taken, set_angles and
set_roi_location point the VAC, and the frame socket's metadata (cam_rot_body) shows the rendered camera pitching."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sitl_process import SitlProcess, free_udp_ports

from viva_sitl.dynamics.rotation import rot_body_to_ned
from viva_sitl.video import FrameClient

GIMBAL_TOML = """
[camera]
mount = "gimbal"
width_px = 160
height_px = 120
[video]
fps = 10
"""


def view_elevation_deg(meta: dict[str, Any]) -> float:
    """Elevation of the rendered camera's optical axis (deg; -90 = straight down) from a frame's metadata."""
    axis = rot_body_to_ned(*meta["att_rpy_rad"]) @ np.asarray(meta["cam_rot_body"], dtype=np.float64)[:, 2]
    return math.degrees(-math.asin(float(axis[2])))


def wait_frame(
    client: FrameClient, pred: Callable[[dict[str, Any]], bool], timeout_s: float = 20.0
) -> dict[str, Any]:
    last: dict[str, Any] | None = None
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        got = client.receive(timeout_s=1.0)
        if got is None:
            continue
        last = got[1]
        if pred(last):
            return last
    raise AssertionError(f"no frame matched within {timeout_s} s; last metadata: {last}")


def test_mavsdk_gimbal_points_the_vac(sitl_factory: Callable[..., SitlProcess], tmp_path: Path) -> None:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.gimbal import ControlMode, GimbalAsync, GimbalMode, SendMode

    cfg = tmp_path / "gimbal.toml"
    cfg.write_text(GIMBAL_TOML)
    sitl = sitl_factory(video_port=free_udp_ports(1)[0], extra_args=["--config", str(cfg)])
    frames = FrameClient(f"tcp://127.0.0.1:{sitl.frame_socket_port}")
    try:
        rest = wait_frame(frames, lambda m: True)
        assert view_elevation_deg(rest) == pytest.approx(-90.0, abs=0.5)  # the nadir mount before any command

        async def scenario() -> dict[str, Any]:
            async with Mavsdk(
                Configuration.create_with_component_type(ComponentType.GROUND_STATION)
            ) as mavsdk:
                await mavsdk.add_any_connection(sitl.ports.mavsdk_url)
                system = await mavsdk.first_autopilot(timeout_s=15.0)
                assert system is not None, "no autopilot discovered"
                gimbal = GimbalAsync(system)
                found = None
                async with asyncio.timeout(20.0):
                    async for gl in gimbal.subscribe_gimbal_list():
                        if gl.gimbals:
                            found = gl.gimbals[0]
                            break
                assert found is not None
                gid = found.gimbal_id
                await gimbal.take_control(gid, ControlMode.PRIMARY)
                await gimbal.set_angles(gid, 0.0, -30.0, 0.0, GimbalMode.YAW_FOLLOW, SendMode.ONCE)
                att = None
                async with asyncio.timeout(10.0):
                    async for a in gimbal.subscribe_attitude():
                        if abs(a.euler_angle_forward.pitch_deg + 30.0) < 0.5:
                            att = a
                            break
                return {
                    "gimbal_id": gid,
                    "manager_compid": found.gimbal_manager_component_id,
                    "vendor": found.vendor_name,
                    "pitch": att.euler_angle_forward.pitch_deg if att else None,
                }

        result = asyncio.run(scenario())
        assert result["manager_compid"] == 1 and result["vendor"] == "viva-sitl"
        assert result["pitch"] == pytest.approx(-30.0, abs=0.5)
        # the rendered view pitched: the frame socket's cam_rot_body (the VAC as rendered) looks 30 deg below the horizon
        pitched = wait_frame(frames, lambda m: abs(view_elevation_deg(m) + 30.0) < 0.5)
        assert view_elevation_deg(pitched) == pytest.approx(-30.0, abs=0.5)
    finally:
        frames.close()
