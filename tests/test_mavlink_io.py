"""MAVLink I/O over real UDP against a real endpoint: .tlog recording, MAVLink 2 signing (PX4's rules), VFR_HUD
airspeed in wind, battery charge states from BAT_LOW_THR/BAT_CRIT_THR, CAMERA_IMAGE_CAPTURED by index."""

from __future__ import annotations

import hashlib
import struct
import time
from pathlib import Path
from typing import Any

import pytest
from mav_client import MavClient, VehicleThread
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from viva_sitl.mavlink import MavlinkConfig
from viva_sitl.selftest import SnapshotCamera

KEY_HEX = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff"


def _config(client: MavClient, **kw: Any) -> MavlinkConfig:
    base: dict[str, Any] = {
        "api_remote_port": client.port,
        "gcs_remote_port": 0,
        "api_local_port": 0,
        "gcs_local_port": 0,
    }
    base.update(kw)
    return MavlinkConfig(**base)


def _sign(client: MavClient, key: bytes) -> None:
    """Make the client a signing MAVLink 2 peer (pymavlink's own signing)."""
    client.mav.signing.secret_key = key
    client.mav.signing.sign_outgoing = True
    client.mav.signing.link_id = 1
    client.mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)


def _param_read(client: MavClient, name: str, timeout_s: float = 2.0) -> Any:
    client.send(client.mav.param_request_read_encode(1, 1, name.encode(), -1))
    return client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name, timeout_s)


# --- .tlog ---------------------------------------------------------------------------------------------
def test_tlog_records_both_directions_readable_by_pymavlink(client: MavClient, tmp_path: Path) -> None:
    path = tmp_path / "logs" / "run.tlog"
    t_start = time.time()
    with VehicleThread(_config(client, tlog_path=str(path))) as vt:
        client.target = vt.api
        client.send(client.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0))
        assert _param_read(client, "COM_DL_LOSS_T") is not None
        assert client.wait_for("ATTITUDE", 2.0) is not None
        client.poll(0.5)
        stats = vt.stats()
    t_end = time.time()
    assert stats["tlog"]["path"] == str(path) and stats["tlog"]["packets"] > 50
    mlog = mavutil.mavlink_connection(str(path))
    msgs = []
    while (m := mlog.recv_match()) is not None:
        msgs.append(m)
    assert len(msgs) >= stats["tlog"]["packets"]  # (the stats were read a moment before the stop)
    # the file is nothing but records: 8-byte timestamp + one whole MAVLink 2 frame (signed frames: +13 bytes)
    raw = path.read_bytes()
    pos = records = 0
    while pos < len(raw):
        assert raw[pos + 8] == 0xFD, f"record {records}: no MAVLink 2 frame at byte {pos + 8}"
        pos += 8 + 12 + raw[pos + 9] + (13 if raw[pos + 10] & M.MAVLINK_IFLAG_SIGNED else 0)
        records += 1
    assert pos == len(raw) and records == len(msgs)
    kinds_from_vehicle = {m.get_type() for m in msgs if m.get_srcSystem() == 1}
    kinds_from_client = {m.get_type() for m in msgs if m.get_srcSystem() == 255}
    assert {"HEARTBEAT", "ATTITUDE", "PARAM_VALUE", "SYS_STATUS"} <= kinds_from_vehicle
    assert kinds_from_client == {"HEARTBEAT", "PARAM_REQUEST_READ"}
    stamps = [m._timestamp for m in msgs]  # the tlog's 8-byte UNIX time of each packet
    assert all(t_start - 0.01 <= t <= t_end + 0.01 for t in stamps)
    assert stamps == sorted(stamps)
    # the request comes before its answer in the log
    order = [m.get_type() for m in msgs]
    assert order.index("PARAM_REQUEST_READ") < order.index("PARAM_VALUE")
    # the timestamp: 8-byte big-endian microseconds
    (usec,) = struct.unpack(">Q", raw[:8])
    assert abs(usec / 1e6 - stamps[0]) < 1e-3 and raw[8] == 0xFD


# --- signing ---------------------------------------------------------------------------------------------
@pytest.mark.slow  # ported to the sim-clock harness: test_mavlink_harness.py (same name)
def test_signing_accepts_signed_client_rejects_unsigned(tmp_path: Path) -> None:
    key = bytes.fromhex(KEY_HEX)
    signed, unsigned = MavClient(), MavClient()
    try:
        cfg = MavlinkConfig(api_remote_port=signed.port, gcs_remote_port=0, api_local_port=0, gcs_local_port=0,
                            signing_key=KEY_HEX)  # fmt: skip
        with VehicleThread(cfg) as vt:
            signed.target = unsigned.target = vt.api
            _sign(signed, key)
            # a signed client is served...
            pv = _param_read(signed, "COM_DL_LOSS_T")
            assert pv is not None
            ack = signed.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
            assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
            # ...and what the vehicle sends is signed with the key (the client's parser checks it)
            checker = M.MAVLink(None)
            checker.signing.secret_key = key
            hb = signed.wait_for("HEARTBEAT", 3.0)
            assert hb is not None
            frame = bytes(hb.get_msgbuf())
            assert frame[2] & M.MAVLINK_IFLAG_SIGNED
            assert checker.parse_char(frame).get_type() == "HEARTBEAT"  # raises on a bad signature
            before = vt.stats()["unsigned_rejected"]
            # an unsigned client is not: no answer, counted
            assert (
                unsigned.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, timeout_s=1.5)
                is None
            )
            unsigned.send(unsigned.mav.param_request_read_encode(1, 1, b"COM_DL_LOSS_T", -1))
            # a client signing with another key neither
            wrong = MavClient(vt.api)
            _sign(wrong, hashlib.sha256(b"not the key").digest())
            assert (
                wrong.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, timeout_s=1.5)
                is None
            )
            wrong.close()
            # RADIO_STATUS is one of the messages PX4 accepts unsigned
            unsigned.send(unsigned.mav.radio_status_encode(200, 190, 100, 90, 80, 0, 0))
            signed.poll(0.3)
            stats = vt.stats()
        assert stats["unsigned_rejected"] - before == 3
        assert stats["commands"] == 1  # only the signed client's command reached a handler
        assert stats["signing"] == {"key_set": True, "sign_cfg": 1}
        assert not any(m.get_type() == "COMMAND_ACK" for _, m in unsigned.received)
    finally:
        signed.close()
        unsigned.close()


def test_setup_signing_sets_the_key_as_px4(client: MavClient) -> None:
    """MAV_SIGN_CFG 1 with a key: SETUP_SIGNING signed with the current key switches to the new one."""
    old, new = bytes.fromhex(KEY_HEX), hashlib.sha256(b"new key").digest()
    with VehicleThread(_config(client, signing_key=KEY_HEX)) as vt:
        client.target = vt.api
        _sign(client, old)
        assert _param_read(client, "COM_DL_LOSS_T") is not None
        client.send(
            client.mav.setup_signing_encode(1, 1, list(new), int((time.time() - 1420070400) * 100_000))
        )
        assert client.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "signing key set" in m.text, 2.0)
        assert _param_read(client, "COM_DL_LOSS_T", 1.0) is None  # the old key no longer works
        _sign(client, new)
        assert _param_read(client, "COM_DL_LOSS_T") is not None


def test_setup_signing_without_key_when_signing_off(client: MavClient) -> None:
    """MAV_SIGN_CFG 0 (no key configured): everything is accepted, SETUP_SIGNING sets a key, replies get signed."""
    key = hashlib.sha256(b"gcs passphrase").digest()
    with VehicleThread(_config(client)) as vt:
        client.target = vt.api
        assert _param_read(client, "COM_DL_LOSS_T") is not None
        client.send(client.mav.setup_signing_encode(1, 1, list(key), 0))
        assert client.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "signing key set" in m.text, 2.0)
        pv = _param_read(client, "COM_DL_LOSS_T")  # unsigned still accepted (signing optional)...
        assert pv is not None and bytes(pv.get_msgbuf())[2] & M.MAVLINK_IFLAG_SIGNED  # ...answers are signed
        assert vt.stats()["unsigned_rejected"] == 0


# --- telemetry content ---------------------------------------------------------------------------------------
def _set_float(client: MavClient, name: str, value: float) -> None:
    client.send(client.mav.param_set_encode(1, 1, name.encode(), value, M.MAV_PARAM_TYPE_REAL32))
    echo = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name, 2.0)
    assert echo is not None and echo.param_value == pytest.approx(value)


def test_vfr_hud_airspeed_is_relative_to_the_wind(client: MavClient) -> None:
    with VehicleThread(_config(client)) as vt:
        client.target = vt.api
        hud = client.wait_for("VFR_HUD", 2.0)
        assert hud is not None and hud.airspeed == pytest.approx(0.0, abs=0.05)  # still air, on the ground
        _set_float(client, "SIM_WIND_N", 3.0)
        _set_float(client, "SIM_WIND_E", -4.0)
        client.drain()
        hud = client.wait_for("VFR_HUD", 2.0)
    # parked: ground speed 0, the 5 m/s wind blows past it
    assert hud is not None and hud.groundspeed == pytest.approx(0.0, abs=0.05)
    assert hud.airspeed == pytest.approx(5.0, abs=0.05)


def _expected_charge(pct: int, low: float, crit: float) -> int | None:
    frac = pct / 100.0
    if abs(frac - low) <= 0.011 or abs(frac - crit) <= 0.011 or abs(frac - 0.05) <= 0.011:
        return None  # rounding of the percentage: too close to a threshold to judge
    if frac <= 0.05:
        return int(M.MAV_BATTERY_CHARGE_STATE_EMERGENCY)
    if frac <= crit:
        return int(M.MAV_BATTERY_CHARGE_STATE_CRITICAL)
    if frac <= low:
        return int(M.MAV_BATTERY_CHARGE_STATE_LOW)
    return int(M.MAV_BATTERY_CHARGE_STATE_OK)


def test_battery_charge_state_follows_bat_low_and_crit_thr(client: MavClient) -> None:
    low, crit = 0.45, 0.25  # PX4's ranges: BAT_LOW_THR 0.12..0.5, BAT_CRIT_THR 0.05..0.25
    with VehicleThread(_config(client), speed=4.0) as vt:
        client.target = vt.api
        _set_float(client, "BAT_LOW_THR", low)
        _set_float(client, "BAT_CRIT_THR", crit)
        _set_float(client, "SIM_BAT_MIN_PCT", 20.0)
        _set_float(client, "BAT1_CAPACITY", 200.0)  # 200 mAh at 200 A hover: drains in seconds
        ack = client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_BATTERY_STATUS, 50_000)  # 20 Hz
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        _set_float(client, "SIM_BAT_HOV_A", 200.0)
        assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
        nan = float("nan")
        assert (
            client.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, nan).result == M.MAV_RESULT_ACCEPTED
        )  # type: ignore[union-attr]
        got = client.wait_for(lambda m: m.get_type() == "BATTERY_STATUS" and m.battery_remaining <= 22, 40.0)
        assert got is not None, "the battery did not drain"
    batt = [m for _, m in client.received if m.get_type() == "BATTERY_STATUS"]
    judged = [
        (m.battery_remaining, m.charge_state, _expected_charge(m.battery_remaining, low, crit)) for m in batt
    ]
    assert all(state == want for _, state, want in judged if want is not None), [
        j for j in judged if j[2] is not None and j[1] != j[2]
    ]
    states = {state for _, state, _ in judged}
    assert {
        M.MAV_BATTERY_CHARGE_STATE_OK,
        M.MAV_BATTERY_CHARGE_STATE_LOW,
        M.MAV_BATTERY_CHARGE_STATE_CRITICAL,
    } <= states
    texts = [m.text for _, m in client.received if m.get_type() == "STATUSTEXT"]
    assert any("Low battery" in t for t in texts) and any("Critical battery" in t for t in texts), texts


def test_camera_image_captured_by_index_and_stream_info_with_camera_information(
    client: MavClient, tmp_path: Path
) -> None:
    camera = SnapshotCamera(tmp_path / "captures")
    with VehicleThread(_config(client), camera=camera) as vt:
        client.target = vt.api
        ack = client.command(
            M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_INFORMATION, target_component=100
        )
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        vsi = client.wait_for("VIDEO_STREAM_INFORMATION", 1.0)
        assert vsi is not None and vsi.get_srcComponent() == 100 and vsi.uri == "5600"
        for _ in range(3):
            ack = client.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, target_component=100)
            assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
            assert client.wait_for("CAMERA_IMAGE_CAPTURED", 5.0) is not None
        client.drain()
        ack = client.command(
            M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, 1, target_component=100
        )
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        again = client.wait_for("CAMERA_IMAGE_CAPTURED", 1.0)
        ack = client.command(
            M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, 7, target_component=100
        )
        assert ack is not None and ack.result != M.MAV_RESULT_ACCEPTED  # never taken
    assert again is not None and again.image_index == 1 and str(again.file_url).endswith("img_00001.pgm")
    assert camera.captured == [0, 1, 2]


def test_version_encoding_as_px4() -> None:
    from viva_sitl.mavlink.version import custom_version, encode_sw_version

    assert encode_sw_version("1.15.2") == 0x010F02FF  # official release: type 255
    assert encode_sw_version("0.1.0rc2") == 0x000100C0  # rc: 192
    assert encode_sw_version("2.0.1b1") == 0x02000180  # beta: 128
    assert encode_sw_version("2.0.1a3") == 0x02000140  # alpha: 64
    assert encode_sw_version("0.2.0.dev5") == 0x00020000  # dev: 0
    # PX4 copies the 64-bit number of the first 16 hex digits in little-endian order: QGC reads bytes 7..0
    commit = "0123456789abcdef" + "0" * 24
    assert custom_version(commit) == bytes([0xEF, 0xCD, 0xAB, 0x89, 0x67, 0x45, 0x23, 0x01])
    assert custom_version(None) == bytes(8)


def test_signing_key_from_hex_or_passphrase() -> None:
    from viva_sitl.mavlink.signing import parse_key

    assert parse_key(KEY_HEX) == bytes.fromhex(KEY_HEX)
    assert parse_key("0x" + KEY_HEX.upper()) == bytes.fromhex(KEY_HEX)
    assert (
        parse_key("my passphrase") == hashlib.sha256(b"my passphrase").digest()
    )  # MAVProxy's `signing setup`
    with pytest.raises(ValueError, match="must not be empty"):
        parse_key("   ")
    with pytest.raises(ValueError, match="sign_cfg"):
        MavlinkConfig(sign_cfg=3)
