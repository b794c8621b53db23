"""Test clients for the MAVLink endpoint: the selftest vehicle on a background thread, and a pymavlink-codec client.

with VehicleThread(MavlinkConfig(...)) as vt:      # SelftestVehicle + MavlinkEndpoint on their own asyncio loop
    client = MavClient(target=vt.api)
    client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)

A `Rig` is either of the two ways a protocol test reaches a vehicle: such a client over UDP with a VehicleThread, or
a client of the in-memory, sim-clock harness (viva_sitl.mavlink.testing) whose timeouts are scaled to the UDP
vehicle's speed (conftest's `rig_factory`). One test body then runs over both.
"""

from __future__ import annotations

import asyncio
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.config import SimConfig
from viva_sitl.mavlink.base import MavMessage
from viva_sitl.mavlink.camera_link import CameraLink
from viva_sitl.mavlink.config import MavlinkConfig
from viva_sitl.mavlink.endpoint import MavlinkEndpoint
from viva_sitl.mavlink.testing import SimClient, SimHarness
from viva_sitl.selftest import SelftestVehicle


class VehicleThread:
    """A SelftestVehicle + MavlinkEndpoint on their own asyncio loop in a background thread.

    `with VehicleThread(config) as vt:` starts both and stops them on exit; `vt.call(fn)` runs fn on the loop.
    """

    def __init__(self, config: MavlinkConfig, speed: float = 1.0, camera: CameraLink | None = None,
                 footage: str | Path | None = None, sim_config: SimConfig | None = None) -> None:  # fmt: skip
        self.config = config
        self.sim_config = sim_config  # None: SimConfig(seed=0), as SelftestVehicle
        self.footage = footage  # None: no footage edge (SelftestVehicle)
        self.speed = speed
        self.camera = camera
        self.vehicle: SelftestVehicle | None = None
        self.endpoint: MavlinkEndpoint | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="mavlink-vehicle", daemon=True)

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # reported to the starting thread
            self._error = exc
            self._ready.set()

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        self.vehicle = SelftestVehicle(
            self.sim_config, speed=self.speed, camera=self.camera, footage=self.footage
        )
        self.endpoint = MavlinkEndpoint(self.vehicle, self.config)
        self.vehicle.step_hooks.append(self.endpoint.on_sim_step)
        self.vehicle.start()
        await self.endpoint.start()
        self._ready.set()
        try:
            await self._stop.wait()
        finally:
            await self.endpoint.stop()
            await self.vehicle.stop()

    def start(self) -> VehicleThread:
        self._thread.start()
        if not self._ready.wait(10.0) or self._error is not None:
            raise RuntimeError(f"vehicle thread did not start: {self._error!r}")
        return self

    def stop(self) -> None:
        if self._loop is not None and self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10.0)

    def call(self, fn: Callable[[], Any], timeout_s: float = 5.0) -> Any:
        """Run fn on the vehicle's loop (thread-safe access to the autopilot or endpoint) and return its result."""
        assert self._loop is not None

        async def run() -> Any:
            return fn()

        return asyncio.run_coroutine_threadsafe(run(), self._loop).result(timeout_s)

    @property
    def api(self) -> tuple[str, int]:
        assert self.endpoint is not None
        return self.call(lambda: self.endpoint.api_address)  # type: ignore[union-attr]

    @property
    def gcs(self) -> tuple[str, int]:
        assert self.endpoint is not None
        return self.call(lambda: self.endpoint.gcs_address)  # type: ignore[union-attr]

    def stats(self) -> dict[str, Any]:
        assert self.endpoint is not None
        return self.call(lambda: self.endpoint.stats)  # type: ignore[union-attr,no-any-return]

    def __enter__(self) -> VehicleThread:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class MavClient:
    """A blocking pymavlink-codec client over a real UDP socket (a GCS or API program, as in the tests)."""

    def __init__(self, target: tuple[str, int] | None = None, sysid: int = 255, compid: int = 190) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self.sock.bind(("127.0.0.1", 0))
        self.target = target
        self.mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.parser = mavlink2.MAVLink(None)
        self.parser.robust_parsing = True
        self.received: list[tuple[float, MavMessage]] = []  # (monotonic time, message) of everything read
        self._pending: deque[MavMessage] = deque()  # read but not yet looked at by wait_for

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    def close(self) -> None:
        self.sock.close()

    def send(self, msg: MavMessage) -> None:
        assert self.target is not None
        self.send_raw(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256

    def send_raw(self, data: bytes) -> None:
        assert self.target is not None
        self.sock.sendto(data, self.target)

    def drain(self) -> None:
        """Forget pending messages (wait_for then sees only what arrives from now on)."""
        self.poll(0.0)
        self._pending.clear()

    def poll(self, timeout_s: float) -> list[MavMessage]:
        """Read datagrams for up to timeout_s; return the messages (also appended to `received`)."""
        out: list[MavMessage] = []
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return out
            self.sock.settimeout(remaining)
            try:
                data, _ = self.sock.recvfrom(65535)
            except TimeoutError:
                return out
            now = time.monotonic()
            for msg in self.parser.parse_buffer(data) or []:
                if msg.get_type() in ("BAD_DATA", "UNKNOWN"):
                    continue
                self.received.append((now, msg))
                self._pending.append(msg)
                out.append(msg)

    def wait_for(
        self, predicate: Callable[[MavMessage], bool] | str, timeout_s: float = 3.0
    ) -> MavMessage | None:
        """The next message matching `predicate` (or of that type name), None on timeout. Messages before it are
        consumed (still in `received`); messages after it stay for the next call."""
        pred = (lambda m: m.get_type() == predicate) if isinstance(predicate, str) else predicate
        deadline = time.monotonic() + timeout_s
        while True:
            while self._pending:
                msg = self._pending.popleft()
                if pred(msg):
                    return msg
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            self.poll(min(0.05, remaining))

    def command(
        self,
        command: int,
        *params: float,
        target_system: int = 1,
        target_component: int = 1,
        timeout_s: float = 1.0,
    ) -> MavMessage | None:
        """COMMAND_LONG with up to 7 params; returns its COMMAND_ACK (None if none came)."""
        p = list(params) + [0.0] * (7 - len(params))
        self.send(self.mav.command_long_encode(target_system, target_component, command, 0, *p))
        return self.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command, timeout_s)


class ScaledSimClient:
    """A harness client whose timeouts are a UDP test's wall seconds at sim speed `speed`: the same sim-time budget
    (what a UDP vehicle at that speed flies in `timeout_s` wall seconds), so one test body serves both."""

    def __init__(self, inner: SimClient, speed: float) -> None:
        self.inner = inner
        self.speed = speed

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def wait_for(self, predicate: Any, timeout_s: float = 3.0) -> MavMessage | None:
        return self.inner.wait_for(predicate, timeout_s * self.speed)

    def command(self, command: int, *params: float, timeout_s: float = 1.0, **kw: int) -> MavMessage | None:
        return self.inner.command(command, *params, timeout_s=timeout_s * self.speed, **kw)

    def poll(self, seconds: float) -> list[MavMessage]:
        return self.inner.poll(seconds * self.speed)

    def close(self) -> None:
        """Nothing to close (no socket); MavClient's API."""


class Rig:
    """A MAVLink peer and the vehicle it talks to: `call(fn)` runs fn where the autopilot lives (the vehicle
    thread's loop over UDP, at once on the harness)."""

    def __init__(
        self,
        client: Any,
        vehicle: SelftestVehicle,
        endpoint: MavlinkEndpoint,
        call: Callable[[Callable[[], Any]], Any],
        peer: Callable[[int, int], Any],
    ) -> None:
        self.client = client  # MavClient over UDP, or ScaledSimClient on the harness: the same API
        self.vehicle = vehicle
        self.autopilot = vehicle.autopilot
        self.endpoint = endpoint
        self.call = call
        self.peer = (
            peer  # peer(sysid, compid): another client on the API link, at an address of its own (close it)
        )

    def stats(self) -> dict[str, Any]:
        return dict(self.call(lambda: self.endpoint.stats))


def sim_rig(
    speed: float = 1.0,
    camera: CameraLink | None = None,
    footage: str | Path | None = None,
    sim_config: SimConfig | None = None,
    **config: Any,
) -> Rig:
    """The harness over a fresh SelftestVehicle and MavlinkConfig(**config); close with rig.vehicle.vehicle.close()."""
    sv = SelftestVehicle(sim_config, speed=speed, camera=camera, footage=footage)
    h = SimHarness(sv, lambda: sv.vehicle.step(1), MavlinkConfig(**config))

    def peer(sysid: int, compid: int) -> ScaledSimClient:
        return ScaledSimClient(
            h.client(addr=("127.0.0.1", 41000 + len(h.clients)), sysid=sysid, compid=compid), speed
        )

    return Rig(ScaledSimClient(h.client(), speed), sv, h.endpoint, lambda fn: fn(), peer)
