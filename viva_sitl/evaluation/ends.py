"""How a trial ends: one StrEnum with a message each (as rotorpy's ExitStatus), so an end reason is a name the code
can check and a reader can look up. Members are strings: they compare equal to, and serialise as, the plain names
results.json / results.csv / end.json have always held ("landed", "crash", ...)."""

from __future__ import annotations

import enum


class TrialEnd(enum.StrEnum):
    """Why a trial ended. `flown` ends are the pilot's result; the others are failures of the pilot's program or
    of the harness (docs/trials-results.md)."""

    LANDED = "landed"
    CRASH = "crash"
    LEFT_FOOTAGE = "left_footage"
    TIMEOUT = "timeout"
    SCORER = "scorer"
    PILOT_ERROR = "pilot_error"
    WALL_TIMEOUT = "wall_timeout"
    ABORTED = "aborted"
    SITL_STOPPED = "sitl_stopped"
    SITL_ERROR = "sitl_error"
    WORKER_DIED = "worker_died"
    TRIAL_ERROR = "trial_error"

    @property
    def message(self) -> str:
        return _MESSAGES[self]

    @property
    def infra(self) -> bool:
        """The harness's failure, not the pilot's (INFRA_ENDS)."""
        return self in INFRA_ENDS

    @property
    def flown(self) -> bool:
        """The vehicle's own outcome (landed, crash, left the footage, ran out of time), not a program failure."""
        return self in (
            TrialEnd.LANDED,
            TrialEnd.CRASH,
            TrialEnd.LEFT_FOOTAGE,
            TrialEnd.TIMEOUT,
            TrialEnd.SCORER,
        )


# trial ends that are the harness's failure, not the pilot's: the runner raised, the worker process died, the
# vehicle process (`viva-sitl run`) did not start or stopped early. They are kept out of the success rate and the
# scores, counted on their own, make `trials run` exit 3, and `--resume` runs them again. (A row read back from
# JSON holds a plain string: `in` compares by value, so `row["end"] in INFRA_ENDS` works on either.)
INFRA_ENDS: tuple[TrialEnd, ...] = (
    TrialEnd.TRIAL_ERROR,
    TrialEnd.WORKER_DIED,
    TrialEnd.SITL_ERROR,
    TrialEnd.SITL_STOPPED,
)

_MESSAGES: dict[TrialEnd, str] = {
    TrialEnd.LANDED: "touched down and disarmed",
    TrialEnd.CRASH: "touched down faster than crash_speed_m_s",
    TrialEnd.LEFT_FOOTAGE: "the ground point stayed outside the footage for end_outside_s",
    TrialEnd.TIMEOUT: "not landed and disarmed within timeout_s of simulated time",
    TrialEnd.SCORER: "a gym environment's scorer ended the episode",
    TrialEnd.PILOT_ERROR: "the pilot's code failed (raised, returned garbage, exited, or could not start)",
    TrialEnd.WALL_TIMEOUT: "the trial took longer than its wall-clock limit",
    TrialEnd.ABORTED: "stopped by the user (Ctrl-C / SIGTERM)",
    TrialEnd.SITL_STOPPED: "the viva-sitl run stopped before the trial ended",
    TrialEnd.SITL_ERROR: "the viva-sitl vehicle process failed",
    TrialEnd.WORKER_DIED: "the worker process running the trial died",
    TrialEnd.TRIAL_ERROR: "the harness raised while running the trial",
}

__all__ = ["INFRA_ENDS", "TrialEnd"]
