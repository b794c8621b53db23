"""Wiring: the only place that connects footage, dynamics, camera, autopilot, MAVLink and video.

asyncio loop (one thread):  physics task (paced by the clock) -> Vehicle.step (Autopilot.update -> EAV step)
                            MavlinkEndpoint tasks (UDP I/O, telemetry, commands)
render thread:              at the stream fps, snapshot the (frozen) state -> VAC render -> VideoPipeline.submit
video worker threads:       encode + send (bounded queues; late frames dropped and counted)
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import json
import logging
import signal
import sys
import time
from pathlib import Path

import cv2

from viva_sitl.autopilot import Autopilot, ParamStore
from viva_sitl.clock import RealTimePacer, run_paced
from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavState
from viva_sitl.evaluation.monitor import Limits
from viva_sitl.evaluation.session import ScenarioSession, read_scenario_file, scenario_config
from viva_sitl.evaluation.spec import Scenario
from viva_sitl.frame import RenderedFrame
from viva_sitl.geo import GeoOrigin
from viva_sitl.mavlink import CameraInfo, CaptureResult, MavlinkEndpoint, StreamEncoding, VideoStreamSpec
from viva_sitl.sim import Simulator
from viva_sitl.vehicle import Vehicle
from viva_sitl.video import FrameScheduler, VideoPipeline

log = logging.getLogger("viva_sitl.app")


class SitlApp:
    """One simulated vehicle: satisfies viva_sitl.mavlink's VehicleLink protocol."""

    def __init__(
        self,
        config: SimConfig,
        *,
        video: bool = True,
        run_dir: Path | None = None,
        scenario: tuple[Scenario, Limits] | None = None,
    ) -> None:
        self.config = config
        params = ParamStore()
        params.adopt("MAV_SYS_ID", config.mavlink.system_id)  # as PX4 SITL -i N
        self.vehicle = Vehicle(config, params=params)  # sets config.params (the [params] table)
        self.sim: Simulator = self.vehicle.sim
        self.params: ParamStore = self.vehicle.params
        for name, value in config.params:
            spec = self.params.spec(name)
            if not spec.in_range(value):  # stored as PX4 stores it; say what the vehicle will use
                log.warning("%s = %g is outside PX4's range [%g, %g]: stored, the vehicle uses %g",
                            name, value, spec.min, spec.max, self.params.get(name))  # fmt: skip
        self.boot_wall_time_s = time.time()
        self.state_wall_time_s = self.boot_wall_time_s
        self.run_dir = run_dir or Path("runs") / time.strftime("%Y%m%d-%H%M%S")
        self.pacer = RealTimePacer(dt_s=self.sim.params.dt_s, speed=config.speed)
        self.video: VideoPipeline | None = None
        self.scheduler: FrameScheduler | None = None
        self.last_frame: RenderedFrame | None = None
        if video:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            vcfg = dataclasses.replace(config.video, sdp_dir=str(self.run_dir))
            self.video = VideoPipeline(vcfg, config.camera.width_px, config.camera.height_px)
            self.scheduler = FrameScheduler(
                self._render_tick, self.video.submit, config.video.fps, name="viva-render"
            )
        self.endpoint = MavlinkEndpoint(self, config.mavlink)
        # --- a landing trial (`run --scenario FILE`): viva_sitl.evaluation.session ---------------------
        self.trial: ScenarioSession | None = None
        if scenario is not None:
            self.trial = ScenarioSession(scenario[0], scenario[1], self.vehicle, self.run_dir)
            self.endpoint.add_event_listener(self.trial.on_statustext)
        self._stopping = asyncio.Event()
        self._physics_task: asyncio.Task[None] | None = None

    # --- VehicleLink ----------------------------------------------------------------------
    @property
    def autopilot(self) -> Autopilot:
        return self.vehicle.autopilot

    @property
    def state(self) -> EavState:
        return self.sim.state

    @property
    def time_s(self) -> float:
        return self.sim.state.time_s

    @property
    def geo(self) -> GeoOrigin:
        return self.sim.geo

    @property
    def camera(self) -> SitlApp | None:
        return self if self.scheduler is not None else None

    def _render_tick(self, tick: int) -> RenderedFrame:
        """Render thread: the VAC at the latest (frozen) state; wall time = when that state was produced."""
        frame = self.sim.render(self.sim.state, wall_time_s=self.state_wall_time_s)
        self.last_frame = frame
        return frame

    # --- CameraLink (MAVLink camera protocol) ------------------------------------------------
    def camera_info(self) -> CameraInfo:
        """The VAC and the RTP streams actually configured (ports after --video-port/--mjpeg-port/--instance)."""
        cam = self.config.camera
        streams: list[VideoStreamSpec] = []
        if self.video is not None:
            vc = self.video.config
            common = {
                "framerate_hz": float(vc.fps),
                "width_px": cam.width_px,
                "height_px": cam.height_px,
                "hfov_deg": cam.hfov_deg,
            }
            if vc.h264_rtp:
                streams.append(
                    VideoStreamSpec(f"udp://{vc.host}:{vc.h264_port}", StreamEncoding.H264, "VAC H.264",
                                    bitrate_bps=vc.bitrate_kbps * 1000, **common)  # type: ignore[arg-type]
                )  # fmt: skip
            if vc.mjpeg_rtp:
                streams.append(
                    VideoStreamSpec(f"udp://{vc.host}:{vc.mjpeg_port}", StreamEncoding.MJPEG, "VAC MJPEG",
                                    **common)  # type: ignore[arg-type]
                )  # fmt: skip
        return CameraInfo(cam.width_px, cam.height_px, cam.hfov_deg, tuple(streams))

    def capture_image(self, seq: int) -> CaptureResult:
        """Save the latest VAC frame and its pose (PNG + JSON sidecar) under run_dir/captures."""
        frame = self.last_frame
        if frame is None:
            return CaptureResult(ok=False, path="", meta=None)
        out = self.run_dir / "captures"
        out.mkdir(parents=True, exist_ok=True)
        path = out / f"img_{seq:05d}.png"
        ok = bool(cv2.imwrite(str(path), frame.image_bgr))
        if ok:
            path.with_suffix(".json").write_text(json.dumps(frame.meta.to_dict(), indent=1))
        return CaptureResult(ok=ok, path=str(path.resolve()), meta=frame.meta)

    # --- loops ---------------------------------------------------------------------------
    def _step_once(self) -> None:
        self.vehicle.step(1)
        if self.trial is not None and self.trial.after_step():
            self.stop()  # the trial is over (landed, crash, left the footage, timeout)

    def _after_batch(self) -> None:
        self.state_wall_time_s = time.time()
        self.pacer.dt_s = self.vehicle.dt_s

    def stop(self) -> None:
        self._stopping.set()

    async def run(self, duration_s: float | None = None, ready: bool = True) -> None:
        if self.scheduler is not None:
            # First render decodes/generates the footage frame and builds caches: do it before we are "ready".
            await asyncio.get_running_loop().run_in_executor(None, self._render_tick, -1)
        await self.endpoint.start()
        if self.video is not None and self.scheduler is not None:
            self.video.start()
            self.scheduler.start()
        self._physics_task = asyncio.create_task(
            run_paced(self.pacer, self._step_once, self._after_batch), name="viva-physics"
        )
        if ready:
            self._print_ready()
        try:
            if duration_s is None:
                await self._stopping.wait()
            else:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._stopping.wait(), duration_s)
        finally:
            self._physics_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._physics_task
            await self.endpoint.stop()
            if self.scheduler is not None:
                self.scheduler.stop()
            if self.video is not None:
                self.video.stop()
            if self.trial is not None:
                self.trial.finish()
            self.sim.close()
            self._print_stats()

    def _print_ready(self) -> None:
        m = self.config.mavlink
        api_host, api_port = self.endpoint.api_address
        gcs_host, gcs_port = self.endpoint.gcs_address
        parts = [
            f"viva-sitl ready: sysid {m.system_id} footage {self.sim.footage.metadata.name}",
            f"mavlink api udp {api_host}:{api_port} -> {m.api_remote_host}:{m.api_remote_port_resolved}",
            f"gcs udp {gcs_host}:{gcs_port} -> {m.gcs_remote_host}:{m.gcs_remote_port}",
        ]
        if self.video is not None:
            for kind, sdp in self.video.sdp_paths.items():
                parts.append(f"{kind} rtp sdp {sdp.resolve()}")
            if self.video.frame_socket_endpoint:
                parts.append(f"frames {self.video.frame_socket_endpoint}")
        print(" | ".join(parts), flush=True)

    def _print_stats(self) -> None:
        stats: dict[str, object] = {
            "sim_time_s": round(self.time_s, 3),
            "skipped_physics_steps": self.pacer.skipped_steps,
        }
        if self.scheduler is not None:
            render = self.scheduler.stats()
            stats["render"] = render
            if self.video is not None:
                video = self.video.stats()
                stats["video"] = video
                # frames the stream should have carried but did not: render ticks skipped + pipeline queue drops
                due = render["ticks"] + render["late_skipped"]
                lost = render["late_skipped"] + video["dropped"]
                stats["frames_lost_pct"] = round(100.0 * lost / due, 3) if due else 0.0
        stats["mavlink"] = self.endpoint.stats
        print(f"viva-sitl stopped: {json.dumps(stats, default=str)}", file=sys.stderr, flush=True)


def config_from_args(args: argparse.Namespace) -> SimConfig:
    cfg = SimConfig.load(args.config)
    sim_updates: dict[str, object] = {}
    if args.footage:
        sim_updates["footage"] = args.footage
    if args.speed is not None:
        sim_updates["speed"] = args.speed
    if args.seed is not None:
        sim_updates["seed"] = args.seed
    mav = cfg.mavlink
    if args.instance is not None:
        mav = dataclasses.replace(mav, instance=args.instance)
    mav_updates = {
        "listen_host": args.listen,
        "api_remote_port": args.api_port,
        "gcs_remote_port": args.gcs_port,
        "api_local_port": args.api_local_port,
        "gcs_local_port": args.gcs_local_port,
    }
    mav = dataclasses.replace(mav, **{k: v for k, v in mav_updates.items() if v is not None})
    video = cfg.video.with_instance(mav.instance)
    video_updates = {
        "h264_port": args.video_port,
        "mjpeg_port": args.mjpeg_port,
        "frame_socket_endpoint": args.frame_socket,
        "record_path": args.record,
    }
    video = dataclasses.replace(video, **{k: v for k, v in video_updates.items() if v is not None})
    if args.mjpeg_port is not None:
        video = dataclasses.replace(video, mjpeg_rtp=True)
    cfg = dataclasses.replace(cfg, mavlink=mav, video=video, **sim_updates)  # type: ignore[arg-type]
    if getattr(args, "scenario", None):  # a trial's start (pose, footage, parameters) over the config
        cfg = scenario_config(cfg, read_scenario_file(args.scenario)[0])
    return cfg


def run_from_args(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    scenario = read_scenario_file(args.scenario) if getattr(args, "scenario", None) else None
    app = SitlApp(
        cfg, video=not args.no_video, run_dir=Path(args.run_dir) if args.run_dir else None, scenario=scenario
    )

    async def main() -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, app.stop)
        await app.run(duration_s=args.duration)

    asyncio.run(main())
    return 0


__all__ = ["SitlApp", "config_from_args", "run_from_args"]
