"""The dashboard's aiohttp server, running in the app's asyncio loop (no thread of its own).

Routes:  /                 the page (static/index.html; plain ES modules, no build step)
         /static/...       its scripts and style
         /api/info         what does not change (footage size, camera, modes, keys, layers)
         /api/state        one telemetry snapshot (the JSON the page gets 10 times a second)
         /api/overview.jpg footage crop ?x0&y0&x1&y1 (footage px) &w&h (output px, <= overview_max_px)
         /ws               JSON both ways: telemetry, STATUSTEXT, acks out; commands, sticks, control in
         /ws/vac           binary VAC frames out (see vac.py for the format)

Every page message is validated (control.py); malformed ones are ignored, counted and answered with an error,
never raised. Telemetry and VAC frames go to each page through a one-message slot (latest wins, drops counted), so a
slow or stalled browser never makes the loop wait.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import json
import logging
import math
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import asdict
from importlib import resources
from typing import Any
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web

from viva_sitl.autopilot import FlightMode, MissionCommand
from viva_sitl.camera.projection import footprint_px
from viva_sitl.dashboard.config import DashboardConfig
from viva_sitl.dashboard.control import DIRECT, SELECTABLE_MODES, Controller
from viva_sitl.dashboard.overview import (
    AnnotationLayer,
    CropRequest,
    LayerProvider,
    OverviewImages,
)
from viva_sitl.dashboard.vac import VacOutput

log = logging.getLogger(__name__)

MAX_WS_MESSAGE_BYTES = 16 * 1024
STATUSTEXT_KEPT = 100
TRAIL_POINTS = 1200
TRAIL_PERIOD_S = 0.25  # wall seconds between trail points
PEER_LOST_S = 3.0  # a MAVLink peer silent this long shows as lost
SLOW_STATS_PERIOD_S = 1.0  # pipeline / scheduler statistics (percentiles) are refreshed this often

KEYS_HELP: tuple[tuple[str, str], ...] = (
    ("W / S or Up / Down", "pitch: forward / back (Position: fly forward / back)"),
    ("A / D or Left / Right", "roll: left / right"),
    ("Q / E", "yaw: left / right"),
    ("R / F", "throttle: up / down (centred = hold altitude)"),
    ("C", "take control (this page steers; other pages become read-only)"),
    ("M", "arm"),
    ("T", "take off"),
    ("L", "land"),
    ("H", "hold"),
    ("B", "return to launch"),
    ("K", "kill (press Confirm)"),
    ("1 / 2 / 3 / 4", "Position / Altitude / Stabilized / Direct mode"),
)


class DashboardError(ValueError):
    """The dashboard cannot start (e.g. the port chosen with --dashboard-port is in use)."""


class _Client:
    def __init__(self, cid: int, ws: web.WebSocketResponse) -> None:
        self.id = cid
        self.ws = ws
        self.pending: str | bytes | None = None  # the one message waiting for this page (latest wins)
        self.wakeup = asyncio.Event()
        self.dropped = 0
        self.sent = 0

    def offer(self, msg: str | bytes) -> None:
        if self.pending is not None:
            self.dropped += 1
        self.pending = msg
        self.wakeup.set()

    async def pump(self) -> None:
        while not self.ws.closed:
            await self.wakeup.wait()
            self.wakeup.clear()
            msg, self.pending = self.pending, None
            if msg is None:
                continue
            try:
                if isinstance(msg, bytes):
                    await self.ws.send_bytes(msg)
                else:
                    await self.ws.send_str(msg)
            except (ConnectionError, RuntimeError):
                return
            self.sent += 1


def _r(v: float, nd: int = 3) -> float | None:
    return round(float(v), nd) if math.isfinite(v) else None


class Dashboard:
    """The web dashboard of one vehicle (the app: SitlApp or anything with the same attributes)."""

    def __init__(
        self, app: Any, config: DashboardConfig, layers: Sequence[LayerProvider] = (), replay: bool = False
    ) -> None:
        """`replay`: `app` is a replay.ReplayApp (a recorded run with a time slider; flying disabled)."""
        self.app = app
        self.replay = replay
        self.config = config
        self.vac = VacOutput(config.jpeg_quality)
        footage = app.sim.footage
        self.geometry = footage.geometry
        self.layers: list[LayerProvider] = [AnnotationLayer(footage), *layers]
        self.controller = Controller(
            get_autopilot=lambda: app.autopilot,
            sim_time_s=lambda: float(app.time_s),
            yaw_rad=lambda: float(app.state.yaw_rad),
            stick_timeout_s=config.stick_timeout_s,
            statustext=self._send_statustext,
        )
        self.overview = OverviewImages(app.config.footage, self.geometry, config.jpeg_quality)
        self.statustexts: deque[dict[str, Any]] = deque(maxlen=STATUSTEXT_KEPT)
        self.trail: deque[tuple[float, float]] = deque(maxlen=TRAIL_POINTS)
        self._trail_next_s = 0.0
        if replay:  # the whole recorded path; the VAC panel gets the replay's re-rendered frames
            self.trail.extend(
                tuple(round(v, 1) for v in self.geometry.ned_to_px(n, e))  # type: ignore[misc]
                for n, e in app.trail_ned(TRAIL_POINTS)
            )
            app.vac = self.vac
        self._clients: dict[int, _Client] = {}
        self._vac_clients: dict[int, _Client] = {}
        self._next_id = 1
        self._tasks: list[asyncio.Task[None]] = []
        self._runner: web.AppRunner | None = None
        self.url = ""
        self.bad_messages = 0
        self.vac_page_drops = 0
        self._slow_stats: dict[str, Any] = {}
        self._slow_next_s = 0.0
        self._rate_ref: tuple[float, float] | None = None  # (wall, sim) for the measured speed factor
        self._measured_speed = math.nan
        self._web = web.Application(client_max_size=64 * 1024)
        static = resources.files("viva_sitl.dashboard") / "static"
        self._static_dir = str(static)
        self._web.add_routes(
            [
                web.get("/", self._index),
                web.get("/api/info", self._info),
                web.get("/api/state", self._state),
                web.get("/api/overview.jpg", self._overview_jpg),
                web.get("/ws", self._ws),
                web.get("/ws/vac", self._ws_vac),
                web.static("/static", self._static_dir, show_index=False),
            ]
        )

    # --- lifecycle ---------------------------------------------------------------------------
    async def start(self) -> None:
        cfg = self.config
        endpoint = getattr(self.app, "endpoint", None)
        if endpoint is not None:
            endpoint.add_event_listener(self._on_statustext)
        runner = web.AppRunner(self._web, access_log=None, handle_signals=False)
        await runner.setup()
        port = cfg.port_resolved
        try:
            site = web.TCPSite(runner, cfg.host, port)
            await site.start()
        except OSError as exc:
            if cfg.port_explicit or exc.errno not in (errno.EADDRINUSE, errno.EACCES):
                await runner.cleanup()
                raise DashboardError(
                    f"dashboard: cannot listen on {cfg.host}:{port}: {exc.strerror or exc}"
                    " (choose another with --dashboard-port, or --no-dashboard)"
                ) from None
            log.warning("dashboard: port %d is in use; serving on a free port instead", port)
            site = web.TCPSite(runner, cfg.host, 0)
            await site.start()
        self._runner = runner
        host, bound = runner.addresses[0][:2]
        shown = f"[{host}]" if ":" in str(host) else host
        self.url = f"http://{shown}:{bound}/"
        self.vac.attach(asyncio.get_running_loop(), self._publish_vac)
        self._tasks = [asyncio.create_task(self._telemetry_loop(), name="dashboard-telemetry")]
        if self.replay:
            self._tasks.append(asyncio.create_task(self.app.play_loop(), name="dashboard-replay"))
            self.app.request_render()
        else:
            self._tasks.append(asyncio.create_task(self._control_loop(), name="dashboard-control"))

    async def stop(self) -> None:
        self.vac.detach()
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._tasks = []
        for client in [*self._clients.values(), *self._vac_clients.values()]:
            with contextlib.suppress(Exception):
                await client.ws.close()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
        await asyncio.get_running_loop().run_in_executor(None, self.overview.close)

    def add_layer(self, provider: LayerProvider) -> None:
        """A toggleable overview layer (viva_sitl/world's ground truth, the trials' risk map); pages opened later
        list it (an open page picks it up on reload)."""
        self.layers.append(provider)

    def before_step(self, now_s: float) -> None:
        """The app calls this before every physics step (cheap when no page steers)."""
        self.controller.before_step(now_s)

    def _vac_drops(self) -> int:
        return self.vac_page_drops + sum(c.dropped for c in self._vac_clients.values())

    def stats(self) -> dict[str, Any]:
        c = self.controller.stats
        return {
            "pages": len(self._clients),
            "vac_pages": len(self._vac_clients),
            "bad_messages": self.bad_messages,
            "control": asdict(c),
            "vac_encoded": self.vac.encoded,
            "vac_page_drops": self._vac_drops(),
            "overview_crops": self.overview.crops_made,
        }

    # --- STATUSTEXT ---------------------------------------------------------------------------
    def _send_statustext(self, severity: int, text: str) -> None:
        endpoint = getattr(self.app, "endpoint", None)
        if endpoint is not None:  # out on every MAVLink link (the endpoint's listener brings it back here)
            endpoint.commands.statustext(None, severity, text)
        else:
            self._on_statustext(text, severity)

    def _on_statustext(self, text: str, severity: int) -> None:
        entry = {"sim_time_s": _r(float(self.app.time_s)), "severity": int(severity), "text": str(text)}
        self.statustexts.append(entry)
        msg = json.dumps({"t": "statustext", **entry})
        for client in self._clients.values():
            with contextlib.suppress(Exception):
                # statustexts are not latest-wins: send directly (rare, small)
                asyncio.get_running_loop().create_task(self._send_quiet(client, msg))

    @staticmethod
    async def _send_quiet(client: _Client, msg: str) -> None:
        with contextlib.suppress(ConnectionError, RuntimeError):
            await client.ws.send_str(msg)

    # --- telemetry ------------------------------------------------------------------------------
    def _links(self) -> list[dict[str, Any]]:
        endpoint = getattr(self.app, "endpoint", None)
        if endpoint is None:
            return []
        # ages are sim seconds (the endpoint's clock): a peer heard once a wall second is `speed` sim seconds apart
        lost_s = PEER_LOST_S * max(1.0, float(self.app.config.speed))
        return [
            {"link": link, "peer": f"{addr[0]}:{addr[1]}", "age_s": round(age, 1), "ok": age <= lost_s}
            for link, addr, age in endpoint.peers_heard()
        ]

    def _refresh_slow_stats(self) -> None:
        now = time.monotonic()
        if now < self._slow_next_s:
            return
        self._slow_next_s = now + SLOW_STATS_PERIOD_S
        app = self.app
        out: dict[str, Any] = {"render_late": 0, "video_dropped": 0}
        scheduler = getattr(app, "scheduler", None)
        if scheduler is not None:
            out["render_late"] = int(scheduler.stats().get("late_skipped", 0))
        video = getattr(app, "video", None)
        if video is not None:
            out["video_dropped"] = int(video.stats().get("dropped", 0))
        pacer = getattr(app, "pacer", None)
        out["physics_skipped"] = int(getattr(pacer, "skipped_steps", 0))
        sim_now = float(app.time_s)
        if self._rate_ref is not None and now - self._rate_ref[0] > 0.5:
            self._measured_speed = (sim_now - self._rate_ref[1]) / (now - self._rate_ref[0])
        self._rate_ref = (now, sim_now)
        self._slow_stats = out

    def snapshot(self) -> dict[str, Any]:
        """Everything the HUD and the overview show, as JSON-ready values (footage pixels for the overview)."""
        app = self.app
        ap = app.autopilot
        state = app.state
        endpoint = getattr(app, "endpoint", None)
        if endpoint is not None:  # the same numbers MAVLink telemetry carries
            snap = endpoint.telemetry.snapshot()
            pos, vel, rpy = snap.pos_ned_m, snap.vel_ned_m_s, snap.rpy_rad
        else:
            pos = tuple(float(v) for v in state.pos_ned_m)
            vel = tuple(float(v) for v in state.vel_ned_m_s)
            rpy = tuple(float(v) for v in state.att_rpy_rad)
        geom = self.geometry
        t = float(app.time_s)
        footage = app.sim.footage
        index = app.sim.footage_index(t)
        footage_t = app.sim.footage_time_s(t)  # the layers' ground truth runs on the footage clock
        n, e, d = pos
        yaw = rpy[2]
        ground_z = float(ap.eav.ground_z_ned_m)
        home = ap.home_ned_m
        vehicle_px = geom.ned_to_px(n, e)
        nose_px = geom.ned_to_px(n + 3.0 * math.cos(yaw), e + 3.0 * math.sin(yaw))
        vel_px = geom.ned_to_px(n + 2.0 * vel[0], e + 2.0 * vel[1])  # where it will be in 2 s
        mission = []
        for it in ap.mission_items:
            if it.command in (MissionCommand.DO_CHANGE_SPEED,) or not (
                math.isfinite(it.north_m) and math.isfinite(it.east_m)
            ):
                continue
            mission.append({"seq": it.seq, "px": list(geom.ned_to_px(it.north_m, it.east_m)),
                            "cmd": it.command.name})  # fmt: skip
        self._refresh_slow_stats()
        slow = self._slow_stats
        pilot = self.controller.pilot
        mode = ap.mode
        mode_name = DIRECT if (pilot.direct and mode == FlightMode.OFFBOARD) else mode.name
        layers = {}
        for layer in self.layers:
            if getattr(layer, "static", False):  # the same at every time: sent once, in /api/info
                continue
            try:
                layers[layer.name] = layer.features(footage_t, index)
            except Exception:  # a faulty provider must not take the HUD down
                log.exception("dashboard layer %s failed", layer.name)
                layers[layer.name] = []
        return {
            "t": "state",
            "sim_time_s": _r(t),
            "wall_time_s": time.time(),
            "speed": float(app.rate) if self.replay else float(app.config.speed),
            "measured_speed": None if self.replay else _r(self._measured_speed, 2),
            "mode": mode_name,
            "px4_mode": mode.name,
            "armed": bool(ap.armed),
            "landed_state": ap.landed_state.name,
            "pos_ned_m": [_r(v) for v in pos],
            "vel_ned_m_s": [_r(v) for v in vel],
            "att_deg": [_r(math.degrees(v), 2) for v in rpy],
            "alt_agl_m": _r(ground_z - d),
            "alt_rel_home_m": _r(float(home[2]) - d),
            "ground_speed_m_s": _r(math.hypot(vel[0], vel[1])),
            "vertical_speed_m_s": _r(-vel[2]),
            "heading_deg": _r(math.degrees(yaw) % 360.0, 2),
            "battery_pct": _r(100.0 * float(ap.battery_remaining), 1),
            "battery_v": _r(float(ap.battery_voltage_v), 2),
            "footage_frame": index,
            "footage_frames": int(footage.frame_count),
            "links": self._links(),
            "dropped": {**slow, "vac_page_drops": self._vac_drops()},
            "rc": {
                "feeding": pilot.feeding,
                "pilot_page": pilot.client_id,
                "sticks": asdict(self.controller.current_sticks(time.monotonic())),
            },
            "vehicle_px": list(vehicle_px),
            "nose_px": list(nose_px),
            "vel_px": list(vel_px),
            "home_px": list(geom.ned_to_px(float(home[0]), float(home[1]))),
            "footprint_px": footprint_px(geom, app.sim.camera, pos, rpy),
            "mission": mission,
            "mission_current": int(ap.mission_current_seq),
            "layers": layers,
            "dashboard": self.stats(),
            "replay": (
                {"time_s": _r(t), "playing": bool(app.playing), "rate": float(app.rate)}
                if self.replay
                else None
            ),
        }

    async def _telemetry_loop(self) -> None:
        period = 1.0 / self.config.telemetry_hz
        while True:
            try:
                now = time.monotonic()
                if (
                    now >= self._trail_next_s and not self.replay
                ):  # the trail is kept with no page open (cheap: one point)
                    self._trail_next_s = now + TRAIL_PERIOD_S
                    pos = self.app.state.pos_ned_m
                    vx, vy = self.geometry.ned_to_px(float(pos[0]), float(pos[1]))
                    if not self.trail or math.hypot(vx - self.trail[-1][0], vy - self.trail[-1][1]) > 0.5:
                        self.trail.append((round(vx, 1), round(vy, 1)))
                if self._clients:  # the full snapshot only for pages
                    msg = json.dumps(self.snapshot())
                    for client in self._clients.values():
                        client.offer(msg)
            except Exception:
                log.exception("dashboard telemetry failed")
            await asyncio.sleep(period)

    async def _control_loop(self) -> None:
        while True:
            try:
                self.controller.tick(time.monotonic())
            except Exception:
                log.exception("dashboard control feed failed")
            if not self.controller.pilot.feeding:  # nobody steers: nothing to feed, wake rarely
                await asyncio.sleep(0.1)
                continue
            # stick expiry and direct-mode yaw are updated often; the autopilot gets the sticks at every physics
            # step anyway (before_step)
            await asyncio.sleep(0.05)

    # --- VAC --------------------------------------------------------------------------------------
    def _publish_vac(self, msg: bytes, frame_counter: int) -> None:
        for client in self._vac_clients.values():
            client.offer(msg)

    # --- HTTP -------------------------------------------------------------------------------------
    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(f"{self._static_dir}/index.html", headers={"Cache-Control": "no-store"})

    async def _info(self, request: web.Request) -> web.Response:
        app = self.app
        cam = app.sim.camera
        g = self.geometry
        meta = app.sim.footage.metadata
        return web.json_response({
            "footage": {"name": meta.name, "width_px": g.width_px, "height_px": g.height_px,
                        "gsd_m_per_px": g.gsd_m_per_px, "frames": int(app.sim.footage.frame_count)},
            "camera": {"width_px": cam.width_px, "height_px": cam.height_px, "hfov_deg": cam.hfov_deg},
            "video": self.replay or getattr(app, "scheduler", None) is not None,
            "replay": app.info() if self.replay else None,
            "fps": int(app.config.video.fps),
            "sysid": int(app.config.mavlink.system_id),
            "modes": list(SELECTABLE_MODES),
            "keys": [list(k) for k in KEYS_HELP],
            "layers": [layer.name for layer in self.layers],
            "static_layers": self._static_layers(),
            "overview_max_px": self.config.overview_max_px,
            "trail": [list(p) for p in self.trail],
            "statustexts": list(self.statustexts),
        })  # fmt: skip

    def _static_layers(self) -> dict[str, list[dict[str, Any]]]:
        out: dict[str, list[dict[str, Any]]] = {}
        for layer in self.layers:
            if getattr(layer, "static", False):
                try:
                    out[layer.name] = layer.features(self.app.sim.footage_time_s(), 0)
                except Exception:
                    log.exception("dashboard layer %s failed", layer.name)
                    out[layer.name] = []
        return out

    async def _state(self, request: web.Request) -> web.Response:
        return web.json_response(self.snapshot())

    async def _overview_jpg(self, request: web.Request) -> web.Response:
        g = self.geometry
        try:
            req = CropRequest.parse(dict(request.query), g.width_px, g.height_px, self.config.overview_max_px)
        except ValueError as exc:
            raise web.HTTPBadRequest(text=f"overview: {exc}") from None
        index = self.app.sim.footage_index(float(self.app.time_s))
        try:
            data = await self.overview.crop(index, req)
        except Exception as exc:
            log.exception("overview crop failed")
            raise web.HTTPInternalServerError(text=f"overview: {exc}") from None
        return web.Response(body=data, content_type="image/jpeg",
                            headers={"Cache-Control": "no-store", "X-Footage-Frame": str(index)})  # fmt: skip

    # --- WebSockets -------------------------------------------------------------------------------
    def _new_id(self) -> int:
        cid = self._next_id
        self._next_id += 1
        return cid

    @staticmethod
    def _check_origin(request: web.Request) -> None:
        """Browsers send Origin on WebSocket upgrades: only this page's own origin may connect (another web site
        open in the same browser must not be able to arm or steer the vehicle). Programs send no Origin."""
        origin = request.headers.get("Origin")
        if origin is not None and urlsplit(origin).netloc.lower() != request.host.lower():
            raise web.HTTPForbidden(text=f"dashboard: WebSocket from origin {origin[:80]!r} refused")

    async def _ws(self, request: web.Request) -> web.WebSocketResponse:
        self._check_origin(request)
        ws = web.WebSocketResponse(max_msg_size=MAX_WS_MESSAGE_BYTES, heartbeat=10.0)
        await ws.prepare(request)
        client = _Client(self._new_id(), ws)
        self._clients[client.id] = client
        pump = asyncio.create_task(client.pump(), name=f"dashboard-page-{client.id}")
        try:
            await ws.send_str(
                json.dumps({"t": "hello", "client_id": client.id, "role": self._role(client.id)})
            )
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    await self._on_page_message(client, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    await self._bad(client, "binary messages are not understood")
                elif msg.type == WSMsgType.ERROR:
                    break
        finally:
            self._clients.pop(client.id, None)
            self.controller.client_gone(client.id)
            pump.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await pump
        return ws

    def _role(self, cid: int) -> str:
        return "pilot" if self.controller.is_pilot(cid) else "read-only"

    async def _bad(self, client: _Client, reason: str) -> None:
        """Count and answer a message that was ignored (sent at once: the telemetry slot must not replace it)."""
        self.bad_messages += 1
        await self._send_quiet(client, json.dumps({"t": "error", "reason": reason}))

    async def _reply(self, client: _Client, payload: dict[str, Any]) -> None:
        await self._send_quiet(client, json.dumps(payload))

    async def _on_page_message(self, client: _Client, data: str) -> None:
        try:
            msg = json.loads(data)
        except ValueError:
            self.controller.stats.malformed += 1
            await self._bad(client, "not JSON")
            return
        if not isinstance(msg, dict) or not isinstance(msg.get("t"), str):
            self.controller.stats.malformed += 1
            await self._bad(client, 'a message is a JSON object with a string "t"')
            return
        kind = msg["t"]
        ctl = self.controller
        if self.replay:
            if kind == "replay":
                reason = self._on_replay(msg)
                if reason is not None:
                    await self._bad(client, reason)
            elif kind == "ping":
                await self._reply(client, {"t": "pong", "wall_time_s": time.time()})
            elif kind in ("sticks", "cmd", "take_control", "release_control"):
                await self._bad(client, "replay: flying is disabled (this is a recorded run)")
            else:
                ctl.stats.malformed += 1
                await self._bad(client, f"unknown message type {kind[:40]!r}")
            return
        if kind == "sticks":
            reason = ctl.sticks(client.id, msg, time.monotonic())
            if reason is not None:
                await self._bad(client, reason)
        elif kind == "cmd":
            outcome = ctl.command(client.id, msg)
            mid = msg.get("id")
            await self._reply(client, {
                "t": "ack", "id": mid if isinstance(mid, int | str) else None, "cmd": str(msg.get("cmd"))[:40],
                "ok": outcome.ok, "result": outcome.result.name, "reason": outcome.reason,
            })  # fmt: skip
        elif kind == "take_control":
            prev = ctl.take_control(client.id)
            await self._reply(client, {"t": "role", "role": "pilot"})
            if prev is not None and prev in self._clients:
                await self._reply(self._clients[prev], {"t": "role", "role": "read-only",
                                                        "reason": f"page {client.id} took control"})  # fmt: skip
        elif kind == "release_control":
            if ctl.release_control(client.id):
                await self._reply(client, {"t": "role", "role": "read-only", "reason": "released"})
        elif kind == "ping":
            await self._reply(client, {"t": "pong", "wall_time_s": time.time()})
        else:
            ctl.stats.malformed += 1
            await self._bad(client, f"unknown message type {kind[:40]!r}")

    def _on_replay(self, msg: dict[str, Any]) -> str | None:
        """A replay control message; the reason when it is ignored."""
        app = self.app
        action = msg.get("action")
        if action == "play":
            if app.time_s >= app.recording.end_s:
                app.seek(app.recording.start_s)
            app.playing = True
        elif action == "pause":
            app.playing = False
        elif action == "seek":
            t = msg.get("time_s")
            if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t):
                return "replay seek: time_s must be a finite number"
            app.seek(float(t))
        elif action == "rate":
            r = msg.get("rate")
            if isinstance(r, bool) or not isinstance(r, int | float) or not 0.1 <= r <= 16.0:
                return "replay rate: a number in 0.1..16"
            app.rate = float(r)
        else:
            return "replay: action must be play, pause, seek or rate"
        return None

    async def _ws_vac(self, request: web.Request) -> web.WebSocketResponse:
        self._check_origin(request)
        ws = web.WebSocketResponse(max_msg_size=MAX_WS_MESSAGE_BYTES, heartbeat=10.0)
        await ws.prepare(request)
        client = _Client(self._new_id(), ws)
        self._vac_clients[client.id] = client
        self.vac.watchers = len(self._vac_clients)
        pump = asyncio.create_task(client.pump(), name=f"dashboard-vac-{client.id}")
        if self.replay:  # a frame for the new page at once (live runs render at the stream rate anyway)
            self.app.request_render()
        try:
            async for msg in ws:  # nothing is expected from the page; anything it sends is ignored
                if msg.type == WSMsgType.ERROR:
                    break
        finally:
            self._vac_clients.pop(client.id, None)
            self.vac_page_drops += client.dropped
            self.vac.watchers = len(self._vac_clients)
            pump.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await pump
        return ws
