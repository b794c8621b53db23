"""End to end: placing footage on Earth as PX4 SITL does (`--home`, PX4_HOME_LAT/LON/ALT), real `viva-sitl run`
processes and a pymavlink peer over UDP; and bad placement / scale input gets one clear line."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from sitl_process import REPO_ROOT, MavlinkPeer, SitlProcess, takeoff

pytestmark = [pytest.mark.e2e]

PX4_HOME = (47.397742, 8.545594, 488.0)  # PX4 SITL's default home: the examples' coordinates
SYDNEY = (-33.8568, 151.2153, 20.0)


def home_position(peer: MavlinkPeer) -> tuple[float, float, float]:
    peer.wait_autopilot()
    ack = peer.command_long(mavlink2.MAV_CMD_REQUEST_MESSAGE, [float(mavlink2.MAVLINK_MSG_ID_HOME_POSITION)])
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
    home = peer.wait("HOME_POSITION", timeout_s=5.0, since_s=0.0)
    return home.latitude / 1e7, home.longitude / 1e7, home.altitude / 1e3


@pytest.mark.slow  # a viva-sitl process over real footage
@pytest.mark.footage
def test_home_places_real_footage_at_px4_default_home(
    interchange_video: Path,
    sitl_factory: Callable[..., SitlProcess],
    peer_factory: Callable[[int], MavlinkPeer],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """--home beats PX4_HOME_* and the footage's own (Kharkiv) geo-reference; the camera still sees the footage."""
    monkeypatch.setenv("PX4_HOME_LAT", str(SYDNEY[0]))
    monkeypatch.setenv("PX4_HOME_LON", str(SYDNEY[1]))
    sitl = sitl_factory(footage="interchange", extra_args=["--home", "47.397742,8.545594,488"])
    peer = peer_factory(sitl.ports.api)
    lat, lon, alt = home_position(peer)
    assert lat == pytest.approx(PX4_HOME[0], abs=1e-6) and lon == pytest.approx(PX4_HOME[1], abs=1e-6)
    assert alt == pytest.approx(PX4_HOME[2], abs=0.5)
    gpi = peer.wait("GLOBAL_POSITION_INT", timeout_s=5.0)
    assert gpi.lat / 1e7 == pytest.approx(PX4_HOME[0], abs=1e-5)
    assert gpi.lon / 1e7 == pytest.approx(PX4_HOME[1], abs=1e-5)
    # a flight written for PX4's default home (as MAVSDK's goto.py): 20 m north of it, as a global position target
    takeoff(peer, 10.0)
    north_lat = PX4_HOME[0] + math.degrees(20.0 / 6371000.0)
    ack = peer.command_long(
        mavlink2.MAV_CMD_DO_REPOSITION,
        [-1.0, 1.0, 0.0, math.nan, north_lat, PX4_HOME[1], PX4_HOME[2] + 10.0],
    )
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED, f"reposition: MAV_RESULT {ack.result}"
    there = peer.wait(
        "LOCAL_POSITION_NED",
        lambda m: abs(m.x - 20.0) < 1.0 and abs(m.y) < 1.0 and math.hypot(m.vx, m.vy) < 0.3,
        timeout_s=60.0,
        what="hover 20 m north of PX4's default home",
    )
    assert there.z == pytest.approx(-10.0, abs=1.0)
    gpi = peer.wait("GLOBAL_POSITION_INT", timeout_s=5.0)
    assert gpi.lat / 1e7 == pytest.approx(north_lat, abs=2e-5) and gpi.lon / 1e7 == pytest.approx(
        PX4_HOME[1], abs=2e-5
    )


@pytest.mark.slow  # a viva-sitl process over real footage
@pytest.mark.footage
def test_px4_home_env_places_footage(
    interchange_video: Path,
    sitl_factory: Callable[..., SitlProcess],
    peer_factory: Callable[[int], MavlinkPeer],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("PX4_HOME_LAT", str(SYDNEY[0]))
    monkeypatch.setenv("PX4_HOME_LON", str(SYDNEY[1]))
    monkeypatch.setenv("PX4_HOME_ALT", str(SYDNEY[2]))
    sitl = sitl_factory(footage="interchange")
    lat, lon, alt = home_position(peer_factory(sitl.ports.api))
    assert (lat, lon) == pytest.approx(SYDNEY[:2], abs=1e-6) and alt == pytest.approx(SYDNEY[2], abs=0.5)


def _run_cli(
    args: list[str], env: dict[str, str] | None = None, timeout_s: float = 60.0
) -> subprocess.CompletedProcess[str]:
    full_env = dict(os.environ, **(env or {}))
    full_env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), full_env.get("PYTHONPATH", "")) if p)
    return subprocess.run(
        [sys.executable, "-m", "viva_sitl", *args],
        capture_output=True, text=True, timeout=timeout_s, env=full_env, stdin=subprocess.DEVNULL,
    )  # fmt: skip


RUN_QUICK = ["run", "--no-video", "--duration", "0.5", "--api-port", "0", "--gcs-port", "0",
             "--api-local-port", "0", "--gcs-local-port", "0"]  # fmt: skip


@pytest.mark.parametrize(
    ("args", "env", "message"),
    [
        (["--home", "95,8"], {}, "latitude must be in [-90, 90]"),
        (["--home", "47.3"], {}, "home must be LAT,LON or LAT,LON,ALT"),
        (["--home", "47.3,eight"], {}, "home must be numbers"),
        (["--footage-alt", "-5"], {}, "expected a positive number"),
        (["--footage-hfov", "200"], {}, "below 180 degrees"),
        ([], {"PX4_HOME_LAT": "47.3"}, "set both PX4_HOME_LAT and PX4_HOME_LON"),
        ([], {"PX4_HOME_LAT": "47.3", "PX4_HOME_LON": "x"}, "PX4_HOME_LAT/LON/ALT: home must be numbers"),
    ],
)
def test_bad_placement_and_scale_input_is_one_line(
    args: list[str], env: dict[str, str], message: str
) -> None:
    res = _run_cli(RUN_QUICK + args, env)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and message in lines[0], res.stderr


def test_bad_home_in_config_is_one_line(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[sim]\nhome = "47.3,8.5,488,1"\n')
    res = _run_cli([*RUN_QUICK, "--config", str(cfg)])
    assert res.returncode == 2 and "Traceback" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "[sim].home" in lines[0] and "LAT,LON" in lines[0], res.stderr
