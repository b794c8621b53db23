"""Benchmark of the MAVLink endpoint: telemetry rate accuracy and jitter, CPU share while streaming, and how many
offboard setpoints per second it handles without backlog.

    python bench/bench_mavlink.py [--quick]

The vehicle runs as a subprocess (`python -m viva_sitl.selftest`: real Autopilot + EAV + MavlinkEndpoint,
no video) on free ports; this script is the client (pymavlink codec over a UDP socket on 127.0.0.1).

1. Telemetry: every message type received for T seconds on the API link (PX4 "onboard" profile); rate vs nominal,
   inter-arrival jitter (std and p99 of |dt - 1/f|).
2. CPU: process CPU time / wall time of the vehicle process, physics-only (`--no-endpoint`) vs physics + endpoint
   streaming to one client; the difference is the endpoint's share of one core.
3. Setpoints: SET_POSITION_TARGET_LOCAL_NED (MAVSDK's mask 2552, one per datagram) blasted at increasing rates for a
   few seconds; handled = the endpoint's `setpoints_handled` counter delta; latency = round trip of PINGs interleaved
   every 20 ms (they wait in the same socket queue as the setpoints, so backlog shows as RTT).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pymavlink.dialects.v20 import common as M

ROOT = Path(__file__).resolve().parents[1]

NOMINAL_HZ = {
    "ATTITUDE": 100.0,
    "ATTITUDE_QUATERNION": 50.0,
    "GLOBAL_POSITION_INT": 50.0,
    "LOCAL_POSITION_NED": 30.0,
    "ALTITUDE": 10.0,
    "GPS_RAW_INT": 10.0,
    "EXTENDED_SYS_STATE": 5.0,
    "SYS_STATUS": 5.0,
    "VFR_HUD": 4.0,
    "HEARTBEAT": 1.0,
    "BATTERY_STATUS": 1.0,
    "MISSION_CURRENT": 1.0,
    "SYSTEM_TIME": 1.0,
    "HOME_POSITION": 0.5,
}


class Vehicle:
    """The selftest vehicle as a subprocess; its stats file is rewritten twice a second."""

    def __init__(self, client_port: int, no_endpoint: bool = False) -> None:
        self.dir = tempfile.TemporaryDirectory(prefix="bench_mavlink_")
        self.stats_path = Path(self.dir.name) / "stats.json"
        cmd = [
            sys.executable, "-m", "viva_sitl.selftest", "--api-remote-port", str(client_port),
            "--gcs-remote-port", "0", "--api-local-port", "0", "--gcs-local-port", "0",
            "--stats-file", str(self.stats_path),
        ]  # fmt: skip
        if no_endpoint:
            cmd.append("--no-endpoint")
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, cwd=ROOT, env=env)
        assert self.proc.stdout is not None
        ready = json.loads(self.proc.stdout.readline())
        self.api = tuple(ready["api"]) if ready["api"] else None

    def stats(self) -> dict[str, float]:
        for _ in range(50):
            try:
                return json.loads(self.stats_path.read_text())  # type: ignore[no-any-return]
            except (FileNotFoundError, json.JSONDecodeError):
                time.sleep(0.05)
        raise RuntimeError("no stats from the vehicle process")

    def fresh_stats(self) -> dict[str, float]:
        """Stats written after this call (waits for the next rewrite)."""
        t0 = self.stats()["wall_s"]
        while True:
            s = self.stats()
            if s["wall_s"] > t0:
                return s
            time.sleep(0.05)

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.dir.cleanup()


def make_socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 * 1024 * 1024)
    s.bind(("127.0.0.1", 0))
    return s


def telemetry(seconds: float) -> tuple[list[tuple[str, float, float, float, float]], dict[str, float], float]:
    sock = make_socket()
    veh = Vehicle(sock.getsockname()[1])
    parser = M.MAVLink(None)
    parser.robust_parsing = True
    arrivals: dict[str, list[float]] = {}
    try:
        time.sleep(1.0)  # let the streams settle
        s0 = veh.fresh_stats()
        while True:  # flush what queued up meanwhile: stale datagrams would be timestamped late, in a burst
            sock.settimeout(0.0)
            try:
                sock.recvfrom(65535)
            except BlockingIOError:
                break
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            sock.settimeout(max(0.001, end - time.monotonic()))
            try:
                data, _ = sock.recvfrom(65535)
            except TimeoutError:
                break
            now = time.monotonic()
            for msg in parser.parse_buffer(data) or []:
                arrivals.setdefault(msg.get_type(), []).append(now)
        s1 = veh.fresh_stats()
    finally:
        veh.close()
        sock.close()
    cpu = (s1["cpu_s"] - s0["cpu_s"]) / (s1["wall_s"] - s0["wall_s"])
    rows = []
    for name, nominal in NOMINAL_HZ.items():
        ts = arrivals.get(name, [])
        rate = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 1 else 0.0
        dts = [b - a for a, b in zip(ts, ts[1:], strict=False)]
        dev = sorted(abs(d - 1.0 / nominal) * 1000.0 for d in dts)
        std_ms = statistics.pstdev(dts) * 1000.0 if len(dts) > 1 else math.nan
        p99_ms = dev[min(len(dev) - 1, int(0.99 * len(dev)))] if dev else math.nan
        rows.append((name, nominal, rate, std_ms, p99_ms))
    tx_rate = (s1["tx_messages"] - s0["tx_messages"]) / (s1["wall_s"] - s0["wall_s"])
    return rows, {"cpu_share": cpu, "tx_msgs_per_s": tx_rate}, cpu


def cpu_physics_only(seconds: float) -> float:
    veh = Vehicle(0, no_endpoint=True)
    try:
        time.sleep(1.0)
        s0 = veh.fresh_stats()
        time.sleep(seconds)
        s1 = veh.fresh_stats()
    finally:
        veh.close()
    return (s1["cpu_s"] - s0["cpu_s"]) / (s1["wall_s"] - s0["wall_s"])


def setpoint_blast(
    rates: list[int], seconds: float
) -> list[tuple[int, float, float, float, float, float, int]]:
    sock = make_socket()
    veh = Vehicle(sock.getsockname()[1])
    assert veh.api is not None
    mav = M.MAVLink(None, 255, 190)
    setpoint = bytes(
        mav.set_position_target_local_ned_encode(
            0, 1, 1, 1, 2552, 1.0, 2.0, -3.0, 0, 0, 0, 0, 0, 0, 0.0, 0
        ).pack(mav)
    )
    parser = M.MAVLink(None)
    parser.robust_parsing = True
    rows = []
    try:
        time.sleep(1.0)
        for rate in rates:
            s0 = veh.fresh_stats()
            sent = 0
            pings: dict[int, float] = {}
            rtts: list[float] = []
            t0 = time.monotonic()
            next_ping = t0
            ping_seq = 0
            sock.setblocking(False)
            while True:
                now = time.monotonic()
                elapsed = now - t0
                if elapsed >= seconds:
                    break
                due = int(elapsed * rate) + 1
                while sent < due:
                    sock.sendto(setpoint, veh.api)
                    sent += 1
                if now >= next_ping:
                    ping_seq += 1
                    pings[ping_seq] = now
                    mav.seq = ping_seq % 256
                    sock.sendto(bytes(mav.ping_encode(ping_seq, ping_seq, 0, 0).pack(mav)), veh.api)
                    next_ping += 0.02
                try:
                    while True:
                        data, _ = sock.recvfrom(65535)
                        for msg in parser.parse_buffer(data) or []:
                            if msg.get_type() == "PING" and msg.time_usec in pings:
                                rtts.append(time.monotonic() - pings.pop(msg.time_usec))
                except BlockingIOError:
                    pass
                if sent >= due:
                    time.sleep(min(0.0005, 1.0 / rate))
            wall = time.monotonic() - t0
            drain_end = time.monotonic() + 1.0  # late PING answers = backlog
            sock.settimeout(0.05)
            while time.monotonic() < drain_end and pings:
                try:
                    data, _ = sock.recvfrom(65535)
                except TimeoutError:
                    continue
                for msg in parser.parse_buffer(data) or []:
                    if msg.get_type() == "PING" and msg.time_usec in pings:
                        rtts.append(time.monotonic() - pings.pop(msg.time_usec))
            time.sleep(0.5)
            s1 = veh.fresh_stats()
            handled = s1["setpoints_handled"] - s0["setpoints_handled"]
            rtts.sort()
            med = rtts[len(rtts) // 2] * 1000 if rtts else math.nan
            p95 = rtts[int(0.95 * (len(rtts) - 1))] * 1000 if rtts else math.nan
            cpu = (s1["cpu_s"] - s0["cpu_s"]) / (s1["wall_s"] - s0["wall_s"])
            rows.append((rate, sent / wall, handled / wall, med, p95, cpu, len(pings)))
    finally:
        veh.close()
        sock.close()
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="shorter runs")
    args = ap.parse_args()
    t_tel = 5.0 if args.quick else 15.0
    t_sp = 1.5 if args.quick else 3.0
    print(f"machine: {os.cpu_count()} CPUs, python {sys.version.split()[0]}, load {os.getloadavg()[0]:.2f}")

    rows, info, cpu_stream = telemetry(t_tel)
    print(f"\n== telemetry on the API link over {t_tel:.0f} s (PX4 onboard rates) ==")
    print(f"{'message':<22}{'nominal Hz':>11}{'got Hz':>9}{'ratio':>7}{'std dt ms':>11}{'p99 |dt-T| ms':>15}")
    for name, nominal, rate, std_ms, p99_ms in rows:
        print(f"{name:<22}{nominal:>11.1f}{rate:>9.2f}{rate / nominal:>7.3f}{std_ms:>11.2f}{p99_ms:>15.2f}")
    ratios = [r[2] / r[1] for r in rows]
    print(f"median rate ratio {statistics.median(ratios):.3f}, min {min(ratios):.3f}; "
          f"{info['tx_msgs_per_s']:.0f} messages/s sent")  # fmt: skip

    cpu_base = cpu_physics_only(t_tel / 2)
    print("\n== CPU (share of one core, vehicle process) ==")
    print(f"physics + autopilot only (250 Hz):     {cpu_base * 100:6.1f} %")
    print(f"+ MAVLink endpoint streaming:          {cpu_stream * 100:6.1f} %")
    print(f"endpoint share:                        {(cpu_stream - cpu_base) * 100:6.1f} %")

    rates = (
        [20, 200, 1000, 2000, 5000, 10000] if args.quick else [20, 200, 1000, 2000, 3000, 5000, 8000, 12000]
    )
    print(f"\n== offboard setpoints (SET_POSITION_TARGET_LOCAL_NED, {t_sp:.1f} s per rate) ==")
    print(
        f"{'offered/s':>10}{'sent/s':>9}{'handled/s':>11}{'handled %':>10}{'PING RTT med ms':>17}{'p95 ms':>8}{'cpu %':>7}{'lost pings':>11}"
    )
    blast = setpoint_blast(rates, t_sp)
    best = 0.0
    for rate, sent, handled, med, p95, cpu, lost in blast:
        pct = 100.0 * handled / sent if sent else 0.0
        print(
            f"{rate:>10d}{sent:>9.0f}{handled:>11.0f}{pct:>10.1f}{med:>17.2f}{p95:>8.2f}{cpu * 100:>7.1f}{lost:>11d}"
        )
        if pct >= 99.0 and p95 < 20.0:
            best = max(best, handled)
    print(f"highest rate handled without backlog (>= 99 % handled, PING p95 < 20 ms): {best:.0f} setpoints/s "
          f"({best / 20.0:.0f}x MAVSDK's 20 Hz offboard stream)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
