"""The `viva-sitl run` process contract the end-to-end fixture relies on: the ready line, a clean exit 0 on SIGINT
with the stats line, --duration, and a clear error (no hang, no ready line) for unusable footage."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import pytest
from sitl_process import READY_PREFIX, MavlinkPeer, SitlError, SitlProcess

pytestmark = pytest.mark.e2e


@pytest.mark.slow  # a viva-sitl process run to its end
def test_ready_line_then_clean_sigint_exit(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    assert sitl.ready_line.startswith(READY_PREFIX)
    assert (
        f"-> 127.0.0.1:{sitl.ports.api}" in sitl.ready_line
        and f"-> 127.0.0.1:{sitl.ports.gcs}" in sitl.ready_line
    )
    peer = peer_factory(sitl.ports.gcs)
    peer.wait("ATTITUDE", lambda m: m.time_boot_ms > 500, 10.0, since_s=0.0, what="0.5 s of simulation")
    assert sitl.stop() == 0, sitl.logs()
    stats = sitl.stop_stats()
    assert stats.get("sim_time_s", 0) >= 0.5, f"no stats line on a clean exit\n{sitl.logs()}"


@pytest.mark.slow  # a viva-sitl process run to its end
def test_duration_ends_the_run(tmp_path: Path) -> None:
    proc = SitlProcess(workdir=tmp_path, speed=1.0, extra_args=["--duration", "2"])
    with proc:
        t0 = time.monotonic()
        assert proc.proc is not None
        code = proc.proc.wait(timeout=20)
        assert code == 0, proc.logs()
        assert time.monotonic() - t0 < 15
    assert 1.5 < proc.stop_stats().get("sim_time_s", 0) < 3.0, proc.logs()


def test_unusable_footage_fails_fast_with_a_message(tmp_path: Path) -> None:
    proc = SitlProcess(workdir=tmp_path, footage=str(tmp_path / "no-such-video.mp4"), ready_timeout_s=30)
    t0 = time.monotonic()
    with pytest.raises(SitlError) as err:
        proc.start()
    assert time.monotonic() - t0 < 30
    assert "exited with" in str(err.value) and "no-such-video" in proc.stderr_text(), str(err.value)
    assert not proc.alive
    proc.stop()
