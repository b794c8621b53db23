#!/usr/bin/env python3
"""Offboard velocity pattern — a square in the NED frame, then a leg in the body frame — with MAVSDK-Python 4.x.

1. take off (AUTO.TAKEOFF) to --altitude;
2. OFFBOARD with velocity setpoints (SET_POSITION_TARGET_LOCAL_NED, frame LOCAL_NED): fly a square of --side metres
   north, east, south, west at up to --speed m/s; each leg ends when the telemetry says the corner is reached, and
   the corner, the cross-track error and the altitude are checked;
3. turn to face 90 deg right of the start heading, then fly --side metres "forward" with a body-frame velocity
   (frame BODY_NED): the vehicle must move along its new heading;
4. leave offboard (Hold), land, wait for touchdown and auto-disarm.

    viva-sitl run &
    python mavsdk_offboard_velocity.py --side 10 --speed 2

Waits are telemetry conditions; the only sleeps pace the setpoint stream. Exit status 0 on success, 1 on failure.
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

from _mission import (
    MissionFailed,
    Tracker,
    add_time_limits,
    first_autopilot,
    log,
    run_flight,
    script_parser,
    stop_and_land,
    stream_until,
    takeoff,
)
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, OffboardError, VelocityBodyYawspeed, VelocityNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

SLOWDOWN_GAIN_1_S = (
    1.0  # commanded speed = gain * remaining distance near a corner, so legs end without overshoot
)
ARRIVED_M = 0.3


def wrap_deg(angle_deg: float) -> float:
    return (angle_deg + 180.0) % 360.0 - 180.0


async def fly(args: argparse.Namespace) -> dict[str, Any]:
    async with first_autopilot(args.url, args.step_timeout) as system:
        telemetry, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        async with Tracker(telemetry).running(args.step_timeout) as tracker:
            await takeoff(tracker, telemetry, action, args.altitude, args.step_timeout)
            result = await pattern(args, tracker, offboard)
            await stop_and_land(tracker, action, offboard, args.step_timeout)
            return result


async def pattern(args: argparse.Namespace, tr: Tracker, offboard: OffboardAsync) -> dict[str, Any]:
    step = args.step_timeout
    yaw0 = tr.yaw_deg
    alt0 = tr.alt_m
    await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, yaw0))
    try:
        await offboard.start()
    except OffboardError as exc:
        raise MissionFailed(f"offboard refused: {exc}") from exc
    await tr.wait_until(lambda: tr.mode == FlightMode.OFFBOARD, step, "flight mode OFFBOARD")
    log("offboard (velocity) active")

    # --- the square, NED frame -------------------------------------------------------------------------------
    n0, e0, _ = tr.ned
    corner = (n0, e0)
    max_cross_m = max_alt_dev_m = max_corner_err_m = 0.0
    for name, (dn, de) in (("north", (1, 0)), ("east", (0, 1)), ("south", (-1, 0)), ("west", (0, -1))):
        start = corner
        corner = (start[0] + dn * args.side, start[1] + de * args.side)
        target = corner

        def remaining(target: tuple[float, float] = target) -> tuple[float, float]:
            n, e, _ = tr.ned
            return target[0] - n, target[1] - e

        async def send(dn: int = dn, de: int = de, start: tuple[float, float] = start) -> None:
            nonlocal max_cross_m, max_alt_dev_m
            rn, re = remaining()
            dist = math.hypot(rn, re)
            speed = min(args.speed, SLOWDOWN_GAIN_1_S * dist)
            n, e, _ = tr.ned
            max_cross_m = max(max_cross_m, abs(-(n - start[0]) * de + (e - start[1]) * dn))
            max_alt_dev_m = max(max_alt_dev_m, abs(tr.alt_m - alt0))
            vn, ve = (speed * rn / dist, speed * re / dist) if dist > 1e-6 else (0.0, 0.0)
            await offboard.set_velocity_ned(VelocityNedYaw(vn, ve, 0.0, yaw0))

        await stream_until(
            tr,
            send,
            lambda: math.hypot(*remaining()) < ARRIVED_M and math.hypot(*tr.vel[:2]) < 0.3,
            step,
            f"the {name} corner ({target[0]:.1f}, {target[1]:.1f}) m",
        )
        n, e, _ = tr.ned
        err = math.hypot(n - target[0], e - target[1])
        max_corner_err_m = max(max_corner_err_m, err)
        log(f"leg {name}: at ({n:.2f}, {e:.2f}) m, corner error {err:.2f} m")
    n, e, _ = tr.ned
    closure_m = math.hypot(n - n0, e - e0)
    if max_cross_m > args.tolerance:
        raise MissionFailed(f"cross-track error {max_cross_m:.2f} m exceeds {args.tolerance} m")
    if max_alt_dev_m > args.tolerance:
        raise MissionFailed(f"altitude deviated {max_alt_dev_m:.2f} m while flying the square")
    if closure_m > args.tolerance:
        raise MissionFailed(f"the square did not close: {closure_m:.2f} m from the start")
    log(f"square done: closure {closure_m:.2f} m, max cross-track {max_cross_m:.2f} m")

    # --- turn right 90 deg, then fly forward in the body frame ------------------------------------------------
    yaw1 = wrap_deg(yaw0 + 90.0)

    async def turn() -> None:
        await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, yaw1))

    await stream_until(
        tr, turn, lambda: abs(wrap_deg(tr.yaw_deg - yaw1)) < 3.0, step, f"heading {yaw1:.0f} deg"
    )
    log(f"turned to {tr.yaw_deg:.1f} deg")
    bn, be, _ = tr.ned
    heading = (math.cos(math.radians(yaw1)), math.sin(math.radians(yaw1)))

    def forward_m() -> float:
        n, e, _ = tr.ned
        return (n - bn) * heading[0] + (e - be) * heading[1]

    async def forward() -> None:
        speed = min(args.speed, SLOWDOWN_GAIN_1_S * (args.side - forward_m()))
        await offboard.set_velocity_body(VelocityBodyYawspeed(max(speed, 0.0), 0.0, 0.0, 0.0))

    await stream_until(
        tr,
        forward,
        lambda: forward_m() > args.side - ARRIVED_M and math.hypot(*tr.vel[:2]) < 0.3,
        step,
        f"{args.side:.1f} m forward in the body frame",
    )
    n, e, _ = tr.ned
    body_m = math.hypot(n - bn, e - be)
    body_dir_deg = math.degrees(math.atan2(e - be, n - bn))
    body_dir_err_deg = abs(wrap_deg(body_dir_deg - yaw1))
    log(f"body-frame leg: {body_m:.2f} m towards {body_dir_deg:.1f} deg (heading {yaw1:.1f} deg)")
    if body_dir_err_deg > 10.0 or abs(body_m - args.side) > args.tolerance:
        raise MissionFailed(
            f"body-frame leg went {body_m:.2f} m towards {body_dir_deg:.1f} deg; expected {args.side:.1f} m "
            f"towards {yaw1:.1f} deg"
        )
    return {
        "square_closure_m": round(closure_m, 3),
        "max_corner_err_m": round(max_corner_err_m, 3),
        "max_cross_track_m": round(max_cross_m, 3),
        "max_alt_dev_m": round(max_alt_dev_m, 3),
        "body_leg_m": round(body_m, 3),
        "body_dir_err_deg": round(body_dir_err_deg, 2),
        "final_north_m": round(n, 3),
        "final_east_m": round(e, 3),
    }


def main() -> int:
    parser = script_parser(__doc__, "udpin://0.0.0.0:14540", "MAVSDK connection URL")
    parser.add_argument("--altitude", type=float, default=10.0, help="takeoff altitude, m")
    parser.add_argument("--side", type=float, default=10.0, help="side of the square and body-frame leg, m")
    parser.add_argument("--speed", type=float, default=2.0, help="cruise speed, m/s")
    parser.add_argument(
        "--tolerance", type=float, default=1.5, help="accepted path / corner / altitude error, m"
    )
    add_time_limits(parser, 240.0)
    args = parser.parse_args()
    return run_flight(fly(args), args.timeout)


if __name__ == "__main__":
    sys.exit(main())
