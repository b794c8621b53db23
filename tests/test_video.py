"""Video outputs: real RTP receivers (PyAV, OpenCV/FFmpeg) decode the streams, the frame-and-pose socket, dropping."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable
from contextlib import closing
from dataclasses import replace
from pathlib import Path
from typing import Any

import av
import cv2
import numpy as np
import pytest
import zmq

from viva_sitl.frame import FrameMeta, RenderedFrame
from viva_sitl.video import (
    FrameClient,
    FrameEncoding,
    FramePublisher,
    FrameScheduler,
    VideoConfig,
    VideoPipeline,
    decode_message,
    encode_message,
    h264_sdp,
    jpeg_sdp,
    read_counter,
    stamp_counter,
)
from viva_sitl.video.receiver import OPENCV_CAPTURE_OPTIONS, RtpReceiver

W, H = 480, 320
FPS = 30


# -- helpers ---------------------------------------------------------------------------------------------------------
def free_rtp_port() -> int:
    """An even UDP port p on 127.0.0.1 with p + 1 also free (RTP + RTCP), found by binding port 0."""
    for _ in range(200):
        with closing(socket.socket(socket.AF_INET, socket.SOCK_DGRAM)) as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if port % 2 or port > 65000:
            continue
        try:
            with (
                closing(socket.socket(socket.AF_INET, socket.SOCK_DGRAM)) as a,
                closing(socket.socket(socket.AF_INET, socket.SOCK_DGRAM)) as b,
            ):
                a.bind(("127.0.0.1", port))
                b.bind(("127.0.0.1", port + 1))
        except OSError:
            continue
        return port
    raise RuntimeError("no free RTP port pair")


def make_meta(counter: int, wall_time_s: float, w: int = W, h: int = H) -> FrameMeta:
    return FrameMeta(
        frame_counter=counter,
        sim_time_s=counter / FPS,
        wall_time_s=wall_time_s,
        pos_ned_m=(1.5 * counter, -2.0, -30.0),
        att_rpy_rad=(0.01, -0.02, 0.5),
        vel_ned_m_s=(1.5 * FPS, 0.0, 0.0),
        footage_frame_index=counter // 2,
        width_px=w,
        height_px=h,
        intrinsics_k=((400.0, 0.0, w / 2), (0.0, 400.0, h / 2), (0.0, 0.0, 1.0)),
        cam_rot_body=((0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        cam_pos_body_m=(0.1, 0.0, 0.05),
        coverage=1.0,
        lat_deg=47.39,
        lon_deg=8.54,
        alt_amsl_m=None,
    )


_YY, _XX = np.mgrid[0:H, 0:W].astype(np.float32)
_NOISE = np.random.default_rng(7).integers(0, 256, (H, 2 * W), dtype=np.uint8)
# detail in luma, smooth colour (like aerial footage; 4:2:0 chroma would blur colour noise below any PSNR bound)
_TEXTURE = cv2.GaussianBlur(_NOISE, (0, 0), 2.0).astype(np.float32)
_TINT = np.stack([0.3 * _XX / W, 0.3 * _YY / H, 0.3 * (1 - _XX / W)], axis=2)


def synthetic_image(counter: int) -> np.ndarray:
    """A scene that moves with the counter: a scrolling texture, a colour gradient and a bright moving disc."""
    shift = (6 * counter) % W
    tex = _TEXTURE[:, shift : shift + W, None]
    img = np.clip(tex * (0.7 + _TINT) + 20.0, 0, 255).astype(np.uint8)
    cx = int((40 + 5 * counter) % (W - 40)) + 20
    cv2.circle(img, (cx, H // 2), 30, (255, 255, 255), -1)
    return img


def synthetic_frame(counter: int) -> RenderedFrame:
    return RenderedFrame(synthetic_image(counter), make_meta(counter, time.time()))


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(255.0**2 / mse)


def config(tmp_path: Path, **kw: object) -> VideoConfig:
    base = VideoConfig(
        h264_port=free_rtp_port(),
        mjpeg_port=free_rtp_port(),
        frame_socket_endpoint="tcp://127.0.0.1:*",
        sdp_dir=str(tmp_path),
        stamp_counter=True,
    )
    return replace(base, **kw)  # type: ignore[arg-type]


class Collector:
    """Runs an RtpReceiver on a thread; keeps (counter at join, [(decode wall time, counter, image)])."""

    def __init__(self, sdp: Path, n_frames: int, counter_now: list[int]) -> None:
        self.sdp, self.n_frames, self.counter_now = sdp, n_frames, counter_now
        self.join_counter = -1
        self.frames: list[tuple[float, int | None, np.ndarray]] = []
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            self.join_counter = self.counter_now[0]
            with RtpReceiver(self.sdp, timeout_s=5.0) as rx:
                for wall, img in rx.frames():
                    self.frames.append((wall, read_counter(img), img))
                    if len(self.frames) >= self.n_frames:
                        break
        except BaseException as exc:  # reported by the test
            self.error = exc

    def join(self, timeout_s: float) -> None:
        self.thread.join(timeout_s)
        assert not self.thread.is_alive(), "receiver did not finish"
        assert self.error is None, f"receiver failed: {self.error!r}"


def run_stream(pipeline: VideoPipeline, counter_now: list[int]) -> FrameScheduler:
    """Feed synthetic frames at FPS through a FrameScheduler (counter = tick) until its stop()."""

    def render(tick: int) -> RenderedFrame:
        counter_now[0] = tick
        return synthetic_frame(tick)

    sched = FrameScheduler(render, pipeline.submit, FPS)
    sched.start()
    return sched


def wait_until(cond: Callable[[], bool], timeout_s: float, what: str) -> None:
    """Poll `cond` until it holds; fail naming `what` after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, f"timed out after {timeout_s} s waiting for {what}"
        time.sleep(0.005)  # polling interval


def submit_and_wait_written(pipe: VideoPipeline, frame: RenderedFrame, timeout_s: float = 10.0) -> None:
    """Submit `frame` once every output has written the previous ones, then wait until they wrote it too: with
    nothing waiting in any queue, no frame can be dropped, so the outputs see exactly the submitted sequence."""
    before = pipe.stats()["outputs"]
    assert pipe.submit(frame), "an output queue was not empty"
    n = pipe.stats()["submitted"]
    wait_until(
        lambda: all(o["sent"] + o["dropped"] + o["errors"] >= n for o in pipe.stats()["outputs"].values()),
        timeout_s,
        f"frame {frame.meta.frame_counter} handled by every output",
    )
    after = pipe.stats()["outputs"]
    for name, o in after.items():
        assert (o["dropped"], o["errors"]) == (before[name]["dropped"], before[name]["errors"]), (name, o)


def wait_for_first_frame(client: FrameClient, pipe: VideoPipeline, timeout_s: float = 10.0) -> None:
    """ZeroMQ's slow joiner: publish a probe frame until the subscription has reached the publisher, then drain."""
    probe = synthetic_frame(999)
    deadline = time.monotonic() + timeout_s
    while client.receive(timeout_s=0.05) is None:
        assert time.monotonic() < deadline, "the frame socket subscription never reached the publisher"
        pipe.submit(probe)
    while client.receive(timeout_s=0.2) is not None:
        pass


# -- config, SDP, stamp ----------------------------------------------------------------------------------------------
def test_config_defaults_validation_and_instances() -> None:
    c = VideoConfig()
    assert (c.h264_port, c.mjpeg_port, c.fps, c.gop) == (5600, 5602, 30, 30)
    assert c.frame_socket_encoding is FrameEncoding.RAW
    assert VideoConfig(frame_socket_encoding="jpeg").frame_socket_encoding is FrameEncoding.JPEG  # type: ignore[arg-type]
    c2 = c.with_instance(2)
    assert (c2.h264_port, c2.mjpeg_port, c2.frame_socket_endpoint) == (5608, 5610, "tcp://127.0.0.1:5702")
    assert VideoConfig(record_path="/tmp/a.mp4").with_instance(1).record_path == "/tmp/a-1.mp4"
    assert c.with_instance(0) is c
    for bad in (
        {"fps": 0},
        {"queue_size": 0},
        {"queue_size": 100},
        {"jpeg_quality": 101},
        {"h264_port": 70000},
        {"mjpeg_rtp": True, "mjpeg_port": 5601},
        {"x264_preset": "warp"},
        {"record_path": "out.avi"},
        {"frame_socket_encoding": "png"},
        {"host": ""},
    ):
        with pytest.raises(ValueError):
            VideoConfig(**bad)  # type: ignore[arg-type]


def test_sdp_text() -> None:
    s = h264_sdp("127.0.0.1", 5600, 30)
    assert "m=video 5600 RTP/AVP 96\r\n" in s
    assert "a=rtpmap:96 H264/90000\r\n" in s and "a=fmtp:96 packetization-mode=1\r\n" in s
    assert "c=IN IP4 127.0.0.1\r\n" in s
    j = jpeg_sdp("::1", 5602, 30)
    assert "m=video 5602 RTP/AVP 26\r\n" in j and "c=IN IP6 ::1\r\n" in j


def test_stamp_survives_jpeg_and_rejects_unstamped() -> None:
    rng = np.random.default_rng(1)
    for counter in (0, 1, 12345, 2**24 - 1):
        img = synthetic_image(counter % 50)
        stamp_counter(img, counter)
        ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 40])
        assert ok
        decoded = cv2.imdecode(jpg, cv2.IMREAD_COLOR)
        assert decoded is not None and read_counter(decoded) == counter
    assert read_counter(synthetic_image(3)) is None
    assert read_counter(rng.integers(0, 256, (H, W, 3), dtype=np.uint8)) is None
    with pytest.raises(ValueError):
        stamp_counter(np.zeros((8, 100, 3), np.uint8), 1)


# -- RTP wire level --------------------------------------------------------------------------------------------------
def _rtp_headers(sock: socket.socket, done: threading.Event) -> list[tuple[int, int, int]]:
    """(payload type, timestamp, marker) of every datagram, until `done` is set and the socket has run dry."""
    out = []
    sock.settimeout(0.2)
    while True:
        try:
            d = sock.recv(65536)
        except TimeoutError:
            if done.is_set():
                return out
            continue
        out.append((d[1] & 0x7F, int.from_bytes(d[4:8], "big"), d[1] >> 7))


@pytest.mark.parametrize(("kind", "payload_type"), [("h264", 96), ("mjpeg", 26)])
def test_rtp_timestamps_advance_90000_over_fps(tmp_path: Path, kind: str, payload_type: int) -> None:
    cfg = config(tmp_path, h264_rtp=kind == "h264", mjpeg_rtp=kind == "mjpeg", frame_socket=False)
    port = cfg.h264_port if kind == "h264" else cfg.mjpeg_port
    with closing(socket.socket(socket.AF_INET, socket.SOCK_DGRAM)) as rx:
        rx.bind(("127.0.0.1", port))
        headers: list[tuple[int, int, int]] = []
        done = threading.Event()
        reader = threading.Thread(target=lambda: headers.extend(_rtp_headers(rx, done)), daemon=True)
        reader.start()  # read while sending: a keyframe burst would overflow an unread socket buffer
        with VideoPipeline(cfg, W, H) as pipe:
            t0 = time.time()
            for k in range(8):
                # frame 5 was never rendered (dropped upstream): its slot stays empty in RTP time
                if k != 5:
                    submit_and_wait_written(
                        pipe, RenderedFrame(synthetic_image(k), make_meta(k, t0 + k / FPS))
                    )
        done.set()  # every frame was sent before the pipeline stopped: what is left is in the socket buffer
        sdp = pipe.sdp_paths[kind].read_text()
        assert f"m=video {port} RTP/AVP {payload_type}" in sdp
        reader.join(5)
        assert not reader.is_alive()
        out = pipe.stats()["outputs"][f"{kind}_rtp"]
        assert (out["sent"], out["dropped"], out["errors"]) == (7, 0, 0), out
    assert headers and {pt for pt, _, _ in headers} == {payload_type}
    stamps = sorted({ts for _, ts, _ in headers})
    steps = np.diff(stamps).tolist()
    assert steps == [3000] * 4 + [6000] + [3000] * 1, steps
    # the marker bit closes each frame: one marked packet per timestamp
    assert sum(m for _, _, m in headers) == len(stamps)


# -- receivers -------------------------------------------------------------------------------------------------------
def test_h264_rtp_pyav_receiver_matches_frame_socket(tmp_path: Path) -> None:
    cfg = config(tmp_path)
    counter_now = [0]
    socket_images: dict[int, np.ndarray] = {}
    socket_metas: dict[int, dict[str, object]] = {}
    with VideoPipeline(cfg, W, H) as pipe:
        endpoint = pipe.frame_socket_endpoint
        assert endpoint is not None and not endpoint.endswith(":*")
        with FrameClient(endpoint, latest_only=False, rcvhwm=1000) as client:
            sched = run_stream(pipe, counter_now)
            # the socket subscription is live once a frame arrives
            assert client.receive(timeout_s=10.0) is not None, "no frame on the frame socket"
            # the receiver joins a running stream, between keyframes (GOP of 30)
            wait_until(lambda: counter_now[0] % cfg.gop in range(10, 20), 10.0, "mid-GOP tick")
            rx = Collector(pipe.sdp_paths["h264"], n_frames=45, counter_now=counter_now)
            deadline = time.monotonic() + 20
            while rx.thread.is_alive() and time.monotonic() < deadline:
                item = client.receive(timeout_s=0.1)
                if item is not None:
                    img, meta = item
                    socket_images[int(meta["frame_counter"])] = img  # type: ignore[call-overload]
                    socket_metas[int(meta["frame_counter"])] = meta  # type: ignore[call-overload]
            rx.join(5)
            sched.stop()
    stats = pipe.stats()
    h264 = stats["outputs"]["h264_rtp"]
    assert h264["errors"] == 0 and h264["sent"] == stats["submitted"] - h264["dropped"]
    assert 0.0 < h264["pose_to_wire_ms_median"] < 10_000.0  # measured from the frames' pose wall times
    counters: list[Any] = [c for _, c, _ in rx.frames]
    assert len(rx.frames) == 45 and None not in counters, counters
    # joined mid-stream: the first picture is the next keyframe, within one GOP of joining
    first = counters[0]
    # skipped ticks and frames dropped before the encoder stretch the keyframe interval measured in ticks
    late = sched.stats()["late_skipped"] + h264["dropped"]
    assert first is not None and rx.join_counter <= first <= rx.join_counter + cfg.gop + late + 2, (
        rx.join_counter,
        first,
        late,
    )
    assert counters == sorted(counters) and len(set(counters)) == len(counters)
    # frames change over time
    assert psnr(rx.frames[0][2], rx.frames[-1][2]) < 20
    # and match the socket's image for the same counter within codec loss
    values = []
    for _, c, img in rx.frames:
        assert c in socket_images, f"counter {c} never arrived on the frame socket"
        values.append(psnr(img, socket_images[c]))
    print(f"H.264 PSNR vs frame socket: min {min(values):.1f} dB, median {np.median(values):.1f} dB")
    assert min(values) > 28.0, f"PSNR vs frame socket: min {min(values):.1f} dB"
    meta = socket_metas[counters[0]]  # type: ignore[index]
    assert meta["pos_ned_m"] == [1.5 * first, -2.0, -30.0]
    assert meta["image"] == {"encoding": "bgr24", "shape": [H, W, 3], "dtype": "uint8"}


def test_h264_rtp_opencv_ffmpeg_receiver(tmp_path: Path) -> None:
    cfg = config(tmp_path, frame_socket=False)
    script = textwrap.dedent(
        """
        import json, sys, cv2
        from viva_sitl.video import read_counter
        cap = cv2.VideoCapture(sys.argv[1], cv2.CAP_FFMPEG)
        cap.set(cv2.CAP_PROP_N_THREADS, 1)
        out = {"opened": cap.isOpened(), "counters": [], "shape": None}
        while cap.isOpened() and len(out["counters"]) < 30:
            ok, img = cap.read()
            if not ok:
                break
            out["shape"] = list(img.shape)
            out["counters"].append(read_counter(img))
        print(json.dumps(out))
        """
    )
    env = dict(os.environ, OPENCV_FFMPEG_CAPTURE_OPTIONS=OPENCV_CAPTURE_OPTIONS)
    counter_now = [0]
    with VideoPipeline(cfg, W, H) as pipe:
        sched = run_stream(pipe, counter_now)
        try:
            proc = subprocess.run(
                [sys.executable, "-c", script, str(pipe.sdp_paths["h264"])],
                env=env,
                capture_output=True,
                text=True,
                timeout=40,
            )
        finally:
            sched.stop()
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["opened"] and out["shape"] == [H, W, 3]
    counters = out["counters"]
    assert len(counters) == 30 and None not in counters, counters
    assert counters == sorted(counters) and counters[-1] - counters[0] >= 25


@pytest.mark.skipif(shutil.which("gst-launch-1.0") is None, reason="GStreamer (gst-launch-1.0) not installed")
def test_h264_rtp_gstreamer_receiver(tmp_path: Path) -> None:
    """QGroundControl's decoder chain (udpsrc ! rtph264depay ! h264parse ! avdec_h264) reads the stream, AUDs and all."""
    cfg = config(tmp_path, frame_socket=False)
    raw = tmp_path / "gst.bgr"
    caps = "application/x-rtp,media=video,clock-rate=90000,encoding-name=H264,payload=96"
    cmd = [
        "gst-launch-1.0",
        "-q",
        "udpsrc",
        f"port={cfg.h264_port}",
        f"caps={caps}",
        "!",
        "rtph264depay",
        "!",
    ]
    cmd += ["h264parse", "!", "avdec_h264", "!", "videoconvert", "!", "video/x-raw,format=BGR", "!"]
    cmd += ["filesink", f"location={raw}"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    if not _wait_for(lambda: _udp_port_taken(cfg.h264_port), 5.0):
        proc.kill()
        pytest.skip("gst-launch-1.0 did not open its UDP port (plugins missing?)")
    counter_now = [0]
    try:
        with VideoPipeline(cfg, W, H) as pipe:
            sched = run_stream(pipe, counter_now)
            wait_until(lambda: pipe.stats()["outputs"]["h264_rtp"]["sent"] >= 60, 30.0, "60 frames sent")
            sched.stop()
        # GStreamer has decoded (at least) what the test needs before it is interrupted (or it has exited)
        wait_until(
            lambda: proc.poll() is not None or (raw.exists() and raw.stat().st_size >= 45 * W * H * 3),
            10.0,
            "45 frames decoded",
        )
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    if b"no element" in err:
        pytest.skip(f"GStreamer plugins missing: {err.decode(errors='replace')[-300:]}")
    data = np.fromfile(raw, dtype=np.uint8)
    n = data.size // (W * H * 3)
    frames = data[: n * W * H * 3].reshape(n, H, W, 3)
    counters: list[Any] = [read_counter(f) for f in frames]
    assert n >= 45 and None not in counters, counters
    assert (
        counters == sorted(counters) and counters[0] == 0
    )  # GStreamer was listening from the first keyframe
    ref = synthetic_image(counters[-1])
    stamp_counter(ref, counters[-1])
    assert psnr(frames[-1], ref) > 28.0


def _udp_port_taken(port: int) -> bool:
    with closing(socket.socket(socket.AF_INET, socket.SOCK_DGRAM)) as s:
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return True
    return False


def _wait_for(cond: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.05)
    return False


def test_mjpeg_rtp_pyav_receiver(tmp_path: Path) -> None:
    cfg = config(tmp_path, h264_rtp=False, mjpeg_rtp=True, frame_socket=False, jpeg_quality=85)
    counter_now = [0]
    with VideoPipeline(cfg, W, H) as pipe:
        sched = run_stream(pipe, counter_now)
        wait_until(lambda: pipe.stats()["outputs"]["mjpeg_rtp"]["sent"] >= 5, 10.0, "the stream running")
        rx = Collector(pipe.sdp_paths["mjpeg"], n_frames=30, counter_now=counter_now)
        rx.join(25)
        sched.stop()
    counters: list[Any] = [c for _, c, _ in rx.frames]
    assert len(counters) == 30 and None not in counters, counters
    assert counters == sorted(counters)
    # every frame is a keyframe: the first picture arrives right after joining
    assert counters[0] <= rx.join_counter + 15  # (the receiver opens in ~0.1 s)
    for _, c, img in rx.frames[::5]:
        assert c is not None
        ref = synthetic_image(c)
        stamp_counter(ref, c)
        assert psnr(img, ref) > 28.0


# -- frame-and-pose socket -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("encoding", [FrameEncoding.RAW, FrameEncoding.JPEG])
def test_frame_socket_metadata_and_image(tmp_path: Path, encoding: FrameEncoding) -> None:
    cfg = config(tmp_path, h264_rtp=False, frame_socket_encoding=encoding, stamp_counter=False)
    with VideoPipeline(cfg, W, H) as pipe:
        endpoint = pipe.frame_socket_endpoint
        assert endpoint is not None
        with FrameClient(endpoint, latest_only=False, rcvhwm=100) as client:
            wait_for_first_frame(client, pipe)
            sent = [synthetic_frame(k) for k in range(10)]
            got = []
            # each frame received before the next is sent: the pipeline's queue (queue_size 2) is empty at each
            # submit, and the publisher reads ZeroMQ's send credits before each frame, so none may be lost (a CI run
            # lost 2 of 10 here before it did: test_a_subscriber_that_keeps_up_loses_no_frame_however_fast_they_come)
            for f in sent:
                submit_and_wait_written(pipe, f)
                item = client.receive(timeout_s=5.0)
                assert item is not None, f"frame {f.meta.frame_counter} did not arrive ({len(got)} did)"
                got.append(item)
            assert client.receive(timeout_s=0.2) is None, "more frames than were sent"
    assert [m["frame_counter"] for _, m in got] == list(range(10))
    for (img, meta), f in zip(got, sent, strict=True):
        want: dict[str, Any] = f.meta.to_dict()
        for key in ("sim_time_s", "wall_time_s", "footage_frame_index", "coverage", "lat_deg", "alt_amsl_m"):
            assert meta[key] == want[key], key
        assert meta["pos_ned_m"] == list(want["pos_ned_m"])
        assert np.allclose(meta["intrinsics_k"], want["intrinsics_k"])
        assert np.allclose(meta["cam_rot_body"], want["cam_rot_body"])
        assert meta["schema"] == "vivasitl.frame.v1" and meta["image"]["encoding"] == encoding.value
        assert img.shape == (H, W, 3) and img.dtype == np.uint8
        if encoding is FrameEncoding.RAW:
            assert np.array_equal(img, f.image_bgr)
        else:
            assert psnr(img, f.image_bgr) > 28.0


def test_frame_socket_wire_format_errors_and_latest_only() -> None:
    frame = synthetic_frame(3)
    parts = [bytes(p) for p in encode_message(frame)]
    assert parts[0] == b"vivasitl.frame.v1"
    img, meta = decode_message(parts)
    assert np.array_equal(img, frame.image_bgr) and meta["frame_counter"] == 3
    with pytest.raises(ValueError, match="3 parts"):
        decode_message(parts[:2])
    with pytest.raises(ValueError, match="topic"):
        decode_message([b"other", parts[1], parts[2]])
    with pytest.raises(ValueError, match="bytes"):
        decode_message([parts[0], parts[1], parts[2][:-1]])
    with pytest.raises(ValueError, match="metadata"):
        decode_message([parts[0], b"{not json", parts[2]])
    # a slow client: latest_only hands over the newest frame and says how many it skipped
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    port = pub.bind_to_random_port("tcp://127.0.0.1")
    try:
        with FrameClient(f"tcp://127.0.0.1:{port}", latest_only=True, rcvhwm=50) as client:
            probe = encode_message(synthetic_frame(999))
            deadline = time.monotonic() + 10.0
            # ZeroMQ's slow joiner: publish probes until the subscription is live
            while client.receive(timeout_s=0.05) is None:
                assert time.monotonic() < deadline, "subscription never reached the publisher"
                pub.send_multipart(probe)
            while client.receive(timeout_s=0.2) is not None:
                pass
            # Each receive hands over the newest frame that has arrived and counts the ones it passed over; how
            # many arrived before a receive depends on timing, so assert what latest_only guarantees:
            # increasing counters, the newest frame always delivered, delivered + skipped = sent; and waiting frames
            # are skipped (seen in at least one of a few bursts: how many arrive before a receive is up to TCP).
            skipped_any = False
            for burst in range(10):
                first = 5 * burst
                for k in range(first, first + 5):
                    pub.send_multipart(encode_message(synthetic_frame(k)))
                assert client._sock.poll(5000, zmq.POLLIN), "nothing arrived"
                # a moment for the rest of the burst to arrive; if it has not, the next burst tries again
                time.sleep(0.05)
                delivered: list[tuple[int, int]] = []
                while not delivered or delivered[-1][0] != first + 4:
                    item = client.receive(timeout_s=5.0)
                    assert item is not None, f"frame {first + 4} never delivered; got {delivered}"
                    delivered.append((item[1]["frame_counter"], item[1]["skipped"]))
                counters = [c for c, _ in delivered]
                assert counters == sorted(set(counters)) and counters[0] >= first, delivered
                assert len(delivered) + sum(n for _, n in delivered) == 5, delivered
                assert client.receive(timeout_s=0.1) is None
                if delivered[0][1] > 0:
                    skipped_any = True
                    break
            assert skipped_any, "latest_only never skipped a waiting frame"
    finally:
        pub.close(0)
        ctx.term()


def test_a_subscriber_that_keeps_up_loses_no_frame_however_fast_they_come() -> None:
    """A frame-socket client that has received every frame before the next is published (a quick lockstep pilot)
    gets every frame, however little time passes between them. libzmq's PUB read the subscriber's send credits at most
    once per ~1 ms, so in this loop it dropped 1 frame in 3 silently (sndhwm 2) until the publisher read them before
    each send (bench/probe_frame_socket_credit.py measures both)."""
    pub = FramePublisher("tcp://127.0.0.1:*", sndhwm=2)
    pub.open()
    try:
        with FrameClient(pub.bound_endpoint, latest_only=False, rcvhwm=100) as client:
            deadline = time.monotonic() + 10.0
            while (
                client.receive(timeout_s=0.05) is None
            ):  # ZeroMQ's slow joiner: probe until the subscription is live
                assert time.monotonic() < deadline, "subscription never reached the publisher"
                pub.write(synthetic_frame(999))
            while client.receive(timeout_s=0.2) is not None:
                pass
            # small frames made beforehand: the loop sends one every ~0.1 ms, well inside libzmq's throttle
            frames = [
                RenderedFrame(np.full((24, 32, 3), k % 256, np.uint8), make_meta(k, 0.0, 32, 24))
                for k in range(600)
            ]
            lost = []
            for k, frame in enumerate(frames):
                pub.write(frame)
                item = client.receive(timeout_s=2.0)
                if item is None:
                    lost.append(k)
                    if len(lost) == 5:  # each costs the 2 s wait: enough to say so
                        break
                else:
                    assert item[1]["frame_counter"] == k, (k, item[1]["frame_counter"])
            assert not lost, f"frames lost: {lost} (of {k + 1} sent)"
            assert pub.would_block == 0
    finally:
        pub.close()


# -- real time: dropping, scheduler, recorder ------------------------------------------------------------------------
class SlowSink:
    """A deliberately slow output: its first write does not return until `release` is set (an encoder stuck for as
    long as the test submits), so whatever else is submitted meanwhile must be dropped, however loaded the machine."""

    name = "slow_sink"

    def __init__(self) -> None:
        self.written: list[int] = []
        self.opened = self.closed = False
        self.release = threading.Event()

    def open(self) -> None:
        self.opened = True

    def write(self, frame: RenderedFrame) -> None:
        assert self.release.wait(30.0), "the test never released the sink"
        self.written.append(frame.meta.frame_counter)

    def close(self) -> None:
        self.closed = True


def test_slow_output_drops_frames_and_submit_never_blocks(tmp_path: Path) -> None:
    sink = SlowSink()
    cfg = config(tmp_path, frame_socket=False, queue_size=1, stamp_counter=False)
    frames = [synthetic_frame(k) for k in range(60)]
    submit_ms = []
    with VideoPipeline(cfg, W, H, extra_outputs=[sink]) as pipe:
        for f in frames:
            t = time.perf_counter()
            pipe.submit(f)
            submit_ms.append((time.perf_counter() - t) * 1e3)
            time.sleep(0.01)  # the stream's pace (100 fps), not a wait: the other outputs keep up with it
        sink.release.set()
    stats = pipe.stats()
    slow = stats["outputs"]["slow_sink"]
    assert sink.opened and sink.closed
    # the stuck sink held one frame in write and one in its queue (queue_size 1): every other one was dropped
    assert slow["dropped"] >= 60 - 3 and len(sink.written) <= 3, stats
    # everything submitted was either written or dropped: nothing lost silently, nothing left queued
    assert slow["sent"] + slow["dropped"] == stats["submitted"] == 60
    assert sink.written == sorted(sink.written) and sink.written[-1] == 59  # drop-oldest keeps the newest
    assert stats["dropped"] == slow["dropped"] and stats["outputs"]["h264_rtp"]["dropped"] < slow["dropped"]
    assert max(submit_ms) < 5.0, f"submit took up to {max(submit_ms):.1f} ms"


def test_scheduler_keeps_the_clock_when_rendering_is_late() -> None:
    got: list[int] = []

    def render(tick: int) -> RenderedFrame | None:
        if tick % 10 == 3:
            time.sleep(3.5 / FPS)  # occasionally 3.5 frame periods late
        if tick == 1:
            raise RuntimeError("render failure is logged and counted")
        return RenderedFrame(np.zeros((H, W, 3), np.uint8), make_meta(tick, time.time()))

    def submit(frame: RenderedFrame) -> bool:
        got.append(frame.meta.frame_counter)
        return True

    sched = FrameScheduler(render, submit, FPS)
    t0 = time.monotonic()
    sched.start()
    wait_until(lambda: bool(got) and got[-1] >= 30, 10.0, "30 ticks")  # a second of the stream's clock
    sched.stop()
    elapsed = time.monotonic() - t0
    st = sched.stats()
    assert st["render_errors"] == 1 and 1 not in got
    assert st["late_skipped"] >= 6, st  # each late tick costs ~3 skipped slots
    # the tick index follows the wall clock, not the number of renders
    assert got[-1] >= int((elapsed - 0.15) * FPS), (got[-1], elapsed)
    assert st["ticks"] + st["late_skipped"] == got[-1] + 1


def test_recorder_writes_complete_mp4(tmp_path: Path) -> None:
    path = tmp_path / "vac.mp4"
    cfg = config(tmp_path, h264_rtp=False, frame_socket=False, record_path=str(path), stamp_counter=True)
    t0 = time.time()
    with VideoPipeline(cfg, W, H) as pipe:
        for k in range(20):  # one at a time: nothing dropped, so the file holds exactly these 20
            submit_and_wait_written(pipe, RenderedFrame(synthetic_image(k), make_meta(k, t0 + k / FPS)))
        assert not path.exists()  # still being written (as .part)
    assert path.is_file() and not (tmp_path / "vac.mp4.part").exists()
    with av.open(str(path)) as c:
        decoded = [f.to_ndarray(format="bgr24") for f in c.decode(video=0)]
    assert [read_counter(img) for img in decoded] == list(range(20))


def test_bad_input_is_rejected_clearly(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="even"):
        VideoPipeline(VideoConfig(), 641, 480)
    bad_dir = VideoConfig(
        frame_socket=False, h264_port=free_rtp_port(), record_path=str(tmp_path / "no" / "x.mp4")
    )
    pipe = VideoPipeline(bad_dir, W, H)
    with pytest.raises(ValueError, match="does not exist"):
        pipe.start()
    cfg = config(tmp_path, frame_socket=False)
    with VideoPipeline(cfg, W, H) as pipe2:
        with pytest.raises(ValueError, match="uint8"):
            pipe2.submit(RenderedFrame(np.zeros((H, W, 3), np.float32), make_meta(0, 0.0)))  # type: ignore[arg-type]
        with pytest.raises(ValueError):
            pipe2.submit(RenderedFrame(np.zeros((H // 2, W, 3), np.uint8), make_meta(0, 0.0)))
    assert pipe2.submit(synthetic_frame(0)) is False  # after stop: rejected, counted
    assert pipe2.stats()["rejected"] == 1
    # two pipelines on one frame-socket endpoint: the second fails at start with the endpoint named
    with VideoPipeline(replace(cfg, frame_socket=True, h264_rtp=False), W, H) as p1:
        taken = p1.frame_socket_endpoint
        assert taken is not None
        with pytest.raises(ValueError, match="cannot bind"):
            VideoPipeline(
                replace(cfg, frame_socket=True, frame_socket_endpoint=taken, h264_rtp=False), W, H
            ).start()
