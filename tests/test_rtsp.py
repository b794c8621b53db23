"""The RTSP server of the VAC (viva_sitl/video/rtsp.py): real FFmpeg clients (PyAV) over TCP and UDP, two at once, clients
that vanish or stall, bad requests, and the one-encode rule (the RTSP packets are the H.264 RTP output's packets)."""

from __future__ import annotations

import shutil
import socket
import struct
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import closing, contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

import av
import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2
from sitl_process import MavlinkPeer, SitlProcess, free_tcp_port, free_udp_ports
from test_video import FPS, H, W, config, psnr, run_stream, synthetic_image, wait_until

from viva_sitl.video import VideoPipeline, read_counter, stamp_counter
from viva_sitl.video.outputs import H264RtpOutput
from viva_sitl.video.rtsp import (
    H264Packetizer,
    RtspError,
    RtspServer,
    Transport,
    parameter_sets,
    parse_request,
    split_annexb,
)

CAMERA_COMPID = 100


# -- helpers ---------------------------------------------------------------------------------------------------------
@contextmanager
def streaming(pipe: VideoPipeline) -> Iterator[list[int]]:
    """The pipeline started and fed with stamped synthetic frames at FPS; yields [the counter of the latest frame]."""
    counter_now = [0]
    with pipe:
        sched = run_stream(pipe, counter_now)
        try:
            yield counter_now
        finally:
            sched.stop()


class PyavClient:
    """An FFmpeg RTSP client (PyAV) on a thread: keeps (wall time, counter) of decoded frames and the last image."""

    def __init__(self, url: str, transport: str, n_frames: int) -> None:
        self.url, self.transport, self.n_frames = url, transport, n_frames
        self.frames: list[tuple[float, int | None]] = []
        self.last: np.ndarray | None = None
        self.error: BaseException | None = None
        self.size: tuple[int, int] = (0, 0)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            with av.open(self.url, options={"rtsp_transport": self.transport}, timeout=(10.0, 5.0)) as c:
                for f in c.decode(video=0):
                    img = f.to_ndarray(format="bgr24")
                    self.size = (f.width, f.height)
                    self.frames.append((time.monotonic(), read_counter(img)))
                    self.last = img
                    if len(self.frames) >= self.n_frames or self.stop.is_set():
                        break
        except BaseException as exc:  # reported by the test
            self.error = exc

    def join(self, timeout_s: float = 30.0) -> None:
        self.thread.join(timeout_s)
        assert not self.thread.is_alive(), f"{self.transport} client did not finish"
        assert self.error is None, f"{self.transport} client failed: {self.error!r}"

    @property
    def counters(self) -> list[int]:
        return [c for _, c in self.frames if c is not None]


def check_decoded(client: PyavClient, min_frames: int) -> None:
    """Frames decoded at the stream's size, counters increasing, the last image equal to its source."""
    client.join()
    counters = client.counters
    assert client.size == (W, H)
    assert len(counters) >= min_frames and len(counters) == len(client.frames), client.frames[:5]
    assert counters == sorted(counters) and len(set(counters)) == len(counters), counters
    assert client.last is not None
    ref = synthetic_image(counters[-1])
    stamp_counter(ref, counters[-1])
    assert psnr(client.last, ref) > 28.0


def rtsp_config(tmp_path: Path, **kw: object) -> Any:
    return config(tmp_path, frame_socket=False, rtsp=True, rtsp_port=0, **kw)


class RawClient:
    """A hand-driven RTSP client on a plain socket (for bad requests and clients that misbehave)."""

    def __init__(self, port: int, rcvbuf: int | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        if rcvbuf is not None:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        self.sock.settimeout(5.0)
        self.sock.connect(("127.0.0.1", port))
        self.buf = b""
        self.cseq = 0

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def request(self, method: str, url: str, **headers: str) -> tuple[int, dict[str, str], bytes]:
        self.cseq += 1
        lines = [f"{method} {url} RTSP/1.0", f"CSeq: {self.cseq}"]
        lines += [f"{k.replace('_', '-')}: {v}" for k, v in headers.items()]
        self.send(("\r\n".join(lines) + "\r\n\r\n").encode())
        return self.response()

    def _fill(self) -> None:
        data = self.sock.recv(65536)
        if not data:
            raise ConnectionError("server closed the connection")
        self.buf += data

    def response(self) -> tuple[int, dict[str, str], bytes]:
        """The next RTSP response (interleaved media before it is skipped)."""
        while True:
            while self.buf.startswith(b"$"):
                while len(self.buf) < 4:
                    self._fill()
                (length,) = struct.unpack("!H", self.buf[2:4])
                while len(self.buf) < 4 + length:
                    self._fill()
                self.buf = self.buf[4 + length :]
            if b"\r\n\r\n" in self.buf and not self.buf.startswith(b"$"):
                break
            self._fill()
        head, _, self.buf = self.buf.partition(b"\r\n\r\n")
        lines = head.decode().split("\r\n")
        status = int(lines[0].split()[1])
        headers = {k.strip().lower(): v.strip() for k, _, v in (ln.partition(":") for ln in lines[1:])}
        n = int(headers.get("content-length", "0"))
        while len(self.buf) < n:
            self._fill()
        body, self.buf = self.buf[:n], self.buf[n:]
        return status, headers, body

    def interleaved(self, n_packets: int) -> list[bytes]:
        """The next n interleaved RTP packets (channel 0)."""
        out: list[bytes] = []
        while len(out) < n_packets:
            while len(self.buf) < 4:
                self._fill()
            assert self.buf[:1] == b"$", self.buf[:40]
            ch, length = struct.unpack("!BH", self.buf[1:4])
            while len(self.buf) < 4 + length:
                self._fill()
            if ch == 0:
                out.append(self.buf[4 : 4 + length])
            self.buf = self.buf[4 + length :]
        return out

    def play_interleaved(self, url: str) -> str:
        status, h, _ = self.request(
            "SETUP", f"{url}/trackID=0", Transport="RTP/AVP/TCP;unicast;interleaved=0-1"
        )
        assert status == 200, status
        session = h["session"].split(";")[0]
        status, _, _ = self.request("PLAY", url, Session=session)
        assert status == 200
        return session

    def vanish(self) -> None:
        """Close with a TCP reset (SO_LINGER 0): the connection is gone without FIN, TEARDOWN or a goodbye."""
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        self.sock.close()

    def close(self) -> None:
        self.sock.close()


# -- unit: packetisation and parsing -------------------------------------------------------------------------------
def test_packetizer_fragments_and_reassembles_nal_units() -> None:
    rng = np.random.default_rng(3)
    sps = b"\x67\x64\x00\x1f\xac\xd9\x40"
    pps = b"\x68\xeb\xe3\xcb"
    idr = b"\x65" + bytes(rng.integers(1, 256, 5000, dtype=np.uint8))  # no zero bytes: no false start codes
    aud = b"\x09\xf0"
    au = (
        b"\x00\x00\x00\x01"
        + sps
        + b"\x00\x00\x01"
        + pps
        + b"\x00\x00\x00\x01"
        + idr
        + b"\x00\x00\x00\x01"
        + aud
    )
    assert list(split_annexb(au)) == [sps, pps, idr, aud]
    assert parameter_sets(au) == (sps, pps)
    assert parameter_sets(b"\x00\x00\x00\x01" + idr) is None
    pk = H264Packetizer(max_payload=1400)
    seq0 = pk.seq
    packets = pk.packetize(au, 9000)
    assert all(len(p) <= 12 + 1400 for p in packets)
    seqs = [struct.unpack("!H", p[2:4])[0] for p in packets]
    assert seqs == [(seq0 + i) & 0xFFFF for i in range(len(packets))]
    assert {struct.unpack("!I", p[4:8])[0] for p in packets} == {(9000 + pk.ts_offset) & 0xFFFFFFFF}
    assert [p[1] >> 7 for p in packets] == [0] * (len(packets) - 1) + [1]  # marker: the frame's last packet
    assert all(p[1] & 0x7F == 96 for p in packets)
    # reassemble: single NAL packets as they are, FU-A fragments joined with the NAL header rebuilt
    nals: list[bytes] = []
    frag = b""
    for p in packets:
        payload = p[12:]
        if payload[0] & 0x1F == 28:
            ind, hdr = payload[0], payload[1]
            if hdr & 0x80:
                frag = bytes(((ind & 0xE0) | (hdr & 0x1F),))
            frag += payload[2:]
            if hdr & 0x40:
                nals.append(frag)
        else:
            nals.append(payload)
    assert nals == [sps, pps, idr, aud]
    assert sum(1 for p in packets if p[12] & 0x1F == 28) == 4  # 5001 bytes in 1398-byte fragments


def test_request_and_transport_parsing() -> None:
    req = parse_request(
        b"SETUP rtsp://h/vac/trackID=0 RTSP/1.0\r\nCSeq: 3\r\nTransport: RTP/AVP;unicast\r\n\r\n"
    )
    assert (req.method, req.cseq, req.headers["transport"]) == ("SETUP", "3", "RTP/AVP;unicast")
    udp = Transport.parse("RTP/AVP/TCP;multicast, RTP/AVP;unicast;client_port=5000-5001")
    assert (udp.tcp, udp.rtp_port, udp.rtcp_port) == (False, 5000, 5001)
    tcp = Transport.parse("RTP/AVP/TCP;unicast;interleaved=2-3")
    assert (tcp.tcp, tcp.channel) == (True, 2)
    for bad in (
        "RTP/AVP;multicast",
        "RTP/AVP;unicast",
        "RTP/SAVP;unicast;client_port=1-2",
        "RTP/AVP;client_port=x",
    ):
        with pytest.raises(RtspError) as exc:
            Transport.parse(bad)
        assert exc.value.status == 461, bad


# -- real clients ----------------------------------------------------------------------------------------------------
def test_pyav_decodes_over_tcp_and_udp_sharing_the_rtp_encode(tmp_path: Path) -> None:
    """Two FFmpeg clients at once (interleaved TCP and UDP) decode the VAC; the RTP/UDP stream runs from the same
    encode (one H.264 output; every packet it muxes is handed to the RTSP server)."""
    pipe = VideoPipeline(rtsp_config(tmp_path), W, H)
    assert [w for w in ("h264_rtp", "h264_rtsp") if w in [o.name for o in pipe._outputs]] == ["h264_rtp"]
    with streaming(pipe):
        url = pipe.rtsp_url
        assert url is not None and url.startswith("rtsp://127.0.0.1:") and url.endswith("/vac")
        tcp = PyavClient(url, "tcp", 45)
        udp = PyavClient(url, "udp", 45)
        wait_until(lambda: pipe.rtsp is not None and pipe.rtsp.playing == 2, 15.0, "two clients playing")
        check_decoded(tcp, 45)
        check_decoded(udp, 45)
    stats = pipe.stats()  # stopped: every frame encoded has been handed over
    shared = set(tcp.counters) & set(udp.counters)
    assert len(shared) >= 20, (tcp.counters, udp.counters)  # the same frames, at the same time
    rtsp = stats["rtsp"]
    assert rtsp["sessions_total"] == 2 and rtsp["errors_sent"] == 0
    # one encode: the RTSP server was fed exactly the frames the H.264 RTP output encoded
    assert stats["outputs"]["h264_rtp"]["sent"] == rtsp["frames_fed"], stats
    assert rtsp["frames_behind"] == 0


def test_rtsp_without_rtp_encodes_once_for_rtsp_only(tmp_path: Path) -> None:
    pipe = VideoPipeline(rtsp_config(tmp_path, h264_rtp=False), W, H)
    assert [o.name for o in pipe._outputs] == ["h264_rtsp"]
    with streaming(pipe):
        assert pipe.sdp_paths == {}
        assert pipe.rtsp_url is not None
        client = PyavClient(pipe.rtsp_url, "tcp", 30)
        check_decoded(client, 30)
    assert not list(tmp_path.glob("*.sdp"))


@pytest.mark.slow  # ~10 s: filling a stalled client's socket buffers
def test_vanishing_and_stalled_clients_do_not_hurt_the_others(tmp_path: Path) -> None:
    """A client reset mid-session, one gone after half a request, a UDP client whose port is closed, and one that
    never reads (its TCP buffer fills): the FFmpeg client keeps decoding every frame, the server cleans up."""
    server = RtspServer("127.0.0.1", 0, fps=FPS, max_client_buffer_bytes=32 * 1024)
    cfg = replace(config(tmp_path, frame_socket=False, h264_rtp=False), stamp_counter=True)
    out = H264RtpOutput("127.0.0.1", 1, W, H, fps=FPS, gop=FPS, send_rtp=False, packet_sink=server.feed)
    pipe = VideoPipeline(cfg, W, H, extra_outputs=[out])
    with server, streaming(pipe):
        url = server.url
        good = PyavClient(url, "tcp", 100_000)  # until good.stop
        wait_until(lambda: server.playing == 1, 15.0, "the FFmpeg client playing")
        # 1. a client that plays interleaved, receives media, then vanishes with a TCP reset
        raw = RawClient(server.port)
        raw.play_interleaved(url)
        assert len(raw.interleaved(5)) == 5
        # 2. a client that never reads: its socket buffer fills, it misses frames, the others do not
        stalled = RawClient(server.port, rcvbuf=4096)
        stalled.play_interleaved(url)
        # 3. a UDP client whose ports nobody listens on (ICMP port unreachable comes back)
        with closing(socket.socket(socket.AF_INET, socket.SOCK_DGRAM)) as s:
            s.bind(("127.0.0.1", 0))
            dead_port = s.getsockname()[1]
        udp = RawClient(server.port)
        status, h, _ = udp.request(
            "SETUP", f"{url}/trackID=0", Transport=f"RTP/AVP;unicast;client_port={dead_port}-{dead_port + 1}"
        )
        assert status == 200 and f"client_port={dead_port}-{dead_port + 1}" in h["transport"]
        assert udp.request("PLAY", url, Session=h["session"].split(";")[0])[0] == 200
        wait_until(lambda: server.playing == 4, 5.0, "four sessions playing")
        t_vanish = time.monotonic()
        raw.vanish()
        # 4. half a request, then gone
        half = RawClient(server.port)
        half.send(b"DESCRIBE rtsp://127.0.0.1/vac RTSP/1.0\r\nCSeq: 1\r\n")
        half.vanish()
        wait_until(lambda: server.playing == 3, 5.0, "the reset client's session ended")
        udp.close()
        wait_until(lambda: server.playing == 2, 5.0, "the UDP client's session ended with its connection")
        # the kernel's socket buffers take a few MB before the server's own limit is reached
        wait_until(
            lambda: server.stats()["client_frames_dropped"] > 0, 20.0, "the stalled client missing frames"
        )
        assert good.thread.is_alive(), "the FFmpeg client stopped early"
        good.stop.set()
        check_decoded(good, 90)
        after = [c for t, c in good.frames if t > t_vanish]
        assert len(after) >= 60, len(after)
        gaps = np.diff(good.counters)
        assert gaps.max() <= 3, f"the good client lost frames: max counter gap {gaps.max()}"
        stalled.vanish()
        wait_until(lambda: server.clients == 0, 5.0, "every session ended")
    stats = server.stats()
    assert stats["sessions_total"] == 4 and stats["sessions_closed"] == 4, stats
    assert stats["frames_behind"] == 0


def test_bad_requests_get_rtsp_error_codes(tmp_path: Path) -> None:
    server = RtspServer("127.0.0.1", 0, fps=FPS, max_clients=2, describe_wait_s=0.1)
    with server:
        url = server.url
        c = RawClient(server.port)
        status, h, _ = c.request("OPTIONS", "*")
        assert status == 200 and "DESCRIBE" in h["public"] and "SETUP" in h["public"]
        assert c.request("DESCRIBE", "rtsp://127.0.0.1/nothing")[0] == 404
        assert c.request("FLY", url)[0] == 501
        assert c.request("RECORD", url)[0] == 405
        assert c.request("ANNOUNCE", url)[0] == 405
        assert c.request("PLAY", url)[0] == 454  # no session
        assert c.request("PLAY", url, Session="deadbeef")[0] == 454
        assert c.request("SETUP", f"{url}/trackID=0", Transport="RTP/AVP;multicast")[0] == 461
        assert c.request("SETUP", f"{url}/trackID=0")[0] == 461  # no Transport at all
        assert c.request("DESCRIBE", url, Accept="text/html")[0] == 406
        assert c.request("DESCRIBE", f"{url}/trackID=0")[0] == 459
        c.send(b"OPTIONS * RTSP/1.0\r\n\r\n")  # no CSeq
        assert c.response()[0] == 400
        c.send(b"OPTIONS * RTSP/2.0\r\nCSeq: 99\r\n\r\n")
        status, h, _ = c.response()
        assert status == 505 and h["cseq"] == "99"
        # after all that, the same connection still works
        status, h, body = c.request("DESCRIBE", url)
        assert status == 200 and h["content-type"] == "application/sdp"
        assert b"m=video 0 RTP/AVP 96" in body and b"a=control:trackID=0" in body
        # the client limit: 453, and a second SETUP in one session: 459
        s1 = c.play_interleaved(url)
        assert (
            c.request("SETUP", f"{url}/trackID=0", Transport="RTP/AVP/TCP;interleaved=2-3", Session=s1)[0]
            == 459
        )
        d = RawClient(server.port)
        d.play_interleaved(url)
        assert d.request("SETUP", f"{url}/trackID=0", Transport="RTP/AVP/TCP;interleaved=0-1")[0] == 453
        assert c.request("GET_PARAMETER", url, Session=s1)[0] == 200  # keep-alive
        assert c.request("TEARDOWN", url, Session=s1)[0] == 200
        assert c.request("PLAY", url, Session=s1)[0] == 454
        # garbage closes the connection after a 400
        g = RawClient(server.port)
        g.send(b"\x16\x03\x01\x02\x00garbage\r\n\r\n")
        assert g.response()[0] == 400
        with pytest.raises((ConnectionError, OSError)):
            g.request("OPTIONS", "*")
        for x in (c, d, g):
            x.close()
        wait_until(lambda: server.clients == 0, 5.0, "sessions of closed connections ended")
    assert server.stats()["errors_sent"] >= 15


def test_port_taken_is_one_clear_error() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(ValueError, match=f"RTSP server: cannot listen on 127.0.0.1:{port}"):
            RtspServer("127.0.0.1", port).start()
    with pytest.raises(ValueError, match="rtsp_port"):
        config(Path("."), rtsp=True, rtsp_port=70000)


@pytest.mark.skipif(shutil.which("gst-launch-1.0") is None, reason="GStreamer (gst-launch-1.0) not installed")
def test_gstreamer_rtspsrc_plays(tmp_path: Path) -> None:
    """QGroundControl's RTSP chain (rtspsrc ! rtph264depay ! h264parse ! avdec_h264) decodes frames."""
    raw = tmp_path / "gst.bgr"
    pipe = VideoPipeline(rtsp_config(tmp_path), W, H)
    with streaming(pipe):
        cmd = [
            "gst-launch-1.0",
            "-q",
            "rtspsrc",
            f"location={pipe.rtsp_url}",
            "latency=0",
            "!",
            "rtph264depay",
        ]
        cmd += ["!", "h264parse", "!", "avdec_h264", "!", "videoconvert", "!", "video/x-raw,format=BGR", "!"]
        cmd += ["filesink", f"location={raw}"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            wait_until(
                lambda: proc.poll() is not None or (raw.exists() and raw.stat().st_size >= 30 * W * H * 3),
                20.0,
                "30 frames decoded by GStreamer",
            )
        finally:
            proc.terminate()
            _, err = proc.communicate(timeout=10)
    if b"no element" in err:
        pytest.skip(f"GStreamer plugins missing: {err.decode(errors='replace')[-300:]}")
    data = np.fromfile(raw, dtype=np.uint8)
    n = data.size // (W * H * 3)
    counters = [read_counter(f) for f in data[: n * W * H * 3].reshape(n, H, W, 3)]
    assert n >= 30 and None not in counters and counters == sorted(counters), counters


@pytest.mark.e2e
@pytest.mark.slow  # a viva-sitl process streaming video
def test_viva_sitl_run_rtsp_advertised_and_played(sitl_factory: Callable[..., SitlProcess]) -> None:
    """`viva-sitl run --rtsp PORT`: the ready line and VIDEO_STREAM_INFORMATION (type RTSP, the full URL) name the
    stream, FFmpeg plays it, and the RTP/UDP stream keeps its own entry."""
    rtsp_port = free_tcp_port()
    video_port = free_udp_ports(1)[0]
    sitl = sitl_factory(video_port=video_port, extra_args=["--rtsp", str(rtsp_port)])
    url = f"rtsp://127.0.0.1:{rtsp_port}/vac"
    assert f"rtsp {url}" in sitl.ready_line
    peer = MavlinkPeer(sitl.ports.gcs)
    try:
        peer.wait_autopilot()
        ack = peer.command_long(
            mavlink2.MAV_CMD_REQUEST_MESSAGE,
            [float(mavlink2.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION), 0.0],
            (1, CAMERA_COMPID),
        )
        assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
        streams: dict[int, Any] = {}
        while len(streams) < 2:
            m = peer.wait("VIDEO_STREAM_INFORMATION", lambda m: m.stream_id not in streams, 3.0, since_s=0.0)
            streams[m.stream_id] = m
    finally:
        peer.close()
    by_type = {m.type: m for m in streams.values()}
    rtsp = by_type[mavlink2.VIDEO_STREAM_TYPE_RTSP]
    assert rtsp.uri == url and rtsp.encoding == mavlink2.VIDEO_STREAM_ENCODING_H264
    assert by_type[mavlink2.VIDEO_STREAM_TYPE_RTPUDP].uri == str(video_port)
    with av.open(url, options={"rtsp_transport": "tcp"}, timeout=(10.0, 5.0)) as c:
        frames = []
        for f in c.decode(video=0):
            frames.append(f.to_ndarray(format="bgr24"))
            if len(frames) >= 30:
                break
    assert len(frames) == 30 and frames[-1].shape == (480, 640, 3)
    assert sitl.alive
    assert sitl.stop() == 0
    stats = sitl.stop_stats()
    assert stats["video"]["rtsp"]["sessions_total"] == 1 and stats["video"]["rtsp"]["errors_sent"] == 0


def test_silent_udp_session_times_out_and_oversized_requests_are_refused() -> None:
    server = RtspServer("127.0.0.1", 0, fps=FPS, session_timeout_s=0.4)
    with server:
        url = server.url
        c = RawClient(server.port)
        status, h, _ = c.request(
            "SETUP", f"{url}/trackID=0", Transport="RTP/AVP;unicast;client_port=40000-40001"
        )
        assert status == 200 and h["session"].endswith(";timeout=1")
        assert server.clients == 1
        wait_until(lambda: server.clients == 0, 5.0, "the silent UDP session timed out")
        assert c.request("PLAY", url, Session=h["session"].split(";")[0])[0] == 454
        big = RawClient(server.port)
        big.send(b"OPTIONS * RTSP/1.0\r\nCSeq: 1\r\nX-Pad: " + b"a" * 40_000 + b"\r\n\r\n")
        assert big.response()[0] == 400
        with pytest.raises((ConnectionError, OSError)):
            big.request("OPTIONS", "*")
        c.close()


def test_rtsp_flag_and_instances() -> None:
    from viva_sitl.app import config_from_args
    from viva_sitl.cli import build_parser

    parser = build_parser()
    off = config_from_args(parser.parse_args(["run"])).video
    assert off.rtsp is False
    v = config_from_args(parser.parse_args(["run", "--rtsp"])).video
    assert (v.rtsp, v.rtsp_port, v.rtsp_host) == (True, 8554, "127.0.0.1")
    v = config_from_args(parser.parse_args(["run", "--rtsp", "--instance", "2"])).video
    assert (v.rtsp, v.rtsp_port) == (True, 8556)
    v = config_from_args(parser.parse_args(["run", "--rtsp", "9000", "--instance", "2"])).video
    assert (v.rtsp, v.rtsp_port) == (True, 9000)  # a port given is used as given, like --video-port
    with pytest.raises(SystemExit):
        parser.parse_args(["run", "--rtsp", "70000"])
