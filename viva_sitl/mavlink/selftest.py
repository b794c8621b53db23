"""A minimal vehicle for the MAVLink endpoint: the real Autopilot + EAV dynamics, paced on the asyncio loop.

Used by the protocol tests and by bench/bench_mavlink.py (as `python -m viva_sitl.mavlink.selftest`); the production
vehicle is viva_sitl.app.SitlApp (footage, camera, video). No footage here: the geofence is open, the camera
(`--camera-dir`) saves a small synthetic image per capture.

    python -m viva_sitl.mavlink.selftest --instance 0 [--speed 1] [--duration 60] [--stats-file s.json]

prints one JSON line `{"ready": ..., "api": [host, port], "gcs": [host, port], "sysid": N}` when listening, and on
SIGINT/SIGTERM or after --duration a final JSON line with the endpoint stats and the process CPU time.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import signal
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot import Autopilot, ParamStore
from viva_sitl.clock import RealTimePacer, run_paced
from viva_sitl.dynamics import EavParams, EavState, step
from viva_sitl.geo import GeoOrigin
from viva_sitl.mavlink.base import MavMessage
from viva_sitl.mavlink.camera import CameraInfo, CameraLink, CaptureResult, VideoStreamSpec
from viva_sitl.mavlink.endpoint import MavlinkConfig, MavlinkEndpoint


class SnapshotCamera:
    """A CameraLink without rendering: each capture writes a small grey PGM image whose name carries the index."""

    def __init__(self, out_dir: Path, info: CameraInfo | None = None) -> None:
        self.out_dir = out_dir
        self.info = info or CameraInfo(
            width_px=640, height_px=480, hfov_deg=82.1, streams=(VideoStreamSpec("udp://127.0.0.1:5600"),)
        )
        self.captured: list[int] = []

    def camera_info(self) -> CameraInfo:
        return self.info

    def capture_image(self, seq: int) -> CaptureResult:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        path = self.out_dir / f"img_{seq:05d}.pgm"
        h, w = 48, 64
        pixels = np.full((h, w), (seq * 37) % 256, dtype=np.uint8)
        path.write_bytes(b"P5 %d %d 255\n" % (w, h) + pixels.tobytes())  # PGM: a valid image with no codec
        self.captured.append(seq)
        return CaptureResult(ok=True, path=str(path.resolve()), meta=None)


class MinimalVehicle:
    """VehicleLink: Autopilot.update -> EAV step at the physics rate, paced against wall time x `speed`."""

    def __init__(
        self,
        eav: EavParams | None = None,
        geo: GeoOrigin | None = None,
        speed: float = 1.0,
        camera: CameraLink | None = None,
        seed: int = 0,
    ) -> None:
        self.eav = eav or EavParams()
        self.geo = geo or GeoOrigin()
        self.params = ParamStore()
        self.autopilot = Autopilot(self.params, self.eav)
        self.state = EavState.at_rest(dt_s=self.eav.dt_s, ground_z_ned_m=self.eav.ground_z_ned_m)
        self.camera = camera
        self.boot_wall_time_s = time.time()
        self.pacer = RealTimePacer(dt_s=self.eav.dt_s, speed=speed)
        self.steps = 0
        self._rng = np.random.default_rng(seed)
        self._params = self.eav
        self._task: asyncio.Task[None] | None = None
        self.step_hooks: list[
            Callable[[], None]
        ] = []  # called after every step (MavlinkEndpoint.on_sim_step)

    @property
    def time_s(self) -> float:
        return float(self.state.time_s)

    def step_once(self) -> None:
        cmd = self.autopilot.update(self.state.time_s, self.state)
        self.state = step(self.state, cmd, self._params, self._rng)
        self.steps += 1
        for hook in self.step_hooks:
            hook()

    def _after_batch(self) -> None:
        self._params = self.autopilot.eav_params()

    def start(self) -> None:
        self.step_once()  # one state through the autopilot: home and pre-arm checks are valid from now on
        self._task = asyncio.get_running_loop().create_task(
            run_paced(self.pacer, self.step_once, self._after_batch), name="minimal-vehicle"
        )

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None


class VehicleThread:
    """A MinimalVehicle + MavlinkEndpoint on their own asyncio loop in a background thread (tests, benchmarks).

    `with VehicleThread(config) as vt:` starts both and stops them on exit; `vt.call(fn)` runs fn on the loop.
    """

    def __init__(self, config: MavlinkConfig, speed: float = 1.0, camera: CameraLink | None = None) -> None:
        self.config = config
        self.speed = speed
        self.camera = camera
        self.vehicle: MinimalVehicle | None = None
        self.endpoint: MavlinkEndpoint | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="mavlink-vehicle", daemon=True)

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # reported to the starting thread
            self._error = exc
            self._ready.set()

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        self.vehicle = MinimalVehicle(speed=self.speed, camera=self.camera)
        self.endpoint = MavlinkEndpoint(self.vehicle, self.config)
        self.vehicle.step_hooks.append(self.endpoint.on_sim_step)
        self.vehicle.start()
        await self.endpoint.start()
        self._ready.set()
        try:
            await self._stop.wait()
        finally:
            await self.endpoint.stop()
            await self.vehicle.stop()

    def start(self) -> VehicleThread:
        self._thread.start()
        if not self._ready.wait(10.0) or self._error is not None:
            raise RuntimeError(f"vehicle thread did not start: {self._error!r}")
        return self

    def stop(self) -> None:
        if self._loop is not None and self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10.0)

    def call(self, fn: Callable[[], Any], timeout_s: float = 5.0) -> Any:
        """Run fn on the vehicle's loop (thread-safe access to the autopilot or endpoint) and return its result."""
        assert self._loop is not None

        async def run() -> Any:
            return fn()

        return asyncio.run_coroutine_threadsafe(run(), self._loop).result(timeout_s)

    @property
    def api(self) -> tuple[str, int]:
        assert self.endpoint is not None
        return self.call(lambda: self.endpoint.api_address)  # type: ignore[union-attr]

    @property
    def gcs(self) -> tuple[str, int]:
        assert self.endpoint is not None
        return self.call(lambda: self.endpoint.gcs_address)  # type: ignore[union-attr]

    def stats(self) -> dict[str, Any]:
        assert self.endpoint is not None
        return self.call(lambda: self.endpoint.stats)  # type: ignore[union-attr,no-any-return]

    def __enter__(self) -> VehicleThread:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class MavClient:
    """A blocking pymavlink-codec client over a real UDP socket (a GCS or API program, as in the tests)."""

    def __init__(self, target: tuple[str, int] | None = None, sysid: int = 255, compid: int = 190) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self.sock.bind(("127.0.0.1", 0))
        self.target = target
        self.mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.parser = mavlink2.MAVLink(None)
        self.parser.robust_parsing = True
        self.received: list[tuple[float, MavMessage]] = []  # (monotonic time, message) of everything read
        self._pending: deque[MavMessage] = deque()  # read but not yet looked at by wait_for

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    def close(self) -> None:
        self.sock.close()

    def send(self, msg: MavMessage) -> None:
        assert self.target is not None
        self.send_raw(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256

    def send_raw(self, data: bytes) -> None:
        assert self.target is not None
        self.sock.sendto(data, self.target)

    def drain(self) -> None:
        """Forget pending messages (wait_for then sees only what arrives from now on)."""
        self.poll(0.0)
        self._pending.clear()

    def poll(self, timeout_s: float) -> list[MavMessage]:
        """Read datagrams for up to timeout_s; return the messages (also appended to `received`)."""
        out: list[MavMessage] = []
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return out
            self.sock.settimeout(remaining)
            try:
                data, _ = self.sock.recvfrom(65535)
            except TimeoutError:
                return out
            now = time.monotonic()
            for msg in self.parser.parse_buffer(data) or []:
                if msg.get_type() in ("BAD_DATA", "UNKNOWN"):
                    continue
                self.received.append((now, msg))
                self._pending.append(msg)
                out.append(msg)

    def wait_for(
        self, predicate: Callable[[MavMessage], bool] | str, timeout_s: float = 3.0
    ) -> MavMessage | None:
        """The next message matching `predicate` (or of that type name), None on timeout. Messages before it are
        consumed (still in `received`); messages after it stay for the next call."""
        pred = (lambda m: m.get_type() == predicate) if isinstance(predicate, str) else predicate
        deadline = time.monotonic() + timeout_s
        while True:
            while self._pending:
                msg = self._pending.popleft()
                if pred(msg):
                    return msg
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            self.poll(min(0.05, remaining))

    def command(
        self,
        command: int,
        *params: float,
        target_system: int = 1,
        target_component: int = 1,
        timeout_s: float = 1.0,
    ) -> MavMessage | None:
        """COMMAND_LONG with up to 7 params; returns its COMMAND_ACK (None if none came)."""
        p = list(params) + [0.0] * (7 - len(params))
        self.send(self.mav.command_long_encode(target_system, target_component, command, 0, *p))
        return self.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command, timeout_s)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m viva_sitl.mavlink.selftest", description=__doc__.split("\n")[0]
    )
    p.add_argument("--instance", type=int, default=0)
    p.add_argument("--listen", default="127.0.0.1")
    p.add_argument("--api-remote-port", type=int, help="default 14540+instance; 0 = answer only who talks")
    p.add_argument("--gcs-remote-port", type=int, help="default 14550; 0 = answer only who talks")
    p.add_argument("--api-local-port", type=int, help="default 14580+instance; 0 = any free port")
    p.add_argument("--gcs-local-port", type=int, help="default 18570+instance; 0 = any free port")
    p.add_argument("--speed", type=float, default=1.0)
    p.add_argument("--duration", type=float, help="stop after this many wall seconds")
    p.add_argument("--stats-file", help="rewrite endpoint stats (JSON) here twice a second")
    p.add_argument("--camera-dir", help="enable the camera component; captures go here")
    p.add_argument("--no-endpoint", action="store_true", help="physics + autopilot only (CPU baseline)")
    p.add_argument("--rate", action="append", default=[], metavar="NAME=HZ", help="telemetry rate override")
    return p


async def _main(args: argparse.Namespace) -> dict[str, object]:
    camera = SnapshotCamera(Path(args.camera_dir)) if args.camera_dir else None
    vehicle = MinimalVehicle(speed=args.speed, camera=camera)
    overrides = tuple((name, float(hz)) for name, hz in (r.split("=", 1) for r in args.rate))
    updates = {
        "api_remote_port": args.api_remote_port,
        "gcs_remote_port": args.gcs_remote_port,
        "api_local_port": args.api_local_port,
        "gcs_local_port": args.gcs_local_port,
    }
    config = MavlinkConfig(
        instance=args.instance,
        listen_host=args.listen,
        rate_overrides=overrides,
        **{k: v for k, v in updates.items() if v is not None},  # type: ignore[arg-type]
    )
    endpoint = None if args.no_endpoint else MavlinkEndpoint(vehicle, config)
    if endpoint is not None:
        vehicle.step_hooks.append(endpoint.on_sim_step)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    vehicle.start()
    if endpoint is not None:
        await endpoint.start()
        ready = {
            "ready": True,
            "sysid": config.system_id,
            "api": endpoint.api_address,
            "gcs": endpoint.gcs_address,
        }
    else:
        ready = {"ready": True, "sysid": config.system_id, "api": None, "gcs": None}
    print(json.dumps(ready), flush=True)
    wall0, cpu0 = time.monotonic(), time.process_time()

    async def write_stats() -> None:
        path = Path(args.stats_file)
        while True:
            stats = dict(endpoint.stats) if endpoint is not None else {}
            stats["cpu_s"] = time.process_time() - cpu0
            stats["wall_s"] = time.monotonic() - wall0
            stats["physics_steps"] = vehicle.steps
            tmp = path.with_suffix(".tmp")
            tmp.write_text(json.dumps(stats))
            tmp.replace(path)  # atomic: a reader never sees half a file
            await asyncio.sleep(0.5)

    stats_task = loop.create_task(write_stats()) if args.stats_file else None
    try:
        if args.duration:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), args.duration)
        else:
            await stop.wait()
    finally:
        if stats_task is not None:
            stats_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await stats_task
        if endpoint is not None:
            await endpoint.stop()
        await vehicle.stop()
    final: dict[str, object] = dict(endpoint.stats) if endpoint is not None else {}
    final.update(
        cpu_s=time.process_time() - cpu0,
        wall_s=time.monotonic() - wall0,
        physics_steps=vehicle.steps,
        sim_time_s=vehicle.time_s,
    )
    return final


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if not (args.speed > 0 and math.isfinite(args.speed)):
        print("selftest: --speed must be a positive number", file=sys.stderr)
        return 2
    try:
        final = asyncio.run(_main(args))
    except (OSError, ValueError) as exc:
        print(f"selftest: {exc}", file=sys.stderr)
        return 2
    print(json.dumps({"stopped": True, **final}, default=str), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
