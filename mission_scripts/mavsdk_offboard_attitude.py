#!/usr/bin/env python3
"""Offboard attitude control — hover, tilt, climb — with MAVSDK-Python 4.x (`pip install mavsdk`).

Flies the vehicle directly with attitude + thrust setpoints (SET_ATTITUDE_TARGET), the way a learned or hand-written
low-level controller would, and checks that the telemetry reacts as physics says it should:

1. take off (AUTO.TAKEOFF) to --altitude and settle;
2. OFFBOARD, level at the hover thrust (read from PX4's MPC_THR_HOVER, 0.5 by default): the altitude must hold;
3. pitch nose-down by --tilt-deg (thrust raised by 1/cos(tilt) to keep the lift): the vehicle must move forward
   along its heading by --tilt-distance, then it pitches back to brake;
4. level with --climb-thrust: the vehicle must climb by --climb;
5. leave offboard (Hold), land, wait for touchdown and auto-disarm.

    viva-sitl run &
    python mavsdk_offboard_attitude.py                  # default udpin://0.0.0.0:14540

Waits are telemetry conditions; the only sleeps pace the setpoint stream. Exit status 0 on success, 1 on failure.
"""

from __future__ import annotations

import argparse
import asyncio
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
from mavsdk.asyncio.plugins.offboard import Attitude, OffboardAsync, OffboardError
from mavsdk.asyncio.plugins.param import ParamAsync, ParamError
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync


async def fly(args: argparse.Namespace) -> dict[str, Any]:
    async with first_autopilot(args.url, args.step_timeout) as system:
        telemetry, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        async with Tracker(telemetry).running(args.step_timeout) as tracker:
            if (
                args.hover_thrust is None
            ):  # the autopilot's own hover thrust, as PX4's position controller uses it
                try:
                    args.hover_thrust = float(await ParamAsync(system).get_param_float("MPC_THR_HOVER"))
                except ParamError as exc:
                    raise MissionFailed(f"cannot read MPC_THR_HOVER ({exc}); pass --hover-thrust") from exc
            log(f"hover thrust {args.hover_thrust:.3f} (MPC_THR_HOVER)")
            return await _fly(args, tracker, telemetry, action, offboard)


async def _fly(
    args: argparse.Namespace,
    tr: Tracker,
    telemetry: TelemetryAsync,
    action: ActionAsync,
    offboard: OffboardAsync,
) -> dict[str, Any]:
    step = args.step_timeout
    await takeoff(tr, telemetry, action, args.altitude, step, still_m_s=0.1,
                  still_what="in air and still (< 0.1 m/s) after takeoff: open-loop thrust would keep any residual "
                  "climb")  # fmt: skip
    yaw_deg = tr.yaw_deg
    alt0 = tr.alt_m

    # Offboard needs a setpoint before start(); MAVSDK then keeps re-sending the latest one at 20 Hz.
    level = Attitude(0.0, 0.0, yaw_deg, args.hover_thrust)
    await offboard.set_attitude(level)
    try:
        await offboard.start()
    except OffboardError as exc:
        raise MissionFailed(f"offboard refused: {exc}") from exc
    await tr.wait_until(lambda: tr.mode == FlightMode.OFFBOARD, step, "flight mode OFFBOARD")
    log("offboard (attitude) active")

    # 1. Hover at the hover thrust: altitude must hold.
    hover_end = asyncio.get_running_loop().time() + args.hover_s
    max_dev = 0.0

    def hover_done() -> bool:
        nonlocal max_dev
        max_dev = max(max_dev, abs(tr.alt_m - alt0))
        return asyncio.get_running_loop().time() >= hover_end

    await stream_until(
        tr, lambda: offboard.set_attitude(level), hover_done, args.hover_s + step, "the hover phase"
    )
    if max_dev > args.alt_tolerance:
        raise MissionFailed(f"altitude not held at thrust {args.hover_thrust}: drifted {max_dev:.2f} m")
    log(f"hover held: max altitude deviation {max_dev:.2f} m")

    # 2. Tilt nose-down: move forward along the heading.
    fwd = (math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg)))
    n0, e0, _ = tr.ned
    alt_tilt0 = tr.alt_m

    def forward_m() -> float:
        n, e, _ = tr.ned
        return (n - n0) * fwd[0] + (e - e0) * fwd[1]

    def lateral_m() -> float:
        n, e, _ = tr.ned
        return -(n - n0) * fwd[1] + (e - e0) * fwd[0]

    tilt_thrust = min(1.0, args.hover_thrust / math.cos(math.radians(args.tilt_deg)))
    await stream_until(
        tr,
        lambda: offboard.set_attitude(Attitude(0.0, -args.tilt_deg, yaw_deg, tilt_thrust)),
        lambda: forward_m() >= args.tilt_distance,
        step,
        f"{args.tilt_distance:.1f} m of forward travel while pitched {-args.tilt_deg:.1f} deg",
    )
    moved, drift = forward_m(), lateral_m()
    log(f"tilted: moved {moved:.2f} m forward, {drift:.2f} m sideways")

    def forward_speed() -> float:
        vn, ve, _ = tr.vel
        return vn * fwd[0] + ve * fwd[1]

    await stream_until(
        tr,
        lambda: offboard.set_attitude(Attitude(0.0, args.tilt_deg, yaw_deg, tilt_thrust)),
        lambda: forward_speed() <= 0.2,
        step,
        "braking to < 0.2 m/s",
    )
    tilt_alt_change = tr.alt_m - alt_tilt0
    if abs(drift) > 0.5 * moved + 1.0:
        raise MissionFailed(f"tilt moved the vehicle sideways: {drift:.2f} m for {moved:.2f} m forward")
    if abs(tilt_alt_change) > 2 * args.alt_tolerance:
        raise MissionFailed(f"altitude changed {tilt_alt_change:.2f} m during the tilt (compensated thrust)")
    log(f"braked: travelled {forward_m():.2f} m forward in total")

    # 3. Climb with more thrust, level.
    alt_climb0 = tr.alt_m
    max_climb_rate = 0.0

    def climbed() -> bool:
        nonlocal max_climb_rate
        max_climb_rate = max(max_climb_rate, -tr.vel[2])
        return tr.alt_m >= alt_climb0 + args.climb

    await stream_until(
        tr,
        lambda: offboard.set_attitude(Attitude(0.0, 0.0, yaw_deg, args.climb_thrust)),
        climbed,
        step,
        f"a {args.climb:.1f} m climb at thrust {args.climb_thrust}",
    )
    log(f"climbed {tr.alt_m - alt_climb0:.2f} m (peak climb rate {max_climb_rate:.2f} m/s)")

    await stop_and_land(tr, action, offboard, step)
    return {
        "hover_thrust": round(args.hover_thrust, 4),
        "hover_max_dev_m": round(max_dev, 3),
        "tilt_forward_m": round(moved, 3),
        "tilt_lateral_m": round(drift, 3),
        "climb_rate_max_m_s": round(max_climb_rate, 3),
    }


def main() -> int:
    parser = script_parser(__doc__, "udpin://0.0.0.0:14540", "MAVSDK connection URL")
    parser.add_argument("--altitude", type=float, default=10.0, help="takeoff altitude, m")
    parser.add_argument(
        "--hover-thrust", type=float, default=0.5, help="thrust that hovers (PX4 MPC_THR_HOVER)"
    )
    parser.add_argument("--hover-s", type=float, default=2.0, help="how long to hover level, wall seconds")
    parser.add_argument(
        "--alt-tolerance", type=float, default=1.5, help="accepted altitude drift while hovering, m"
    )
    parser.add_argument("--tilt-deg", type=float, default=8.0, help="nose-down pitch, deg")
    parser.add_argument(
        "--tilt-distance", type=float, default=5.0, help="forward travel to reach while tilted, m"
    )
    parser.add_argument("--climb-thrust", type=float, default=0.6, help="thrust for the climb, 0..1")
    parser.add_argument("--climb", type=float, default=3.0, help="height to gain, m")
    add_time_limits(parser, 180.0)
    args = parser.parse_args()
    return run_flight(fly(args), args.timeout)


if __name__ == "__main__":
    sys.exit(main())
