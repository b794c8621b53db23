"""Follow Me (PX4's AUTO.FOLLOW_TARGET, FlightTaskAutoFollowTarget): keep a moving target in view from a set distance,
angle and height.

The target comes from FOLLOW_TARGET messages (a phone, MAVSDK's follow_me plugin: `set_target`) or, beyond PX4, from
the footage's ground truth: FLW_TGT_TRACK = N (>= 0) follows world track N (viva_sitl.world, the index in
`world.tracks.tracks`) at the current simulation time, through the `track_lookup` the Vehicle provides.

As PX4 (facts from its flight task and FLW_TGT_* parameters):
- the target position is low-pass filtered (FLW_TGT_RS, 0..1: lower follows faster; time constant FLW_TGT_RS x 10 s
  here) after a prediction with its velocity that cancels the filter's lag, and predicted between messages;
- the vehicle stands FLW_TGT_DST metres from the target at FLW_TGT_FA degrees from the target's course (0 in front,
  90 right, 180 behind: the default), the course being the direction of the target's velocity once it moves faster
  than 0.5 m/s (before that: toward the vehicle's current heading, so the vehicle at least faces the target);
- height: FLW_TGT_ALT_M 0 (and 1: the ground here is flat) FLW_TGT_HT above home, 2 FLW_TGT_HT above the target;
  the vehicle first reaches that height, then moves horizontally (PX4's ALT_ACCEPTANCE_THRESHOLD);
- velocity feed-forward from the target's velocity while it moves; speed up to MPC_XY_VEL_MAX; the heading faces
  the target;
- no target (none yet, or none for TARGET_TIMEOUT_S): hold position, with one warning.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from viva_sitl.autopilot.context import FlightContext
from viva_sitl.autopilot.control import TrajectorySetpoint
from viva_sitl.autopilot.tasks.common import limits, run_position, yaw_rate_auto
from viva_sitl.autopilot.types import Severity
from viva_sitl.dynamics import EavCommand, EavParams, EavState

TARGET_TIMEOUT_S = 3.0  # no target message for this long: the target is lost, hold
MIN_SPEED_FOR_COURSE_M_S = 0.5  # the target's course (and the feed-forward) only when it moves faster
ALT_ACCEPTANCE_M = (
    3.0  # climb to the follow height before moving horizontally (PX4's ALT_ACCEPTANCE_THRESHOLD)
)
MIN_DISTANCE_FOR_YAW_M = 1.0  # closer than this to the target: keep the heading
RS_TIME_CONSTANT_S = 10.0  # FLW_TGT_RS 0.1 -> a 1 s position filter

# (track index, sim time) -> (north, east, v_north, v_east) of that ground-truth track, None when it is absent
TrackLookup = Callable[[int, float], "tuple[float, float, float, float] | None"]


@dataclass(frozen=True)
class FollowTarget:
    """A target observation in NED (m, m/s) at sim time `time_s`."""

    north_m: float
    east_m: float
    down_m: float  # NaN: unknown (2D)
    vel_ned_m_s: tuple[float, float, float]
    time_s: float


class FollowTargetTask:
    def __init__(self, ctx: FlightContext) -> None:
        self.ctx = ctx
        self.target: FollowTarget | None = None  # the latest FOLLOW_TARGET
        self.track_lookup: TrackLookup | None = None
        self.targets_received = 0
        self._filtered: tuple[float, float] | None = None
        self._course: tuple[float, float] = (1.0, 0.0)  # unit (north, east)
        self._hold: tuple[float, float, float] | None = None
        self._lost_warned = False
        self._track_warned = -2
        self.following: tuple[float, float, float] | None = None  # the (filtered) target on the ground, NED

    def set_target(self, target: FollowTarget) -> None:
        self.target = target
        self.targets_received += 1
        self._lost_warned = False

    def activate(self, now_s: float) -> None:
        ctx = self.ctx
        self._filtered = None
        self.following = None
        # PX4: before the target's course is known, stand on the side the vehicle faces from
        self._course = (math.cos(ctx.yaw), math.sin(ctx.yaw))
        pos = ctx.pos
        self._hold = (float(pos[0]), float(pos[1]), float(pos[2]))
        self._lost_warned = False

    def _observation(self, now_s: float) -> FollowTarget | None:
        """The target to follow now: the ground-truth track (FLW_TGT_TRACK >= 0) or the latest fresh message."""
        track = round(self.ctx.params.get("FLW_TGT_TRACK"))
        if track >= 0:
            hit = self.track_lookup(track, now_s) if self.track_lookup is not None else None
            if hit is None:
                if self._track_warned != track:
                    self._track_warned = track
                    why = "no ground truth" if self.track_lookup is None else "absent now"
                    self.ctx.event(Severity.WARNING, f"Follow target: track {track} {why}, holding")
                return None
            self._track_warned = -2
            n, e, vn, ve = hit
            return FollowTarget(n, e, math.nan, (vn, ve, 0.0), now_s)
        t = self.target
        if t is None or now_s - t.time_s > TARGET_TIMEOUT_S:
            if not self._lost_warned and (t is not None or self.ctx.armed):
                self._lost_warned = True
                self.ctx.event(Severity.WARNING, "Follow target: no target position, holding")
            return None
        dt = max(0.0, now_s - t.time_s)  # predicted forward between messages (PX4's target estimator)
        v = t.vel_ned_m_s
        return FollowTarget(t.north_m + v[0] * dt, t.east_m + v[1] * dt, t.down_m, v, now_s)

    def update(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        ctx = self.ctx
        p = ctx.params
        lim = limits(ctx, xy=p.get("MPC_XY_VEL_MAX"), auto=True)
        obs = self._observation(now_s)
        pos = state.pos_ned_m
        self.following = None
        if obs is None:
            if self._hold is None:
                self._hold = (float(pos[0]), float(pos[1]), float(pos[2]))
            sp = TrajectorySetpoint(pos_ned_m=self._hold)
            return run_position(ctx, dt, state, sp, lim, eav, None, yaw_rate_auto(ctx))
        # filter (FLW_TGT_RS); its input is predicted one time constant ahead, which cancels the filter's lag for a
        # target at constant velocity (as PX4 predicts the target before its filter)
        tau = max(0.0, p.get("FLW_TGT_RS")) * RS_TIME_CONSTANT_S
        vn, ve = obs.vel_ned_m_s[0], obs.vel_ned_m_s[1]
        if self._filtered is None or tau <= 0.0:
            self._filtered = (obs.north_m, obs.east_m)
        else:
            k = dt / (tau + dt)
            fn, fe = self._filtered
            self._filtered = (fn + k * (obs.north_m + vn * tau - fn), fe + k * (obs.east_m + ve * tau - fe))
        tn, te = self._filtered
        ground = float(ctx.home[2]) if not math.isfinite(obs.down_m) else obs.down_m
        self.following = (tn, te, ground)
        speed = math.hypot(vn, ve)
        if speed > MIN_SPEED_FOR_COURSE_M_S:
            self._course = (vn / speed, ve / speed)
        angle = math.radians(p.get("FLW_TGT_FA"))
        cn, ce = self._course
        on = cn * math.cos(angle) - ce * math.sin(angle)  # the course turned clockwise by the follow angle
        oe = cn * math.sin(angle) + ce * math.cos(angle)
        dist = p.get("FLW_TGT_DST")
        height = p.get("FLW_TGT_HT")
        if round(p.get("FLW_TGT_ALT_M")) == 2 and math.isfinite(obs.down_m):
            down = obs.down_m - height
        else:
            down = float(ctx.home[2]) - height
        want = (tn + on * dist, te + oe * dist, down)
        if abs(down - float(pos[2])) > ALT_ACCEPTANCE_M:  # height first, then horizontally
            hold_xy = self._hold if self._hold is not None else (float(pos[0]), float(pos[1]), down)
            sp = TrajectorySetpoint(pos_ned_m=(hold_xy[0], hold_xy[1], down))
        else:
            self._hold = want
            ff = (vn, ve, 0.0) if speed > MIN_SPEED_FOR_COURSE_M_S else (0.0, 0.0, 0.0)
            sp = TrajectorySetpoint(pos_ned_m=want, vel_ned_m_s=ff)
        to_n, to_e = tn - float(pos[0]), te - float(pos[1])
        yaw = math.atan2(to_e, to_n) if math.hypot(to_n, to_e) > MIN_DISTANCE_FOR_YAW_M else None
        return run_position(ctx, dt, state, sp, lim, eav, yaw, yaw_rate_auto(ctx))
