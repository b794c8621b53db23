"""MAVSDK's camera plugin against the real endpoint over UDP: the video stream URI and the capture feedback.

MAVSDK's CameraImpl requests VIDEO_STREAM_INFORMATION only every 20 s (its first request goes out before it has seen
the camera), so the camera component sends it along with CAMERA_INFORMATION / VIDEO_STREAM_STATUS: a client gets the
URI within seconds, well before MAVSDK's own 20 s request. Both APIs: `mavsdk` 4.x (native `mavsdk.asyncio`) and the
classic gRPC API (`mavsdk_grpc`, run as a subprocess: its mavsdk_server outlives the event loop).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import socket
import subprocess
import sys
import textwrap
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any, TypeVar

import pytest
from mav_client import VehicleThread
from sitl_process import free_tcp_port

from viva_sitl.mavlink import MavlinkConfig
from viva_sitl.selftest import SnapshotCamera

T = TypeVar("T")
STREAM_PORT = (
    5600  # SnapshotCamera's default stream udp://127.0.0.1:5600: VIDEO_STREAM_INFORMATION.uri "5600"
)
URI_DEADLINE_S = 12.0  # well under MAVSDK's own 20 s VIDEO_STREAM_INFORMATION request period


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def _first(gen: AsyncIterator[T], pred: Callable[[T], bool], timeout_s: float) -> T:
    async def run() -> T:
        async for item in gen:
            if pred(item):
                return item
        raise AssertionError("stream ended")

    return await asyncio.wait_for(run(), timeout_s)


def test_mavsdk_native_camera_gets_stream_uri_and_capture_info(tmp_path: Path) -> None:
    pytest.importorskip("mavsdk.asyncio", reason="needs mavsdk>=4")
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.camera.camera import CameraAsync

    port = _free_udp_port()
    camera = SnapshotCamera(tmp_path / "captures")
    cfg = MavlinkConfig(api_remote_port=port, gcs_remote_port=0, api_local_port=0, gcs_local_port=0)

    async def scenario() -> tuple[Any, Any, float, int]:
        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(config) as mavsdk:
            await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
            system = await mavsdk.first_autopilot(timeout_s=10.0)
            cam = CameraAsync(system)
            loop = asyncio.get_running_loop()
            t0 = loop.time()
            cams = await _first(cam.subscribe_camera_list(), lambda cl: len(cl.cameras) > 0, 10.0)
            assert cams.cameras[0].component_id == 100
            update = await _first(
                cam.subscribe_video_stream_info(),
                lambda u: bool(u.video_stream_info.settings.uri),
                URI_DEADLINE_S,
            )
            uri_after_s = loop.time() - t0
            # the subscription starts some time after the generator first runs, with no signal, and a capture before
            # that is not replayed (MAVSDK notifies the subscribers of the moment): photos until one is seen
            got: asyncio.Queue[Any] = asyncio.Queue()

            async def consume() -> None:
                async for c in cam.subscribe_capture_info():
                    got.put_nowait(c)

            consumer = asyncio.ensure_future(consume())
            info, taken = None, 0
            while info is None and taken < 5:
                await cam.take_photo(100)
                taken += 1
                with contextlib.suppress(TimeoutError):
                    info = await asyncio.wait_for(got.get(), 3.0)
            consumer.cancel()
            return update, info, uri_after_s, taken

    with VehicleThread(cfg, speed=1.0, camera=camera) as vt:
        update, info, uri_after_s, taken = asyncio.run(asyncio.wait_for(scenario(), 60.0))
        stats = vt.stats()
    settings = update.video_stream_info.settings
    assert update.component_id == 100
    assert settings.uri == str(STREAM_PORT)  # QGC's reading of an RTP/UDP stream: the port
    assert (settings.horizontal_resolution_pix, settings.vertical_resolution_pix) == (1280, 720)  # the spec's
    assert uri_after_s < URI_DEADLINE_S
    assert info is not None, f"no capture feedback after {taken} photos"
    assert info.is_success and 0 <= info.index < taken and info.component_id == 100
    assert info.file_url == f"file://{tmp_path / 'captures' / f'img_{info.index:05d}.pgm'}"
    assert Path(info.file_url[len("file://") :]).is_file()
    assert camera.captured == list(range(taken))
    # the camera's attitude: a nadir camera on a level vehicle heading north looks straight down (pitch -90 deg)
    q = info.attitude_quaternion
    assert (q.w, q.x, q.y, q.z) == pytest.approx((math.sqrt(0.5), 0.0, -math.sqrt(0.5), 0.0), abs=0.02)
    assert stats["handler_errors"] == 0


GRPC_SCRIPT = textwrap.dedent(
    """
    import asyncio, json, os, sys
    from mavsdk_grpc import System

    async def first(gen, pred, timeout_s):
        async def run():
            async for item in gen:
                if pred(item):
                    return item
        return await asyncio.wait_for(run(), timeout_s)

    async def main():
        url, grpc_port = sys.argv[1], int(sys.argv[2])
        drone = System(port=grpc_port)
        await drone.connect(system_address=url)
        await first(drone.core.connection_state(), lambda s: s.is_connected, 20.0)
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        out = {}
        try:
            cams = await first(drone.camera.camera_list(), lambda cl: len(cl.cameras) > 0, 15.0)
            out["camera_ids"] = [c.component_id for c in cams.cameras]
            upd = await first(drone.camera.video_stream_info(), lambda u: bool(u.video_stream_info.settings.uri), 12.0)
            out["uri"] = upd.video_stream_info.settings.uri
            out["uri_after_s"] = loop.time() - t0
            # a gRPC subscription becomes active some time after the call, with no signal: a capture before that
            # is not replayed to it (MAVSDK notifies the subscribers of the moment). So: photos until one is seen.
            got = asyncio.Queue()

            async def consume():
                async for c in drone.camera.capture_info():
                    got.put_nowait(c)

            consumer = asyncio.ensure_future(consume())
            info, taken = None, 0
            while info is None and taken < 5:
                await drone.camera.take_photo(100)
                taken += 1
                try:
                    info = await asyncio.wait_for(got.get(), 3.0)
                except asyncio.TimeoutError:
                    pass
            consumer.cancel()
            q = info.attitude_quaternion
            out["capture"] = {"ok": info.is_success, "index": info.index, "url": info.file_url,
                              "q": [q.w, q.x, q.y, q.z], "taken": taken}
        except Exception as exc:
            out["error"] = f"{type(exc).__name__}: {exc}"
        print("RESULT " + json.dumps(out), flush=True)
        os._exit(0)  # the gRPC API's mavsdk_server threads can keep a finished process alive

    asyncio.run(main())
    """
)


def test_mavsdk_grpc_camera_gets_stream_uri_and_capture_info(tmp_path: Path) -> None:
    pytest.importorskip("mavsdk_grpc", reason="the classic API needs `pip install mavsdk-grpc`")
    port = _free_udp_port()
    camera = SnapshotCamera(tmp_path / "captures")
    cfg = MavlinkConfig(api_remote_port=port, gcs_remote_port=0, api_local_port=0, gcs_local_port=0)
    script = tmp_path / "grpc_camera.py"
    script.write_text(GRPC_SCRIPT)
    with VehicleThread(cfg, speed=1.0, camera=camera):
        try:
            run = subprocess.run(
                [sys.executable, str(script), f"udpin://127.0.0.1:{port}", str(free_tcp_port())],
                capture_output=True,
                text=True,
                timeout=90,
            )
        except subprocess.TimeoutExpired as exc:
            pytest.fail(f"the gRPC client hung: {exc.stdout!r} {exc.stderr!r}"[-3000:])
    lines = [ln for ln in run.stdout.splitlines() if ln.startswith("RESULT ")]
    assert lines, f"no result: rc {run.returncode}\n{run.stdout[-2000:]}\n{run.stderr[-2000:]}"
    out = json.loads(lines[-1][len("RESULT ") :])
    assert "error" not in out, out
    assert out["camera_ids"] == [100]
    assert out["uri"] == str(STREAM_PORT) and out["uri_after_s"] < URI_DEADLINE_S
    cap = out["capture"]
    assert cap["ok"] and 0 <= cap["index"] < cap["taken"] and Path(cap["url"][len("file://") :]).is_file()
    assert cap["url"].endswith(f"img_{cap['index']:05d}.pgm")
    assert cap["q"] == pytest.approx([math.sqrt(0.5), 0.0, -math.sqrt(0.5), 0.0], abs=0.02)
    assert camera.captured == list(range(cap["taken"]))
