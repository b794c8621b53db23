"""`viva-sitl trials run --backend ray --address HOST:PORT` on a real cluster (issue 20): a `ray start --head` run
in its own directory with token authentication on, a driver in another directory (its pilot module, spec and `-o`
relative to it), the same rows as `--backend local`; a pilot that the workers cannot import is an infrastructure
error (exit 3, one line saying which import failed); a driver without the token, or an address where nothing
listens, is one line (exit 2), not a traceback.

One head for the module (starting Ray takes ~10 s on 2 cores); it runs with `--block` in its own session and is
stopped by its process id (SIGTERM ends its children), never by `ray stop` (which would end every Ray process of
this user on the machine, other people's included); no process of its session may be left."""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from viva_sitl.evaluation.campaign import _pack_dir, _ray_one, _unpack_dir, ray_runtime_env
from viva_sitl.evaluation.spec import draw_scenarios, load_spec

pytest.importorskip("ray", reason="the ray backend needs the trials-ray extra")

BIN = Path(sys.executable).parent
SPEC = """\
[trials]
name = "raycluster"
n = 2
seed = 11
timeout_s = 40.0

[scenario]
footage = "synthetic"
north_m = [-30.0, 30.0]
east_m = [-30.0, 30.0]
altitude_m = [8.0, 10.0]
land_at_s = 0.5
wind_speed_m_s = [0.0, 2.0]
"""
PILOT = "from viva_sitl.evaluation.pilots import BUILTIN_PILOTS\n\nDescend = BUILTIN_PILOTS['descend']\n\n\nclass Cls(Descend):\n    pass\n"
# imports a package that only the driver has (on its PYTHONPATH, outside its working directory): the workers lack it
BAD_PILOT = "import vivatest_driver_only_dep  # noqa: F401\n\nfrom mypilot import Cls  # noqa: F401\n"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _session_pids(sid: int) -> list[int]:
    """The processes left in the head's session (pgrep -s: the raylet's workers rename themselves ray::IDLE)."""
    out = subprocess.run(["pgrep", "-s", str(sid)], capture_output=True, text=True).stdout
    return [int(p) for p in out.split()]


@dataclass
class Head:
    address: str
    env: dict[str, str]  # what a driver needs: the cluster's token
    cwd: Path  # where `ray start` ran


@pytest.fixture(scope="module")
def ray_head() -> Iterator[Head]:
    root = Path(tempfile.mkdtemp(prefix="vr"))  # short: Ray's unix sockets live under --temp-dir
    head_cwd = root / "head"
    head_cwd.mkdir()
    port = _free_port()
    env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32),
           "RAY_USAGE_STATS_ENABLED": "0"}  # fmt: skip
    env.pop("RAY_ADDRESS", None)
    log = (root / "head.log").open("w")
    proc = subprocess.Popen(
        [str(BIN / "ray"), "start", "--head", "--port", str(port), "--num-cpus", "2", "--block",
         "--include-dashboard", "false", "--ray-client-server-port", str(_free_port()),
         "--temp-dir", str(root / "t"), "--disable-usage-stats"],
        cwd=head_cwd, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 180.0
        while "Ray runtime started" not in (root / "head.log").read_text():
            assert proc.poll() is None, "ray start --head ended: " + (root / "head.log").read_text()[-2000:]
            assert time.monotonic() < deadline, "ray start --head not up in 180 s"
            time.sleep(0.2)
        yield Head(f"127.0.0.1:{port}", {k: env[k] for k in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN")}, head_cwd)
    finally:
        proc.send_signal(signal.SIGTERM)  # --block: ray start ends the processes it started
        try:
            proc.wait(60.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10.0)
        log.close()
        deadline = time.monotonic() + 30.0
        while _session_pids(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.2)
        left = _session_pids(proc.pid)
        for pid in left:  # ours (the head's session): never leave them running, whatever the test says
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        shutil.rmtree(root, ignore_errors=True)
        assert not left, f"Ray processes left after the head stopped: {left}"


def _driver(tmp_path: Path) -> Path:
    """The driver's working directory: the spec and the pilot module, nothing installed."""
    d = tmp_path / "driver"
    d.mkdir()
    (d / "spec.toml").write_text(SPEC)
    (d / "mypilot.py").write_text(PILOT)
    return d


def _trials(cwd: Path, *args: str, env: dict[str, str] | None = None, timeout: float = 600.0) -> subprocess.CompletedProcess[str]:  # fmt: skip
    base = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    return subprocess.run([str(BIN / "viva-sitl"), "trials", "run", *args, "--no-progress"], cwd=cwd,
                          env={**base, **(env or {})}, capture_output=True, text=True, timeout=timeout)  # fmt: skip


def _rows(out: Path) -> list[dict[str, object]]:
    rows = json.loads((out / "results.json").read_text())["rows"]
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in sorted(rows, key=lambda r: r["trial"])]


@pytest.mark.slow  # a real Ray cluster and three campaigns
def test_cluster_run_matches_local_and_keeps_paths_on_the_driver(tmp_path: Path, ray_head: Head) -> None:
    drv = _driver(tmp_path)
    t0 = time.monotonic()
    r = _trials(drv, "spec.toml", "--pilot", "mypilot:Cls", "--backend", "ray", "--address", ray_head.address,
                "--n", "2", "-o", "ray_out", env=ray_head.env)  # fmt: skip
    ray_s = time.monotonic() - t0
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    out = drv / "ray_out"
    for k in (0, 1):  # the trial folders in the driver's -o, written by the workers
        assert (out / "trials" / f"{k:04d}" / "result.json").is_file()
        assert (out / "trials" / f"{k:04d}" / "scenario.json").is_file()
    assert not (ray_head.cwd / "ray_out").exists()  # not where `ray start` ran
    assert not list(out.glob(".ray-driver-*"))  # the driver's marker is gone
    rows = _rows(out)
    assert [x["end"] for x in rows] == ["landed", "landed"]
    assert all(x["success"] is not None for x in rows)
    t0 = time.monotonic()
    loc = _trials(drv, "spec.toml", "--pilot", "mypilot:Cls", "--n", "2", "--jobs", "2", "-o", "local_out")
    local_s = time.monotonic() - t0
    assert loc.returncode == 0, loc.stdout + loc.stderr
    assert rows == _rows(drv / "local_out")
    print(f"2 trials: ray cluster {ray_s:.1f} s, local pool {local_s:.1f} s (wall, driver command)")

    # a pilot the workers cannot import: every trial an infrastructure error, exit 3, the import named once
    deps = tmp_path / "driver_only"
    deps.mkdir()
    (deps / "vivatest_driver_only_dep.py").write_text("X = 1\n")
    (drv / "badpilot.py").write_text(BAD_PILOT)
    bad = _trials(drv, "spec.toml", "--pilot", "badpilot:Cls", "--backend", "ray", "--address", ray_head.address,
                  "--n", "2", "-o", "bad_out", env={**ray_head.env, "PYTHONPATH": str(deps)})  # fmt: skip
    assert bad.returncode == 3, bad.stdout + bad.stderr
    assert "Traceback" not in bad.stderr
    first = [line for line in bad.stderr.splitlines() if "first harness error" in line]
    assert len(first) == 1 and "No module named 'vivatest_driver_only_dep'" in first[0], bad.stderr
    assert "Ray worker on" in first[0]
    doc = json.loads((drv / "bad_out" / "results.json").read_text())
    assert [x["end"] for x in doc["rows"]] == ["trial_error", "trial_error"]
    assert all(x["success"] is None for x in doc["rows"])
    assert "unavailable (no trial flew)" in bad.stdout and "0.0 %" not in bad.stdout  # not "success 0 %"
    assert doc["aggregate"]["infra_errors"]["n"] == 2

    # the same cluster without the token: one line naming the fix, at once (not Ray's 20 s of retries)
    t0 = time.monotonic()
    noauth = _trials(drv, "spec.toml", "--pilot", "mypilot:Cls", "--backend", "ray", "--address",
                     ray_head.address, "--n", "2", "-o", "noauth_out", timeout=60.0)  # fmt: skip
    assert noauth.returncode == 2, noauth.stdout + noauth.stderr
    assert "Traceback" not in noauth.stderr
    assert "uses token authentication" in noauth.stderr and "RAY_AUTH_MODE=token" in noauth.stderr
    assert time.monotonic() - t0 < 20.0


def test_no_cluster_at_the_address_is_one_line(tmp_path: Path) -> None:
    drv = _driver(tmp_path)
    port = _free_port()  # nothing listens there
    r = _trials(drv, "spec.toml", "--pilot", "descend", "--backend", "ray", "--address", f"127.0.0.1:{port}",
                "-o", "out", timeout=60.0)  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    assert f"no Ray cluster at 127.0.0.1:{port}" in r.stderr and "ray start --head" in r.stderr
    assert "Traceback" not in r.stderr
    assert not (drv / "out").exists()  # no empty run left behind


def test_address_needs_the_ray_backend(tmp_path: Path) -> None:
    r = _trials(_driver(tmp_path), "spec.toml", "--address", "127.0.0.1:6379", timeout=60.0)
    assert r.returncode == 2 and "--backend ray" in r.stderr, r.stderr


def test_shipped_directory_leaves_out_results_and_environments(tmp_path: Path) -> None:
    env = ray_runtime_env(tmp_path, (tmp_path / "runs" / "a").resolve())
    assert env["working_dir"] == str(tmp_path)
    assert {".git", ".venv", "__pycache__", "trials-out", "/runs/a"} <= set(env["excludes"])
    outside = ray_runtime_env(tmp_path / "x", tmp_path / "elsewhere")
    assert not [e for e in outside["excludes"] if e.startswith("/")]


def test_worker_without_the_drivers_out_sends_the_trial_folder_back(tmp_path: Path) -> None:
    """A worker on another machine (it does not see the driver's marker in OUT) flies into a folder of its own
    and returns it; unpacked in the driver's OUT it is the folder a worker on the driver's machine writes."""
    (tmp_path / "spec.toml").write_text(SPEC)
    spec = load_spec(tmp_path / "spec.toml")
    sc = draw_scenarios(spec)[0]
    out = tmp_path / "out"
    row, packed = _ray_one(spec, sc, "descend", str(out), 0, False, str(tmp_path), str(out / ".no-marker"))
    assert not out.exists()  # nothing written where this worker cannot see
    assert packed is not None and row["end"] == "landed"
    _unpack_dir(packed, out / "trials" / "0000")
    names = {p.name for p in (out / "trials" / "0000").iterdir()}
    assert {"scenario.json"} <= names and len(names) > 1, names
    assert json.loads((out / "trials" / "0000" / "scenario.json").read_text())["index"] == 0
    again = tmp_path / "again"
    _unpack_dir(_pack_dir(out / "trials" / "0000"), again)
    assert {p.name for p in again.iterdir()} == names
