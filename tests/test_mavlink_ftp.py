"""MAVLink FTP: the vehicle's empty read-only file system answers every request at once, so real FTP clients fall
back instead of timing out. Driven with pymavlink's own MAVFTP client (what MAVProxy's ftp and parameter modules use)
and with raw FILE_TRANSFER_PROTOCOL messages, against a real MavlinkEndpoint over UDP on 127.0.0.1."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import pytest
from mav_client import MavClient, VehicleThread
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from viva_sitl.mavlink import MavlinkConfig

mavftp = pytest.importorskip("pymavlink.mavftp", reason="pymavlink without mavftp (needs >= 2.4.41)")

HEADER = struct.Struct("<HBBBBBBI")


@pytest.fixture
def vehicle() -> Iterator[VehicleThread]:
    cfg = MavlinkConfig(api_remote_port=0, gcs_remote_port=0, api_local_port=0, gcs_local_port=0)
    with VehicleThread(cfg) as vt:
        yield vt


def _ftp_stat(vt: VehicleThread) -> tuple[int, int]:
    return vt.call(lambda: (vt.endpoint.ftp.requests, vt.endpoint.ftp.naks))


@pytest.fixture
def master(vehicle: VehicleThread) -> Iterator[mavutil.mavfile]:
    host, port = vehicle.api
    conn = mavutil.mavlink_connection(f"udpout:{host}:{port}", source_system=255, source_component=190)
    conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)  # now the vehicle knows us
    assert conn.wait_heartbeat(timeout=5) is not None
    yield conn
    conn.close()


def test_pymavlink_mavftp_gets_file_not_found_on_the_first_try(
    vehicle: VehicleThread, master: mavutil.mavfile, tmp_path: Path
) -> None:
    # pymavlink's defaults except a shorter idle detection (it ends a failed get after that much FTP silence)
    settings = mavftp.MAVFTPSettings(
        [
            ("debug", int, 0),
            ("pkt_loss_tx", int, 0),
            ("pkt_loss_rx", int, 0),
            ("max_backlog", int, 5),
            ("burst_read_size", int, 80),
            ("write_size", int, 80),
            ("write_qsize", int, 5),
            ("idle_detection_time", float, 1.2),
            ("read_retry_time", float, 1.0),
            ("retry_time", float, 0.5),
        ]
    )
    ftp = mavftp.MAVFTP(
        master, target_system=1, target_component=1, settings=settings
    )  # ResetSessions -> ACK
    assert _ftp_stat(vehicle) == (1, 0)  # the reset was answered with an ACK, not retried

    # MAVProxy's parameter download opens @PARAM/param.pck; QGC opens the component-metadata JSON
    for path in ("@PARAM/param.pck?withdefaults=1", "/etc/extras/component_general.json.xz"):
        before = _ftp_stat(vehicle)
        ftp.cmd_get([path, str(tmp_path / "out.bin")])
        ret = ftp.process_ftp_reply("OpenFileRO", timeout=10)
        assert ret.error_code == mavftp.FtpError.FileNotFound, ret.error_code
        after = _ftp_stat(vehicle)
        assert after[1] - before[1] >= 1  # at least one NAK
        # one OpenFileRO, no retries (a missing reply makes the client retry every retry_time)
        assert after[0] - before[0] <= 2, f"{after[0] - before[0]} requests for one open: retried"
        assert not (tmp_path / "out.bin").exists() or (tmp_path / "out.bin").stat().st_size == 0

    listing = ftp.cmd_list(["/"])  # an empty root directory
    assert listing.error_code == mavftp.FtpError.Success
    assert ftp.list_result == []
    missing = ftp.cmd_list(["/fs/microsd/log"])
    assert missing.error_code == mavftp.FtpError.FileNotFound


def _request(
    client: MavClient, seq: int, opcode: int, data: bytes = b"", session: int = 0
) -> M.MAVLink_message:
    payload = (HEADER.pack(seq, session, opcode, len(data), 0, 0, 0, 0) + data).ljust(251, b"\0")
    client.send(client.mav.file_transfer_protocol_encode(0, 1, 1, list(payload)))
    reply = client.wait_for(lambda m: m.get_type() == "FILE_TRANSFER_PROTOCOL", 2.0)
    assert reply is not None, f"no answer to opcode {opcode}"
    return reply


@pytest.mark.parametrize(
    ("opcode", "data", "expect"),
    [
        (2, b"", (128, None)),  # ResetSessions -> ACK
        (1, b"", (128, None)),  # TerminateSession -> ACK
        (4, b"/etc/params\0", (129, 10)),  # OpenFileRO -> FileNotFound
        (14, b"/etc/params\0", (129, 10)),  # CalcFileCRC32 -> FileNotFound
        (3, b"/\0", (129, 6)),  # ListDirectory of the root -> EOF (empty)
        (5, b"", (129, 4)),  # ReadFile without a session -> InvalidSession
        (15, b"", (129, 4)),  # BurstReadFile -> InvalidSession
        (6, b"/x.txt\0", (129, 9)),  # CreateFile -> FileProtected
        (8, b"/x.txt\0", (129, 9)),  # RemoveFile -> FileProtected
        (99, b"", (129, 7)),  # unknown opcode -> UnknownCommand
    ],
)
def test_raw_requests_get_protocol_conforming_answers(
    vehicle: VehicleThread, opcode: int, data: bytes, expect: tuple[int, int | None]
) -> None:
    client = MavClient(target=vehicle.api)
    try:
        reply = _request(client, 41, opcode, data, session=3)
        assert reply.target_system == 255 and reply.target_component == 190  # addressed to the asker
        seq, session, op, size, req_opcode, _burst, _pad, _offset = HEADER.unpack_from(bytes(reply.payload))
        assert seq == 42 and session == 3 and req_opcode == opcode
        assert op == expect[0]
        if expect[1] is None:
            assert size == 0
        else:
            assert size == 1 and reply.payload[HEADER.size] == expect[1]
    finally:
        client.close()


def test_short_or_foreign_ftp_messages_are_ignored(
    vehicle: VehicleThread, caplog: pytest.LogCaptureFixture
) -> None:
    client = MavClient(target=vehicle.api)
    try:
        # addressed to another system: not ours to answer
        payload = HEADER.pack(1, 0, 4, 0, 0, 0, 0, 0).ljust(251, b"\0")
        client.send(client.mav.file_transfer_protocol_encode(0, 7, 1, list(payload)))
        # an ACK (another server's reply) is never answered
        client.send(
            client.mav.file_transfer_protocol_encode(
                0, 1, 1, list(HEADER.pack(1, 0, 128, 0, 4, 0, 0, 0).ljust(251, b"\0"))
            )
        )
        got = client.poll(0.5)
        assert not any(m.get_type() == "FILE_TRANSFER_PROTOCOL" for m in got)
        assert _ftp_stat(vehicle) == (0, 0)
        assert vehicle.call(lambda: vehicle.endpoint.stats["handler_errors"]) == 0
    finally:
        client.close()


@pytest.mark.parametrize("msgid", [397, 395])  # COMPONENT_METADATA, COMPONENT_INFORMATION
def test_component_metadata_requests_get_a_prompt_unsupported(vehicle: VehicleThread, msgid: int) -> None:
    """QGroundControl asks for the component metadata first; a clean refusal makes it use its built-in PX4 data."""
    client = MavClient(target=vehicle.api)
    try:
        ack = client.command(M.MAV_CMD_REQUEST_MESSAGE, float(msgid), timeout_s=1.0)
        assert ack is not None, "no COMMAND_ACK"
        assert ack.command == M.MAV_CMD_REQUEST_MESSAGE and ack.result == M.MAV_RESULT_UNSUPPORTED
    finally:
        client.close()
