"""Land detector (PX4's land_detector module, reduced): ground contact transitions, the landed state reported in
EXTENDED_SYS_STATE, and what auto-disarm needs (time on the ground, whether the vehicle flew since arming)."""

from __future__ import annotations

import enum

from viva_sitl.autopilot.types import LandedState
from viva_sitl.dynamics import EavState


class Transition(enum.Enum):
    NONE = 0
    TOUCHDOWN = 1
    LIFTOFF = 2


class LandDetector:
    def __init__(self) -> None:
        self.landed = True  # the detector's verdict
        self.ground_since_s = 0.0  # when the vehicle last touched down (or was armed on the ground)
        self.has_flown = False  # since arming
        self.landed_state = LandedState.ON_GROUND

    def start(self, state: EavState) -> None:
        """The first state: no transition for where the vehicle starts."""
        self.landed = bool(state.landed)

    def on_armed(self, now_s: float) -> None:
        self.has_flown = False
        self.ground_since_s = now_s

    def update(self, now_s: float, state: EavState, armed: bool) -> Transition:
        on_ground = bool(state.landed)
        change = Transition.NONE
        if on_ground and not self.landed:
            self.ground_since_s = now_s
            change = Transition.TOUCHDOWN
        elif not on_ground and self.landed and armed:
            self.has_flown = True
            change = Transition.LIFTOFF
        self.landed = on_ground
        return change

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
