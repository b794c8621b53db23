"""Dashboard cost: CPU share of `viva-sitl run` with one page open vs none, and the VAC panel's latency.

One `viva-sitl run` (synthetic footage, 640x480 VAC at 30 fps, H.264 RTP out, speed 1) runs for the whole bench; the
phases alternate (none, page, none, page, ...) so the reference (no page) is measured in the same run, under the same
machine load:
  none     nobody has the dashboard open (the server idles; the VAC output skips encoding)
  page     one headless Chromium page (selenium) shows the dashboard: VAC panel, overview, HUD
  ws       (optional, --ws) a Python client on /ws and /ws/vac only: the server's share without a browser

CPU: utime + stime of the viva-sitl process (/proc/PID/stat, all its threads) over each phase, in % of one core;
Chromium's own CPU is reported beside it (its whole process tree).
VAC latency (page phases): every 100 ms the page's `data-latency-ms` (the browser's Date.now() when the frame was
drawn minus the frame's pose sampling time FrameMeta.wall_time_s: render + JPEG + WebSocket + JS decode + draw), and
the sim-time gap: the page's shown frame sim time vs the sim time the HUD reports at the same moment, in frame periods.
Physics health from the run's stop line: skipped physics steps, render ticks skipped, telemetry late.

    python bench/bench_dashboard.py --phase-s 15 --rounds 3 [--ws]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from dashboard_browser import chromium, chromium_paths, dashboard_url  # noqa: E402
from sitl_process import SitlProcess, free_tcp_port, free_udp_ports  # noqa: E402

TICK_S = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK_S


def tree_cpu_s(root: int) -> float:
    """CPU seconds of `root` and its descendants (Chromium is a process tree)."""
    children: dict[int, list[int]] = {}
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            ppid = int((p / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(p.name))
    total, stack = 0.0, [root]
    while stack:
        pid = stack.pop()
        with contextlib.suppress(OSError, IndexError, ValueError):  # the process ended meanwhile
            total += cpu_s(pid)
        stack.extend(children.get(pid, []))
    return total


def health(url: str) -> tuple[int, float]:
    """(render ticks skipped so far, sim time) from /api/state (the render counter refreshes once a second)."""
    import urllib.request

    with urllib.request.urlopen(url + "api/state", timeout=5) as r:
        st = json.loads(r.read())
    return int(st["dropped"]["render_late"]), float(st["sim_time_s"])


def loadavg() -> float:
    return float(Path("/proc/loadavg").read_text().split()[0])


def pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(q / 100 * len(s)))] if s else float("nan")


def phase_none(pid: int, seconds: float) -> dict[str, Any]:
    c0, t0, l0 = cpu_s(pid), time.monotonic(), loadavg()
    time.sleep(seconds)  # a measurement window, not a wait for a condition
    return {"cpu_pct": 100 * (cpu_s(pid) - c0) / (time.monotonic() - t0), "load": (l0 + loadavg()) / 2}


def phase_page(pid: int, url: str, seconds: float) -> dict[str, Any]:
    with chromium() as driver:
        driver.get(url)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            if (
                int(driver.execute_script("return document.getElementById('vac').dataset.frameCounter") or -1)
                > 0
            ):
                break
            time.sleep(0.1)
        driver_pid = driver.service.process.pid
        c0, b0, t0, l0 = cpu_s(pid), tree_cpu_s(driver_pid), time.monotonic(), loadavg()
        lat: list[float] = []
        gap: list[float] = []
        while time.monotonic() - t0 < seconds:
            got = driver.execute_script(
                "const v = document.getElementById('vac').dataset, h = document.getElementById('hud-time').dataset;"
                "return [v.latencyMs, v.simTime, h.value];"
            )
            if got and got[0] is not None:
                lat.append(float(got[0]))
                if got[1] is not None and got[2] is not None:
                    gap.append(float(got[2]) - float(got[1]))
            time.sleep(0.1)
        dt = time.monotonic() - t0
        return {
            "cpu_pct": 100 * (cpu_s(pid) - c0) / dt,
            "browser_cpu_pct": 100 * (tree_cpu_s(driver_pid) - b0) / dt,
            "load": (l0 + loadavg()) / 2,
            "latency_ms": lat,
            "sim_gap_s": gap,
        }


def phase_ws(pid: int, url: str, seconds: float) -> dict[str, Any]:
    import aiohttp

    from viva_sitl.dashboard.vac import unpack_vac_message

    async def run() -> dict[str, Any]:
        lat: list[float] = []
        async with (
            aiohttp.ClientSession() as s,
            s.ws_connect(url + "ws") as ws,
            s.ws_connect(url + "ws/vac") as vac,
        ):
            c0, t0, l0 = cpu_s(pid), time.monotonic(), loadavg()

            async def drain_json() -> None:
                async for _ in ws:
                    pass

            task = asyncio.create_task(drain_json())
            while time.monotonic() - t0 < seconds:
                msg = await vac.receive(timeout=5)
                head, _ = unpack_vac_message(msg.data)
                lat.append((time.time() - float(head["wall_time_s"])) * 1e3)  # type: ignore[arg-type]
            dt = time.monotonic() - t0
            task.cancel()
            return {"cpu_pct": 100 * (cpu_s(pid) - c0) / dt, "load": (l0 + loadavg()) / 2, "latency_ms": lat}

    return asyncio.run(run())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--phase-s", type=float, default=15.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--ws", action="store_true", help="also a Python WebSocket client phase per round")
    ap.add_argument("--json", help="write every figure here")
    args = ap.parse_args()
    if chromium_paths() is None:
        print("bench_dashboard: Chromium absent (apt-get install chromium chromium-driver)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        sitl = SitlProcess(
            workdir=Path(tmp), video_port=free_udp_ports(1)[0], speed=1.0,
            extra_args=["--dashboard-port", str(free_tcp_port())],
        )  # fmt: skip
        with sitl:
            assert sitl.proc is not None
            pid, url = sitl.proc.pid, dashboard_url(sitl.ready_line)
            time.sleep(2.0)  # let start-up work (first renders, caches) finish before measuring
            phases: dict[str, list[dict[str, Any]]] = {"none": [], "page": [], "ws": []}
            for r in range(args.rounds):
                for name in ("none", "page", "ws"):
                    if name == "ws" and not args.ws:
                        continue
                    late0, sim0 = health(url)
                    w0 = time.monotonic()
                    if name == "none":
                        res = phase_none(pid, args.phase_s)
                    elif name == "page":
                        res = phase_page(pid, url, args.phase_s)
                    else:
                        res = phase_ws(pid, url, args.phase_s)
                    late1, sim1 = health(url)
                    res["render_late"] = late1 - late0
                    res["sim_per_wall"] = (sim1 - sim0) / (time.monotonic() - w0)
                    phases[name].append(res)
                print(f"round {r + 1}: " + ", ".join(
                    f"{k} {v[-1]['cpu_pct']:.1f} % (load {v[-1]['load']:.1f})" for k, v in phases.items() if v
                ), flush=True)  # fmt: skip
        stop = sitl.stop_stats()
    fps = 30.0
    print(
        f"\nmachine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    )
    for k, v in phases.items():
        if not v:
            continue
        cpus = [p["cpu_pct"] for p in v]
        line = f"{k:5s} viva-sitl CPU % of one core: median {statistics.median(cpus):.1f} (each {', '.join(f'{c:.1f}' for c in cpus)})"
        if k == "page":
            line += f"; Chromium {statistics.median(p['browser_cpu_pct'] for p in v):.1f} %"
        line += f"; render ticks skipped {sum(p['render_late'] for p in v)}"
        line += f"; sim/wall {statistics.median(p['sim_per_wall'] for p in v):.3f}"
        print(line)
        lat = [x for p in v for x in p.get("latency_ms", [])]
        if lat:
            print(f"      VAC latency ms (pose sampled -> shown): median {statistics.median(lat):.1f}, p95 {pct(lat, 95):.1f},"
                  f" max {max(lat):.1f} = {statistics.median(lat) * fps / 1000:.2f} / {pct(lat, 95) * fps / 1000:.2f}"
                  f" frame periods (median / p95), n={len(lat)}")  # fmt: skip
        gap = [x for p in v for x in p.get("sim_gap_s", [])]
        if gap:
            print(f"      HUD sim time - shown frame sim time: median {statistics.median(gap) * fps:.2f},"
                  f" p95 {pct(gap, 95) * fps:.2f} frame periods")  # fmt: skip
    none_med = statistics.median(p["cpu_pct"] for p in phases["none"])
    page_med = statistics.median(p["cpu_pct"] for p in phases["page"])
    print(
        f"one page open costs viva-sitl {page_med - none_med:+.1f} % of a core ({page_med / none_med:.2f}x the no-page run)"
    )
    print("physics / render health over the whole run:", json.dumps({
        "skipped_physics_steps": stop.get("skipped_physics_steps"),
        "render_late_skipped": stop.get("render", {}).get("late_skipped"),
        "render_ticks": stop.get("render", {}).get("ticks"),
        "telemetry_late": stop.get("mavlink", {}).get("telemetry_late"),
        "dashboard": stop.get("dashboard"),
    }))  # fmt: skip
    if args.json:
        Path(args.json).write_text(json.dumps({"phases": phases, "stop": stop}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
