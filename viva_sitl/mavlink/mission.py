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
Altitudes above home (GLOBAL_RELATIVE_ALT frames) are resolved against home when the item starts, not at upload.

The three plan types are stored separately (MISSION, FENCE, RALLY), each with its own upload, download and clear;
MISSION_CLEAR_ALL with MAV_MISSION_TYPE_ALL clears all three. FENCE: NAV_FENCE_POLYGON_VERTEX_INCLUSION/EXCLUSION
(param1 = vertex count, repeated on every vertex of one polygon), NAV_FENCE_CIRCLE_INCLUSION/EXCLUSION (param1 =
radius; 0 is stored and contains no point, as PX4 stores MAVSDK's "no circle" placeholder at lat/lon 0/0) and
NAV_FENCE_RETURN_POINT; a bad polygon (vertex count wrong or < 3, self-intersecting, non-finite) is
refused with a MAV_MISSION_* code and a STATUSTEXT. RALLY: NAV_RALLY_POINT; a rally point outside the fence is
accepted with a warning (PX4 does not check them). DO items PX4 would not know are refused (UNSUPPORTED); any other
MAV_CMD that is not a NAV command is accepted, logged and skipped when the mission runs.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.geofence import (
    CircleFence,
    Geofence,
    PolygonFence,
    RallyPoint,
    validate_circle,
    validate_polygon,
)
from viva_sitl.autopilot.types import CommandResult, MissionCommand, MissionItem, Severity
from viva_sitl.mavlink.base import MavMessage, Origin, Outbox, StatusSink, VehicleLink

log = logging.getLogger(__name__)
M = mavlink2

_AMSL = {M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT}
_RELATIVE = {M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
_TERRAIN = {M.MAV_FRAME_GLOBAL_TERRAIN_ALT, M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT}
_GLOBAL = _AMSL | _RELATIVE | _TERRAIN
_LOCAL = {M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_LOCAL_ENU}
_MISSION, _FENCE, _RALLY = M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_RALLY
_PLAN_TYPES = (_MISSION, _FENCE, _RALLY)
_TYPE_NAME = {_MISSION: "Mission", _FENCE: "Geofence", _RALLY: "Rally points"}
_POLY = {
    M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: True,
    M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION: False,
}
_CIRCLE = {M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION: True, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION: False}
# MAV_CMDs that are not navigation commands: accepted in a mission, logged and skipped (never a whole-mission refusal)
_OTHER_COMMANDS = frozenset(
    int(v)
    for v, e in M.enums["MAV_CMD"].items()
    if not e.name.startswith(("MAV_CMD_NAV_", "MAV_CMD_ENUM_END"))
)
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
    mission_type: int = M.MAV_MISSION_TYPE_MISSION

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
            int(getattr(msg, "mission_type", 0)),
        )  # fmt: skip

    def to_int_msg(self, target: Origin) -> MavMessage:
        return M.MAVLink_mission_item_int_message(
            target.sysid, target.compid, self.seq, self.frame, self.command, self.current, self.autocontinue,
            self.param1, self.param2, self.param3, self.param4, self.x, self.y, self.z, self.mission_type,
        )  # fmt: skip

    def to_float_msg(self, target: Origin) -> MavMessage:
        scale = 1e-7 if self.frame in _GLOBAL else 1e-4
        return M.MAVLink_mission_item_message(
            target.sysid, target.compid, self.seq, self.frame, self.command, self.current, self.autocontinue,
            self.param1, self.param2, self.param3, self.param4, self.x * scale, self.y * scale, self.z,
            self.mission_type,
        )  # fmt: skip


class ItemError(ValueError):
    """An item that cannot be flown; `result` is the MAV_MISSION_RESULT to answer with."""

    def __init__(self, result: int, text: str) -> None:
        super().__init__(text)
        self.result = result


def _position(
    w: WireItem, vehicle: VehicleLink, what: str = "Mission item", need_alt: bool = True
) -> tuple[float, float, float]:
    """(north, east, down) of a positional wire item (NaN north/east for lat = lon = 0; raises ItemError).
    need_alt=False (fence vertices): a NaN altitude is allowed and gives a NaN down."""
    if not need_alt and not math.isfinite(w.z):
        w = replace(w, z=0.0)
    north = east = down = math.nan
    if w.frame in _GLOBAL:
        if not math.isfinite(w.z):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM7, f"{what} {w.seq}: altitude is not finite")
        lat, lon = w.x * 1e-7, w.y * 1e-7
        if not (-90.0 <= lat <= 90.0):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM5_X, f"{what} {w.seq}: latitude out of range")
        if not (-180.0 <= lon <= 180.0):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM6_Y, f"{what} {w.seq}: longitude out of range")
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
            raise ItemError(M.MAV_MISSION_INVALID_PARAM7, f"{what} {w.seq}: z is not finite")
        x_m, y_m = w.x * 1e-4, w.y * 1e-4
        if w.frame == M.MAV_FRAME_LOCAL_NED:
            north, east, down = x_m, y_m, w.z
        else:  # ENU
            north, east, down = y_m, x_m, -w.z
    else:
        raise ItemError(M.MAV_MISSION_UNSUPPORTED_FRAME, f"{what} {w.seq}: frame {w.frame} not supported")
    return north, east, down


def wire_to_item(w: WireItem, vehicle: VehicleLink) -> MissionItem:
    """Convert one wire item to the autopilot's local-NED MissionItem (raises ItemError)."""
    try:
        command = MissionCommand(w.command)
    except ValueError:
        if w.command not in _OTHER_COMMANDS:
            raise ItemError(
                M.MAV_MISSION_UNSUPPORTED, f"Mission item {w.seq}: command {w.command} not supported"
            ) from None
        command = MissionCommand.OTHER
    north = east = down = math.nan
    alt_rel = math.nan
    if command in _POSITIONAL:
        north, east, down = _position(w, vehicle)
        if w.frame in _RELATIVE:
            alt_rel = w.z
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
        alt_rel_home_m=alt_rel,
        raw_command=w.command,
    )


def wire_to_fence(items: list[WireItem], vehicle: VehicleLink) -> Geofence:
    """MISSION_TYPE_FENCE items -> Geofence in local NED (raises ItemError with the MAV_MISSION_* code)."""
    polygons: list[PolygonFence] = []
    circles: list[CircleFence] = []
    ret: tuple[float, float, float] | None = None
    i = 0
    while i < len(items):
        w = items[i]
        if w.command in _POLY:
            count = w.param1
            if not (math.isfinite(count) and count == int(count) and count >= 3):
                raise ItemError(
                    M.MAV_MISSION_INVALID_PARAM1,
                    f"Geofence item {w.seq}: polygon vertex count {count:g} (at least 3)",
                )
            n = int(count)
            group = items[i : i + n]
            if len(group) < n or any(g.command != w.command or g.param1 != w.param1 for g in group):
                raise ItemError(
                    M.MAV_MISSION_INVALID_PARAM1,
                    f"Geofence item {w.seq}: polygon of {n} vertices does not have {n} vertex items",
                )
            verts = []
            for g in group:
                north, east, _ = _position(g, vehicle, "Geofence item", need_alt=False)
                if not (math.isfinite(north) and math.isfinite(east)):
                    raise ItemError(
                        M.MAV_MISSION_INVALID_PARAM5_X, f"Geofence item {g.seq}: vertex has no position"
                    )
                verts.append((north, east))
            try:
                validate_polygon(verts, len(polygons))
            except ValueError as exc:
                raise ItemError(M.MAV_MISSION_ERROR, str(exc)) from None
            polygons.append(PolygonFence(tuple(verts), inclusion=_POLY[w.command]))
            i += n
            continue
        if w.command in _CIRCLE:
            north, east, _ = _position(w, vehicle, "Geofence item", need_alt=False)
            if w.frame in _GLOBAL and w.x == 0 and w.y == 0:
                # lat/lon 0/0 is a real place for a fence circle (MAVSDK's "no circle" placeholder sits there).
                north, east, _ = vehicle.geo.global_to_ned(0.0, 0.0, vehicle.geo.alt_amsl_m)
            try:
                validate_circle((north, east), w.param1, len(circles))
            except ValueError as exc:
                raise ItemError(M.MAV_MISSION_INVALID_PARAM1, str(exc)) from None
            circles.append(CircleFence((north, east), w.param1, inclusion=_CIRCLE[w.command]))
        elif w.command == M.MAV_CMD_NAV_FENCE_RETURN_POINT:
            ret = _position(w, vehicle, "Geofence item")
        else:
            raise ItemError(
                M.MAV_MISSION_UNSUPPORTED, f"Geofence item {w.seq}: command {w.command} not supported"
            )
        i += 1
    return Geofence(tuple(polygons), tuple(circles), ret)


def wire_to_rally(items: list[WireItem], vehicle: VehicleLink) -> list[RallyPoint]:
    out = []
    for w in items:
        if w.command != M.MAV_CMD_NAV_RALLY_POINT:
            raise ItemError(
                M.MAV_MISSION_UNSUPPORTED, f"Rally item {w.seq}: command {w.command} not supported"
            )
        north, east, down = _position(w, vehicle, "Rally point")
        if not (math.isfinite(north) and math.isfinite(east)):
            raise ItemError(M.MAV_MISSION_INVALID_PARAM5_X, f"Rally point {w.seq}: no position")
        out.append(RallyPoint(north, east, down))
    return out


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
        item.seq, frame, item.raw_command or int(item.command), 0, int(item.autocontinue),
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
    mission_type: int = M.MAV_MISSION_TYPE_MISSION

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
        self._plan_wire: dict[int, list[WireItem]] = {_FENCE: [], _RALLY: []}  # fence / rally as uploaded
        # (peer, mission type) -> snapshot at MISSION_REQUEST_LIST
        self._download: dict[tuple[tuple[str, int], int], list[WireItem]] = {}
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
        t = up.mission_type
        msg = (
            M.MAVLink_mission_request_int_message(o.sysid, o.compid, seq, t)
            if up.use_int
            else M.MAVLink_mission_request_message(o.sysid, o.compid, seq, t)
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
        if mission_type not in _PLAN_TYPES:
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
            self._ack(origin, M.MAV_MISSION_DENIED, mission_type)  # another client is uploading
            return
        self.upload = None
        if count > self.limits.max_items:
            self.uploads_failed += 1
            self.statustext(
                origin,
                Severity.ERROR,
                f"{_TYPE_NAME[mission_type]} rejected: {count} items, at most {self.limits.max_items}",
            )
            self._ack(origin, M.MAV_MISSION_NO_SPACE, mission_type)
            return
        if count == 0:
            self._clear(origin, mission_type)
            return
        self.upload = _Upload(
            origin, count, [], use_int=True, last_activity_s=now_s, mission_type=mission_type
        )
        self._request(self.upload)

    def handle_item(self, origin: Origin, msg: MavMessage, now_s: float) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        up = self.upload
        if up is None or up.origin.addr != origin.addr or mission_type != up.mission_type:
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
        if up.mission_type != _MISSION:
            self._finish_plan(up)
            return
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

    def _finish_plan(self, up: _Upload) -> None:
        """FENCE / RALLY upload complete: convert, validate, hand to the autopilot atomically."""
        ap = self.vehicle.autopilot
        t = up.mission_type
        try:
            if t == _FENCE:
                outcome = ap.set_geofence(wire_to_fence(up.items, self.vehicle))
            else:
                rally = wire_to_rally(up.items, self.vehicle)
                outcome = ap.set_rally_points(rally)
        except ItemError as exc:
            self.uploads_failed += 1
            self.statustext(up.origin, Severity.ERROR, str(exc))
            self._ack(up.origin, exc.result, t)
            return
        if not outcome.ok:
            self.uploads_failed += 1
            if outcome.reason:
                self.statustext(up.origin, Severity.ERROR, outcome.reason)
            self._ack(up.origin, M.MAV_MISSION_DENIED, t)
            return
        self._plan_wire[t] = up.items
        self.uploads_completed += 1
        self._ack(up.origin, M.MAV_MISSION_ACCEPTED, t)
        if t == _RALLY:
            fence = ap.geofence
            for i, r in enumerate(ap.rally_points):
                if not fence.empty and not fence.contains(r.north_m, r.east_m):
                    self.statustext(up.origin, Severity.WARNING, f"Rally point {i} is outside the geofence")

    def poll(self, now_s: float) -> None:
        """Retries and the upload timeout; called periodically by the endpoint."""
        up = self.upload
        if up is None or now_s - up.last_activity_s < self.limits.retry_s:
            return
        if up.retries >= self.limits.max_retries:
            self.upload = None
            self.uploads_failed += 1
            self.statustext(
                up.origin,
                Severity.ERROR,
                f"{_TYPE_NAME[up.mission_type]} upload timed out at item {up.expected} of {up.count}",
            )
            self._ack(up.origin, M.MAV_MISSION_OPERATION_CANCELLED, up.mission_type)
            return
        up.retries += 1
        up.last_activity_s = now_s
        self._request(up)

    # --- download ---------------------------------------------------------------------------
    def _snapshot(self, mission_type: int) -> list[WireItem]:
        if mission_type == _MISSION:
            return self.current_wire_items()
        return list(self._plan_wire.get(mission_type, []))

    def handle_request_list(self, origin: Origin, msg: MavMessage) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        if mission_type not in _PLAN_TYPES:
            self._ack(origin, M.MAV_MISSION_UNSUPPORTED, mission_type)
            return
        snapshot = self._snapshot(mission_type)
        self._download[(origin.addr, mission_type)] = snapshot
        self.out.reply(
            origin, M.MAVLink_mission_count_message(origin.sysid, origin.compid, len(snapshot), mission_type)
        )

    def handle_request(self, origin: Origin, msg: MavMessage) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        if mission_type not in _PLAN_TYPES:
            self._ack(origin, M.MAV_MISSION_INVALID_SEQUENCE, mission_type)
            return
        snapshot = self._download.get((origin.addr, mission_type))
        if snapshot is None:
            snapshot = self._snapshot(mission_type)
        seq = int(msg.seq)
        if not 0 <= seq < len(snapshot):
            self._ack(origin, M.MAV_MISSION_INVALID_SEQUENCE, mission_type)
            return
        item = snapshot[seq]
        if msg.get_msgId() == M.MAVLINK_MSG_ID_MISSION_REQUEST_INT:
            self.out.reply(origin, item.to_int_msg(origin))
        else:
            self.out.reply(origin, item.to_float_msg(origin))

    def handle_ack(self, origin: Origin, msg: MavMessage) -> None:
        # the client finished (or gave up on) its download
        self._download.pop((origin.addr, int(getattr(msg, "mission_type", 0))), None)

    # --- clear / current --------------------------------------------------------------------
    def _clear(self, origin: Origin, mission_type: int = M.MAV_MISSION_TYPE_MISSION) -> None:
        ap = self.vehicle.autopilot
        if mission_type in (_FENCE, M.MAV_MISSION_TYPE_ALL):
            ap.set_geofence(Geofence())
            self._plan_wire[_FENCE] = []
        if mission_type in (_RALLY, M.MAV_MISSION_TYPE_ALL):
            ap.set_rally_points([])
            self._plan_wire[_RALLY] = []
        if mission_type not in (_MISSION, M.MAV_MISSION_TYPE_ALL):
            self._ack(origin, M.MAV_MISSION_ACCEPTED, mission_type)
            return
        outcome = ap.clear_mission()
        if outcome.ok:
            self._wire = []
            self._ack(origin, M.MAV_MISSION_ACCEPTED, mission_type)
        else:
            if outcome.reason:
                self.statustext(origin, Severity.ERROR, outcome.reason)
            self._ack(origin, M.MAV_MISSION_DENIED, mission_type)

    def handle_clear_all(self, origin: Origin, msg: MavMessage) -> None:
        mission_type = int(getattr(msg, "mission_type", 0))
        if mission_type in (*_PLAN_TYPES, M.MAV_MISSION_TYPE_ALL):
            self._clear(origin, mission_type)
        else:
            self._ack(origin, M.MAV_MISSION_UNSUPPORTED, mission_type)

    def handle_set_current(self, origin: Origin, msg: MavMessage) -> None:
        outcome = self.vehicle.autopilot.set_mission_current(int(msg.seq))
        if not outcome.ok and outcome.reason:
            self.statustext(origin, Severity.WARNING, outcome.reason)
        # MISSION_CURRENT follows from the endpoint's change detection
