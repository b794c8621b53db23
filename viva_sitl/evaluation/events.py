"""What a trial's events are: one StrEnum of their kinds (as `TrialEnd` for end reasons), so that the code that
writes an event and the code that looks for one name the same member. Members are strings: they compare equal to,
and serialise as, the plain names events.jsonl has always held ("failsafe", "land_now", ...), and an in-process
pilot that compares `e["kind"] == "failsafe"` still sees it."""

from __future__ import annotations

import enum


class EventKind(enum.StrEnum):
    """The kind of one trial event (events.jsonl `kind`; the in-process pilots' `Observation.events`)."""

    START = "start"  # the monitor's first step: start pose, mode, armed
    AUTOPILOT = "autopilot"  # an autopilot STATUSTEXT
    FAILSAFE = "failsafe"  # an autopilot STATUSTEXT about a failsafe (scored: the row's failsafes column)
    LAND_NOW = "land_now"  # the scenario's "land now" (told to the pilot)
    FAILURE = "failure"  # a scenario failure injected (or refused)
    REACTION = "reaction"  # the pilot's first command after land now
    MODE = "mode"  # a flight mode change
    ARMED = "armed"
    DISARMED = "disarmed"
    TOUCHDOWN = "touchdown"
    LIFTOFF = "liftoff"
    OUTSIDE = "outside"  # the ground point left the footage
    INSIDE = "inside"  # the ground point back over the footage
    END = "end"  # the trial's end (and why)
    PILOT = "pilot"  # an external pilot's exit note

    @classmethod
    def parse(cls, value: object, where: str) -> EventKind:
        """`value` read back from disk as a member; ValueError (one line naming `where`) for a kind this version
        does not write."""
        if isinstance(value, str) and value in cls._value2member_map_:
            return cls(value)
        known = ", ".join(k.value for k in cls)
        raise ValueError(f"{where}: unknown event kind {value!r} (known: {known})")
