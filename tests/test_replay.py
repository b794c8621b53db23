"""The trajectory log of a real `viva-sitl run` flight, and `viva-sitl replay` of it (in a real browser).

One flight (take off to 8 m, reposition 15 m north) is recorded once for the module; its trajectory.csv is checked
against the MAVLink telemetry in the same run's .tlog; the replay page is checked against the recorded values and
against a direct render of the recorded pose.
"""

from __future__ import annotations

import asyncio
import base64
import json
import math
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from dashboard_browser import chromium, chromium_paths, screenshot
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2
from sitl_process import MavlinkPeer, SitlProcess, e2e_speed, free_tcp_port, home_of, offset, takeoff

from viva_sitl.camera.projection import footprint_px
from viva_sitl.config import SimConfig
from viva_sitl.dashboard.replay import ReplayError, eav_state_of, load_recording
from viva_sitl.footage import open_footage
from viva_sitl.recording import COLUMNS, read_run_info, read_trajectory
from viva_sitl.sim import Simulator

pytestmark = pytest.mark.e2e
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    work = tmp_path_factory.mktemp("recorded")
    sitl = SitlProcess(workdir=work, speed=e2e_speed(), extra_args=["--no-dashboard"], name="rec")
    with sitl, MavlinkPeer(sitl.ports.gcs) as peer:
        peer.wait_autopilot()
        lat0, lon0 = home_of(peer)
        takeoff(peer, 8.0)
        lat, lon = offset(lat0, lon0, 15.0, 0.0)
        t0 = time.monotonic()
        peer.send(peer.mav.command_int_encode(
            1, 1, mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavlink2.MAV_CMD_DO_REPOSITION, 0, 0,
            -1.0, float(mavlink2.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE), 0.0, math.nan, lat, lon, 8.0,
        ))  # fmt: skip
        ack = peer.wait("COMMAND_ACK", lambda m: m.command == mavlink2.MAV_CMD_DO_REPOSITION, 5, since_s=t0)
        assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
        peer.wait("LOCAL_POSITION_NED", lambda m: m.x > 14.0, 60, what="15 m north")
        assert sitl.stop() == 0, sitl.logs()
    return work / "rec-run"


@pytest.mark.slow  # shares a recorded viva-sitl flight
def test_trajectory_log_is_the_flight_mavlink_reported(run_dir: Path) -> None:
    info = read_run_info(run_dir)
    assert info is not None and info["version"] == 1 and info["footage"] == "synthetic"
    assert info["trajectory"] == {"file": "trajectory.csv", "format_version": 1, "rate_hz": 30.0}
    cfg = SimConfig.from_dict(info["config"])
    assert cfg.footage == "synthetic" and cfg.speed == e2e_speed()
    assert (run_dir / "trajectory.csv").read_text().splitlines()[0].split(",") == list(COLUMNS)

    rows = read_trajectory(run_dir / "trajectory.csv")
    t = np.array([r.sim_time_s for r in rows])
    gaps = np.diff(t)
    dt = cfg.physics.dt_s
    # a fixed sim-time rate: one row per 1/30 s (the first physics step at or after each grid time)
    assert (
        (gaps > 0).all()
        and abs(float(np.median(gaps)) - 1 / 30) <= dt + 1e-6
        and gaps.max() < 1 / 30 + 2 * dt
    )
    assert len(rows) >= 30 * (t[-1] - t[0]) - 2
    modes = {r.mode for r in rows}
    assert {"AUTO_TAKEOFF", "AUTO_LOITER"} <= modes, modes
    assert rows[0].armed is False and any(r.armed for r in rows)
    assert {"ON_GROUND", "IN_AIR"} <= {r.landed_state for r in rows}
    assert max(-r.pos_ned_m[2] for r in rows) > 7.5 and rows[-1].pos_ned_m[0] > 14.0
    with open_footage("synthetic") as src:
        assert all(r.footage_frame == src.frame_index_at(r.sim_time_s) for r in rows[::17])
    assert rows[-1].battery_pct < rows[0].battery_pct <= 100.0

    # the same flight as the .tlog's LOCAL_POSITION_NED (sim time = time_boot_ms)
    mlog = mavutil.mavlink_connection(str(run_dir / "telemetry.tlog"), dialect="common")
    checked = 0
    while (m := mlog.recv_match(type="LOCAL_POSITION_NED")) is not None:
        if m.get_srcComponent() != 1:
            continue
        tm = m.time_boot_ms / 1000.0
        k = int(np.argmin(np.abs(t - tm)))
        r = rows[k]
        lag = abs(r.sim_time_s - tm)
        assert lag <= 1 / 60 + dt, (tm, r.sim_time_s)
        speed = math.hypot(m.vx, m.vy, m.vz)
        err = math.dist(r.pos_ned_m, (m.x, m.y, m.z))
        assert err <= speed * lag + 0.02, f"t {tm}: trajectory {r.pos_ned_m} vs MAVLink {(m.x, m.y, m.z)}"
        checked += 1
    mlog.close()
    assert checked > 100


@pytest.mark.slow  # shares a recorded viva-sitl flight
def test_replay_falls_back_to_the_tlog(run_dir: Path, tmp_path: Path) -> None:
    only_tlog = tmp_path / "tlog-only"
    only_tlog.mkdir()
    shutil.copy(run_dir / "telemetry.tlog", only_tlog)
    rec = load_recording(only_tlog)
    assert rec.source == "tlog" and rec.config.footage == "synthetic"
    traj = load_recording(run_dir)
    assert traj.source == "trajectory"
    for s in rec.samples[:: max(1, len(rec.samples) // 50)]:
        ref = traj.at(s.sim_time_s)
        lag = s.sim_time_s - ref.sim_time_s
        assert math.dist(s.pos_ned_m, ref.pos_ned_m) <= math.hypot(*ref.vel_ned_m_s) * lag + 0.05
    assert {"AUTO_TAKEOFF", "AUTO_LOITER"} <= {s.mode for s in rec.samples}
    first = rec.samples[0]  # before the first HEARTBEAT / SYS_STATUS: the first values the log has
    assert first.mode == "AUTO_LOITER" and first.landed_state == "ON_GROUND" and first.battery_pct == 100.0


def test_replay_opens_an_inprocess_trial_folder_on_its_footage_clock(tmp_path: Path) -> None:
    """`trials run` of an in-process pilot leaves trial_trajectory.csv and scenario.json (no run.json, no
    trajectory.csv): the folder replays from them, over the scenario's footage, with the footage frames the trial saw
    (its footage clock started at the scenario's footage_time_s)."""
    from viva_sitl.dashboard.replay import ReplayApp
    from viva_sitl.evaluation.campaign import run_campaign
    from viva_sitl.evaluation.spec import spec_from_dict

    spec = spec_from_dict(
        {"trials": {"name": "replay", "n": 1, "seed": 2, "timeout_s": 30.0},
         "scenario": {"footage": "synthetic", "start": "air", "north_m": [-20.0, 20.0], "east_m": [-20.0, 20.0],
                      "altitude_m": 8.0, "footage_time_s": [10.0, 20.0], "land_at_s": 0.5}},
        "replay",
    )  # fmt: skip
    camp = run_campaign(spec, "descend", tmp_path, jobs=1, progress=False)
    (row,) = camp.ordered_rows()
    assert row["end"] == "landed", row
    tdir = tmp_path / "trials" / "0000"
    assert not (tdir / "trajectory.csv").exists() and not (tdir / "run.json").exists()
    rec = load_recording(tdir)
    sc = camp.scenarios[0]
    assert rec.source == "trial" and rec.footage_offset_s == sc.footage_time_s >= 10.0
    assert rec.config.footage == "synthetic" and rec.config.seed == sc.seed
    first, last = rec.samples[0], rec.samples[-1]
    assert -first.pos_ned_m[2] == pytest.approx(8.0, abs=0.05) and first.armed
    assert last.landed_state == "ON_GROUND" and not last.armed
    assert (first.pos_ned_m[0], first.pos_ned_m[1]) == pytest.approx((sc.north_m, sc.east_m), abs=0.01)
    app = ReplayApp(rec)
    try:
        mid = rec.at((rec.start_s + rec.end_s) / 2)
        frame = app.render_at(mid)
        with open_footage("synthetic") as src:
            assert (
                frame.meta.footage_frame_index == src.frame_index_at(mid.sim_time_s + sc.footage_time_s) > 0
            )
    finally:
        app.close()
    # and from the command line: the folder serves (it was refused before: no trajectory.csv)
    r = subprocess.run([sys.executable, "-m", "viva_sitl", "replay", str(tdir), "--duration", "1",
                        "--dashboard-port", str(free_tcp_port())], capture_output=True, text=True, timeout=120,
                       cwd=REPO)  # fmt: skip
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stdout + r.stderr


def test_bad_run_directories_are_one_line_errors(tmp_path: Path) -> None:
    with pytest.raises(ReplayError, match="no such run directory"):
        load_recording(tmp_path / "missing")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ReplayError, match="none of trajectory.csv, telemetry.tlog, trial_trajectory.csv"):
        load_recording(empty)
    (empty / "trajectory.csv").write_text("not,a,trajectory\n1,2,3\n")
    out = subprocess.run([sys.executable, "-m", "viva_sitl", "replay", str(empty)], capture_output=True,
                         text=True, timeout=60, cwd=REPO)  # fmt: skip
    assert out.returncode == 2 and out.stderr.strip().count("\n") == 0, out.stderr
    assert "not a trajectory.csv" in out.stderr


# --- the replay page ------------------------------------------------------------------------------------------
class ReplayProcess:
    def __init__(self, run_dir: Path) -> None:
        cmd = [
            sys.executable,
            "-m",
            "viva_sitl",
            "replay",
            str(run_dir),
            "--dashboard-port",
            str(free_tcp_port()),
        ]
        self.proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO
        )
        self.lines: list[str] = []
        self.url = ""
        ready = threading.Event()

        def read() -> None:
            assert self.proc.stdout is not None
            for line in self.proc.stdout:
                self.lines.append(line.rstrip())
                if line.startswith("viva-sitl replay ready") and "| dashboard " in line:
                    self.url = line.rsplit("| dashboard ", 1)[1].strip()
                    ready.set()

        threading.Thread(target=read, daemon=True).start()
        if not ready.wait(60):
            self.stop()
            raise AssertionError("replay never ready:\n" + "\n".join(self.lines))

    def stop(self) -> int:
        self.proc.terminate()
        try:
            return self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait(10)


@pytest.fixture
def replay(run_dir: Path) -> Iterator[ReplayProcess]:
    rp = ReplayProcess(run_dir)
    yield rp
    assert rp.stop() == 0, "\n".join(rp.lines)


def _wait(cond: Any, timeout_s: float, what: str) -> Any:
    deadline = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < deadline:
        last = cond()
        if last:
            return last
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what} (last {last!r})")


@pytest.mark.slow  # a replay process of a recorded flight
def test_flying_messages_are_refused_in_replay(replay: ReplayProcess) -> None:
    import aiohttp

    async def talk() -> list[dict[str, Any]]:
        async with aiohttp.ClientSession() as s, s.ws_connect(replay.url + "ws") as ws:
            for msg in ({"t": "cmd", "cmd": "arm", "id": 1}, {"t": "take_control"},
                        {"t": "sticks", "x": 0, "y": 0, "z": 0.5, "r": 0},
                        {"t": "replay", "action": "seek", "time_s": "soon"}):  # fmt: skip
                await ws.send_str(json.dumps(msg))
            out: list[dict[str, Any]] = []
            while len([m for m in out if m.get("t") == "error"]) < 4:
                out.append(json.loads((await ws.receive(timeout=10)).data))
            return out

    replies = [m for m in asyncio.run(talk()) if m.get("t") == "error"]
    assert [("flying is disabled" in m["reason"]) for m in replies] == [True, True, True, False]
    assert "finite number" in replies[3]["reason"]


def _canvas_image(driver: Any, element_id: str) -> np.ndarray:  # type: ignore[type-arg]
    url = driver.execute_script(f"return document.getElementById('{element_id}').toDataURL('image/png');")
    data = base64.b64decode(url.split(",", 1)[1])
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:  # type: ignore[type-arg]
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 99.0 if mse == 0 else 10 * math.log10(255.0**2 / mse)


@pytest.mark.slow  # a replay process + Chromium
@pytest.mark.skipif(
    chromium_paths() is None, reason="Chromium absent: apt-get install chromium chromium-driver"
)
def test_replay_page_slider_shows_the_recorded_moment(replay: ReplayProcess, run_dir: Path) -> None:
    pytest.importorskip("selenium", reason="selenium is in the test extra")
    rec = load_recording(run_dir)
    ground = rec.samples[0]
    moving = next(s for s in rec.samples if s.mode == "AUTO_LOITER" and s.pos_ned_m[0] > 7.0)
    sim = Simulator(rec.config)
    shots = run_dir / "screenshots"

    def attr(driver: Any, eid: str, name: str) -> str | None:
        return driver.execute_script(
            "const e = document.getElementById(arguments[0]); return e ? e.getAttribute(arguments[1]) : null;",
            eid, name,
        )  # fmt: skip

    def seek(driver: Any, t_s: float) -> None:
        driver.execute_script(
            "const s = document.getElementById('replay-slider'); s.value = String(arguments[0]);"
            "s.dispatchEvent(new Event('input')); s.dispatchEvent(new Event('change'));",
            t_s,
        )

    def footprint(driver: Any) -> list[tuple[float, ...]]:
        raw = attr(driver, "overview", "data-footprint") or ""
        return [tuple(float(v) for v in p.split()) for p in raw.split(";") if p]

    with chromium() as driver:
        driver.get(replay.url)
        _wait(lambda: attr(driver, "replay", "hidden") is None, 20, "the replay bar")
        assert attr(driver, "fly", "hidden") is not None, "flying controls are shown in replay"
        for sample in (moving, ground, moving):
            seek(driver, sample.sim_time_s)
            _wait(lambda s=sample: abs(float(attr(driver, "hud-time", "data-value") or -1) - s.sim_time_s) < 1e-3,
                  10, f"the HUD at t {sample.sim_time_s}")  # fmt: skip
            # the HUD shows the recorded values of that moment
            assert abs(float(attr(driver, "hud-alt", "data-value") or "nan") + sample.pos_ned_m[2]) < 0.002
            assert attr(driver, "hud-mode", "data-value") == sample.mode
            assert attr(driver, "hud-armed", "data-value") == str(sample.armed).lower()
            assert abs(float(attr(driver, "hud-bat", "data-value") or "nan") - sample.battery_pct) < 0.06
            # the footprint is the recorded pose's
            want = footprint_px(sim.footage.geometry, sim.camera, sample.pos_ned_m, sample.att_rpy_rad)
            assert want is not None
            got = _wait(lambda: footprint(driver), 5, "a footprint")
            assert max(math.dist(a, b) for a, b in zip(got, want, strict=True)) < 0.2, (got, want)
            # the VAC view is a re-render of that pose: as a direct render of it, not as one of the other moment
            _wait(lambda s=sample: abs(float(attr(driver, "vac", "data-sim-time") or -1) - s.sim_time_s) < 1e-6,
                  15, "the VAC frame of that moment")  # fmt: skip
            shown = _canvas_image(driver, "vac")
            direct = sim.render(eav_state_of(sample, sim.params.dt_s)).image_bgr
            other = ground if sample is moving else moving
            elsewhere = sim.render(eav_state_of(other, sim.params.dt_s)).image_bgr
            assert shown.shape == direct.shape
            same, diff = _psnr(shown, direct), _psnr(shown, elsewhere)
            assert same > 30.0 and same > diff + 6.0, (same, diff)
        fp_moving = footprint(driver)
        screenshot(driver, shots, "replay-01-moving")

        # play: the time advances by itself, and the footprint with it
        seek(driver, rec.start_s)
        _wait(
            lambda: float(attr(driver, "hud-time", "data-value") or -1) < rec.start_s + 0.01, 10, "the start"
        )
        # the footprint is drawn after the HUD: wait for the start pose's own (reading it at once raced in CI)
        start = rec.samples[0]
        want_start = footprint_px(sim.footage.geometry, sim.camera, start.pos_ned_m, start.att_rpy_rad)
        assert want_start is not None
        fp_start = _wait(
            lambda: (fp := footprint(driver)) and max(math.dist(a, b) for a, b in zip(fp, want_start, strict=True)) < 0.2
            and fp, 10, "the start's footprint",
        )  # fmt: skip
        assert max(math.dist(a, b) for a, b in zip(fp_start, fp_moving, strict=True)) > 1.0
        driver.find_element("id", "btn-play").click()
        _wait(lambda: attr(driver, "btn-play", "data-playing") == "true", 5, "playing")
        t_before = float(attr(driver, "hud-time", "data-value") or 0)
        _wait(
            lambda: float(attr(driver, "hud-time", "data-value") or 0) > t_before + 0.5, 10, "time advancing"
        )
        driver.find_element("id", "btn-play").click()
        _wait(lambda: attr(driver, "btn-play", "data-playing") == "false", 5, "paused")
        screenshot(driver, shots, "replay-02-paused")
    sim.close()


def test_recorder_rows_are_on_the_sim_time_grid(tmp_path: Path) -> None:
    from viva_sitl.recording import Sample, TrajectoryRecorder

    rec = TrajectoryRecorder(tmp_path / "t.csv", rate_hz=30.0)
    dt = 0.004
    for k in range(0, 1000):  # 4 s of physics steps
        t = k * dt
        if rec.due(t):
            last_t = t
            rec.add(Sample(t, (t, 0, -1), (1, 0, 0), (0, 0, 0.1), "POSCTL", True, "IN_AIR", k, 99.0, 16.0))
        if k % 250 == 0:
            rec.flush()
    # the same sim time again (as the app's final sample when no step followed the last row): ignored
    rec.add(Sample(last_t, (0, 0, 0), (0, 0, 0), (0, 0, 0), "X", False, "ON_GROUND", 0, 0.0, 0.0))
    rec.close()
    rows = read_trajectory(tmp_path / "t.csv")
    t = np.array([r.sim_time_s for r in rows])
    assert len(rows) == rec.rows_written == 120  # 0, 1/30, ... 3.967: one per grid time; the repeat ignored
    assert np.all(np.diff(t) > 0) and np.all(np.abs(t - np.ceil(np.arange(120) / 30 / dt - 1e-9) * dt) < 1e-9)
    assert rows[5].mode == "POSCTL" and rows[5].armed and abs(rows[5].pos_ned_m[0] - t[5]) < 1e-4


def test_run_info_config_reads_back_equal_with_every_section(tmp_path: Path) -> None:
    """run.json's config is what replay rebuilds the run from: every table (perception.sr included) reads back to
    an equal config (a `[perception]` table written under [sim] made replay refuse every recorded run)."""
    from viva_sitl.config import SimConfig
    from viva_sitl.recording import config_to_dict

    for cfg in (
        SimConfig(),
        SimConfig.from_dict({"perception": {"sr": {"method": "fsrcnn", "model_path": "/x/FSRCNN_x2.pb"}}}),
    ):
        table = json.loads(json.dumps(config_to_dict(cfg)))
        assert "perception" not in table["sim"]
        assert SimConfig.from_dict(table, "run.json") == cfg
