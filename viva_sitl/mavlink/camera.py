"""MAVLink camera protocol: the camera component (compid 100) of the vehicle.

It heartbeats as MAV_TYPE_CAMERA, answers REQUEST_MESSAGE for CAMERA_INFORMATION (259), CAMERA_SETTINGS (260),
STORAGE_INFORMATION (261), CAMERA_CAPTURE_STATUS (262), VIDEO_STREAM_INFORMATION (269) and VIDEO_STREAM_STATUS (270)
plus the legacy REQUEST_* commands, and takes pictures on MAV_CMD_IMAGE_START_CAPTURE (2000): the ACK goes out at once,
the capture runs on a worker thread (it encodes and writes a file) and CAMERA_IMAGE_CAPTURED follows.

For an RTP/UDP stream VIDEO_STREAM_INFORMATION.uri is the port alone ("5600"): QGroundControl builds
udp://0.0.0.0:<uri> from it (PX4's reference and QGC's VideoManager).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Coroutine
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.types import CommandResult, Outcome, Severity
from viva_sitl.dynamics import quat_from_euler
from viva_sitl.mavlink.base import (
    CommandRequest,
    Component,
    MavMessage,
    Origin,
    Outbox,
    StatusSink,
    VehicleLink,
    clamp_int,
    fixed_bytes,
    time_boot_ms,
)
from viva_sitl.mavlink.camera_link import (
    DEFAULT_CAMERA_INFO,
    CameraInfo,
    CameraLink,
    CaptureResult,
)

log = logging.getLogger(__name__)
M = mavlink2


# Commands that belong to the camera component (answered by compid 100 when broadcast)
CAMERA_COMMANDS = {
    M.MAV_CMD_IMAGE_START_CAPTURE,
    M.MAV_CMD_IMAGE_STOP_CAPTURE,
    M.MAV_CMD_REQUEST_CAMERA_INFORMATION,
    M.MAV_CMD_REQUEST_CAMERA_SETTINGS,
    M.MAV_CMD_REQUEST_STORAGE_INFORMATION,
    M.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS,
    M.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION,
    M.MAV_CMD_REQUEST_VIDEO_STREAM_STATUS,
    M.MAV_CMD_SET_CAMERA_MODE,
    M.MAV_CMD_VIDEO_START_STREAMING,
    M.MAV_CMD_VIDEO_STOP_STREAMING,
    M.MAV_CMD_STORAGE_FORMAT,
    M.MAV_CMD_RESET_CAMERA_SETTINGS,
}
CAMERA_MESSAGES = {
    M.MAVLINK_MSG_ID_CAMERA_INFORMATION,
    M.MAVLINK_MSG_ID_CAMERA_SETTINGS,
    M.MAVLINK_MSG_ID_STORAGE_INFORMATION,
    M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS,
    M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED,
    M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION,
    M.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS,
}
MAX_INTERVAL_CAPTURES = 10_000


def is_camera_command(req: CommandRequest) -> bool:
    if req.command in CAMERA_COMMANDS:
        return True
    return (
        req.command == M.MAV_CMD_REQUEST_MESSAGE and math.isfinite(req.p1) and int(req.p1) in CAMERA_MESSAGES
    )


class CameraComponent:
    """The camera component's protocol state (capture counter, interval capture task)."""

    def __init__(self, vehicle: VehicleLink, camera: CameraLink, out: Outbox, statustext: StatusSink) -> None:
        self.vehicle = vehicle
        self.camera = camera
        self.out = out
        self.statustext = statustext
        self.image_count = 0  # images captured so far (CAMERA_IMAGE_CAPTURED.image_index of the next one)
        self.captures_failed = 0
        self._interval_task: asyncio.Task[None] | None = None
        self._interval_s = 0.0
        self._pending: set[asyncio.Task[None]] = set()
        self._last_captured: MavMessage | None = None
        self._warned_info = False

    # --- messages ---------------------------------------------------------------------------
    def heartbeat(self) -> MavMessage:
        return M.MAVLink_heartbeat_message(
            M.MAV_TYPE_CAMERA, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE, 3
        )

    def _info(self) -> CameraInfo:
        fn = getattr(self.camera, "camera_info", None)
        if callable(fn):
            info = fn()
            if isinstance(info, CameraInfo):
                return info
        if not self._warned_info:  # a CameraLink without camera_info(): answer with the defaults, say so once
            self._warned_info = True
            log.warning("camera link has no camera_info(); advertising %s", DEFAULT_CAMERA_INFO)
        return DEFAULT_CAMERA_INFO

    def camera_information(self) -> MavMessage:
        info = self._info()
        flags = M.CAMERA_CAP_FLAGS_CAPTURE_IMAGE | M.CAMERA_CAP_FLAGS_CAN_CAPTURE_IMAGE_IN_VIDEO_MODE
        if info.streams:
            flags |= M.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
        return M.MAVLink_camera_information_message(
            time_boot_ms(self.vehicle), fixed_bytes(info.vendor, 32), fixed_bytes(info.model, 32),
            info.firmware_version, info.focal_length_mm, info.sensor_width_mm, info.sensor_height_mm,
            info.width_px, info.height_px, 0, flags, 0, b"", 0, 0,
        )  # fmt: skip

    def camera_settings(self) -> MavMessage:
        return M.MAVLink_camera_settings_message(
            time_boot_ms(self.vehicle), M.CAMERA_MODE_IMAGE, math.nan, math.nan, 0
        )

    def storage_information(self) -> MavMessage:
        return M.MAVLink_storage_information_message(
            time_boot_ms(self.vehicle), 1, 1, M.STORAGE_STATUS_READY, 100_000.0, 0.0, 100_000.0, 100.0, 100.0,
            M.STORAGE_TYPE_OTHER, b"run dir", 0,
        )  # fmt: skip

    def capture_status(self) -> MavMessage:
        interval = self._interval_task is not None and not self._interval_task.done()
        return M.MAVLink_camera_capture_status_message(
            time_boot_ms(self.vehicle), 3 if interval else 0, 0, self._interval_s if interval else 0.0, 0,
            100_000.0, self.image_count, 0,
        )  # fmt: skip

    def video_stream_information(self, stream_id: int = 0) -> list[MavMessage]:
        streams = self._info().streams
        out = []
        for i, s in enumerate(streams, start=1):
            if stream_id not in (0, i):
                continue
            out.append(
                M.MAVLink_video_stream_information_message(
                    i,
                    len(streams),
                    s.stream_type,
                    M.VIDEO_STREAM_STATUS_FLAGS_RUNNING,
                    s.framerate_hz,
                    s.width_px,
                    s.height_px,
                    s.bitrate_bps,
                    0,
                    clamp_int(s.hfov_deg, 0, 359),
                    s.name.encode("ascii", errors="replace")[:32],
                    s.wire_uri.encode("ascii", errors="replace")[:160],
                    s.wire_encoding,
                    0,
                )  # fmt: skip
            )
        return out

    def video_stream_status(self, stream_id: int = 0) -> list[MavMessage]:
        streams = self._info().streams
        return [
            M.MAVLink_video_stream_status_message(
                i,
                M.VIDEO_STREAM_STATUS_FLAGS_RUNNING,
                s.framerate_hz,
                s.width_px,
                s.height_px,
                s.bitrate_bps,
                0,
                clamp_int(s.hfov_deg, 0, 359),
                0,
            )  # fmt: skip
            for i, s in enumerate(streams, start=1)
            if stream_id in (0, i)
        ]

    def request_message(self, msgid: int, params: tuple[float, ...]) -> list[MavMessage] | None:
        p2 = int(params[0]) if params and math.isfinite(params[0]) else 0
        if msgid == M.MAVLINK_MSG_ID_CAMERA_INFORMATION:
            return [self.camera_information()]
        if msgid == M.MAVLINK_MSG_ID_CAMERA_SETTINGS:
            return [self.camera_settings()]
        if msgid == M.MAVLINK_MSG_ID_STORAGE_INFORMATION:
            return [self.storage_information()]
        if msgid == M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS:
            return [self.capture_status()]
        if msgid == M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION:
            return self.video_stream_information(p2)
        if msgid == M.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS:
            return self.video_stream_status(p2)
        if msgid == M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED:
            return [self._last_captured] if self._last_captured is not None else None
        return None

    # --- commands ---------------------------------------------------------------------------
    def handle(self, origin: Origin, req: CommandRequest) -> None:
        try:
            outcome, followups = self._dispatch(origin, req)
        except Exception as exc:  # answered FAILED, logged: never a silent client timeout
            log.exception("camera command %d failed", req.command)
            outcome, followups = Outcome(CommandResult.FAILED, f"camera command failed: {exc}"), []
        ack = M.MAVLink_command_ack_message(
            req.command, int(outcome.result), 0, 0, origin.sysid, origin.compid
        )
        self.out.reply(origin, ack, Component.CAMERA)
        if outcome.result != CommandResult.ACCEPTED and outcome.reason:
            self.statustext(origin, Severity.WARNING, outcome.reason)
        for msg in followups:
            self.out.reply(origin, msg, Component.CAMERA)

    def _dispatch(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        ok = Outcome(CommandResult.ACCEPTED)
        legacy = {
            M.MAV_CMD_REQUEST_CAMERA_INFORMATION: M.MAVLINK_MSG_ID_CAMERA_INFORMATION,
            M.MAV_CMD_REQUEST_CAMERA_SETTINGS: M.MAVLINK_MSG_ID_CAMERA_SETTINGS,
            M.MAV_CMD_REQUEST_STORAGE_INFORMATION: M.MAVLINK_MSG_ID_STORAGE_INFORMATION,
            M.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS: M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS,
            M.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION: M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION,
            M.MAV_CMD_REQUEST_VIDEO_STREAM_STATUS: M.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS,
        }
        if req.command == M.MAV_CMD_REQUEST_MESSAGE:
            msgs = self.request_message(int(req.p1), req.params[1:])
            return (ok, msgs) if msgs is not None else (Outcome(CommandResult.UNSUPPORTED), [])
        if req.command in legacy:
            if req.p1 == 0 and req.command != M.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION:
                return ok, []  # param1 = 0: "do not send" in the legacy camera commands
            params = (
                (req.p1,)
                if req.command
                in (M.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION, M.MAV_CMD_REQUEST_VIDEO_STREAM_STATUS)
                else ()
            )
            return ok, self.request_message(legacy[req.command], params) or []
        if req.command == M.MAV_CMD_IMAGE_START_CAPTURE:
            return self._start_capture(origin, req), []
        if req.command == M.MAV_CMD_IMAGE_STOP_CAPTURE:
            self._stop_interval()
            return ok, []
        if req.command in (M.MAV_CMD_SET_CAMERA_MODE, M.MAV_CMD_VIDEO_START_STREAMING, M.MAV_CMD_VIDEO_STOP_STREAMING,
                           M.MAV_CMD_RESET_CAMERA_SETTINGS):  # fmt: skip
            return ok, []  # one mode, and the stream always runs
        return Outcome(CommandResult.UNSUPPORTED), []

    def _start_capture(self, origin: Origin, req: CommandRequest) -> Outcome:
        interval = req.p2 if math.isfinite(req.p2) else 0.0
        total = int(req.p3) if math.isfinite(req.p3) and req.p3 >= 0 else 1
        if total == 1 or interval <= 0:
            if self._interval_task is not None and not self._interval_task.done():
                return Outcome(CommandResult.TEMPORARILY_REJECTED, "Camera: interval capture running")
            self._spawn(self._capture_once())
            return Outcome(CommandResult.ACCEPTED)
        self._stop_interval()
        self._interval_s = interval
        count = total if total > 0 else MAX_INTERVAL_CAPTURES  # 0 = until IMAGE_STOP_CAPTURE
        self._interval_task = asyncio.get_running_loop().create_task(self._interval_loop(interval, count))
        return Outcome(CommandResult.ACCEPTED)

    def _spawn(self, coro: Coroutine[Any, Any, None]) -> None:
        task: asyncio.Task[None] = asyncio.get_running_loop().create_task(coro)
        self._pending.add(task)
        task.add_done_callback(self._pending.discard)

    async def _interval_loop(self, interval_s: float, count: int) -> None:
        for _ in range(count):
            await self._capture_once()
            await asyncio.sleep(interval_s)

    def _stop_interval(self) -> None:
        if self._interval_task is not None:
            self._interval_task.cancel()
            self._interval_task = None

    async def _capture_once(self) -> None:
        index = self.image_count
        self.image_count += 1
        try:
            result = await asyncio.to_thread(self.camera.capture_image, index)
        except Exception as exc:  # the camera failed: report a failed capture, keep the component alive
            log.exception("capture_image failed")
            result = CaptureResult(ok=False, path="", meta=None)
            self.statustext(None, Severity.ERROR, f"Camera: capture failed: {exc}")
        if not result.ok:
            self.captures_failed += 1
        msg = self.image_captured(index, result)
        self._last_captured = msg
        self.out.broadcast(msg, Component.CAMERA)

    def image_captured(self, index: int, result: CaptureResult) -> MavMessage:
        meta = result.meta
        state = self.vehicle.state
        geo = self.vehicle.geo
        if meta is not None:
            pos = meta.pos_ned_m
            att = meta.att_rpy_rad
        else:
            pos = (float(state.pos_ned_m[0]), float(state.pos_ned_m[1]), float(state.pos_ned_m[2]))
            att = (float(state.att_rpy_rad[0]), float(state.att_rpy_rad[1]), float(state.att_rpy_rad[2]))
        if (
            meta is not None
            and meta.lat_deg is not None
            and meta.lon_deg is not None
            and meta.alt_amsl_m is not None
        ):
            lat, lon, alt = meta.lat_deg, meta.lon_deg, meta.alt_amsl_m
        else:
            lat, lon, alt = geo.ned_to_global(*pos)
        home_down = float(self.vehicle.autopilot.home_ned_m[2])
        wall = meta.wall_time_s if meta is not None else time.time()
        url = ("file://" + result.path) if result.ok and result.path else ""
        return M.MAVLink_camera_image_captured_message(
            time_boot_ms(self.vehicle), int(wall * 1e6), 0,
            clamp_int(lat * 1e7, -900000000, 900000000), clamp_int(lon * 1e7, -1800000000, 1800000000),
            clamp_int(alt * 1000.0, -(2**31), 2**31 - 1), clamp_int((home_down - pos[2]) * 1000.0, -(2**31), 2**31 - 1),
            list(quat_from_euler(*att)), index, 1 if result.ok else 0, url.encode("utf-8", errors="replace")[:205],
        )  # fmt: skip

    async def stop(self) -> None:
        tasks = list(self._pending)
        if self._interval_task is not None:
            tasks.append(self._interval_task)
        for t in tasks:
            t.cancel()
        for t in tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
        self._interval_task = None
