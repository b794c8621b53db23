"""Flying from the page: who may steer, stick messages, and the buttons, through the autopilot's own code paths.

Pure logic (no sockets, no clock of its own): the server passes wall time (`now_wall_s`) and simulation time
(`now_s`). Everything a page sends is validated here; what is malformed or out of range is ignored and counted.

Who wins (two pages at once): the page that last took control is the *pilot*; every other page is read-only (its
commands and sticks are refused with a reason, counted). Taking control is explicit ("Take control" / key C).

Sticks (the same ManualInput QGroundControl's MANUAL_CONTROL gives the autopilot: x forward, y right, r yaw right
in -1..1, z throttle 0..1 with 0.5 = centred) are fed to `Autopilot.set_manual_input` by `tick()` at a rate that
keeps COM_RC_LOSS_T fresh at any speed factor. Sticks not refreshed by the pilot page within `stick_timeout_s`
(keys released and the page gone quiet, tab hidden, socket closed) are centred: the vehicle holds. Once a page took
control the dashboard keeps feeding (centred when nobody steers) until a page releases control, as a joystick left
centred would; after a release the autopilot's own RC-loss failsafe applies, as when QGC's joystick is switched off.

Direct mode (the paper's roll, pitch, yaw-rate, thrust): an offboard attitude target through the autopilot (the
path a program pilot's SET_ATTITUDE_TARGET takes): roll = y * max tilt, pitch = -x * max tilt, yaw integrates
r * MPC_MAN_Y_MAX, thrust = the throttle stick on PX4's hover-centred curve; centred sticks level the vehicle at
hover thrust.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from viva_sitl.autopilot import AttitudeTarget, Autopilot, CommandResult, FlightMode, ManualInput, Outcome
from viva_sitl.autopilot.setpoints import throttle_to_thrust_norm
from viva_sitl.dynamics import wrap_pi
from viva_sitl.dynamics.rotation import quat_from_euler

CENTRED = ManualInput(0.0, 0.0, 0.5, 0.0)
DIRECT = "DIRECT"  # the page's name for the paper's direct mode (OFFBOARD attitude from the sticks)

# Modes a page may select (FlightMode names), plus DIRECT.
SELECTABLE_MODES: tuple[str, ...] = (
    "POSCTL",
    "ALTCTL",
    "STABILIZED",
    DIRECT,
    "AUTO_LOITER",
    "AUTO_MISSION",
    "AUTO_RTL",
    "AUTO_LAND",
    "AUTO_TAKEOFF",
    "MANUAL",
    "OFFBOARD",
)
COMMANDS = ("arm", "disarm", "takeoff", "land", "hold", "rtl", "kill", "mode")


def _denied(reason: str) -> Outcome:
    return Outcome(CommandResult.DENIED, reason)


def parse_sticks(msg: dict[str, Any]) -> ManualInput | None:
    """A stick message {x, y, z, r} -> ManualInput; None when a value is missing, not a number or out of range.

    Out of range means beyond the axis (x, y, r outside -1..1, z outside 0..1): such a message is ignored whole,
    never clipped (a page that sends 5.0 has a bug, and guessing what it meant would fly the vehicle)."""
    vals: list[float] = []
    for key in ("x", "y", "z", "r"):
        v = msg.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            return None
        vals.append(float(v))
    x, y, z, r = vals
    if not (-1.0 <= x <= 1.0 and -1.0 <= y <= 1.0 and -1.0 <= r <= 1.0 and 0.0 <= z <= 1.0):
        return None
    return ManualInput(x=x, y=y, z=z, r=r)


@dataclass
class ControlStats:
    malformed: int = 0  # not JSON / not an object / unknown type or command / bad fields
    out_of_range: int = 0  # stick values outside the axes (ignored whole)
    not_pilot: int = 0  # commands or sticks from a read-only page
    commands: int = 0
    refused: int = 0
    sticks: int = 0
    takeovers: int = 0


@dataclass
class PilotState:
    client_id: int | None = None  # the page that has control (None: nobody)
    feeding: bool = False  # the dashboard feeds MANUAL input (a page took control and nobody released it)
    sticks: ManualInput = CENTRED
    sticks_wall_s: float = -math.inf
    direct: bool = False
    direct_yaw_rad: float = 0.0
    last_tick_sim_s: float | None = None
    fed_manual: ManualInput | None = None  # what before_step() gives the autopilot at every physics step
    fed_attitude: AttitudeTarget | None = None


@dataclass
class Controller:
    """The flying side of the dashboard for one vehicle (its autopilot and the clock readers the app gives)."""

    autopilot: Autopilot
    sim_time_s: Callable[[], float]
    yaw_rad: Callable[[], float]
    stick_timeout_s: float = 0.5
    # a refusal's reason also goes out as STATUSTEXT (as the MAVLink commands' refusals): (severity, text)
    statustext: Callable[[int, str], None] | None = None
    stats: ControlStats = field(default_factory=ControlStats)
    pilot: PilotState = field(default_factory=PilotState)

    # --- who steers --------------------------------------------------------------------------
    def take_control(self, client_id: int) -> int | None:
        """`client_id` becomes the pilot; returns the previous pilot (now read-only), if another page."""
        prev = self.pilot.client_id
        self.pilot.client_id = client_id
        self.pilot.feeding = True
        self.pilot.sticks = CENTRED
        self.pilot.sticks_wall_s = -math.inf
        # RC present at once: a mode switch may follow right away
        self.pilot.fed_manual = CENTRED
        self.autopilot.set_manual_input(self.sim_time_s(), CENTRED)
        if prev is not None and prev != client_id:
            self.stats.takeovers += 1
            return prev
        return None

    def release_control(self, client_id: int) -> bool:
        """The pilot gives control back: the dashboard stops feeding sticks (the RC-loss failsafe applies)."""
        if self.pilot.client_id != client_id:
            return False
        self.pilot = PilotState(direct_yaw_rad=self.pilot.direct_yaw_rad)  # feeding off
        return True

    def client_gone(self, client_id: int) -> None:
        """A page closed its socket: when it was the pilot, sticks are centred and the vehicle holds."""
        if self.pilot.client_id == client_id:
            self.pilot.client_id = None
            self.pilot.sticks = CENTRED
            self.pilot.sticks_wall_s = -math.inf
            if self.pilot.feeding:
                self.pilot.fed_manual = CENTRED

    def is_pilot(self, client_id: int) -> bool:
        return self.pilot.client_id == client_id

    # --- sticks ------------------------------------------------------------------------------
    def sticks(self, client_id: int, msg: dict[str, Any], now_wall_s: float) -> str | None:
        """A stick message from a page; returns why it was ignored (None: taken)."""
        if not self.is_pilot(client_id):
            self.stats.not_pilot += 1
            return "read-only: another page has control (press Take control)"
        manual = parse_sticks(msg)
        if manual is None:
            self.stats.out_of_range += 1
            return "sticks ignored: values missing, not finite or out of range"
        self.pilot.sticks = manual
        self.pilot.sticks_wall_s = now_wall_s
        self.stats.sticks += 1
        self.pilot.fed_manual = manual
        self.autopilot.set_manual_input(self.sim_time_s(), manual)  # at once; tick() keeps it fresh
        return None

    def current_sticks(self, now_wall_s: float) -> ManualInput:
        if now_wall_s - self.pilot.sticks_wall_s > self.stick_timeout_s:
            return CENTRED
        return self.pilot.sticks

    def tick(self, now_wall_s: float) -> None:
        """Feed the autopilot (called on the asyncio loop, several times per COM_RC_LOSS_T of sim time)."""
        p = self.pilot
        if not p.feeding:
            return
        now = self.sim_time_s()
        sticks = self.current_sticks(now_wall_s)
        p.fed_manual = sticks
        self.autopilot.set_manual_input(now, sticks)
        dt = 0.0 if p.last_tick_sim_s is None else max(0.0, min(0.5, now - p.last_tick_sim_s))
        p.last_tick_sim_s = now
        if p.direct:
            if self.autopilot.mode != FlightMode.OFFBOARD:
                p.direct = False  # someone switched away (a button, MAVLink, a failsafe): direct mode ends
                return
            self._feed_direct(now, sticks, dt)

    def before_step(self, now_s: float) -> None:
        """Called by the app before every physics step: the latest sticks (and direct-mode attitude) reach the
        autopilot at each step, as from an RC receiver wired to it. So a busy machine, whose loop runs many physics
        steps in one batch, never looks like an RC loss; expiry stays with tick() (wall time)."""
        p = self.pilot
        if not p.feeding or p.fed_manual is None:
            return
        self.autopilot.set_manual_input(now_s, p.fed_manual)
        if p.direct and p.fed_attitude is not None and self.autopilot.mode == FlightMode.OFFBOARD:
            self.autopilot.set_attitude_target(now_s, p.fed_attitude)

    def _attitude_target(self, sticks: ManualInput) -> AttitudeTarget:
        ap = self.autopilot
        tilt = float(ap.eav.max_tilt_rad)
        q = quat_from_euler(sticks.y * tilt, -sticks.x * tilt, self.pilot.direct_yaw_rad)
        thrust = throttle_to_thrust_norm(sticks.z, ap.params.get("MPC_THR_HOVER"))
        return AttitudeTarget(q_wxyz=q, body_rates_rad_s=None, thrust_norm=min(1.0, max(0.0, thrust)))

    def _feed_direct(self, now: float, sticks: ManualInput, dt: float) -> None:
        rate = math.radians(self.autopilot.params.get("MPC_MAN_Y_MAX"))
        self.pilot.direct_yaw_rad = wrap_pi(self.pilot.direct_yaw_rad + sticks.r * rate * dt)
        self.pilot.fed_attitude = self._attitude_target(sticks)
        self.autopilot.set_attitude_target(now, self.pilot.fed_attitude)

    # --- buttons -----------------------------------------------------------------------------
    def command(self, client_id: int, msg: dict[str, Any]) -> Outcome:
        """A button: the same autopilot calls the MAVLink commands make (mavlink/commands.py), same refusals."""
        if not self.is_pilot(client_id):
            self.stats.not_pilot += 1
            return _denied("Read-only: another page has control (press Take control)")
        name = msg.get("cmd")
        if name not in COMMANDS:
            self.stats.malformed += 1
            return _denied(f"Unknown command {str(name)[:40]!r}")
        self.stats.commands += 1
        outcome = self._run(str(name), msg)
        if not outcome.ok:
            self.stats.refused += 1
            if outcome.reason and self.statustext is not None:
                # ERROR / WARNING, as commands.py
                severity = 3 if outcome.result == CommandResult.FAILED else 4
                self.statustext(severity, outcome.reason)
        return outcome

    def _run(self, name: str, msg: dict[str, Any]) -> Outcome:
        ap = self.autopilot
        now = self.sim_time_s()
        if name == "arm":  # COMPONENT_ARM_DISARM param1=1
            return ap.arm(now)
        if name == "disarm":
            return ap.disarm(now)
        if name == "kill":  # COMPONENT_ARM_DISARM param1=0 param2=21196 (force): motors off, in the air too
            if msg.get("confirm") is not True:
                return _denied("Kill needs confirmation")
            return ap.kill(now)
        if name == "takeoff":  # NAV_TAKEOFF without altitude: MIS_TAKEOFF_ALT
            return ap.takeoff(now, None)
        if name == "land":
            return ap.land(now)
        if name == "rtl":
            return ap.return_to_launch(now)
        if name == "hold":  # DO_SET_MODE AUTO_LOITER
            return ap.set_mode(now, FlightMode.AUTO_LOITER)
        mode_name = msg.get("mode")
        if mode_name == DIRECT:
            return self._enter_direct(now)
        if mode_name not in SELECTABLE_MODES:
            return _denied(f"Unsupported mode {str(mode_name)[:40]!r}")
        return ap.set_mode(now, FlightMode[str(mode_name)])

    def _enter_direct(self, now: float) -> Outcome:
        ap = self.autopilot
        if not self.pilot.feeding:
            return _denied("Direct mode needs control (press Take control)")
        self.pilot.direct_yaw_rad = float(self.yaw_rad())
        # as MAVSDK's offboard start: a setpoint first, then the mode switch (refused when the stream is stale)
        self.pilot.fed_attitude = self._attitude_target(CENTRED)
        outcome = ap.set_attitude_target(now, self.pilot.fed_attitude)
        if outcome.ok:
            outcome = ap.set_mode(now, FlightMode.OFFBOARD)
        self.pilot.direct = outcome.ok
        self.pilot.last_tick_sim_s = now
        return outcome
