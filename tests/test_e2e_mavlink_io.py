"""End to end, `viva-sitl run` as a user starts it: the .tlog of every run (on by default, in the run directory, named
in the ready and stop lines, readable by pymavlink), --no-tlog, and a taken port -> one line, exit status 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from pymavlink import mavutil
from sitl_process import REPO_ROOT, MavlinkPeer, SitlProcess

pytestmark = pytest.mark.e2e


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), env.get("PYTHONPATH", "")) if p)
    return env


@pytest.mark.slow  # two viva-sitl processes
def test_tlog_by_default_and_port_in_use_is_one_line(tmp_path: Path) -> None:
    sitl = SitlProcess(tmp_path, name="first")
    with sitl, MavlinkPeer(sitl.ports.gcs) as peer:
        peer.wait_autopilot()
        tlog = (tmp_path / "first-run" / "telemetry.tlog").resolve()
        assert f"tlog {tlog}" in sitl.ready_line, sitl.ready_line
        # a second vehicle on the same local port: one line naming the port and the way out, exit status 2
        taken = sitl.ports.api_local
        second = subprocess.run(
            [sys.executable, "-m", "viva_sitl", "run", "--footage", "synthetic", "--no-video", "--no-tlog", "--no-dashboard",
             "--run-dir", str(tmp_path / "second-run"), "--api-local-port", str(taken), "--gcs-local-port", "0"],
            capture_output=True, text=True, timeout=120, env=_env(), cwd=tmp_path,
        )  # fmt: skip
        assert peer.latest("HEARTBEAT") is not None
    assert second.returncode == 2, second.stderr
    lines = [ln for ln in second.stderr.splitlines() if ln.strip() and "INFO" not in ln]
    assert len(lines) == 1, second.stderr
    assert f"UDP port {taken}" in lines[0] and "--instance N" in lines[0] and "Traceback" not in second.stderr
    assert sitl.returncode == 0
    assert sitl.stop_stats().get("tlog") == str(tlog)
    mlog = mavutil.mavlink_connection(str(tlog))
    kinds: dict[tuple[int, str], int] = {}
    while (m := mlog.recv_match()) is not None:
        key = (m.get_srcSystem(), m.get_type())
        kinds[key] = kinds.get(key, 0) + 1
    assert kinds.get((1, "HEARTBEAT"), 0) >= 1 and kinds.get((1, "ATTITUDE"), 0) > 50
    assert kinds.get((255, "HEARTBEAT"), 0) >= 1  # the ground station's side is in the log too


@pytest.mark.slow  # a viva-sitl run
def test_no_tlog_writes_none(tmp_path: Path) -> None:
    sitl = SitlProcess(tmp_path, name="quiet", extra_args=["--no-tlog"])
    with sitl:
        assert " tlog " not in sitl.ready_line
    assert sitl.returncode == 0
    assert not list(tmp_path.rglob("*.tlog"))


def test_unwritable_tlog_is_one_line(tmp_path: Path) -> None:
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("a file where the tlog's directory should be")
    run = subprocess.run(
        [sys.executable, "-m", "viva_sitl", "run", "--footage", "synthetic", "--no-video", "--run-dir",
         str(tmp_path / "run"), "--tlog", str(blocker / "x.tlog"), "--api-local-port", "0", "--gcs-local-port", "0",
         "--no-dashboard"],
        capture_output=True, text=True, timeout=120, env=_env(), cwd=tmp_path,
    )  # fmt: skip
    assert run.returncode == 2, run.stderr
    lines = [ln for ln in run.stderr.splitlines() if ln.strip() and "INFO" not in ln]
    assert len(lines) == 1 and lines[0].startswith(
        f"viva-sitl: cannot create the tlog {blocker / 'x.tlog'}: "
    )
    assert "Traceback" not in run.stderr
