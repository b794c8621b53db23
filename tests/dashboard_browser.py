"""Helpers for the dashboard's real-browser tests: a headless Debian Chromium driven by selenium + chromedriver."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1500,1100",
)


def chromium_paths() -> tuple[str, str] | None:
    """(chromium, chromedriver) from PATH (Debian: apt-get install chromium chromium-driver), or None."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if browser is None or driver is None:
        return None
    return browser, driver


def dashboard_url(ready_line: str) -> str:
    """The `| dashboard http://...` part of viva-sitl's ready line."""
    for part in ready_line.split(" | "):
        if part.startswith("dashboard http"):
            return part.split(" ", 1)[1].strip()
    raise AssertionError(f"no dashboard URL in the ready line: {ready_line!r}")


@contextmanager
def chromium() -> Iterator[Any]:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    paths = chromium_paths()
    assert paths is not None
    browser, driver_path = paths
    with tempfile.TemporaryDirectory(prefix="viva-chromium-") as profile:
        opts = webdriver.ChromeOptions()
        opts.binary_location = browser
        for flag in CHROMIUM_FLAGS:
            opts.add_argument(flag)
        opts.add_argument(f"--user-data-dir={profile}")
        driver = webdriver.Chrome(service=Service(driver_path), options=opts)
        try:
            driver.set_page_load_timeout(30)
            yield driver
        finally:
            driver.quit()


ARTIFACTS_ENV = "VIVA_TEST_ARTIFACTS"  # CI: also copy screenshots here (pytest's tmp dirs are rotated)


def screenshot(driver: Any, directory: Path, name: str) -> Path:
    """Save a PNG under `directory` (the viva-sitl run directory) and, when $VIVA_TEST_ARTIFACTS is set, a copy
    there under the run directory's name."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{name}.png"
    assert driver.save_screenshot(str(path)), f"screenshot {path} failed"
    extra = os.environ.get(ARTIFACTS_ENV)
    if extra:
        dest = Path(extra) / directory.parent.parent.name / directory.parent.name
        dest.mkdir(parents=True, exist_ok=True)
        shutil.copy2(path, dest / path.name)
    return path
