#!/usr/bin/env python3
"""Vision landing companion: on "land now", look, pick the lowest-risk spot in view, fly there in offboard, land.

MAVSDK-Python 4.x (native asyncio API) for the flight, the frame-and-pose socket (ZeroMQ, `viva_sitl.video`) for
the camera, and the perception extra (`pip install 'viva-sitl[perception]'`) for the eyes:

- the risk U-Net (`--segmenter unet.pt`, from `viva-sitl perception train-segmenter`): risk level 1..5 per pixel,
  mapped onto the ground through the frame's pose (`Segmenter.on_ground`);
- the YOLO detector (`--detector best.pt|.onnx`, extra perception-yolo): people and vehicles, each put on the ground
  and surrounded by a keep-out disc (`--person-buffer-m`, `--vehicle-buffer-m`) of level 5.

Either model may be left out (the other one is used alone, and the script says so); at least one is needed. It never
reads ground truth: only the camera image, the pose the frame socket sends with it, and MAVLink telemetry.

The landing: OFFBOARD position setpoints (NED, streamed at 20 Hz by their own task) hold the vehicle while it looks;
the spot is the seen cell within `--search-radius-m` with the lowest risk level in a `--margin-m` disc around it,
then the largest clearance from level-4/5 ground (up to `--clearance-cap-m`), then the shortest flight. It flies
there at its altitude, then descends over it to `--approach-alt`; every new frame on the way re-checks the spot and
re-plans from the current view when it turns risky (a person walks in). At `--approach-alt` it hands over to
AUTO.LAND and waits for touchdown and the disarm.

The trigger:
- in landing trials (`viva-sitl trials run SPEC --frames --pilot "{python} mission_scripts/vision_landing.py ..."`)
  the scenario file in VIVA_SITL_SCENARIO: a ground start takes off to the scenario's altitude first; "land now"
  is the "Emergency: land now" STATUSTEXT, or the frame clock reaching the scenario's land_at_s;
- by hand: `--now` (land at once), else it waits for that STATUSTEXT.

Connection: the MAVSDK URL (argument, else VIVA_SITL_MAVSDK_URL, else PX4's udpin://0.0.0.0:14540) and the frame
socket (`--frames`, else VIVA_SITL_FRAME_SOCKET, else tcp://127.0.0.1:5700), as `viva-sitl trials` passes them.

    viva-sitl run --footage synthetic --pose 10,-20,25 &         # any airborne vehicle
    python mission_scripts/vision_landing.py --now --segmenter unet.pt [--detector best.pt]

Exit status 0 landed (RESULT line), 1 failed (FAILED: line), 2 bad arguments or weights (one line), 130 Ctrl-C.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import sys
import time
from collections.abc import AsyncGenerator, Callable
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from _mission import (
    SETPOINT_PERIOD_S,
    MissionFailed,
    Tracker,
    arm_and_take_off,
    failed,
    first_autopilot,
    log,
    print_result,
)
from numpy.typing import NDArray

try:
    from viva_sitl.perception.errors import PerceptionError
    from viva_sitl.perception.landing_spot import Eyes, PlanConfig, RiskView, Spot, check_spot, choose_spot
except ImportError as _exc:  # one line, not a traceback
    print(f"vision_landing: viva_sitl is not importable ({_exc}): pip install 'viva-sitl[perception]'",
          file=sys.stderr)  # fmt: skip
    sys.exit(2)

LAND_NOW_TEXT = "land now"  # the trials' STATUSTEXT is "Emergency: land now"
MAX_REENGAGE = 2  # times OFFBOARD is taken back after the vehicle's offboard-loss failsafe
STALL_S = 0.25  # a 20 Hz re-send gap this long (wall s): this process was starved (COM_OF_LOSS_T 1 s / speed)


def load_models(args: argparse.Namespace) -> tuple[Any | None, Any | None]:
    """(segmenter, detector); PerceptionError (one line) for a missing or foreign file or a missing extra."""
    if not args.segmenter and not args.detector:
        raise PerceptionError("no model: give --segmenter PATH (risk U-Net) and/or --detector PATH (YOLO)")
    seg = det = None
    if args.segmenter:
        from viva_sitl.perception.errors import require_torch

        torch = require_torch()
        torch.set_num_threads(args.threads)
        from viva_sitl.perception.segment import Segmenter

        seg = Segmenter.load(args.segmenter)
    if args.detector:
        from viva_sitl.perception.detect import Detector

        det = Detector(args.detector, conf=args.conf, imgsz=args.imgsz)
        # warm-up before the trigger: ultralytics' first predict sets itself up (4.4 s measured at load 6.5),
        # which would otherwise delay the first look after "land now"
        det.detect(np.zeros((480, 640, 3), np.uint8))
    if seg is None:
        log("no --segmenter: ground risk from detections only (seen ground counts as level 1)")
    if det is None:
        log(
            "no --detector: ground risk from the segmenter only (people/vehicles as it sees them, no keep-out)"
        )
    return seg, det


# ---------------------------------------------------------------------------------------------------- flight


def offboard_loss_text(text: str) -> bool:
    """PX4's (and viva-sitl's) failsafe STATUSTEXT for a setpoint stream that stopped."""
    t = text.lower()
    return "offboard" in t and ("lost" in t or "loss" in t or "no offboard" in t)


class LandingTracker(Tracker):
    """The telemetry (a lost link fails every wait), and the vehicle's STATUSTEXTs: "land now" and the others."""

    def __init__(self, telemetry: Any, link_timeout_s: float) -> None:
        super().__init__(telemetry, link_timeout_s)
        self.land_now = False
        self.texts: list[str] = []  # the vehicle's STATUSTEXTs since the last take_texts()

    def streams(self) -> list[tuple[str, AsyncGenerator[Any, None]]]:
        return [*super().streams(), ("text", self._telemetry.subscribe_status_text())]

    def received(self, name: str, value: Any) -> None:
        if name != "text":
            super().received(name, value)
        elif LAND_NOW_TEXT in value.text.lower():
            self.land_now = True
        else:
            self.texts = [*self.texts[-7:], value.text]

    def take_texts(self) -> list[str]:
        texts, self.texts = self.texts, []
        return texts


class Camera:
    """The frame-and-pose socket, read off the event loop (the newest frame only)."""

    def __init__(self, endpoint: str) -> None:
        from viva_sitl.video import FrameClient

        self.endpoint = endpoint
        self.client = FrameClient(endpoint, latest_only=True)
        self.last_sim_time_s = -math.inf

    async def fresh(self, timeout_s: float, after_sim_s: float = -math.inf) -> tuple[NDArray[np.uint8], dict[str, Any]]:  # fmt: skip
        """The newest frame rendered after `after_sim_s` (sim time); MissionFailed after timeout_s wall."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            item = await asyncio.to_thread(self.client.receive, 0.25)
            if item is None:
                continue
            image, meta = item
            t = float(meta.get("sim_time_s", 0.0))
            self.last_sim_time_s = max(self.last_sim_time_s, t)
            if t > after_sim_s:
                return image, meta
        raise MissionFailed(
            f"no camera frame on {self.endpoint} within {timeout_s:.0f} s (is the frame socket on? "
            "`viva-sitl run` serves it unless --no-video; `viva-sitl trials run` needs --frames or trials.frames)"
        )

    def close(self) -> None:
        self.client.close()


class Setpoint:
    """The offboard position setpoint, re-sent at 20 Hz by its own task whatever the planner is doing."""

    def __init__(self, offboard: Any, yaw_deg: float) -> None:
        from mavsdk.asyncio.plugins.offboard import PositionNedYaw

        self._cls = PositionNedYaw
        self.offboard = offboard
        self.yaw_deg = yaw_deg
        self.target: tuple[float, float, float] | None = None
        self._task: asyncio.Task[None] | None = None
        self.stall_s = (
            0.0  # the last gap between two re-sends longer than STALL_S (this process was starved) ...
        )
        self.stall_end = -math.inf  # ... and when it ended (monotonic s)

    async def set(self, north_m: float, east_m: float, down_m: float) -> None:
        self.target = (north_m, east_m, down_m)
        await self.offboard.set_position_ned(self._cls(north_m, east_m, down_m, self.yaw_deg))

    def stalled(self, within_s: float = 5.0) -> float:
        """The stall that ended in the last `within_s` (0.0: none): a freeze of the whole process, MAVSDK's own
        20 Hz re-send thread included, that the vehicle sees as a lost setpoint stream."""
        return self.stall_s if time.monotonic() - self.stall_end < within_s else 0.0

    async def _run(self) -> None:
        prev = time.monotonic()
        while True:
            now = time.monotonic()
            if now - prev > STALL_S:
                self.stall_s, self.stall_end = now - prev, now
            prev = now
            if self.target is not None:
                with contextlib.suppress(Exception):  # a refused re-send is seen by the mode check
                    await self.offboard.set_position_ned(self._cls(*self.target, self.yaw_deg))
            await asyncio.sleep(SETPOINT_PERIOD_S)

    def start(self) -> None:
        self._task = asyncio.create_task(self._run())

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
            self._task = None


class Companion:
    def __init__(self, args: argparse.Namespace, eyes: Eyes, cfg: PlanConfig, scenario: dict[str, Any] | None) -> None:  # fmt: skip
        self.args, self.eyes, self.cfg, self.scenario = args, eyes, cfg, scenario
        self.replans = 0
        self.looks = 0

    async def look(self, cam: Camera, tr: LandingTracker, after_sim_s: float) -> RiskView:
        deadline = time.monotonic() + self.args.frame_timeout
        while True:
            tr.check_link()
            image, meta = await cam.fresh(max(0.5, deadline - time.monotonic()), after_sim_s)
            try:
                view = await asyncio.to_thread(self.eyes.look, image, meta)
            except PerceptionError as exc:  # e.g. tilted so far (braking) that the view reaches the horizon
                if time.monotonic() > deadline:
                    raise MissionFailed(
                        f"no usable frame for {self.args.frame_timeout:.0f} s: {exc}"
                    ) from None
                after_sim_s = float(meta.get("sim_time_s", after_sim_s))
                continue
            self.looks += 1
            return view

    async def wait_trigger(self, tr: LandingTracker, cam: Camera, mode_name: Callable[[], str]) -> None:
        land_at = None if self.scenario is None else self.scenario.get("land_at_s")
        if self.args.now:
            log("--now: landing at once")
            return
        log("waiting for 'land now' (STATUSTEXT" + (f", or frame clock {land_at:g} s)" if land_at else ")"))
        while not tr.land_now:
            tr.check_link()
            if land_at is not None:
                with contextlib.suppress(MissionFailed):
                    await cam.fresh(0.3)
                if cam.last_sim_time_s >= float(land_at):
                    log(f"land-now time reached on the frame clock ({cam.last_sim_time_s:.1f} s)")
                    return
            else:
                await asyncio.sleep(0.1)
        log(f"'land now' received (mode {mode_name()})")

    async def land(self, tr: LandingTracker, cam: Camera, action: Any, offboard: Any) -> dict[str, Any]:
        from mavsdk.asyncio.plugins.telemetry import FlightMode

        args, cfg = self.args, self.cfg
        sp = Setpoint(offboard, float(tr.values["euler"].yaw_deg))
        n0, e0, d0 = tr.ned
        await sp.set(n0, e0, d0)  # hold here first: PX4 wants a setpoint stream (> 2 Hz) before OFFBOARD
        sp.start()
        reengaged = 0
        try:
            await self._engage(tr, offboard)
            log(f"offboard: holding at ({n0:.1f}, {e0:.1f}) m, {-d0:.1f} m up; looking")
            look_down = d0
            t_sim = cam.last_sim_time_s
            view = await self.look(cam, tr, t_sim)
            spot = self._plan(view, tr)
            cruise = True
            strikes = 0
            while True:
                if tr.values["mode"] != FlightMode.OFFBOARD:
                    # the failsafe's STATUSTEXT comes with the mode change but through another stream: wait a moment
                    with contextlib.suppress(MissionFailed):
                        await tr.wait_until(lambda: any(map(offboard_loss_text, tr.texts)), 2.0, "the reason")
                    texts = tr.take_texts()
                    why = next((t for t in reversed(texts) if offboard_loss_text(t)), None)
                    stall_s = sp.stalled()
                    if why is None and stall_s > STALL_S:  # frozen: the failsafe's text was likely lost too
                        why = f"this process stalled {stall_s:.1f} s, longer than a setpoint stream may pause"
                    if why is not None and reengaged < MAX_REENGAGE:
                        # PX4's offboard-loss failsafe: our setpoints stopped reaching it for COM_OF_LOSS_T (a
                        # starved machine); nobody else asked for the mode change, so take control back
                        reengaged += 1
                        log(f"left OFFBOARD ({why}); re-engaging OFFBOARD ({reengaged}/{MAX_REENGAGE})")
                        await self._engage(tr, offboard)
                        continue
                    said = f"; vehicle said {texts[-3:]}" if texts else ""
                    raise MissionFailed(f"left OFFBOARD (now {tr.values['mode'].name}) while landing{said}")
                n, e, d = tr.ned
                horiz = math.hypot(n - spot.north_m, e - spot.east_m)
                if cruise and horiz < args.arrive_radius and math.hypot(*tr.vel[:2]) < 0.5:
                    cruise = False
                    log(f"over the spot at {-d:.1f} m: descending to {args.approach_alt:g} m, re-checking")
                down = look_down if cruise else -args.approach_alt
                if sp.target != (spot.north_m, spot.east_m, down):
                    await sp.set(spot.north_m, spot.east_m, down)
                if not cruise and -d <= args.approach_alt + 0.3 and horiz < args.arrive_radius:
                    break
                view = await self.look(cam, tr, view.sim_time_s)
                now = check_spot(view, spot, cfg)
                if now is None:
                    continue  # not in this view (yet): keep going
                level, clear = now
                risky = level > max(spot.level, cfg.accept_level)
                strikes = strikes + 1 if risky else 0
                # two looks in a row (not one noisy frame), and at most --max-replans times
                if strikes >= 2 and self.replans < args.max_replans:
                    strikes = 0
                    self.replans += 1
                    log(f"spot ({spot.north_m:.1f}, {spot.east_m:.1f}) now level {level} (was {spot.level}): "
                        f"re-planning ({self.replans}/{args.max_replans})")  # fmt: skip
                    new = choose_spot(view, (n, e), cfg)
                    if new is None or new.level > cfg.accept_level and -d < -look_down - 1.0:
                        log(
                            f"nothing acceptable in the low view: climbing back to {-look_down:.1f} m to look"
                        )
                        await sp.set(n, e, look_down)
                        await tr.wait_until(lambda d0=look_down: abs(tr.ned[2] - d0) < 1.0, args.step_timeout,
                                            "the climb back to the look altitude")  # fmt: skip
                        view = await self.look(cam, tr, view.sim_time_s)
                        new = choose_spot(view, tr.ned[:2], cfg) or new
                    if new is None:
                        raise MissionFailed("no ground seen to land on")
                    spot = self._log_spot(new, view)
                    if self.replans == args.max_replans:  # an emergency landing must end on the ground
                        log(f"{self.replans} re-plans: committing to this spot (no more re-plans)")
                    cruise = True
                    look_down = tr.ned[2]  # fly the new leg at the current height
            final = check_spot(view, spot, cfg)
            log(f"at {tr.alt_m:.1f} m over the spot (level now {final[0] if final else '?'}): AUTO.LAND")
            await self._command_land(tr, action)  # the setpoints keep flowing until LAND has taken over
        finally:
            await sp.stop()
        from mavsdk.asyncio.plugins.telemetry import LandedState

        await tr.wait_until(
            lambda: tr.values["landed"] == LandedState.ON_GROUND, args.step_timeout, "touchdown"
        )
        await tr.wait_until(lambda: not tr.values["armed"], args.step_timeout, "auto-disarm after landing")
        n, e, _ = tr.ned
        log(f"landed and disarmed at ({n:.2f}, {e:.2f}) m")
        return {
            "touchdown_north_m": round(n, 2), "touchdown_east_m": round(e, 2),
            "spot_north_m": round(spot.north_m, 2), "spot_east_m": round(spot.east_m, 2),
            "spot_level": spot.level, "replans": self.replans, "looks": self.looks,
        }  # fmt: skip

    async def _engage(self, tr: LandingTracker, offboard: Any) -> None:
        """OFFBOARD with the setpoint stream already flowing; a refused or unacknowledged start is retried."""
        from mavsdk.asyncio.plugins.offboard import OffboardError
        from mavsdk.asyncio.plugins.telemetry import FlightMode

        for attempt in range(1, 6):
            # a few setpoints out first (wall time: on a loaded machine the stream needs it)
            await asyncio.sleep(0.5)
            try:
                await offboard.start()
                break
            except OffboardError as exc:
                if tr.values["mode"] == FlightMode.OFFBOARD:  # it switched; only the ACK was lost
                    break
                if attempt == 5:
                    raise MissionFailed(f"offboard refused: {exc}") from exc
                log(f"offboard start: {exc}; retrying")
        await tr.wait_until(
            lambda: tr.values["mode"] == FlightMode.OFFBOARD, self.args.step_timeout, "OFFBOARD"
        )

    async def _command_land(self, tr: LandingTracker, action: Any) -> None:
        """AUTO.LAND; a lost COMMAND_ACK (a loaded link) is retried, and a mode already LAND counts as done."""
        from mavsdk.asyncio.plugins.action import ActionError
        from mavsdk.asyncio.plugins.telemetry import FlightMode

        def landing() -> bool:  # the command took effect even if its ACK was lost (or it already landed)
            return bool(tr.values["mode"] == FlightMode.LAND or not tr.values["armed"])

        attempts = 6  # a starved machine can lose several ACKs in a row; the mode check sees what happened
        for attempt in range(1, attempts + 1):
            try:
                await action.land()
                return
            except ActionError as exc:
                with contextlib.suppress(MissionFailed):
                    await tr.wait_until(landing, 5.0, "LAND")
                if landing():
                    return
                if attempt == attempts:
                    raise MissionFailed(f"land refused: {exc}") from exc
                log(f"land: {exc}; retrying")

    def _plan(self, view: RiskView, tr: LandingTracker) -> Spot:
        n, e, _ = tr.ned
        spot = choose_spot(view, (n, e), self.cfg)
        if spot is None:
            raise MissionFailed("no ground seen far enough from the edge of the view to land on")
        return self._log_spot(spot, view)

    def _log_spot(self, spot: Spot, view: RiskView) -> Spot:
        seen = view.levels[view.levels > 0]
        hist = " ".join(
            f"L{k}:{100 * float(np.mean(seen == k)):.0f}%" for k in range(1, 6) if np.any(seen == k)
        )
        log(f"view: {hist}; {view.people} people, {view.vehicles} vehicles detected -> spot "
            f"({spot.north_m:.1f}, {spot.east_m:.1f}) level {spot.level}, clearance {spot.clearance_m:.1f} m, "
            f"{spot.distance_m:.1f} m away")  # fmt: skip
        return spot


async def fly(args: argparse.Namespace, eyes: Eyes, cfg: PlanConfig, scenario: dict[str, Any] | None) -> dict[str, Any]:  # fmt: skip
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync
    from mavsdk.asyncio.plugins.telemetry import LandedState, TelemetryAsync

    cam = Camera(args.frames)
    try:
        async with first_autopilot(
            args.url, args.step_timeout, companion=True, also=f"; camera {args.frames}"
        ) as system:
            telemetry, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
            async with LandingTracker(telemetry, args.link_timeout).running(args.step_timeout) as tr:
                on_ground = tr.values["landed"] == LandedState.ON_GROUND or not tr.values["armed"]
                if on_ground:
                    if scenario is None or scenario.get("start") != "ground":
                        raise MissionFailed("the vehicle is on the ground: nothing to land (a ground-start "
                                            "scenario file makes it take off first)")  # fmt: skip
                    await arm_and_take_off(
                        tr, telemetry, action, float(scenario["altitude_m"]), args.step_timeout
                    )
                comp = Companion(args, eyes, cfg, scenario)
                await comp.wait_trigger(tr, cam, lambda: str(tr.values["mode"].name))
                return await comp.land(tr, cam, action, offboard)
    finally:
        cam.close()


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # one line, not the usage block
        self.exit(2, f"vision_landing: error: {message} (see --help)\n")


def _env(name: str, default: str) -> str:
    return os.environ.get(name) or default


def main() -> int:
    parser = _Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("url", nargs="?", default=_env("VIVA_SITL_MAVSDK_URL", "udpin://0.0.0.0:14540"),
                        help="MAVSDK connection URL (default: $VIVA_SITL_MAVSDK_URL, else udpin://0.0.0.0:14540)")  # fmt: skip
    parser.add_argument("--frames", default=_env("VIVA_SITL_FRAME_SOCKET", "tcp://127.0.0.1:5700"),
                        help="frame-and-pose socket (default: $VIVA_SITL_FRAME_SOCKET, else tcp://127.0.0.1:5700)")  # fmt: skip
    parser.add_argument("--scenario", default=os.environ.get("VIVA_SITL_SCENARIO"),
                        help="trial scenario file (default: $VIVA_SITL_SCENARIO): start and land-now time")  # fmt: skip
    parser.add_argument("--now", action="store_true", help="land at once (no trials: the by-hand trigger)")
    parser.add_argument("--segmenter", help="risk U-Net checkpoint (viva-sitl perception train-segmenter)")
    parser.add_argument("--detector", help="YOLO detection weights, .pt or .onnx (extra perception-yolo)")
    parser.add_argument("--conf", type=float, default=0.25, help="detector confidence threshold")
    parser.add_argument("--imgsz", type=int, default=640, help="detector input size")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads for the segmenter")
    d = PlanConfig()
    parser.add_argument("--margin-m", type=float, default=d.margin_m, help="landing precision disc, m")
    parser.add_argument(
        "--search-radius-m", type=float, default=d.search_radius_m, help="how far it may go, m"
    )
    parser.add_argument("--person-buffer-m", type=float, default=d.person_buffer_m, help="keep-out, m")
    parser.add_argument("--vehicle-buffer-m", type=float, default=d.vehicle_buffer_m, help="keep-out, m")
    parser.add_argument("--approach-alt", type=float, default=3.0, help="hand over to AUTO.LAND here, m")
    parser.add_argument(
        "--arrive-radius", type=float, default=0.7, help="horizontal radius 'over the spot', m"
    )
    parser.add_argument("--max-replans", type=int, default=6)
    parser.add_argument("--frame-timeout", type=float, default=10.0, help="wall s to wait for a camera frame")
    parser.add_argument("--link-timeout", type=float, default=5.0, help="wall s without telemetry = lost")
    parser.add_argument("--step-timeout", type=float, default=60.0, help="limit for each wait, wall s")
    parser.add_argument("--timeout", type=float, default=300.0, help="whole-flight limit, wall s")
    args = parser.parse_args()
    nums = (
        args.margin_m,
        args.search_radius_m,
        args.person_buffer_m,
        args.vehicle_buffer_m,
        args.approach_alt,
    )
    if not all(math.isfinite(v) and v > 0 for v in nums):
        parser.error("--margin-m, --search-radius-m, the buffers and --approach-alt must be finite and > 0")
    scenario = None
    if args.scenario:
        try:
            scenario = json.loads(Path(args.scenario).read_text())
            if not isinstance(scenario, dict) or "land_at_s" not in scenario:
                raise ValueError("no land_at_s: not a vivasitl.scenario.v1 file")
        except (OSError, ValueError) as exc:
            print(
                f"vision_landing: cannot read the scenario {args.scenario}: {exc}",
                file=sys.stderr,
                flush=True,
            )
            return 2
    cfg = PlanConfig(margin_m=args.margin_m, search_radius_m=args.search_radius_m,
                     person_buffer_m=args.person_buffer_m, vehicle_buffer_m=args.vehicle_buffer_m)  # fmt: skip
    try:
        seg, det = load_models(args)
    except PerceptionError as exc:
        print(f"vision_landing: {exc}", file=sys.stderr, flush=True)
        return 2
    try:
        result = asyncio.run(asyncio.wait_for(fly(args, Eyes(seg, det, cfg), cfg, scenario), args.timeout))
    except MissionFailed as exc:
        return failed(str(exc))
    except TimeoutError:
        return failed(f"the landing took longer than --timeout {args.timeout:.0f} s")
    except (ValueError, PerceptionError) as exc:  # e.g. a malformed frame socket address
        return failed(str(exc))
    except KeyboardInterrupt:
        print("vision_landing: interrupted (Ctrl-C)", file=sys.stderr, flush=True)
        return 130
    print_result(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
