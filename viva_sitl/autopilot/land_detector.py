"""Land detector (PX4's land_detector module, reduced): ground contact -> maybe landed -> landed with PX4's
hysteresis, the landed state reported in EXTENDED_SYS_STATE, and what auto-disarm needs (time since the landing was
detected, whether the vehicle flew since arming).

PX4 (multicopter): LNDMC_TRIG_TIME (default 1.0 s) is the total time the landing conditions must hold to go through
the three stages ground contact, maybe landed, landed (a third each). Here the condition is the EAV's ground contact;
leaving the ground is detected at once (PX4 declares take-off without delay too).
"""

from __future__ import annotations

import enum

from viva_sitl.autopilot.params import ParamStore
from viva_sitl.autopilot.types import LandedState
from viva_sitl.dynamics import EavState

LNDMC_TRIG_TIME_DEFAULT_S = 1.0  # PX4's default, used while the parameter table has no LNDMC_TRIG_TIME


class Transition(enum.Enum):
    NONE = 0
    TOUCHDOWN = 1  # landed (after the hysteresis)
    LIFTOFF = 2


class Stage(enum.IntEnum):
    AIRBORNE = 0
    GROUND_CONTACT = 1
    MAYBE_LANDED = 2
    LANDED = 3


def trigger_time_s(params: ParamStore) -> float:
    if "LNDMC_TRIG_TIME" in params:
        return max(0.0, params.get("LNDMC_TRIG_TIME"))
    return LNDMC_TRIG_TIME_DEFAULT_S


class LandDetector:
    def __init__(self, params: ParamStore) -> None:
        self.params = params
        self.stage = Stage.LANDED
        self.contact_since_s = 0.0  # when the present ground contact began
        self._in_contact = True
        self.ground_since_s = 0.0  # when the landing was detected (or the vehicle armed on the ground)
        self.has_flown = False  # since arming
        self.landed_state = LandedState.ON_GROUND

    @property
    def landed(self) -> bool:
        """The detector's verdict (PX4's vehicle_land_detected.landed)."""
        return self.stage == Stage.LANDED

    def start(self, state: EavState) -> None:
        """The first state: where the vehicle starts is no transition (on the ground: landed at once)."""
        self.stage = Stage.LANDED if state.landed else Stage.AIRBORNE
        self._in_contact = bool(state.landed)
        self.contact_since_s = state.time_s

    def on_armed(self, now_s: float) -> None:
        self.has_flown = False
        self.ground_since_s = now_s

    def update(self, now_s: float, state: EavState, armed: bool) -> Transition:
        if not state.landed:
            was_landed = self.landed
            self.stage = Stage.AIRBORNE
            self._in_contact = False
            if was_landed and armed:
                self.has_flown = True
                return Transition.LIFTOFF
            return Transition.NONE
        if self.stage == Stage.LANDED:
            return Transition.NONE
        if not self._in_contact:
            self._in_contact = True
            self.contact_since_s = now_s
        trigger_s = trigger_time_s(self.params)
        elapsed = now_s - self.contact_since_s
        if elapsed + 1e-9 >= trigger_s:
            self.stage = Stage.LANDED
            self.ground_since_s = now_s
            return Transition.TOUCHDOWN
        self.stage = Stage(min(int(Stage.MAYBE_LANDED), int(3.0 * elapsed / trigger_s + 1e-9)))
        return Transition.NONE

    def classify(self, armed: bool, takeoff_phase: bool, landing_phase: bool) -> LandedState:
        """The landed state from the verdict and what the flight task is doing."""
        if self.landed:
            state = LandedState.ON_GROUND
        elif not armed:
            state = LandedState.IN_AIR
        elif takeoff_phase:
            state = LandedState.TAKEOFF
        elif landing_phase:
            state = LandedState.LANDING
        else:
            state = LandedState.IN_AIR
        self.landed_state = state
        return state
