"""How simulated time relates to an external pilot's computing: realtime, lockstep or charged (`--timing`).

- **realtime** (default): simulated time = speed x wall time (clock.RealTimePacer); the pilot's computing takes wall
  time, so its score depends on the CPU it got. The run records what the pilot experienced (its CPU time and its
  run-queue delay from /proc: time it wanted a CPU and had none) and flags a starved pilot.
- **lockstep**: simulated time advances in quanta (QUANTUM_S of sim time); after each quantum (its telemetry, frames
  and events sent), the loop waits until the pilot's processes are idle (pilotwatch: no thread runnable, no CPU used
  over a settle interval) while the endpoint keeps receiving, so everything the pilot answered is applied at the
  quantum's end, whatever the machine's load. While the pilot is idle the clock runs at `speed` x wall (a pilot that
  sleeps on a wall-clock timer sees `speed` x its sleep pass; clients' wall-clock timers set the highest safe speed:
  see README "Timing").
- **charged**: lockstep, plus the pilot's computing is charged in simulated time: the CPU time its processes used
  (from the OS, which load barely changes) times `pilot_cpu_factor` (2 = a companion computer 2x slower than this
  CPU); what it sent while computing takes effect that much simulated time later (the endpoint holds it until then).

A pilot that is never idle (busy polling) cannot be lockstepped: once it has used NEVER_IDLE_GIVE_UP_S seconds of CPU
in one quantum's wait (CPU, not wall time: a long computation on a loaded machine takes more wall time but the same
CPU, and must not be mistaken for a busy loop), or NEVER_IDLE_WALL_MAX_S wall seconds passed, the quantum runs anyway, counted in `never_idle` (the trial's timing record says `lockstep_held: false`); after
NEVER_IDLE_QUANTA such quanta in a row a trial ends as pilot_error with that reason, and a plain run goes on in
realtime.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from viva_sitl.pilotwatch import IDLE_CPU_FRACTION, PilotTree, TreeSample

QUANTUM_S = 0.02  # sim seconds between two waits for the pilot (its reaction time is at most one quantum)
SETTLE_S = 0.001  # wall seconds: the longest nap between two looks (and the idle tolerance's base)
NAP_MIN_S = 0.0001  # the shortest nap between two looks (doubles while the pilot computes)
DRAIN_MAX_YIELDS = 64  # event-loop iterations a drain runs before it falls back to a SETTLE_S sleep
WAITED_S = 0.003  # a quantum whose wait took longer counts as one the pilot made the clock wait for
# CPU seconds of the pilot's after which one quantum stops waiting for it (2 was too few: a vision pilot's first
# look, a model's warm-up, took > 2 CPU s at load 14-17 and lost lockstep for it)
NEVER_IDLE_GIVE_UP_S = 10.0
NEVER_IDLE_WALL_MAX_S = 60.0  # and the wall seconds after which it stops whatever the CPU says
VIDEO_WAIT_MAX_S = 10.0  # wall seconds a quantum waits for the video outputs to have sent its frames
NEVER_IDLE_QUANTA = (
    3  # that many such quanta in a row: the pilot cannot be lockstepped (a trial ends pilot_error)
)
STARVED_RUN_DELAY_SHARE = 0.10  # realtime: a pilot that waited for a CPU > 10 % of its wall time was starved
WATCH_PERIOD_S = 0.25  # realtime: how often the pilot's CPU and run delay are read


class Timing(StrEnum):
    REALTIME = "realtime"
    LOCKSTEP = "lockstep"
    CHARGED = "charged"


def parse_timing(value: str) -> Timing:
    try:
        return Timing(value)
    except ValueError:
        raise ValueError(
            f"timing must be one of {', '.join(t.value for t in Timing)}, got {value!r}"
        ) from None


@dataclass
class TimingStats:
    """What the pilot experienced, for end.json's "timing" and the result row."""

    mode: Timing
    speed: float
    pilot_cpu_factor: float | None
    pilot_latency_ms: float | None = None  # charged: the fixed latency per frame
    pilot_pid: int | None = None
    quanta: int = 0  # lockstep quanta run
    waited: int = 0  # quanta after which the pilot was still computing
    busy_wall_s: float = 0.0  # wall seconds the clock stood still for the pilot
    max_busy_wall_s: float = 0.0
    charged_sim_s: float = 0.0  # simulated seconds charged for the pilot's computing (charged)
    never_idle: int = 0  # quanta run without the pilot becoming idle (lockstep not held)
    pilot_cpu_s: float = 0.0
    pilot_run_delay_s: float = 0.0  # time the pilot's threads were runnable but had no CPU
    pilot_wall_s: float = 0.0  # wall seconds the pilot was watched
    max_setpoint_gap_s: float = 0.0  # the longest sim-time gap between two offboard setpoints it sent
    skipped_steps: int = 0  # realtime: physics steps the clock skipped (the simulation itself fell behind)
    note: str = ""
    _cpu0: int | None = field(default=None, repr=False)
    _delay0: int = field(default=0, repr=False)
    _wall0: float = field(default=0.0, repr=False)

    def observe(self, s: TreeSample) -> None:
        if self._cpu0 is None:
            self._cpu0, self._delay0, self._wall0 = s.cpu_ns, s.run_delay_ns, s.wall_s
        self.pilot_cpu_s = (s.cpu_ns - self._cpu0) / 1e9
        self.pilot_run_delay_s = (s.run_delay_ns - self._delay0) / 1e9
        self.pilot_wall_s = s.wall_s - self._wall0

    @property
    def starved(self) -> bool:
        return self.pilot_wall_s > 0 and self.pilot_run_delay_s > STARVED_RUN_DELAY_SHARE * self.pilot_wall_s

    @property
    def lockstep_held(self) -> bool | None:
        if self.mode is Timing.REALTIME:
            return None
        return self.pilot_pid is not None and self.never_idle == 0

    def to_dict(self) -> dict[str, Any]:
        return {
            "mode": self.mode.value, "speed": self.speed, "pilot_cpu_factor": self.pilot_cpu_factor,
            "pilot_latency_ms": self.pilot_latency_ms,
            "pilot_pid": self.pilot_pid, "quanta": self.quanta, "waited": self.waited,
            "busy_wall_s": round(self.busy_wall_s, 3), "max_busy_wall_s": round(self.max_busy_wall_s, 3),
            "charged_sim_s": round(self.charged_sim_s, 4), "never_idle": self.never_idle,
            "pilot_cpu_s": round(self.pilot_cpu_s, 3), "pilot_run_delay_s": round(self.pilot_run_delay_s, 3),
            "pilot_wall_s": round(self.pilot_wall_s, 3), "starved": self.starved,
            "lockstep_held": self.lockstep_held, "max_setpoint_gap_s": round(self.max_setpoint_gap_s, 4),
            "skipped_steps": self.skipped_steps, "note": self.note,
        }  # fmt: skip


class PilotGate:
    """Waits until the pilot's process tree is idle (pilotwatch.PilotTree); returns the CPU it used meanwhile."""

    def __init__(self, tree: PilotTree, stats: TimingStats) -> None:
        self.tree = tree
        self.stats = stats
        self._last = tree.sample(time.monotonic())
        stats.observe(self._last)

    async def wait_idle(self, ready: Callable[[], bool] = lambda: True) -> float:
        """Wait until the pilot is idle (and `ready()`: e.g. the video outputs wrote the quantum's frames);
        return the pilot's CPU seconds since the previous call.

        Idle = two looks (pilotwatch.TreeSample), with the endpoint drained between them (`_drain`: the event loop
        has read everything the pilot sent), that both find no thread runnable and between which the pilot's CPU
        grew by at most IDLE_CPU_FRACTION of the interval (capped at that share of SETTLE_S). The first of the two
        may be the previous call's last look: a pilot that used no CPU since then (nothing reached it, or it ignored
        it) is idle after one look. A pilot found quiet but having used CPU is looked at again after the drain alone
        (once per quantum; later after NAP_MIN_S); while it computes the gate naps NAP_MIN_S, doubling up to SETTLE_S
        (then on the event loop's timer). A look costs tens of microseconds (two preads per pilot thread).
        """
        loop = asyncio.get_running_loop()
        t0 = time.monotonic()
        cpu_before = self._last.cpu_ns
        prev: TreeSample = self._last
        nap = NAP_MIN_S
        quick = True
        while True:
            await _drain(loop)  # the endpoint reads the pilot's messages
            now = time.monotonic()
            if not ready() and now - t0 < VIDEO_WAIT_MAX_S:
                await asyncio.sleep(SETTLE_S)
                continue
            cur = self.tree.sample(now)
            if cur.processes == 0:  # the pilot is gone: nothing to wait for
                break
            if (
                prev.quiet
                and cur.quiet
                and cur.cpu_ns - prev.cpu_ns <= IDLE_CPU_FRACTION * min(now - prev.wall_s, SETTLE_S) * 1e9
            ):
                break
            if cur.cpu_ns - cpu_before >= NEVER_IDLE_GIVE_UP_S * 1e9 or now - t0 >= NEVER_IDLE_WALL_MAX_S:
                self.stats.never_idle += 1
                break
            prev = cur
            if cur.quiet:  # it has just finished (or a timer thread ran): confirm soon
                nap = NAP_MIN_S
                # the first time in a quantum after the drain alone, then after a nap (no busy polling)
                if quick:
                    quick = False
                    continue
            if nap >= SETTLE_S:
                await asyncio.sleep(SETTLE_S)
            else:
                time.sleep(nap)  # sub-millisecond (the event loop's timers are in whole ms); drained next
                nap *= 2
        last = self._last = cur  # the newest look: the pilot's CPU up to now
        self.stats.observe(last)
        waited = time.monotonic() - t0
        if waited > WAITED_S:
            self.stats.waited += 1
        self.stats.busy_wall_s += waited
        self.stats.max_busy_wall_s = max(self.stats.max_busy_wall_s, waited)
        return max(0.0, (last.cpu_ns - cpu_before) / 1e9)


async def _drain(loop: asyncio.AbstractEventLoop) -> None:
    """Let the event loop run until it has no I/O ready: every datagram the pilot sent so far has been read and
    handed to the endpoint (a datagram transport reads one datagram per loop iteration). Peeks at the loop's
    selector (level-triggered, so peeking consumes nothing); a loop without one (not asyncio's selector loop) gets
    a SETTLE_S sleep instead, as does I/O still ready after DRAIN_MAX_YIELDS iterations."""
    selector = getattr(loop, "_selector", None)
    select = getattr(selector, "select", None)
    if select is None:
        await asyncio.sleep(SETTLE_S)
        return
    await asyncio.sleep(0)
    for _ in range(DRAIN_MAX_YIELDS):
        await asyncio.sleep(0)  # the callbacks of the previous iteration's ready I/O have run
        if not select(0):
            return
    await asyncio.sleep(SETTLE_S)


@dataclass
class LockstepClock:
    """Sim time may reach speed x (wall time not spent waiting for the pilot) + the charges."""

    dt_s: float
    speed: float
    _wall0: float = field(default=math.nan, init=False)
    _steps: int = field(default=0, init=False)
    _frozen_wall_s: float = field(default=0.0, init=False)
    _charged_s: float = field(default=0.0, init=False)

    def start(self) -> None:
        self._wall0 = time.monotonic()

    def frozen(self, wall_s: float) -> None:
        self._frozen_wall_s += wall_s

    def charge(self, sim_s: float) -> None:
        self._charged_s += sim_s

    def mark_done(self, n: int) -> None:
        self._steps += n

    def wall_until_due_s(self) -> float:
        """Wall seconds until the next step may run (0: now)."""
        allowed = (time.monotonic() - self._wall0 - self._frozen_wall_s) * self.speed + self._charged_s
        ahead = (self._steps + 1) * self.dt_s - allowed
        return max(0.0, ahead / self.speed)
