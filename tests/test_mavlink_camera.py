"""MAVLink camera protocol (compid 100) over real UDP, as MAVSDK's camera plugin and QGC use it: heartbeat,
CAMERA_INFORMATION / VIDEO_STREAM_INFORMATION discovery, settings/status/storage, image capture with the pose."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import pytest
from mav_client import MavClient, Rig, VehicleThread
from pymavlink.dialects.v20 import common as M

from viva_sitl.mavlink import CaptureResult, MavlinkConfig
from viva_sitl.mavlink.camera_link import DEFAULT_CAMERA_INFO
from viva_sitl.selftest import SnapshotCamera

CAM = 100


def _cfg(client: MavClient) -> MavlinkConfig:
    return MavlinkConfig(api_remote_port=client.port, gcs_remote_port=0, api_local_port=0, gcs_local_port=0)


@pytest.fixture
def camera(tmp_path: Path) -> SnapshotCamera:
    return SnapshotCamera(tmp_path / "captures")


@pytest.fixture
def vehicle(vehicle_factory: Callable[..., VehicleThread], camera: SnapshotCamera) -> VehicleThread:
    return vehicle_factory(camera=camera)


def _request(
    client: MavClient, msgid: int, *params: float, component: int = CAM
) -> tuple[M.MAVLink_message, list[M.MAVLink_message]]:
    ack = client.command(M.MAV_CMD_REQUEST_MESSAGE, msgid, *params, target_component=component)
    assert ack is not None, f"no ACK for REQUEST_MESSAGE {msgid} to component {component}"
    client.poll(0.2)
    return ack, [m for _, m in client.received if m.get_msgId() == msgid]


def test_camera_heartbeat(client: MavClient, vehicle: VehicleThread) -> None:
    hb = client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == CAM, 2.5)
    assert hb is not None
    assert (
        hb.get_srcSystem() == 1 and hb.type == M.MAV_TYPE_CAMERA and hb.autopilot == M.MAV_AUTOPILOT_INVALID
    )


def test_camera_information_and_video_stream(client: MavClient, vehicle: VehicleThread) -> None:
    ack, infos = _request(client, M.MAVLINK_MSG_ID_CAMERA_INFORMATION)
    assert ack.result == M.MAV_RESULT_ACCEPTED and ack.get_srcComponent() == CAM
    assert len(infos) == 1 and infos[0].get_srcComponent() == CAM
    info = infos[0]
    assert info.flags & M.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM and info.flags & M.CAMERA_CAP_FLAGS_CAPTURE_IMAGE
    assert (info.resolution_h, info.resolution_v) == (640, 480)
    assert bytes(info.vendor_name).rstrip(b"\0") == b"viva-sitl"

    client.received.clear()
    ack, streams = _request(client, M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, 0)
    assert ack.result == M.MAV_RESULT_ACCEPTED and len(streams) == 1
    vs = streams[0]
    assert vs.uri == "5600"  # RTP/UDP: the port alone (QGC builds udp://0.0.0.0:5600)
    assert vs.type == M.VIDEO_STREAM_TYPE_RTPUDP and vs.encoding == M.VIDEO_STREAM_ENCODING_H264
    assert vs.flags & M.VIDEO_STREAM_STATUS_FLAGS_RUNNING and vs.stream_id == 1 and vs.count == 1
    assert vs.framerate == pytest.approx(30.0) and vs.hfov == 82

    for msgid in (M.MAVLINK_MSG_ID_CAMERA_SETTINGS, M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS,
                  M.MAVLINK_MSG_ID_STORAGE_INFORMATION, M.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS):  # fmt: skip
        client.received.clear()
        ack, got = _request(client, msgid)
        assert ack.result == M.MAV_RESULT_ACCEPTED and len(got) == 1, msgid


def test_legacy_requests_and_broadcast_and_autopilot_refusal(
    client: MavClient, vehicle: VehicleThread
) -> None:
    ack = client.command(M.MAV_CMD_REQUEST_CAMERA_INFORMATION, 1, target_component=CAM)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    assert client.wait_for("CAMERA_INFORMATION", 1.0) is not None
    ack = client.command(M.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION, 0, target_component=CAM)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    assert client.wait_for("VIDEO_STREAM_INFORMATION", 1.0) is not None
    # broadcast (component 0): the camera answers, the autopilot stays quiet
    client.received.clear()
    ack, infos = _request(client, M.MAVLINK_MSG_ID_CAMERA_INFORMATION, component=0)
    assert ack.get_srcComponent() == CAM and ack.result == M.MAV_RESULT_ACCEPTED and len(infos) == 1
    acks = [m for _, m in client.received if m.get_type() == "COMMAND_ACK"]
    assert len(acks) == 1
    # asked of the autopilot (MAVSDK asks every component): UNSUPPORTED from component 1
    ack = client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_INFORMATION, target_component=1)
    assert ack is not None and ack.result == M.MAV_RESULT_UNSUPPORTED and ack.get_srcComponent() == 1
    # an unknown camera command
    ack = client.command(M.MAV_CMD_VIDEO_START_CAPTURE, 0, 1, target_component=CAM)
    assert ack is not None and ack.result == M.MAV_RESULT_UNSUPPORTED and ack.get_srcComponent() == CAM


def test_image_capture_single_and_interval(
    client: MavClient, vehicle: VehicleThread, camera: SnapshotCamera
) -> None:
    ack = client.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1, target_component=CAM)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    cap = client.wait_for("CAMERA_IMAGE_CAPTURED", 2.0)
    assert cap is not None and cap.get_srcComponent() == CAM
    assert cap.image_index == 0 and cap.capture_result == 1
    assert cap.file_url.startswith("file://")
    path = Path(cap.file_url[len("file://") :])
    assert path.is_file() and path.read_bytes().startswith(b"P5")
    assert cap.lat == pytest.approx(473977420, abs=20) and cap.lon == pytest.approx(85455940, abs=20)
    assert cap.alt == pytest.approx(488000, abs=50) and cap.relative_alt == pytest.approx(0, abs=50)
    assert math.isclose(math.fsum(q * q for q in cap.q), 1.0, rel_tol=1e-5)

    # 3 images, 0.1 s apart
    ack = client.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0.1, 3, 0, target_component=CAM)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    idx = []
    for _ in range(3):
        m = client.wait_for("CAMERA_IMAGE_CAPTURED", 2.0)
        assert m is not None
        idx.append(m.image_index)
    assert idx == [1, 2, 3]
    assert camera.captured == [0, 1, 2, 3]
    ack = client.command(M.MAV_CMD_IMAGE_STOP_CAPTURE, 0, target_component=CAM)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    client.received.clear()
    _, status = _request(client, M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS)
    assert status[0].image_count == 4 and status[0].image_status == 0


@pytest.fixture(params=[pytest.param("udp", marks=pytest.mark.slow), "sim"])
def camera_less(request: pytest.FixtureRequest, rig_factory: Callable[..., Rig]) -> Rig:
    """A vehicle without a camera over UDP (slow: 2 s of listening for silence) or on the sim-clock harness."""
    return rig_factory(request.param)


def test_no_camera_no_component(camera_less: Rig) -> None:
    client = camera_less.client
    client.poll(1.5)
    assert not any(m.get_srcComponent() == CAM for _, m in client.received)
    assert client.command(M.MAV_CMD_REQUEST_MESSAGE, 259, target_component=CAM, timeout_s=0.5) is None


class _CaptureOnly:
    """A camera link that cannot describe itself (e.g. an app written before camera_info existed)."""

    def capture_image(self, seq: int) -> CaptureResult:
        return CaptureResult(ok=False, path="", meta=None)


def test_camera_without_info_advertises_defaults_and_reports_failed_capture(client: MavClient) -> None:
    with VehicleThread(_cfg(client), camera=_CaptureOnly()) as vt:  # type: ignore[arg-type]
        client.target = vt.api
        ack, infos = _request(client, M.MAVLINK_MSG_ID_CAMERA_INFORMATION)
        assert ack.result == M.MAV_RESULT_ACCEPTED
        assert (infos[0].resolution_h, infos[0].resolution_v) == (
            DEFAULT_CAMERA_INFO.width_px,
            DEFAULT_CAMERA_INFO.height_px,
        )
        ack = client.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1, target_component=CAM)
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        cap = client.wait_for("CAMERA_IMAGE_CAPTURED", 2.0)
        assert cap is not None and cap.capture_result == 0 and cap.file_url == ""
        assert vt.stats()["handler_errors"] == 0
