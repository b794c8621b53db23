"""An RTSP server for the VAC's H.264 stream: the packets the H.264 RTP output already encoded, to every RTSP client.

    server = RtspServer("127.0.0.1", 8554, fps=30)
    server.start()                                  # binds; ValueError naming the port when it cannot
    server.feed(annexb_bytes, rtp_ts, keyframe)     # from the encoder's thread, per encoded frame (never blocks)
    print(server.url)                               # rtsp://127.0.0.1:8554/vac
    server.stop()

`ffplay rtsp://127.0.0.1:8554/vac`, QGroundControl's RTSP video source, VLC, GStreamer's rtspsrc and PyAV open it.

Why a server of our own (about 500 lines on asyncio) and not a library: PyPI has no maintained pure-Python RTSP
*server* that takes already-encoded H.264. `rtsp` (2.0) encodes the frames itself (a second libx264 encode, which the
issue rules out) and suggests a MediaMTX relay for several clients; `rtsp-rs` is a compiled hobby project its author
marks alpha; `aiortsp` and the others are clients; GStreamer's gst-rtsp-server is a system library with GObject
bindings, not a pip dependency. What a live single-stream server needs is small and fixed by RFC 2326 / RFC 6184:

- OPTIONS, DESCRIBE (SDP with sprop-parameter-sets from the stream's latest keyframe), SETUP (RTP/AVP over UDP
  unicast to the client's client_port, or interleaved over the RTSP TCP connection), PLAY, PAUSE, TEARDOWN and
  GET_PARAMETER / OPTIONS as keep-alives; anything else gets an RTSP error code (400, 404, 405, 406, 454, 455, 459,
  461, 501, 505, 453 when the client limit is reached), never a dropped connection or a traceback.
- One packetisation (RFC 6184: single NAL units and FU-A, marker bit on a frame's last packet) shared by all clients:
  the same RTP packets go to every playing session. A client starts (and restarts after a drop) on a keyframe.
- Bounded: at most `max_clients` sessions; frames handed over from the encoder thread are dropped when the server's
  loop is behind (`max_pending_frames`); a client whose TCP send buffer holds more than `max_client_buffer_bytes`
  misses frames (counted) and resumes at the next keyframe, so one slow or stuck client never grows memory or delays
  the others. A client that disconnects (even mid-request, or without TEARDOWN) loses its sessions at once; a UDP
  session whose control connection stays silent for `session_timeout_s` (no keep-alive) is ended.
- Its own thread and event loop: nothing here runs on the simulator's loop, and the encoder thread only packetises
  (when someone is playing) and posts the packets.

Not done: RTCP sender reports (FFmpeg, GStreamer and VLC play without them), multicast, authentication, RTSP 2.0.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import ipaddress
import logging
import secrets
import socket
import struct
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlsplit

log = logging.getLogger(__name__)

DEFAULT_RTSP_PORT = (
    8554  # the usual unprivileged RTSP port (MediaMTX, PX4's camera docs, gst-rtsp-server examples)
)
STREAM_PATH = "vac"  # rtsp://host:port/vac
TRACK = "trackID=0"  # the SETUP control URL of the one video track: rtsp://host:port/vac/trackID=0
PAYLOAD_TYPE = 96
MAX_RTP_PAYLOAD = 1400  # bytes of H.264 per RTP packet: fits a 1500-byte MTU with IP/UDP/RTP headers
RTP_CLOCK_HZ = 90_000
SERVER_NAME = "viva-sitl"
_MAX_REQUEST_BYTES = 16 * 1024  # request line + headers; longer gets 400 and the connection is closed
_MAX_BODY_BYTES = 64 * 1024
_METHODS = ("OPTIONS", "DESCRIBE", "SETUP", "PLAY", "PAUSE", "TEARDOWN", "GET_PARAMETER")
_KNOWN_METHODS = set(_METHODS) | {"ANNOUNCE", "RECORD", "REDIRECT", "SET_PARAMETER"}
_REASONS = {
    200: "OK",
    400: "Bad Request",
    404: "Not Found",
    405: "Method Not Allowed",
    406: "Not Acceptable",
    453: "Not Enough Bandwidth",
    454: "Session Not Found",
    455: "Method Not Valid in This State",
    459: "Aggregate Operation Not Allowed",
    461: "Unsupported Transport",
    500: "Internal Server Error",
    501: "Not Implemented",
    503: "Service Unavailable",
    505: "RTSP Version Not Supported",
}


# --- RFC 6184 packetisation ------------------------------------------------------------------------------------------
def split_annexb(data: bytes) -> Iterator[bytes]:
    """The NAL units of an Annex-B byte stream (3- or 4-byte start codes; trailing zero bytes dropped)."""
    n = len(data)
    i = data.find(b"\x00\x00\x01")
    while i >= 0:
        start = i + 3
        j = data.find(b"\x00\x00\x01", start)
        end = n if j < 0 else j
        nal = data[start:end].rstrip(
            b"\x00"
        )  # a NAL never ends in 0x00 (rbsp trailing bits): zeros are padding
        if nal:
            yield nal
        i = j


class H264Packetizer:
    """H.264 access units -> RTP packets (RFC 6184 packetization-mode 1: single NAL unit packets and FU-A)."""

    def __init__(self, payload_type: int = PAYLOAD_TYPE, max_payload: int = MAX_RTP_PAYLOAD) -> None:
        if max_payload < 16:
            raise ValueError(f"max_payload must be >= 16 bytes, got {max_payload}")
        self.payload_type = payload_type
        self.max_payload = max_payload
        self.ssrc = secrets.randbits(32)
        self.seq = secrets.randbits(16)
        self.ts_offset = secrets.randbits(32)

    def _header(self, marker: bool, ts: int) -> bytes:
        h = struct.pack("!BBHII", 0x80, (0x80 if marker else 0) | self.payload_type, self.seq, ts, self.ssrc)
        self.seq = (self.seq + 1) & 0xFFFF
        return h

    def packetize(self, annexb: bytes, rtp_ts: int) -> list[bytes]:
        """The RTP packets of one access unit (all NAL units of one frame) at RTP time `rtp_ts` (90 kHz)."""
        ts = (rtp_ts + self.ts_offset) & 0xFFFFFFFF
        nals = list(split_annexb(annexb))
        out: list[bytes] = []
        limit = self.max_payload
        for k, nal in enumerate(nals):
            last_nal = k == len(nals) - 1
            if len(nal) <= limit:
                out.append(self._header(last_nal, ts) + nal)
                continue
            nri_type = nal[0]
            fu_indicator = bytes(((nri_type & 0x60) | 28,))  # FU-A, the NAL's NRI
            nal_type = nri_type & 0x1F
            body = memoryview(nal)[1:]
            step = limit - 2
            for off in range(0, len(body), step):
                first, last = off == 0, off + step >= len(body)
                fu_header = bytes(((0x80 if first else 0) | (0x40 if last else 0) | nal_type,))
                out.append(
                    self._header(last_nal and last, ts) + fu_indicator + fu_header + body[off : off + step]
                )
        return out


def parameter_sets(annexb: bytes) -> tuple[bytes, bytes] | None:
    """(SPS, PPS) of an access unit that carries both (a keyframe with repeat-headers), else None."""
    sps = pps = b""
    for nal in split_annexb(annexb):
        t = nal[0] & 0x1F
        if t == 7 and not sps:
            sps = nal
        elif t == 8 and not pps:
            pps = nal
        elif t in (1, 5):  # slices: the parameter sets come before them
            break
    return (sps, pps) if sps and pps else None


def h264_rtsp_sdp(host: str, fps: int, params: tuple[bytes, bytes] | None, session_id: int) -> str:
    """The DESCRIBE answer: one H.264 video track, control URL trackID=0 (relative to Content-Base)."""
    at = "IP6" if _is_ipv6(host) else "IP4"
    fmtp = f"a=fmtp:{PAYLOAD_TYPE} packetization-mode=1"
    if params is not None:
        sps, pps = params
        sprop = ",".join(base64.b64encode(p).decode("ascii") for p in (sps, pps))
        fmtp += f";profile-level-id={sps[1:4].hex().upper()};sprop-parameter-sets={sprop}"
    lines = [
        "v=0",
        f"o=- {session_id} 1 IN {at} {host}",
        "s=viva-sitl VAC",
        f"c=IN {at} {'::' if at == 'IP6' else '0.0.0.0'}",
        "t=0 0",
        "a=tool:viva-sitl",
        "a=control:*",
        "a=range:npt=now-",
        f"m=video 0 RTP/AVP {PAYLOAD_TYPE}",
        f"a=rtpmap:{PAYLOAD_TYPE} H264/{RTP_CLOCK_HZ}",
        fmtp,
        f"a=framerate:{fps}",
        f"a=control:{TRACK}",
    ]
    return "\r\n".join(lines) + "\r\n"


def _is_ipv6(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).version == 6
    except ValueError:
        return False


# --- RTSP messages ---------------------------------------------------------------------------------------------------
class RtspError(Exception):
    """An RTSP error status for the request being answered (the connection stays open unless `close`)."""

    def __init__(self, status: int, why: str = "", *, close: bool = False, cseq: str | None = None) -> None:
        super().__init__(why or _REASONS.get(status, ""))
        self.status, self.why, self.close, self.cseq = status, why, close, cseq


@dataclass
class Request:
    method: str
    url: str
    headers: dict[str, str]  # lower-case names
    body: bytes = b""

    @property
    def cseq(self) -> str | None:
        return self.headers.get("cseq")


def parse_request(head: bytes) -> Request:
    """Request line and headers (through the blank line). RtspError 400 / 505 for what is not an RTSP/1.0 request."""
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        raise RtspError(400, "request is not UTF-8 text", close=True) from None
    lines = text.split("\r\n") if "\r\n" in text else text.split("\n")
    parts = lines[0].split()
    if len(parts) != 3:
        raise RtspError(400, f"bad request line {lines[0][:80]!r}", close=True)
    method, url, version = parts
    if not version.startswith("RTSP/"):
        raise RtspError(400, f"not an RTSP request: {lines[0][:80]!r}", close=True)
    headers: dict[str, str] = {}
    for line in lines[1:]:
        if not line:
            continue
        name, sep, value = line.partition(":")
        if not sep or not name.strip():
            raise RtspError(400, f"bad header line {line[:80]!r}")
        headers[name.strip().lower()] = value.strip()
    req = Request(method, url, headers)
    if version != "RTSP/1.0":
        raise RtspError(505, f"{version} is not supported (RTSP/1.0 only)", cseq=req.cseq)
    return req


def response(
    status: int, cseq: str | None, headers: dict[str, str] | None = None, body: bytes = b""
) -> bytes:
    lines = [f"RTSP/1.0 {status} {_REASONS.get(status, 'Error')}"]
    if cseq is not None:
        lines.append(f"CSeq: {cseq}")
    lines.append(f"Server: {SERVER_NAME}")
    for k, v in (headers or {}).items():
        lines.append(f"{k}: {v}")
    if body or status != 200:
        lines.append(f"Content-Length: {len(body)}")
    return ("\r\n".join(lines) + "\r\n\r\n").encode("utf-8") + body


@dataclass
class Transport:
    """What SETUP agreed: UDP unicast to (client_ip, rtp_port) or interleaved channels on the RTSP connection."""

    tcp: bool
    rtp_port: int = 0
    rtcp_port: int = 0
    channel: int = 0

    @staticmethod
    def parse(value: str) -> Transport:
        """The first transport of the client's list that the server can do; RtspError 461 when none."""
        why = "no transport offered"
        for spec in value.split(","):
            params = [p.strip() for p in spec.split(";") if p.strip()]
            if not params:
                continue
            proto = params[0].upper()
            kv = dict(p.partition("=")[::2] for p in params[1:])
            if "multicast" in (p.lower() for p in params[1:]):
                why = "multicast is not supported"
                continue
            try:
                if proto in ("RTP/AVP", "RTP/AVP/UDP"):
                    if "client_port" not in kv:
                        why = "UDP transport without client_port"
                        continue
                    lo, _, hi = kv["client_port"].partition("-")
                    rtp = int(lo)
                    rtcp = int(hi) if hi else rtp + 1
                    if not (1 <= rtp <= 65535 and 1 <= rtcp <= 65535):
                        why = f"client_port {kv['client_port']} out of range"
                        continue
                    return Transport(tcp=False, rtp_port=rtp, rtcp_port=rtcp)
                if proto == "RTP/AVP/TCP":
                    lo, _, _hi = kv.get("interleaved", "0-1").partition("-")
                    ch = int(lo)
                    if not 0 <= ch <= 254:
                        why = f"interleaved channel {ch} out of range"
                        continue
                    return Transport(tcp=True, channel=ch)
            except ValueError:
                why = f"bad transport parameters {spec.strip()[:80]!r}"
                continue
            why = f"transport {params[0]!r} is not supported (RTP/AVP unicast UDP or RTP/AVP/TCP)"
        raise RtspError(461, why)

    def header(self, ssrc: int, server_ports: tuple[int, int]) -> str:
        if self.tcp:
            return f"RTP/AVP/TCP;unicast;interleaved={self.channel}-{self.channel + 1};ssrc={ssrc:08X}"
        return (
            f"RTP/AVP;unicast;client_port={self.rtp_port}-{self.rtcp_port};"
            f"server_port={server_ports[0]}-{server_ports[1]};ssrc={ssrc:08X}"
        )


@dataclass(eq=False)
class Session:
    id: str
    conn: _Connection
    transport: Transport
    client_ip: str
    playing: bool = False
    need_keyframe: bool = True
    last_seen: float = field(default_factory=time.monotonic)
    frames_sent: int = 0
    frames_dropped: int = 0  # the client's buffer was full (TCP) or the UDP socket's was


class _Connection:
    """One RTSP control connection (and, for interleaved sessions, their media)."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer
        peer = writer.get_extra_info("peername")
        self.peer_ip: str = peer[0] if isinstance(peer, tuple) else "127.0.0.1"
        self.sessions: dict[str, Session] = {}
        self.closed = False

    def buffered(self) -> int:
        transport = self.writer.transport
        return transport.get_write_buffer_size() if not transport.is_closing() else 1 << 62


class _Discard(asyncio.DatagramProtocol):
    """The server's RTP/RTCP UDP sockets: receivers' RTCP reports and ICMP errors are ignored."""

    def error_received(self, exc: Exception) -> None:  # e.g. port unreachable: the client went away
        pass


# --- the server ------------------------------------------------------------------------------------------------------
class RtspServer:
    """Serves one live H.264 stream at rtsp://host:port/vac; fed with encoded access units by `feed()`."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = DEFAULT_RTSP_PORT,
        *,
        fps: int = 30,
        max_clients: int = 16,
        max_pending_frames: int = 8,
        max_client_buffer_bytes: int = 1 << 20,
        session_timeout_s: float = 60.0,
        describe_wait_s: float = 2.0,
    ) -> None:
        if not 0 <= port <= 65535:
            raise ValueError(f"RTSP port must be in 0..65535 (0 = any free port), got {port}")
        if not 1 <= fps <= 240:
            raise ValueError(f"fps must be in 1..240, got {fps}")
        self.host, self.port, self.fps = host, port, fps
        self.max_clients = max_clients
        self.max_pending_frames = max_pending_frames
        self.max_client_buffer_bytes = max_client_buffer_bytes
        self.session_timeout_s = session_timeout_s
        self.describe_wait_s = describe_wait_s
        self.packetizer = H264Packetizer()
        self.session_id = secrets.randbits(31)
        self._params: tuple[bytes, bytes] | None = None
        self._params_event: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server: asyncio.Server | None = None
        self._rtp: asyncio.DatagramTransport | None = None
        self._rtcp: asyncio.DatagramTransport | None = None
        self._expiry: asyncio.Task[None] | None = None
        self.server_ports = (0, 0)
        self._sessions: dict[str, Session] = {}
        self._conns: set[_Connection] = set()
        self._playing = 0  # sessions playing (read by feed() on the encoder thread: a plain int, GIL-atomic)
        self._pending = 0
        self._pending_lock = threading.Lock()
        # counters
        self.frames_fed = 0
        self.frames_posted = 0
        self.frames_behind = 0  # dropped because the server loop had max_pending_frames waiting
        self.requests = 0
        self.errors_sent = 0
        self.sessions_total = 0
        self.sessions_closed = 0

    # -- lifecycle ---------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Bind the RTSP port and the RTP/RTCP UDP pair; serve on a thread. ValueError when the port is taken."""
        if self._thread is not None:
            raise RuntimeError("RtspServer can be started once")
        ready = threading.Event()
        failure: list[BaseException] = []
        loop = asyncio.new_event_loop()

        def run() -> None:
            asyncio.set_event_loop(loop)
            try:
                loop.run_until_complete(self._open())
            except BaseException as exc:  # reported to start()'s caller
                failure.append(exc)
                ready.set()
                loop.close()
                return
            ready.set()
            try:
                loop.run_forever()
            finally:
                loop.run_until_complete(self._close())
                loop.close()

        self._loop = loop
        self._thread = threading.Thread(target=run, name="video-rtsp", daemon=True)
        self._thread.start()
        ready.wait()
        if failure:
            self._thread.join()
            exc = failure[0]
            raise ValueError(f"RTSP server: cannot listen on {self.host}:{self.port}: {exc}") from None
        log.info("RTSP server on %s (RTP from UDP %d-%d)", self.url, *self.server_ports)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Close every session and the sockets, end the thread (idempotent)."""
        loop, thread = self._loop, self._thread
        if loop is None or thread is None or not thread.is_alive():
            return
        with contextlib.suppress(RuntimeError):  # the loop already closed
            loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout_s)
        if thread.is_alive():
            log.error("RTSP server thread did not stop within %.1f s", timeout_s)

    def __enter__(self) -> RtspServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def url(self) -> str:
        host = self.host
        if host in ("0.0.0.0", "::", ""):
            host = _reachable_address()
        if _is_ipv6(host):
            host = f"[{host}]"
        return f"rtsp://{host}:{self.port}/{STREAM_PATH}"

    @property
    def clients(self) -> int:
        """Sessions that are set up (playing or not)."""
        return len(self._sessions)

    @property
    def playing(self) -> int:
        return self._playing

    def stats(self) -> dict[str, Any]:
        sessions = list(self._sessions.values())
        return {
            "url": self.url,
            "clients": len(sessions),
            "playing": self._playing,
            "sessions_total": self.sessions_total,
            "sessions_closed": self.sessions_closed,
            "frames_fed": self.frames_fed,
            "frames_posted": self.frames_posted,
            "frames_behind": self.frames_behind,
            "client_frames_dropped": sum(s.frames_dropped for s in sessions),
            "requests": self.requests,
            "errors_sent": self.errors_sent,
        }

    # -- the encoder's side ------------------------------------------------------------------------------------
    def feed(self, annexb: bytes, rtp_ts: int, keyframe: bool) -> None:
        """One encoded access unit (Annex-B) and its presentation time in 90 kHz units. Any thread; never blocks; cheap when idle."""
        self.frames_fed += 1
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        if keyframe:
            params = parameter_sets(annexb)
            if params is not None and params != self._params:
                self._params = params
                with contextlib.suppress(RuntimeError):
                    loop.call_soon_threadsafe(self._params_known)
        if self._playing == 0:
            return  # nobody to send to: no packetisation, no hand-over
        with self._pending_lock:
            if self._pending >= self.max_pending_frames:
                self.frames_behind += 1
                return
            self._pending += 1
        packets = self.packetizer.packetize(annexb, rtp_ts)
        try:
            loop.call_soon_threadsafe(self._fanout, packets, keyframe)
            self.frames_posted += 1
        except RuntimeError:  # the loop closed meanwhile
            with self._pending_lock:
                self._pending -= 1

    # -- the loop's side -----------------------------------------------------------------------------------------
    def _params_known(self) -> None:
        if self._params_event is not None:
            self._params_event.set()

    def _fanout(self, packets: list[bytes], keyframe: bool) -> None:
        with self._pending_lock:
            self._pending -= 1
        interleaved: bytes | None = None
        for s in list(self._sessions.values()):
            if not s.playing:
                continue
            if s.need_keyframe and not keyframe:
                continue
            try:
                interleaved = self._send(s, packets, interleaved)
            except (OSError, RuntimeError) as exc:  # a transport that broke under us: that client only
                log.debug("RTSP session %s: send failed: %s", s.id, exc)
                s.frames_dropped += 1
                s.need_keyframe = True

    def _send(self, s: Session, packets: list[bytes], interleaved: bytes | None) -> bytes | None:
        """Send one frame's packets to one session (or count it missed when its buffer is full); returns the
        channel-0 interleaved bytes, built once per frame for every interleaved session."""
        if s.transport.tcp:
            if s.conn.buffered() > self.max_client_buffer_bytes:
                s.frames_dropped += 1
                s.need_keyframe = True
                return interleaved
            ch = s.transport.channel
            if ch == 0 and interleaved is not None:
                data = interleaved
            else:
                data = b"".join(struct.pack("!BBH", 0x24, ch, len(p)) + p for p in packets)
                if ch == 0:
                    interleaved = data
            s.conn.writer.write(data)
        else:
            rtp = self._rtp
            if rtp is None or _udp_buffered(rtp) > self.max_client_buffer_bytes:
                s.frames_dropped += 1
                s.need_keyframe = True
                return interleaved
            addr = (s.client_ip, s.transport.rtp_port)
            for p in packets:
                rtp.sendto(p, addr)
        s.need_keyframe = False
        s.frames_sent += 1
        return interleaved

    async def _open(self) -> None:
        self._params_event = asyncio.Event()
        if self._params is not None:
            self._params_event.set()
        self._server = await asyncio.start_server(
            self._serve, self.host, self.port, limit=_MAX_REQUEST_BYTES, reuse_address=True
        )
        self.port = self._server.sockets[0].getsockname()[1]
        self._rtp, self._rtcp, self.server_ports = await self._udp_pair()
        self._expiry = asyncio.get_running_loop().create_task(self._expire_sessions())

    async def _udp_pair(self) -> tuple[asyncio.DatagramTransport, asyncio.DatagramTransport, tuple[int, int]]:
        """An even UDP port for RTP and the next one for RTCP (RFC 3550), on the server's address family."""
        loop = asyncio.get_running_loop()
        family = socket.AF_INET6 if _is_ipv6(self.host) else socket.AF_INET
        try:  # the RTSP address when it is one (loopback stays loopback), else every interface
            bind_host = str(ipaddress.ip_address(self.host))
        except ValueError:
            bind_host = "::" if family == socket.AF_INET6 else "0.0.0.0"
        for _ in range(50):
            rtp, _p = await loop.create_datagram_endpoint(_Discard, local_addr=(bind_host, 0), family=family)
            port = rtp.get_extra_info("sockname")[1]
            if port % 2 == 0 and port < 65535:
                try:
                    rtcp, _q = await loop.create_datagram_endpoint(
                        _Discard, local_addr=(bind_host, port + 1), family=family
                    )
                except OSError:
                    rtp.close()
                    continue
                return rtp, rtcp, (port, port + 1)
            rtp.close()
        raise OSError("no free even/odd UDP port pair for RTP/RTCP")

    async def _close(self) -> None:
        for conn in list(self._conns):
            self._drop_connection(conn)
            _close_writer(conn.writer)
        if self._server is not None:
            self._server.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 1.0)
        for udp in (self._rtp, self._rtcp):
            if udp is not None:
                udp.close()
        tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    async def _expire_sessions(self) -> None:
        while True:
            await asyncio.sleep(min(5.0, self.session_timeout_s / 4))
            now = time.monotonic()
            for s in list(self._sessions.values()):
                if not s.transport.tcp and now - s.last_seen > self.session_timeout_s:
                    log.info("RTSP session %s of %s timed out (no keep-alive)", s.id, s.client_ip)
                    self._end_session(s)

    def _end_session(self, s: Session) -> None:
        if self._sessions.pop(s.id, None) is None:
            return
        s.conn.sessions.pop(s.id, None)
        if s.playing:
            s.playing = False
            self._playing -= 1
        self.sessions_closed += 1

    def _drop_connection(self, conn: _Connection) -> None:
        conn.closed = True
        self._conns.discard(conn)
        for s in list(conn.sessions.values()):
            self._end_session(s)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        conn = _Connection(reader, writer)
        self._conns.add(conn)
        try:
            while True:
                first = await reader.read(1)
                if not first:
                    return  # the client closed the connection
                if first == b"$":  # interleaved data from the client (its RTCP receiver reports): skipped
                    _ch, length = struct.unpack("!BH", await reader.readexactly(3))
                    await reader.readexactly(length)
                    for s in conn.sessions.values():
                        s.last_seen = time.monotonic()
                    continue
                try:
                    head = first + await reader.readuntil(b"\r\n\r\n")
                except asyncio.LimitOverrunError:
                    await self._reply(conn, response(400, None, body=b"request headers too long\r\n"), True)
                    return
                close = await self._handle(conn, head)
                if close:
                    return
        except (asyncio.IncompleteReadError, ConnectionError, OSError):
            return  # vanished mid-message: its sessions end below
        finally:
            self._drop_connection(conn)
            _close_writer(writer)
            with contextlib.suppress(Exception):
                await asyncio.wait_for(writer.wait_closed(), 1.0)

    async def _reply(self, conn: _Connection, data: bytes, error: bool = False) -> None:
        if error:
            self.errors_sent += 1
        conn.writer.write(data)
        await conn.writer.drain()

    async def _handle(self, conn: _Connection, head: bytes) -> bool:
        """Answer one request; True when the connection is to be closed."""
        self.requests += 1
        cseq: str | None = None
        try:
            req = parse_request(head)
            cseq = req.cseq
            length = req.headers.get("content-length", "0")
            if not length.isdigit() or int(length) > _MAX_BODY_BYTES:
                raise RtspError(400, f"bad Content-Length {length[:20]!r}", close=True)
            req.body = await conn.reader.readexactly(int(length)) if int(length) else b""
            if cseq is None:
                raise RtspError(400, "no CSeq header")
            status, headers, body = await self._dispatch(conn, req)
        except RtspError as exc:
            cseq = cseq if cseq is not None else exc.cseq
            log.debug("RTSP %s: %d %s", conn.peer_ip, exc.status, exc.why)
            body = (exc.why + "\r\n").encode("utf-8") if exc.why else b""
            await self._reply(conn, response(exc.status, cseq, body=body), True)
            return exc.close
        await self._reply(conn, response(status, cseq, headers, body))
        return False

    def _check_url(self, url: str, *, track: bool | None) -> None:
        """404 unless `url` names the stream (track None: the stream or its track; False: the stream only)."""
        try:
            path = urlsplit(url).path.strip("/")
        except ValueError:
            raise RtspError(400, f"bad URL {url[:80]!r}") from None
        ok_stream = path == STREAM_PATH
        ok_track = path == f"{STREAM_PATH}/{TRACK}"
        if track is None and (ok_stream or ok_track):
            return
        if track is False and ok_stream:
            return
        if track is False and ok_track:
            raise RtspError(459, "use the stream URL (aggregate control) for this request")
        raise RtspError(404, f"no stream at {url[:120]!r} (this server has /{STREAM_PATH})")

    def _session_of(self, conn: _Connection, req: Request) -> Session:
        sid = req.headers.get("session", "").split(";")[0].strip()
        if not sid:
            raise RtspError(454, "no Session header")
        s = self._sessions.get(sid)
        if s is None:
            raise RtspError(454, f"no session {sid[:40]!r}")
        if s.conn is not conn and s.transport.tcp:
            raise RtspError(455, "an interleaved session is controlled on its own connection")
        s.last_seen = time.monotonic()
        return s

    def _session_header(self, s: Session) -> str:
        return f"{s.id};timeout={max(1, round(self.session_timeout_s))}"

    async def _dispatch(self, conn: _Connection, req: Request) -> tuple[int, dict[str, str], bytes]:
        m = req.method
        for s in conn.sessions.values():  # any request on the connection keeps its sessions alive
            s.last_seen = time.monotonic()
        if m not in _METHODS:
            if m in _KNOWN_METHODS:
                raise RtspError(405, f"{m} is not allowed on a live stream")
            raise RtspError(501, f"method {m[:40]!r} is not implemented")
        if m == "OPTIONS":
            if req.url != "*":
                self._check_url(req.url, track=None)
            return 200, {"Public": ", ".join(_METHODS)}, b""
        if m == "DESCRIBE":
            self._check_url(req.url, track=False)
            accept = req.headers.get("accept", "application/sdp")
            if "application/sdp" not in accept and "*/*" not in accept:
                raise RtspError(406, f"only application/sdp is offered, not {accept[:60]!r}")
            if self._params is None and self._params_event is not None:  # a moment for the first keyframe
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._params_event.wait(), self.describe_wait_s)
            sdp_host = self.host if self.host not in ("", "0.0.0.0", "::") else _reachable_address()
            sdp = h264_rtsp_sdp(sdp_host, self.fps, self._params, self.session_id).encode("utf-8")
            base = self.url.replace(f"/{STREAM_PATH}", f"/{STREAM_PATH}/")
            return 200, {"Content-Type": "application/sdp", "Content-Base": base}, sdp
        if m == "SETUP":
            self._check_url(req.url, track=None)
            transport = Transport.parse(req.headers.get("transport", ""))
            if "session" in req.headers:  # a second SETUP in the session: we have only one track
                s = self._session_of(conn, req)
                raise RtspError(459, f"session {s.id} already has the stream's one track")
            if len(self._sessions) >= self.max_clients:
                raise RtspError(453, f"{self.max_clients} clients are already set up")
            s = Session(secrets.token_hex(8), conn, transport, conn.peer_ip)
            self._sessions[s.id] = s
            conn.sessions[s.id] = s
            self.sessions_total += 1
            headers = {
                "Transport": transport.header(self.packetizer.ssrc, self.server_ports),
                "Session": self._session_header(s),
            }
            return 200, headers, b""
        if m == "PLAY":
            self._check_url(req.url, track=None)
            s = self._session_of(conn, req)
            if not s.playing:
                s.playing, s.need_keyframe = True, True
                self._playing += 1
            return 200, {"Session": self._session_header(s), "Range": "npt=now-"}, b""
        if m == "PAUSE":
            self._check_url(req.url, track=None)
            s = self._session_of(conn, req)
            if s.playing:
                s.playing = False
                self._playing -= 1
            return 200, {"Session": self._session_header(s)}, b""
        if m == "TEARDOWN":
            self._check_url(req.url, track=None)
            s = self._session_of(conn, req)
            self._end_session(s)
            return 200, {}, b""
        # GET_PARAMETER: a keep-alive (an empty body) or a question about parameters we do not have
        if "session" in req.headers:
            s = self._session_of(conn, req)
            return 200, {"Session": self._session_header(s)}, b""
        return 200, {}, b""


def _close_writer(writer: asyncio.StreamWriter) -> None:
    """Close a connection; one with unsent data (a client that stopped reading) is reset, not waited for."""
    transport = writer.transport
    if transport.is_closing():
        return
    if transport.get_write_buffer_size() > 0:
        transport.abort()
    else:
        writer.close()


def _udp_buffered(transport: asyncio.DatagramTransport) -> int:
    """Bytes waiting in a UDP transport (asyncio's selector transport has the count; typeshed does not say so)."""
    size = getattr(transport, "get_write_buffer_size", None)
    return int(size()) if callable(size) else 0


def _reachable_address() -> str:
    """This host's address as other machines see it (for a server bound to 0.0.0.0), loopback as a fallback."""
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(
                ("192.0.2.1", 9)
            )  # TEST-NET-1: nothing is sent, the kernel just picks the outgoing address
            return str(s.getsockname()[0])
    except OSError:
        return "127.0.0.1"
