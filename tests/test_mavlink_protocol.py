"""Protocol-level tests of the MAVLink endpoint: a real MavlinkEndpoint over real UDP on 127.0.0.1 (free ports),
driven by the real Autopilot + EAV dynamics (viva_sitl.selftest.SelftestVehicle), and a pymavlink-codec client.
"""

from __future__ import annotations

import math
import struct
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from mav_client import MavClient, Rig, VehicleThread
from pymavlink.dialects.v20 import common as M

import viva_sitl
from viva_sitl.autopilot import FlightMode, ParamStore
from viva_sitl.mavlink import MavlinkConfig
from viva_sitl.selftest import SnapshotCamera

NAN = math.nan


def _config(client: MavClient, **kw: object) -> MavlinkConfig:
    # the client plays MAVSDK's udpin://:14540 (the API link's remote), on a free port; no GCS remote
    base = {"api_remote_port": client.port, "gcs_remote_port": 0, "api_local_port": 0, "gcs_local_port": 0}
    base.update(kw)
    return MavlinkConfig(**base)  # type: ignore[arg-type]


@pytest.fixture
def vehicle(vehicle_factory: Callable[..., VehicleThread], tmp_path: Path) -> VehicleThread:
    return vehicle_factory(camera=SnapshotCamera(tmp_path / "captures"))


@pytest.fixture
def fast_vehicle(vehicle_factory: Callable[..., VehicleThread]) -> VehicleThread:
    """Sim time 4x wall time: flights take seconds."""
    return vehicle_factory(speed=4.0)


@pytest.fixture(params=[pytest.param("udp", marks=pytest.mark.slow), "sim"])
def rig(request: pytest.FixtureRequest, rig_factory: Callable[..., Rig]) -> Rig:
    """Over UDP in real time (slow: seconds of streams), or on the sim-clock harness (the fast tier)."""
    return rig_factory(request.param)


@pytest.fixture(params=[pytest.param("udp", marks=pytest.mark.slow), "sim"])
def fast_rig(request: pytest.FixtureRequest, rig_factory: Callable[..., Rig]) -> Rig:
    """Over UDP at speed 4 (slow: a flight in real time), or on the sim-clock harness (the fast tier)."""
    return rig_factory(request.param, speed=4.0)


def _autopilot_hb(m: M.MAVLink_message) -> bool:
    return m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1


def _seen(client: MavClient, pred: Callable[[M.MAVLink_message], bool], timeout_s: float) -> bool:
    """True if a matching message already arrived or arrives within timeout_s (order-insensitive)."""
    return any(pred(m) for _, m in client.received) or client.wait_for(pred, timeout_s) is not None


# --- discovery ------------------------------------------------------------------------------------------------


def test_heartbeat_is_px4_quadrotor_in_hold(client: MavClient, vehicle: VehicleThread) -> None:
    hb = client.wait_for(_autopilot_hb, 3.0)
    assert hb is not None, "no autopilot HEARTBEAT within 3 s"
    assert hb.get_srcSystem() == 1
    assert hb.type == M.MAV_TYPE_QUADROTOR
    assert hb.autopilot == M.MAV_AUTOPILOT_PX4
    assert hb.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.custom_mode == FlightMode.AUTO_LOITER.custom_mode == 50593792
    assert hb.system_status == M.MAV_STATE_STANDBY
    # 1 Hz: at least 2 more autopilot heartbeats within 2.5 s
    client.poll(2.5)
    n = sum(1 for _, m in client.received if _autopilot_hb(m))
    assert n >= 3


def test_autopilot_version_via_request_message_and_legacy_command(
    client: MavClient, vehicle: VehicleThread
) -> None:
    ack = client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    assert ack.target_system == 255 and ack.target_component == 190
    ver = client.wait_for("AUTOPILOT_VERSION", 1.0) or next(
        (m for _, m in client.received if m.get_type() == "AUTOPILOT_VERSION"), None
    )
    assert ver is not None
    needed = (
        M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
        | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
        | M.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
        | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
        | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
        | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
        | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    )
    assert ver.capabilities & needed == needed
    # the package version in PX4's encoding: major<<24 | minor<<16 | patch<<8 | type (255 = official release)
    major, minor, patch = (int(x) for x in viva_sitl.__version__.split(".")[:3])
    sw = ver.flight_sw_version
    assert (sw >> 24, (sw >> 16) & 0xFF, (sw >> 8) & 0xFF, sw & 0xFF) == (major, minor, patch, 255)
    # the commit of this checkout, as PX4 stores it: the first 16 hex digits as a little-endian uint64
    head = subprocess.run(
        ["git", "-C", str(Path(viva_sitl.__file__).parents[1]), "rev-parse", "HEAD"],
        capture_output=True, text=True, check=False,
    ).stdout.strip()  # fmt: skip
    if head:
        assert bytes(reversed(bytes(ver.flight_custom_version))).hex() == head[:16]
    else:
        assert bytes(ver.flight_custom_version) == bytes(8)
    client.received.clear()
    ack = client.command(M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    assert client.wait_for("AUTOPILOT_VERSION", 1.0) is not None or any(
        m.get_type() == "AUTOPILOT_VERSION" for _, m in client.received
    )


def test_home_position_on_request(client: MavClient, vehicle: VehicleThread) -> None:
    ack = client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    home = client.wait_for("HOME_POSITION", 1.0) or next(
        (m for _, m in client.received if m.get_type() == "HOME_POSITION"), None
    )
    assert home is not None
    assert home.latitude == pytest.approx(47.397742e7, abs=10)  # GeoOrigin default, vehicle at the origin
    assert home.longitude == pytest.approx(8.545594e7, abs=10)
    assert home.altitude == pytest.approx(488000, abs=10)


def test_health_bits_mavsdk_reads(client: MavClient, vehicle: VehicleThread) -> None:
    st = client.wait_for("SYS_STATUS", 2.0)
    assert st is not None
    for bit in (M.MAV_SYS_STATUS_SENSOR_3D_GYRO, M.MAV_SYS_STATUS_SENSOR_3D_ACCEL, M.MAV_SYS_STATUS_SENSOR_3D_MAG,
                M.MAV_SYS_STATUS_SENSOR_GPS, M.MAV_SYS_STATUS_PREARM_CHECK):  # fmt: skip
        assert st.onboard_control_sensors_present & bit
        assert st.onboard_control_sensors_enabled & bit
        assert st.onboard_control_sensors_health & bit, f"bit {bit:#x} unhealthy on the ground"
    assert 0 <= st.battery_remaining <= 100
    gps = client.wait_for("GPS_RAW_INT", 2.0)
    assert gps is not None and gps.fix_type == 3


# --- parameters -----------------------------------------------------------------------------------------------


def test_param_list_has_every_index_once(client: MavClient, vehicle: VehicleThread) -> None:
    expected = ParamStore().names()
    assert len(expected) > 1000
    t0 = time.monotonic()
    client.send(client.mav.param_request_list_encode(1, 1))
    first = client.wait_for("PARAM_VALUE", 1.0)
    # PX4 answers with the _HASH_CHECK first (index -1 on the wire = 65535, UINT32), QGC's cache key
    assert first is not None and first.param_id == "_HASH_CHECK"
    assert first.param_index == 65535 and first.param_type == M.MAV_PARAM_TYPE_UINT32
    assert first.param_count == len(expected)
    values: dict[int, M.MAVLink_message] = {}
    # a PING answered while the list streams: the loop is not blocked
    client.send(client.mav.ping_encode(123, 7, 0, 0))
    ping_answered_after: int | None = None
    while len(values) < len(expected) or ping_answered_after is None:
        msg = client.wait_for(lambda m: m.get_type() in ("PARAM_VALUE", "PING"), 2.0)
        assert msg is not None, f"list stalled after {len(values)} of {len(expected)}"
        if msg.get_type() == "PING":
            ping_answered_after = len(values) if msg.seq == 7 else ping_answered_after
            continue
        assert msg.param_count == len(expected)
        assert msg.param_index not in values, f"index {msg.param_index} twice"
        values[msg.param_index] = msg
    elapsed = time.monotonic() - t0
    assert sorted(values) == list(range(len(expected)))
    assert [values[i].param_id for i in range(len(expected))] == expected
    mis = values[expected.index("MIS_TAKEOFF_ALT")]
    assert mis.param_type == M.MAV_PARAM_TYPE_REAL32 and mis.param_value == pytest.approx(2.5)
    assert vehicle.stats()["param_list_values_sent"] == len(expected)  # each one once, no duplicates
    auto = values[expected.index("SYS_AUTOSTART")]
    assert auto.param_type == M.MAV_PARAM_TYPE_INT32 and _float_as_int(auto.param_value) == 4001
    # paced (20 per 10 ms, as PX4's bursts), not one loop-blocking flood; and still quick
    assert ping_answered_after is not None and ping_answered_after < len(expected) // 2
    assert elapsed > 0.3, f"{len(expected)} parameters in {elapsed:.3f} s: not paced"
    assert elapsed < 10.0


def test_param_list_restart_and_hash_stop(client: MavClient, vehicle: VehicleThread) -> None:
    n = len(ParamStore())
    client.send(client.mav.param_request_list_encode(1, 1))
    assert client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_index == 10, 2.0) is not None
    # QGC's "my cache matches": PARAM_SET _HASH_CHECK stops the stream; nothing like the full list follows
    client.send(client.mav.param_set_encode(1, 1, b"_HASH_CHECK", 0.0, M.MAV_PARAM_TYPE_UINT32))
    client.drain()
    tail = [m for m in client.poll(0.5) if m.get_type() == "PARAM_VALUE"]
    assert len(tail) < n // 2, f"{len(tail)} PARAM_VALUEs after _HASH_CHECK"
    # a new request lists everything again
    client.drain()
    client.send(client.mav.param_request_list_encode(1, 1))
    last = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_index == n - 1, 5.0)
    assert last is not None


def _int_as_float(v: int) -> float:
    return float(struct.unpack("<f", struct.pack("<i", v))[0])


def _float_as_int(f: float) -> int:
    return int(struct.unpack("<i", struct.pack("<f", f))[0])


@pytest.mark.slow  # ported to the sim-clock harness: test_mavlink_harness.py::test_param_set_float_and_int32_bytewise
def test_param_set_float_and_int32_bytewise(client: MavClient, vehicle: VehicleThread) -> None:
    client.send(client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 5.5, M.MAV_PARAM_TYPE_REAL32))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT", 1.0)
    assert pv is not None and pv.param_value == pytest.approx(5.5)
    assert vehicle.call(lambda: vehicle.vehicle.params.get("MIS_TAKEOFF_ALT")) == pytest.approx(5.5)

    # INT32: the integer's bytes travel in the float field (PX4 bytewise encoding)
    client.send(client.mav.param_set_encode(1, 1, b"NAV_DLL_ACT", _int_as_float(2), M.MAV_PARAM_TYPE_INT32))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "NAV_DLL_ACT", 1.0)
    assert pv is not None and pv.param_type == M.MAV_PARAM_TYPE_INT32
    assert _float_as_int(pv.param_value) == 2
    assert vehicle.call(lambda: vehicle.vehicle.params.get("NAV_DLL_ACT")) == 2

    # read back by name and by index
    client.send(client.mav.param_request_read_encode(1, 1, b"NAV_DLL_ACT", -1))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "NAV_DLL_ACT", 1.0)
    assert pv is not None and _float_as_int(pv.param_value) == 2
    idx = ParamStore().names().index("MIS_TAKEOFF_ALT")
    client.send(client.mav.param_request_read_encode(1, 1, b"", idx))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_index == idx, 1.0)
    assert pv is not None and pv.param_id == "MIS_TAKEOFF_ALT" and pv.param_value == pytest.approx(5.5)


@pytest.mark.slow  # ported to the sim-clock harness: test_mavlink_harness.py::test_param_rejections_as_px4
def test_param_rejections_as_px4(client: MavClient, vehicle: VehicleThread) -> None:
    # unknown name: no PARAM_VALUE, a STATUSTEXT (PX4: "[pm] unknown param")
    client.send(client.mav.param_set_encode(1, 1, b"NO_SUCH_PARAM", 1.0, M.MAV_PARAM_TYPE_REAL32))
    text = client.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "unknown param" in m.text, 1.0)
    assert text is not None and "NO_SUCH_PARAM" in text.text
    assert not any(m.get_type() == "PARAM_VALUE" for _, m in client.received)
    client.send(client.mav.param_request_read_encode(1, 1, b"NO_SUCH_PARAM", -1))
    assert client.wait_for("PARAM_VALUE", 0.5) is None

    # type mismatch: REAL32 write to an INT32 parameter changes nothing
    client.send(client.mav.param_set_encode(1, 1, b"NAV_DLL_ACT", 3.0, M.MAV_PARAM_TYPE_REAL32))
    assert client.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "mismatch" in m.text, 1.0) is not None
    assert vehicle.call(lambda: vehicle.vehicle.params.get("NAV_DLL_ACT")) == 0

    # out of range: stored and echoed as PX4 does (PX4 does not enforce min/max; the GCS warns)
    client.send(client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 1e6, M.MAV_PARAM_TYPE_REAL32))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT", 1.0)
    assert pv is not None and pv.param_value == pytest.approx(1e6)
    client.send(client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 2.5, M.MAV_PARAM_TYPE_REAL32))
    # (the 1e6 change is also re-announced ~5 ms later, as PX4's send_untransmitted: wait for the new value)
    pv = client.wait_for(
        lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT" and m.param_value == 2.5,
        1.0,
    )
    assert pv is not None and pv.param_value == pytest.approx(2.5)

    # index beyond the list: no PARAM_VALUE, a STATUSTEXT
    client.drain()
    client.send(client.mav.param_request_read_encode(1, 1, b"", len(ParamStore())))
    got = client.poll(0.5)
    assert any(m.get_type() == "STATUSTEXT" and "unknown param" in m.text for m in got)
    assert not any(m.get_type() == "PARAM_VALUE" for m in got)

    # NaN value
    client.send(client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", NAN, M.MAV_PARAM_TYPE_REAL32))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT", 1.0)
    assert pv is not None and pv.param_value == pytest.approx(2.5)


# --- streams --------------------------------------------------------------------------------------------------


def _rate(client: Any, msg_type: str, seconds: float) -> float:
    client.received.clear()
    client.poll(seconds)
    times = [t for t, m in client.received if m.get_type() == msg_type]
    if len(times) < 2:
        return 0.0
    return (len(times) - 1) / (times[-1] - times[0])


@pytest.mark.slow  # ported to the sim-clock harness: test_mavlink_harness.py::test_default_rates_and_set_message_interval
def test_default_rates_and_set_message_interval(client: MavClient, vehicle: VehicleThread) -> None:
    client.poll(0.3)
    assert _rate(client, "ATTITUDE", 1.5) == pytest.approx(100.0, rel=0.3)
    ack = client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, 100_000)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    assert _rate(client, "ATTITUDE_QUATERNION", 2.0) == pytest.approx(10.0, rel=0.25)
    ack = client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, -1)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    client.poll(0.1)
    assert _rate(client, "ATTITUDE_QUATERNION", 1.0) == 0.0
    ack = client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, 0)  # default
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    assert _rate(client, "ATTITUDE_QUATERNION", 1.5) == pytest.approx(50.0, rel=0.3)
    # a message it cannot produce
    ack = client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HIL_SENSOR, 100_000)
    assert ack is not None and ack.result == M.MAV_RESULT_UNSUPPORTED
    # GET via REQUEST_MESSAGE(MESSAGE_INTERVAL, p2 = message id)
    client.received.clear()
    ack = client.command(
        M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE
    )
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    mi = client.wait_for("MESSAGE_INTERVAL", 1.0) or next(
        (m for _, m in client.received if m.get_type() == "MESSAGE_INTERVAL"), None
    )
    assert mi is not None and mi.message_id == M.MAVLINK_MSG_ID_ATTITUDE and mi.interval_us == 10_000


@pytest.mark.slow  # ported to the sim-clock harness: test_mavlink_harness.py::test_ping_and_timesync_answered
def test_ping_and_timesync_answered(client: MavClient, vehicle: VehicleThread) -> None:
    client.send(client.mav.ping_encode(123456789, 42, 0, 0))
    ping = client.wait_for("PING", 1.0)
    assert ping is not None
    assert (ping.time_usec, ping.seq, ping.target_system, ping.target_component) == (123456789, 42, 255, 190)
    client.send(client.mav.timesync_encode(0, 987654321))
    ts = client.wait_for(lambda m: m.get_type() == "TIMESYNC" and m.ts1 == 987654321, 1.0)
    assert ts is not None and ts.tc1 > 0
    # a PING addressed to us is a reply to a ping we never sent: no answer
    client.send(client.mav.ping_encode(1, 43, 1, 1))
    assert client.wait_for("PING", 0.5) is None


def test_gcs_link_answers_whoever_talks(client: MavClient, vehicle: VehicleThread) -> None:
    gcs = MavClient(target=vehicle.gcs, sysid=254, compid=190)
    try:
        assert (
            gcs.wait_for("HEARTBEAT", 0.5) is None
        )  # no default GCS remote in this config: silent until we talk
        gcs.send(gcs.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE))
        assert gcs.wait_for(_autopilot_hb, 2.5) is not None
        ack = gcs.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert ack is not None and ack.target_system == 254
        # the GCS link streams the onboard rates by default (ATTITUDE 100 Hz)
        assert _rate(gcs, "ATTITUDE", 1.5) == pytest.approx(100.0, rel=0.3)
        assert vehicle.call(
            lambda: vehicle.vehicle.autopilot.commander.gcs_seen
        )  # GCS heartbeat reached the autopilot
    finally:
        gcs.close()


def test_gcs_link_normal_profile_option(client: MavClient) -> None:
    with VehicleThread(_config(client, gcs_profile="normal")) as vt:
        gcs = MavClient(target=vt.gcs, sysid=254, compid=190)
        try:
            gcs.send(
                gcs.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
            )
            # PX4's "normal" mavlink mode: ATTITUDE ~15 Hz, GLOBAL_POSITION_INT ~5 Hz
            assert 8.0 < _rate(gcs, "ATTITUDE", 1.5) < 25.0
        finally:
            gcs.close()


# --- commands -------------------------------------------------------------------------------------------------


@pytest.mark.slow  # ported to the sim-clock harness: test_mavlink_harness.py::test_every_command_is_acked
def test_every_command_is_acked(client: MavClient, vehicle: VehicleThread) -> None:
    def ack(cmd: int, *p: float, **kw: int) -> int:
        a = client.command(cmd, *p, timeout_s=0.5, **kw)
        assert a is not None, f"no COMMAND_ACK for command {cmd} within 0.5 s"
        return int(a.result)

    assert ack(M.MAV_CMD_NAV_TAKEOFF, *[NAN] * 7) == M.MAV_RESULT_DENIED  # not armed
    assert any(m.get_type() == "STATUSTEXT" and "not armed" in m.text for _, m in client.received)
    assert ack(M.MAV_CMD_MISSION_START, 0, 0) == M.MAV_RESULT_DENIED  # no mission
    assert ack(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_TEMPORARILY_REJECTED  # offboard w/o setpoints
    assert ack(M.MAV_CMD_DO_REPOSITION, -1, 1, 0, NAN, NAN, NAN, NAN) == M.MAV_RESULT_DENIED  # not armed
    assert ack(M.MAV_CMD_DO_CHANGE_SPEED, 1, 3.0, -1) == M.MAV_RESULT_ACCEPTED
    assert ack(M.MAV_CMD_DO_CHANGE_SPEED, 1, -2.0, -1) == M.MAV_RESULT_ACCEPTED  # back to default
    assert ack(M.MAV_CMD_DO_CHANGE_SPEED, 1, 0.0, -1) == M.MAV_RESULT_DENIED
    assert ack(M.MAV_CMD_DO_SET_MODE, 129, 4, 3) == M.MAV_RESULT_ACCEPTED  # Hold, base_mode 129 is not "arm"
    assert not vehicle.call(lambda: vehicle.vehicle.autopilot.armed)
    assert ack(M.MAV_CMD_DO_SET_MODE, 1, 99, 0) == M.MAV_RESULT_DENIED  # unknown mode
    assert ack(31999, 1, 2, 3) == M.MAV_RESULT_UNSUPPORTED
    assert ack(M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == M.MAV_RESULT_UNSUPPORTED
    assert ack(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, NAN) == M.MAV_RESULT_ACCEPTED  # MAVSDK: param2 NaN
    assert ack(M.MAV_CMD_NAV_RETURN_TO_LAUNCH) == M.MAV_RESULT_ACCEPTED
    assert ack(M.MAV_CMD_NAV_LAND, *[NAN] * 7) == M.MAV_RESULT_ACCEPTED
    assert ack(M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196) == M.MAV_RESULT_ACCEPTED  # kill
    assert not vehicle.call(lambda: vehicle.vehicle.autopilot.armed)
    # COMMAND_INT gets its ACK too
    client.send(
        client.mav.command_int_encode(
            1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 31998, 0, 0, 0, 0, 0, 0, 0, 0, 0
        )
    )
    a = client.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == 31998, 0.5)
    assert a is not None and a.result == M.MAV_RESULT_UNSUPPORTED
    # SET_MODE message: answered like DO_SET_MODE
    client.send(client.mav.set_mode_encode(1, 1, FlightMode.AUTO_RTL.custom_mode))
    a = client.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == M.MAV_CMD_DO_SET_MODE, 0.5)
    assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
    assert _seen(client, lambda m: _autopilot_hb(m) and m.custom_mode == FlightMode.AUTO_RTL.custom_mode, 1.5)
    # a command for another system or component is not ours: silence
    assert client.command(M.MAV_CMD_NAV_LAND, target_system=7, timeout_s=0.4) is None
    assert client.command(M.MAV_CMD_NAV_LAND, target_component=55, timeout_s=0.4) is None


def test_arm_takeoff_land_seen_in_telemetry(client: MavClient, fast_vehicle: VehicleThread) -> None:
    client.send(client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 3.0, M.MAV_PARAM_TYPE_REAL32))
    assert client.wait_for("PARAM_VALUE", 1.0) is not None
    a = client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, NAN)
    assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
    hb = client.wait_for(lambda m: _autopilot_hb(m) and m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, 1.5)
    assert hb is not None and hb.system_status == M.MAV_STATE_ACTIVE
    a = client.command(M.MAV_CMD_NAV_TAKEOFF, *[NAN] * 7)
    assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
    assert (
        client.wait_for(lambda m: m.get_type() == "EXTENDED_SYS_STATE" and m.landed_state == 3, 2.0)
        is not None
    )
    assert _seen(
        client, lambda m: _autopilot_hb(m) and m.custom_mode == FlightMode.AUTO_TAKEOFF.custom_mode, 2.0
    )
    # climbs to MIS_TAKEOFF_ALT (3 m) and holds
    top = client.wait_for(lambda m: m.get_type() == "GLOBAL_POSITION_INT" and m.relative_alt > 2900, 6.0)
    assert top is not None
    assert (
        client.wait_for(lambda m: m.get_type() == "EXTENDED_SYS_STATE" and m.landed_state == 2, 3.0)
        is not None
    )
    lp = client.wait_for("LOCAL_POSITION_NED", 1.0)
    assert lp is not None and lp.z == pytest.approx(-3.0, abs=0.3)
    assert top.alt == pytest.approx(488000 + 3000, abs=300)  # AMSL = home 488 m + 3 m
    assert abs(top.lat - 473977420) < 20 and abs(top.lon - 85455940) < 20  # climbed straight up
    a = client.command(M.MAV_CMD_NAV_LAND, *[NAN] * 7)
    assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
    assert (
        client.wait_for(lambda m: m.get_type() == "EXTENDED_SYS_STATE" and m.landed_state == 4, 2.0)
        is not None
    )
    assert (
        client.wait_for(lambda m: m.get_type() == "EXTENDED_SYS_STATE" and m.landed_state == 1, 10.0)
        is not None
    )
    # auto-disarm after landing (COM_DISARM_LAND 2 s sim = 0.5 s wall at 4x)
    hb = client.wait_for(lambda m: _autopilot_hb(m) and not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, 3.0)
    assert hb is not None
    texts = [m.text for _, m in client.received if m.get_type() == "STATUSTEXT"]
    assert any("Landing detected" in t for t in texts), texts


def test_takeoff_amsl_altitude_then_reposition_command_int(fast_rig: Rig) -> None:
    client = fast_rig.client
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
    # COMMAND_LONG NAV_TAKEOFF param7 is AMSL (PX4): home 488 m + 4.5 m
    ack = client.command(M.MAV_CMD_NAV_TAKEOFF, NAN, NAN, NAN, NAN, NAN, NAN, 488.0 + 4.5)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    top = client.wait_for(lambda m: m.get_type() == "GLOBAL_POSITION_INT" and m.relative_alt > 4300, 8.0)
    assert top is not None
    assert client.wait_for(lambda m: m.get_type() == "EXTENDED_SYS_STATE" and m.landed_state == 2, 3.0)
    lp = client.wait_for("LOCAL_POSITION_NED", 1.0)
    assert lp is not None and lp.z == pytest.approx(-4.5, abs=0.3)
    geo = fast_rig.call(lambda: fast_rig.vehicle.geo)
    lat, lon, _ = geo.ned_to_global(8.0, -4.0, 0.0)
    client.send(client.mav.command_int_encode(
        1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_DO_REPOSITION, 0, 0,
        -1, 1, 0, NAN, round(lat * 1e7), round(lon * 1e7), 4.0,
    ))  # fmt: skip
    a = client.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == M.MAV_CMD_DO_REPOSITION, 3.0)
    assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
    lp = client.wait_for(
        lambda m: (
            m.get_type() == "LOCAL_POSITION_NED"
            and abs(m.x - 8) < 0.3
            and abs(m.y + 4) < 0.3
            and abs(m.z + 4) < 0.3
        ),
        12.0,
    )
    assert lp is not None, "did not reach the DO_REPOSITION target (8, -4, -4)"


def test_highres_imu_on_request_as_mavsdk_set_rate_imu(rig: Rig) -> None:
    """MAVSDK's telemetry.set_rate_imu (its highres_imu example) sends SET_MESSAGE_INTERVAL(HIGHRES_IMU): PX4 streams
    it; a vehicle at rest on the ground reads -g on the accelerometer's z, no rotation, ISA pressure at home."""
    client = rig.client
    client.poll(0.3)
    assert _rate(client, "HIGHRES_IMU", 0.5) == 0.0  # not in the default streams
    ack = client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HIGHRES_IMU, 20_000)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    assert _rate(client, "HIGHRES_IMU", 1.5) == pytest.approx(50.0, rel=0.3)
    imu = [m for _, m in client.received if m.get_type() == "HIGHRES_IMU"][-1]
    assert imu.zacc == pytest.approx(-9.81, abs=0.1) and abs(imu.xacc) < 0.1 and abs(imu.yacc) < 0.1
    assert max(abs(imu.xgyro), abs(imu.ygyro), abs(imu.zgyro)) < 0.01
    assert 0.3 < math.sqrt(imu.xmag**2 + imu.ymag**2 + imu.zmag**2) < 0.6  # gauss
    assert imu.abs_pressure == pytest.approx(955.5, abs=2.0)  # hPa at PX4's default home, 488 m AMSL
    assert imu.fields_updated == 0x1FFF
