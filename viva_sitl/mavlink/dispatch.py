"""The endpoint's protocol half: a received message -> its handler (message id table) -> a concern module.

    HEARTBEAT (GCS) -> autopilot.gcs_heartbeat        COMMAND_LONG/INT -> camera (compid 100) or commands
    SET_MODE -> commands                              PARAM_* -> params, FILE_TRANSFER_PROTOCOL -> ftp, LOG_* -> logs
    MISSION_* -> mission                              SET_POSITION/ATTITUDE_TARGET, MANUAL_CONTROL -> autopilot
    PING, TIMESYNC, SETUP_SIGNING: answered here      FOLLOW_TARGET, GIMBAL_MANAGER_* -> follow_target, gimbal

Messages addressed to another system or component are counted as ignored. No handler exception escapes: it is logged
and counted (handler_errors). Sending goes through the Outbox (links.py); nothing here touches a socket.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.types import Severity
from viva_sitl.mavlink.base import Component, MavMessage, Origin, Outbox, StatusSink, VehicleLink
from viva_sitl.mavlink.camera import CameraComponent, is_camera_command
from viva_sitl.mavlink.commands import CommandHandler, CommandRequest
from viva_sitl.mavlink.config import EndpointStats
from viva_sitl.mavlink.follow_target import FollowTargetInput
from viva_sitl.mavlink.ftp import FtpServer
from viva_sitl.mavlink.gimbal import GimbalManager
from viva_sitl.mavlink.links import Link
from viva_sitl.mavlink.logs import LogProtocol
from viva_sitl.mavlink.mission import MissionProtocol
from viva_sitl.mavlink.offboard import (
    Rejected,
    decode_attitude_target,
    decode_manual_control,
    decode_position_target_global,
    decode_position_target_local,
)
from viva_sitl.mavlink.params import ParamProtocol
from viva_sitl.mavlink.signing import SigningState
from viva_sitl.mavlink.telemetry import TelemetryBuilder

log = logging.getLogger(__name__)
M = mavlink2

SETPOINT_WARN_INTERVAL_S = 5.0  # sim s: at most one STATUSTEXT per this for ignored setpoints

Handler = Callable[[Link, Origin, MavMessage], None]


class Dispatcher:
    """The message -> handler table of one endpoint, and the handlers that are not a concern module's own."""

    def __init__(
        self,
        vehicle: VehicleLink,
        sysid: int,
        stats: EndpointStats,
        out: Outbox,
        statustext: StatusSink,
        clock: Callable[[], float],
        signing: SigningState,
        *,
        telemetry: TelemetryBuilder,
        commands: CommandHandler,
        params: ParamProtocol,
        ftp: FtpServer,
        logs: LogProtocol,
        mission: MissionProtocol,
        camera: CameraComponent | None,
        follow_target: FollowTargetInput,
        gimbal: GimbalManager | None,
        wake_at: Callable[[float], None],
    ) -> None:
        self.vehicle = vehicle
        self.sysid = sysid
        self.stats = stats
        self.out = out
        self.statustext = statustext
        self.clock = clock
        self.signing = signing
        self.telemetry = telemetry
        self.commands = commands
        self.camera = camera
        self.gimbal = gimbal
        self.wake_at = wake_at  # the schedule's: the camera's next interval capture is due at this sim time
        # the longest gap (sim s) between two offboard setpoints handled: what a pilot's stream looked like here
        self.max_setpoint_gap_s = 0.0
        self._last_setpoint_s: float | None = None
        self._last_setpoint_warn = -math.inf
        t = self._targeted
        self.handlers: dict[int, Handler] = {
            M.MAVLINK_MSG_ID_HEARTBEAT: self._on_heartbeat,
            M.MAVLINK_MSG_ID_COMMAND_LONG: self._on_command,
            M.MAVLINK_MSG_ID_COMMAND_INT: self._on_command,
            M.MAVLINK_MSG_ID_SET_MODE: self._on_set_mode,
            M.MAVLINK_MSG_ID_PARAM_REQUEST_LIST: t(params.handle_request_list),
            M.MAVLINK_MSG_ID_PARAM_REQUEST_READ: t(params.handle_request_read),
            M.MAVLINK_MSG_ID_PARAM_SET: t(params.handle_set),
            M.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL: t(ftp.handle),
            M.MAVLINK_MSG_ID_LOG_REQUEST_LIST: t(logs.handle_request_list),
            M.MAVLINK_MSG_ID_LOG_REQUEST_DATA: t(logs.handle_request_data),
            M.MAVLINK_MSG_ID_LOG_REQUEST_END: t(logs.handle_request_end),
            M.MAVLINK_MSG_ID_LOG_ERASE: t(logs.handle_erase),
            M.MAVLINK_MSG_ID_MISSION_COUNT: t(lambda o, m: mission.handle_count(o, m, self.clock())),
            M.MAVLINK_MSG_ID_MISSION_ITEM: t(lambda o, m: mission.handle_item(o, m, self.clock())),
            M.MAVLINK_MSG_ID_MISSION_ITEM_INT: t(lambda o, m: mission.handle_item(o, m, self.clock())),
            M.MAVLINK_MSG_ID_MISSION_REQUEST_LIST: t(mission.handle_request_list),
            M.MAVLINK_MSG_ID_MISSION_REQUEST: t(mission.handle_request),
            M.MAVLINK_MSG_ID_MISSION_REQUEST_INT: t(mission.handle_request),
            M.MAVLINK_MSG_ID_MISSION_ACK: t(mission.handle_ack),
            M.MAVLINK_MSG_ID_MISSION_CLEAR_ALL: t(mission.handle_clear_all),
            M.MAVLINK_MSG_ID_MISSION_SET_CURRENT: t(mission.handle_set_current),
            M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED: self._on_position_target,
            M.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT: self._on_position_target,
            M.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET: self._on_attitude_target,
            M.MAVLINK_MSG_ID_MANUAL_CONTROL: self._on_manual_control,
            M.MAVLINK_MSG_ID_PING: self._on_ping,
            M.MAVLINK_MSG_ID_TIMESYNC: self._on_timesync,
            M.MAVLINK_MSG_ID_SETUP_SIGNING: self._on_setup_signing,
            M.MAVLINK_MSG_ID_FOLLOW_TARGET: lambda _lk, o, m: follow_target.handle(o, m),
        }
        if gimbal is not None:
            self.handlers[M.MAVLINK_MSG_ID_GIMBAL_MANAGER_SET_ATTITUDE] = t(gimbal.handle_set_attitude)
            self.handlers[M.MAVLINK_MSG_ID_GIMBAL_MANAGER_SET_PITCHYAW] = t(gimbal.handle_set_pitchyaw)

    def dispatch(self, link: Link, origin: Origin, msg: MavMessage) -> None:
        """One received message to its handler (Links.deliver)."""
        handler = self.handlers.get(msg.get_msgId())
        if handler is None:
            self.stats.ignored_messages += 1
            return
        try:
            handler(link, origin, msg)
        except Exception:  # never let one message kill the endpoint: log with traceback and count
            log.exception("handler for %s failed", msg.get_type())
            self.stats.handler_errors += 1

    def _for_us(self, msg: MavMessage, components: tuple[int, ...] = (0, Component.AUTOPILOT)) -> bool:
        ts = int(getattr(msg, "target_system", 0))
        tc = int(getattr(msg, "target_component", 0))
        return ts in (0, self.sysid) and tc in components

    def _targeted(self, fn: Callable[[Origin, MavMessage], None]) -> Handler:
        def run(link: Link, origin: Origin, msg: MavMessage) -> None:
            if self._for_us(msg):
                fn(origin, msg)
            else:
                self.stats.ignored_messages += 1

        return run

    # --- handlers ---------------------------------------------------------------------------
    def _on_heartbeat(self, link: Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.type) == M.MAV_TYPE_GCS:
            self.vehicle.autopilot.gcs_heartbeat(self.vehicle.time_s)

    def _on_command(self, link: Link, origin: Origin, msg: MavMessage) -> None:
        ts, tc = int(msg.target_system), int(msg.target_component)
        if ts not in (0, self.sysid):
            self.stats.ignored_messages += 1
            return
        req = (
            CommandRequest.from_int(msg)
            if msg.get_msgId() == M.MAVLINK_MSG_ID_COMMAND_INT
            else CommandRequest.from_long(msg)
        )
        self.stats.commands += 1
        if tc == Component.CAMERA or (tc == 0 and self.camera is not None and is_camera_command(req)):
            if self.camera is not None:
                self.camera.handle(origin, req)
                self.wake_at(self.camera.next_trigger_s)  # interval capture
            else:
                self.stats.ignored_messages += 1  # no camera component: nobody answers (as on a real bus)
            return
        if tc in (0, Component.AUTOPILOT):
            self.commands.handle(origin, req)
        else:
            self.stats.ignored_messages += 1

    def _on_set_mode(self, link: Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.target_system) in (0, self.sysid):
            self.commands.handle_set_mode_message(origin, msg)

    def _setpoint_rejected(self, reason: str) -> None:
        self.stats.setpoints_rejected += 1
        now = self.clock()
        if now - self._last_setpoint_warn >= SETPOINT_WARN_INTERVAL_S:
            self._last_setpoint_warn = now
            self.statustext(None, Severity.WARNING, f"Offboard setpoint ignored: {reason}")
        log.debug("setpoint ignored: %s", reason)

    def _setpoint_seen(self) -> None:
        now = self.clock()
        if self._last_setpoint_s is not None and now >= self._last_setpoint_s:
            self.max_setpoint_gap_s = max(self.max_setpoint_gap_s, now - self._last_setpoint_s)
        self._last_setpoint_s = now

    def _on_position_target(self, link: Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.target_system) not in (0, self.sysid):
            self.stats.ignored_messages += 1
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
        self.stats.setpoints_handled += 1
        self._setpoint_seen()
        if not outcome.ok:
            self.stats.setpoints_refused += 1

    def _on_attitude_target(self, link: Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.target_system) not in (0, self.sysid):
            self.stats.ignored_messages += 1
            return
        target = decode_attitude_target(msg)
        if isinstance(target, Rejected):
            self._setpoint_rejected(target.reason)
            return
        outcome = self.vehicle.autopilot.set_attitude_target(self.vehicle.time_s, target)
        self.stats.setpoints_handled += 1
        self._setpoint_seen()
        if not outcome.ok:
            self.stats.setpoints_refused += 1

    def _on_manual_control(self, link: Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.target) != self.sysid:
            self.stats.ignored_messages += 1
            return
        manual = decode_manual_control(msg)
        if isinstance(manual, Rejected):
            self._setpoint_rejected(manual.reason)
            return
        self.telemetry.last_manual_input_s = self.clock()
        self.vehicle.autopilot.set_manual_input(self.vehicle.time_s, manual)
        self.stats.manual_inputs += 1

    def _on_ping(self, link: Link, origin: Origin, msg: MavMessage) -> None:
        # a request has target 0/0; a PING addressed to us is an answer to a ping we never send: ignore it
        if int(msg.target_system) == 0 and int(msg.target_component) == 0:
            self.out.reply(
                origin, M.MAVLink_ping_message(int(msg.time_usec), int(msg.seq), origin.sysid, origin.compid)
            )

    def _on_setup_signing(self, link: Link, origin: Origin, msg: MavMessage) -> None:
        """SETUP_SIGNING (PX4): a message that got past the signature rules sets the key for every link."""
        if int(msg.target_system) not in (0, self.sysid) or int(msg.target_component) not in (
            0,
            Component.AUTOPILOT,
        ):
            self.stats.ignored_messages += 1
            return
        key = bytes(bytearray(msg.secret_key))
        self.signing.set_key(key, int(msg.initial_timestamp))
        text = "MAVLink signing key set" if self.signing.key is not None else "MAVLink signing key cleared"
        log.info("%s by %s:%d (sysid %d)", text, origin.addr[0], origin.addr[1], origin.sysid)
        self.statustext(origin, Severity.INFO, text)

    def _on_timesync(self, link: Link, origin: Origin, msg: MavMessage) -> None:
        if int(msg.tc1) == 0:  # a request: answer with our clock (sim time since boot, ns; never 0)
            now_ns = max(1, int(self.vehicle.time_s * 1e9)) if math.isfinite(self.vehicle.time_s) else 1
            self.out.reply(origin, M.MAVLink_timesync_message(now_ns, int(msg.ts1)))

    # --- REQUEST_MESSAGE (for CommandHandler) --------------------------------------------------
    def request_message(
        self, origin: Origin, msgid: int, params: tuple[float, ...], interval_us: Callable[[Origin, int], int]
    ) -> list[MavMessage] | None:
        if msgid == M.MAVLINK_MSG_ID_MESSAGE_INTERVAL:
            if not params or not math.isfinite(params[0]):
                return None
            target = int(params[0])
            return [M.MAVLink_message_interval_message(target, interval_us(origin, target))]
        if self.gimbal is not None:
            gimbal_msgs = self.gimbal.request_message(msgid)
            if gimbal_msgs is not None:
                return gimbal_msgs
        msg = self.telemetry.build(msgid)
        return [msg] if msg is not None else None
