"""The MAVLink endpoint: two UDP links (API 14540+i, GCS 14550) as PX4 SITL, owned asyncio tasks, dispatch.

    UDP datagram -> per-peer DatagramParser (reset per datagram) -> dispatch by message id -> concern modules:
        commands (COMMAND_LONG/INT, SET_MODE), params, mission, offboard (setpoints), camera (compid 100)
    on the SIM clock (the vehicle calls `on_sim_step()` after every physics step): heartbeat (1 Hz), telemetry
    (per-link stream tables, SET_MESSAGE_INTERVAL), housekeeping (autopilot events -> STATUSTEXT /
    MISSION_ITEM_REACHED, mission retries, MISSION_CURRENT on change), peer timeouts. `--speed N` therefore changes
    only the wall clock: ATTITUDE at 100 Hz is 100 messages per simulated second at any speed, as in PX4 lockstep.
    One wall-clock task keeps the link alive for clients' own (wall) timeouts (a heartbeat at least once a wall
    second when the simulation runs slower than real time), flushes the .tlog and drives a vehicle that never calls
    on_sim_step().

Each link sends from its own local port to its configured remote (MAVSDK's udpin://:14540, QGC's 14550) and to every
peer that talked to it in the last `peer_timeout_s`; replies go to the peer that asked. No handler exception ever
escapes a datagram: it is logged and counted, and the vehicle keeps heartbeating.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import math
import socket
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.types import FlightMode, Severity
from viva_sitl.mavlink.base import (
    Component,
    EventListener,
    LinkKind,
    MavMessage,
    Origin,
    VehicleLink,
    statustext_messages,
)
from viva_sitl.mavlink.calibration import CalibrationWorker
from viva_sitl.mavlink.camera import CameraComponent, is_camera_command
from viva_sitl.mavlink.codec import DatagramParser, Encoder
from viva_sitl.mavlink.commands import CommandHandler, CommandRequest
from viva_sitl.mavlink.config import EndpointStartError, EndpointStats, MavlinkConfig, PortInUseError
from viva_sitl.mavlink.follow_target import FollowTargetInput
from viva_sitl.mavlink.ftp import FtpServer
from viva_sitl.mavlink.gimbal import GimbalManager
from viva_sitl.mavlink.logs import LogProtocol
from viva_sitl.mavlink.mission import MissionLimits, MissionProtocol
from viva_sitl.mavlink.offboard import (
    Rejected,
    decode_attitude_target,
    decode_manual_control,
    decode_position_target_global,
    decode_position_target_local,
)
from viva_sitl.mavlink.params import ParamProtocol
from viva_sitl.mavlink.signing import SigningState
from viva_sitl.mavlink.telemetry import LinkStreams, TelemetryBuilder
from viva_sitl.mavlink.tlog import TlogWriter

__all__ = ["MavlinkEndpoint", "VehicleLink"]  # its config, counters and errors: viva_sitl.mavlink.config

log = logging.getLogger(__name__)
M = mavlink2

MAX_PARSERS_PER_LINK = 64  # per-peer parsers kept (LRU): a flood of source ports cannot grow memory
MAX_PEERS_PER_LINK = 16  # talking peers that receive telemetry; the longest silent one makes room
HOUSEKEEPING_HZ = 20.0  # per sim second
SETPOINT_WARN_INTERVAL_S = 5.0  # sim s: at most one STATUSTEXT per this for ignored setpoints
WALL_TICK_S = 0.05  # the wall-clock task's period
HEARTBEAT_MAX_WALL_GAP_S = 1.0  # MAVSDK/QGC drop a vehicle after 3 wall seconds without a heartbeat


class _UdpProtocol(asyncio.DatagramProtocol):
    def __init__(self, endpoint: MavlinkEndpoint, kind: LinkKind) -> None:
        self.endpoint = endpoint
        self.kind = kind

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:  # type: ignore[override]
        self.endpoint._on_datagram(self.kind, data, (str(addr[0]), int(addr[1])))

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable after sending to a remote that is not listening (yet): normal for UDP
        self.endpoint._stats.send_errors += 1


@dataclass
class _Link:
    kind: LinkKind
    transport: asyncio.DatagramTransport
    default_remote: tuple[str, int] | None
    streams: LinkStreams
    encoders: dict[Component, Encoder]
    signing: SigningState | None = None
    peers: dict[tuple[str, int], float] = field(default_factory=dict)  # talking peer -> last rx (monotonic)
    parsers: OrderedDict[tuple[str, int], DatagramParser] = field(default_factory=OrderedDict)

    def parser(self, addr: tuple[str, int]) -> DatagramParser:
        p = self.parsers.get(addr)
        if p is None:
            p = self.parsers[addr] = DatagramParser(self.signing)
            while len(self.parsers) > MAX_PARSERS_PER_LINK:
                self.parsers.popitem(last=False)
        else:
            self.parsers.move_to_end(addr)
        return p

    def heard(self, addr: tuple[str, int], now_s: float) -> None:
        self.peers[addr] = now_s
        if len(self.peers) > MAX_PEERS_PER_LINK:
            del self.peers[min(self.peers, key=self.peers.__getitem__)]

    def targets(self, now_s: float, timeout_s: float) -> list[tuple[str, int]]:
        out = [a for a, t in self.peers.items() if now_s - t <= timeout_s]
        if self.default_remote is not None and self.default_remote not in out:
            out.append(self.default_remote)
        return out

    @property
    def local_address(self) -> tuple[str, int]:
        sockname = self.transport.get_extra_info("sockname")
        return (str(sockname[0]), int(sockname[1]))


def _advance(due_s: float, period_s: float, now_s: float) -> float:
    """The next due time of a periodic event: keeps the phase; after a gap, one period from now (no burst)."""
    due_s += period_s
    return due_s if due_s > now_s else now_s + period_s


def _resolve(host: str, port: int) -> tuple[str, int]:
    """A numeric IPv4 address (sendto with a name would resolve it on every datagram)."""
    info = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    return (str(info[0][4][0]), int(info[0][4][1]))


class MavlinkEndpoint:
    """PX4-SITL-compatible MAVLink endpoint for one vehicle. `await start()`, then `await stop()`."""

    def __init__(self, vehicle: VehicleLink, config: MavlinkConfig | None = None) -> None:
        self.vehicle = vehicle
        self.config = config if config is not None else MavlinkConfig()
        self.sysid = self.config.system_id
        self._stats = EndpointStats()
        self._links: dict[LinkKind, _Link] = {}
        self._tasks: list[asyncio.Task[None]] = []
        self._listeners: list[EventListener] = []
        # charged timing: received datagrams wait in _held (due sim time, link, data, peer)
        self._holding = False
        self._held: deque[tuple[float | None, LinkKind, bytes, tuple[str, int]]] = deque()
        # the longest gap (sim s) between two offboard setpoints handled: what a pilot's stream looked like here
        self.max_setpoint_gap_s = 0.0
        self._last_setpoint_s: float | None = None
        self._statustext_id = 0
        self._last_setpoint_warn = -math.inf
        self._loop: asyncio.AbstractEventLoop | None = None
        self.signing = self.config.signing_state()
        self.telemetry = TelemetryBuilder(vehicle, self.sysid)
        # looked up per call: Vehicle.reset replaces the autopilot
        self.telemetry.prearm_ok = lambda: bool(self.vehicle.autopilot.prearm_check(self.vehicle.time_s).ok)
        self.commands = CommandHandler(
            vehicle, self, self._statustext, self._request_message, self._set_interval, self._get_interval
        )
        self.params = ParamProtocol(vehicle.autopilot.params, self, self._statustext)
        self.ftp = FtpServer(self)
        self.logs = LogProtocol(self)  # the app points it at the run's ULog (logs.set_source)
        self.calibration = CalibrationWorker(vehicle, self._statustext)
        self.commands.handlers[M.MAV_CMD_PREFLIGHT_CALIBRATION] = self.calibration.handle
        limits = MissionLimits(
            self.config.mission_max_items, self.config.mission_retry_s, self.config.mission_max_retries
        )
        self.mission = MissionProtocol(vehicle, self, self._statustext, limits)
        cam = vehicle.camera
        self.camera: CameraComponent | None = (
            CameraComponent(vehicle, cam, self, self._statustext) if cam else None
        )
        self._last_mission_current: tuple[int, int] | None = None
        self._last_hb_state: tuple[bool, FlightMode] | None = None
        self._last_home: tuple[float, float, float] | None = None
        self._last_landed: int | None = None
        self._next_service_s = math.inf
        self._next_heartbeat_s = 0.0
        self._next_housekeeping_s = 0.0
        self._last_now_s = 0.0
        self._last_heartbeat_wall_s = -math.inf
        self._tlog: TlogWriter | None = None
        self._handlers: dict[int, Callable[[_Link, Origin, MavMessage], None]] = {
            M.MAVLINK_MSG_ID_HEARTBEAT: self._on_heartbeat,
            M.MAVLINK_MSG_ID_COMMAND_LONG: self._on_command,
            M.MAVLINK_MSG_ID_COMMAND_INT: self._on_command,
            M.MAVLINK_MSG_ID_SET_MODE: self._on_set_mode,
            M.MAVLINK_MSG_ID_PARAM_REQUEST_LIST: self._targeted(
                lambda _lk, o, m: self.params.handle_request_list(o, m)
            ),
            M.MAVLINK_MSG_ID_PARAM_REQUEST_READ: self._targeted(
                lambda _lk, o, m: self.params.handle_request_read(o, m)
            ),
            M.MAVLINK_MSG_ID_PARAM_SET: self._targeted(lambda _lk, o, m: self.params.handle_set(o, m)),
            M.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL: self._targeted(lambda _lk, o, m: self.ftp.handle(o, m)),
            M.MAVLINK_MSG_ID_LOG_REQUEST_LIST: self._targeted(
                lambda _lk, o, m: self.logs.handle_request_list(o, m)
            ),
            M.MAVLINK_MSG_ID_LOG_REQUEST_DATA: self._targeted(
                lambda _lk, o, m: self.logs.handle_request_data(o, m)
            ),
            M.MAVLINK_MSG_ID_LOG_REQUEST_END: self._targeted(
                lambda _lk, o, m: self.logs.handle_request_end(o, m)
            ),
            M.MAVLINK_MSG_ID_LOG_ERASE: self._targeted(lambda _lk, o, m: self.logs.handle_erase(o, m)),
            M.MAVLINK_MSG_ID_MISSION_COUNT: self._targeted(
                lambda _lk, o, m: self.mission.handle_count(o, m, self._now())
            ),
            M.MAVLINK_MSG_ID_MISSION_ITEM: self._targeted(
                lambda _lk, o, m: self.mission.handle_item(o, m, self._now())
            ),
            M.MAVLINK_MSG_ID_MISSION_ITEM_INT: self._targeted(
                lambda _lk, o, m: self.mission.handle_item(o, m, self._now())
            ),
            M.MAVLINK_MSG_ID_MISSION_REQUEST_LIST: self._targeted(
                lambda _lk, o, m: self.mission.handle_request_list(o, m)
            ),
            M.MAVLINK_MSG_ID_MISSION_REQUEST: self._targeted(
                lambda _lk, o, m: self.mission.handle_request(o, m)
            ),
            M.MAVLINK_MSG_ID_MISSION_REQUEST_INT: self._targeted(
                lambda _lk, o, m: self.mission.handle_request(o, m)
            ),
            M.MAVLINK_MSG_ID_MISSION_ACK: self._targeted(lambda _lk, o, m: self.mission.handle_ack(o, m)),
            M.MAVLINK_MSG_ID_MISSION_CLEAR_ALL: self._targeted(
                lambda _lk, o, m: self.mission.handle_clear_all(o, m)
            ),
            M.MAVLINK_MSG_ID_MISSION_SET_CURRENT: self._targeted(
                lambda _lk, o, m: self.mission.handle_set_current(o, m)
            ),
            M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED: self._on_position_target,
            M.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT: self._on_position_target,
            M.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET: self._on_attitude_target,
            M.MAVLINK_MSG_ID_MANUAL_CONTROL: self._on_manual_control,
            M.MAVLINK_MSG_ID_PING: self._on_ping,
            M.MAVLINK_MSG_ID_TIMESYNC: self._on_timesync,
            M.MAVLINK_MSG_ID_SETUP_SIGNING: self._on_setup_signing,
        }
        # Follow Me's target input (follow_target.py)
        self.follow_target = FollowTargetInput(vehicle, self._statustext)
        self._handlers[M.MAVLINK_MSG_ID_FOLLOW_TARGET] = lambda _lk, o, m: self.follow_target.handle(o, m)
        # the gimbal manager (gimbal.py): only for a `gimbal` camera mount (the autopilot then has a gimbal)
        self.gimbal: GimbalManager | None = None
        if getattr(vehicle.autopilot, "gimbal", None) is not None:
            gm = self.gimbal = GimbalManager(vehicle, self, self._statustext, self.commands._down_from_alt)
            self.commands.handlers.update(gm.command_handlers())
            self._handlers[M.MAVLINK_MSG_ID_GIMBAL_MANAGER_SET_ATTITUDE] = self._targeted(
                lambda _lk, o, m: gm.handle_set_attitude(o, m)
            )
            self._handlers[M.MAVLINK_MSG_ID_GIMBAL_MANAGER_SET_PITCHYAW] = self._targeted(
                lambda _lk, o, m: gm.handle_set_pitchyaw(o, m)
            )

    # --- lifecycle --------------------------------------------------------------------------
    async def start(self) -> None:
        if self._links:
            raise RuntimeError("MavlinkEndpoint already started")
        loop = asyncio.get_running_loop()
        self._loop = loop
        cfg = self.config
        overrides = cfg.overrides_hz()
        builders = set(self.telemetry.builders)
        specs = (
            (
                LinkKind.API,
                cfg.api_local_port_resolved,
                cfg.api_remote_host,
                cfg.api_remote_port_resolved,
                cfg.api_profile,
            ),
            (
                LinkKind.GCS,
                cfg.gcs_local_port_resolved,
                cfg.gcs_remote_host,
                cfg.gcs_remote_port,
                cfg.gcs_profile,
            ),
        )
        remotes: dict[LinkKind, tuple[str, int] | None] = {}
        for kind, _, rhost, rport, _ in specs:
            try:
                remotes[kind] = _resolve(rhost, rport) if rport else None
            except OSError as exc:
                raise ValueError(
                    f"mavlink: cannot resolve the {kind.value} remote host {rhost!r}: {exc}"
                ) from exc
        try:
            for link_id, (kind, local_port, _, _, profile) in enumerate(specs):
                try:
                    transport, _ = await loop.create_datagram_endpoint(
                        lambda kind=kind: _UdpProtocol(self, kind),  # type: ignore[misc]
                        local_addr=(cfg.listen_host, local_port),
                        family=socket.AF_INET,
                    )
                except OSError as exc:
                    if exc.errno == errno.EADDRINUSE:
                        flag = "--api-local-port" if kind == LinkKind.API else "--gcs-local-port"
                        raise PortInUseError(
                            exc.errno,
                            f"UDP port {local_port} ({kind.value} link) on {cfg.listen_host} is already in use "
                            f"(another viva-sitl or PX4 SITL?): run with --instance N (N = 1, 2, ...) or {flag}",
                        ) from None
                    raise EndpointStartError(
                        exc.errno,
                        f"MAVLink endpoint cannot bind UDP {cfg.listen_host}:{local_port}: {exc.strerror or exc}",
                    ) from exc
                encoders = {c: Encoder(self.sysid, int(c), self.signing, link_id) for c in Component}
                streams = LinkStreams(profile, overrides, builders)
                self._links[kind] = _Link(kind, transport, remotes[kind], streams, encoders, self.signing)  # type: ignore[arg-type]
        except OSError:
            for link in self._links.values():
                link.transport.close()
            self._links.clear()
            raise
        if cfg.tlog_path:
            try:
                self._tlog = TlogWriter(cfg.tlog_path)
            except OSError as exc:
                for link in self._links.values():
                    link.transport.close()
                self._links.clear()
                raise EndpointStartError(
                    exc.errno, f"cannot create the tlog {cfg.tlog_path}: {exc.strerror or exc}"
                ) from exc
        self._reset_schedule(self._now())
        self._last_now_s = self._now()
        self._tasks = [
            loop.create_task(self._wall_loop(), name="mavlink-wall"),
            loop.create_task(self.params.run(), name="mavlink-params"),
        ]
        log.info(
            "MAVLink sysid %d: api %s -> %s, gcs %s -> %s",
            self.sysid, self.api_address, self._links[LinkKind.API].default_remote,
            self.gcs_address, self._links[LinkKind.GCS].default_remote,
        )  # fmt: skip

    async def stop(self) -> None:
        tasks, self._tasks = self._tasks, []
        for t in tasks:
            t.cancel()
        for t in tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await t
        if self.camera is not None:
            await self.camera.stop()
        for link in self._links.values():
            link.transport.close()
        self._links.clear()
        if self._tlog is not None:
            self._tlog.close()

    @property
    def tlog_path(self) -> str | None:
        """The .tlog being written (None: none)."""
        return str(self._tlog.path) if self._tlog is not None else None

    def peers_heard(self) -> list[tuple[str, tuple[str, int], float]]:
        """Each talking peer of each link: (link name "api"/"gcs", peer (host, port), seconds since it was last
        heard, on the endpoint's clock: simulation time). At most MAX_PEERS_PER_LINK a link; empty before start."""
        now = self._now()
        out: list[tuple[str, tuple[str, int], float]] = []
        for kind, link in self._links.items():
            for addr, heard in list(link.peers.items()):
                out.append((str(kind.value), addr, max(0.0, now - heard)))
        return out

    @property
    def api_address(self) -> tuple[str, int]:
        """The bound local (host, port) of the API link (useful with port 0)."""
        return self._links[LinkKind.API].local_address

    @property
    def gcs_address(self) -> tuple[str, int]:
        return self._links[LinkKind.GCS].local_address

    @property
    def rx_messages(self) -> int:
        """MAVLink messages received from any peer so far (a pilot that has said anything has connected)."""
        return self._stats.rx_messages

    @property
    def pilot_actions(self) -> int:
        """Commands, setpoints and manual inputs received so far: a counter that moves when a pilot acts."""
        st = self._stats
        return st.commands + st.setpoints_handled + st.setpoints_refused + st.manual_inputs

    @property
    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = asdict(self._stats)
        out["param_sets_accepted"] = self.params.sets_accepted
        out["param_sets_rejected"] = self.params.sets_rejected
        out["param_list_values_sent"] = self.params.list_values_sent
        out["ftp_requests"] = self.ftp.requests
        out["mission_uploads_completed"] = self.mission.uploads_completed
        out["mission_uploads_failed"] = self.mission.uploads_failed
        out["command_acks"] = self.commands.acks_sent
        if self._tlog is not None:
            out["tlog"] = {
                "path": str(self._tlog.path),
                "packets": self._tlog.packets,
                "failed": self._tlog.failed,
            }
        out["signing"] = {"key_set": self.signing.key is not None, "sign_cfg": self.signing.sign_cfg}
        if self.camera is not None:
            out["images_captured"] = self.camera.image_count
        out["peers"] = {
            k.value: sorted(f"{a[0]}:{a[1]}" for a in link.peers) for k, link in self._links.items()
        }
        return out

    def add_event_listener(self, listener: EventListener) -> None:
        """Called with (text, severity) for every STATUSTEXT the vehicle sends (e.g. for the app's log)."""
        self._listeners.append(listener)

    # --- sending (Outbox) -------------------------------------------------------------------
    def _now(self) -> float:
        """The endpoint's clock: simulation seconds (the physics clock), so --speed changes only the wall clock."""
        t = float(self.vehicle.time_s)
        return t if math.isfinite(t) else 0.0

    def _send(self, link: _Link, msg: MavMessage, component: Component, addrs: list[tuple[str, int]]) -> None:
        if not addrs:
            return
        try:
            buf = link.encoders[component].pack(msg)
        except Exception:  # a message we built with a bad field: a bug, logged; the loop goes on
            log.exception("cannot pack %s", msg.get_type())
            self._stats.handler_errors += 1
            return
        if self._tlog is not None:
            self._tlog.write(buf)
        for addr in addrs:
            try:
                link.transport.sendto(buf, addr)
            except OSError:
                self._stats.send_errors += 1
                continue
            self._stats.tx_messages += 1
            self._stats.tx_bytes += len(buf)

    def reply(self, origin: Origin, msg: MavMessage, component: Component = Component.AUTOPILOT) -> None:
        link = self._links.get(origin.link)
        if link is not None:
            self._send(link, msg, component, [origin.addr])

    def broadcast(self, msg: MavMessage, component: Component = Component.AUTOPILOT) -> None:
        now = self._now()
        for link in self._links.values():
            self._send(link, msg, component, link.targets(now, self.config.peer_timeout_s))

    def _statustext(self, origin: Origin | None, severity: int, text: str) -> None:
        """PX4 sends every STATUSTEXT on every link (a GCS sees why a script's command was refused); the peer that
        caused it gets it even when it is not (yet) a telemetry target."""
        self._statustext_id = (self._statustext_id + 1) % 0xFFFF
        now = self._now()
        for msg in statustext_messages(int(severity), text, self._statustext_id + 1):
            self.broadcast(msg)
            if origin is not None:
                link = self._links.get(origin.link)
                if link is not None and origin.addr not in link.targets(now, self.config.peer_timeout_s):
                    self.reply(origin, msg)
        for listener in self._listeners:
            with contextlib.suppress(Exception):
                listener(text, int(severity))

    # --- receiving --------------------------------------------------------------------------
    # --- charged timing (viva_sitl.timing): what the pilot sends while it computes takes effect later ----------
    def hold_incoming(self, on: bool) -> None:
        """Hold every received datagram instead of handling it (charged timing); `release_due` hands them on.
        Turning it off handles whatever is held at once."""
        self._holding = on
        if not on:
            held, self._held = self._held, deque()
            for _, kind, data, addr in held:
                self._handle_datagram(kind, data, addr)

    def stamp_held(self, due_s: float) -> int:
        """Give the held datagrams not yet stamped the simulation time they take effect at; returns how many."""
        n = 0
        last = self._held[0][0] if self._held and self._held[0][0] is not None else -math.inf
        for k, (due, kind, data, addr) in enumerate(self._held):
            if due is None:
                last = max(last, due_s)  # never before one received earlier: order is kept
                self._held[k] = (last, kind, data, addr)
                n += 1
            else:
                last = due
        return n

    def release_due(self, now_s: float) -> None:
        """Handle the held datagrams stamped at or before simulation time `now_s`, in the order received."""
        held = self._held
        while held and held[0][0] is not None and held[0][0] <= now_s:
            _, kind, data, addr = held.popleft()
            self._handle_datagram(kind, data, addr)

    def _setpoint_seen(self) -> None:
        now = self._now()
        if self._last_setpoint_s is not None and now >= self._last_setpoint_s:
            self.max_setpoint_gap_s = max(self.max_setpoint_gap_s, now - self._last_setpoint_s)
        self._last_setpoint_s = now

    def _on_datagram(self, kind: LinkKind, data: bytes, addr: tuple[str, int]) -> None:
        if self._holding:
            self._held.append((None, kind, data, addr))
            return
        self._handle_datagram(kind, data, addr)

    def _handle_datagram(self, kind: LinkKind, data: bytes, addr: tuple[str, int]) -> None:
        link = self._links.get(kind)
        if link is None:
            return
        st = self._stats
        st.rx_datagrams += 1
        st.rx_bytes += len(data)
        try:
            result = link.parser(addr).parse(data)
        except Exception:  # DatagramParser never raises by design; if it does, drop the datagram, keep going
            log.exception("datagram parser failed")
            st.handler_errors += 1
            return
        st.bad_frames += result.bad_frames
        st.garbage_bytes += result.garbage_bytes
        st.unknown_messages += result.unknown
        st.unsigned_rejected += result.unsigned_rejected
        if result.messages:
            link.heard(addr, self._now())
        tlog = self._tlog
        for msg in result.messages:
            st.rx_messages += 1
            if tlog is not None:
                tlog.write(bytes(msg.get_msgbuf()))
            handler = self._handlers.get(msg.get_msgId())
            if handler is None:
                st.ignored_messages += 1
                continue
            origin = Origin(kind, addr, msg.get_srcSystem(), msg.get_srcComponent())
            try:
                handler(link, origin, msg)
            except Exception:  # never let one message kill the endpoint: log with traceback and count
                log.exception("handler for %s failed", msg.get_type())
                st.handler_errors += 1

    def _for_us(self, msg: MavMessage, components: tuple[int, ...] = (0, Component.AUTOPILOT)) -> bool:
        ts = int(getattr(msg, "target_system", 0))
        tc = int(getattr(msg, "target_component", 0))
        return ts in (0, self.sysid) and tc in components

    def _targeted(
        self, fn: Callable[[_Link, Origin, MavMessage], None]
    ) -> Callable[[_Link, Origin, MavMessage], None]:
        def run(link: _Link, origin: Origin, msg: MavMessage) -> None:
            if self._for_us(msg):
                fn(link, origin, msg)
            else:
                self._stats.ignored_messages += 1

        return run

    # --- handlers ---------------------------------------------------------------------------
    def _on_heartbeat(self, link: _Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.type) == M.MAV_TYPE_GCS:
            self.vehicle.autopilot.gcs_heartbeat(self.vehicle.time_s)

    def _on_command(self, link: _Link, origin: Origin, msg: MavMessage) -> None:
        ts, tc = int(msg.target_system), int(msg.target_component)
        if ts not in (0, self.sysid):
            self._stats.ignored_messages += 1
            return
        req = (
            CommandRequest.from_int(msg)
            if msg.get_msgId() == M.MAVLINK_MSG_ID_COMMAND_INT
            else CommandRequest.from_long(msg)
        )
        self._stats.commands += 1
        if tc == Component.CAMERA or (tc == 0 and self.camera is not None and is_camera_command(req)):
            if self.camera is not None:
                self.camera.handle(origin, req)
                self._next_service_s = min(
                    self._next_service_s, self.camera.next_trigger_s
                )  # interval capture
            else:
                self._stats.ignored_messages += 1  # no camera component: nobody answers (as on a real bus)
            return
        if tc in (0, Component.AUTOPILOT):
            self.commands.handle(origin, req)
        else:
            self._stats.ignored_messages += 1

    def _on_set_mode(self, link: _Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.target_system) in (0, self.sysid):
            self.commands.handle_set_mode_message(origin, msg)

    def _setpoint_rejected(self, reason: str) -> None:
        self._stats.setpoints_rejected += 1
        now = self._now()
        if now - self._last_setpoint_warn >= SETPOINT_WARN_INTERVAL_S:
            self._last_setpoint_warn = now
            self._statustext(None, Severity.WARNING, f"Offboard setpoint ignored: {reason}")
        log.debug("setpoint ignored: %s", reason)

    def _on_position_target(self, link: _Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.target_system) not in (0, self.sysid):
            self._stats.ignored_messages += 1
            return
        ap = self.vehicle.autopilot
        if msg.get_msgId() == M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED:
            target = decode_position_target_local(msg, self.vehicle.state)
        else:
            home = ap.home_ned_m
            target = decode_position_target_global(
                msg,
                self.vehicle.geo,
                (float(home[0]), float(home[1]), float(home[2])),
                float(ap.eav.ground_z_ned_m),
            )
        if isinstance(target, Rejected):
            self._setpoint_rejected(target.reason)
            return
        outcome = ap.set_position_target(self.vehicle.time_s, target)
        self._stats.setpoints_handled += 1
        self._setpoint_seen()
        if not outcome.ok:
            self._stats.setpoints_refused += 1

    def _on_attitude_target(self, link: _Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.target_system) not in (0, self.sysid):
            self._stats.ignored_messages += 1
            return
        target = decode_attitude_target(msg)
        if isinstance(target, Rejected):
            self._setpoint_rejected(target.reason)
            return
        outcome = self.vehicle.autopilot.set_attitude_target(self.vehicle.time_s, target)
        self._stats.setpoints_handled += 1
        self._setpoint_seen()
        if not outcome.ok:
            self._stats.setpoints_refused += 1

    def _on_manual_control(self, link: _Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.target) != self.sysid:
            self._stats.ignored_messages += 1
            return
        manual = decode_manual_control(msg)
        if isinstance(manual, Rejected):
            self._setpoint_rejected(manual.reason)
            return
        self.telemetry.last_manual_input_s = self._now()
        self.vehicle.autopilot.set_manual_input(self.vehicle.time_s, manual)
        self._stats.manual_inputs += 1

    def _on_ping(self, link: _Link, origin: Origin, msg: MavMessage) -> None:
        # a request has target 0/0; a PING addressed to us is an answer to a ping we never send: ignore it
        if int(msg.target_system) == 0 and int(msg.target_component) == 0:
            self.reply(
                origin, M.MAVLink_ping_message(int(msg.time_usec), int(msg.seq), origin.sysid, origin.compid)
            )

    def _on_setup_signing(self, link: _Link, origin: Origin, msg: MavMessage) -> None:
        """SETUP_SIGNING (PX4): a message that got past the signature rules sets the key for every link."""
        if int(msg.target_system) not in (0, self.sysid) or int(msg.target_component) not in (
            0,
            Component.AUTOPILOT,
        ):
            self._stats.ignored_messages += 1
            return
        key = bytes(bytearray(msg.secret_key))
        self.signing.set_key(key, int(msg.initial_timestamp))
        text = "MAVLink signing key set" if self.signing.key is not None else "MAVLink signing key cleared"
        log.info("%s by %s:%d (sysid %d)", text, origin.addr[0], origin.addr[1], origin.sysid)
        self._statustext(origin, Severity.INFO, text)

    def _on_timesync(self, link: _Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.tc1) == 0:  # a request: answer with our clock (sim time since boot, ns; never 0)
            now_ns = max(1, int(self.vehicle.time_s * 1e9)) if math.isfinite(self.vehicle.time_s) else 1
            self.reply(origin, M.MAVLink_timesync_message(now_ns, int(msg.ts1)))

    # --- REQUEST_MESSAGE / intervals (for CommandHandler) ------------------------------------
    def _request_message(
        self, origin: Origin, msgid: int, params: tuple[float, ...]
    ) -> list[MavMessage] | None:
        if msgid == M.MAVLINK_MSG_ID_MESSAGE_INTERVAL:
            if not params or not math.isfinite(params[0]):
                return None
            target = int(params[0])
            return [M.MAVLink_message_interval_message(target, self._get_interval(origin, target))]
        if self.gimbal is not None:
            gimbal_msgs = self.gimbal.request_message(msgid)
            if gimbal_msgs is not None:
                return gimbal_msgs
        msg = self.telemetry.build(msgid)
        return [msg] if msg is not None else None

    def _set_interval(self, origin: Origin, msgid: int, interval_us: float) -> bool:
        link = self._links.get(origin.link)
        return link is not None and link.streams.set_interval(msgid, interval_us, self._now())

    def _get_interval(self, origin: Origin, msgid: int) -> int:
        if msgid == M.MAVLINK_MSG_ID_HEARTBEAT:
            return int(1e6 / self.config.heartbeat_hz)
        link = self._links.get(origin.link)
        return link.streams.interval_us(msgid) if link is not None else 0

    # --- the sim-clock schedule -------------------------------------------------------------
    def on_sim_step(self) -> None:
        """Call after every physics step, on the endpoint's loop: sends what is due at the new simulation time.

        Cheap when nothing is due (one comparison). Because every step is seen, message rates are exact per
        simulated second even when the physics task runs several steps in one batch (load, --speed > 1)."""
        if not self._links:
            return
        now = self._now()
        if now < self._last_now_s:  # the simulation was reset: restart every schedule from now
            self._reset_schedule(now)
        self._last_now_s = now
        if now >= self._next_service_s:
            self._service(now)

    def _reset_schedule(self, now: float) -> None:
        self._next_heartbeat_s = self._next_housekeeping_s = now
        for link in self._links.values():
            for stream in link.streams.streams.values():
                stream.next_due_s = now
        self._next_service_s = now

    def _service(self, now: float) -> None:
        heartbeat_due = now >= self._next_heartbeat_s
        if heartbeat_due or now >= self._next_housekeeping_s:
            # housekeeping before any heartbeat: the STATUSTEXT that explains a mode change (failsafe, ...) goes
            # out before the first heartbeat that shows the new mode, as a client reading both expects
            try:
                self._housekeeping()
            except Exception:
                log.exception("housekeeping failed")
                self._stats.handler_errors += 1
            if now >= self._next_housekeeping_s:
                self._next_housekeeping_s = _advance(self._next_housekeeping_s, 1.0 / HOUSEKEEPING_HZ, now)
        if heartbeat_due:
            self._send_heartbeats()
            self._next_heartbeat_s = _advance(self._next_heartbeat_s, 1.0 / self.config.heartbeat_hz, now)
        if self.camera is not None and now >= self.camera.next_trigger_s:
            self.camera.on_sim_time(now)
        timeout = self.config.peer_timeout_s
        built: dict[int, MavMessage | None] = {}  # one build per message and instant, shared by the links
        for link in self._links.values():
            due = link.streams.due(now)
            self._stats.telemetry_late += link.streams.skipped
            link.streams.skipped = 0
            if not due:
                continue
            targets = link.targets(now, timeout)
            if not targets:
                continue  # nobody listens on this link: keep the schedule, skip the work
            for msgid in due:
                if msgid in built:
                    msg = built[msgid]
                else:
                    try:
                        msg = built[msgid] = self.telemetry.build(msgid)
                    except Exception:
                        log.exception("building telemetry message %d failed", msgid)
                        self._stats.handler_errors += 1
                        built[msgid] = None
                        continue
                if msg is not None:
                    self._send(link, msg, Component.AUTOPILOT, targets)
        self._next_service_s = min(
            self._next_heartbeat_s,
            self._next_housekeeping_s,
            self.camera.next_trigger_s if self.camera is not None else math.inf,
            *(link.streams.next_due_s() for link in self._links.values()),
        )

    def _send_heartbeats(self) -> None:
        try:
            self.broadcast(self.telemetry.heartbeat())
            if self.camera is not None:
                self.broadcast(self.camera.heartbeat(), Component.CAMERA)
        except Exception:
            log.exception("heartbeat failed")
            self._stats.handler_errors += 1
        self._last_heartbeat_wall_s = time.monotonic()

    async def _wall_loop(self) -> None:
        """Wall-clock duties: a heartbeat at least once a wall second (a slow simulation must not look dead to
        MAVSDK's 3 s timeout), the .tlog flush, and the schedule for a vehicle that never calls on_sim_step()."""
        last_flush = time.monotonic()
        while True:
            await asyncio.sleep(WALL_TICK_S)
            wall = time.monotonic()
            try:
                if wall - self._last_heartbeat_wall_s >= HEARTBEAT_MAX_WALL_GAP_S:
                    self._send_heartbeats()
                self.on_sim_step()
                if self._tlog is not None and wall - last_flush >= 1.0:
                    last_flush = wall
                    self._tlog.flush()
            except Exception:
                log.exception("endpoint wall tick failed")
                self._stats.handler_errors += 1

    def _housekeeping(self) -> None:
        ap = self.vehicle.autopilot
        for event in ap.pop_events():
            self._statustext(None, int(event.severity), event.text)
            if event.mission_item_reached is not None:
                self.broadcast(
                    M.MAVLink_mission_item_reached_message(int(event.mission_item_reached) & 0xFFFF)
                )
        for action in ap.pop_payload_actions():  # mission camera items -> the camera component
            if self.camera is not None:
                outcome = self.camera.payload_action(action)
                if not outcome.ok and outcome.reason:
                    self._statustext(None, Severity.WARNING, outcome.reason)
            else:
                log.info("camera action %s dropped: no camera component", action.kind)
        self.mission.poll(self._now())
        if self.gimbal is not None:
            self.gimbal.poll(self._now())
        current = (int(ap.mission_current_seq), len(ap.mission_items))
        if current != self._last_mission_current:
            self._last_mission_current = current
            self.broadcast(self.telemetry.mission_current())
        # state changes reach clients at once, not up to one stream period later (PX4 does the same for home)
        hb_state = (bool(ap.armed), ap.mode)
        if hb_state != self._last_hb_state:
            if self._last_hb_state is not None:
                self.broadcast(self.telemetry.heartbeat())
            self._last_hb_state = hb_state
        landed = int(ap.landed_state)
        if landed != self._last_landed:
            if self._last_landed is not None:
                self.broadcast(self.telemetry.extended_sys_state())
            self._last_landed = landed
        home = ap.home_ned_m
        home3 = (float(home[0]), float(home[1]), float(home[2]))
        if home3 != self._last_home:
            if self._last_home is not None:
                self.broadcast(self.telemetry.home_position())
            self._last_home = home3
