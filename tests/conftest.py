"""Shared fixtures: the ../shared footage (skip when absent), free UDP ports, viva-sitl subprocesses, MAVLink peers,
and the MAVLink protocol tests' client + selftest vehicle on a thread (`client`, `vehicle_factory`)."""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable, Generator, Iterator
from pathlib import Path
from typing import Any

import pytest
from mav_client import MavClient, Rig, VehicleThread, sim_rig
from sitl_process import MavlinkPeer, SitlProcess, e2e_speed, free_udp_ports

from viva_sitl.config import SimConfig
from viva_sitl.mavlink import MavlinkConfig
from viva_sitl.mavlink.camera_link import CameraLink

# The Ctrl-C tests send SIGINT to the processes they start. A shell that starts a job in the background without job
# control (`cmd &` in a script, as a CI harness may) starts it with SIGINT ignored, and exec keeps an ignored signal
# ignored in every child: the Python processes under test would then never see a KeyboardInterrupt. The default
# handler here makes their own default (exec resets a handled signal to SIG_DFL, which Python then handles).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

SHARED_DIR = Path(__file__).resolve().parents[2] / "shared"


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    # Remember each phase's report on the test item, so fixtures can print logs only for failed tests.
    rep = yield
    setattr(item, f"rep_{rep.when}", rep)
    return rep


_torch_threads_set = False


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    # Torch in the test process computes on one thread. Its default (one per core) spin-waits for a second core
    # that, on a shared 2-core machine, the other processes hold: the U-Net overfit test took 12 s on two threads
    # at load ~5 and 1.2 s on one. Only once torch is imported (by a test module or a test); never imported here.
    global _torch_threads_set
    torch = sys.modules.get("torch")
    if torch is not None and not _torch_threads_set:
        torch.set_num_threads(1)
        _torch_threads_set = True


@pytest.fixture
def shared_dir() -> Path:
    if not SHARED_DIR.is_dir():
        pytest.skip(f"shared footage directory {SHARED_DIR} is absent")
    return SHARED_DIR


@pytest.fixture
def interchange_video(shared_dir: Path) -> Path:
    path = shared_dir / "footage" / "interchange" / "interchange_1080p.mp4"
    if not path.is_file():
        pytest.skip(f"shared footage {path} is absent")
    return path


@pytest.fixture
def udp_ports() -> Callable[[int], list[int]]:
    """free_udp_ports(n): n distinct UDP ports free on 127.0.0.1."""
    return free_udp_ports


@pytest.fixture
def sitl_factory(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[Callable[..., SitlProcess]]:
    """start(**SitlProcess kwargs) -> a ready viva-sitl process; every one is stopped at teardown (logs on failure)."""
    started: list[SitlProcess] = []

    def start(**kwargs: Any) -> SitlProcess:
        kwargs.setdefault("speed", e2e_speed())
        kwargs.setdefault("name", f"sitl{len(started)}")
        proc = SitlProcess(workdir=tmp_path, **kwargs)
        started.append(proc)
        return proc.start()

    yield start
    failed = getattr(request.node, "rep_call", None) is not None and request.node.rep_call.failed
    for proc in started:
        code = proc.stop()
        if failed:
            print(f"\n[viva-sitl {proc.name} exit {code}]\n{proc.logs()}")


@pytest.fixture
def sitl(sitl_factory: Callable[..., SitlProcess]) -> SitlProcess:
    """One viva-sitl over the synthetic field, on free ports, at the e2e speed factor."""
    return sitl_factory()


@pytest.fixture
def peer_factory() -> Iterator[Callable[[int], MavlinkPeer]]:
    peers: list[MavlinkPeer] = []

    def make(port: int) -> MavlinkPeer:
        peer = MavlinkPeer(port)
        peers.append(peer)
        return peer

    yield make
    for peer in peers:
        peer.close()


@pytest.fixture
def client() -> Iterator[MavClient]:
    """A pymavlink-codec client on a free UDP port of 127.0.0.1 (plays MAVSDK's API peer); closed at teardown."""
    c = MavClient()
    yield c
    c.close()


@pytest.fixture
def vehicle_factory(client: MavClient) -> Iterator[Callable[..., VehicleThread]]:
    """start(speed=1.0, camera=None, footage=None, sim_config=None, **MavlinkConfig fields) -> a started VehicleThread whose API link
    talks to `client` (client.target set to it); no GCS remote, local ports free. Every one is stopped at teardown.

    A test module's `vehicle` fixture is one call: `return vehicle_factory(speed=4.0)`."""
    started: list[VehicleThread] = []

    def start(
        speed: float = 1.0,
        camera: CameraLink | None = None,
        footage: str | Path | None = None,
        sim_config: SimConfig | None = None,
        **config: Any,
    ) -> VehicleThread:
        fields: dict[str, Any] = {"api_remote_port": client.port, "gcs_remote_port": 0, "api_local_port": 0,
                                  "gcs_local_port": 0}  # fmt: skip
        fields.update(config)
        vt = VehicleThread(
            MavlinkConfig(**fields), speed=speed, camera=camera, footage=footage, sim_config=sim_config
        )
        started.append(vt)
        vt.start()
        client.target = vt.api
        return vt

    yield start
    for vt in started:
        vt.stop()


@pytest.fixture
def rig_factory(request: pytest.FixtureRequest) -> Iterator[Callable[..., Rig]]:
    """make(transport, speed=1.0, footage=None, sim_config=None, **MavlinkConfig fields) -> Rig. "udp": the `client`
    fixture and a vehicle thread (`vehicle_factory`) at `speed`; "sim": the sim-clock harness, its client's timeouts
    scaled by `speed`. A test module parametrizes its `rig` over both, the UDP one marked slow (the same exchanges,
    seconds of real time)."""
    sims: list[Rig] = []

    def make(
        transport: str,
        speed: float = 1.0,
        footage: str | Path | None = None,
        sim_config: SimConfig | None = None,
        **config: Any,
    ) -> Rig:
        if transport == "udp":
            client: MavClient = request.getfixturevalue("client")
            vt: VehicleThread = request.getfixturevalue("vehicle_factory")(
                speed=speed, footage=footage, sim_config=sim_config, **config
            )
            assert vt.vehicle is not None and vt.endpoint is not None

            def peer(sysid: int, compid: int) -> MavClient:
                return MavClient(target=vt.api, sysid=sysid, compid=compid)

            return Rig(client, vt.vehicle, vt.endpoint, vt.call, peer)
        assert transport == "sim", transport
        rig = sim_rig(speed, footage=footage, sim_config=sim_config, **config)
        sims.append(rig)
        return rig

    yield make
    for rig in sims:
        rig.vehicle.vehicle.close()


@pytest.fixture(autouse=True, scope="session")
def _automatic_tile_caches_in_a_temporary_folder(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[None]:
    """Heavy (>= 4K) test videos opened in the test process get their automatic tile cache (viva_sitl.footage.
    autocache) in a temporary folder, not in the user's ~/.cache."""
    from viva_sitl.footage import autocache

    before = autocache.policy()
    autocache.set_policy(
        autocache.CachePolicy(root=tmp_path_factory.mktemp("tiles-auto"), show_progress=False)
    )
    yield
    autocache.set_policy(before)
