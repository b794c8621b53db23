"""`viva-sitl trials fly SPEC --trial K` (issue 10): a person flies trial K on the real dashboard page (headless
Chromium), the trial ends and is scored like a program's; `trials compare` pairs it with a program's campaign."""

from __future__ import annotations

import csv
import json
import math
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from dashboard_browser import chromium, chromium_paths, dashboard_url, screenshot
from sitl_process import free_tcp_port, free_udp_ports

from viva_sitl.evaluation.human import HUMAN_READY_PREFIX
from viva_sitl.evaluation.scoring import COLUMNS, SCHEMA

REPO = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.e2e

# An emergency over the synthetic field: air start low (a short landing), no wind (the touchdown is where it held).
SPEC = """
[trials]
name = "fly-test"
n = 4
seed = 0
timeout_s = 60.0
speed = 4.0

[scenario]
footage = ["synthetic"]
start = "air"
north_m = [-30.0, 30.0]
east_m = [-30.0, 30.0]
altitude_m = [5.0, 7.0]
yaw_deg = [0.0, 360.0]
footage_time_s = [0.0, 30.0]
land_at_s = [1.0, 2.0]

[scoring]
criterion = { name = "soft", landed = true, max_touchdown_speed_m_s = 1.5 }
"""
SCENARIO_COLUMNS = ("trial", "seed", "footage", "start", "start_north_m", "start_east_m", "start_altitude_m",
                    "start_yaw_deg", "footage_time_s", "land_at_s", "wind_speed_m_s", "failures")  # fmt: skip


def _cli(*args: str, timeout_s: float = 300.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "viva_sitl", *args], capture_output=True, text=True, cwd=REPO,
                          timeout=timeout_s)  # fmt: skip


def _leftovers(marker: str) -> list[str]:
    ps = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
    return [line for line in ps.splitlines() if marker in line and "ps -eo" not in line]


class Flight:
    """A real `viva-sitl trials fly` process; its output lines are collected by a reader thread."""

    def __init__(self, spec: Path, out: Path, *args: str) -> None:
        api, gcs, video = free_udp_ports(3)
        self.ports = (api, gcs)
        cmd = [sys.executable, "-m", "viva_sitl", "trials", "fly", str(spec), *args, "-o", str(out),
               "--dashboard-port", str(free_tcp_port()), "--api-port", str(api), "--gcs-port", str(gcs), "--video-port", str(video)]  # fmt: skip
        self.proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def ready_line(self, timeout_s: float = 120.0) -> str:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            hit = next((x for x in self.lines if x.startswith(HUMAN_READY_PREFIX)), None)
            if hit:
                return hit
            assert self.proc.poll() is None, "trials fly exited before it was ready:\n" + self.output
            time.sleep(0.1)
        raise AssertionError("no ready line from trials fly:\n" + self.output)

    def wait(self, timeout_s: float) -> int:
        rc = self.proc.wait(timeout_s)
        self._reader.join(5)
        return rc

    @property
    def output(self) -> str:
        return "\n".join(self.lines[-40:])

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)


def _attr(driver: object, element_id: str, name: str) -> str | None:
    return driver.execute_script(  # type: ignore[attr-defined, no-any-return]
        "const e = document.getElementById(arguments[0]); return e ? e.getAttribute(arguments[1]) : null;",
        element_id, name,
    )  # fmt: skip


def _wait_for(cond: object, timeout_s: float, what: str) -> object:
    deadline = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < deadline:
        last = cond()  # type: ignore[operator]
        if last:
            return last
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what} (last: {last!r})")


@pytest.mark.slow  # a real-time trial flown from the page
@pytest.mark.skipif(
    chromium_paths() is None,
    reason="Chromium absent: apt-get install chromium chromium-driver (Debian) to run the browser tests",
)
def test_human_flies_a_trial_on_the_page_and_is_scored_like_a_program(tmp_path: Path) -> None:
    pytest.importorskip("selenium", reason="selenium is in the test extra: pip install -e '.[test]'")
    spec = tmp_path / "fly.toml"
    spec.write_text(SPEC)
    human = tmp_path / "human"
    flight = Flight(spec, human, "--trial", "2", "--seed", "11", "--speed", "2")
    try:
        ready = flight.ready_line()
        api, gcs = flight.ports
        assert "trial 2 of fly-test (seed " in ready and "air start" in ready and "speed 2" in ready, ready
        assert f"-> 127.0.0.1:{api}" in ready and f"-> 127.0.0.1:{gcs}" in ready, (
            ready
        )  # MAVLink for QGC/MAVSDK
        url = dashboard_url(ready)
        shots = tmp_path / "screenshots"
        with chromium() as driver:
            driver.get(url)
            _wait_for(lambda: int(_attr(driver, "vac", "data-frame-counter") or -1) >= 0, 30, "a VAC frame")
            _wait_for(lambda: _attr(driver, "hud-armed", "data-value") == "true", 10, "armed (air start)")
            # the person is told to land, on the page, as a program pilot is over MAVLink
            _wait_for(
                lambda: "land now" in driver.find_element("id", "statustext").text, 30, "'land now' shown"
            )
            screenshot(driver, shots, "01-told-to-land")
            driver.find_element("id", "btn-take").click()
            _wait_for(lambda: _attr(driver, "role", "data-role") == "pilot", 10, "this page in control")
            driver.find_element("id", "btn-land").click()
            _wait_for(
                lambda: _attr(driver, "hud-mode", "data-value") == "AUTO_LAND", 10, "Land mode on the HUD"
            )
            screenshot(driver, shots, "02-landing")
            rc = flight.wait(180)
    finally:
        flight.kill()
    assert rc == 0, flight.output
    assert "trial 2 [human]: landed" in flight.output, flight.output

    # The result files: a one-row campaign with the campaign's schema.
    doc = json.loads((human / "results.json").read_text())
    assert doc["schema"] == SCHEMA and doc["pilot"] == "human" and doc["trials_done"] == 1 and doc["complete"]
    (row,) = doc["rows"]
    assert (
        row["pilot"] == "human"
        and row["end"] == "landed"
        and row["landed"] is True
        and row["success"] is True
    )
    assert row["trial"] == 2 and row["touchdown_speed_m_s"] < 1.5
    assert math.hypot(row["touchdown_north_m"] - row["start_north_m"],
                      row["touchdown_east_m"] - row["start_east_m"]) < 2.0, row  # fmt: skip
    with (human / "results.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == list(COLUMNS) and len(rows) == 1 and rows[0]["end"] == "landed"

    # The same scenario `trials run SPEC --seed 11` draws for trial 2.
    drawn = _cli("trials", "scenarios", str(spec), "--seed", "11")
    assert drawn.returncode == 0, drawn.stderr
    assert doc["scenarios"] == [json.loads(drawn.stdout.splitlines()[2])]

    # The run recording: `viva-sitl replay` opens the trial directory.
    tdir = human / "trials" / "0002"
    for name in ("run.json", "trajectory.csv", "telemetry.tlog", "trial_trajectory.csv", "events.jsonl"):
        assert (tdir / name).stat().st_size > 0, name
    rep = _cli("replay", str(tdir), "--dashboard-port", "0", "--duration", "1", timeout_s=120)
    assert rep.returncode == 0 and "viva-sitl replay ready:" in rep.stdout, rep.stdout + rep.stderr
    assert _leftovers(str(tmp_path)) == []

    # A program's campaign over the same spec and seed pairs with the human on trial 2.
    prog = tmp_path / "prog"
    run = _cli("trials", "run", str(spec), "--pilot", "descend", "--seed", "11", "--jobs", "1", "--no-progress",
               "-o", str(prog))  # fmt: skip
    assert run.returncode == 0, run.stdout + run.stderr
    prow = next(r for r in json.loads((prog / "results.json").read_text())["rows"] if r["trial"] == 2)
    assert {k: row[k] for k in SCENARIO_COLUMNS} == {k: prow[k] for k in SCENARIO_COLUMNS}
    cmp = _cli("trials", "compare", str(human), str(prog), "-o", str(tmp_path / "cmp.json"))
    assert cmp.returncode == 0, cmp.stderr
    res = json.loads((tmp_path / "cmp.json").read_text())
    assert res["pairs"] == 1 and res["same_scenarios"] is True and res["unmatched_b"] == 3, res
    assert res["a"]["pilot"] == "human" and res["b"]["pilot"] == "descend"
    assert "WARNING" not in cmp.stdout and "3 only in B" in cmp.stdout, cmp.stdout


@pytest.mark.slow  # a real-time trial
def test_ctrl_c_aborts_the_trial_and_keeps_the_recording(tmp_path: Path) -> None:
    spec = tmp_path / "fly.toml"
    spec.write_text(SPEC)
    out = tmp_path / "human"
    flight = Flight(spec, out, "--trial", "0")
    try:
        flight.ready_line()
        tdir = out / "trials" / "0000"
        # the vehicle is flying (its recording grows) when the person gives up
        _wait_for(lambda: (tdir / "trajectory.csv").exists() and (tdir / "trajectory.csv").stat().st_size > 2000,
                  30, "the recording under way")  # fmt: skip
        flight.proc.send_signal(signal.SIGINT)
        rc = flight.wait(60)
    finally:
        flight.kill()
    assert rc == 130, flight.output
    assert "trial 0 [human]: aborted" in flight.output, flight.output
    (row,) = json.loads((out / "results.json").read_text())["rows"]
    assert row["end"] == "aborted" and row["landed"] is False and row["success"] is False
    assert row["end_t_s"] > 0.5 and row["touchdown_north_m"] is None
    for name in ("run.json", "trajectory.csv", "trial_trajectory.csv", "events.jsonl", "end.json"):
        assert (tdir / name).stat().st_size > 0, name
    events = [json.loads(x) for x in (tdir / "events.jsonl").read_text().splitlines()]
    assert events[-1]["kind"] == "end" and events[-1]["text"].startswith("aborted: stopped by the user")
    assert _leftovers(str(tmp_path)) == []

    # An aborted flight still pairs with the program that flew the same scenario (a one-trial `trials run`).
    prog = tmp_path / "prog"
    run = _cli(
        "trials", "run", str(spec), "--pilot", "descend", "--trial", "0", "--no-progress", "-o", str(prog)
    )
    assert run.returncode == 0, run.stdout + run.stderr
    cmp = _cli("trials", "compare", str(prog), str(out), "-o", str(tmp_path / "cmp.json"))
    assert cmp.returncode == 0, cmp.stderr
    res = json.loads((tmp_path / "cmp.json").read_text())
    assert (
        res["pairs"] == 1 and res["same_scenarios"] is True and res["unmatched_a"] == res["unmatched_b"] == 0
    )
    assert res["success"]["only_a"] == 1 and res["success"]["only_b"] == 0, res["success"]  # descend landed


def test_bad_input_is_one_line(tmp_path: Path) -> None:
    spec = tmp_path / "fly.toml"
    spec.write_text(SPEC)
    out = _cli("trials", "fly", str(spec), "--trial", "4", "-o", str(tmp_path / "a"), timeout_s=60)
    assert out.returncode == 2 and out.stderr.strip() == "viva-sitl trials: --trial 4: no such trial (0..3)"
    bad = tmp_path / "bad.toml"
    bad.write_text(SPEC.replace('name = "fly-test"', 'name = "fly-test"\nbogus = 1'))
    out = _cli("trials", "fly", str(bad), "--trial", "0", "-o", str(tmp_path / "b"), timeout_s=60)
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1
    assert "trials.bogus: unknown key" in out.stderr
    done = tmp_path / "done"
    done.mkdir()
    (done / "results.json").write_text("{}")
    out = _cli("trials", "fly", str(spec), "--trial", "0", "-o", str(done), timeout_s=60)
    assert (
        out.returncode == 2 and "holds a result already" in out.stderr and len(out.stderr.splitlines()) == 1
    )
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
