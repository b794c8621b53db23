"""One clock: telemetry rates, SET_MESSAGE_INTERVAL, heartbeats and MAVLink-visible failsafe timers run on SIM time, so
`--speed N` changes only the wall clock (as PX4 lockstep SITL). A real endpoint + vehicle over real UDP: the rate tests
run the vehicle in its own process (`python -m viva_sitl.selftest`), so this client, reading 1000+ messages a
wall second at 4x, never competes with it for the interpreter.

Sim time is read from the messages themselves (ATTITUDE.time_boot_ms is the vehicle's simulation clock).
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import signal
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from mav_client import MavClient, VehicleThread
from pymavlink.dialects.v20 import common as M
from sitl_process import REPO_ROOT

from viva_sitl.autopilot import FlightMode
from viva_sitl.mavlink import MavlinkConfig
from viva_sitl.selftest import SnapshotCamera

SPEEDS = [
    pytest.param(1.0, marks=pytest.mark.slow),
    4.0,
]  # the 4x variant checks the same in a quarter of the time


def _config(client: MavClient) -> MavlinkConfig:
    return MavlinkConfig(api_remote_port=client.port, gcs_remote_port=0, api_local_port=0, gcs_local_port=0)


@contextlib.contextmanager
def _vehicle_process(client: MavClient, speed: float) -> Iterator[subprocess.Popen[str]]:
    cmd = [sys.executable, "-m", "viva_sitl.selftest", "--speed", str(speed), "--api-remote-port",
           str(client.port), "--gcs-remote-port", "0", "--api-local-port", "0", "--gcs-local-port", "0"]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    try:
        assert proc.stdout is not None
        ready = json.loads(proc.stdout.readline() or "{}")
        assert ready.get("ready"), "the selftest vehicle did not start"
        client.target = (str(ready["api"][0]), int(ready["api"][1]))
        yield proc
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5.0)


def _collect_sim_span(client: MavClient, span_ms: int, wall_timeout_s: float) -> list[tuple[float, Any]]:
    """Poll until ATTITUDE covers `span_ms` of sim time; return (wall, msg) of everything read meanwhile. The wall
    times are arrival times: Python's garbage collector is off meanwhile, so that a collection of this test process
    (large by the end of a full suite) cannot hold the first reads back and shorten the wall span (a suspected cause of
    sim/wall 5.6-5.7 against 4 +- 0.8 at --speed 4, twice in full suites, never with the file alone)."""
    start = len(client.received)
    deadline = time.monotonic() + wall_timeout_s
    first: int | None = None
    gc_was_on = gc.isenabled()
    gc.disable()
    try:
        while time.monotonic() < deadline:
            client.poll(0.05)
            att = [m for _, m in client.received[start:] if m.get_type() == "ATTITUDE"]
            if att:
                first = int(att[0].time_boot_ms) if first is None else first
                if int(att[-1].time_boot_ms) - first >= span_ms:
                    return client.received[start:]
    finally:
        if gc_was_on:
            gc.enable()
    pytest.fail(f"ATTITUDE did not cover {span_ms} ms of sim time within {wall_timeout_s} s wall")


def _rate_per_sim_s(window: list[tuple[float, Any]], kind: str) -> tuple[float, int]:
    msgs = [m for _, m in window if m.get_type() == kind]
    times = [int(m.time_boot_ms) for m in msgs]
    assert len(set(times)) == len(times), f"{kind}: the same sim instant sent twice"
    return (len(times) - 1) / ((times[-1] - times[0]) / 1000.0), len(times)


@pytest.mark.parametrize("speed", SPEEDS)
def test_telemetry_rates_are_per_sim_second(client: MavClient, speed: float) -> None:
    with _vehicle_process(client, speed):
        client.send(client.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0))
        client.poll(0.3)  # let the link settle
        window = _collect_sim_span(client, 4000, 30.0)
    att_hz, n_att = _rate_per_sim_s(window, "ATTITUDE")
    gpi_hz, _ = _rate_per_sim_s(window, "GLOBAL_POSITION_INT")
    lpn_hz, _ = _rate_per_sim_s(window, "LOCAL_POSITION_NED")
    # PX4's onboard profile: ATTITUDE 100 Hz, GLOBAL_POSITION_INT 50 Hz, LOCAL_POSITION_NED 30 Hz per SIM second
    assert att_hz == pytest.approx(100.0, rel=0.03)
    assert gpi_hz == pytest.approx(50.0, rel=0.03)
    assert lpn_hz == pytest.approx(30.0, rel=0.04)
    # heartbeats: 1 per sim second too (4 sim seconds: 4, give or take the one at each end)
    att = [(w, m) for w, m in window if m.get_type() == "ATTITUDE"]
    w0, w1 = att[0][0], att[-1][0]
    hbs = [
        m for w, m in window if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1 and w0 <= w <= w1
    ]
    assert 3 <= len(hbs) <= 5
    # ...and what --speed changes is the wall clock: 4 sim seconds took 4/speed wall seconds
    sim_s = (int(att[-1][1].time_boot_ms) - int(att[0][1].time_boot_ms)) / 1000.0
    wall_s = w1 - w0
    assert sim_s / wall_s == pytest.approx(speed, rel=0.2)
    assert (n_att - 1) / wall_s == pytest.approx(100.0 * speed, rel=0.2)  # 400 ATTITUDE per wall second at 4x


def test_slow_simulation_still_heartbeats_once_a_wall_second(client: MavClient) -> None:
    """At --speed 0.25 a 1 Hz sim-time heartbeat would come every 4 wall seconds, past MAVSDK's 3 s timeout: the
    endpoint also heartbeats at least once a wall second."""
    with VehicleThread(_config(client), speed=0.25) as vt:
        client.target = vt.api
        client.poll(0.5)
        start = len(client.received)
        t0 = time.monotonic()
        client.poll(4.0)
        wall_s = time.monotonic() - t0
        window = client.received[start:]
    hb_wall = [w for w, m in window if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1]
    att = [m for _, m in window if m.get_type() == "ATTITUDE"]
    sim_s = (att[-1].time_boot_ms - att[0].time_boot_ms) / 1000.0
    assert sim_s == pytest.approx(0.25 * wall_s, rel=0.25)  # the simulation did run slowly
    assert len(hb_wall) >= 3 and max(b - a for a, b in zip(hb_wall, hb_wall[1:], strict=False)) < 1.5
    att_hz, _ = _rate_per_sim_s(window, "ATTITUDE")
    assert att_hz == pytest.approx(100.0, rel=0.05)  # still 100 per sim second


@pytest.mark.parametrize("speed", SPEEDS)
def test_set_message_interval_is_per_sim_second(client: MavClient, speed: float) -> None:
    with _vehicle_process(client, speed):
        client.poll(0.2)
        ack = client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 40_000)  # 25 Hz
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        ack = client.command(
            M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE
        )
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        iv = client.wait_for("MESSAGE_INTERVAL", 2.0)
        assert iv is not None and iv.message_id == M.MAVLINK_MSG_ID_ATTITUDE and iv.interval_us == 40_000
        client.poll(0.1)
        window = _collect_sim_span(client, 4000, 30.0)
    att_hz, _ = _rate_per_sim_s(window, "ATTITUDE")
    assert att_hz == pytest.approx(25.0, rel=0.04)


@pytest.mark.parametrize("speed", SPEEDS)
def test_interval_capture_is_per_sim_second(client: MavClient, speed: float, tmp_path: Path) -> None:
    camera = SnapshotCamera(tmp_path / "captures")
    with VehicleThread(_config(client), speed=speed, camera=camera) as vt:
        client.target = vt.api
        ack = client.command(
            M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0.5, 5, target_component=100
        )  # every 0.5 s, 5 images
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        caps = []
        deadline = time.monotonic() + 20.0
        while len(caps) < 5 and time.monotonic() < deadline:
            msg = client.wait_for("CAMERA_IMAGE_CAPTURED", 1.0)
            if msg is not None:
                caps.append(msg)
    assert [c.image_index for c in caps] == [0, 1, 2, 3, 4]
    gaps_s = [(b.time_boot_ms - a.time_boot_ms) / 1000.0 for a, b in zip(caps, caps[1:], strict=False)]
    assert gaps_s == pytest.approx([0.5] * 4, abs=0.005)  # sim seconds (wall time would give 0.5 * speed)


# --- failsafe timers ------------------------------------------------------------------------------------
def _set_param(client: MavClient, name: str, value: float, int32: bool) -> float:
    wire = struct.unpack("<f", struct.pack("<i", int(value)))[0] if int32 else float(value)
    ptype = M.MAV_PARAM_TYPE_INT32 if int32 else M.MAV_PARAM_TYPE_REAL32
    client.send(client.mav.param_set_encode(1, 1, name.encode(), wire, ptype))
    echo = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name, 3.0)
    assert echo is not None, f"no PARAM_VALUE for {name}"
    return float(struct.unpack("<i", struct.pack("<f", echo.param_value))[0]) if int32 else echo.param_value


def _autopilot_mode(m: Any) -> int | None:
    if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1:
        return int(m.custom_mode)
    return None


def _send_stamped(client: MavClient, msg: Any) -> int:
    """Send `msg` and a TIMESYNC request in ONE datagram: the vehicle handles them in order and answers the
    TIMESYNC with its simulation clock, i.e. the sim time (ms) at which `msg` was received."""
    ts1 = time.monotonic_ns()
    frames = msg.pack(client.mav)
    client.mav.seq = (client.mav.seq + 1) % 256
    frames += client.mav.timesync_encode(0, ts1).pack(client.mav)
    client.mav.seq = (client.mav.seq + 1) % 256
    client.send_raw(frames)
    reply = client.wait_for(lambda m: m.get_type() == "TIMESYNC" and m.ts1 == ts1 and m.tc1 > 0, 3.0)
    assert reply is not None, "no TIMESYNC answer"
    return int(reply.tc1) // 1_000_000


class Watch:
    """What the client has seen so far, updated incrementally (the client must keep up with 1000+ msgs/s)."""

    def __init__(self, client: MavClient) -> None:
        self.client = client
        self.cursor = 0
        self.sim_ms = -1  # latest ATTITUDE.time_boot_ms
        self.mode: int | None = None
        self.rel_alt_mm = 0
        self.texts: list[str] = []
        self.mode_changes: list[tuple[int, int]] = []  # (sim ms of the ATTITUDE before it, new mode)

    def update(self) -> None:
        received = self.client.received
        for _, m in received[self.cursor :]:
            kind = m.get_type()
            if kind == "ATTITUDE":
                self.sim_ms = int(m.time_boot_ms)
            elif kind == "GLOBAL_POSITION_INT":
                self.rel_alt_mm = int(m.relative_alt)
            elif kind == "STATUSTEXT":
                self.texts.append(str(m.text))
            mode = _autopilot_mode(m)
            if mode is not None and mode != self.mode:
                self.mode = mode
                self.mode_changes.append((self.sim_ms, mode))
        self.cursor = len(received)

    def pump_until(
        self,
        pred: Callable[[], bool],
        wall_timeout_s: float,
        send: Callable[[], None] | None = None,
        hz: float = 1.0,
    ) -> None:
        """Poll (and call `send` at `hz` wall) until pred() holds."""
        deadline = time.monotonic() + wall_timeout_s
        next_send = 0.0
        self.update()
        while not pred():
            now = time.monotonic()
            if now > deadline:
                pytest.fail(
                    f"condition not reached in {wall_timeout_s} s; mode {self.mode}, texts {self.texts}"
                )
            if send is not None and now >= next_send:
                send()
                next_send = now + 1.0 / hz
            self.client.poll(0.02)
            self.update()

    def catch_up(self) -> int:
        """Read everything already queued: returns the vehicle's sim time now (ms), to within a few steps."""
        while len(self.client.poll(0.002)) >= 5:
            pass
        self.update()
        return self.sim_ms


@pytest.mark.parametrize("speed", SPEEDS)
def test_gcs_link_loss_failsafe_after_com_dl_loss_t_sim_seconds(
    client: MavClient, vehicle_factory: Callable[..., VehicleThread], speed: float
) -> None:
    vt = vehicle_factory(speed=speed)
    watch = Watch(client)
    gcs_hb = client.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
    land = FlightMode.AUTO_LAND.custom_mode
    try:
        client.send(gcs_hb)
        assert _set_param(client, "NAV_DLL_ACT", 3, int32=True) == 3  # Land
        assert _set_param(client, "COM_DL_LOSS_T", 5, int32=True) == 5
        ack = client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        nan = float("nan")
        ack = client.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, nan)  # to MIS_TAKEOFF_ALT (2.5 m)
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        watch.pump_until(
            lambda: watch.rel_alt_mm > 2000 and watch.mode == FlightMode.AUTO_LOITER.custom_mode,
            60.0,
            lambda: client.send(gcs_hb),
            hz=4.0,  # every 0.25 wall s: at most 1 sim s apart at 4x, far inside COM_DL_LOSS_T
        )
        last_hb_ms = _send_stamped(client, gcs_hb)  # the last GCS heartbeat: the link is lost from here
        n_changes = len(watch.mode_changes)
        watch.pump_until(lambda: watch.mode == land, 30.0 / speed + 10.0)
    finally:
        vt.stop()
    assert any("ground station lost" in t for t in watch.texts), watch.texts
    lost_ms, mode = watch.mode_changes[n_changes]
    assert mode == land
    elapsed_s = (lost_ms - last_hb_ms) / 1000.0
    # COM_DL_LOSS_T = 5 SIM seconds at any speed (on the wall clock it would be 20 sim seconds at 4x)
    assert 5.0 - 0.06 <= elapsed_s <= 5.0 + 0.15, elapsed_s


@pytest.mark.parametrize("speed", SPEEDS)
def test_offboard_loss_failsafe_after_com_of_loss_t_sim_seconds(
    client: MavClient, vehicle_factory: Callable[..., VehicleThread], speed: float
) -> None:
    vt = vehicle_factory(speed=speed)
    watch = Watch(client)
    hover = client.mav.set_position_target_local_ned_encode(
        0, 1, 1, M.MAV_FRAME_LOCAL_NED, 2552, 0.0, 0.0, -3.0, 0, 0, 0, 0, 0, 0, 0.0, 0
    )
    offboard = FlightMode.OFFBOARD.custom_mode
    try:
        assert _set_param(client, "COM_OF_LOSS_T", 2.0, int32=False) == pytest.approx(2.0)
        t_end = time.monotonic() + 0.5
        watch.pump_until(lambda: time.monotonic() > t_end, 5.0, lambda: client.send(hover), hz=20.0)
        ack = client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        client.send(hover)
        ack = client.command(M.MAV_CMD_DO_SET_MODE, 129, 6, 0)  # OFFBOARD
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        sim_start = watch.catch_up()
        # fly on the stream for 1.5 sim s (a setpoint every 50 ms wall: far inside COM_OF_LOSS_T at any speed)
        watch.pump_until(
            lambda: watch.mode == offboard and watch.sim_ms - sim_start > 1500,
            20.0,
            lambda: client.send(hover),
            20.0,
        )
        last_sp_ms = _send_stamped(client, hover)  # the last setpoint
        n_changes = len(watch.mode_changes)
        watch.pump_until(lambda: watch.mode != offboard, 20.0 / speed + 10.0)
    finally:
        vt.stop()
    lost_ms, _ = watch.mode_changes[n_changes]
    elapsed_s = (lost_ms - last_sp_ms) / 1000.0
    # COM_OF_LOSS_T = 2 SIM seconds at any speed
    assert 2.0 - 0.06 <= elapsed_s <= 2.0 + 0.15, elapsed_s
