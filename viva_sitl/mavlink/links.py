"""The endpoint's transport half (aiortc's habit: transport below, protocol above): bytes in and out of the links.

    Transport (a UDP socket, or the in-memory one of mavlink/testing.py) --datagram--> Links.receive
        -> [held while a pilot's compute is charged] -> per-peer DatagramParser (signing rules) -> deliver(msg)
    Links.send / reply / broadcast / statustext: encode (sign), record in the .tlog, sendto each target peer.

A link knows its peers (who talked in the last `peer_timeout_s` of the endpoint's clock, at most MAX_PEERS_PER_LINK)
and its configured remote; it knows nothing of what the messages mean (that is dispatch.py) or when telemetry is
due (schedule.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import math
import socket
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from viva_sitl.mavlink.base import (
    Component,
    EventListener,
    LinkKind,
    MavMessage,
    Origin,
    statustext_messages,
)
from viva_sitl.mavlink.codec import DatagramParser, Encoder
from viva_sitl.mavlink.config import EndpointStartError, EndpointStats, MavlinkConfig, PortInUseError
from viva_sitl.mavlink.signing import SigningState
from viva_sitl.mavlink.tlog import TlogWriter

log = logging.getLogger(__name__)

MAX_PARSERS_PER_LINK = 64  # per-peer parsers kept (LRU): a flood of source ports cannot grow memory
MAX_PEERS_PER_LINK = 16  # talking peers that receive telemetry; the longest silent one makes room

Address = tuple[str, int]
Deliver = Callable[["Link", Origin, MavMessage], None]


class Transport(Protocol):
    """What a link sends through: an asyncio datagram transport, or an in-memory one (mavlink/testing.py)."""

    def sendto(self, data: bytes, addr: Address) -> None: ...
    def close(self) -> None: ...
    def get_extra_info(self, name: str, default: object = None) -> object: ...


class _UdpProtocol(asyncio.DatagramProtocol):
    def __init__(self, links: Links, kind: LinkKind) -> None:
        self.links = links
        self.kind = kind

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:  # type: ignore[override]
        self.links.receive(self.kind, data, (str(addr[0]), int(addr[1])))

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable after sending to a remote that is not listening (yet): normal for UDP
        self.links.stats.send_errors += 1


@dataclass
class Link:
    kind: LinkKind
    transport: Transport
    default_remote: Address | None
    encoders: dict[Component, Encoder]
    signing: SigningState | None = None
    peers: dict[Address, float] = field(default_factory=dict)  # talking peer -> last rx (endpoint clock)
    parsers: OrderedDict[Address, DatagramParser] = field(default_factory=OrderedDict)

    def parser(self, addr: Address) -> DatagramParser:
        p = self.parsers.get(addr)
        if p is None:
            p = self.parsers[addr] = DatagramParser(self.signing)
            while len(self.parsers) > MAX_PARSERS_PER_LINK:
                self.parsers.popitem(last=False)
        else:
            self.parsers.move_to_end(addr)
        return p

    def heard(self, addr: Address, now_s: float) -> None:
        self.peers[addr] = now_s
        if len(self.peers) > MAX_PEERS_PER_LINK:
            del self.peers[min(self.peers, key=self.peers.__getitem__)]

    def targets(self, now_s: float, timeout_s: float) -> list[Address]:
        out = [a for a, t in self.peers.items() if now_s - t <= timeout_s]
        if self.default_remote is not None and self.default_remote not in out:
            out.append(self.default_remote)
        return out

    @property
    def local_address(self) -> Address:
        sockname = self.transport.get_extra_info("sockname")
        assert isinstance(sockname, tuple)
        return (str(sockname[0]), int(sockname[1]))


def _resolve(host: str, port: int) -> Address:
    """A numeric IPv4 address (sendto with a name would resolve it on every datagram)."""
    info = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    return (str(info[0][4][0]), int(info[0][4][1]))


class Links:
    """The endpoint's links (API, GCS): binding, receiving (and holding), parsing, sending, peers, the .tlog.

    `deliver(link, origin, msg)` is called for every message that passes the parser (dispatch's entry point);
    `clock()` is the endpoint's clock (simulation seconds) that peers are timed on."""

    def __init__(
        self,
        sysid: int,
        signing: SigningState,
        stats: EndpointStats,
        peer_timeout_s: float,
        clock: Callable[[], float],
    ) -> None:
        self.sysid = sysid
        self.signing = signing
        self.stats = stats
        self.peer_timeout_s = peer_timeout_s
        self.clock = clock
        self.links: dict[LinkKind, Link] = {}
        self.deliver: Deliver | None = None
        self.tlog: TlogWriter | None = None
        self.listeners: list[EventListener] = []
        self._statustext_id = 0
        # charged timing: received datagrams wait in _held (due sim time, link, data, peer)
        self._holding = False
        self._held: deque[tuple[float | None, LinkKind, bytes, Address]] = deque()

    # --- opening and closing ----------------------------------------------------------------
    def attach(self, kind: LinkKind, transport: Transport, default_remote: Address | None) -> Link:
        """Add a link over an open transport (its link id for signing is its position: API 0, GCS 1)."""
        link_id = len(self.links)
        encoders = {c: Encoder(self.sysid, int(c), self.signing, link_id) for c in Component}
        link = self.links[kind] = Link(kind, transport, default_remote, encoders, self.signing)
        return link

    async def bind_udp(self, cfg: MavlinkConfig) -> None:
        """Bind the two UDP links as PX4 SITL (API, GCS); one clear error when a port is taken or a host unknown."""
        loop = asyncio.get_running_loop()
        specs = (
            (LinkKind.API, cfg.api_local_port_resolved, cfg.api_remote_host, cfg.api_remote_port_resolved),
            (LinkKind.GCS, cfg.gcs_local_port_resolved, cfg.gcs_remote_host, cfg.gcs_remote_port),
        )
        remotes: dict[LinkKind, Address | None] = {}
        for kind, _, rhost, rport in specs:
            try:
                remotes[kind] = _resolve(rhost, rport) if rport else None
            except OSError as exc:
                raise ValueError(
                    f"mavlink: cannot resolve the {kind.value} remote host {rhost!r}: {exc}"
                ) from exc
        try:
            for kind, local_port, _, _ in specs:
                try:
                    transport, _ = await loop.create_datagram_endpoint(
                        lambda kind=kind: _UdpProtocol(self, kind),  # type: ignore[misc]
                        local_addr=(cfg.listen_host, local_port),
                        family=socket.AF_INET,
                    )
                except OSError as exc:
                    if exc.errno == errno.EADDRINUSE:
                        flag = "--api-local-port" if kind == LinkKind.API else "--gcs-local-port"
                        raise PortInUseError(
                            exc.errno,
                            f"UDP port {local_port} ({kind.value} link) on {cfg.listen_host} is already in use "
                            f"(another viva-sitl or PX4 SITL?): run with --instance N (N = 1, 2, ...) or {flag}",
                        ) from None
                    raise EndpointStartError(
                        exc.errno,
                        f"MAVLink endpoint cannot bind UDP {cfg.listen_host}:{local_port}: {exc.strerror or exc}",
                    ) from exc
                self.attach(kind, transport, remotes[kind])
        except OSError:
            self.close()
            raise

    def open_tlog(self, path: str) -> None:
        """Record every packet sent and accepted in `path`; closes the links when it cannot be created."""
        try:
            self.tlog = TlogWriter(path)
        except OSError as exc:
            self.close()
            raise EndpointStartError(
                exc.errno, f"cannot create the tlog {path}: {exc.strerror or exc}"
            ) from exc

    def close(self) -> None:
        for link in self.links.values():
            link.transport.close()
        self.links.clear()

    def close_tlog(self) -> None:
        if self.tlog is not None:
            self.tlog.close()

    # --- sending (the concern modules' Outbox) -------------------------------------------------
    def send(self, link: Link, msg: MavMessage, component: Component, addrs: list[Address]) -> None:
        if not addrs:
            return
        try:
            buf = link.encoders[component].pack(msg)
        except Exception:  # a message we built with a bad field: a bug, logged; the loop goes on
            log.exception("cannot pack %s", msg.get_type())
            self.stats.handler_errors += 1
            return
        if self.tlog is not None:
            self.tlog.write(buf)
        for addr in addrs:
            try:
                link.transport.sendto(buf, addr)
            except OSError:
                self.stats.send_errors += 1
                continue
            self.stats.tx_messages += 1
            self.stats.tx_bytes += len(buf)

    def targets(self, link: Link, now_s: float) -> list[Address]:
        return link.targets(now_s, self.peer_timeout_s)

    def reply(self, origin: Origin, msg: MavMessage, component: Component = Component.AUTOPILOT) -> None:
        link = self.links.get(origin.link)
        if link is not None:
            self.send(link, msg, component, [origin.addr])

    def broadcast(self, msg: MavMessage, component: Component = Component.AUTOPILOT) -> None:
        now = self.clock()
        for link in self.links.values():
            self.send(link, msg, component, link.targets(now, self.peer_timeout_s))

    def statustext(self, origin: Origin | None, severity: int, text: str) -> None:
        """PX4 sends every STATUSTEXT on every link (a GCS sees why a script's command was refused); the peer that
        caused it gets it even when it is not (yet) a telemetry target."""
        self._statustext_id = (self._statustext_id + 1) % 0xFFFF
        now = self.clock()
        for msg in statustext_messages(int(severity), text, self._statustext_id + 1):
            self.broadcast(msg)
            if origin is not None:
                link = self.links.get(origin.link)
                if link is not None and origin.addr not in link.targets(now, self.peer_timeout_s):
                    self.reply(origin, msg)
        for listener in self.listeners:
            with contextlib.suppress(Exception):
                listener(text, int(severity))

    # --- receiving --------------------------------------------------------------------------
    def receive(self, kind: LinkKind, data: bytes, addr: Address) -> None:
        """A datagram from `addr` on link `kind` (the transport calls this): handled now, or held (charged timing)."""
        if self._holding:
            self._held.append((None, kind, data, addr))
            return
        self._handle_datagram(kind, data, addr)

    # charged timing (viva_sitl.timing): what the pilot sends while it computes takes effect later
    def hold_incoming(self, on: bool) -> None:
        self._holding = on
        if not on:
            held, self._held = self._held, deque()
            for _, kind, data, addr in held:
                self._handle_datagram(kind, data, addr)

    def stamp_held(self, due_s: float) -> int:
        n = 0
        last = self._held[0][0] if self._held and self._held[0][0] is not None else -math.inf
        for k, (due, kind, data, addr) in enumerate(self._held):
            if due is None:
                last = max(last, due_s)  # never before one received earlier: order is kept
                self._held[k] = (last, kind, data, addr)
                n += 1
            else:
                last = due
        return n

    def release_due(self, now_s: float) -> None:
        held = self._held
        while held and held[0][0] is not None and held[0][0] <= now_s:
            _, kind, data, addr = held.popleft()
            self._handle_datagram(kind, data, addr)

    def _handle_datagram(self, kind: LinkKind, data: bytes, addr: Address) -> None:
        link = self.links.get(kind)
        if link is None:
            return
        st = self.stats
        st.rx_datagrams += 1
        st.rx_bytes += len(data)
        try:
            result = link.parser(addr).parse(data)
        except Exception:  # DatagramParser never raises by design; if it does, drop the datagram, keep going
            log.exception("datagram parser failed")
            st.handler_errors += 1
            return
        st.bad_frames += result.bad_frames
        st.garbage_bytes += result.garbage_bytes
        st.unknown_messages += result.unknown
        st.unsigned_rejected += result.unsigned_rejected
        if result.messages:
            link.heard(addr, self.clock())
        tlog = self.tlog
        deliver = self.deliver
        for msg in result.messages:
            st.rx_messages += 1
            if tlog is not None:
                tlog.write(bytes(msg.get_msgbuf()))
            if deliver is None:
                st.ignored_messages += 1
                continue
            deliver(link, Origin(kind, addr, msg.get_srcSystem(), msg.get_srcComponent()), msg)

    def peers_heard(self) -> list[tuple[str, Address, float]]:
        now = self.clock()
        out: list[tuple[str, Address, float]] = []
        for kind, link in self.links.items():
            for addr, heard in list(link.peers.items()):
                out.append((str(kind.value), addr, max(0.0, now - heard)))
        return out
