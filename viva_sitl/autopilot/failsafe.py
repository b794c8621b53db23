"""Failsafe evaluation (PX4's FailsafeBase, reduced): a pure function from what the vehicle knows now to the actions
the commander must take. No state is changed here: the latched flags come in and go out.

Checks, in order: offboard loss (COM_OF_LOSS_T -> COM_OBL_RC_ACT), manual control loss in manual modes
(COM_RC_LOSS_T -> NAV_RCL_ACT, once per loss), ground-station link loss once a GCS was seen (COM_DL_LOSS_T ->
NAV_DLL_ACT, in the air), the footage edge (SIM_FTG_FENCE, once per exit, in the air), the uploaded geofence and
the GF_MAX_HOR_DIST / GF_MAX_VER_DIST cylinder (GF_ACTION, once per breach, in the air), and the battery level
(BAT_LOW_THR / BAT_CRIT_THR, a warning once per crossing).

SIM_FTG_FENCE and GF_ACTION share PX4's geofence action codes: 0 none, 1 warning, 2 Hold, 3 Return, 4 Terminate,
5 Land. The footage edge defaults to 1 (a STATUSTEXT once per exit: unchanged PX4 code flies beyond the footage, the
camera shows the fill there); Hold holds where the camera last saw footage.

The parameters hold PX4's integer codes, and each parameter numbers its choices its own way (NAV_DLL_ACT 3 is Land,
GF_ACTION 3 is Return). They become a typed `FailsafeAction` at the boundary, in the `from_*_param` functions named
after PX4's (failsafe.cpp fromNavDllOrRclActParam, fromGfActParam, fromOffboardLossActParam); past it only the enum is
compared. `Cause` says why, as PX4's failsafe framework does, with the texts the STATUSTEXTs carry.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, replace

from viva_sitl.autopilot.geofence import FenceLimits, Geofence, breach_reason
from viva_sitl.autopilot.params import ParamStore
from viva_sitl.autopilot.types import FlightMode, Severity

_MANUAL_MODES = frozenset({FlightMode.MANUAL, FlightMode.STABILIZED, FlightMode.ALTCTL, FlightMode.POSCTL})


class FailsafeAction(enum.Enum):
    """What a failsafe does (PX4 FailsafeBase::Action; later members take precedence there). Not an IntEnum on
    purpose: the parameters' codes differ per parameter, so an action never compares equal to a code."""

    NONE = 0
    WARN = 1
    FALLBACK_POSCTRL = 2
    FALLBACK_ALTCTRL = 3
    FALLBACK_STAB = 4
    HOLD = 5
    RTL = 6
    LAND = 7
    DESCEND = 8
    DISARM = 9  # PX4's "Lockdown" choice of NAV_DLL_ACT / COM_OBL_RC_ACT
    TERMINATE = 10


class Cause(enum.Enum):
    """Why a failsafe acts (PX4 FailsafeBase::Cause, with the causes this vehicle has): `reason` goes into
    "Failsafe activated (reason): switching to ...", `kind` into the disarm text "kind: termination"."""

    OFFBOARD_LOSS = ("no offboard", "Offboard lost")
    MANUAL_CONTROL_LOSS = ("manual control lost", "RC lost")
    GCS_CONNECTION_LOSS = ("no GCS", "GCS lost")
    GEOFENCE = ("geofence", "Geofence")
    ATTITUDE_INVALID = ("attitude estimate invalid", "No attitude estimate")

    @property
    def reason(self) -> str:
        return self.value[0]

    @property
    def kind(self) -> str:
        return self.value[1]


_A = FailsafeAction
# NAV_DLL_ACT / NAV_RCL_ACT: 0 off, 1 Hold, 2 Return, 3 Land, 5 Terminate, 6 Lockdown (4 and others: none)
_NAV_ACT = {1: _A.HOLD, 2: _A.RTL, 3: _A.LAND, 5: _A.TERMINATE, 6: _A.DISARM}
# GF_ACTION / SIM_FTG_FENCE: 0 none, 1 warning, 2 Hold, 3 Return, 4 Terminate, 5 Land
_GF_ACT = {0: _A.NONE, 1: _A.WARN, 2: _A.HOLD, 3: _A.RTL, 4: _A.TERMINATE, 5: _A.LAND}
# COM_OBL_RC_ACT: 0 Position, 1 Altitude, 2 Manual (these three need RC), 3 Return, 4 Land, 5 Hold, 6 Terminate,
# 7 Disarm (others: Hold)
_OBL_ACT = {0: _A.FALLBACK_POSCTRL, 1: _A.FALLBACK_ALTCTRL, 2: _A.FALLBACK_STAB, 3: _A.RTL, 4: _A.LAND,
            5: _A.HOLD, 6: _A.TERMINATE, 7: _A.DISARM}  # fmt: skip
# the fallbacks to a manual mode (they need manual control; without it they become Hold, as PX4 v1.14)
_FALLBACK_MODE = {_A.FALLBACK_POSCTRL: FlightMode.POSCTL, _A.FALLBACK_ALTCTRL: FlightMode.ALTCTL,
                  _A.FALLBACK_STAB: FlightMode.STABILIZED}  # fmt: skip
# the actions that take the vehicle over (a mode, or a disarm): not none, a warning or a manual fallback
FLOWN_ACTIONS = frozenset({_A.HOLD, _A.RTL, _A.LAND, _A.TERMINATE, _A.DISARM})


def from_nav_dll_or_rcl_act_param(code: int) -> FailsafeAction:
    """NAV_DLL_ACT / NAV_RCL_ACT -> the action (NONE: off, or a code this vehicle does not fly)."""
    return _NAV_ACT.get(code, FailsafeAction.NONE)


def from_gf_act_param(code: int) -> FailsafeAction:
    """GF_ACTION / SIM_FTG_FENCE -> the action (NONE: 0 or a code out of range)."""
    return _GF_ACT.get(code, FailsafeAction.NONE)


def from_offboard_loss_act_param(code: int) -> FailsafeAction:
    """COM_OBL_RC_ACT -> the action (HOLD: a code out of range)."""
    return _OBL_ACT.get(code, FailsafeAction.HOLD)


@dataclass(frozen=True)
class FailsafeInputs:
    now_s: float
    mode: FlightMode
    armed: bool
    in_air: bool  # armed and not on the ground
    offboard_last_s: float  # when the last offboard setpoint arrived
    manual_fresh: bool  # MANUAL_CONTROL within COM_RC_LOSS_T
    gcs_seen: bool
    gcs_last_s: float
    inside: bool | None  # the footage test now; None: not evaluated this step
    pos_ned_m: tuple[float, float, float]
    geofence: Geofence | None = None  # the uploaded fence to test now; None: not evaluated this step
    home_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class FailsafeFlags:
    """What the evaluation latches between steps."""

    dll_lost: bool = False
    rc_lost_handled: bool = False
    gf_outside: bool = False
    last_inside_ned_m: tuple[float, float, float] | None = None
    fence_breached: bool = False  # the uploaded geofence / home cylinder


@dataclass(frozen=True)
class SwitchMode:
    """Enter `mode`; then, when `text`, a WARNING with it."""

    mode: FlightMode
    text: str | None = None


@dataclass(frozen=True)
class ApplyFailsafe:
    """Take `action` (one of FLOWN_ACTIONS: Hold, RTL and Land switch mode, Terminate and Disarm disarm)."""

    action: FailsafeAction
    cause: Cause


@dataclass(frozen=True)
class HoldAt:
    """Enter Hold at `pos_ned_m` (None: at the braking point)."""

    pos_ned_m: tuple[float, float, float] | None


@dataclass(frozen=True)
class Notify:
    severity: Severity
    text: str


Action = SwitchMode | ApplyFailsafe | HoldAt | Notify


def evaluate(inp: FailsafeInputs, flags: FailsafeFlags, p: ParamStore) -> tuple[FailsafeFlags, list[Action]]:
    """The actions due now and the new flags (reads the parameters only)."""
    out: list[Action] = []
    # Offboard loss.
    if inp.mode == FlightMode.OFFBOARD and inp.now_s - inp.offboard_last_s > p.get("COM_OF_LOSS_T"):
        act = from_offboard_loss_act_param(p.get_int("COM_OBL_RC_ACT"))
        if act in _FALLBACK_MODE and inp.manual_fresh:
            target = _FALLBACK_MODE[act]
            out.append(SwitchMode(target, f"Failsafe activated (offboard lost): switching to {target.name}"))
        elif not inp.armed:
            out.append(SwitchMode(FlightMode.AUTO_LOITER))
        else:
            act = FailsafeAction.HOLD if act in _FALLBACK_MODE else act
            out.append(ApplyFailsafe(act, Cause.OFFBOARD_LOSS))
    # Manual control loss in manual modes (once per loss).
    if inp.mode in _MANUAL_MODES and inp.armed and not inp.manual_fresh:
        if not flags.rc_lost_handled:
            flags = replace(flags, rc_lost_handled=True)
            act = from_nav_dll_or_rcl_act_param(p.get_int("NAV_RCL_ACT"))
            # off (0) or a code not flown: Hold (PX4 switches to Hold as a plain mode change there)
            act = act if act in FLOWN_ACTIONS else FailsafeAction.HOLD
            out.append(ApplyFailsafe(act, Cause.MANUAL_CONTROL_LOSS))
    elif inp.manual_fresh:
        flags = replace(flags, rc_lost_handled=False)
    # Ground-station link loss (only once a GCS has been seen).
    if inp.gcs_seen and not flags.dll_lost and inp.now_s - inp.gcs_last_s > p.get("COM_DL_LOSS_T"):
        flags = replace(flags, dll_lost=True)
        act = from_nav_dll_or_rcl_act_param(p.get_int("NAV_DLL_ACT"))
        out.append(Notify(Severity.CRITICAL, "Connection to ground station lost"))
        if inp.in_air and act in FLOWN_ACTIONS:
            out.append(ApplyFailsafe(act, Cause.GCS_CONNECTION_LOSS))
    # The footage edge (SIM_FTG_FENCE).
    if inp.inside is True:
        flags = replace(flags, gf_outside=False, last_inside_ned_m=inp.pos_ned_m)
    elif inp.inside is False and not flags.gf_outside:
        flags = replace(flags, gf_outside=True)
        act = from_gf_act_param(p.get_int("SIM_FTG_FENCE"))
        if inp.in_air and act is FailsafeAction.WARN:
            out.append(Notify(Severity.WARNING, "Outside the footage: the camera sees no ground imagery"))
        elif inp.in_air and act in FLOWN_ACTIONS:
            out.append(Notify(Severity.CRITICAL, "Geofence breached: outside footage"))
            if act is FailsafeAction.HOLD:
                last = flags.last_inside_ned_m
                # hold where the camera still saw footage, at the current altitude
                out.append(HoldAt(None if last is None else (last[0], last[1], inp.pos_ned_m[2])))
                out.append(Notify(Severity.WARNING, "Failsafe activated (geofence): switching to Hold"))
            else:
                out.append(ApplyFailsafe(act, Cause.GEOFENCE))
    # The uploaded geofence and the home cylinder (GF_ACTION).
    if inp.geofence is not None:
        limits = FenceLimits(p.get("GF_MAX_HOR_DIST"), p.get("GF_MAX_VER_DIST"))
        reason = breach_reason(inp.geofence, inp.pos_ned_m, inp.home_ned_m, limits)
        if reason is None:
            flags = replace(flags, fence_breached=False)
        elif inp.in_air and not flags.fence_breached:
            flags = replace(flags, fence_breached=True)
            act = from_gf_act_param(p.get_int("GF_ACTION"))
            if act is not FailsafeAction.NONE:
                out.append(Notify(Severity.CRITICAL, f"Geofence breached: {reason}"))
            if act in FLOWN_ACTIONS:
                out.append(ApplyFailsafe(act, Cause.GEOFENCE))
    return flags, out


def quiet(now_s: float, mode: FlightMode, offboard_last_s: float, gcs_seen: bool, gcs_last_s: float,
          flags: FailsafeFlags, p: ParamStore) -> bool:  # fmt: skip
    """True when `evaluate` with these inputs, no footage test (inside None) and no fence test (geofence None) would
    return no action and flags equal to `flags` — the common case, checked without building FailsafeInputs (this
    runs at 250 Hz). Conservative: False sends the caller to `evaluate`, which stays the reference."""
    if (
        mode in _MANUAL_MODES or flags.rc_lost_handled
    ):  # the manual-control branch may act or change the flags
        return False
    if mode == FlightMode.OFFBOARD and now_s - offboard_last_s > p.get("COM_OF_LOSS_T"):
        return False
    return not (gcs_seen and not flags.dll_lost and now_s - gcs_last_s > p.get("COM_DL_LOSS_T"))


def battery_level(remaining: float, p: ParamStore) -> int:
    """0 ok, 1 low (BAT_LOW_THR), 2 critical (BAT_CRIT_THR)."""
    return 2 if remaining <= p.get("BAT_CRIT_THR") else 1 if remaining <= p.get("BAT_LOW_THR") else 0


def battery_warning(level: int, remaining: float) -> Notify | None:
    if level == 1:
        return Notify(
            Severity.WARNING, f"Low battery level! Return advised ({remaining * 100:.0f}% remaining)"
        )
    if level == 2:
        return Notify(
            Severity.CRITICAL, f"Critical battery level! Land now ({remaining * 100:.0f}% remaining)"
        )
    return None
