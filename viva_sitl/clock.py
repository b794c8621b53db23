"""The one clock: simulation time advanced in fixed physics steps, paced against wall time or free-running.

`RealTimePacer` answers "how many physics steps are due now?" for a speed factor; the caller steps. With
`speed=None` the simulation free-runs (as fast as the caller steps it), as in tests and batch trials.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass
class RealTimePacer:
    dt_s: float  # physics step (sim seconds)
    speed: float = 1.0  # sim seconds per wall second
    max_catch_up_steps: int = 250  # beyond this the sim is late: steps are skipped (counted), not queued
    wall_clock: Callable[[], float] = time.monotonic
    _wall0: float = field(default=math.nan, init=False)
    _steps_done: int = field(default=0, init=False)
    skipped_steps: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if not (self.speed > 0.0 and math.isfinite(self.speed)):
            raise ValueError(f"speed factor must be a positive number, got {self.speed!r}")
        if not (self.dt_s > 0.0):
            raise ValueError(f"dt_s must be > 0, got {self.dt_s!r}")

    def start(self) -> None:
        self._wall0 = self.wall_clock()
        self._steps_done = 0

    def steps_due(self) -> int:
        """Number of physics steps to run now to keep sim time = speed * wall time elapsed."""
        if math.isnan(self._wall0):
            self.start()
        target = int((self.wall_clock() - self._wall0) * self.speed / self.dt_s)
        due = target - self._steps_done
        if due > self.max_catch_up_steps:
            self.skipped_steps += due - self.max_catch_up_steps
            self._steps_done += due - self.max_catch_up_steps
            due = self.max_catch_up_steps
        return max(0, due)

    def mark_done(self, n: int) -> None:
        self._steps_done += n

    def wall_until_next_step_s(self) -> float:
        next_wall = self._wall0 + (self._steps_done + 1) * self.dt_s / self.speed
        return max(0.0, next_wall - self.wall_clock())


async def run_paced(
    pacer: RealTimePacer, step_once: Callable[[], None], after_batch: Callable[[], None]
) -> None:
    """The physics task of every vehicle loop: run the steps that are due, then `after_batch`, then sleep.

    Runs until cancelled. Late steps are caught up in whole steps (bounded by the pacer), never skipped silently.
    """
    pacer.start()
    while True:
        n = pacer.steps_due()
        for _ in range(n):
            step_once()
        if n:
            pacer.mark_done(n)
            after_batch()
        await asyncio.sleep(max(0.0005, pacer.wall_until_next_step_s()))
