"""FOLLOW_TARGET (144) input for Follow Me (AUTO.FOLLOW_TARGET, autopilot/tasks/follow.py).

MAVSDK's follow_me plugin sends it once a second while the vehicle is in Follow Me (lat/lon 1e7 degrees, alt AMSL in
metres, vel NED in m/s, est_capabilities bit 0 = position). The message has no target fields: any peer's counts, as
PX4. A position of (0, 0), out of range, or without the position bit is ignored, with one STATUSTEXT at most every
5 s, short enough for one STATUSTEXT (never a traceback); a NaN altitude is a 2D target (FLW_TGT_ALT_M 0 and 1 do not need it), NaN velocity
components count as unknown (0).
"""

from __future__ import annotations

import logging
import math

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.types import Severity
from viva_sitl.mavlink.base import MavMessage, Origin, StatusSink, VehicleLink

log = logging.getLogger(__name__)
M = mavlink2

EST_POS = 1  # FOLLOW_TARGET.est_capabilities bit 0: position
WARN_INTERVAL_S = 5.0


class FollowTargetInput:
    def __init__(self, vehicle: VehicleLink, statustext: StatusSink) -> None:
        self.vehicle = vehicle
        self.statustext = statustext
        self.accepted = 0
        self.ignored = 0
        self._last_warn_s = -math.inf

    def _ignore(self, origin: Origin, why: str) -> None:
        self.ignored += 1
        now = float(self.vehicle.time_s)
        if not math.isfinite(now) or now - self._last_warn_s >= WARN_INTERVAL_S:
            self._last_warn_s = now if math.isfinite(now) else self._last_warn_s
            self.statustext(origin, Severity.WARNING, f"Follow target ignored: {why}")
        log.info("FOLLOW_TARGET from %d/%d ignored: %s", origin.sysid, origin.compid, why)

    def handle(self, origin: Origin, msg: MavMessage) -> None:
        if not int(msg.est_capabilities) & EST_POS:
            self._ignore(origin, "no position bit")
            return
        lat, lon = int(msg.lat) * 1e-7, int(msg.lon) * 1e-7
        if (int(msg.lat), int(msg.lon)) == (0, 0) or not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            self._ignore(origin, "lat/lon invalid")
            return
        geo = self.vehicle.geo
        alt = float(msg.alt)
        north, east, down = geo.global_to_ned(lat, lon, alt if math.isfinite(alt) else geo.alt_amsl_m)
        if not math.isfinite(alt):
            down = math.nan
        vel = tuple(float(v) if math.isfinite(float(v)) else 0.0 for v in msg.vel)
        outcome = self.vehicle.autopilot.set_follow_target(
            self.vehicle.time_s, (north, east, down), (vel[0], vel[1], vel[2])
        )
        if outcome.ok:
            self.accepted += 1
        else:
            self._ignore(origin, "position out of range")


__all__ = ["FollowTargetInput"]
