"""The MAVLink endpoint: two UDP links (API 14540+i, GCS 14550) as PX4 SITL; the composition of three parts.

    links.py     transport: UDP sockets (or any Transport), per-peer parsers and signing, send/receive of bytes,
                 peers, the .tlog, charged-timing holds (hold_incoming / stamp_held / release_due)
    dispatch.py  protocol: message id -> handler -> concern modules: commands (COMMAND_LONG/INT, SET_MODE),
                 params, mission, ftp, logs, offboard setpoints, camera (compid 100), gimbal, follow target
    schedule.py  the SIM clock (the vehicle calls `on_sim_step()` after every physics step): heartbeat, telemetry
                 (per-link stream tables, SET_MESSAGE_INTERVAL), housekeeping, and one wall-clock task

Each link sends from its own local port to its configured remote (MAVSDK's udpin://:14540, QGC's 14550) and to every
peer that talked to it in the last `peer_timeout_s`; replies go to the peer that asked. No handler exception ever
escapes a datagram: it is logged and counted, and the vehicle keeps heartbeating. `start_on(transports)` runs the
same endpoint over other transports with no task of its own (the in-memory, sim-clock harness: mavlink/testing.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Mapping
from dataclasses import asdict
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.mavlink.base import Component, EventListener, LinkKind, MavMessage, Origin, VehicleLink
from viva_sitl.mavlink.calibration import CalibrationWorker
from viva_sitl.mavlink.camera import CameraComponent
from viva_sitl.mavlink.commands import CommandHandler
from viva_sitl.mavlink.config import EndpointStats, MavlinkConfig
from viva_sitl.mavlink.dispatch import Dispatcher
from viva_sitl.mavlink.follow_target import FollowTargetInput
from viva_sitl.mavlink.ftp import FtpServer
from viva_sitl.mavlink.gimbal import GimbalManager
from viva_sitl.mavlink.links import Address, Links, Transport
from viva_sitl.mavlink.logs import LogProtocol
from viva_sitl.mavlink.mission import MissionLimits, MissionProtocol
from viva_sitl.mavlink.params import ParamProtocol
from viva_sitl.mavlink.schedule import Schedule
from viva_sitl.mavlink.telemetry import TelemetryBuilder

__all__ = ["MavlinkEndpoint", "VehicleLink"]  # its config, counters and errors: viva_sitl.mavlink.config

log = logging.getLogger(__name__)
M = mavlink2


class MavlinkEndpoint:
    """PX4-SITL-compatible MAVLink endpoint for one vehicle. `await start()`, then `await stop()`."""

    def __init__(self, vehicle: VehicleLink, config: MavlinkConfig | None = None) -> None:
        self.vehicle = vehicle
        self.config = config if config is not None else MavlinkConfig()
        self.sysid = self.config.system_id
        self._stats = EndpointStats()
        self._tasks: list[asyncio.Task[None]] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self.signing = self.config.signing_state()
        self.links = Links(self.sysid, self.signing, self._stats, self.config.peer_timeout_s, self._now)
        statustext = self.links.statustext
        self.telemetry = TelemetryBuilder(vehicle, self.sysid)
        # looked up per call: Vehicle.reset replaces the autopilot
        self.telemetry.prearm_ok = lambda: bool(self.vehicle.autopilot.prearm_check(self.vehicle.time_s).ok)
        self.schedule = Schedule(vehicle, self.config, self._stats, self.links, self.telemetry, self._now)
        self.commands = CommandHandler(
            vehicle,
            self,
            statustext,
            self._request_message,
            self.schedule.set_interval,
            self.schedule.get_interval,
        )
        self.params = ParamProtocol(vehicle.autopilot.params, self, statustext)
        self.ftp = FtpServer(self)
        self.logs = LogProtocol(self)  # the app points it at the run's ULog (logs.set_source)
        self.calibration = CalibrationWorker(vehicle, statustext)
        self.commands.handlers[M.MAV_CMD_PREFLIGHT_CALIBRATION] = self.calibration.handle
        limits = MissionLimits(
            self.config.mission_max_items, self.config.mission_retry_s, self.config.mission_max_retries
        )
        self.mission = MissionProtocol(vehicle, self, statustext, limits)
        cam = vehicle.camera
        self.camera: CameraComponent | None = CameraComponent(vehicle, cam, self, statustext) if cam else None
        # Follow Me's target input (follow_target.py)
        self.follow_target = FollowTargetInput(vehicle, statustext)
        # the gimbal manager (gimbal.py): only for a `gimbal` camera mount (the autopilot then has a gimbal)
        self.gimbal: GimbalManager | None = None
        if getattr(vehicle.autopilot, "gimbal", None) is not None:
            self.gimbal = GimbalManager(vehicle, self, statustext, self.commands._down_from_alt)
            self.commands.handlers.update(self.gimbal.command_handlers())
        self.schedule.mission, self.schedule.camera, self.schedule.gimbal = (
            self.mission,
            self.camera,
            self.gimbal,
        )
        self.dispatch = Dispatcher(
            vehicle, self.sysid, self._stats, self, statustext, self._now, self.signing,
            telemetry=self.telemetry, commands=self.commands, params=self.params, ftp=self.ftp, logs=self.logs,
            mission=self.mission, camera=self.camera, follow_target=self.follow_target, gimbal=self.gimbal,
            wake_at=self.schedule.wake_at,
        )  # fmt: skip
        self.links.deliver = self.dispatch.dispatch

    # --- lifecycle --------------------------------------------------------------------------
    async def start(self) -> None:
        """Bind the UDP links, open the .tlog, start the schedule and the endpoint's tasks."""
        if self.links.links:
            raise RuntimeError("MavlinkEndpoint already started")
        loop = asyncio.get_running_loop()
        self._loop = loop
        overrides = self.config.overrides_hz()
        await self.links.bind_udp(self.config)
        self._opened(overrides)
        self._tasks = [
            loop.create_task(self.schedule.wall_loop(), name="mavlink-wall"),
            loop.create_task(self.params.run(), name="mavlink-params"),
        ]
        log.info(
            "MAVLink sysid %d: api %s -> %s, gcs %s -> %s",
            self.sysid, self.api_address, self.links.links[LinkKind.API].default_remote,
            self.gcs_address, self.links.links[LinkKind.GCS].default_remote,
        )  # fmt: skip

    def start_on(self, transports: Mapping[LinkKind, tuple[Transport, Address | None]]) -> None:
        """Start over the given transports ((transport, default remote) per link; they call `links.receive`)
        with no task: nothing runs on the wall clock, and the caller drives on_sim_step (mavlink/testing.py)."""
        if self.links.links:
            raise RuntimeError("MavlinkEndpoint already started")
        overrides = self.config.overrides_hz()
        for kind, (transport, remote) in transports.items():
            self.links.attach(kind, transport, remote)
        self._opened(overrides)

    def _opened(self, overrides: dict[int, float]) -> None:
        for kind in self.links.links:
            self.schedule.add_link(kind, overrides)
        if self.config.tlog_path:
            try:
                self.links.open_tlog(self.config.tlog_path)
            except OSError:
                self.schedule.clear()
                raise
        self.schedule.start()

    async def stop(self) -> None:
        tasks, self._tasks = self._tasks, []
        for t in tasks:
            t.cancel()
        for t in tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await t
        if self.camera is not None:
            await self.camera.stop()
        self.links.close()
        self.schedule.clear()
        self.links.close_tlog()

    @property
    def tlog_path(self) -> str | None:
        """The .tlog being written (None: none)."""
        tlog = self.links.tlog
        return str(tlog.path) if tlog is not None else None

    def peers_heard(self) -> list[tuple[str, tuple[str, int], float]]:
        """Each talking peer of each link: (link name "api"/"gcs", peer (host, port), seconds since it was last
        heard, on the endpoint's clock: simulation time). At most MAX_PEERS_PER_LINK a link; empty before start."""
        return self.links.peers_heard()

    @property
    def api_address(self) -> tuple[str, int]:
        """The bound local (host, port) of the API link (useful with port 0)."""
        return self.links.links[LinkKind.API].local_address

    @property
    def gcs_address(self) -> tuple[str, int]:
        return self.links.links[LinkKind.GCS].local_address

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
    def max_setpoint_gap_s(self) -> float:
        """The longest gap (sim s) between two offboard setpoints handled: what a pilot's stream looked like here."""
        return self.dispatch.max_setpoint_gap_s

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
        tlog = self.links.tlog
        if tlog is not None:
            out["tlog"] = {"path": str(tlog.path), "packets": tlog.packets, "failed": tlog.failed}
        out["signing"] = {"key_set": self.signing.key is not None, "sign_cfg": self.signing.sign_cfg}
        if self.camera is not None:
            out["images_captured"] = self.camera.image_count
        out["peers"] = {
            k.value: sorted(f"{a[0]}:{a[1]}" for a in link.peers) for k, link in self.links.links.items()
        }
        return out

    def add_event_listener(self, listener: EventListener) -> None:
        """Called with (text, severity) for every STATUSTEXT the vehicle sends (e.g. for the app's log)."""
        self.links.listeners.append(listener)

    # --- the clock, and sending (the concern modules' Outbox) ---------------------------------
    def _now(self) -> float:
        """The endpoint's clock: simulation seconds (the physics clock), so --speed changes only the wall clock."""
        t = float(self.vehicle.time_s)
        return t if math.isfinite(t) else 0.0

    def reply(self, origin: Origin, msg: MavMessage, component: Component = Component.AUTOPILOT) -> None:
        self.links.reply(origin, msg, component)

    def broadcast(self, msg: MavMessage, component: Component = Component.AUTOPILOT) -> None:
        self.links.broadcast(msg, component)

    def _request_message(
        self, origin: Origin, msgid: int, params: tuple[float, ...]
    ) -> list[MavMessage] | None:
        return self.dispatch.request_message(origin, msgid, params, self.schedule.get_interval)

    # --- the sim-clock schedule -------------------------------------------------------------
    def on_sim_step(self) -> None:
        """Call after every physics step, on the endpoint's loop: sends what is due at the new simulation time.

        Cheap when nothing is due (one comparison). Because every step is seen, message rates are exact per
        simulated second even when the physics task runs several steps in one batch (load, --speed > 1)."""
        self.schedule.on_sim_step()

    # --- charged timing (viva_sitl.timing): what the pilot sends while it computes takes effect later ----------
    def hold_incoming(self, on: bool) -> None:
        """Hold every received datagram instead of handling it (charged timing); `release_due` hands them on.
        Turning it off handles whatever is held at once."""
        self.links.hold_incoming(on)

    def stamp_held(self, due_s: float) -> int:
        """Give the held datagrams not yet stamped the simulation time they take effect at; returns how many."""
        return self.links.stamp_held(due_s)

    def release_due(self, now_s: float) -> None:
        """Handle the held datagrams stamped at or before simulation time `now_s`, in the order received."""
        self.links.release_due(now_s)
