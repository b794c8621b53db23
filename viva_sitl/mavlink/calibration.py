"""MAV_CMD_PREFLIGHT_CALIBRATION answered as PX4 SITL's commander does, with the "[cal]" STATUSTEXT protocol
(version 2) that QGroundControl and MAVSDK's calibration plugin parse:

    "[cal] calibration started: 2 <sensor>"    "[cal] progress <N>"    "[cal] calibration done: <sensor>"
    "[cal] calibration failed: <reason>"        "[cal] calibration cancelled"

The command is ACKed at once (ACCEPTED, the calibration then runs in the background like PX4's worker thread;
TEMPORARILY_REJECTED while armed or while another calibration runs; all parameters 0 = cancel the running one,
ACCEPTED). Time is simulation time, as PX4 SITL in lockstep. The simulated sensors are ideal, so each calibration
succeeds or waits exactly where PX4's does on a vehicle that nobody touches:

    gyro  (param1 = 1)  the vehicle must be still: progress <5> .. <100> over 2 s, then done.
    level (param5 = 2)  0.5 s windows of attitude (retried while it moves), tilt <= 0.8 rad: done; the mean
                        roll/pitch go to SENS_BOARD_X_OFF / SENS_BOARD_Y_OFF when the parameter set has them.
    accel (param5 = 1)  PX4's six-side routine: the resting side ("down") is detected and measured (progress <17>),
                        then it waits for the other sides ("[cal] pending: back front left right up", "[cal] hold
                        vehicle still on a pending side"); the vehicle stays on "down", which PX4 counts as an
                        orientation failure ("[cal] down side already completed"): after 5 of them it fails with
                        "[cal] calibration failed: timeout: no motion" (about 10 s). Cancel works throughout.
    mag   (param2 = 1)  the resting side is detected, then "[cal] Rotate vehicle around the detected orientation"
                        and it waits for a rotation (0.5 rad) that never comes: after 35 s "[cal] calibration
                        failed: mag". Cancel works throughout.

Baro, RC, airspeed, ESC and temperature calibrations are UNSUPPORTED (no such simulated hardware).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Awaitable, Callable

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.types import CommandResult, Outcome, Severity
from viva_sitl.mavlink.base import CommandRequest, MavMessage, Origin, StatusSink, VehicleLink

log = logging.getLogger(__name__)
M = mavlink2

GRAVITY = 9.80665
POLL_WALL_S = 0.01  # how often the worker looks at the simulation clock
GYRO_DURATION_S = 2.0
STILL_TIME_S = 1.5  # PX4's still detector: at rest this long before the orientation is taken
SIDE_MEASURE_S = 1.0
MAX_ORIENTATION_FAILURES = 4  # PX4 fails on the fifth
MAG_SIDE_S = 7.0
MAG_ROTATION_RAD = 0.5
LEVEL_WINDOW_S = 0.5
LEVEL_MAX_TILT_RAD = 0.8
STILL_SPEED_M_S = 0.05
STILL_RATE_RAD_S = math.radians(1.0)
SIDES = ("back", "front", "left", "right", "up", "down")


class _Cancelled(Exception):
    pass


class _Failed(Exception):
    pass


def _ok(result: CommandResult, reason: str = "") -> Outcome:
    return Outcome(result, reason)


class CalibrationWorker:
    """One calibration at a time, run as an asyncio task on the endpoint's loop."""

    def __init__(self, vehicle: VehicleLink, statustext: StatusSink) -> None:
        self.vehicle = vehicle
        self.statustext = statustext
        self._task: asyncio.Task[None] | None = None
        self._cancel = False
        self.kind: str | None = None
        self.completed: list[tuple[str, str]] = []  # (sensor, "done" | "failed" | "cancelled")

    @property
    def busy(self) -> bool:
        return self._task is not None and not self._task.done()

    # --- the command ------------------------------------------------------------------------
    def handle(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        p = [int(v) if math.isfinite(v) else 0 for v in req.params]
        if all(v == 0 for v in p[:6]):  # cancel (or "RC calibration ended"): ACCEPTED either way
            if self.busy:
                self._cancel = True
            return _ok(CommandResult.ACCEPTED), []
        if self.vehicle.autopilot.armed or self.busy:
            reason = "Calibration denied: vehicle armed" if self.vehicle.autopilot.armed else (
                f"Calibration denied: {self.kind} calibration running")  # fmt: skip
            return _ok(CommandResult.TEMPORARILY_REJECTED, reason), []
        runs: dict[str, Callable[[], Awaitable[None]]] = {
            "gyro": self._gyro, "mag": self._mag, "accel": self._accel, "level": self._level,
        }  # fmt: skip
        kind: str | None = None
        if p[0] == 1:
            kind = "gyro"
        elif p[1] == 1:
            kind = "mag"
        elif p[4] == 1:
            kind = "accel"
        elif p[4] == 2:
            kind = "level"
        if kind is None:
            return _ok(CommandResult.UNSUPPORTED, "Calibration not supported by this simulated vehicle"), []
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            return _ok(CommandResult.FAILED, "Calibration needs the endpoint's event loop"), []
        self.kind = kind
        self._cancel = False
        self._task = loop.create_task(self._run(kind, runs[kind]), name=f"calibration-{kind}")
        return _ok(CommandResult.ACCEPTED), []

    async def stop(self) -> None:
        task, self._task = self._task, None
        if task is not None and not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    # --- helpers ----------------------------------------------------------------------------
    def _say(self, text: str, severity: int = Severity.INFO) -> None:
        self.statustext(None, severity, text)

    def _now(self) -> float:
        t = float(self.vehicle.time_s)
        return t if math.isfinite(t) else 0.0

    async def _wait(self, duration_s: float) -> None:
        """Wait `duration_s` of simulation time; a cancel request ends the calibration."""
        end = self._now() + duration_s
        while True:
            if self._cancel:
                raise _Cancelled
            if self._now() >= end:
                return
            await asyncio.sleep(POLL_WALL_S)

    def _still(self) -> bool:
        s = self.vehicle.state
        v = s.vel_ned_m_s
        speed = math.sqrt(float(v[0]) ** 2 + float(v[1]) ** 2 + float(v[2]) ** 2)
        return bool(s.landed) and speed < STILL_SPEED_M_S

    def _orientation(self) -> str | None:
        """Which side faces down, from the specific force an accelerometer at rest would measure (PX4's rule)."""
        roll, pitch = float(self.vehicle.state.att_rpy_rad[0]), float(self.vehicle.state.att_rpy_rad[1])
        f = (GRAVITY * math.sin(pitch), -GRAVITY * math.sin(roll) * math.cos(pitch),
             -GRAVITY * math.cos(roll) * math.cos(pitch))  # fmt: skip
        thr = 5.0  # m/s^2
        axes = ((0, 1.0, "back"), (0, -1.0, "front"), (1, 1.0, "left"), (1, -1.0, "right"),
                (2, 1.0, "up"), (2, -1.0, "down"))  # fmt: skip
        for axis, sign, name in axes:
            if all(abs(f[i] - (sign * GRAVITY if i == axis else 0.0)) < thr for i in range(3)):
                return name
        return None

    async def _detect_orientation(self) -> str | None:
        """PX4's detect_orientation: wait for rest ("detected rest position"), STILL_TIME_S of it, then the side."""
        announced = False
        still_since: float | None = None
        while True:
            if self._still():
                if still_since is None:
                    still_since = self._now()
                    if not announced:
                        self._say("[cal] detected rest position, hold still...")
                        announced = True
                elif self._now() - still_since >= STILL_TIME_S:
                    return self._orientation()
            elif still_since is not None:
                self._say("[cal] detected motion, hold still...")
                still_since = None
            await self._wait(0.02)

    async def _run(self, kind: str, body: Callable[[], Awaitable[None]]) -> None:
        self._say(f"[cal] calibration started: 2 {kind}")
        outcome = "done"
        self.vehicle.autopilot.calibrating = True
        try:
            await body()
            self._say(f"[cal] calibration done: {kind}")
        except _Cancelled:
            outcome = "cancelled"
            self._say("[cal] calibration cancelled", Severity.CRITICAL)
        except _Failed as exc:
            outcome = "failed"
            self._say(f"[cal] calibration failed: {exc}", Severity.CRITICAL)
        except asyncio.CancelledError:
            raise
        except Exception:  # a bug: the client still hears an end
            log.exception("%s calibration failed", kind)
            outcome = "failed"
            self._say(f"[cal] calibration failed: {kind}", Severity.CRITICAL)
        finally:
            self.vehicle.autopilot.calibrating = False
            self.completed.append((kind, outcome))
            self._cancel = False

    # --- the calibrations -------------------------------------------------------------------
    async def _gyro(self) -> None:
        for pct in range(5, 101, 5):
            if not self._still():
                self._say("[cal] detected motion, hold still...")
                raise _Failed("gyro")
            await self._wait(GYRO_DURATION_S / 20.0)
            self._say(f"[cal] progress <{pct}>")

    async def _level(self) -> None:
        for _ in range(50):
            rolls: list[float] = []
            pitches: list[float] = []
            start = self._now()
            last_report = -100
            while self._now() - start < LEVEL_WINDOW_S:
                progress = int(100 * (self._now() - start) / LEVEL_WINDOW_S)
                if progress >= last_report + 20:
                    self._say(f"[cal] progress <{progress}>")
                    last_report = progress
                att = self.vehicle.state.att_rpy_rad
                rolls.append(float(att[0]))
                pitches.append(float(att[1]))
                await self._wait(0.02)
            if (
                rolls
                and max(rolls) - min(rolls) < math.radians(0.5)
                and max(pitches) - min(pitches) < math.radians(0.5)
            ):
                break
        else:
            self._say("[cal] progress <100>")
            self._say("motion during calibration", Severity.CRITICAL)
            raise _Failed("level")
        self._say("[cal] progress <100>")
        roll = sum(rolls) / len(rolls)
        pitch = sum(pitches) / len(pitches)
        if abs(roll) > LEVEL_MAX_TILT_RAD or abs(pitch) > LEVEL_MAX_TILT_RAD:
            self._say(
                "excess roll angle" if abs(roll) > LEVEL_MAX_TILT_RAD else "excess pitch angle",
                Severity.CRITICAL,
            )
            raise _Failed("level")
        params = self.vehicle.autopilot.params
        for name, value in (("SENS_BOARD_X_OFF", roll), ("SENS_BOARD_Y_OFF", pitch)):
            if name in params:
                with contextlib.suppress(Exception):
                    params.set(name, math.degrees(value))

    async def _sides(self, worker: Callable[[str], Awaitable[None]], done: set[str]) -> None:
        """PX4's calibrate_from_orientation."""
        failures = 0
        while len(done) < len(SIDES):
            if failures > MAX_ORIENTATION_FAILURES:
                raise _Failed("timeout: no motion")
            pending = " ".join(s for s in SIDES if s not in done)
            self._say(f"[cal] pending: {pending}")
            self._say("[cal] hold vehicle still on a pending side")
            side = await self._detect_orientation()
            if side is None:
                failures += 1
                self._say("[cal] detected motion, hold still...")
                continue
            if side in done:
                failures += 1
                self._say(f"[cal] {side} side already completed")
                await self._wait(0.2)
                continue
            self._say(f"[cal] {side} orientation detected")
            failures = 0
            await worker(side)
            done.add(side)
            self._say(f"[cal] {side} side done, rotate to a different side")
            await self._wait(0.2)

    async def _accel(self) -> None:
        done: set[str] = set()

        async def measure(side: str) -> None:
            self._say(f"[cal] Hold still, measuring {side} side")
            await self._wait(SIDE_MEASURE_S)
            if not self._still():
                raise _Failed("motion during calibration")
            self._say(f"[cal] progress <{17 * (len(done) + 1)}>")

        await self._sides(measure, done)

    async def _mag(self) -> None:
        done: set[str] = set()

        async def rotate(side: str) -> None:
            self._say("[cal] Rotate vehicle around the detected orientation")
            self._say(f"[cal] Continue rotation for {side} {MAG_SIDE_S:.0f} s")
            start = self._now()
            yaw0 = float(self.vehicle.state.att_rpy_rad[2])
            turned = 0.0
            while self._now() - start < MAG_SIDE_S * 5:
                yaw = float(self.vehicle.state.att_rpy_rad[2])
                turned += abs(math.remainder(yaw - yaw0, math.tau))
                yaw0 = yaw
                if turned >= MAG_ROTATION_RAD:
                    await self._wait(MAG_SIDE_S)
                    self._say(f"[cal] progress <{int(100 * (len(done) + 1) / len(SIDES))}>")
                    return
                await self._wait(0.05)
            self._say("Failed: This calibration requires rotation.", Severity.CRITICAL)
            raise _Failed("mag")

        await self._sides(rotate, done)


__all__ = ["CalibrationWorker"]
