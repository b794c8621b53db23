"""Video outputs: encode cost, glass-to-glass latency on loopback, dropped frames at 30 fps 1280x720, CPU headroom.

    python bench/bench_video.py                      # ~2.5 min: encode, latency (10 s each), sustained 60 s
    python bench/bench_video.py --duration 600       # the 10-minute sustained run
    python bench/bench_video.py --skip-encode --skip-latency --duration 30

Frames are rendered like the app does (a perspective warp of a 4K nadir still, ../shared/footage/songdo/00003.jpg,
moving with time; a synthetic texture when the footage is absent), stamped with their counter, and sent through
VideoPipeline. Latency = time.time() when the frame's pose was sampled (FrameMeta.wall_time_s, just before render)
-> time.time() when a PyAV client in another process has the decoded BGR frame (the stamped counter names the frame).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
from contextlib import closing
from dataclasses import replace
from pathlib import Path
from typing import Any

import av
import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.frame import FrameMeta, RenderedFrame
from viva_sitl.video import (
    FrameClient,
    FrameEncoding,
    FramePublisher,
    FrameScheduler,
    H264RtpOutput,
    MjpegRtpOutput,
    VideoConfig,
    VideoPipeline,
)

REPO = Path(__file__).resolve().parents[1]
FOOTAGE = REPO.parent / "shared" / "footage" / "songdo" / "00003.jpg"


# -- frames ----------------------------------------------------------------------------------------------------------
class Renderer:
    """A VAC-like render: a moving, slowly rotating view of a 4K still, by cv2.warpPerspective (INTER_LINEAR)."""

    def __init__(self, width: int, height: int, fps: int) -> None:
        self.width, self.height, self.fps = width, height, fps
        src = cv2.imread(str(FOOTAGE), cv2.IMREAD_COLOR) if FOOTAGE.is_file() else None
        if src is None:
            rng = np.random.default_rng(0)
            src = cv2.GaussianBlur(rng.integers(0, 256, (2160, 3840, 3), dtype=np.uint8), (0, 0), 3.0)
            self.source = "synthetic 3840x2160 texture"
        else:
            self.source = f"{FOOTAGE.name} ({src.shape[1]}x{src.shape[0]})"
        self.src = src

    def homography(self, t_s: float) -> np.ndarray:
        sh, sw = self.src.shape[:2]
        scale = 3.0 * self.width / sw  # the view spans 1/3 of the still: 1 px per source px at 1280 wide
        ang = 0.05 * t_s
        cx = sw / 2 + 600 * np.sin(0.2 * t_s)
        cy = sh / 2 + 300 * np.cos(0.15 * t_s)
        c, s = np.cos(ang) * scale, np.sin(ang) * scale
        # dst = S R (src - centre) + dst centre
        return np.array(
            [
                [c, -s, self.width / 2 - c * cx + s * cy],
                [s, c, self.height / 2 - s * cx - c * cy],
                [0.0, 0.0, 1.0],
            ]
        )

    def render(self, counter: int, wall_time_s: float) -> RenderedFrame:
        t = counter / self.fps
        img: NDArray[np.uint8] = cv2.warpPerspective(  # type: ignore[assignment]
            self.src, self.homography(t), (self.width, self.height), flags=cv2.INTER_LINEAR
        )
        k = ((600.0, 0.0, self.width / 2), (0.0, 600.0, self.height / 2), (0.0, 0.0, 1.0))
        meta = FrameMeta(
            frame_counter=counter,
            sim_time_s=t,
            wall_time_s=wall_time_s,
            pos_ned_m=(float(t), 0.0, -50.0),
            att_rpy_rad=(0.0, 0.0, 0.05 * t),
            vel_ned_m_s=(1.0, 0.0, 0.0),
            footage_frame_index=0,
            width_px=self.width,
            height_px=self.height,
            intrinsics_k=k,
            cam_rot_body=((0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
            cam_pos_body_m=(0.0, 0.0, 0.0),
            coverage=1.0,
        )
        return RenderedFrame(img, meta)


def free_rtp_port() -> int:
    for _ in range(200):
        with closing(socket.socket(socket.AF_INET, socket.SOCK_DGRAM)) as s:
            s.bind(("127.0.0.1", 0))
            port = int(s.getsockname()[1])
        if port % 2 == 0 and port < 65000:
            try:
                with closing(socket.socket(socket.AF_INET, socket.SOCK_DGRAM)) as b:
                    b.bind(("127.0.0.1", port + 1))
                return port
            except OSError:
                continue
    raise RuntimeError("no free RTP port pair")


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if values else float("nan")


# -- 1. encode cost --------------------------------------------------------------------------------------------------
class _PyavMjpeg:
    """The alternative MJPEG path (PyAV's mjpeg encoder) for comparison with cv2.imencode + RTP muxer."""

    name = "pyav_mjpeg"

    def __init__(self, port: int, width: int, height: int, fps: int) -> None:
        from fractions import Fraction

        self.c = av.open(f"rtp://127.0.0.1:{port}", mode="w", format="rtp")
        st = self.c.add_stream("mjpeg", rate=fps)
        assert isinstance(st, av.VideoStream)
        st.width, st.height, st.pix_fmt = width, height, "yuvj420p"
        st.codec_context.time_base = Fraction(1, fps)
        st.thread_count = 1
        st.codec_context.options = {"huffman": "default"}
        self.st, self.n = st, 0

    def write(self, frame: RenderedFrame) -> None:
        vf = av.VideoFrame.from_ndarray(frame.image_bgr, format="bgr24")
        vf.pts = self.n
        self.n += 1
        for p in self.st.encode(vf):
            self.c.mux(p)

    def close(self) -> None:
        self.c.close()


def bench_encode(sizes: list[tuple[int, int]], n_frames: int, fps: int) -> list[dict[str, Any]]:
    rows = []
    for w, h in sizes:
        r = Renderer(w, h, fps)
        frames = [r.render(k, time.time() + k / fps) for k in range(n_frames)]
        outputs: list[Any] = [
            H264RtpOutput("127.0.0.1", free_rtp_port(), w, h, fps, 4000, fps),
            MjpegRtpOutput("127.0.0.1", free_rtp_port(), w, h, fps, quality=80),
            _PyavMjpeg(free_rtp_port(), w, h, fps),
            FramePublisher("tcp://127.0.0.1:*", FrameEncoding.RAW),
            FramePublisher("tcp://127.0.0.1:*", FrameEncoding.JPEG, 80),
        ]
        labels = [
            "H.264 RTP (cv2 BGR->I420, x264 ultrafast zerolatency, mux)",
            "MJPEG RTP (cv2.imencode q80 + FFmpeg RFC 2435 mux) [chosen]",
            "MJPEG RTP via PyAV mjpeg encoder (alternative)",
            "frame socket RAW (no subscriber)",
            "frame socket JPEG q80 (no subscriber)",
        ]
        for out, label in zip(outputs, labels, strict=True):
            if hasattr(out, "open"):
                out.open()
            times = []
            for f in frames:
                t0 = time.perf_counter()
                out.write(f)
                times.append((time.perf_counter() - t0) * 1e3)
            out.close()
            times = times[5:]  # encoder warm-up
            rows.append(
                {
                    "size": f"{w}x{h}",
                    "output": label,
                    "median_ms": statistics.median(times),
                    "p95_ms": pct(times, 95),
                }
            )
            print(
                f"  encode {w}x{h} {label}: median {rows[-1]['median_ms']:.2f} ms, p95 {rows[-1]['p95_ms']:.2f} ms"
            )
    return rows


# -- 2. latency ------------------------------------------------------------------------------------------------------
RECEIVER = textwrap.dedent(
    """
    import json, sys, time, resource
    from viva_sitl.video import read_counter
    from viva_sitl.video.receiver import RtpReceiver
    n = int(sys.argv[2])
    got = 0
    t0 = time.time()
    with RtpReceiver(sys.argv[1], timeout_s=5.0) as rx:
        print(json.dumps({"opened_s": time.time() - t0}), flush=True)
        for t, img in rx.frames():
            print(json.dumps({"c": read_counter(img), "t": t}), flush=True)
            got += 1
            if got >= n:
                break
    ru = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({"cpu_s": ru.ru_utime + ru.ru_stime, "errors": rx.decode_errors}), flush=True)
    """
)

FRAME_CLIENT = textwrap.dedent(
    """
    import json, sys, time, resource
    from viva_sitl.video import FrameClient
    got = lat = 0
    lats = []
    with FrameClient(sys.argv[1]) as c:
        for img, meta in c.frames(timeout_s=5.0):
            lats.append(time.time() - meta["wall_time_s"])
            got += 1
    ru = resource.getrusage(resource.RUSAGE_SELF)
    lats.sort()
    print(json.dumps({"frames": got, "skipped": c.skipped, "cpu_s": ru.ru_utime + ru.ru_stime,
                      "lat_median_ms": 1e3 * lats[len(lats) // 2] if lats else None}), flush=True)
    """
)


def start_receiver(sdp: Path, n: int) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-c", RECEIVER, str(sdp), str(n)], stdout=subprocess.PIPE, text=True, cwd=str(REPO)
    )


def read_receiver(proc: subprocess.Popen[str], walls: dict[int, float], skip_s: float) -> dict[str, Any]:
    """Latencies (ms) of the frames a receiver subprocess decoded, skipping its first `skip_s` seconds."""
    assert proc.stdout is not None
    lat: list[float] = []
    first_t: float | None = None
    info: dict[str, Any] = {"bad_counter": 0}
    for line in proc.stdout:
        d = json.loads(line)
        if "c" not in d:
            info.update(d)
            continue
        c, t = d["c"], d["t"]
        if c is None or c not in walls:
            info["bad_counter"] += 1
            continue
        first_t = first_t if first_t is not None else t
        if t - first_t >= skip_s:
            lat.append((t - walls[c]) * 1e3)
    proc.wait(10)
    info["lat_ms"] = lat
    return info


def bench_latency(width: int, height: int, fps: int, seconds: float) -> list[dict[str, Any]]:
    rows = []
    variants: list[tuple[str, dict[str, Any]]] = [
        ("H.264 RTP (end-of-frame AUD, default)", {"h264_rtp": True, "h264_end_of_frame_aud": True}),
        ("H.264 RTP (no AUD)", {"h264_rtp": True, "h264_end_of_frame_aud": False}),
        ("MJPEG RTP", {"h264_rtp": False, "mjpeg_rtp": True}),
    ]
    for label, kw in variants:
        with tempfile.TemporaryDirectory() as d:
            cfg = replace(
                VideoConfig(frame_socket=False, stamp_counter=True, sdp_dir=d, fps=fps),
                h264_port=free_rtp_port(),
                mjpeg_port=free_rtp_port(),
                **kw,
            )
            r = Renderer(width, height, fps)
            walls: dict[int, float] = {}

            def render(tick: int, r: Renderer = r, walls: dict[int, float] = walls) -> RenderedFrame:
                now = time.time()
                walls[tick] = now
                return r.render(tick, now)

            with VideoPipeline(cfg, width, height) as pipe:
                sched = FrameScheduler(render, pipe.submit, fps)
                sched.start()
                kind = "h264" if cfg.h264_rtp else "mjpeg"
                proc = start_receiver(pipe.sdp_paths[kind], int((seconds + 1.5) * fps))
                info = read_receiver(proc, walls, skip_s=1.0)
                sched.stop()
            lat = info["lat_ms"]
            row = {
                "stream": label,
                "size": f"{width}x{height}",
                "frames": len(lat),
                "median_ms": statistics.median(lat) if lat else float("nan"),
                "p95_ms": pct(lat, 95),
                "max_ms": max(lat) if lat else float("nan"),
                "receiver_open_s": info.get("opened_s"),
                "bad_counter": info["bad_counter"],
                "encode_ms_median": pipe.stats()["encode_ms_median"],
            }
            rows.append(row)
            print(
                f"  latency {label} {width}x{height}: median {row['median_ms']:.1f} ms, p95 {row['p95_ms']:.1f} ms, "
                f"max {row['max_ms']:.1f} ms over {row['frames']} frames (unreadable stamps {row['bad_counter']})"
            )
    return rows


# -- 3. sustained 30 fps ---------------------------------------------------------------------------------------------
def _cpu_busy() -> tuple[float, float]:
    with open("/proc/stat") as f:
        vals = [float(x) for x in f.readline().split()[1:]]
    idle = vals[3] + vals[4]
    return sum(vals) - idle, sum(vals)


class Ticker:
    """A 250 Hz loop on its own thread, like the physics: how late its ticks run while the video works (GIL, CPU)."""

    def __init__(self, rate_hz: float) -> None:
        self.period = 1.0 / rate_hz
        self.late_ms: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)

    def _run(self) -> None:
        t0 = time.perf_counter()
        k = 0
        while not self._stop.is_set():
            k += 1
            due = t0 + k * self.period
            delay = due - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            self.late_ms.append((time.perf_counter() - due) * 1e3)

    def stats(self) -> dict[str, float]:
        v = self.late_ms
        return {
            "ticks": len(v),
            "late_ms_median": statistics.median(v),
            "late_ms_p99": pct(v, 99),
            "late_ms_max": max(v),
            "ticks_late_over_4ms_pct": 100.0 * sum(x > 4.0 for x in v) / len(v),
        }


def bench_sustained(
    width: int, height: int, fps: int, duration_s: float, clients: bool, x264_threads: int = 0
) -> dict[str, Any]:
    baseline = Ticker(250.0)  # the same loop without video: what the machine's other load alone does to it
    baseline.start()
    b_busy0, b_total0 = _cpu_busy()
    time.sleep(min(10.0, duration_s / 3))
    b_busy1, b_total1 = _cpu_busy()
    baseline.stop()
    with tempfile.TemporaryDirectory() as d:
        cfg = replace(
            VideoConfig(
                stamp_counter=True,
                sdp_dir=d,
                fps=fps,
                frame_socket_endpoint="tcp://127.0.0.1:*",
                x264_threads=x264_threads,
            ),
            h264_port=free_rtp_port(),
        )
        r = Renderer(width, height, fps)
        walls: dict[int, float] = {}

        def render(tick: int) -> RenderedFrame:
            now = time.time()
            walls[tick] = now
            return r.render(tick, now)

        with VideoPipeline(cfg, width, height) as pipe:
            procs: list[subprocess.Popen[str]] = []
            if clients:
                procs.append(start_receiver(pipe.sdp_paths["h264"], 10**9))
                endpoint = pipe.frame_socket_endpoint
                assert endpoint is not None
                procs.append(
                    subprocess.Popen(
                        [sys.executable, "-c", FRAME_CLIENT, endpoint],
                        stdout=subprocess.PIPE,
                        text=True,
                        cwd=REPO,
                    )
                )
                time.sleep(1.0)
            results: dict[str, Any] = {}
            reader: threading.Thread | None = None
            if clients:
                reader = threading.Thread(
                    target=lambda: results.update(rx=read_receiver(procs[0], walls, skip_s=1.0)), daemon=True
                )
                reader.start()
            sched = FrameScheduler(render, pipe.submit, fps)
            ticker = Ticker(250.0)
            ticker.start()
            busy0, total0 = _cpu_busy()
            cpu0, wall0 = time.process_time(), time.monotonic()
            sched.start()
            time.sleep(duration_s)
            sched.stop()
            cpu1, wall1 = time.process_time(), time.monotonic()
            busy1, total1 = _cpu_busy()
            ticker.stop()
        # pipeline stopped: the frame socket closes, the clients time out (5 s) and report
        for p in procs[1:]:
            text, _ = p.communicate(timeout=30)
            results["frame_client"] = json.loads(text.strip().splitlines()[-1])
        if reader is not None:
            reader.join(30)
    ss, ps = sched.stats(), pipe.stats()
    ticks_due = ss["ticks"] + ss["late_skipped"]
    lost = ps["dropped"] + ss["late_skipped"] + ss["render_errors"]
    ncpu = os.cpu_count() or 1
    out = {
        "size": f"{width}x{height}",
        "duration_s": duration_s,
        "ticks_due": ticks_due,
        "rendered": ss["rendered"],
        "late_skipped": ss["late_skipped"],
        "pipeline_dropped": ps["dropped"],
        "dropped_pct": 100.0 * lost / max(1, ticks_due),
        "render_ms_median": ss["render_ms_median"],
        "render_ms_p95": ss["render_ms_p95"],
        "outputs": ps["outputs"],
        "sender_cpu_pct_of_one_core": 100.0 * (cpu1 - cpu0) / (wall1 - wall0),
        "machine_busy_pct": 100.0 * (busy1 - busy0) / max(1e-9, total1 - total0),
        "cores": ncpu,
        "x264_threads": x264_threads,
        "physics_like_250hz_thread": ticker.stats(),
        "baseline_without_video": {
            "machine_busy_pct": 100.0 * (b_busy1 - b_busy0) / max(1e-9, b_total1 - b_total0),
            "physics_like_250hz_thread": baseline.stats(),
        },
    }
    if "rx" in results:
        lat = results["rx"]["lat_ms"]
        out["h264_client"] = {
            "frames": len(lat),
            "lat_median_ms": statistics.median(lat) if lat else None,
            "lat_p95_ms": pct(lat, 95),
            "cpu_pct_of_one_core": 100.0 * results["rx"].get("cpu_s", float("nan")) / (wall1 - wall0 + 6),
            "decode_errors": results["rx"].get("errors"),
        }
    if "frame_client" in results:
        fc = results["frame_client"]
        out["frame_client"] = fc
    print(json.dumps(out, indent=1, default=float))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=60.0, help="sustained run length (s), 0 to skip")
    ap.add_argument("--latency-seconds", type=float, default=10.0)
    ap.add_argument("--encode-frames", type=int, default=120)
    ap.add_argument("--fps", type=int, default=30)
    ap.add_argument(
        "--x264-threads", type=int, default=0, help="VideoConfig.x264_threads for the sustained run"
    )
    ap.add_argument("--skip-encode", action="store_true")
    ap.add_argument("--skip-latency", action="store_true")
    ap.add_argument(
        "--no-clients", action="store_true", help="sustained run without the two client processes"
    )
    args = ap.parse_args()
    print(
        f"machine: {platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"PyAV {av.__version__} (FFmpeg {av.ffmpeg_version_info}), OpenCV {cv2.__version__}"
    )
    print(f"render source: {Renderer(64, 48, 30).source}")
    report: dict[str, Any] = {}
    if not args.skip_encode:
        print("encode cost per frame (ms):")
        report["encode"] = bench_encode([(640, 480), (1280, 720)], args.encode_frames, args.fps)
    if not args.skip_latency:
        print("glass-to-glass latency, pose sample -> decoded BGR frame in a PyAV client process (loopback):")
        report["latency"] = []
        for w, h in ((640, 480), (1280, 720)):
            report["latency"] += bench_latency(w, h, args.fps, args.latency_seconds)
    if args.duration > 0:
        print(
            f"sustained {args.fps} fps 1280x720 for {args.duration:.0f} s (render + H.264 RTP + frame socket):"
        )
        report["sustained"] = bench_sustained(
            1280, 720, args.fps, args.duration, clients=not args.no_clients, x264_threads=args.x264_threads
        )
    _ = FrameClient  # the clients run in subprocesses; imported to fail early if the package is broken


if __name__ == "__main__":
    main()
