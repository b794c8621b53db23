"""End to end against a `viva-sitl run` process: the run's PX4 ULog downloaded with MAVSDK's log_files plugin and
read with pyulog, and MAV_CMD_PREFLIGHT_CALIBRATION with MAVSDK's calibration plugin and a pymavlink peer."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sitl_process import MavlinkPeer, SitlProcess

pytestmark = pytest.mark.e2e
pyulog = pytest.importorskip("pyulog")

CMD_PREFLIGHT_CALIBRATION = 241
ACCEPTED, TEMPORARILY_REJECTED = 0, 1


def _texts(peer: MavlinkPeer, since_s: float = 0.0) -> list[str]:
    return [str(m.text) for m in peer.messages("STATUSTEXT", since_s=since_s)]


def _wait_text(peer: MavlinkPeer, fragment: str, timeout_s: float, since_s: float) -> Any:
    return peer.wait(
        "STATUSTEXT", lambda m: fragment in str(m.text), timeout_s, since_s=since_s, what=fragment
    )


def test_mavsdk_downloads_the_current_ulog_and_pyulog_reads_the_flight(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer], tmp_path: Path
) -> None:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.log_files import LogFilesAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
    from mavsdk.plugins.log_files import LogFilesResult

    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    out = tmp_path / "downloaded.ulg"

    async def scenario() -> int:
        async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as mavsdk:
            await mavsdk.add_any_connection(sitl.ports.mavsdk_url)
            system = await mavsdk.first_autopilot(timeout_s=15.0)
            assert system is not None, "no autopilot discovered"
            action, telemetry, logs = ActionAsync(system), TelemetryAsync(system), LogFilesAsync(system)
            await action.set_takeoff_altitude(3.0)
            await action.arm()
            await action.takeoff()
            async with asyncio.timeout(60):
                async for position in telemetry.subscribe_position():
                    if position.relative_altitude_m > 2.8:
                        break
            entries = (
                await logs.get_entries()
            )  # the log being written is listed, as PX4 lists its current one
            assert len(entries) == 1 and entries[0].size_bytes > 1000, entries
            results = [r async for r, _ in logs.download_log_file(entries[0], str(out))]
            assert results[-1] == LogFilesResult.SUCCESS
            return int(entries[0].size_bytes)

    size = asyncio.run(scenario())
    data = out.read_bytes()
    assert len(data) == size
    sitl.stop()
    final = (sitl.workdir / f"{sitl.name}-run" / "log.ulg").read_bytes()
    assert final[:size] == data  # the download is the file as it was when listed

    u = pyulog.ULog(str(out))
    names = {d.name for d in u.data_list}
    assert {"vehicle_local_position", "vehicle_global_position", "vehicle_attitude", "vehicle_status",
            "battery_status", "trajectory_setpoint", "failsafe_flags"} <= names, names  # fmt: skip
    for d in u.data_list:
        assert np.all(np.diff(d.data["timestamp"].astype(np.int64)) > 0), d.name
    lp = u.get_dataset("vehicle_local_position").data
    assert lp["z"].min() < -2.7
    assert 2 in set(u.get_dataset("vehicle_status").data["arming_state"])
    # the same flight as the telemetry: LOCAL_POSITION_NED (30 Hz) against the ULog (50 Hz) interpolated to its instants
    t_ulog = lp["timestamp"].astype(np.float64)
    checked = 0
    for m in peer.messages("LOCAL_POSITION_NED"):
        t_us = float(m.time_boot_ms) * 1000.0
        if t_ulog[0] <= t_us <= t_ulog[-1]:
            logged = tuple(float(np.interp(t_us, t_ulog, lp[k])) for k in ("x", "y", "z"))
            assert logged == pytest.approx((m.x, m.y, m.z), abs=0.03), (t_us, logged, (m.x, m.y, m.z))
            checked += 1
    assert checked >= 30, f"only {checked} LOCAL_POSITION_NED samples inside the downloaded log"
    full = pyulog.ULog(str(sitl.workdir / f"{sitl.name}-run" / "log.ulg"))
    assert "Takeoff detected" in [m.message for m in full.logged_messages]


def test_mavsdk_gyro_calibration_completes_and_an_armed_vehicle_refuses(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.calibration import CalibrationAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
    from mavsdk.plugins.calibration import CalibrationError, CalibrationResult

    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    t0 = time.monotonic()

    async def scenario() -> list[float]:
        async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as mavsdk:
            await mavsdk.add_any_connection(sitl.ports.mavsdk_url)
            system = await mavsdk.first_autopilot(timeout_s=15.0)
            assert system is not None, "no autopilot discovered"
            cal, action, telemetry = CalibrationAsync(system), ActionAsync(system), TelemetryAsync(system)
            progress: list[float] = []
            async with asyncio.timeout(30):
                async for result, data in cal.calibrate_gyro():
                    if result == CalibrationResult.NEXT and data.has_progress:
                        progress.append(float(data.progress))
            await action.arm()
            async with asyncio.timeout(10):
                async for armed in telemetry.subscribe_armed():
                    if armed:
                        break
            with pytest.raises(CalibrationError) as err:
                async for _ in cal.calibrate_gyro():
                    pass
            assert err.value.result == CalibrationResult.FAILED_ARMED  # MAVSDK checks locally first
            # the vehicle itself refuses too (a GCS that does not check): PX4 answers TEMPORARILY_REJECTED
            ack = await asyncio.to_thread(peer.command_long, CMD_PREFLIGHT_CALIBRATION, [1.0])
            assert ack.result == TEMPORARILY_REJECTED, ack
            await action.disarm()
            return progress

    progress = asyncio.run(scenario())
    assert progress and progress[-1] == pytest.approx(1.0), progress
    assert progress == sorted(progress) and len(progress) >= 10, progress
    texts = _texts(peer, t0)
    assert "[cal] calibration started: 2 gyro" in texts and "[cal] calibration done: gyro" in texts, texts
    assert texts.index("[cal] calibration started: 2 gyro") < texts.index("[cal] calibration done: gyro")


def test_accel_waits_for_sides_that_never_come_and_fails_as_px4_mag_is_cancelled(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    t0 = time.monotonic()
    ack = peer.command_long(CMD_PREFLIGHT_CALIBRATION, [0, 0, 0, 0, 1])  # accel
    assert ack.result == ACCEPTED, ack
    _wait_text(peer, "[cal] pending: back front left right up", 30, t0)
    busy = peer.command_long(CMD_PREFLIGHT_CALIBRATION, [1])  # gyro while accel runs
    assert busy.result == TEMPORARILY_REJECTED, busy
    arm = peer.command_long(400, [1])  # MAV_CMD_COMPONENT_ARM_DISARM while calibrating: PX4 refuses
    assert arm.result == TEMPORARILY_REJECTED, arm
    _wait_text(peer, "[cal] calibration failed: timeout: no motion", 60, t0)
    texts = _texts(peer, t0)
    order = ["[cal] calibration started: 2 accel", "[cal] down orientation detected", "[cal] progress <17>",
             "[cal] down side done, rotate to a different side", "[cal] down side already completed"]  # fmt: skip
    assert all(t in texts for t in order), texts
    assert [texts.index(t) for t in order] == sorted(texts.index(t) for t in order), texts
    assert texts.count("[cal] down side already completed") == 5, texts

    t1 = time.monotonic()
    assert peer.command_long(CMD_PREFLIGHT_CALIBRATION, [0, 1]).result == ACCEPTED  # mag
    _wait_text(peer, "[cal] Rotate vehicle around the detected", 30, t1)  # 52 chars: 2 chunks
    assert peer.command_long(CMD_PREFLIGHT_CALIBRATION, [0, 0, 0, 0, 0, 0, 0]).result == ACCEPTED  # cancel
    _wait_text(peer, "[cal] calibration cancelled", 10, t1)
    assert not any("calibration done" in t or "calibration failed" in t for t in _texts(peer, t1))
    # and the next calibration starts normally
    t2 = time.monotonic()
    assert peer.command_long(CMD_PREFLIGHT_CALIBRATION, [0, 0, 0, 0, 2]).result == ACCEPTED  # level
    _wait_text(peer, "[cal] calibration done: level", 30, t2)
