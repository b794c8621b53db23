"""The MAVLink log protocol (viva_sitl/mavlink/logs.py) against a real MavlinkEndpoint over UDP, with pymavlink as
the client: listing, download, and PX4's answers to bad input (offset past the end, unknown id, data before a
list), LOG_REQUEST_END and LOG_ERASE."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mav_client import VehicleThread
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from viva_sitl.mavlink import MavlinkConfig


@pytest.fixture
def vehicle() -> Iterator[VehicleThread]:
    cfg = MavlinkConfig(api_remote_port=0, gcs_remote_port=0, api_local_port=0, gcs_local_port=0)
    with VehicleThread(cfg) as vt:
        yield vt


@pytest.fixture
def master(vehicle: VehicleThread) -> Iterator[mavutil.mavfile]:
    host, port = vehicle.api
    conn = mavutil.mavlink_connection(f"udpout:{host}:{port}", source_system=255, source_component=190)
    conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    assert conn.wait_heartbeat(timeout=5) is not None
    yield conn
    conn.close()


def _collect(conn: mavutil.mavfile, kind: str, quiet_s: float = 0.5, timeout_s: float = 10.0) -> list[Any]:
    """Messages of `kind` until none came for `quiet_s`."""
    out: list[Any] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = conn.recv_match(type=kind, blocking=True, timeout=quiet_s)
        if msg is None:
            break
        out.append(msg)
    return out


def _logs(vehicle: VehicleThread, files: list[tuple[Path, bool]]) -> None:
    vehicle.call(lambda: vehicle.endpoint.logs.set_source(lambda: list(files)))


def _download(conn: mavutil.mavfile, log_id: int, size: int) -> bytes:
    conn.mav.log_request_data_send(1, 1, log_id, 0, size)
    data = bytearray()
    for msg in _collect(conn, "LOG_DATA"):
        assert msg.id == log_id and msg.ofs == len(data), (msg.ofs, len(data))
        data += bytes(msg.data[: msg.count])
    return bytes(data)


def test_no_logs_is_one_entry_with_num_logs_0(vehicle: VehicleThread, master: mavutil.mavfile) -> None:
    master.mav.log_request_list_send(1, 1, 0, 0xFFFF)
    entries = _collect(master, "LOG_ENTRY")
    assert [(e.id, e.num_logs, e.last_log_num, e.size) for e in entries] == [(0, 0, 0, 0)]


@pytest.mark.slow  # ported to the sim-clock harness: test_mavlink_harness.py (same name)
def test_list_and_download_logs_and_the_bad_requests_px4_ignores(
    vehicle: VehicleThread, master: mavutil.mavfile, tmp_path: Path
) -> None:
    old = tmp_path / "old.ulg"
    old.write_bytes(bytes(range(256)) * 3 + b"tail")  # 772 bytes: 8 full LOG_DATA and a short one
    cur = tmp_path / "log.ulg"
    cur.write_bytes(b"ULog" * 50)
    _logs(vehicle, [(old, False), (cur, True)])

    master.mav.log_request_data_send(1, 1, 0, 0, 100)  # before any list: PX4 does not answer
    assert _collect(master, "LOG_DATA") == []

    master.mav.log_request_list_send(1, 1, 0, 0xFFFF)
    entries = _collect(master, "LOG_ENTRY")
    assert [(e.id, e.num_logs, e.last_log_num, e.size) for e in entries] == [(0, 2, 1, 772), (1, 2, 1, 200)]
    assert abs(entries[0].time_utc - old.stat().st_mtime) <= 1

    assert _download(master, 0, 772) == old.read_bytes()
    assert _download(master, 1, 0xFFFFFFFF) == cur.read_bytes()

    # a part of a log, from an offset
    master.mav.log_request_data_send(1, 1, 0, 180, 100)
    parts = _collect(master, "LOG_DATA")
    assert [(m.ofs, m.count) for m in parts] == [(180, 90), (270, 10)]
    assert bytes(parts[0].data[:90]) + bytes(parts[1].data[:10]) == old.read_bytes()[180:280]

    # past the end: one LOG_DATA with count 0 at the offset (PX4)
    master.mav.log_request_data_send(1, 1, 0, 5000, 90)
    assert [(m.id, m.ofs, m.count) for m in _collect(master, "LOG_DATA")] == [(0, 5000, 0)]

    # unknown id: no answer (PX4)
    master.mav.log_request_data_send(1, 1, 7, 0, 90)
    assert _collect(master, "LOG_DATA") == []

    # the log being written grows: a new list shows its new size
    cur.write_bytes(b"ULog" * 60)
    master.mav.log_request_list_send(1, 1, 0, 0xFFFF)
    assert [e.size for e in _collect(master, "LOG_ENTRY")] == [772, 240]

    # a range of the list
    master.mav.log_request_list_send(1, 1, 1, 1)
    assert [(e.id, e.num_logs, e.last_log_num) for e in _collect(master, "LOG_ENTRY")] == [(1, 2, 1)]

    # LOG_REQUEST_END forgets the list: data requests go unanswered until the next list
    master.mav.log_request_end_send(1, 1)
    time.sleep(0.2)
    master.mav.log_request_data_send(1, 1, 0, 0, 90)
    assert _collect(master, "LOG_DATA") == []


def test_erase_deletes_finished_logs_and_keeps_the_one_being_written(
    vehicle: VehicleThread, master: mavutil.mavfile, tmp_path: Path
) -> None:
    old, cur = tmp_path / "old.ulg", tmp_path / "log.ulg"
    old.write_bytes(b"x" * 10)
    cur.write_bytes(b"y" * 10)
    _logs(vehicle, [(old, False), (cur, True)])
    master.mav.log_erase_send(1, 1)
    deadline = time.monotonic() + 5
    while old.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not old.exists() and cur.exists()
    _logs(vehicle, [(cur, True)])
    master.mav.log_request_list_send(1, 1, 0, 0xFFFF)
    assert [(e.id, e.num_logs, e.size) for e in _collect(master, "LOG_ENTRY")] == [(0, 1, 10)]
