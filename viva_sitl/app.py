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
import os
import signal
import sys
import time
from pathlib import Path

import cv2

from viva_sitl.autopilot import Autopilot, ParamStore
from viva_sitl.clock import RealTimePacer, run_paced
from viva_sitl.config import ConfigError, SimConfig
from viva_sitl.dashboard.config import DashboardConfig
from viva_sitl.dashboard.layers import world_layers
from viva_sitl.dashboard.overview import LayerProvider
from viva_sitl.dashboard.server import Dashboard
from viva_sitl.dynamics import EavState, floats3
from viva_sitl.dynamics.rotation import quat_from_euler
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.episode import scenario_config
from viva_sitl.evaluation.monitor import Limits
from viva_sitl.evaluation.session import ScenarioSession, read_scenario_file
from viva_sitl.evaluation.spec import Scenario
from viva_sitl.flightlog import LOG_FILE, FlightLog
from viva_sitl.footage import open_footage
from viva_sitl.footage.loader import resolve_metadata
from viva_sitl.frame import RenderedFrame
from viva_sitl.geo import GeoOrigin, home_from_env
from viva_sitl.mavlink import CameraInfo, CaptureResult, MavlinkEndpoint, StreamEncoding, VideoStreamSpec
from viva_sitl.mavlink.config import EndpointStartError
from viva_sitl.perception.from_config import super_resolution_from_config
from viva_sitl.pilotwatch import PilotTree, owner_of_udp_port, process_group, supported, zmq_io_threads
from viva_sitl.recording import TRAJECTORY_FILE, Sample, TrajectoryRecorder, write_run_info
from viva_sitl.sim import Simulator
from viva_sitl.timing import (
    NEVER_IDLE_GIVE_UP_S,
    NEVER_IDLE_QUANTA,
    QUANTUM_S,
    WATCH_PERIOD_S,
    LockstepClock,
    PilotGate,
    Timing,
    TimingStats,
)
from viva_sitl.vehicle import Vehicle
from viva_sitl.video import FrameScheduler, VideoPipeline
from viva_sitl.world import world_from_source

log = logging.getLogger("viva_sitl.app")
PILOT_WAIT_MAX_S = 15.0  # wall seconds a trial's clock waits for the pilot's first MAVLink message
PILOT_SEARCH_PERIOD_S = (
    0.5  # wall seconds between two looks for the pilot's process (lockstep, realtime watch)
)


def _world_layers_of(cfg: SimConfig) -> list[LayerProvider]:
    """The dashboard's ground-truth layers for footage that has any (none, with a warning, when it fails)."""
    try:
        meta = resolve_metadata(cfg.footage)
        with open_footage(cfg.footage, altitude_m=cfg.footage_alt_m, hfov_deg=cfg.footage_hfov_deg,
                          gsd_m_per_px=cfg.footage_gsd_m_per_px) as src:  # fmt: skip
            world = world_from_source(src, meta)
    except Exception as exc:  # ground truth is an extra: the run goes on without it
        log.warning("dashboard: no ground-truth layers (%s)", exc)
        return []
    return world_layers(world)


class SitlApp:
    """One simulated vehicle: satisfies viva_sitl.mavlink's VehicleLink protocol."""

    def __init__(
        self,
        config: SimConfig,
        *,
        video: bool = True,
        run_dir: Path | None = None,
        dashboard: DashboardConfig | None = None,
        scenario: tuple[Scenario, Limits] | None = None,
    ) -> None:
        self.config = config
        self.vehicle = Vehicle(config, super_resolution=super_resolution_from_config(config))
        self.sim: Simulator = self.vehicle.sim
        self.params: ParamStore = self.vehicle.params
        self.boot_wall_time_s = time.time()
        self.state_wall_time_s = self.boot_wall_time_s
        self.run_dir = run_dir or Path("runs") / time.strftime("%Y%m%d-%H%M%S")
        self.pacer = RealTimePacer(dt_s=self.sim.params.dt_s, speed=config.speed)
        self.video: VideoPipeline | None = None
        self.scheduler: FrameScheduler | None = None
        self.last_frame: RenderedFrame | None = None
        # --- dashboard (viva_sitl/dashboard): construction ---------------------------------------------
        self.dashboard: Dashboard | None = None
        self.dashboard_note = ""  # why there is none, for the ready line
        dash_cfg = dashboard if dashboard is not None else DashboardConfig(enabled=False)
        if dash_cfg.enabled:
            self.dashboard = Dashboard(self, dash_cfg)
        # --- end dashboard ----------------------------------------------------------------------------
        if video:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            vcfg = dataclasses.replace(config.video, sdp_dir=str(self.run_dir))
            extra = (self.dashboard.vac,) if self.dashboard is not None else ()
            self.video = VideoPipeline(
                vcfg, config.camera.width_px, config.camera.height_px, extra_outputs=extra
            )
            self.scheduler = FrameScheduler(
                self._render_tick, self.video.submit, config.video.fps, name="viva-render"
            )
        mav = config.mavlink
        # a .tlog of every run, in its run directory (as QGroundControl logs every flight)
        if mav.tlog and not mav.tlog_path:
            mav = dataclasses.replace(mav, tlog_path=str(self.run_dir / "telemetry.tlog"))
        elif not mav.tlog:
            mav = dataclasses.replace(mav, tlog_path=None)
        self.endpoint = MavlinkEndpoint(self, mav)
        # the trajectory of every run (recording.py), for `viva-sitl replay` and analysis
        self.trajectory = TrajectoryRecorder(self.run_dir / TRAJECTORY_FILE)
        self._trajectory_task: asyncio.Task[None] | None = None
        # --- a landing trial (`run --scenario FILE`): viva_sitl.evaluation.session ---------------------
        self.trial: ScenarioSession | None = None
        self.pilot_wait_wall_s: float | None = None  # a trial: wall seconds its clock waited for the pilot
        if scenario is not None:
            self.trial = ScenarioSession(scenario[0], scenario[1], self.vehicle, self.run_dir)
            self.endpoint.add_event_listener(self.trial.on_statustext)
        self._stopping = asyncio.Event()
        self._physics_task: asyncio.Task[None] | None = None
        self.flightlog: FlightLog | None = None  # the run's PX4 ULog (flightlog.py), opened by run()
        # --- timing (viva_sitl.timing): realtime, lockstep or charged ------------------------------------
        self.timing = Timing(config.timing)
        charged = self.timing is Timing.CHARGED
        self.timing_stats = TimingStats(
            self.timing, config.speed, config.pilot_cpu_factor if charged else None,
            config.pilot_latency_ms if charged else None,
        )  # fmt: skip
        self.pilot_pid: int | None = None  # --pilot-pid; else found from the first MAVLink message's sender
        self._pilot_tree: PilotTree | None = None
        self._next_pilot_search_s = 0.0  # finding the owner of a port scans /proc (~40 ms): not every quantum
        if self.trial is not None:
            self.trial.timing = self._timing_record

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

    def _render_tick(self, tick: int) -> RenderedFrame | None:
        """Render thread: the VAC at the latest (frozen) state; wall time = when that state was produced."""
        if self.vehicle.camera_dropped:  # an injected camera failure (OFF): no frame to any output
            return None
        frame = self.vehicle.render(self.sim.state, wall_time_s=self.state_wall_time_s)  # gimbal applied
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
            if self.video.rtsp_url:  # RTSP: the H.264 stream's packets (video/rtsp.py)
                streams.append(VideoStreamSpec(self.video.rtsp_url, StreamEncoding.H264, "VAC H.264 RTSP",
                                               bitrate_bps=vc.bitrate_kbps * 1000, **common))  # type: ignore[arg-type]  # fmt: skip
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
        if self.flightlog is not None:
            self._log_capture(seq, frame, ok)
        if ok:
            path.with_suffix(".json").write_text(json.dumps(frame.meta.to_dict(), indent=1))
        return CaptureResult(ok=ok, path=str(path.resolve()), meta=frame.meta)

    # --- loops ---------------------------------------------------------------------------
    def _step_once(self) -> None:
        if self.dashboard is not None:  # its sticks reach the autopilot at every step (an RC receiver)
            self.dashboard.before_step(self.vehicle.time_s)
        self.vehicle.step(1)
        if self.flightlog is not None:
            self.flightlog.step(self.sim.state, self.autopilot)
        self.endpoint.on_sim_step()  # telemetry, heartbeats and MAVLink timers run on sim time
        if self.trajectory.due(self.sim.state.time_s):
            self._sample_trajectory()
        if self.trial is not None and self.trial.after_step():
            self.stop()  # the trial is over (landed, crash, left the footage, timeout)

    async def _physics(self) -> None:
        """The paced physics loop; a trial (`--scenario`) first holds the clock at 0 until the pilot connects."""
        if self.trial is not None:
            await self._wait_for_pilot()
        if self.timing is Timing.REALTIME:
            watch = asyncio.create_task(self._watch_pilot(), name="viva-pilot-watch")
            try:
                await run_paced(self.pacer, self._step_once, self._after_batch)
            finally:
                watch.cancel()
        else:
            await self._physics_lockstep()

    def _timing_record(self) -> dict[str, object]:
        """The run's clock and what its pilot experienced (end.json "timing", the stop line)."""
        self.timing_stats.max_setpoint_gap_s = self.endpoint.max_setpoint_gap_s
        self.timing_stats.skipped_steps = self.pacer.skipped_steps
        return self.timing_stats.to_dict()

    def _find_pilot(self) -> PilotTree | None:
        """The pilot's process group: --pilot-pid's, else the owner's of the local UDP port its MAVLink came from."""
        if self._pilot_tree is not None:
            return self._pilot_tree
        now = time.monotonic()
        if now < self._next_pilot_search_s:
            return None
        self._next_pilot_search_s = now + PILOT_SEARCH_PERIOD_S
        pid = self.pilot_pid
        if pid is None:
            for _, (host, port), _age in self.endpoint.peers_heard():
                if host.startswith("127.") or host in ("::1", "localhost"):
                    pid = owner_of_udp_port(port)
                    if pid is not None:
                        break
        if pid is None:
            return None
        pgid = process_group(pid)
        if pgid is None or pgid == os.getpgid(0):
            # the pilot shares our process group (started by the same shell job): watch the pilot's process alone
            pgid = pid if pgid is not None else None
        if pgid is None:
            return None
        extra = zmq_io_threads() if self.video is not None and self.video.publisher is not None else ()
        self._pilot_tree = PilotTree(pgid, extra_threads=extra, exclude=(os.getpid(),))
        self.timing_stats.pilot_pid = pid
        log.info("timing %s: watching the pilot's process group %d (pid %d)", self.timing.value, pgid, pid)
        return self._pilot_tree

    async def _watch_pilot(self) -> None:
        """Realtime: read the pilot's CPU time and run-queue delay now and then (what it experienced)."""
        if supported():
            return
        while True:
            await asyncio.sleep(WATCH_PERIOD_S)
            tree = self._find_pilot()
            if tree is not None:
                self.timing_stats.observe(tree.sample(time.monotonic()))

    async def _physics_lockstep(self) -> None:
        """Lockstep / charged (viva_sitl.timing): a quantum of physics, then wait until the pilot is idle."""
        why = supported()
        if why:
            log.error("%s: running in realtime instead", why)
            self.timing_stats.note = why
            await run_paced(self.pacer, self._step_once, self._after_batch)
            return
        dt = self.vehicle.dt_s
        clock = LockstepClock(dt, self.config.speed)
        clock.start()
        q_steps = max(1, round(QUANTUM_S / dt))
        charged = self.timing is Timing.CHARGED
        factor = self.config.pilot_cpu_factor
        latency_s = self.config.pilot_latency_ms / 1000.0
        video = self.video if self.scheduler is not None else None
        frame_period = 1.0 / self.config.video.fps
        next_frame_t = self.sim.state.time_s
        seen_t = (
            self.sim.state.time_s
        )  # the sim time of what the pilot last saw: the last frame, else the state
        tick = 0
        busy_run = 0  # consecutive quanta after which the pilot was still busy
        gate: PilotGate | None = None
        while True:
            wait = clock.wall_until_due_s()
            if wait > 0:
                await asyncio.sleep(
                    wait
                )  # the pilot is idle: the clock runs at `speed`; messages arrive meanwhile
            for _ in range(q_steps):
                if charged:
                    self.endpoint.release_due(self.sim.state.time_s)
                self._step_once()
                if video is not None and self.sim.state.time_s + 1e-9 >= next_frame_t:
                    next_frame_t += frame_period
                    self.state_wall_time_s = time.time()
                    frame = self._render_tick(tick)  # a frame at an exact sim time, not a wall tick
                    if frame is not None:  # None: an injected camera failure drops it
                        video.submit(frame)
                        seen_t = self.sim.state.time_s
                    tick += 1
            clock.mark_done(q_steps)
            self._after_batch()
            if gate is None:
                tree = self._find_pilot()
                if tree is None:
                    continue  # no pilot yet: the clock runs at `speed`
                gate = PilotGate(tree, self.timing_stats)
                if charged:
                    self.endpoint.hold_incoming(True)
            t0 = time.monotonic()
            never_idle = self.timing_stats.never_idle
            cpu_s = await gate.wait_idle(ready=video.idle if video is not None else lambda: True)
            clock.frozen(time.monotonic() - t0)
            self.timing_stats.quanta += 1
            busy_run = busy_run + 1 if self.timing_stats.never_idle > never_idle else 0
            if busy_run >= NEVER_IDLE_QUANTA:
                why = (
                    f"the pilot (pid {self.timing_stats.pilot_pid}) never became idle for {busy_run} quanta "
                    f"(at least {busy_run * NEVER_IDLE_GIVE_UP_S:g} s of its CPU time): {self.timing.value} timing needs a "
                    "pilot that waits for input (a busy-polling loop never does); run it with --timing realtime"
                )
                log.error("%s", why)
                self.timing_stats.note = why
                if self.trial is not None:
                    self.trial.abort(TrialEnd.PILOT_ERROR, why)
                if charged:
                    self.endpoint.hold_incoming(False)
                await run_paced(self.pacer, self._step_once, self._after_batch)  # realtime from here on
                return
            if charged:
                now = self.sim.state.time_s
                charge = cpu_s * factor
                # a fixed latency per frame counts from the frame the pilot answered (without video: from the
                # state it was sent); the CPU charge from now; what it sent takes effect at the later of the two
                self.endpoint.stamp_held(
                    max(now + charge, (seen_t if video is not None else now) + latency_s)
                )
                clock.charge(charge)
                self.timing_stats.charged_sim_s += charge

    async def _wait_for_pilot(self) -> None:
        """Simulated time stands still until the first MAVLink message from the pilot arrives (a pilot that starts
        slowly, e.g. a 3 s import, misses nothing of its scenario: "land now" at land_at_s is land_at_s after it
        connected), or PILOT_WAIT_MAX_S wall seconds passed (a listen-only pilot; then "land now" is repeated until
        it acts). Heartbeats go out meanwhile (the endpoint's wall-clock loop), so MAVSDK and pymavlink discover
        the vehicle."""
        t0 = time.monotonic()
        while self.endpoint.rx_messages == 0 and time.monotonic() - t0 < PILOT_WAIT_MAX_S:
            await asyncio.sleep(0.005)
        self.pilot_wait_wall_s = round(time.monotonic() - t0, 3)
        if self.endpoint.rx_messages == 0:
            log.warning(
                "no MAVLink message from the pilot after %g s: the trial's clock starts anyway",
                PILOT_WAIT_MAX_S,
            )

    def _sample_trajectory(self) -> None:
        s = self.sim.state
        ap = self.autopilot
        self.trajectory.add(
            Sample(
                float(s.time_s),
                floats3(s.pos_ned_m),
                floats3(s.vel_ned_m_s),
                floats3(s.att_rpy_rad),
                ap.mode.name,
                bool(ap.armed),
                ap.landed_state.name,
                self.sim.footage_index(float(s.time_s)),
                100.0 * float(ap.battery_remaining),
                float(ap.battery_voltage_v),
            )
        )

    def _after_batch(self) -> None:
        self.state_wall_time_s = time.time()
        self.pacer.dt_s = self.vehicle.dt_s

    def stop(self) -> None:
        self._stopping.set()

    async def run(self, duration_s: float | None = None, ready: bool = True) -> None:
        if self.scheduler is not None:
            # First render decodes/generates the footage frame and builds caches: do it before we are "ready".
            await asyncio.get_running_loop().run_in_executor(None, self._render_tick, -1)
        try:
            write_run_info(self.run_dir, self.config, self.sim.footage.metadata.name, self.trajectory.rate_hz)
        except OSError as exc:  # the run goes on; the trajectory counts its write errors (stop line)
            log.warning("cannot write %s: %s (no replay of this run)", self.run_dir, exc.strerror or exc)
        self._open_flightlog()
        self._sample_trajectory()  # the initial state
        self._trajectory_task = asyncio.create_task(self.trajectory.run(), name="viva-trajectory")
        # dashboard: start (first: a busy --dashboard-port fails before anything runs)
        if self.dashboard is not None:
            # the footage's ground truth (objects, risk map) as overview layers, built off the loop
            for layer in await asyncio.get_running_loop().run_in_executor(None, self._world_layers):
                self.dashboard.add_layer(layer)
            await self.dashboard.start()
        await self.endpoint.start()
        if self.video is not None and self.scheduler is not None:
            self.video.start()
            if self.timing is Timing.REALTIME:  # lockstep renders in the physics loop, at sim-time ticks
                self.scheduler.start()
        self._physics_task = asyncio.create_task(self._physics(), name="viva-physics")
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
            self._trajectory_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._trajectory_task
            self._sample_trajectory()  # the final state
            await asyncio.get_running_loop().run_in_executor(None, self.trajectory.close)
            if self.flightlog is not None:
                await asyncio.get_running_loop().run_in_executor(None, self.flightlog.close)
            if self.dashboard is not None:  # dashboard: stop
                await self.dashboard.stop()
            await self.endpoint.stop()
            if self.scheduler is not None:
                self.scheduler.stop()
            if self.video is not None:
                self.video.stop()
            if self.trial is not None:
                self.trial.finish()
            self.sim.close()
            self._print_stats()

    def _world_layers(self) -> list[LayerProvider]:
        return _world_layers_of(self.config)

    # --- the PX4 ULog of the run (viva_sitl/flightlog.py), served over the MAVLink log protocol -------------------
    def _open_flightlog(self) -> None:
        try:
            flog = FlightLog(self.run_dir / LOG_FILE, self.geo, self.params, start_time_s=self.time_s,
                             system_id=self.config.mavlink.system_id)  # fmt: skip
        except OSError as exc:  # the run goes on without a ULog
            log.warning(
                "cannot write %s: %s (no ULog of this run)", self.run_dir / LOG_FILE, exc.strerror or exc
            )
            return
        self.flightlog = flog
        self.endpoint.logs.set_source(lambda: [(flog.path, not flog.writer.closed)])
        self.endpoint.add_event_listener(lambda text, severity: flog.text(severity, self.time_s, text))

    def _log_capture(self, seq: int, frame: RenderedFrame, ok: bool) -> None:
        assert self.flightlog is not None
        s = self.sim.state
        lat, lon, alt = self.geo.ned_to_global(*floats3(s.pos_ned_m))
        ground = float(self.autopilot.eav.ground_z_ned_m) - float(s.pos_ned_m[2])
        q = quat_from_euler(*floats3(s.att_rpy_rad))
        self.flightlog.camera_capture(seq, float(s.time_s), lat, lon, alt, ground, q, ok)

    def _print_ready(self) -> None:
        m = self.config.mavlink
        api_host, api_port = self.endpoint.api_address
        gcs_host, gcs_port = self.endpoint.gcs_address
        parts = [
            f"viva-sitl ready: sysid {m.system_id} footage {self.sim.footage.metadata.name}",
            f"mavlink api udp {api_host}:{api_port} -> {m.api_remote_host}:{m.api_remote_port_resolved}",
            f"gcs udp {gcs_host}:{gcs_port} -> {m.gcs_remote_host}:{m.gcs_remote_port}",
        ]
        if self.endpoint.tlog_path:
            parts.append(f"tlog {Path(self.endpoint.tlog_path).resolve()}")
        if self.video is not None:
            for kind, sdp in self.video.sdp_paths.items():
                parts.append(f"{kind} rtp sdp {sdp.resolve()}")
            if self.video.rtsp_url:
                parts.append(f"rtsp {self.video.rtsp_url}")
            if self.video.frame_socket_endpoint:
                parts.append(f"frames {self.video.frame_socket_endpoint}")
        if self.dashboard is not None:  # dashboard: ready-line part
            parts.append(f"dashboard {self.dashboard.url}")
        elif self.dashboard_note:
            parts.append(f"dashboard {self.dashboard_note}")
        print(" | ".join(parts), flush=True)

    def _print_stats(self) -> None:
        stats: dict[str, object] = {
            "sim_time_s": round(self.time_s, 3),
            "skipped_physics_steps": self.pacer.skipped_steps,
        }
        if self.pilot_wait_wall_s is not None:
            stats["pilot_wait_wall_s"] = self.pilot_wait_wall_s
        stats["timing"] = self._timing_record()
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
        if self.dashboard is not None:
            stats["dashboard"] = self.dashboard.stats()
        stats["trajectory"] = {"path": str(self.trajectory.path.resolve()), "rows": self.trajectory.rows_written,
                               "write_errors": self.trajectory.write_errors}  # fmt: skip
        if self.flightlog is not None:
            stats["ulog"] = self.flightlog.stats
        if self.endpoint.tlog_path:
            stats["tlog"] = str(Path(self.endpoint.tlog_path).resolve())
        print(f"viva-sitl stopped: {json.dumps(stats, default=str)}", file=sys.stderr, flush=True)


def config_from_args(args: argparse.Namespace) -> SimConfig:
    cfg = SimConfig.load(args.config)
    sim_updates: dict[str, object] = {}
    if args.footage:
        sim_updates["footage"] = args.footage
    if args.speed is not None:
        sim_updates["speed"] = args.speed
    if getattr(args, "timing", None) is not None:
        sim_updates["timing"] = args.timing
    if getattr(args, "pilot_cpu_factor", None) is not None:
        sim_updates["pilot_cpu_factor"] = args.pilot_cpu_factor
    if getattr(args, "pilot_latency_ms", None) is not None:
        sim_updates["pilot_latency_ms"] = args.pilot_latency_ms
    if args.seed is not None:
        sim_updates["seed"] = args.seed
    # placement, as PX4 SITL: --home, else [sim] home, else PX4_HOME_LAT/LON/ALT, else the footage's own place
    home = getattr(args, "home", None)
    if home is None and cfg.home is None:
        try:
            home = home_from_env()
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    if home is not None:
        sim_updates["home"] = home
    for key, flag in (("footage_alt_m", "footage_alt"), ("footage_hfov_deg", "footage_hfov"),
                      ("footage_gsd_m_per_px", "footage_gsd")):  # fmt: skip
        if getattr(args, flag, None) is not None:
            sim_updates[key] = getattr(args, flag)
    mav = cfg.mavlink
    if args.instance is not None:
        mav = dataclasses.replace(mav, instance=args.instance)
    mav_updates = {
        "listen_host": args.listen,
        "api_remote_port": args.api_port,
        "gcs_remote_port": args.gcs_port,
        "api_local_port": args.api_local_port,
        "gcs_local_port": args.gcs_local_port,
        "tlog_path": getattr(args, "tlog", None),
        "signing_key": getattr(args, "signing_key", None),
    }
    if getattr(args, "no_tlog", False):
        mav = dataclasses.replace(mav, tlog=False, tlog_path=None)
    elif getattr(args, "tlog", None):
        mav = dataclasses.replace(mav, tlog=True)
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
    if getattr(args, "rtsp", None) is not None:  # --rtsp [PORT]: -1 = the config's port (after --instance)
        video = dataclasses.replace(
            video, rtsp=True, rtsp_port=args.rtsp if args.rtsp >= 0 else video.rtsp_port
        )
    cfg = dataclasses.replace(cfg, mavlink=mav, video=video, **sim_updates)  # type: ignore[arg-type]
    if getattr(args, "scenario", None):  # a trial's start (pose, footage, parameters) over the config
        cfg = scenario_config(cfg, read_scenario_file(args.scenario)[0])
    return cfg


def dashboard_config_from_args(args: argparse.Namespace, instance: int) -> DashboardConfig:
    """--dashboard-port / --no-dashboard (the dashboard listens where --listen says, loopback by default)."""
    return DashboardConfig(
        enabled=not getattr(args, "no_dashboard", False),
        host=getattr(args, "listen", None) or "127.0.0.1",
        port=getattr(args, "dashboard_port", None),
        instance=instance,
    )


def run_from_args(args: argparse.Namespace) -> int:
    try:
        cfg = config_from_args(args)
    except ValueError as exc:  # a command-line value a config section refuses (e.g. --instance 500)
        print(f"viva-sitl: {exc}", file=sys.stderr)
        return 2
    scenario = read_scenario_file(args.scenario) if getattr(args, "scenario", None) else None
    if cfg.timing != "realtime" and supported():
        print(f"viva-sitl: {supported()}", file=sys.stderr)
        return 2
    app = SitlApp(
        cfg,
        video=not args.no_video,
        run_dir=Path(args.run_dir) if args.run_dir else None,
        dashboard=dashboard_config_from_args(args, cfg.mavlink.instance),
        scenario=scenario,
    )
    app.pilot_pid = getattr(args, "pilot_pid", None)

    async def main() -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, app.stop)
        await app.run(duration_s=args.duration)

    try:
        asyncio.run(main())
    except EndpointStartError as exc:  # one line naming the port (or the tlog), no traceback
        print(f"viva-sitl: {exc.strerror}", file=sys.stderr)
        return 2
    except ValueError as exc:
        if "already in use" not in str(exc):
            raise
        print(f"viva-sitl: {exc} (run with --instance N, N = 1, 2, ...)", file=sys.stderr)
        return 2
    return 0


def replay_from_args(args: argparse.Namespace) -> int:
    """`viva-sitl replay RUN_DIR`: the recorded run in the dashboard until Ctrl-C (or --duration)."""
    from viva_sitl.dashboard.replay import ReplayApp, ReplayError, load_recording

    try:
        recording = load_recording(Path(args.run_dir), footage=getattr(args, "footage", None))
    except ReplayError as exc:
        print(f"viva-sitl: {exc}", file=sys.stderr)
        return 2
    app = ReplayApp(recording)
    dash_cfg = DashboardConfig(host=getattr(args, "listen", None) or "127.0.0.1", port=args.dashboard_port)
    dashboard = Dashboard(app, dash_cfg, replay=True)

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        for layer in await loop.run_in_executor(None, _world_layers_of, recording.config):
            dashboard.add_layer(layer)
        await dashboard.start()
        try:
            r = recording
            print(f"viva-sitl replay ready: {r.path} ({r.source}, {len(r.samples)} samples, "
                  f"{r.start_s:.2f}..{r.end_s:.2f} s) footage {app.sim.footage.metadata.name} "
                  f"| dashboard {dashboard.url}", flush=True)  # fmt: skip
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), args.duration)
        finally:
            await dashboard.stop()
            await loop.run_in_executor(None, app.close)

    asyncio.run(main())
    return 0


__all__ = ["SitlApp", "config_from_args", "dashboard_config_from_args", "replay_from_args", "run_from_args"]
