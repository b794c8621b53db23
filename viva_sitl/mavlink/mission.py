"""Mission protocol: upload, download and clear (MISSION_COUNT / REQUEST_INT / ITEM_INT / ACK), MISSION_SET_CURRENT.

Upload is a state machine driven by the vehicle: after MISSION_COUNT it requests items in order (MISSION_REQUEST_INT,
or MISSION_REQUEST when the client sends float MISSION_ITEMs), re-requests an item after `retry_s` of silence and
gives up after `max_retries` (MISSION_ACK OPERATION_CANCELLED; the previous mission stays). A duplicate item is
ignored, an item ahead of the expected one is answered by requesting the expected one again (as PX4). The mission
reaches the autopilot only when the last item arrived and every item converted: the swap is atomic.

Items are converted to local NED through the GeoOrigin: frames GLOBAL(_INT) (AMSL), GLOBAL_RELATIVE_ALT(_INT) (above
home), GLOBAL_TERRAIN_ALT(_INT) (above the ground plane), LOCAL_NED and LOCAL_ENU (metres; MISSION_ITEM_INT carries
x/y * 1e4), MISSION (no position). A global item at lat = lon = 0 means "where the vehicle is" (NaN north/east), as
QGC writes TAKEOFF/LAND items without coordinates. The uploaded wire items are kept and returned on download as sent.
Only the mission type MISSION is stored; FENCE and RALLY downloads answer an empty list, uploads are refused.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.types import CommandResult, MissionCommand, MissionItem, Severity
from viva_sitl.mavlink.base import MavMessage, Origin, Outbox, StatusSink, VehicleLink

log = logging.getLogger(__name__)
M = mavlink2

_AMSL = {M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT}
_RELATIVE = {M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
_TERRAIN = {M.MAV_FRAME_GLOBAL_TERRAIN_ALT, M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT}
_GLOBAL = _AMSL | _RELATIVE | _TERRAIN
_LOCAL = {M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_LOCAL_ENU}
_POSITIONAL = {
    MissionCommand.NAV_WAYPOINT,
    MissionCommand.NAV_LOITER_TIME,
    MissionCommand.NAV_LAND,
    MissionCommand.NAV_TAKEOFF,
}


@dataclass(frozen=True)
class WireItem:
    """A mission item as MISSION_ITEM_INT carries it (x, y: degE7 for global frames, m * 1e4 for local frames)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float

    @classmethod
    def from_msg(cls, msg: MavMessage) -> WireItem:
        if msg.get_msgId() == M.MAVLINK_MSG_ID_MISSION_ITEM:  # float form: degrees / metres
            scale = 1e7 if int(msg.frame) in _GLOBAL else 1e4
            x = round(msg.x * scale) if math.isfinite(msg.x) else 0
            y = round(msg.y * scale) if math.isfinite(msg.y) else 0
        else:
            x, y = int(msg.x), int(msg.y)
        return cls(
            int(msg.seq), int(msg.frame), int(msg.command), int(msg.current), int(msg.autocontinue),
            float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4), x, y, float(msg.z),
        )  # fmt: skip

    def to_int_msg(self, target: Origin) -> MavMessage:
        return M.MAVLink_mission_item_int_message(
            target.sysid, target.compid, self.seq, self.frame, self.command, self.current, self.autocontinue,
            self.param1, self.param2, self.param3, self.param4, self.x, self.y, self.z, M.MAV_MISSION_TYPE_MISSION,
        )  # fmt: skip

    def to_float_msg(self, target: Origin) -> MavMessage:
        scale = 1e-7 if self.frame in _GLOBAL else 1e-4
        return M.MAVLink_mission_item_message(
            target.sysid, target.compid, self.seq, self.frame, self.command, self.current, self.autocontinue,
            self.param1, self.param2, self.param3, self.param4, self.x * scale, self.y * scale, self.z,
            M.MAV_MISSION_TYPE_MISSION,
        )  # fmt: skip


class ItemError(ValueError):
    """An item that cannot be flown; `result` is the MAV_MISSION_RESULT to answer with."""

    def __init__(self, result: int, text: str) -> None:
        super().__init__(text)
        self.result = result


def wire_to_item(w: WireItem, vehicle: VehicleLink) -> MissionItem:
    """Convert one wire item to the autopilot's local-NED MissionItem (raises ItemError)."""
    try:
        command = MissionCommand(w.command)
    except ValueError:
        raise ItemError(
            M.MAV_MISSION_UNSUPPORTED, f"Mission item {w.seq}: command {w.command} not supported"
        ) from None
    north = east = down = math.nan
    if command in _POSITIONAL:
        if w.frame in _GLOBAL:
            if not math.isfinite(w.z):
                raise ItemError(M.MAV_MISSION_INVALID_PARAM7, f"Mission item {w.seq}: altitude is not finite")
            lat, lon = w.x * 1e-7, w.y * 1e-7
            if not (-90.0 <= lat <= 90.0):
                raise ItemError(
                    M.MAV_MISSION_INVALID_PARAM5_X, f"Mission item {w.seq}: latitude out of range"
                )
            if not (-180.0 <= lon <= 180.0):
                raise ItemError(
                    M.MAV_MISSION_INVALID_PARAM6_Y, f"Mission item {w.seq}: longitude out of range"
                )
            geo = vehicle.geo
            if not (w.x == 0 and w.y == 0):
                north, east, _ = geo.global_to_ned(lat, lon, geo.alt_amsl_m)
            if w.frame in _AMSL:
                down = geo.alt_amsl_m - w.z
            elif w.frame in _RELATIVE:
                down = float(vehicle.autopilot.home_ned_m[2]) - w.z
            else:
                down = float(vehicle.autopilot.eav.ground_z_ned_m) - w.z
        elif w.frame in _LOCAL:
            if not math.isfinite(w.z):
                raise ItemError(M.MAV_MISSION_INVALID_PARAM7, f"Mission item {w.seq}: z is not finite")
            x_m, y_m = w.x * 1e-4, w.y * 1e-4
            if w.frame == M.MAV_FRAME_LOCAL_NED:
                north, east, down = x_m, y_m, w.z
            else:  # ENU
                north, east, down = y_m, x_m, -w.z
        else:
            raise ItemError(
                M.MAV_MISSION_UNSUPPORTED_FRAME, f"Mission item {w.seq}: frame {w.frame} not supported"
            )
    elif w.frame not in _GLOBAL | _LOCAL | {M.MAV_FRAME_MISSION}:
        raise ItemError(
            M.MAV_MISSION_UNSUPPORTED_FRAME, f"Mission item {w.seq}: frame {w.frame} not supported"
        )

    def param(v: float, default: float) -> float:
        return v if math.isfinite(v) else default

    return MissionItem(
        seq=w.seq,
        command=command,
        north_m=north,
        east_m=east,
        down_m=down,
        param1=param(w.param1, 0.0),
        param2=param(w.param2, 0.0),
        param3=param(w.param3, 0.0),
        param4=w.param4,
        autocontinue=bool(w.autocontinue),
    )


def item_to_wire(item: MissionItem, vehicle: VehicleLink) -> WireItem:
    """A MissionItem the autopilot holds (not uploaded by us) as a GLOBAL_RELATIVE_ALT_INT wire item."""
    geo = vehicle.geo
    home_down = float(vehicle.autopilot.home_ned_m[2])
    if math.isfinite(item.north_m) and math.isfinite(item.east_m):
        lat, lon, _ = geo.ned_to_global(item.north_m, item.east_m, 0.0)
        x, y = round(lat * 1e7), round(lon * 1e7)
    else:
        x = y = 0
    z = home_down - item.down_m if math.isfinite(item.down_m) else 0.0
    frame = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT if item.command in _POSITIONAL else M.MAV_FRAME_MISSION
    return WireItem(
        item.seq, frame, int(item.command), 0, int(item.autocontinue),
        item.param1, item.param2, item.param3, item.param4, x, y, z,
    )  # fmt: skip


@dataclass
class _Upload:
    origin: Origin
    count: int
    items: list[WireItem]
    use_int: bool
    last_activity_s: float
    retries: int = 0

    @property
    def expected(self) -> int:
        return len(self.items)


@dataclass(frozen=True)
class MissionLimits:
    max_items: int = 1000  # MISSION_COUNT above this: MISSION_ACK NO_SPACE
    retry_s: float = 0.5  # re-request a missing item after this long (wall time)
    max_retries: int = 5  # then cancel the upload


class MissionProtocol:
    def __init__(
        self, vehicle: VehicleLink, out: Outbox, statustext: StatusSink, limits: MissionLimits
    ) -> None:
        self.vehicle = vehicle
        self.out = out
        self.statustext = statustext
        self.limits = limits
        self.upload: _Upload | None = None
        self._wire: list[WireItem] = []  # what was uploaded, for download
        self._download: dict[tuple[str, int], list[WireItem]] = {}  # peer -> snapshot at MISSION_REQUEST_LIST
        self.uploads_completed = 0
        self.uploads_failed = 0

    # --- helpers ----------------------------------------------------------------------------
    def _ack(self, origin: Origin, result: int, mission_type: int = M.MAV_MISSION_TYPE_MISSION) -> None:
        self.out.reply(
            origin, M.MAVLink_mission_ack_message(origin.sysid, origin.compid, result, mission_type)
        )

    def _request(self, up: _Upload) -> None:
        seq = up.expected
        o = up.origin
        msg = (
            M.MAVLink_mission_request_int_message(o.sysid, o.compid, seq, M.MAV_MISSION_TYPE_MISSION)
            if up.use_int
            else M.MAVLink_mission_request_message(o.sysid, o.compid, seq, M.MAV_MISSION_TYPE_MISSION)
        )
        self.out.reply(o, msg)

    def current_wire_items(self) -> list[WireItem]:
        """The mission as the autopilot holds it, in wire form (our upload if it is still the autopilot's mission)."""
        items = list(self.vehicle.autopilot.mission_items)
        if len(items) == len(self._wire):
            return list(self._wire)
        return [replace(item_to_wire(it, self.vehicle), seq=i) for i, it in enumerate(items)]

    # --- upload -----------------------------------------------------------------------------
    def handle_count(self, origin: Origin, msg: MavMessage, now_s: float) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        if mission_type != M.MAV_MISSION_TYPE_MISSION:
            self._ack(origin, M.MAV_MISSION_UNSUPPORTED, mission_type)
            return
        count = int(msg.count)
        up = self.upload
        other_client = up is not None and (up.origin.addr, up.origin.sysid) != (origin.addr, origin.sysid)
        if (
            other_client
            and up is not None
            and now_s - up.last_activity_s < self.limits.retry_s * (self.limits.max_retries + 1)
        ):
            self._ack(origin, M.MAV_MISSION_DENIED)  # another client is uploading
            return
        self.upload = None
        if count > self.limits.max_items:
            self.uploads_failed += 1
            self.statustext(
                origin, Severity.ERROR, f"Mission rejected: {count} items, at most {self.limits.max_items}"
            )
            self._ack(origin, M.MAV_MISSION_NO_SPACE)
            return
        if count == 0:
            self._clear(origin)
            return
        self.upload = _Upload(origin, count, [], use_int=True, last_activity_s=now_s)
        self._request(self.upload)

    def handle_item(self, origin: Origin, msg: MavMessage, now_s: float) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        up = self.upload
        if up is None or up.origin.addr != origin.addr or mission_type != M.MAV_MISSION_TYPE_MISSION:
            return  # an item nobody asked for (PX4 ignores it too)
        seq = int(msg.seq)
        if seq < up.expected:
            return  # duplicate of an item we already have
        if seq > up.expected:
            up.last_activity_s = now_s
            self._request(up)  # ask again for the one we need
            return
        up.use_int = msg.get_msgId() == M.MAVLINK_MSG_ID_MISSION_ITEM_INT
        up.items.append(WireItem.from_msg(msg))
        up.last_activity_s = now_s
        up.retries = 0
        if up.expected < up.count:
            self._request(up)
            return
        self.upload = None
        self._finish(up)

    def _finish(self, up: _Upload) -> None:
        try:
            items = [wire_to_item(w, self.vehicle) for w in up.items]
        except ItemError as exc:
            self.uploads_failed += 1
            self.statustext(up.origin, Severity.ERROR, str(exc))
            self._ack(up.origin, exc.result)
            return
        outcome = self.vehicle.autopilot.set_mission(items)
        if not outcome.ok:
            self.uploads_failed += 1
            if outcome.reason:
                self.statustext(up.origin, Severity.ERROR, outcome.reason)
            denied = outcome.result in (CommandResult.DENIED, CommandResult.TEMPORARILY_REJECTED)
            self._ack(up.origin, M.MAV_MISSION_DENIED if denied else M.MAV_MISSION_ERROR)
            return
        self._wire = up.items
        self.uploads_completed += 1
        self._ack(up.origin, M.MAV_MISSION_ACCEPTED)

    def poll(self, now_s: float) -> None:
        """Retries and the upload timeout; called periodically by the endpoint."""
        up = self.upload
        if up is None or now_s - up.last_activity_s < self.limits.retry_s:
            return
        if up.retries >= self.limits.max_retries:
            self.upload = None
            self.uploads_failed += 1
            self.statustext(
                up.origin, Severity.ERROR, f"Mission upload timed out at item {up.expected} of {up.count}"
            )
            self._ack(up.origin, M.MAV_MISSION_OPERATION_CANCELLED)
            return
        up.retries += 1
        up.last_activity_s = now_s
        self._request(up)

    # --- download ---------------------------------------------------------------------------
    def handle_request_list(self, origin: Origin, msg: MavMessage) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        if mission_type != M.MAV_MISSION_TYPE_MISSION:
            # no fence or rally points: an empty list (what QGC expects from a vehicle without them)
            self.out.reply(
                origin, M.MAVLink_mission_count_message(origin.sysid, origin.compid, 0, mission_type)
            )
            return
        snapshot = self.current_wire_items()
        self._download[origin.addr] = snapshot
        self.out.reply(
            origin, M.MAVLink_mission_count_message(origin.sysid, origin.compid, len(snapshot), mission_type)
        )

    def handle_request(self, origin: Origin, msg: MavMessage) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        if mission_type != M.MAV_MISSION_TYPE_MISSION:
            self._ack(origin, M.MAV_MISSION_INVALID_SEQUENCE, mission_type)
            return
        snapshot = self._download.get(origin.addr)
        if snapshot is None:
            snapshot = self.current_wire_items()
        seq = int(msg.seq)
        if not 0 <= seq < len(snapshot):
            self._ack(origin, M.MAV_MISSION_INVALID_SEQUENCE)
            return
        item = snapshot[seq]
        if msg.get_msgId() == M.MAVLINK_MSG_ID_MISSION_REQUEST_INT:
            self.out.reply(origin, item.to_int_msg(origin))
        else:
            self.out.reply(origin, item.to_float_msg(origin))

    def handle_ack(self, origin: Origin, msg: MavMessage) -> None:
        self._download.pop(origin.addr, None)  # the client finished (or gave up on) its download

    # --- clear / current --------------------------------------------------------------------
    def _clear(self, origin: Origin, mission_type: int = M.MAV_MISSION_TYPE_MISSION) -> None:
        outcome = self.vehicle.autopilot.clear_mission()
        if outcome.ok:
            self._wire = []
            self._ack(origin, M.MAV_MISSION_ACCEPTED, mission_type)
        else:
            if outcome.reason:
                self.statustext(origin, Severity.ERROR, outcome.reason)
            self._ack(origin, M.MAV_MISSION_DENIED, mission_type)

    def handle_clear_all(self, origin: Origin, msg: MavMessage) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        if mission_type in (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_ALL):
            self._clear(origin, mission_type)
        else:
            self._ack(origin, M.MAV_MISSION_ACCEPTED, mission_type)  # nothing stored of that type

    def handle_set_current(self, origin: Origin, msg: MavMessage) -> None:
        outcome = self.vehicle.autopilot.set_mission_current(int(msg.seq))
        if not outcome.ok and outcome.reason:
            self.statustext(origin, Severity.WARNING, outcome.reason)
        # MISSION_CURRENT follows from the endpoint's change detection
