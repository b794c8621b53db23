"""The dashboard's readings of the app: MAVLink peers through the endpoint's public `peers_heard`, and the autopilot
looked up at every use (Vehicle.reset replaces it)."""

from __future__ import annotations

import json
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

import pytest
from sitl_process import MavlinkPeer, SitlProcess, free_tcp_port

from viva_sitl.app import SitlApp
from viva_sitl.config import SimConfig
from viva_sitl.dashboard.config import DashboardConfig


def test_a_controller_steers_the_autopilot_of_now_after_a_reset(tmp_path: Path) -> None:
    app = SitlApp(SimConfig(), video=False, run_dir=tmp_path, dashboard=DashboardConfig(port=0))
    try:
        assert app.dashboard is not None
        ctl = app.dashboard.controller
        old = app.autopilot
        app.vehicle.reset(seed=1)
        assert app.autopilot is not old and ctl.autopilot is app.autopilot
        ctl.take_control(7)
        outcome = ctl.command(7, {"cmd": "arm"})
        assert outcome.ok, outcome.reason
        assert (
            app.autopilot.armed and not old.armed
        )  # the button armed the vehicle that flies, not the old one
    finally:
        app.sim.close()


@pytest.mark.slow  # a viva-sitl process
@pytest.mark.e2e
def test_hud_links_are_the_peers_the_endpoint_heard(sitl_factory: Callable[..., SitlProcess]) -> None:
    sitl = sitl_factory(extra_args=["--dashboard-port", str(free_tcp_port())])
    url = next(p.split(" ", 1)[1] for p in sitl.ready_line.split(" | ") if p.startswith("dashboard http"))

    def links() -> list[dict[str, object]]:
        with urllib.request.urlopen(url + "api/state", timeout=10) as r:
            return list(json.load(r)["links"])

    assert links() == []  # nobody has talked yet
    with MavlinkPeer(sitl.ports.gcs) as peer:
        peer.wait_autopilot()
        peer.send(peer.mav.heartbeat_encode(6, 8, 0, 0, 0))  # a GCS heartbeat, as QGroundControl's
        deadline = time.monotonic() + 10
        seen: list[dict[str, object]] = []
        while time.monotonic() < deadline and not seen:
            seen = [lk for lk in links() if lk["link"] == "gcs"]
            time.sleep(0.1)
        assert len(seen) == 1, seen
        assert seen[0]["ok"] is True and 0.0 <= float(seen[0]["age_s"]) < 3.0, seen  # type: ignore[arg-type]
    # the peer closed (silent longer than PEER_LOST_S x speed, in sim seconds): shown as lost
    t0 = time.monotonic()
    while time.monotonic() - t0 < 20 and seen[0]["ok"]:
        seen = [lk for lk in links() if lk["link"] == "gcs"]
        time.sleep(0.2)
    assert seen[0]["ok"] is False and float(seen[0]["age_s"]) > 3.0, seen  # type: ignore[arg-type]
