"""The dashboard in a real browser (headless Chromium) against a real `viva-sitl run`, checked against MAVLink.

Screenshots are kept under the viva-sitl run directory (<tmp>/<name>-run/screenshots): CI artefacts.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import pytest
from dashboard_browser import chromium, chromium_paths, dashboard_url, screenshot
from sitl_process import MavlinkPeer, SitlProcess, free_tcp_port, free_udp_ports

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.slow,  # a viva-sitl process and a headless Chromium per test
    pytest.mark.skipif(
        chromium_paths() is None,
        reason="Chromium absent: apt-get install chromium chromium-driver (Debian) to run the browser tests",
    ),
]
pytest.importorskip("selenium", reason="selenium is in the test extra: pip install -e '.[test]'")

MODE_POSCTL = 3 << 16
ARMED_FLAG = 128


def wait_for(cond: Callable[[], Any], timeout_s: float, what: str, poll_s: float = 0.05) -> Any:
    deadline = time.monotonic() + timeout_s
    last: Any = None
    while time.monotonic() < deadline:
        last = cond()
        if last:
            return last
        time.sleep(poll_s)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what} (last: {last!r})")


def attr(driver: Any, element_id: str, name: str) -> str | None:
    return driver.execute_script(
        "const e = document.getElementById(arguments[0]); return e ? e.getAttribute(arguments[1]) : null;",
        element_id,
        name,
    )


def text(driver: Any, element_id: str) -> str:
    return str(driver.execute_script("return document.getElementById(arguments[0]).textContent;", element_id))


def footprint_centre(driver: Any) -> tuple[float, float] | None:
    raw = attr(driver, "overview", "data-footprint")
    if not raw:
        return None
    pts = [tuple(float(v) for v in p.split()) for p in raw.split(";")]
    return sum(p[0] for p in pts) / len(pts), sum(p[1] for p in pts) / len(pts)


def press(driver: Any, key: str) -> None:
    from selenium.webdriver.common.action_chains import ActionChains

    ActionChains(driver).key_down(key).key_up(key).perform()


def test_page_shows_the_flight_and_keys_fly_it(sitl_factory: Callable[..., SitlProcess]) -> None:
    video_port = free_udp_ports(1)[0]
    sitl = sitl_factory(video_port=video_port, extra_args=["--dashboard-port", str(free_tcp_port())])
    url = dashboard_url(sitl.ready_line)
    assert url.startswith("http://127.0.0.1:")
    shots = sitl.workdir / f"{sitl.name}-run" / "screenshots"
    with MavlinkPeer(sitl.ports.gcs) as peer, chromium() as driver:
        peer.wait_autopilot()
        driver.get(url)

        # The VAC image updates: frame counters advance and the canvas shows them.
        first = int(wait_for(lambda: int(attr(driver, "vac", "data-frame-counter") or -1) >= 0 and
                             attr(driver, "vac", "data-frame-counter"), 20, "a first VAC frame"))  # fmt: skip
        wait_for(
            lambda: int(attr(driver, "vac", "data-frame-counter") or -1) >= first + 10,
            10,
            "10 more VAC frames",
        )
        latency_ms = float(attr(driver, "vac", "data-latency-ms") or "nan")
        assert latency_ms < 1000, f"VAC frame shown {latency_ms} ms after its pose was sampled"
        wait_for(lambda: attr(driver, "overview", "data-bg-frame"), 10, "the overview footage image")
        screenshot(driver, shots, "01-loaded")

        # Zoom (mouse wheel at the vehicle): the server sends a crop of the visible part, at the canvas resolution.
        full_rect = [float(v) for v in (attr(driver, "overview", "data-bg-rect") or "").split(",")]
        driver.execute_script(
            "const c = document.getElementById('overview'), r = c.getBoundingClientRect();"
            "for (let i = 0; i < 8; i++) c.dispatchEvent(new WheelEvent('wheel', {deltaY: -100, bubbles: true,"
            " cancelable: true, clientX: r.left + r.width / 2, clientY: r.top + r.height / 2}));"
        )

        def zoomed_rect() -> list[float] | None:
            rect = [float(v) for v in (attr(driver, "overview", "data-bg-rect") or "").split(",")]
            return rect if rect[2] - rect[0] < (full_rect[2] - full_rect[0]) / 4 else None

        rect = wait_for(zoomed_rect, 10, "a zoomed-in overview crop")
        size = driver.execute_script(
            "const c = document.getElementById('overview'); return [c.width, c.height];"
        )
        # the crop asked for is no bigger than the canvas (times devicePixelRatio 1 in headless Chromium)
        assert rect[2] - rect[0] < full_rect[2] - full_rect[0] and size[0] <= 2048
        screenshot(driver, shots, "01b-zoomed")
        driver.find_element("id", "btn-fit").click()

        # A refused command shows its reason on the page and goes out as STATUSTEXT like a MAVLink refusal.
        press(driver, "c")
        wait_for(lambda: attr(driver, "role", "data-role") == "pilot", 5, "this page to take control")
        t0 = time.monotonic()
        press(driver, "t")  # take off while disarmed
        wait_for(lambda: "not armed" in text(driver, "last-result"), 5, "the take-off refusal on the page")
        peer.wait("STATUSTEXT", lambda m: "Takeoff denied: vehicle not armed" in m.text, 5, since_s=t0)
        wait_for(lambda: "Takeoff denied" in text(driver, "statustext"), 5, "the refusal in the message list")

        # Keys: Position mode, arm, take off.
        press(driver, "1")
        peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1 and m.custom_mode == MODE_POSCTL, 5)
        press(driver, "m")
        peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1 and m.base_mode & ARMED_FLAG, 5)
        press(driver, "t")
        peer.wait("LOCAL_POSITION_NED", lambda m: m.z < -2.0, 30, what="the climb after T")
        wait_for(lambda: float(attr(driver, "hud-alt", "data-value") or 0) > 1.5, 5, "the HUD altitude")

        # HUD values match MAVLink telemetry (sampled together while hovering).
        peer.wait("LOCAL_POSITION_NED", lambda m: m.z < -2.4 and abs(m.vz) < 0.2, 40, what="a steady hover")
        for _ in range(3):
            pos = peer.latest("LOCAL_POSITION_NED")
            hud_alt = float(attr(driver, "hud-alt", "data-value") or "nan")
            if abs(hud_alt - (-pos.z)) < 0.3:
                break
            time.sleep(0.2)
        assert abs(hud_alt - (-pos.z)) < 0.3, f"HUD altitude {hud_alt} vs LOCAL_POSITION_NED {-pos.z}"
        bat = peer.latest("SYS_STATUS")
        hud_bat = float(attr(driver, "hud-bat", "data-value") or "nan")
        assert abs(hud_bat - bat.battery_remaining) <= 1.5, (hud_bat, bat.battery_remaining)
        assert attr(driver, "hud-armed", "data-value") == "true"
        vfr = peer.latest("VFR_HUD")
        hud_hdg = float(attr(driver, "hud-hdg", "data-value") or "nan")
        assert abs((hud_hdg - vfr.heading + 180) % 360 - 180) <= 2.0, (hud_hdg, vfr.heading)
        screenshot(driver, shots, "02-hover")

        # Position mode: W flies forward (north at heading 0); the footprint follows the vehicle on the overview.
        press(driver, "1")
        peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1 and m.custom_mode == MODE_POSCTL, 10)
        before = peer.latest("LOCAL_POSITION_NED")
        fp_before = wait_for(lambda: footprint_centre(driver), 5, "a footprint on the overview")
        from selenium.webdriver.common.action_chains import ActionChains

        ActionChains(driver).key_down("w").perform()
        try:
            peer.wait(
                "LOCAL_POSITION_NED", lambda m: m.x > before.x + 4.0, 30, what="4 m forward while W is held"
            )
            wait_for(
                lambda: float(attr(driver, "hud-gs", "data-value") or 0) > 1.0, 5, "ground speed on the HUD"
            )
            screenshot(driver, shots, "03-flying-forward")
        finally:
            ActionChains(driver).key_up("w").perform()
        fp_after = footprint_centre(driver)
        assert fp_after is not None
        # footage v grows southwards (north up in the synthetic field): flying north moves the footprint up
        moved = math.hypot(fp_after[0] - fp_before[0], fp_after[1] - fp_before[1])
        assert fp_after[1] < fp_before[1] - 2.0 and moved > 2.0, (fp_before, fp_after)

        # Released key: sticks centred, the vehicle brakes and holds.
        peer.wait(
            "LOCAL_POSITION_NED", lambda m: math.hypot(m.vx, m.vy) < 0.3, 30, what="the stop after release"
        )
        held = peer.latest("LOCAL_POSITION_NED")
        now = peer.wait("LOCAL_POSITION_NED", since_s=time.monotonic() + 1.0, timeout_s=5, what="1 s later")
        assert math.hypot(now.x - held.x, now.y - held.y) < 1.0
        assert attr(driver, "hud-mode", "data-value") == "POSCTL"
        screenshot(driver, shots, "04-holding")

        # A key held while the window loses focus (tab switched, hidden) is released: sticks centred on the server.
        ActionChains(driver).key_down("d").perform()
        try:
            wait_for(lambda: "y 0.60" in text(driver, "hud-sticks"), 5, "the D key on the server's sticks")
            driver.execute_script("window.dispatchEvent(new Event('blur'));")
            wait_for(lambda: "y 0.00" in text(driver, "hud-sticks"), 5, "sticks centred after blur")
        finally:
            ActionChains(driver).key_up("d").perform()
        peer.wait(
            "LOCAL_POSITION_NED", lambda m: math.hypot(m.vx, m.vy) < 0.3, 30, what="the stop after blur"
        )

        # Kill needs the confirmation button; then the motors stop (disarmed, as MAVLink reports).
        press(driver, "k")
        driver.find_element("id", "btn-kill-confirm").click()
        peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1 and not m.base_mode & ARMED_FLAG, 5)
        wait_for(lambda: "Kill switch" in text(driver, "statustext"), 5, "the kill message on the page")
        screenshot(driver, shots, "05-killed")
    assert sitl.alive, sitl.logs()


def _overview_pixels(driver: Any) -> Any:
    import numpy as np

    data = driver.execute_script(
        "const c = document.getElementById('overview');"
        "return Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data);"
    )
    return np.array(data, np.int16)


def test_ground_truth_layers_toggle(sitl_factory: Callable[..., SitlProcess]) -> None:
    """The synthetic field's objects and risk map are drawn on the overview; unticking a layer removes it."""
    import json
    import urllib.request

    sitl = sitl_factory(extra_args=["--dashboard-port", str(free_tcp_port())])
    url = dashboard_url(sitl.ready_line)
    shots = sitl.workdir / f"{sitl.name}-run" / "screenshots"
    with urllib.request.urlopen(url + "api/info", timeout=10) as r:
        info = json.load(r)
    assert {"objects", "risk map"} <= set(info["layers"])
    n_risk = len(info["static_layers"]["risk map"])
    assert n_risk > 0
    with chromium() as driver:
        driver.get(url)
        wait_for(lambda: attr(driver, "overview", "data-bg-frame"), 20, "the overview footage image")

        def drawn() -> dict[str, int]:
            raw = attr(driver, "overview", "data-layers") or ""
            return {k: int(v) for k, v in (p.split("=") for p in raw.split(";") if "=" in p)}

        counts = wait_for(lambda: (d := drawn()).get("objects", 0) > 0 and d, 10, "objects on the overview")
        assert counts["risk map"] == n_risk
        with urllib.request.urlopen(url + "api/state", timeout=10) as r:
            n_objects = len(json.load(r)["layers"]["objects"])
        assert abs(counts["objects"] - n_objects) <= 2  # actors enter/leave between the two samples
        screenshot(driver, shots, "10-layers-on")
        with_risk = _overview_pixels(driver)

        driver.find_element("css selector", 'input[data-layer="risk map"]').click()
        wait_for(lambda: "risk map" not in drawn(), 5, "the risk map toggled off")
        driver.find_element("css selector", 'input[data-layer="objects"]').click()
        wait_for(lambda: "objects" not in drawn(), 5, "the objects toggled off")
        screenshot(driver, shots, "11-layers-off")
        without = _overview_pixels(driver)
        changed = float((abs(with_risk - without).reshape(-1, 4)[:, :3].max(axis=1) > 20).mean())
        assert changed > 0.05, f"toggling the layers changed only {changed:.3f} of the overview's pixels"
        driver.find_element("css selector", 'input[data-layer="risk map"]').click()
        wait_for(lambda: drawn().get("risk map") == n_risk, 5, "the risk map back on")
    assert sitl.alive, sitl.logs()
