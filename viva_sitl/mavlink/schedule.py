"""The endpoint's periodic duties, on the SIM clock (the vehicle calls `on_sim_step()` after every physics step):

    heartbeat (heartbeat_hz), telemetry (per-link stream tables, SET_MESSAGE_INTERVAL), housekeeping at
    HOUSEKEEPING_HZ (autopilot events -> STATUSTEXT / MISSION_ITEM_REACHED, mission retries, gimbal streams,
    MISSION_CURRENT / HEARTBEAT / EXTENDED_SYS_STATE / HOME_POSITION on change), the camera's interval capture.

`--speed N` therefore changes only the wall clock: ATTITUDE at 100 Hz is 100 messages per simulated second at any
speed, as in PX4 lockstep. One wall-clock task (`wall_loop`) keeps the link alive for clients' own (wall) timeouts
(a heartbeat at least once a wall second when the simulation runs slower than real time), flushes the .tlog and
drives a vehicle that never calls on_sim_step().
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.types import FlightMode, Severity
from viva_sitl.mavlink.base import Component, LinkKind, MavMessage, Origin, VehicleLink
from viva_sitl.mavlink.camera import CameraComponent
from viva_sitl.mavlink.config import EndpointStats, MavlinkConfig
from viva_sitl.mavlink.gimbal import GimbalManager
from viva_sitl.mavlink.links import Links
from viva_sitl.mavlink.mission import MissionProtocol
from viva_sitl.mavlink.telemetry import LinkStreams, TelemetryBuilder

log = logging.getLogger(__name__)
M = mavlink2

HOUSEKEEPING_HZ = 20.0  # per sim second
WALL_TICK_S = 0.05  # the wall-clock task's period
HEARTBEAT_MAX_WALL_GAP_S = 1.0  # MAVSDK/QGC drop a vehicle after 3 wall seconds without a heartbeat


def _advance(due_s: float, period_s: float, now_s: float) -> float:
    """The next due time of a periodic event: keeps the phase; after a gap, one period from now (no burst)."""
    due_s += period_s
    return due_s if due_s > now_s else now_s + period_s


class Schedule:
    """What goes out when, on the endpoint's clock (simulation seconds); sends through `links`."""

    def __init__(
        self,
        vehicle: VehicleLink,
        config: MavlinkConfig,
        stats: EndpointStats,
        links: Links,
        telemetry: TelemetryBuilder,
        clock: Callable[[], float],
    ) -> None:
        self.vehicle = vehicle
        self.config = config
        self.stats = stats
        self.links = links
        self.telemetry = telemetry
        self.clock = clock
        self.streams: dict[LinkKind, LinkStreams] = {}  # per link: SET_MESSAGE_INTERVAL's tables
        # set by the endpoint once built (they send through links and need the schedule's intervals first)
        self.mission: MissionProtocol | None = None
        self.camera: CameraComponent | None = None
        self.gimbal: GimbalManager | None = None
        self._last_mission_current: tuple[int, int] | None = None
        self._last_hb_state: tuple[bool, FlightMode] | None = None
        self._last_home: tuple[float, float, float] | None = None
        self._last_landed: int | None = None
        self._next_service_s = math.inf
        self._next_heartbeat_s = 0.0
        self._next_housekeeping_s = 0.0
        self._last_now_s = 0.0
        self._last_heartbeat_wall_s = -math.inf

    # --- stream tables (SET_MESSAGE_INTERVAL bookkeeping) ------------------------------------
    def add_link(self, kind: LinkKind, overrides_hz: dict[int, float]) -> None:
        """The stream table of a link that was just opened: its profile, the config's rate overrides."""
        cfg = self.config
        profile = cfg.api_profile if kind == LinkKind.API else cfg.gcs_profile
        self.streams[kind] = LinkStreams(profile, overrides_hz, set(self.telemetry.builders))

    def clear(self) -> None:
        self.streams.clear()

    def set_interval(self, origin: Origin, msgid: int, interval_us: float) -> bool:
        streams = self.streams.get(origin.link)
        return streams is not None and streams.set_interval(msgid, interval_us, self.clock())

    def get_interval(self, origin: Origin, msgid: int) -> int:
        if msgid == M.MAVLINK_MSG_ID_HEARTBEAT:
            return int(1e6 / self.config.heartbeat_hz)
        streams = self.streams.get(origin.link)
        return streams.interval_us(msgid) if streams is not None else 0

    def wake_at(self, t_s: float) -> None:
        """Service no later than sim time `t_s` (a new camera interval capture)."""
        self._next_service_s = min(self._next_service_s, t_s)

    # --- the sim-clock schedule -------------------------------------------------------------
    def start(self) -> None:
        """Every schedule from now (the links are open)."""
        now = self.clock()
        self.reset(now)
        self._last_now_s = now

    def on_sim_step(self) -> None:
        if not self.links.links:
            return
        now = self.clock()
        if now < self._last_now_s:  # the simulation was reset: restart every schedule from now
            self.reset(now)
        self._last_now_s = now
        if now >= self._next_service_s:
            self._service(now)

    def reset(self, now: float) -> None:
        self._next_heartbeat_s = self._next_housekeeping_s = now
        for streams in self.streams.values():
            for stream in streams.streams.values():
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
                self.stats.handler_errors += 1
            if now >= self._next_housekeeping_s:
                self._next_housekeeping_s = _advance(self._next_housekeeping_s, 1.0 / HOUSEKEEPING_HZ, now)
        if heartbeat_due:
            self.send_heartbeats()
            self._next_heartbeat_s = _advance(self._next_heartbeat_s, 1.0 / self.config.heartbeat_hz, now)
        if self.camera is not None and now >= self.camera.next_trigger_s:
            self.camera.on_sim_time(now)
        built: dict[int, MavMessage | None] = {}  # one build per message and instant, shared by the links
        for kind, link in self.links.links.items():
            streams = self.streams[kind]
            due = streams.due(now)
            self.stats.telemetry_late += streams.skipped
            streams.skipped = 0
            if not due:
                continue
            targets = self.links.targets(link, now)
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
                        self.stats.handler_errors += 1
                        built[msgid] = None
                        continue
                if msg is not None:
                    self.links.send(link, msg, Component.AUTOPILOT, targets)
        self._next_service_s = min(
            self._next_heartbeat_s,
            self._next_housekeeping_s,
            self.camera.next_trigger_s if self.camera is not None else math.inf,
            *(self.streams[kind].next_due_s() for kind in self.links.links),
        )

    def send_heartbeats(self) -> None:
        try:
            # the camera's first, the autopilot's last: MAVSDK's Follow Me plugin takes the mode from whichever
            # component's HEARTBEAT came last (a camera's base_mode 0 reads as "not following"), so the autopilot's
            # must be the latest one in every tick or set_target_location() answers NOT_ACTIVE
            if self.camera is not None:
                self.links.broadcast(self.camera.heartbeat(), Component.CAMERA)
            self.links.broadcast(self.telemetry.heartbeat())
        except Exception:
            log.exception("heartbeat failed")
            self.stats.handler_errors += 1
        self._last_heartbeat_wall_s = time.monotonic()

    async def wall_loop(self) -> None:
        """Wall-clock duties: a heartbeat at least once a wall second (a slow simulation must not look dead to
        MAVSDK's 3 s timeout), the .tlog flush, and the schedule for a vehicle that never calls on_sim_step()."""
        last_flush = time.monotonic()
        while True:
            await asyncio.sleep(WALL_TICK_S)
            wall = time.monotonic()
            try:
                if wall - self._last_heartbeat_wall_s >= HEARTBEAT_MAX_WALL_GAP_S:
                    self.send_heartbeats()
                self.on_sim_step()
                tlog = self.links.tlog
                if tlog is not None and wall - last_flush >= 1.0:
                    last_flush = wall
                    tlog.flush()
            except Exception:
                log.exception("endpoint wall tick failed")
                self.stats.handler_errors += 1

    def _housekeeping(self) -> None:
        ap = self.vehicle.autopilot
        out = self.links
        for event in ap.pop_events():
            out.statustext(None, int(event.severity), event.text)
            if event.mission_item_reached is not None:
                out.broadcast(
                    M.MAVLink_mission_item_reached_message(int(event.mission_item_reached) & 0xFFFF)
                )
        for action in ap.pop_payload_actions():  # mission camera items -> the camera component
            if self.camera is not None:
                outcome = self.camera.payload_action(action)
                if not outcome.ok and outcome.reason:
                    out.statustext(None, Severity.WARNING, outcome.reason)
            else:
                log.info("camera action %s dropped: no camera component", action.kind)
        if self.mission is not None:
            self.mission.poll(self.clock())
        if self.gimbal is not None:
            self.gimbal.poll(self.clock())
        current = (int(ap.mission_current_seq), len(ap.mission_items))
        if current != self._last_mission_current:
            self._last_mission_current = current
            out.broadcast(self.telemetry.mission_current())
        # state changes reach clients at once, not up to one stream period later (PX4 does the same for home)
        hb_state = (bool(ap.armed), ap.mode)
        if hb_state != self._last_hb_state:
            if self._last_hb_state is not None:
                out.broadcast(self.telemetry.heartbeat())
            self._last_hb_state = hb_state
        landed = int(ap.landed_state)
        if landed != self._last_landed:
            if self._last_landed is not None:
                out.broadcast(self.telemetry.extended_sys_state())
            self._last_landed = landed
        home = ap.home_ned_m
        home3 = (float(home[0]), float(home[1]), float(home[2]))
        if home3 != self._last_home:
            if self._last_home is not None:
                out.broadcast(self.telemetry.home_position())
            self._last_home = home3
