"""An in-memory, sim-clock harness for the MAVLink endpoint: protocol tests without sockets, threads or sleeps.

    harness = SimHarness(vehicle, step=lambda: vehicle.vehicle.step(1))   # any VehicleLink + "one physics step"
    gcs = harness.client()                       # a pymavlink-codec peer on the API link (its default remote)
    ack = gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)   # steps the simulation until the ACK (sim timeout)
    harness.advance(2.0)                         # two simulated seconds: physics, autopilot, endpoint schedule

The endpoint is the real MavlinkEndpoint (links -> dispatch -> concern modules, the sim-clock schedule), started
with `start_on` over MemoryTransports: a datagram a client sends is parsed and handled at once, and whatever the
endpoint sends lands, already parsed, in the addressed client's `received`. Time is the vehicle's simulation time,
advanced only by `step`/`advance` (or by a client waiting for an answer), so a test of a 1 Hz retry or a 10 Hz
stream takes what its physics steps cost, not wall seconds. What stays on the wall clock is not run: the endpoint's
wall-clock task (the heartbeat a slow simulation still sends once a wall second, the .tlog flush) and the parameter
list pacing task (`pump_params()` runs one burst of it by hand). The socket e2e tests cover those.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.mavlink.base import LinkKind, MavMessage, VehicleLink
from viva_sitl.mavlink.config import MavlinkConfig
from viva_sitl.mavlink.endpoint import MavlinkEndpoint
from viva_sitl.mavlink.links import Address

API_LOCAL: Address = ("127.0.0.1", 14580)
GCS_LOCAL: Address = ("127.0.0.1", 18570)
API_REMOTE: Address = ("127.0.0.1", 14540)  # MAVSDK's udpin://:14540: the API link's default remote


class MemoryTransport:
    """A link's Transport without a socket: every datagram goes to the harness, which hands it to its addressee."""

    def __init__(self, harness: SimHarness, kind: LinkKind, local: Address) -> None:
        self.harness = harness
        self.kind = kind
        self.local = local
        self.closed = False

    def sendto(self, data: bytes, addr: Address) -> None:
        if not self.closed:
            self.harness._route(self.kind, data, addr)

    def close(self) -> None:
        self.closed = True

    def get_extra_info(self, name: str, default: object = None) -> object:
        return self.local if name == "sockname" else default


Predicate = Callable[[MavMessage], bool] | str


class SimClient:
    """A pymavlink-codec peer at `addr` on one link of the harness; the API of tests/mav_client.py's MavClient,
    with every timeout in SIMULATED seconds (waiting steps the simulation)."""

    def __init__(self, harness: SimHarness, kind: LinkKind, addr: Address, sysid: int, compid: int) -> None:
        self.harness = harness
        self.kind = kind
        self.addr = addr
        self.mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.parser = mavlink2.MAVLink(None)
        self.parser.robust_parsing = True
        self.received: list[tuple[float, MavMessage]] = []  # (sim time, message) of everything received
        self._pending: deque[MavMessage] = deque()  # received but not yet looked at by wait_for

    @property
    def port(self) -> int:
        return self.addr[1]

    def send(self, msg: MavMessage) -> None:
        """Pack and deliver at once: the endpoint handles it (or holds it, charged timing) before this returns."""
        self.send_raw(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256

    def send_raw(self, data: bytes) -> None:
        self.harness.endpoint.links.receive(self.kind, data, self.addr)

    def _datagram(self, data: bytes) -> None:
        now = self.harness.time_s
        for msg in self.parser.parse_buffer(data) or []:
            if msg.get_type() in ("BAD_DATA", "UNKNOWN"):
                continue
            self.received.append((now, msg))
            self._pending.append(msg)

    def drain(self) -> None:
        """Forget pending messages (wait_for then sees only what arrives from now on)."""
        self._pending.clear()

    def poll(self, sim_s: float) -> list[MavMessage]:
        """Run the simulation for `sim_s` seconds; return what arrived meanwhile (also in `received`)."""
        n = len(self.received)
        self.harness.advance(sim_s)
        return [m for _, m in self.received[n:]]

    def wait_for(self, predicate: Predicate, timeout_s: float = 3.0) -> MavMessage | None:
        """The next message matching `predicate` (or of that type name), None after `timeout_s` simulated
        seconds. Messages before it are consumed (still in `received`); messages after it stay."""
        pred = (lambda m: m.get_type() == predicate) if isinstance(predicate, str) else predicate
        deadline = self.harness.time_s + timeout_s
        while True:
            while self._pending:
                msg = self._pending.popleft()
                if pred(msg):
                    return msg
            if self.harness.time_s >= deadline:
                return None
            self.harness.step()

    def command(
        self,
        command: int,
        *params: float,
        target_system: int = 1,
        target_component: int = 1,
        timeout_s: float = 1.0,
    ) -> MavMessage | None:
        """COMMAND_LONG with up to 7 params; returns its COMMAND_ACK (None if none came within timeout_s sim)."""
        p = list(params) + [0.0] * (7 - len(params))
        self.send(self.mav.command_long_encode(target_system, target_component, command, 0, *p))
        return self.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command, timeout_s)


class SimHarness:
    """A real MavlinkEndpoint over in-memory links, on a clock that moves only when the test steps it.

    `step` advances the vehicle by one physics step (e.g. `lambda: selftest_vehicle.vehicle.step(1)`); the harness
    calls the endpoint's on_sim_step() after each, as the app and the selftest vehicle do."""

    def __init__(
        self,
        vehicle: VehicleLink,
        step: Callable[[], None],
        config: MavlinkConfig | None = None,
        api_remote: Address | None = API_REMOTE,
        gcs_remote: Address | None = None,
    ) -> None:
        self.vehicle = vehicle
        self._step = step
        self.endpoint = MavlinkEndpoint(vehicle, config)
        self.clients: dict[tuple[LinkKind, Address], SimClient] = {}
        self.undelivered = 0  # datagrams sent to an address no client has
        self.endpoint.start_on(
            {
                LinkKind.API: (MemoryTransport(self, LinkKind.API, API_LOCAL), api_remote),
                LinkKind.GCS: (MemoryTransport(self, LinkKind.GCS, GCS_LOCAL), gcs_remote),
            }
        )
        self._api_remote = api_remote

    @property
    def time_s(self) -> float:
        return float(self.vehicle.time_s)

    def client(
        self, kind: LinkKind = LinkKind.API, addr: Address | None = None, sysid: int = 255, compid: int = 190
    ) -> SimClient:
        """A peer on link `kind` at `addr` (default: the API link's remote; on the GCS link, a fresh port)."""
        if addr is None:
            if kind == LinkKind.API and self._api_remote is not None:
                addr = self._api_remote
            else:
                addr = ("127.0.0.1", 40000 + len(self.clients))
        c = self.clients[(kind, addr)] = SimClient(self, kind, addr, sysid, compid)
        return c

    def step(self, n: int = 1) -> None:
        """n physics steps, each followed by the endpoint's sim-clock schedule."""
        for _ in range(n):
            self._step()
            self.endpoint.on_sim_step()

    def advance(self, sim_s: float) -> None:
        """Step until `sim_s` simulated seconds have passed."""
        end = self.time_s + sim_s
        while self.time_s < end - 1e-9:
            self.step()

    def pump_params(self) -> None:
        """What the endpoint's parameter task does on the wall clock, once: changed values re-announced, one
        burst of every parameter list in progress."""
        self.endpoint.params.send_untransmitted()
        self.endpoint.params.send_burst()

    def _route(self, kind: LinkKind, data: bytes, addr: Address) -> None:
        client = self.clients.get((kind, addr))
        if client is None:
            self.undelivered += 1
            return
        client._datagram(data)
