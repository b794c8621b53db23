"""Real time, end to end: `viva-sitl run` over 4K footage with a 1280x720 30 fps H.264 stream, a decoding client and a
flying MAVLink client, for --duration seconds (issue 4's target: 10 min, <= 1 % dropped, <= 45 ms H.264 / <= 15 ms MJPEG).

    python bench/bench_realtime.py                        # 600 s, H.264 + frame socket (the default outputs)
    python bench/bench_realtime.py --duration 60 --mjpeg  # also MJPEG over RTP, with its own decoding client

What runs (all on this machine, over loopback):
- viva-sitl as a subprocess (tests/sitl_process.SitlProcess) over the shared 1080p interchange clip upscaled to
  3840x2160 (bench_core.make_clip, cached in /tmp/viva-sitl-bench), camera 1280x720, [video] stamp_counter = true;
- a PyAV client per RTP stream in its own process (this script with --client): opens the SDP with the receiver options
  of viva_sitl.video.RtpReceiver, decodes every frame, reads the stamped counter from the luma plane and logs
  (counter, time.time()) - "decoded" = the decoder returned the picture (no BGR conversion);
- a frame-socket subscriber in this process that keeps each frame's metadata only (counter -> pose wall time);
- a pymavlink client on the API link (onboard telemetry profile, as MAVSDK/companions get): takeoff to 20 m, then
  offboard velocity circles (5 m/s, 30 s period) until the end.
Glass-to-glass latency = decode time at the client - FrameMeta.wall_time_s of the same counter (the time.time() at
which the physics produced the pose the frame was rendered at). CPU from /proc (utime+stime) and /proc/stat.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import platform
import shlex
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "bench"))

CLK_TCK = os.sysconf("SC_CLK_TCK")
ALT_M = 20.0
CIRCLE_SPEED_M_S = 5.0
CIRCLE_PERIOD_S = 30.0


# ---------------------------------------------------------------------------------------------------- client
def run_client(sdp: str, out_path: str) -> int:
    """Decode the RTP stream of `sdp`, write 'counter wall_time' lines to out_path until SIGTERM or 5 s of silence."""
    import av

    from viva_sitl.video import read_counter

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    options = {  # those of viva_sitl.video.RtpReceiver(low_delay=True)
        "protocol_whitelist": "file,udp,rtp",
        "flags": "low_delay",
        "reorder_queue_size": "0",
        "analyzeduration": "100000",
        "probesize": "32768",
    }
    container = av.open(sdp, format="sdp", options=options, timeout=5.0)
    stream = container.streams.video[0]
    stream.thread_type = "SLICE"
    errors = unreadable = 0
    with open(out_path, "w", buffering=1 << 16) as out:
        try:
            for packet in container.demux(stream):
                try:
                    frames = packet.decode()
                except av.InvalidDataError:
                    errors += 1
                    continue
                for frame in frames:
                    t = time.time()
                    plane = frame.planes[0]
                    y = np.frombuffer(memoryview(plane), np.uint8).reshape(frame.height, plane.line_size)[
                        :, : frame.width
                    ]
                    c = read_counter(y)
                    if c is None:
                        unreadable += 1
                    else:
                        out.write(f"{c} {t:.6f}\n")
                if stop.is_set():
                    break
        except (av.FFmpegError, OSError):
            pass
        out.write(f"# errors {errors} unreadable {unreadable}\n")
    container.close()
    return 0


# ---------------------------------------------------------------------------------------------------- helpers
def proc_cpu_s(pid: int) -> float:
    """utime + stime of a process (and its threads) in seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def machine_cpu() -> tuple[float, float]:
    """(busy, total) jiffies of the whole machine from /proc/stat."""
    v = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = v[3] + v[4]
    return float(sum(v) - idle), float(sum(v))


def cpu_model() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or "?"


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if values else math.nan


class MetaCollector:
    """Frame-socket subscriber keeping only the metadata (part 1) of every message."""

    def __init__(self, endpoint: str) -> None:
        import zmq

        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.RCVHWM, 1000)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.subscribe(b"vivasitl.frame.v1")
        self.sock.connect(endpoint)
        self.meta: dict[int, tuple[float, float]] = {}  # counter -> (pose wall time, sim time)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            if not self.sock.poll(200):
                continue
            parts = self.sock.recv_multipart(copy=False)
            m = json.loads(parts[1].bytes)
            self.meta[int(m["frame_counter"])] = (float(m["wall_time_s"]), float(m["sim_time_s"]))

    def close(self) -> None:
        self._stop.set()
        self.thread.join(timeout=2.0)
        self.sock.close(0)
        self.ctx.term()


class CircleFlight:
    """Offboard velocity setpoints at 20 Hz: a horizontal circle at CIRCLE_SPEED_M_S, altitude held at alt_m."""

    def __init__(self, peer: Any, alt_m: float = ALT_M) -> None:
        self.peer, self.alt_m = peer, alt_m
        self._stop = threading.Event()
        self.t0 = time.monotonic()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        from pymavlink.dialects.v20 import common as m2

        mask = 0b0000_1101_1100_0111  # use vx, vy, vz only (ignore position, acceleration, yaw, yaw rate)
        while not self._stop.wait(0.05):
            w = 2.0 * math.pi / CIRCLE_PERIOD_S * (time.monotonic() - self.t0)
            lp = self.peer.latest("LOCAL_POSITION_NED")
            vz = 0.0 if lp is None else max(-1.0, min(1.0, 0.8 * (-self.alt_m - lp.z)))
            self.peer.send(
                self.peer.mav.set_position_target_local_ned_encode(
                    0,
                    1,
                    1,
                    m2.MAV_FRAME_LOCAL_NED,
                    mask,
                    0,
                    0,
                    0,
                    CIRCLE_SPEED_M_S * math.cos(w),
                    CIRCLE_SPEED_M_S * math.sin(w),
                    vz,
                    0,
                    0,
                    0,
                    0,
                    0,
                )  # fmt: skip
            )

    def stop(self) -> None:
        self._stop.set()
        self.thread.join(timeout=2.0)


def read_client(path: Path) -> tuple[dict[int, float], str]:
    got: dict[int, float] = {}
    tail = ""
    if path.exists():
        for line in path.read_text().splitlines():
            if line.startswith("#"):
                tail = line[1:].strip()
                continue
            c, t = line.split()
            got.setdefault(int(c), float(t))
    return got, tail


def stream_figures(
    name: str, got: dict[int, float], meta: dict[int, tuple[float, float]], fps: float
) -> dict[str, Any]:
    if not got:
        return {"stream": name, "decoded": 0}
    lat = [(t - meta[c][0]) * 1e3 for c, t in got.items() if c in meta]
    cs = sorted(got)
    span = cs[-1] - cs[0] + 1  # rendered frames in the client's window (counters are consecutive per render)
    ts = sorted(got.values())
    window_s = ts[-1] - ts[0]
    return {
        "stream": name,
        "decoded": len(got),
        "counter_span": span,
        "missing_in_span": span - len(got),
        "missing_pct": 100.0 * (span - len(got)) / span,
        "window_s": round(window_s, 1),
        "decoded_fps": len(got) / window_s if window_s > 0 else math.nan,
        "dropped_vs_fps_pct": 100.0 * max(0.0, 1.0 - len(got) / (window_s * fps + 1))
        if window_s > 0
        else math.nan,
        "latency_ms_median": statistics.median(lat) if lat else math.nan,
        "latency_ms_p95": pct(lat, 95),
        "latency_ms_p99": pct(lat, 99),
        "latency_ms_max": max(lat) if lat else math.nan,
        "latency_samples": len(lat),
    }


# ---------------------------------------------------------------------------------------------------- main
def _shell_words(text: str) -> list[str]:
    """--sitl-cache-args: split as a shell would; a bad quote is argparse's one-line error."""
    try:
        return shlex.split(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def main() -> int:
    from bench_core import add_tile_cache_arg, apply_tile_cache

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=600.0, help="wall seconds of the run after ready")
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--fps", type=int, default=30)
    ap.add_argument(
        "--alt", type=float, default=ALT_M, help="altitude of the offboard circles, m (default 20)"
    )
    ap.add_argument("--mjpeg", action="store_true", help="also stream MJPEG over RTP and decode it")
    ap.add_argument(
        "--footage", help="footage path or name (default: the 4K clip made from the shared 1080p clip)"
    )
    ap.add_argument("--clip-frames", type=int, default=60, help="frames of the generated 4K clip")
    ap.add_argument("--json", type=Path, help="write the figures here as JSON")
    ap.add_argument(
        "--sitl-cache-args", type=_shell_words, default=[],
        help="automatic-cache flags for the viva-sitl run child, e.g. \"--cache-compact --tile-cache-dir DIR\"",
    )  # fmt: skip
    add_tile_cache_arg(ap)  # the viva-sitl run child inherits it
    ap.add_argument("--client", nargs=2, metavar=("SDP", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    apply_tile_cache(ap, args)
    if args.client:
        return run_client(*args.client)

    from bench_core import DEFAULT_CACHE, make_clip
    from pymavlink.dialects.v20 import common as m2
    from sitl_process import MavlinkPeer, SitlProcess, free_tcp_port, free_udp_ports, takeoff

    footage = args.footage or str(make_clip(DEFAULT_CACHE, args.clip_frames))
    load_before = os.getloadavg()
    figures: dict[str, Any] = {
        "command": " ".join([Path(sys.executable).name, "bench/bench_realtime.py", *sys.argv[1:]]),
        "machine": {"nproc": os.cpu_count(), "cpu": cpu_model(), "loadavg_before": load_before},
        "config": {"footage": footage, "camera": f"{args.width}x{args.height}", "fps": args.fps,
                   "speed": args.speed, "duration_s": args.duration, "mjpeg": args.mjpeg, "alt_m": args.alt},
    }  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="bench_realtime_") as tmp_s:
        tmp = Path(tmp_s)
        cfg = tmp / "bench.toml"
        cfg.write_text(
            f"[camera]\nwidth_px = {args.width}\nheight_px = {args.height}\n"
            f"[video]\nstamp_counter = true\nfps = {args.fps}\n"
        )
        video_port, _, mjpeg_port, _ = free_udp_ports(4)
        extra = ["--config", str(cfg)] + (["--mjpeg-port", str(mjpeg_port)] if args.mjpeg else [])
        extra += args.sitl_cache_args
        sitl = SitlProcess(
            workdir=tmp, footage=footage, speed=args.speed, video_port=video_port,
            frame_socket_port=free_tcp_port(), extra_args=extra, ready_timeout_s=180.0, name="bench",
        )  # fmt: skip
        sitl.start()
        t_ready = time.monotonic()
        pid = sitl.proc.pid  # type: ignore[union-attr]
        parts = {
            p.split(" rtp sdp ")[0]: p.split(" rtp sdp ")[1]
            for p in sitl.ready_line.split(" | ")
            if " rtp sdp " in p
        }
        frames_ep = sitl.ready_line.rsplit("frames ", 1)[1].split(" | ")[0].strip()
        meta = MetaCollector(frames_ep)
        clients: dict[str, tuple[subprocess.Popen[bytes], Path]] = {}
        for kind, sdp in parts.items():
            out = tmp / f"client_{kind}.txt"
            clients[kind] = (
                subprocess.Popen([sys.executable, __file__, "--client", sdp, str(out)], cwd=REPO,
                                 env=dict(os.environ, PYTHONPATH=str(REPO))),
                out,
            )  # fmt: skip
        peer = MavlinkPeer(sitl.ports.api)
        flight: CircleFlight | None = None
        cpu0 = proc_cpu_s(pid)
        m0 = machine_cpu()
        w0 = time.monotonic()
        loads: list[float] = []
        notes: list[str] = []
        try:
            peer.wait_autopilot(30.0)
            takeoff(peer, args.alt, timeout_s=120.0)
            flight = CircleFlight(peer, args.alt)
            time.sleep(0.5)
            ack = peer.command_long(m2.MAV_CMD_DO_SET_MODE, [1.0, 6.0, 0.0])
            if ack.result != m2.MAV_RESULT_ACCEPTED:
                notes.append(f"offboard refused: MAV_RESULT {ack.result}")
            end = t_ready + args.duration
            next_load = time.monotonic()
            while time.monotonic() < end:
                if time.monotonic() >= next_load:
                    loads.append(os.getloadavg()[0])
                    next_load += 10.0
                time.sleep(min(1.0, max(0.0, end - time.monotonic())))
            cpu1 = proc_cpu_s(pid)
            m1 = machine_cpu()
            w1 = time.monotonic()
            client_cpu = {k: proc_cpu_s(p.pid) for k, (p, _) in clients.items()}
        finally:
            if flight is not None:
                flight.stop()
            code = sitl.stop(timeout_s=20.0)
            for p, _ in clients.values():
                with contextlib.suppress(ProcessLookupError):
                    p.send_signal(signal.SIGTERM)
            for p, _ in clients.values():
                try:
                    p.wait(timeout=10.0)
                except subprocess.TimeoutExpired:
                    p.kill()
            meta.close()
            peer.close()
        stats = sitl.stop_stats()
        figures["exit_code"] = code
        results = {k: read_client(out) for k, (_, out) in clients.items()}

    # --- figures -------------------------------------------------------------------------------------------
    wall = w1 - w0
    figures["machine"]["loadavg_during"] = {"median": statistics.median(loads) if loads else math.nan,
                                            "max": max(loads) if loads else math.nan}  # fmt: skip
    figures["machine"]["loadavg_after"] = os.getloadavg()
    busy = (m1[0] - m0[0]) / (m1[1] - m0[1])
    sitl_cores = (cpu1 - cpu0) / wall
    figures["cpu"] = {
        "window_s": round(wall, 1),
        "viva_sitl_cores": round(sitl_cores, 3),
        "viva_sitl_pct_of_machine": round(100.0 * sitl_cores / (os.cpu_count() or 1), 1),
        "clients_cpu_s_total": {k: round(v, 1) for k, v in client_cpu.items()},
        "machine_busy_pct": round(100.0 * busy, 1),
        "machine_idle_pct": round(100.0 * (1.0 - busy), 1),
    }
    render, video = stats.get("render", {}), stats.get("video", {})
    ticks = render.get("ticks", 0) + render.get("late_skipped", 0)
    h264o = video.get("outputs", {}).get("h264_rtp", {})
    figures["pipeline"] = {
        "ticks_due": ticks,
        "rendered": render.get("rendered"),
        "late_skipped_ticks": render.get("late_skipped"),
        "late_skipped_pct": 100.0 * render.get("late_skipped", 0) / ticks if ticks else math.nan,
        "render_ms_median": render.get("render_ms_median"),
        "render_ms_p95": render.get("render_ms_p95"),
        "submitted": video.get("submitted"),
        "dropped_max_output": video.get("dropped"),
        "dropped_pct": video.get("dropped_pct"),
        "per_output": {
            k: {kk: (round(vv, 2) if isinstance(vv, float) else vv) for kk, vv in v.items()}
            for k, v in video.get("outputs", {}).items()
        },  # fmt: skip
        "h264_dropped": h264o.get("dropped"),
        "frames_lost_pct": stats.get("frames_lost_pct"),  # the app's own: (late-skipped + queue drops) / due
    }
    figures["streams"] = {k: stream_figures(k, got, meta.meta, args.fps) for k, (got, _) in results.items()}
    for k, (_, tail) in results.items():
        figures["streams"][k]["client_tail"] = tail

    # physics real time: SYSTEM_TIME (wall usec, sim boot ms) over the run
    st = peer.messages("SYSTEM_TIME")
    phys: dict[str, Any] = {
        "sim_time_s": stats.get("sim_time_s"),
        "skipped_physics_steps": stats.get("skipped_physics_steps"),
    }
    if len(st) >= 3:
        wt = np.array([m.time_unix_usec / 1e6 for m in st])
        sm = np.array([m.time_boot_ms / 1e3 for m in st])
        slope = float(np.polyfit(wt - wt[0], sm - sm[0], 1)[0])
        resid = (sm - sm[0]) - args.speed * (wt - wt[0])
        phys.update({
            "sim_per_wall": round(slope, 5),
            "sim_minus_wall_s_final": round(float(resid[-1]), 4),
            "sim_minus_wall_s_maxabs": round(float(np.max(np.abs(resid - resid[0]))), 4),
            "samples": len(st),
        })  # fmt: skip
    if stats.get("sim_time_s") and phys.get("skipped_physics_steps") is not None:
        phys["skipped_pct"] = 100.0 * phys["skipped_physics_steps"] / (stats["sim_time_s"] / 0.004)
    figures["physics"] = phys

    # telemetry at the client (API link), after takeoff began
    t_lo = w0 + 5.0
    recs = [r for r in peer.records if r.t_s >= t_lo]
    span = (recs[-1].t_s - recs[0].t_s) if len(recs) > 1 else math.nan
    counts: dict[str, int] = {}
    for r in recs:
        counts[r.msg.get_type()] = counts.get(r.msg.get_type(), 0) + 1
    hb = [r.t_s for r in recs if r.msg.get_type() == "HEARTBEAT" and r.msg.get_srcComponent() == 1]
    figures["telemetry"] = {
        "window_s": round(span, 1),
        "messages_per_s": round(len(recs) / span, 1) if span else math.nan,
        "rates_hz": {k: round(v / span, 2) for k, v in sorted(counts.items(), key=lambda kv: -kv[1])},
        "heartbeat_gap_s_max": round(float(np.max(np.diff(hb))), 3) if len(hb) > 1 else math.nan,
        "mavlink_stats": {k: v for k, v in stats.get("mavlink", {}).items() if k != "peers"},
    }
    lp = [r.msg for r in recs if r.msg.get_type() == "LOCAL_POSITION_NED"]
    if lp:
        figures["flight"] = {
            "max_radius_m": round(max(math.hypot(m.x, m.y) for m in lp), 1),
            "alt_m_median": round(-statistics.median(m.z for m in lp), 2),
            "speed_m_s_median": round(statistics.median(math.hypot(m.vx, m.vy) for m in lp), 2),
        }
    figures["notes"] = notes

    print(json.dumps(figures, indent=1, default=str))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1, default=str))
    h = figures["streams"].get("h264", {})
    print(
        f"\nSUMMARY {args.duration:.0f}s: h264 decoded {h.get('decoded')} / span {h.get('counter_span')}, "
        f"dropped vs {args.fps} fps {h.get('dropped_vs_fps_pct', math.nan):.2f} %, "
        f"latency median {h.get('latency_ms_median', math.nan):.1f} ms p95 {h.get('latency_ms_p95', math.nan):.1f} ms; "
        f"physics sim/wall {phys.get('sim_per_wall')} skipped {phys.get('skipped_physics_steps')}; "
        f"viva-sitl {sitl_cores:.2f} cores, machine busy {100 * busy:.0f} %",
        file=sys.stderr,
    )
    if "mjpeg" in figures["streams"]:
        mj = figures["streams"]["mjpeg"]
        print(f"SUMMARY mjpeg: latency median {mj.get('latency_ms_median', math.nan):.1f} ms "
              f"p95 {mj.get('latency_ms_p95', math.nan):.1f} ms, missing {mj.get('missing_pct', math.nan):.2f} %",
              file=sys.stderr)  # fmt: skip
    return 0 if code == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
