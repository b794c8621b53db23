"""What serving RTSP costs the simulator: physics pace and MAVLink telemetry of `viva-sitl run` with and without RTSP.

    python bench/bench_rtsp.py                      # 3 variants x 1 round x 20 s, 1280x720 30 fps, synthetic field
    python bench/bench_rtsp.py --seconds 60 --rounds 2

Variants, each a fresh `viva-sitl run` (tests/sitl_process.SitlProcess, speed 1, H.264 RTP + frame socket as by
default, camera 1280x720 via a config file):
- `no-rtsp`:   as today;
- `rtsp-idle`: `--rtsp`, nobody connected (the encoder thread only looks at the number of playing sessions);
- `rtsp-4`:    `--rtsp` with four clients: two FFmpeg clients over interleaved TCP and one over UDP (PyAV, demuxing
               every RTP packet without decoding, in one child process, so that decoding does not compete for the
               2 cores), plus one TCP client that plays and never reads (its buffers fill; the server drops its
               frames).
Measured over the same window: the physics pacer's skipped steps (viva-sitl's stop stats), simulation time advanced
per wall second (ATTITUDE.time_boot_ms on a pymavlink GCS peer), ATTITUDE inter-arrival gaps at the peer (median,
p99, max), MAVLink messages lost (sequence numbers), the stream's lost frames, viva-sitl's CPU (utime+stime), and
what the RTSP server counted (frames to clients, frames a stalled client missed).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
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
from sitl_process import MavlinkPeer, SitlProcess, free_tcp_port, free_udp_ports  # noqa: E402

VARIANTS = ("no-rtsp", "rtsp-idle", "rtsp-4")
CONFIG = """
[camera]
width_px = 1280
height_px = 720
"""


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def clients_main(url: str, n_tcp: int, n_udp: int, seconds: float) -> None:
    """Child process: PyAV clients demuxing (not decoding) the RTSP stream for `seconds`; prints their packet counts."""
    import av

    counts: dict[str, int] = {}
    errors: dict[str, str] = {}

    def run(name: str, transport: str) -> None:
        counts[name] = 0
        try:
            with av.open(url, options={"rtsp_transport": transport}, timeout=(10.0, 5.0)) as c:
                t_end = time.monotonic() + seconds
                for _ in c.demux(video=0):
                    counts[name] += 1
                    if time.monotonic() > t_end:
                        break
        except Exception as exc:  # reported in the JSON
            errors[name] = repr(exc)

    threads = [threading.Thread(target=run, args=(f"tcp{i}", "tcp")) for i in range(n_tcp)]
    threads += [threading.Thread(target=run, args=(f"udp{i}", "udp")) for i in range(n_udp)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    print(json.dumps({"packets": counts, "errors": errors}))


def stalled_client(port: int) -> socket.socket:
    """A TCP client that sets up an interleaved session, plays, and never reads again."""
    s = socket.create_connection(("127.0.0.1", port), timeout=5.0)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    url = f"rtsp://127.0.0.1:{port}/vac"
    buf = b""

    def request(text: str) -> dict[str, str]:
        nonlocal buf
        s.sendall(text.encode())
        while b"\r\n\r\n" not in buf:
            buf += s.recv(4096)
        head, _, buf = buf.partition(b"\r\n\r\n")
        lines = head.decode().split("\r\n")
        assert " 200 " in lines[0], lines[0]
        return {k.strip().lower(): v.strip() for k, _, v in (ln.partition(":") for ln in lines[1:])}

    h = request(
        f"SETUP {url}/trackID=0 RTSP/1.0\r\nCSeq: 1\r\nTransport: RTP/AVP/TCP;unicast;interleaved=0-1\r\n\r\n"
    )
    session = h["session"].split(";")[0]
    request(f"PLAY {url} RTSP/1.0\r\nCSeq: 2\r\nSession: {session}\r\n\r\n")
    return s


def run_variant(variant: str, seconds: float, workdir: Path) -> dict[str, Any]:
    cfg = workdir / "bench.toml"
    cfg.write_text(CONFIG)
    rtsp_port = free_tcp_port()
    extra = ["--config", str(cfg), "--no-dashboard"]
    if variant != "no-rtsp":
        extra += ["--rtsp", str(rtsp_port)]
    sitl = SitlProcess(
        workdir=workdir, speed=1.0, video_port=free_udp_ports(1)[0], extra_args=extra, name=variant
    )
    sitl.start()
    assert sitl.proc is not None
    peer = MavlinkPeer(sitl.ports.gcs)
    clients: subprocess.Popen[str] | None = None
    stalled: socket.socket | None = None
    try:
        peer.wait_autopilot()
        if variant == "rtsp-4":
            url = f"rtsp://127.0.0.1:{rtsp_port}/vac"
            cmd = [sys.executable, __file__, "--clients", url, "2", "1", str(seconds + 3.0)]
            clients = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
            stalled = stalled_client(rtsp_port)
            time.sleep(3.0)  # the clients connect and play (not measured)
        c0, t0 = cpu_s(sitl.proc.pid), time.monotonic()
        time.sleep(seconds)
        c1, t1 = cpu_s(sitl.proc.pid), time.monotonic()
        records = [r for r in list(peer.records) if t0 <= r.t_s <= t1 and r.msg.get_type() == "ATTITUDE"]
        lost = peer.lost
    finally:
        peer.close()
        client_out = clients.communicate(timeout=60)[0] if clients is not None else ""
        if stalled is not None:
            stalled.close()
        sitl.stop()
    stats = sitl.stop_stats()
    times = np.array([r.t_s for r in records])
    boot = np.array([r.msg.time_boot_ms for r in records], dtype=np.float64) / 1e3
    gaps_ms = np.diff(times) * 1e3
    row: dict[str, Any] = {
        "variant": variant,
        "skipped_physics_steps": stats.get("skipped_physics_steps"),
        "sim_s_per_wall_s": float((boot[-1] - boot[0]) / (times[-1] - times[0])),
        "attitude_hz": float(len(records) / (t1 - t0)),
        "attitude_gap_ms_median": float(np.median(gaps_ms)),
        "attitude_gap_ms_p99": float(np.percentile(gaps_ms, 99)),
        "attitude_gap_ms_max": float(gaps_ms.max()),
        "mavlink_lost": lost,
        "telemetry_late": stats.get("mavlink", {}).get("telemetry_late"),
        "frames_lost_pct": stats.get("frames_lost_pct"),
        "cpu_cores": (c1 - c0) / (t1 - t0),
    }
    rtsp = stats.get("video", {}).get("rtsp")
    if rtsp:
        row["rtsp"] = {k: rtsp[k] for k in ("sessions_total", "frames_posted", "frames_behind",
                                             "client_frames_dropped", "errors_sent")}  # fmt: skip
    if client_out:
        row["clients"] = json.loads(client_out.strip().splitlines()[-1])
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0, help="measured wall seconds per variant and round")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument(
        "--clients", nargs=4, metavar=("URL", "N_TCP", "N_UDP", "SECONDS"), help=argparse.SUPPRESS
    )
    args = ap.parse_args()
    if args.clients:
        url, n_tcp, n_udp, secs = args.clients
        clients_main(url, int(n_tcp), int(n_udp), float(secs))
        return
    if args.rounds < 1 or not args.seconds >= 5:
        ap.error("--rounds must be >= 1 and --seconds >= 5")
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for v in VARIANTS:
                d = Path(tmp) / f"{v}-{r}"
                d.mkdir()
                row = run_variant(v, args.seconds, d)
                rows.append(row)
                print(json.dumps(row), flush=True)
    print(f"\n{args.rounds} round(s) x {args.seconds:g} s, medians per variant:")
    keys = ("skipped_physics_steps", "sim_s_per_wall_s", "attitude_hz", "attitude_gap_ms_median",
            "attitude_gap_ms_p99", "attitude_gap_ms_max", "mavlink_lost", "frames_lost_pct", "cpu_cores")  # fmt: skip
    print("variant     " + " ".join(f"{k:>22}" for k in keys))
    for v in VARIANTS:
        vr = [row for row in rows if row["variant"] == v]
        vals = [statistics.median(float(row[k] or 0) for row in vr) for k in keys]
        print(f"{v:<11} " + " ".join(f"{x:22.3f}" for x in vals))


if __name__ == "__main__":
    main()
