"""A minimal vehicle for the MAVLink endpoint: a Vehicle (real Autopilot + EAV dynamics) paced on the asyncio loop.

A small app beside app.py (it builds a Vehicle and an endpoint, so it sits above both, not inside mavlink/). Used by the protocol tests (tests/mav_client.py) and by bench/bench_mavlink.py (as
`python -m viva_sitl.selftest`); the production vehicle is viva_sitl.app.SitlApp (footage, camera, video).
Nothing is rendered here: the geofence is open, the camera (`--camera-dir`) saves a small synthetic image per capture.

    python -m viva_sitl.selftest --instance 0 [--speed 1] [--duration 60] [--stats-file s.json]

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
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from viva_sitl.autopilot import Autopilot, ParamStore
from viva_sitl.clock import RealTimePacer, run_paced
from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavState
from viva_sitl.geo import GeoOrigin
from viva_sitl.mavlink.camera_link import CameraInfo, CameraLink, CaptureResult, VideoStreamSpec
from viva_sitl.mavlink.config import MavlinkConfig
from viva_sitl.mavlink.endpoint import MavlinkEndpoint
from viva_sitl.vehicle import Vehicle


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


class SelftestVehicle:
    """VehicleLink over a Vehicle, paced on the asyncio loop against wall time x `speed` (clock.run_paced). Nothing
    is rendered: `camera` is an optional CameraLink. Without `footage`: no footage edge (an open world, the edgeless
    synthetic field); with one (a catalog name or footage file, e.g. a finite synthetic field), its edge is the
    footage-edge fence (SIM_FTG_FENCE)."""

    def __init__(
        self,
        config: SimConfig | None = None,
        speed: float = 1.0,
        camera: CameraLink | None = None,
        seed: int = 0,
        footage: str | Path | None = None,
    ) -> None:
        self.vehicle = Vehicle(config or SimConfig(seed=seed), footage=footage, geofence=footage is not None)
        self.camera = camera
        self.boot_wall_time_s = time.time()
        self.pacer = RealTimePacer(dt_s=self.vehicle.dt_s, speed=speed)
        self._task: asyncio.Task[None] | None = None
        # called after every step (MavlinkEndpoint.on_sim_step)
        self.step_hooks: list[Callable[[], None]] = []

    @property
    def autopilot(self) -> Autopilot:
        return self.vehicle.autopilot

    @property
    def params(self) -> ParamStore:
        return self.vehicle.params

    @property
    def state(self) -> EavState:
        return self.vehicle.state

    @property
    def time_s(self) -> float:
        return self.vehicle.time_s

    @property
    def geo(self) -> GeoOrigin:
        return self.vehicle.geo

    @property
    def steps(self) -> int:
        return self.vehicle.steps

    def step_once(self) -> None:
        self.vehicle.step(1)
        for hook in self.step_hooks:
            hook()

    def _after_batch(self) -> None:
        self.pacer.dt_s = self.vehicle.dt_s

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(
            run_paced(self.pacer, self.step_once, self._after_batch), name="selftest-vehicle"
        )

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        self.vehicle.close()


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m viva_sitl.selftest", description=__doc__.split("\n")[0])
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
    vehicle = SelftestVehicle(speed=args.speed, camera=camera)
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
