"""Watching an unchanged pilot program from the outside (Linux /proc): is it computing, or waiting for input?

Lockstep and charged timing (clock.py, `--timing`) need one fact about a program we do not control: has it finished
reacting to what the vehicle sent it? A process tree is **idle** when, in two samples (timing.PilotGate takes them
with the vehicle's event loop drained between them; the first may be the previous quantum's last),

- none of its threads is runnable or in uninterruptible wait (/proc/PID/task/TID/stat state R or D),
- its CPU time (the sum of /proc/PID/task/TID/schedstat's first field, nanoseconds) grew by less than
  IDLE_CPU_FRACTION of the interval, capped at that share of 1 ms (a wall-clock timer thread that wakes for
  microseconds, as MAVSDK's and gRPC's do, is idle; a thread that computes is not).

A program that sleeps on a wall-clock timer with data unread is idle (it is not computing: time passes for it, as it
would on a real vehicle); when it wakes and reads, it is computing, and is waited for. Bytes in socket queues are not
looked at: a datagram sent on loopback wakes its reader before `sendto` returns, and reading /proc/net/tcp costs
~20 ms on this machine (the kernel walks its whole connection table), far more than a control step.

The tree is the process group of the pilot: the one `trials run` starts (its own session) or, for `viva-sitl run
--timing lockstep` with a pilot started by hand, the group of the process that owns the local UDP port the pilot's
first MAVLink message came from (`owner_of_udp_port`): a MAVSDK script's group holds its mavsdk_server too.

The same samples give realtime trials their honesty figures: the pilot's CPU time and its run-queue delay (schedstat's
second field: time its threads were runnable but not running: CPU starvation by the machine's load).

Everything here is Linux-only; `supported()` says whether this machine has it (schedstat needs CONFIG_SCHED_INFO).
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, field
from pathlib import Path

IDLE_CPU_FRACTION = 0.05  # CPU growth below this share of the settle interval still counts as idle
FULL_RESCAN_S = 5.0  # wall seconds between two rescans that read every process's group again
_NET_TABLES = ("udp", "udp6")
_PROC = Path("/proc")


def supported() -> str:
    """'' when this machine can watch a pilot; else why not (one line)."""
    if not _PROC.joinpath("self", "schedstat").exists():
        return "lockstep and charged timing need Linux /proc with schedstat (this system has none)"
    return ""


def _read(path: str) -> str | None:
    try:
        with open(path, "rb") as f:
            return f.read().decode("ascii", "replace")
    except OSError:
        return None


def _pgrp_state(pid: int) -> tuple[int | None, str]:
    """(process group, state letter) of a process from /proc/PID/stat; (None, '') when it is gone."""
    try:
        fd = os.open(f"/proc/{pid}/stat", os.O_RDONLY)
    except OSError:
        return None, ""
    try:
        text = os.read(fd, 512)
    except OSError:
        return None, ""
    finally:
        os.close(fd)
    i = text.rfind(b")")
    f = text[i + 2 :].split(None, 3)
    try:
        return int(f[2]), f[0].decode("ascii", "replace")
    except (IndexError, ValueError):
        return None, ""


def _stat_fields(text: str) -> list[str]:
    """/proc/.../stat fields after the command name (which may hold spaces and parentheses)."""
    return text[text.rfind(")") + 2 :].split()


def _socket_inodes(pid: int) -> set[int]:
    out: set[int] = set()
    fd_dir = f"/proc/{pid}/fd"
    try:
        names = os.listdir(fd_dir)
    except OSError:
        return out
    for name in names:
        try:
            target = os.readlink(f"{fd_dir}/{name}")
        except OSError:
            continue
        if target.startswith("socket:["):
            out.add(int(target[8:-1]))
    return out


def _net_rows() -> list[tuple[int, int, int]]:
    """(local port, rx_queue bytes, inode) of every UDP socket in this network namespace."""
    rows: list[tuple[int, int, int]] = []
    for table in _NET_TABLES:
        text = _read(f"/proc/net/{table}")
        if not text:
            continue
        for line in text.splitlines()[1:]:
            parts = line.split()
            if len(parts) < 10:
                continue
            try:
                port = int(parts[1].rsplit(":", 1)[1], 16)
                rx = int(parts[4].split(":")[1], 16)
                rows.append((port, rx, int(parts[9])))
            except (ValueError, IndexError):
                continue
    return rows


def owner_of_udp_port(port: int) -> int | None:
    """The pid of a process holding the local UDP socket bound to `port` (None when none on this machine)."""
    inodes = {inode for p, _, inode in _net_rows() if p == port and inode}
    if not inodes:
        return None
    me = os.getpid()
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == me:
            continue
        if _socket_inodes(int(entry)) & inodes:
            return int(entry)
    return None


def process_group(pid: int) -> int | None:
    text = _read(f"/proc/{pid}/stat")
    if text is None:
        return None
    try:
        return int(_stat_fields(text)[2])  # state, ppid, pgrp
    except (IndexError, ValueError):
        return None


@dataclass(frozen=True)
class TreeSample:
    """One look at the pilot's processes."""

    wall_s: float
    processes: int  # live processes in the group (0: the pilot is gone)
    running: int  # threads runnable or in uninterruptible wait (state R or D)
    cpu_ns: int  # CPU time of its threads, summed (threads that ended keep theirs)
    run_delay_ns: int  # time its threads spent runnable but not running (CPU starvation), summed

    @property
    def quiet(self) -> bool:
        return self.running == 0


class _Thread:
    """Open /proc files of one thread, re-read with pread (a quarter of the cost of opening them each time)."""

    __slots__ = ("tid", "stat_fd", "sched_fd", "cpu_ns", "delay_ns")

    def __init__(self, base: str, tid: int) -> None:
        self.tid = tid
        self.stat_fd = os.open(f"{base}/stat", os.O_RDONLY)
        try:
            self.sched_fd = os.open(f"{base}/schedstat", os.O_RDONLY)
        except OSError:
            os.close(self.stat_fd)
            raise
        self.cpu_ns = 0
        self.delay_ns = 0

    def state(self) -> str:
        """'R', 'S', 'D', ... ; '' once the thread is gone."""
        try:
            text = os.pread(self.stat_fd, 512, 0)
        except OSError:
            return ""
        i = text.rfind(b")")
        return chr(text[i + 2]) if 0 <= i < len(text) - 2 else ""

    def times(self) -> bool:
        try:
            parts = os.pread(self.sched_fd, 128, 0).split()
            self.cpu_ns, self.delay_ns = int(parts[0]), int(parts[1])
            return True
        except (OSError, IndexError, ValueError):
            return False

    def close(self) -> None:
        for fd in (self.stat_fd, self.sched_fd):
            with contextlib.suppress(OSError):
                os.close(fd)


@dataclass
class PilotTree:
    """The pilot's process group, watched through /proc. `extra_threads` are threads of *this* process that carry
    data to the pilot (a ZeroMQ I/O thread): while one runs, what it carries has not reached the pilot yet."""

    pgid: int
    extra_threads: tuple[int, ...] = ()
    exclude: tuple[int, ...] = ()  # pids never counted (this process, when the pilot shares its group)
    rescan_s: float = (
        0.25  # how often the group's members and threads (a child the pilot spawns) are looked up
    )
    _threads: dict[tuple[int, int], _Thread] = field(default_factory=dict, init=False)
    _extra: list[_Thread] = field(default_factory=list, init=False)
    _processes: int = field(default=0, init=False)
    _scanned_wall_s: float = field(default=-1e9, init=False)
    _gone_cpu_ns: int = field(default=0, init=False)  # CPU of threads that ended (the total never drops)
    _gone_delay_ns: int = field(default=0, init=False)
    _others: set[int] = field(default_factory=set, init=False)  # pids seen outside the group
    _full_wall_s: float = field(default=-1e9, init=False)

    def __post_init__(self) -> None:
        for tid in self.extra_threads:
            with contextlib.suppress(OSError):
                self._extra.append(_Thread(f"/proc/self/task/{tid}", tid))

    def _rescan(self, now_s: float) -> None:
        # Which processes are in the group: a process outside it (checked once, kept in _others while its pid
        # lives) is not read again, so a rescan reads /proc/PID/stat of the group's members and of new pids only
        # (reading all of them cost ~3 ms per rescan with ~100 processes); every FULL_RESCAN_S all are read again
        # (a process that joined the group by setpgid).
        full = now_s - self._full_wall_s >= FULL_RESCAN_S
        if full:
            self._others.clear()
            self._full_wall_s = now_s
        live: set[int] = set()
        pids = []
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            pid = int(entry)
            live.add(pid)
            if pid in self._others:
                continue
            pgrp, state = _pgrp_state(pid)
            if pgrp is None:
                continue
            if pgrp == self.pgid and state != "Z" and pid not in self.exclude:
                pids.append(pid)
            elif pgrp != self.pgid:
                self._others.add(pid)
        self._others &= live
        seen: set[tuple[int, int]] = set()
        for pid in pids:
            try:
                tids = os.listdir(f"/proc/{pid}/task")
            except OSError:
                continue
            for tid in tids:
                key = (pid, int(tid))
                seen.add(key)
                if key not in self._threads:
                    with contextlib.suppress(OSError):
                        th = _Thread(f"/proc/{pid}/task/{tid}", int(tid))
                        th.times()
                        self._threads[key] = th
        for key in [k for k in self._threads if k not in seen]:
            self._drop(key)
        self._processes = len(pids)
        self._scanned_wall_s = now_s

    def _drop(self, key: tuple[int, int]) -> None:
        th = self._threads.pop(key)
        self._gone_cpu_ns += th.cpu_ns
        self._gone_delay_ns += th.delay_ns
        th.close()

    def running(self, now_s: float) -> int:
        """Threads of the pilot (and the extra threads) runnable or in uninterruptible wait now."""
        if now_s - self._scanned_wall_s >= self.rescan_s:
            self._rescan(now_s)
        n = 0
        for th in self._threads.values():
            if th.state() in ("R", "D"):
                n += 1
        for th in self._extra:
            if th.state() in ("R", "D"):
                n += 1
        return n

    def sample(self, now_s: float) -> TreeSample:
        running = self.running(now_s)
        for key, th in list(self._threads.items()):
            if not th.times():  # ended: its last figures stay in the totals
                self._drop(key)
        cpu = self._gone_cpu_ns + sum(th.cpu_ns for th in self._threads.values())
        delay = self._gone_delay_ns + sum(th.delay_ns for th in self._threads.values())
        return TreeSample(now_s, self._processes, running, cpu, delay)

    def close(self) -> None:
        for key in list(self._threads):
            self._drop(key)
        for th in self._extra:
            th.close()
        self._extra.clear()


def zmq_io_threads() -> tuple[int, ...]:
    """This process's ZeroMQ background threads (named ZMQbg/... by libzmq), which carry frame-socket messages."""
    out = []
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return ()
    for tid in tids:
        name = _read(f"/proc/self/task/{tid}/comm")
        if name is not None and name.startswith("ZMQbg/IO"):
            out.append(int(tid))
    return tuple(out)
