"""Helpers for the end-to-end tests: a `viva-sitl run` subprocess on free ports, a pymavlink peer, script runs.

- `SitlProcess`: starts `python -m viva_sitl run` on given ports, waits for its `viva-sitl ready` line (with a
  timeout), keeps its stdout/stderr for failure reports, and always ends it (SIGINT, then SIGKILL of its process
  group) so no test leaks a process.
- `MavlinkPeer`: a UDP socket bound where viva-sitl sends (the API or GCS port), decoding with pymavlink's codec in a
  thread; it records every message, answers with a GCS heartbeat each second and offers `wait`/`command`/`upload`.
- `run_script`: runs a mission script as a subprocess (own process group, killed whole on timeout) and parses its
  `RESULT key=value ...` line.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

REPO_ROOT = Path(__file__).resolve().parents[1]
MISSION_SCRIPTS = REPO_ROOT / "mission_scripts"
EARTH_RADIUS_M = 6371000.0
RECV_BUFFER_BYTES = 4 * 1024 * 1024
READY_PREFIX = "viva-sitl ready"
STOPPED_PREFIX = "viva-sitl stopped:"

# PX4 custom_mode values (main << 16 | sub << 24)
MODE_OFFBOARD = 6 << 16
MODE_AUTO_TAKEOFF = (4 << 16) | (2 << 24)
MODE_AUTO_LOITER = (4 << 16) | (3 << 24)
MODE_AUTO_MISSION = (4 << 16) | (4 << 24)
MODE_AUTO_RTL = (4 << 16) | (5 << 24)
MODE_AUTO_LAND = (4 << 16) | (6 << 24)


def e2e_speed() -> float:
    """Speed factor for end-to-end flights (VIVA_E2E_SPEED, default 3)."""
    return float(os.environ.get("VIVA_E2E_SPEED", "3"))


PREARM_CHECK_BIT = 0x10000000  # MAV_SYS_STATUS_PREARM_CHECK


class SitlError(RuntimeError):
    """viva-sitl did not start, or a peer wait failed; the message carries the process logs."""


def free_udp_ports(count: int) -> list[int]:
    """`count` distinct UDP ports free on 127.0.0.1 right now (bound together, then released)."""
    socks = []
    try:
        for _ in range(count):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class SitlPorts:
    """Remote ports (where viva-sitl sends: the clients listen there) and viva-sitl's own local ports."""

    api: int
    gcs: int
    api_local: int
    gcs_local: int

    @classmethod
    def free(cls) -> SitlPorts:
        return cls(*free_udp_ports(4))

    @property
    def mavsdk_url(self) -> str:
        return f"udpin://127.0.0.1:{self.api}"

    @property
    def pymavlink_url(self) -> str:
        return f"udpin:127.0.0.1:{self.gcs}"


@dataclass
class SitlProcess:
    """One `viva-sitl run` subprocess. Use as a context manager, or call start()/stop()."""

    workdir: Path
    ports: SitlPorts = field(default_factory=SitlPorts.free)
    footage: str = "synthetic"
    speed: float = 1.0
    instance: int | None = None
    video_port: int | None = None  # None: --no-video; else H.264 RTP to this UDP port (+ a frame socket)
    frame_socket_port: int = field(default_factory=free_tcp_port)  # used with video only
    extra_args: Sequence[str] = ()
    ready_timeout_s: float = 60.0
    name: str = "sitl"
    proc: subprocess.Popen[str] | None = field(default=None, init=False)
    ready_line: str = field(default="", init=False)
    stdout_lines: list[str] = field(default_factory=list, init=False)
    returncode: int | None = field(default=None, init=False)
    _ready: threading.Event = field(default_factory=threading.Event, init=False)
    _reader: threading.Thread | None = field(default=None, init=False)

    @property
    def stderr_path(self) -> Path:
        return self.workdir / f"{self.name}.stderr.log"

    def command(self) -> list[str]:
        cmd = [
            sys.executable,
            "-m",
            "viva_sitl",
            "run",
            "--footage",
            self.footage,
            "--speed",
            repr(self.speed),
        ]
        cmd += ["--api-port", str(self.ports.api), "--gcs-port", str(self.ports.gcs)]
        cmd += ["--api-local-port", str(self.ports.api_local), "--gcs-local-port", str(self.ports.gcs_local)]
        cmd += ["--listen", "127.0.0.1", "--run-dir", str(self.workdir / f"{self.name}-run")]
        if self.video_port is None:
            cmd += ["--no-video"]
        else:
            cmd += [
                "--video-port",
                str(self.video_port),
                "--frame-socket",
                f"tcp://127.0.0.1:{self.frame_socket_port}",
            ]
        if self.instance is not None:
            cmd += ["--instance", str(self.instance)]
        return cmd + list(self.extra_args)

    def start(self) -> SitlProcess:
        self.workdir.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), env.get("PYTHONPATH", "")) if p)
        with self.stderr_path.open(
            "w"
        ) as err:  # a file, not a pipe: a chatty stderr can never block the child
            self.proc = subprocess.Popen(
                self.command(),
                cwd=self.workdir,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
                env=env,
                start_new_session=True,  # its own process group: stop() can end it and anything it spawned
            )
        self._reader = threading.Thread(target=self._read_stdout, name=f"{self.name}-stdout", daemon=True)
        self._reader.start()
        deadline = time.monotonic() + self.ready_timeout_s
        while not self._ready.wait(0.1):
            if self.proc.poll() is not None:
                self._reader.join(timeout=2.0)
                raise SitlError(f"viva-sitl exited with {self.proc.returncode} before ready\n{self.logs()}")
            if time.monotonic() > deadline:
                self.stop()
                raise SitlError(f"viva-sitl not ready within {self.ready_timeout_s:.0f} s\n{self.logs()}")
        return self

    def _read_stdout(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        for line in self.proc.stdout:
            self.stdout_lines.append(line.rstrip("\n"))
            if line.startswith(READY_PREFIX) and not self._ready.is_set():
                self.ready_line = line.strip()
                self._ready.set()

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self, timeout_s: float = 10.0) -> int | None:
        """SIGINT (clean shutdown), then SIGKILL of the whole process group; returns the exit status."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(timeout=5.0)
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)  # stragglers in its group, if any
        if self._reader is not None:
            self._reader.join(timeout=2.0)
        self.returncode = self.proc.returncode
        return self.returncode

    def stop_stats(self) -> dict[str, Any]:
        """The JSON of the `viva-sitl stopped: {...}` line printed on a clean exit ({} if absent)."""
        for line in reversed(self.stderr_text().splitlines()):
            if line.startswith(STOPPED_PREFIX):
                return dict(json.loads(line[len(STOPPED_PREFIX) :]))
        return {}

    def stderr_text(self) -> str:
        try:
            return self.stderr_path.read_text(errors="replace")
        except FileNotFoundError:
            return ""

    def logs(self, tail_chars: int = 6000) -> str:
        out = "\n".join(self.stdout_lines)[-tail_chars:]
        err = self.stderr_text()[-tail_chars:]
        return f"--- {self.name} command: {' '.join(self.command())}\n--- stdout:\n{out}\n--- stderr:\n{err}"

    def __enter__(self) -> SitlProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


@dataclass
class Record:
    t_s: float  # time.monotonic() on receipt
    msg: Any  # a pymavlink MAVLink_message


class MavlinkPeer:
    """A pymavlink-codec peer on a UDP port where viva-sitl sends; replies go to whoever sent last (viva-sitl)."""

    def __init__(
        self, port: int, host: str = "127.0.0.1", src_system: int = 255, src_component: int = 190
    ) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # A large receive buffer: on a loaded machine this Python thread can stall for a second or two, and the default
        # (~200 KB, a few hundred datagrams) would then drop telemetry the assertions look at.
        with contextlib.suppress(OSError):
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECV_BUFFER_BYTES)
        self.sock.bind((host, port))
        self.sock.settimeout(0.1)
        self.mav = mavlink2.MAVLink(
            self, srcSystem=src_system, srcComponent=src_component
        )  # file=self: write()
        self.mav.robust_parsing = True
        self.peer: tuple[str, int] | None = None
        # Every address that sent to us; with send_to_all, each message goes to all of them, as a ground station's
        # one UDP link does when several vehicles (PX4 SITL -i 0, -i 1, ...) all send to its port 14550.
        self.remotes: list[tuple[str, int]] = []
        self.send_to_all = False
        self.records: list[Record] = []
        self.bad_data = 0
        self.lost = (
            0  # messages missing from the MAVLink sequence numbers (dropped on the way or in our buffer)
        )
        self._last_seq: dict[tuple[int, int], int] = {}
        self.heartbeat = True  # set False to fall silent (link-loss tests)
        self.last_heartbeat_sent_s = -math.inf
        self._cond = threading.Condition()
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"mavlink-peer-{port}", daemon=True)
        self._thread.start()

    # --- I/O ---------------------------------------------------------------------------------------------------
    def write(self, buf: bytes) -> None:  # pymavlink calls this from mav.send()/xxx_send()
        if self.send_to_all:
            for addr in list(self.remotes):
                self.sock.sendto(buf, addr)
        elif self.peer is not None:
            self.sock.sendto(buf, self.peer)

    def send(self, msg: Any) -> None:
        with self._send_lock:
            self.mav.send(msg)

    def send_raw(self, data: bytes) -> None:
        if self.peer is None:
            raise SitlError("no datagram from viva-sitl yet: peer address unknown")
        self.sock.sendto(data, self.peer)

    def _run(self) -> None:
        next_hb = 0.0
        # One parser for the stream from viva-sitl: our own MAVLink object only encodes (its parse state is
        # touched by nobody else).
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        while not self._stop.is_set():
            now = time.monotonic()
            if self.heartbeat and self.peer is not None and now >= next_hb:
                with self._send_lock:
                    self.mav.heartbeat_send(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                self.last_heartbeat_sent_s = now
                next_hb = now + 1.0
            try:
                data, addr = self.sock.recvfrom(65536)
            except (TimeoutError, OSError):
                continue
            self.peer = addr
            if addr not in self.remotes:
                self.remotes.append(addr)
            msgs = parser.parse_buffer(data) or []
            t = time.monotonic()
            with self._cond:
                for m in msgs:
                    if m.get_type() == "BAD_DATA":
                        self.bad_data += 1
                        continue
                    key = (m.get_srcSystem(), m.get_srcComponent())
                    if key in self._last_seq:
                        self.lost += (m.get_seq() - self._last_seq[key] - 1) % 256
                    self._last_seq[key] = m.get_seq()
                    self.records.append(Record(t, m))
                self._cond.notify_all()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.sock.close()

    def __enter__(self) -> MavlinkPeer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- queries -----------------------------------------------------------------------------------------------
    def messages(self, kind: str, since_s: float = 0.0, component: int | None = None) -> list[Any]:
        with self._cond:
            return [
                r.msg
                for r in self.records
                if r.t_s >= since_s
                and r.msg.get_type() == kind
                and (component is None or r.msg.get_srcComponent() == component)
            ]

    def latest(self, kind: str, component: int | None = None) -> Any:  # None when never received
        with self._cond:
            for r in reversed(self.records):
                if r.msg.get_type() == kind and (component is None or r.msg.get_srcComponent() == component):
                    return r.msg
        return None

    def wait(
        self,
        kind: str | Iterable[str],
        predicate: Callable[[Any], bool] = lambda m: True,
        timeout_s: float = 10.0,
        since_s: float | None = None,
        what: str = "",
    ) -> Any:
        """First message of `kind` received after `since_s` (default: now) that satisfies `predicate`."""
        kinds = {kind} if isinstance(kind, str) else set(kind)
        start = time.monotonic() if since_s is None else since_s
        deadline = time.monotonic() + timeout_s
        index = 0
        with self._cond:
            while True:
                for r in self.records[index:]:
                    if r.t_s >= start and r.msg.get_type() in kinds and predicate(r.msg):
                        return r.msg
                index = len(self.records)
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    last = {
                        k: self.latest_unlocked(k) for k in ("HEARTBEAT", "LOCAL_POSITION_NED", "STATUSTEXT")
                    }
                    raise SitlError(
                        f"timed out after {timeout_s} s waiting for {what or kinds}; last seen: {last}"
                    )
                self._cond.wait(min(remaining, 0.2))

    def latest_unlocked(self, kind: str) -> Any | None:
        for r in reversed(self.records):
            if r.msg.get_type() == kind:
                return r.msg
        return None

    def wait_autopilot(self, timeout_s: float = 15.0) -> Any:
        return self.wait(
            "HEARTBEAT", lambda m: m.get_srcComponent() == 1, timeout_s, since_s=0.0, what="heartbeat"
        )

    def wait_armable(self, timeout_s: float = 15.0) -> Any:
        """SYS_STATUS with the pre-arm check bit healthy (what MAVSDK's is_armable reads)."""
        return self.wait(
            "SYS_STATUS",
            lambda m: bool(m.onboard_control_sensors_health & PREARM_CHECK_BIT),
            timeout_s,
            since_s=0.0,
            what="pre-arm checks passing (SYS_STATUS)",
        )

    # --- actions -----------------------------------------------------------------------------------------------
    def command_long(
        self,
        command: int,
        params: Sequence[float] = (),
        target: tuple[int, int] = (1, 1),
        timeout_s: float = 3.0,
    ) -> Any:
        """COMMAND_LONG, resent every 0.5 s until its COMMAND_ACK (IN_PROGRESS extends the wait); returns the ACK."""
        p = (list(params) + [0.0] * 7)[:7]
        deadline = time.monotonic() + timeout_s
        confirmation = 0
        while time.monotonic() < deadline:
            t0 = time.monotonic()
            self.send(self.mav.command_long_encode(target[0], target[1], command, confirmation, *p))
            try:
                ack = self.wait(
                    "COMMAND_ACK",
                    lambda m: m.command == command,
                    timeout_s=min(0.5, max(0.01, deadline - t0)),
                    since_s=t0,
                    what=f"ACK of command {command}",
                )
            except SitlError:
                confirmation = min(confirmation + 1, 255)
                continue
            if ack.result == mavlink2.MAV_RESULT_IN_PROGRESS:
                ack = self.wait(
                    "COMMAND_ACK",
                    lambda m: m.command == command and m.result != mavlink2.MAV_RESULT_IN_PROGRESS,
                    max(0.01, deadline - time.monotonic()),
                    since_s=t0,
                    what=f"final ACK of command {command}",
                )
            return ack
        raise SitlError(f"no COMMAND_ACK for command {command} within {timeout_s} s")

    def set_param(
        self, name: str, value: float, target: tuple[int, int] = (1, 1), timeout_s: float = 3.0
    ) -> Any:
        """PARAM_SET (REAL32) and the PARAM_VALUE echo."""
        t0 = time.monotonic()
        self.send(
            self.mav.param_set_encode(
                target[0], target[1], name.encode(), value, mavlink2.MAV_PARAM_TYPE_REAL32
            )
        )
        return self.wait(
            "PARAM_VALUE", lambda m: m.param_id == name, timeout_s, since_s=t0, what=f"PARAM_VALUE {name}"
        )

    def get_param(self, name: str, target: tuple[int, int] = (1, 1), timeout_s: float = 3.0) -> float:
        """PARAM_REQUEST_READ by name -> the PARAM_VALUE's value (REAL32 parameters)."""
        t0 = time.monotonic()
        self.send(self.mav.param_request_read_encode(target[0], target[1], name.encode(), -1))
        msg = self.wait(
            "PARAM_VALUE", lambda m: m.param_id == name, timeout_s, since_s=t0, what=f"PARAM_VALUE {name}"
        )
        return float(msg.param_value)

    def set_param_int(
        self, name: str, value: int, target: tuple[int, int] = (1, 1), timeout_s: float = 3.0
    ) -> int:
        """PARAM_SET of an INT32 parameter with PX4's bytewise encoding; returns the echoed value."""
        as_float = struct.unpack("<f", struct.pack("<i", value))[0]
        t0 = time.monotonic()
        self.send(
            self.mav.param_set_encode(
                target[0], target[1], name.encode(), as_float, mavlink2.MAV_PARAM_TYPE_INT32
            )
        )
        echo = self.wait(
            "PARAM_VALUE", lambda m: m.param_id == name, timeout_s, since_s=t0, what=f"PARAM_VALUE {name}"
        )
        return int(struct.unpack("<i", struct.pack("<f", echo.param_value))[0])

    def upload_mission(
        self, items: Sequence[Any], target: tuple[int, int] = (1, 1), timeout_s: float = 10.0
    ) -> Any:
        """Mission upload handshake; `items` are MISSION_ITEM_INT messages (seq set). Returns the MISSION_ACK."""
        t0 = time.monotonic()
        self.send(self.mav.mission_count_encode(target[0], target[1], len(items), 0))
        deadline = t0 + timeout_s
        handled = t0
        while True:
            msg = self.wait(
                ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"),
                timeout_s=max(0.01, deadline - time.monotonic()),
                since_s=handled,
                what="mission request/ack",
            )
            handled = time.monotonic()
            if msg.get_type() == "MISSION_ACK":
                return msg
            self.send(items[msg.seq])

    def local_position(self) -> tuple[float, float, float]:
        m = self.latest("LOCAL_POSITION_NED")
        if m is None:
            raise SitlError("no LOCAL_POSITION_NED received")
        return float(m.x), float(m.y), float(m.z)


LANDED_ON_GROUND, LANDED_IN_AIR, LANDED_TAKEOFF, LANDED_LANDING = 1, 2, 3, 4


def modes_seen(peer: MavlinkPeer) -> list[int]:
    seen: list[int] = []
    for hb in peer.messages("HEARTBEAT", component=1):
        if not seen or seen[-1] != hb.custom_mode:
            seen.append(hb.custom_mode)
    return seen


def landed_states_seen(peer: MavlinkPeer) -> list[int]:
    seen: list[int] = []
    for m in peer.messages("EXTENDED_SYS_STATE"):
        if not seen or seen[-1] != m.landed_state:
            seen.append(m.landed_state)
    return seen


def assert_landed_disarmed(
    peer: MavlinkPeer, near: tuple[float, float] | None = None, tol_m: float = 1.0
) -> None:
    hb = peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, 5.0, what="a heartbeat")
    assert not is_armed(hb), "still armed after the script ended"
    ext = peer.wait("EXTENDED_SYS_STATE", timeout_s=5.0)
    assert ext.landed_state == LANDED_ON_GROUND
    x, y, z = peer.local_position()
    assert abs(z) < 0.3, f"not on the ground: z = {z:.2f} m"
    if near is not None:
        assert math.hypot(x - near[0], y - near[1]) < tol_m, f"landed at ({x:.2f}, {y:.2f}), expected {near}"


class SetpointStreamer:
    """Streams a fixed SET_POSITION_TARGET_LOCAL_NED at 20 Hz from a thread, like an offboard companion."""

    def __init__(self, peer: MavlinkPeer, msg: Any) -> None:
        self.peer, self.msg = peer, msg  # replace .msg to change the setpoint
        self.sent = 0
        self._sent_cond = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.05):
            self.peer.send(self.msg)
            with self._sent_cond:
                self.sent += 1
                self._sent_cond.notify_all()

    def wait_sent(self, count: int, timeout_s: float = 10.0) -> None:
        """Until `count` setpoints have gone out (20 = PX4's "stream for a second before OFFBOARD")."""
        with self._sent_cond:
            if not self._sent_cond.wait_for(lambda: self.sent >= count, timeout_s):
                raise SitlError(f"only {self.sent} of {count} setpoints sent within {timeout_s} s")

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


def offset(lat: float, lon: float, north_m: float, east_m: float) -> tuple[int, int]:
    """(lat*1e7, lon*1e7) of a point north_m/east_m from (lat, lon) (flat earth)."""
    lat2 = lat + math.degrees(north_m / EARTH_RADIUS_M)
    lon2 = lon + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat))))
    return round(lat2 * 1e7), round(lon2 * 1e7)


def home_of(peer: MavlinkPeer) -> tuple[float, float]:
    ack = peer.command_long(mavlink2.MAV_CMD_REQUEST_MESSAGE, [float(mavlink2.MAVLINK_MSG_ID_HOME_POSITION)])
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED, (
        f"REQUEST_MESSAGE HOME_POSITION: MAV_RESULT {ack.result}"
    )
    home = peer.wait("HOME_POSITION", timeout_s=5.0, since_s=0.0)
    return home.latitude / 1e7, home.longitude / 1e7


def takeoff(peer: MavlinkPeer, altitude_m: float, timeout_s: float = 60.0) -> Any:
    """MIS_TAKEOFF_ALT, wait armable, arm, NAV_TAKEOFF (NaN params, as MAVSDK); returns the settled LOCAL_POSITION_NED."""
    peer.set_param("MIS_TAKEOFF_ALT", altitude_m)
    peer.wait_armable()
    ack = peer.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, [1.0])
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED, f"arm: MAV_RESULT {ack.result}"
    ack = peer.command_long(mavlink2.MAV_CMD_NAV_TAKEOFF, [math.nan] * 7)
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED, f"takeoff: MAV_RESULT {ack.result}"
    return peer.wait(
        "LOCAL_POSITION_NED",
        lambda m: m.z < -(altitude_m - 0.3) and math.hypot(m.vx, m.vy, m.vz) < 0.2,
        timeout_s,
        what=f"hover at {altitude_m} m",
    )


def is_armed(heartbeat: Any) -> bool:
    return bool(heartbeat.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)


def finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def mavsdk_servers_on(port: int) -> list[str]:
    """Command lines of running mavsdk_server processes serving gRPC on `port`."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            args = cmdline.read_bytes().split(b"\0")
        except OSError:
            continue
        if args and args[0].endswith(b"mavsdk_server") and str(port).encode() in args:
            found.append(b" ".join(args).decode(errors="replace"))
    return found


@dataclass(frozen=True)
class ScriptRun:
    returncode: int
    stdout: str
    stderr: str
    result: dict[str, str]

    def describe(self) -> str:
        return (
            f"exit {self.returncode}\n--- stdout:\n{self.stdout[-4000:]}\n--- stderr:\n{self.stderr[-4000:]}"
        )


def run_script(name: str, args: Sequence[str], timeout_s: float = 120.0) -> ScriptRun:
    """Run mission_scripts/<name> with this interpreter; on timeout kill its whole process group."""
    proc = subprocess.Popen(
        [sys.executable, str(MISSION_SCRIPTS / name), *args],
        cwd=REPO_ROOT,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # the gRPC API spawns mavsdk_server: kill the group, leak nothing
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        err += f"\n[test harness] killed after {timeout_s:.0f} s"
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)  # children left behind (e.g. mavsdk_server)
    result: dict[str, str] = {}
    for line in out.splitlines():
        if line.startswith("RESULT "):
            result = dict(kv.split("=", 1) for kv in line[len("RESULT ") :].split() if "=" in kv)
    return ScriptRun(proc.returncode, out, err, result)
