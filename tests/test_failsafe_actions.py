"""The PX4 failsafe parameters' codes become typed actions at the boundary: every code of every action parameter
gives the action the vehicle flew before the codes were typed (the tables below are PX4's meanings of the codes)."""

from __future__ import annotations

import pytest

from viva_sitl.autopilot.failsafe import (
    ApplyFailsafe,
    Cause,
    FailsafeAction,
    FailsafeFlags,
    FailsafeInputs,
    HoldAt,
    Notify,
    SwitchMode,
    evaluate,
)
from viva_sitl.autopilot.params import ParamStore
from viva_sitl.autopilot.types import CommandResult, FlightMode, Severity

A = FailsafeAction
AIR = (0.0, 0.0, -10.0)


def _inputs(**kw: object) -> FailsafeInputs:
    base: dict[str, object] = dict(now_s=10.0, mode=FlightMode.AUTO_LOITER, armed=True, in_air=True,
                                   offboard_last_s=10.0, manual_fresh=False, gcs_seen=False, gcs_last_s=10.0,
                                   inside=None, pos_ned_m=AIR)  # fmt: skip
    base.update(kw)
    return FailsafeInputs(**base)  # type: ignore[arg-type]


def _params(name: str, code: int) -> ParamStore:
    p = ParamStore()
    p.set(name, code)
    return p


def _applied(actions: list[object]) -> list[ApplyFailsafe]:
    return [a for a in actions if isinstance(a, ApplyFailsafe)]


@pytest.mark.parametrize(("code", "want"), [(0, A.HOLD), (1, A.HOLD), (2, A.RTL), (3, A.LAND), (4, A.HOLD),
                                            (5, A.TERMINATE), (6, A.DISARM)])  # fmt: skip
def test_nav_rcl_act_codes(code: int, want: FailsafeAction) -> None:
    """Manual control lost in a manual mode: off and codes not flown fall back to Hold."""
    _, out = evaluate(_inputs(mode=FlightMode.POSCTL), FailsafeFlags(), _params("NAV_RCL_ACT", code))
    assert out == [ApplyFailsafe(want, Cause.MANUAL_CONTROL_LOSS)]


@pytest.mark.parametrize(("code", "want"), [(0, None), (1, A.HOLD), (2, A.RTL), (3, A.LAND), (4, None),
                                            (5, A.TERMINATE), (6, A.DISARM)])  # fmt: skip
def test_nav_dll_act_codes(code: int, want: FailsafeAction | None) -> None:
    inp = _inputs(now_s=20.0, gcs_seen=True, gcs_last_s=0.0)  # past COM_DL_LOSS_T
    flags, out = evaluate(inp, FailsafeFlags(), _params("NAV_DLL_ACT", code))
    assert flags.dll_lost and out[0] == Notify(Severity.CRITICAL, "Connection to ground station lost")
    assert _applied(out) == ([] if want is None else [ApplyFailsafe(want, Cause.GCS_CONNECTION_LOSS)])


@pytest.mark.parametrize(("code", "want"), [(0, A.HOLD), (1, A.HOLD), (2, A.HOLD), (3, A.RTL), (4, A.LAND),
                                            (5, A.HOLD), (6, A.TERMINATE), (7, A.DISARM)])  # fmt: skip
def test_com_obl_rc_act_codes_without_manual_control(code: int, want: FailsafeAction) -> None:
    inp = _inputs(mode=FlightMode.OFFBOARD, offboard_last_s=0.0)
    _, out = evaluate(inp, FailsafeFlags(), _params("COM_OBL_RC_ACT", code))
    assert out == [ApplyFailsafe(want, Cause.OFFBOARD_LOSS)]


@pytest.mark.parametrize(("code", "mode"), [(0, FlightMode.POSCTL), (1, FlightMode.ALTCTL),
                                            (2, FlightMode.STABILIZED)])  # fmt: skip
def test_com_obl_rc_act_fallbacks_with_manual_control(code: int, mode: FlightMode) -> None:
    inp = _inputs(mode=FlightMode.OFFBOARD, offboard_last_s=0.0, manual_fresh=True)
    _, out = evaluate(inp, FailsafeFlags(), _params("COM_OBL_RC_ACT", code))
    assert out == [SwitchMode(mode, f"Failsafe activated (offboard lost): switching to {mode.name}")]


@pytest.mark.parametrize(("code", "want"), [(0, None), (1, None), (2, "hold"), (3, A.RTL), (4, A.TERMINATE),
                                            (5, A.LAND)])  # fmt: skip
def test_sim_ftg_fence_codes(code: int, want: FailsafeAction | str | None) -> None:
    flags, out = evaluate(_inputs(inside=False), FailsafeFlags(), _params("SIM_FTG_FENCE", code))
    assert flags.gf_outside
    if code == 0:
        assert out == []
    elif code == 1:
        assert out == [Notify(Severity.WARNING, "Outside the footage: the camera sees no ground imagery")]
    else:
        assert out[0] == Notify(Severity.CRITICAL, "Geofence breached: outside footage")
        if want == "hold":
            assert isinstance(out[1], HoldAt) and not _applied(out)
        else:
            assert _applied(out) == [ApplyFailsafe(want, Cause.GEOFENCE)]  # type: ignore[arg-type]


def test_causes_carry_the_texts_the_statustexts_had() -> None:
    assert (Cause.OFFBOARD_LOSS.reason, Cause.OFFBOARD_LOSS.kind) == ("no offboard", "Offboard lost")
    assert (Cause.ATTITUDE_INVALID.reason, Cause.ATTITUDE_INVALID.kind) == (
        "attitude estimate invalid",
        "No attitude estimate",
    )
    assert all(a != a.value for a in FailsafeAction)  # an action never equals an int (a parameter's code)


@pytest.mark.parametrize(
    ("action", "armed", "mode", "text"),
    [
        (A.HOLD, True, FlightMode.AUTO_LOITER, "Failsafe activated (no GCS): switching to Hold"),
        (A.RTL, True, FlightMode.AUTO_RTL, "Failsafe activated (no GCS): switching to Return"),
        (A.LAND, True, FlightMode.AUTO_LAND, "Failsafe activated (no GCS): switching to Land"),
        (A.TERMINATE, False, None, "GCS lost: termination"),
        (A.DISARM, False, None, "GCS lost: lockdown"),
        (A.WARN, True, None, None),
        (A.FALLBACK_STAB, True, None, None),
    ],
)
def test_the_commander_takes_each_action(
    action: FailsafeAction, armed: bool, mode: FlightMode | None, text: str | None
) -> None:
    """Hold / RTL / Land switch mode with a WARNING, Terminate / Disarm (PX4's Lockdown) disarm with an EMERGENCY
    naming the cause, the rest change nothing."""
    from tests.test_autopilot import Flight

    f = Flight()
    f.run(0.1)
    assert f.ap.arm(f.t).result == CommandResult.ACCEPTED
    assert f.ap.takeoff(f.t, None).ok
    f.run(1.0)  # climbing in Takeoff
    before = f.ap.mode
    f.ap.pop_events()
    f.ap.commander.failsafe(action, Cause.GCS_CONNECTION_LOSS)
    assert f.ap.armed is armed
    assert before not in (
        FlightMode.AUTO_LOITER,
        FlightMode.AUTO_RTL,
        FlightMode.AUTO_LAND,
    )  # each switch is seen
    if text is None:  # nothing taken: the mode is the one before
        assert f.ap.mode == before
    if mode is not None:
        assert f.ap.mode == mode
    events = [(e.severity, e.text) for e in f.ap.pop_events()]
    if text is None:
        assert events == []
    else:
        sev = Severity.EMERGENCY if not armed else Severity.WARNING
        assert (sev, text) in events, events
