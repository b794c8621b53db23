#!/usr/bin/env python3
"""A ground-station script in pymavlink: upload a mission that ends in a landing, fly it, check where it landed.

What a GCS (QGroundControl, a dispatch server) does over MAVLink, with nothing but pymavlink:

1. wait for the autopilot's HEARTBEAT and HOME_POSITION, and for the pre-arm checks to pass (SYS_STATUS);
2. upload a mission with the MAVLink mission protocol (MISSION_COUNT -> MISSION_REQUEST_INT -> MISSION_ITEM_INT ...
   -> MISSION_ACK), items in frame 3 (GLOBAL_RELATIVE_ALT_INT) as QGC sends them:
   TAKEOFF at home, WAYPOINT --north m north of home, WAYPOINT --north/--east, LAND --east m east of home;
3. arm (COMMAND_LONG 400) and start: DO_SET_MODE to AUTO.MISSION (main 4, sub 4), or MISSION_START with --start;
4. watch MISSION_CURRENT / MISSION_ITEM_REACHED, flight mode and landed state (EXTENDED_SYS_STATE) until the vehicle
   has landed and disarmed; check every waypoint was reached in order and the touchdown is within --tolerance of
   the LAND item.

It sends a GCS HEARTBEAT every second throughout (PX4's data-link-loss failsafe watches for it).

    viva-sitl run &
    python pymavlink_gcs_mission.py                   # default udpin:0.0.0.0:14550, where PX4 SITL sends GCS traffic

Exit status 0 on success, 1 on a refused command, a failed check or a timeout (the message says which).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Callable
from typing import Any

os.environ.setdefault("MAVLINK20", "1")  # pymavlink reads this at import: speak MAVLink 2 as PX4 does
from _mission import MissionFailed, failed, log, script_parser, succeeded  # noqa: E402
from pymavlink import mavutil  # noqa: E402

mavlink = mavutil.mavlink
EARTH_RADIUS_M = 6371000.0
GCS_HEARTBEAT_PERIOD_S = 1.0
PREARM_BIT = 0x10000000  # MAV_SYS_STATUS_PREARM_CHECK
MAIN_MODE_AUTO, SUB_MODE_MISSION = 4, 4
LANDED_STATES = {0: "UNDEFINED", 1: "ON_GROUND", 2: "IN_AIR", 3: "TAKEOFF", 4: "LANDING"}


def px4_mode_name(custom_mode: int) -> str:
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    names = {1: "MANUAL", 2: "ALTCTL", 3: "POSCTL", 5: "ACRO", 6: "OFFBOARD", 7: "STABILIZED"}
    subs = {1: "READY", 2: "TAKEOFF", 3: "LOITER", 4: "MISSION", 5: "RTL", 6: "LAND"}
    if main == MAIN_MODE_AUTO:
        return f"AUTO.{subs.get(sub, sub)}"
    return names.get(main, f"main{main}")


def offset_deg(lat_deg: float, lon_deg: float, north_m: float, east_m: float) -> tuple[float, float]:
    """Latitude/longitude `north_m`, `east_m` away (flat earth: cm-accurate over a few hundred metres)."""
    lat = lat_deg + math.degrees(north_m / EARTH_RADIUS_M)
    lon = lon_deg + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat_deg))))
    return lat, lon


def distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    north = math.radians(lat2 - lat1) * EARTH_RADIUS_M
    east = math.radians(lon2 - lon1) * EARTH_RADIUS_M * math.cos(math.radians(lat1))
    return math.hypot(north, east)


class Gcs:
    """One pymavlink link to one autopilot, with a GCS heartbeat kept alive by every receive call."""

    def __init__(self, url: str) -> None:
        self.conn = mavutil.mavlink_connection(url, source_system=255, source_component=190)
        self.target_system = 1
        self.target_component = 1
        self.latest: dict[str, Any] = {}
        self._next_heartbeat_s = 0.0

    def close(self) -> None:
        self.conn.close()

    def _tick(self) -> None:
        now = time.monotonic()
        if now >= self._next_heartbeat_s and self.latest:  # only once we know where the vehicle is
            self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self._next_heartbeat_s = now + GCS_HEARTBEAT_PERIOD_S

    def recv(self, timeout_s: float) -> Any | None:
        """The next message from the autopilot (None on timeout). Prints STATUSTEXT, remembers the latest of each."""
        deadline = time.monotonic() + timeout_s
        while True:
            self._tick()
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            msg = self.conn.recv_match(blocking=True, timeout=min(remaining, 0.1))
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            if self.latest and msg.get_srcSystem() != self.target_system:
                continue
            self.latest[msg.get_type()] = msg
            if msg.get_type() == "STATUSTEXT":
                log(f"vehicle says: {msg.text}")
            return msg

    def wait(self, types: set[str], predicate: Callable[[Any], bool], timeout_s: float, what: str) -> Any:
        deadline = time.monotonic() + timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            msg = self.recv(remaining)
            if msg is not None and msg.get_type() in types and predicate(msg):
                return msg
        raise MissionFailed(f"timed out after {timeout_s:.0f} s waiting for {what}")

    def command(self, command: int, params: list[float], timeout_s: float = 5.0) -> int:
        """COMMAND_LONG with PX4's retry rule (resend after 1 s without an ACK); returns the MAV_RESULT."""
        padded = (params + [0.0] * 7)[:7]
        deadline = time.monotonic() + timeout_s
        for confirmation in range(255):
            self.conn.mav.command_long_send(
                self.target_system, self.target_component, command, confirmation, *padded
            )
            try:
                ack = self.wait(
                    {"COMMAND_ACK"},
                    lambda m: m.command == command,
                    min(1.0, deadline - time.monotonic()),
                    "ack",
                )
            except MissionFailed:
                if time.monotonic() >= deadline:
                    break
                continue
            if ack.result == mavlink.MAV_RESULT_IN_PROGRESS:
                continue
            return int(ack.result)
        raise MissionFailed(f"no COMMAND_ACK for command {command} within {timeout_s:.0f} s")


def build_mission(
    args: argparse.Namespace, home_lat: float, home_lon: float
) -> list[tuple[int, float, float, float]]:
    """(command, lat, lon, alt above home) for TAKEOFF, two WAYPOINTs and LAND."""
    wp1 = offset_deg(home_lat, home_lon, args.north, 0.0)
    wp2 = offset_deg(home_lat, home_lon, args.north, args.east)
    land = offset_deg(home_lat, home_lon, 0.0, args.east)
    return [
        (mavlink.MAV_CMD_NAV_TAKEOFF, home_lat, home_lon, args.altitude),
        (mavlink.MAV_CMD_NAV_WAYPOINT, *wp1, args.altitude),
        (mavlink.MAV_CMD_NAV_WAYPOINT, *wp2, args.altitude),
        (mavlink.MAV_CMD_NAV_LAND, *land, 0.0),
    ]


def upload(
    gcs: Gcs, items: list[tuple[int, float, float, float]], acceptance_m: float, timeout_s: float
) -> None:
    """The MAVLink mission upload handshake, answering each MISSION_REQUEST(_INT) with its MISSION_ITEM_INT."""
    deadline = time.monotonic() + timeout_s
    sent_count_s = -math.inf
    while time.monotonic() < deadline:
        if time.monotonic() - sent_count_s > 2.0:  # (re)start the handshake if the vehicle went quiet
            gcs.conn.mav.mission_count_send(
                gcs.target_system, gcs.target_component, len(items), mavlink.MAV_MISSION_TYPE_MISSION
            )
            sent_count_s = time.monotonic()
        msg = gcs.recv(0.2)
        if msg is None:
            continue
        kind = msg.get_type()
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            seq = msg.seq
            if not 0 <= seq < len(items):
                raise MissionFailed(f"vehicle requested mission item {seq}, we have {len(items)}")
            command, lat, lon, alt = items[seq]
            gcs.conn.mav.mission_item_int_send(
                gcs.target_system,
                gcs.target_component,
                seq,
                mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                command,
                0,  # current
                1,  # autocontinue
                0.0,  # param1: hold time (waypoint) / pitch (takeoff)
                acceptance_m if command == mavlink.MAV_CMD_NAV_WAYPOINT else 0.0,  # param2: acceptance radius
                0.0,
                math.nan,  # param4: yaw, NaN = keep
                int(round(lat * 1e7)),
                int(round(lon * 1e7)),
                alt,
                mavlink.MAV_MISSION_TYPE_MISSION,
            )
            sent_count_s = time.monotonic()
            log(f"sent mission item {seq}")
        elif kind == "MISSION_ACK":
            if msg.type != mavlink.MAV_MISSION_ACCEPTED:
                raise MissionFailed(f"mission upload refused: MISSION_ACK type {msg.type}")
            log(f"mission of {len(items)} items accepted")
            return
    raise MissionFailed(f"mission upload not acknowledged within {timeout_s:.0f} s")


def fly(args: argparse.Namespace) -> dict[str, Any]:
    gcs = Gcs(args.url)
    try:
        return _fly(args, gcs)
    finally:
        gcs.close()


def _fly(args: argparse.Namespace, gcs: Gcs) -> dict[str, Any]:
    step = args.step_timeout
    log(f"listening on {args.url}")
    hb = gcs.wait(
        {"HEARTBEAT"},
        lambda m: (
            m.autopilot != mavlink.MAV_AUTOPILOT_INVALID
            and m.type not in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_CAMERA)
        ),
        step,
        "an autopilot HEARTBEAT",
    )
    gcs.target_system, gcs.target_component = hb.get_srcSystem(), hb.get_srcComponent()
    gcs.latest = {"HEARTBEAT": hb}
    log(
        f"autopilot: system {gcs.target_system}, component {gcs.target_component}, mode {px4_mode_name(hb.custom_mode)}"
    )

    # Home: ask for it (REQUEST_MESSAGE), as QGC and MAVSDK do.
    gcs.conn.mav.command_long_send(
        gcs.target_system, gcs.target_component, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
        mavlink.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0, 0, 0, 0,
    )  # fmt: skip
    home = gcs.wait({"HOME_POSITION"}, lambda m: True, step, "HOME_POSITION")
    home_lat, home_lon = home.latitude / 1e7, home.longitude / 1e7
    log(f"home: {home_lat:.7f}, {home_lon:.7f}")
    gcs.wait(
        {"SYS_STATUS"},
        lambda m: (
            not (m.onboard_control_sensors_present & PREARM_BIT)
            or bool(m.onboard_control_sensors_health & PREARM_BIT)
        ),
        step,
        "the pre-arm checks to pass (SYS_STATUS)",
    )

    items = build_mission(args, home_lat, home_lon)
    upload(gcs, items, args.acceptance, step)

    result = gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [1.0])
    if result != mavlink.MAV_RESULT_ACCEPTED:
        raise MissionFailed(f"arming refused: MAV_RESULT {result}")
    gcs.wait(
        {"HEARTBEAT"},
        lambda m: bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED),
        step,
        "armed heartbeat",
    )
    log("armed")
    if args.start == "mode":
        result = gcs.command(
            mavlink.MAV_CMD_DO_SET_MODE,
            [
                float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED),
                float(MAIN_MODE_AUTO),
                float(SUB_MODE_MISSION),
            ],
        )
    else:
        result = gcs.command(mavlink.MAV_CMD_MISSION_START, [0.0, float(len(items) - 1)])
    if result != mavlink.MAV_RESULT_ACCEPTED:
        raise MissionFailed(f"mission start ({args.start}) refused: MAV_RESULT {result}")
    log(f"mission started ({args.start})")

    # Watch the flight until landed and disarmed.
    reached: list[int] = []
    modes: list[str] = []
    landed_states: list[str] = []
    max_alt_m = 0.0
    airborne = False
    deadline = time.monotonic() + args.timeout
    while True:
        if time.monotonic() > deadline:
            raise MissionFailed(
                f"mission not finished within {args.timeout:.0f} s (reached {reached}, modes {modes}, "
                f"landed states {landed_states})"
            )
        msg = gcs.recv(0.5)
        if msg is None:
            continue
        kind = msg.get_type()
        if kind == "MISSION_ITEM_REACHED" and (not reached or reached[-1] != msg.seq):
            reached.append(msg.seq)
            log(f"reached mission item {msg.seq}")
        elif kind == "HEARTBEAT" and msg.get_srcComponent() == gcs.target_component:
            mode = px4_mode_name(msg.custom_mode)
            if not modes or modes[-1] != mode:
                modes.append(mode)
                log(f"mode {mode}")
            armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            ext = gcs.latest.get("EXTENDED_SYS_STATE")
            if (
                airborne
                and not armed
                and ext is not None
                and ext.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND
            ):
                break
        elif kind == "EXTENDED_SYS_STATE":
            state = LANDED_STATES.get(msg.landed_state, str(msg.landed_state))
            if not landed_states or landed_states[-1] != state:
                landed_states.append(state)
                log(f"landed state {state}")
            airborne = airborne or msg.landed_state == mavlink.MAV_LANDED_STATE_IN_AIR
        elif kind == "GLOBAL_POSITION_INT":
            max_alt_m = max(max_alt_m, msg.relative_alt / 1000.0)
    log("landed and disarmed")

    pos = gcs.wait({"GLOBAL_POSITION_INT"}, lambda m: True, step, "a final GLOBAL_POSITION_INT")
    _, land_lat, land_lon, _ = items[-1]
    error_m = distance_m(land_lat, land_lon, pos.lat / 1e7, pos.lon / 1e7)
    log(f"touchdown {error_m:.2f} m from the LAND item; peak altitude {max_alt_m:.2f} m")
    waypoints = [1, 2]
    if [s for s in reached if s in waypoints] != waypoints or reached != sorted(reached):
        raise MissionFailed(f"mission items reached out of order or missed: {reached}")
    if "AUTO.MISSION" not in modes:
        raise MissionFailed(f"the vehicle never showed AUTO.MISSION (modes seen: {modes})")
    if error_m > args.tolerance:
        raise MissionFailed(f"landed {error_m:.2f} m from the LAND item (tolerance {args.tolerance} m)")
    if abs(max_alt_m - args.altitude) > 1.5:
        raise MissionFailed(f"peak altitude {max_alt_m:.2f} m, mission altitude {args.altitude} m")
    return {
        "reached": ",".join(str(s) for s in reached),
        "modes": ",".join(modes),
        "landing_error_m": round(error_m, 3),
        "max_alt_m": round(max_alt_m, 3),
        "final_rel_alt_m": round(pos.relative_alt / 1000.0, 3),
    }


def main() -> int:
    parser = script_parser(__doc__, "udpin:0.0.0.0:14550", "pymavlink connection string")
    parser.add_argument("--altitude", type=float, default=10.0, help="mission altitude above home, m")
    parser.add_argument("--north", type=float, default=15.0, help="waypoints: metres north of home")
    parser.add_argument(
        "--east", type=float, default=15.0, help="second waypoint and landing: metres east of home"
    )
    parser.add_argument("--acceptance", type=float, default=1.0, help="waypoint acceptance radius, m")
    parser.add_argument(
        "--tolerance", type=float, default=2.0, help="accepted distance touchdown - LAND item, m"
    )
    parser.add_argument("--start", choices=["mode", "mission-start"], default="mode",
                        help="start with DO_SET_MODE AUTO.MISSION or with MISSION_START")  # fmt: skip
    parser.add_argument("--timeout", type=float, default=240.0, help="limit for the flight, wall seconds")
    parser.add_argument(
        "--step-timeout", type=float, default=60.0, help="limit for each other wait, wall seconds"
    )
    args = parser.parse_args()
    try:
        result = fly(args)
    except MissionFailed as exc:
        return failed(str(exc))
    return succeeded(result)


if __name__ == "__main__":
    sys.exit(main())
