"""COMMAND_LONG / COMMAND_INT dispatch to the autopilot, with a COMMAND_ACK for every command.

Every command addressed to the autopilot component (or broadcast) is answered at once (PX4 and MAVSDK expect an ACK
within 0.5 s): the autopilot's Outcome becomes the ACK result, and a refusal's reason also goes out as STATUSTEXT.
Unknown commands are ACKed UNSUPPORTED. Altitudes follow PX4: COMMAND_LONG's param7 is AMSL; COMMAND_INT's z is read
in its frame (GLOBAL / GLOBAL_INT: AMSL, GLOBAL_RELATIVE_ALT(_INT): above home, TERRAIN: above the ground plane).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.types import CommandResult, FlightMode, Outcome, Severity
from viva_sitl.mavlink.base import CommandRequest, MavMessage, Origin, Outbox, StatusSink, VehicleLink

log = logging.getLogger(__name__)
M = mavlink2

FORCE_MAGIC = 21196  # COMPONENT_ARM_DISARM param2: force (arm without checks / disarm in the air = kill)

_AMSL_FRAMES = {M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT}
_RELATIVE_FRAMES = {M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
_TERRAIN_FRAMES = {M.MAV_FRAME_GLOBAL_TERRAIN_ALT, M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT}


# (origin, message id, request params p2..p7) -> messages to send, or None when this vehicle cannot produce it
RequestMessageFn = Callable[[Origin, int, tuple[float, ...]], "list[MavMessage] | None"]
# (origin, message id, interval_us) -> accepted
SetIntervalFn = Callable[[Origin, int, float], bool]
GetIntervalFn = Callable[[Origin, int], int]


def _ok(result: CommandResult, reason: str = "") -> Outcome:
    return Outcome(result, reason)


class CommandHandler:
    """The autopilot component's commands."""

    def __init__(
        self,
        vehicle: VehicleLink,
        out: Outbox,
        statustext: StatusSink,
        request_message: RequestMessageFn,
        set_interval: SetIntervalFn,
        get_interval: GetIntervalFn,
    ) -> None:
        self.vehicle = vehicle
        self.out = out
        self.statustext = statustext
        self.request_message = request_message
        self.set_interval = set_interval
        self.get_interval = get_interval
        self.acks_sent = 0
        self.handlers: dict[int, Callable[[Origin, CommandRequest], tuple[Outcome, list[MavMessage]]]] = {
            M.MAV_CMD_COMPONENT_ARM_DISARM: self._arm_disarm,
            M.MAV_CMD_NAV_TAKEOFF: self._takeoff,
            M.MAV_CMD_NAV_LAND: self._simple(lambda now: self.vehicle.autopilot.land(now)),
            M.MAV_CMD_NAV_RETURN_TO_LAUNCH: self._simple(
                lambda now: self.vehicle.autopilot.return_to_launch(now)
            ),
            M.MAV_CMD_DO_SET_MODE: self._set_mode,
            M.MAV_CMD_DO_REPOSITION: self._reposition,
            M.MAV_CMD_DO_ORBIT: self._orbit,
            M.MAV_CMD_DO_CHANGE_SPEED: self._change_speed,
            M.MAV_CMD_MISSION_START: self._mission_start,
            M.MAV_CMD_DO_SET_MISSION_CURRENT: self._set_mission_current,
            M.MAV_CMD_DO_FLIGHTTERMINATION: self._terminate,
            M.MAV_CMD_DO_SET_HOME: self._set_home,
            M.MAV_CMD_INJECT_FAILURE: self._inject_failure,
            M.MAV_CMD_REQUEST_MESSAGE: self._request_message,
            M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: self._request_fixed(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION),
            M.MAV_CMD_GET_HOME_POSITION: self._request_fixed(M.MAVLINK_MSG_ID_HOME_POSITION),
            M.MAV_CMD_SET_MESSAGE_INTERVAL: self._set_message_interval,
            M.MAV_CMD_GET_MESSAGE_INTERVAL: self._get_message_interval,
        }

    # --- entry points -------------------------------------------------------------------------
    def handle(self, origin: Origin, req: CommandRequest) -> None:
        handler = self.handlers.get(req.command)
        followups: list[MavMessage] = []
        if handler is None:
            outcome = _ok(CommandResult.UNSUPPORTED)
        else:
            try:
                outcome, followups = handler(origin, req)
            except (
                Exception
            ) as exc:  # a bug must still be answered: FAILED, logged, never a silent client timeout
                log.exception("command %d failed", req.command)
                outcome, followups = _ok(CommandResult.FAILED, f"command {req.command} failed: {exc}"), []
        self.ack(origin, req.command, outcome)
        for msg in followups:
            self.out.reply(origin, msg)

    def handle_set_mode_message(self, origin: Origin, msg: MavMessage) -> None:
        """SET_MODE (11): custom_mode as in HEARTBEAT. PX4 answers it like DO_SET_MODE (COMMAND_ACK 176)."""
        if not int(msg.base_mode) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            outcome = _ok(CommandResult.DENIED, "SET_MODE without custom mode flag")
        else:
            outcome = self._apply_mode_pair(
                (int(msg.custom_mode) >> 16) & 0xFF, (int(msg.custom_mode) >> 24) & 0xFF
            )
        self.ack(origin, M.MAV_CMD_DO_SET_MODE, outcome)

    def ack(self, origin: Origin, command: int, outcome: Outcome) -> None:
        self.out.reply(
            origin,
            M.MAVLink_command_ack_message(command, int(outcome.result), 0, 0, origin.sysid, origin.compid),
        )
        self.acks_sent += 1
        if outcome.result != CommandResult.ACCEPTED and outcome.reason:
            self.statustext(
                origin,
                Severity.WARNING if outcome.result != CommandResult.FAILED else Severity.ERROR,
                outcome.reason,
            )

    # --- helpers ----------------------------------------------------------------------------
    @property
    def _now(self) -> float:
        return float(self.vehicle.time_s)

    def _simple(
        self, fn: Callable[[float], Outcome]
    ) -> Callable[[Origin, CommandRequest], tuple[Outcome, list[MavMessage]]]:
        def run(origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
            return fn(self._now), []

        return run

    def _request_fixed(
        self, msgid: int
    ) -> Callable[[Origin, CommandRequest], tuple[Outcome, list[MavMessage]]]:
        def run(origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
            msgs = self.request_message(origin, msgid, ())
            if msgs is None:
                return _ok(CommandResult.UNSUPPORTED), []
            return _ok(CommandResult.ACCEPTED), msgs

        return run

    def _home_amsl_m(self) -> float:
        home_down = float(self.vehicle.autopilot.home_ned_m[2])
        return self.vehicle.geo.alt_amsl_m - home_down

    def _down_from_alt(self, alt_m: float, frame: int) -> float | None:
        """NED down of an altitude given in `frame`; None when NaN (keep current) or the frame is unknown."""
        if not math.isfinite(alt_m):
            return None
        if frame in _AMSL_FRAMES:
            return self.vehicle.geo.alt_amsl_m - alt_m
        if frame in _RELATIVE_FRAMES:
            return float(self.vehicle.autopilot.home_ned_m[2]) - alt_m
        if frame in _TERRAIN_FRAMES:
            return float(self.vehicle.autopilot.eav.ground_z_ned_m) - alt_m
        return None

    # --- handlers ---------------------------------------------------------------------------
    def _arm_disarm(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        ap = self.vehicle.autopilot
        if not math.isfinite(req.p1):
            return _ok(CommandResult.DENIED, "arm/disarm: param1 must be 0 or 1"), []
        force = math.isfinite(req.p2) and int(round(req.p2)) == FORCE_MAGIC
        if req.p1 >= 0.5:
            return ap.arm(self._now, force=force), []
        if force:
            return ap.kill(self._now), []
        return ap.disarm(self._now), []

    def _takeoff(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        ap = self.vehicle.autopilot
        down = self._down_from_alt(req.alt_m, req.frame)
        altitude: float | None = None
        if down is not None:
            altitude = float(ap.home_ned_m[2]) - down  # metres above home, as MIS_TAKEOFF_ALT
            if not altitude > 0.0:
                self.statustext(
                    origin, Severity.WARNING, "Takeoff altitude below home: using MIS_TAKEOFF_ALT"
                )
                altitude = None
        return ap.takeoff(self._now, altitude), []

    def _apply_mode_pair(self, main: int, sub: int) -> Outcome:
        try:
            mode = FlightMode.from_px4(main, sub)
        except ValueError:
            return _ok(CommandResult.DENIED, f"Unsupported mode main {main} sub {sub}")
        return self.vehicle.autopilot.set_mode(self._now, mode)

    def _set_mode(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        # base_mode bit 0x80 (armed) is how MAVSDK describes the current state, never an arming request
        if not (math.isfinite(req.p1) and math.isfinite(req.p2)):
            return _ok(CommandResult.DENIED, "DO_SET_MODE: mode is not finite"), []
        if not int(req.p1) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return _ok(CommandResult.DENIED, "DO_SET_MODE: only custom (PX4) modes are supported"), []
        sub = int(req.p3) if math.isfinite(req.p3) else 0
        return self._apply_mode_pair(int(req.p2), sub), []

    def _reposition(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        ap = self.vehicle.autopilot
        pos = self.vehicle.state.pos_ned_m
        north, east = float(pos[0]), float(pos[1])
        if math.isfinite(req.lat_deg) and math.isfinite(req.lon_deg):
            if not (-90.0 <= req.lat_deg <= 90.0 and -180.0 <= req.lon_deg <= 180.0):
                return _ok(CommandResult.DENIED, "Reposition: latitude/longitude out of range"), []
            north, east, _ = self.vehicle.geo.global_to_ned(
                req.lat_deg, req.lon_deg, self.vehicle.geo.alt_amsl_m
            )
        elif math.isfinite(req.lat_deg) != math.isfinite(req.lon_deg):
            return _ok(CommandResult.DENIED, "Reposition: give both latitude and longitude"), []
        down = self._down_from_alt(req.alt_m, req.frame)
        if down is None:
            if math.isfinite(req.alt_m):
                return _ok(CommandResult.DENIED, f"Reposition: unsupported frame {req.frame}"), []
            down = float(pos[2])
        yaw = math.radians(req.p4) if math.isfinite(req.p4) else None
        speed = req.p1 if math.isfinite(req.p1) and req.p1 > 0 else None
        # param2 bit 0 (MAV_DO_REPOSITION_FLAGS_CHANGE_MODE): switch to Hold; without it PX4 only moves an active Hold
        change_mode = math.isfinite(req.p2) and bool(int(req.p2) & M.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE)
        return ap.reposition(self._now, north, east, down, yaw, speed, change_mode=change_mode), []

    def _orbit(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        """MAV_CMD_DO_ORBIT: p1 radius (sign = direction), p2 speed, p3 ORBIT_YAW_BEHAVIOUR, lat/lon centre and
        AMSL altitude (NaN / unset: the current orbit's, or the vehicle's position and altitude)."""
        center: tuple[float, float] | None = None
        if math.isfinite(req.lat_deg) and math.isfinite(req.lon_deg):
            if not (-90.0 <= req.lat_deg <= 90.0 and -180.0 <= req.lon_deg <= 180.0):
                return _ok(CommandResult.DENIED, "Orbit: latitude/longitude out of range"), []
            north, east, _ = self.vehicle.geo.global_to_ned(
                req.lat_deg, req.lon_deg, self.vehicle.geo.alt_amsl_m
            )
            center = (north, east)
        # PX4's Orbit task reads param7 / z as AMSL whatever the frame (MAVSDK's do_orbit sends an absolute altitude
        # in a COMMAND_INT with frame GLOBAL_RELATIVE_ALT): do the same
        down = self._down_from_alt(req.alt_m, M.MAV_FRAME_GLOBAL)
        ap = self.vehicle.autopilot
        return ap.orbit(self._now, req.p1, req.p2, req.p3, center, down), []

    def _change_speed(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        # param2: speed (m/s), -1 = no change, -2 = back to the default (the autopilot reads both)
        if not math.isfinite(req.p2):
            return _ok(CommandResult.ACCEPTED), []  # nothing asked (MAVSDK fills unused params with NaN)
        return self.vehicle.autopilot.change_speed(self._now, req.p2), []

    def _mission_start(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        first = int(req.p1) if math.isfinite(req.p1) and req.p1 >= 0 else 0
        return self.vehicle.autopilot.mission_start(self._now, first), []

    def _set_mission_current(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        if not math.isfinite(req.p1) or req.p1 < 0:
            return _ok(CommandResult.DENIED, "Mission: invalid current item"), []
        return self.vehicle.autopilot.set_mission_current(int(req.p1)), []

    def _terminate(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        if math.isfinite(req.p1) and req.p1 > 0.5:
            return self.vehicle.autopilot.kill(self._now), []
        return _ok(CommandResult.ACCEPTED), []

    def _inject_failure(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        """MAV_CMD_INJECT_FAILURE: p1 FAILURE_UNIT, p2 FAILURE_TYPE, p3 instance (0: all), gated by SYS_FAILURE_EN
        as PX4 (DENIED, "Failure injection disabled"); the same Autopilot.inject_failure the trials' scenario
        failures take. Units PX4 SITL's simulators do not implement here are UNSUPPORTED (autopilot/failures.py)."""
        if not all(math.isfinite(v) for v in (req.p1, req.p2, req.p3)):
            return _ok(CommandResult.DENIED, "Failure injection: parameters not finite"), []
        unit, ftype, instance = round(req.p1), round(req.p2), round(req.p3)
        return self.vehicle.autopilot.inject_failure(self._now, unit, ftype, instance), []

    def _set_home(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        ap = self.vehicle.autopilot
        set_home = getattr(ap, "set_home", None)  # optional in the autopilot contract
        if set_home is None:
            return _ok(CommandResult.UNSUPPORTED, "DO_SET_HOME is not supported"), []
        if math.isfinite(req.p1) and req.p1 >= 0.5:
            pos = self.vehicle.state.pos_ned_m
            target = (float(pos[0]), float(pos[1]), float(pos[2]))
        else:
            if not (math.isfinite(req.lat_deg) and math.isfinite(req.lon_deg)):
                return _ok(CommandResult.DENIED, "DO_SET_HOME: position required"), []
            north, east, _ = self.vehicle.geo.global_to_ned(
                req.lat_deg, req.lon_deg, self.vehicle.geo.alt_amsl_m
            )
            down = self._down_from_alt(req.alt_m, req.frame)
            target = (north, east, down if down is not None else float(ap.home_ned_m[2]))
        outcome: Outcome = set_home(self._now, target)
        followups = self.request_message(origin, M.MAVLINK_MSG_ID_HOME_POSITION, ()) if outcome.ok else None
        return outcome, followups or []

    def _request_message(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        if not math.isfinite(req.p1) or req.p1 < 0:
            return _ok(CommandResult.DENIED, "REQUEST_MESSAGE: invalid message id"), []
        msgs = self.request_message(origin, int(req.p1), req.params[1:])
        if msgs is None:
            return _ok(CommandResult.UNSUPPORTED), []
        return _ok(CommandResult.ACCEPTED), msgs

    def _set_message_interval(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        if not (math.isfinite(req.p1) and math.isfinite(req.p2)) or req.p1 < 0:
            return _ok(CommandResult.DENIED, "SET_MESSAGE_INTERVAL: invalid parameters"), []
        if self.set_interval(origin, int(req.p1), req.p2):
            return _ok(CommandResult.ACCEPTED), []
        return _ok(CommandResult.UNSUPPORTED), []

    def _get_message_interval(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        if not math.isfinite(req.p1) or req.p1 < 0:
            return _ok(CommandResult.DENIED, "GET_MESSAGE_INTERVAL: invalid message id"), []
        msgid = int(req.p1)
        return _ok(CommandResult.ACCEPTED), [
            M.MAVLink_message_interval_message(msgid, self.get_interval(origin, msgid))
        ]
