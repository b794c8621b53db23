"""The lockstep gate (viva_sitl.timing.PilotGate) against real pilot processes: it lets time go on only once the
pilot is idle and everything it sent has been read, counts a child's CPU, gives up on a pilot that never waits, and
returns when the pilot is gone. Real processes, a real UDP socket on the event loop."""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from viva_sitl import timing
from viva_sitl.pilotwatch import PilotTree, supported
from viva_sitl.timing import PilotGate, Timing, TimingStats

pytestmark = pytest.mark.skipif(bool(supported()), reason=supported() or "Linux /proc with schedstat")

# Per datagram received: MS of CPU (argv[1]), then N answers (argv[2]); 4 idle threads beside (as a MAVSDK
# script's timer threads). With argv[3] == "child" the CPU is spent by a child process it spawned (a pipe job).
PILOT = r"""
import socket, subprocess, sys, threading, time
ms, n, how = float(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
for _ in range(4):
    threading.Thread(target=lambda: time.sleep(3600), daemon=True).start()
child = None
if how == "child":
    child = subprocess.Popen([sys.executable, "-c", "import sys, time\nfor line in sys.stdin:\n"
        "    end = time.thread_time() + float(line) / 1000.0\n    while time.thread_time() < end: pass\n"
        "    print('ok', flush=True)"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
print(s.getsockname()[1], flush=True)
while True:
    data, addr = s.recvfrom(2048)
    if data == b"exit":
        sys.exit(0)
    if data == b"spin":
        while True:
            pass
    if child is not None:
        child.stdin.write(f"{ms}\n"); child.stdin.flush()
        assert child.stdout.readline().strip() == "ok"
    else:
        end = time.thread_time() + ms / 1000.0
        while time.thread_time() < end:
            pass
    for _ in range(n):
        s.sendto(data, addr)
"""


@contextmanager
def _pilot(ms: float, n: int, how: str = "self") -> Iterator[tuple[subprocess.Popen[str], int]]:
    proc = subprocess.Popen([sys.executable, "-c", PILOT, str(ms), str(n), how], stdout=subprocess.PIPE, text=True,
                            start_new_session=True)  # fmt: skip
    try:
        assert proc.stdout is not None
        yield proc, int(proc.stdout.readline())
    finally:
        proc.kill()
        proc.wait(5)


async def _gate_run(
    proc: subprocess.Popen[str], port: int, quanta: int, n: int, msg: bytes = b"q"
) -> dict[str, float]:
    """Per quantum: one datagram to the pilot, then the gate; counts the answers not yet read when it returned."""
    loop = asyncio.get_running_loop()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    got = [0]
    loop.add_reader(sock.fileno(), lambda: (sock.recv(2048), got.__setitem__(0, got[0] + 1)))
    tree = PilotTree(proc.pid)
    # the first look finds the threads (a rescan); wait until the child, if any, is in the group too
    while tree.sample(time.monotonic()).processes == 0:
        await asyncio.sleep(0.01)
    stats = TimingStats(Timing.LOCKSTEP, 1.0, None, pilot_pid=proc.pid)
    gate = PilotGate(tree, stats)
    unread, cpu, wall = 0, 0.0, 0.0
    try:
        for k in range(quanta):
            sock.sendto(msg, ("127.0.0.1", port))
            t0 = time.monotonic()
            cpu += await gate.wait_idle()
            wall += time.monotonic() - t0
            if got[0] != (k + 1) * n:
                unread += 1
                got[0] = (k + 1) * n
    finally:
        loop.remove_reader(sock.fileno())
        sock.close()
        tree.close()
    return {"unread": unread, "cpu_s": cpu, "wall_s": wall, "never_idle": stats.never_idle}


def test_the_gate_returns_once_the_pilots_answers_are_read() -> None:
    # a pilot that answers at once (tens of us of CPU) and one that computes 2 ms and then sends 3 datagrams
    for ms, n, quanta in ((0.0, 1, 300), (2.0, 3, 60)):
        with _pilot(ms, n) as (proc, port):
            r = asyncio.run(_gate_run(proc, port, quanta, n))
        assert r["unread"] == 0, (ms, n, r)
        assert r["never_idle"] == 0
        assert r["cpu_s"] >= quanta * ms / 1000.0 * 0.9, r  # the pilot's own computing is what it returns


def test_the_gate_waits_for_a_child_that_computes_and_counts_its_cpu() -> None:
    with _pilot(5.0, 1, "child") as (proc, port):
        r = asyncio.run(_gate_run(proc, port, 20, 1))
    assert r["unread"] == 0 and r["never_idle"] == 0, r
    assert r["cpu_s"] >= 20 * 0.005 * 0.9, r


def test_the_gate_gives_up_on_a_pilot_that_never_waits(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(timing, "NEVER_IDLE_GIVE_UP_S", 0.1)  # CPU seconds per quantum (2 in a trial)
    with _pilot(0.0, 1) as (proc, port):
        r = asyncio.run(_gate_run(proc, port, 1, 1, msg=b"spin"))
    assert r["never_idle"] == 1 and r["cpu_s"] >= 0.1, r


def test_the_gate_returns_when_the_pilot_is_gone() -> None:
    with _pilot(0.0, 1) as (proc, port):

        async def run() -> tuple[float, int]:
            tree = PilotTree(proc.pid)
            tree.rescan_s = 0.0  # look the group up at every look (the default: every 0.25 s)
            while tree.sample(time.monotonic()).processes == 0:
                await asyncio.sleep(0.01)
            gate = PilotGate(tree, TimingStats(Timing.LOCKSTEP, 1.0, None, pilot_pid=proc.pid))
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(b"exit", ("127.0.0.1", port))
            proc.wait(5)
            t0 = time.monotonic()
            await gate.wait_idle()
            return time.monotonic() - t0, tree.sample(time.monotonic()).processes

        wall, processes = asyncio.run(run())
    assert processes == 0 and wall < 1.0
