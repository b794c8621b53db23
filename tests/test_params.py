"""ParamStore: PX4 names, types, defaults, ranges; the SIM_* parameters rebuild the EAV parameters."""

from __future__ import annotations

import math

import pytest

from viva_sitl.autopilot import Autopilot, ParamStore, ParamType
from viva_sitl.dynamics import EavParams, WindParams


def test_defaults_and_types_follow_px4() -> None:
    ps = ParamStore()
    expected = {
        "MIS_TAKEOFF_ALT": (2.5, ParamType.REAL32),
        "MPC_XY_CRUISE": (5.0, ParamType.REAL32),
        "MPC_XY_VEL_MAX": (12.0, ParamType.REAL32),
        "MPC_Z_VEL_MAX_UP": (3.0, ParamType.REAL32),
        "MPC_Z_VEL_MAX_DN": (1.5, ParamType.REAL32),
        "MPC_LAND_SPEED": (0.7, ParamType.REAL32),
        "MPC_THR_HOVER": (0.5, ParamType.REAL32),
        "MPC_TILTMAX_AIR": (45.0, ParamType.REAL32),
        "RTL_RETURN_ALT": (60.0, ParamType.REAL32),
        "COM_OF_LOSS_T": (1.0, ParamType.REAL32),
        "COM_OBL_RC_ACT": (0, ParamType.INT32),
        "NAV_DLL_ACT": (0, ParamType.INT32),
        "COM_DL_LOSS_T": (10, ParamType.INT32),
        "COM_DISARM_LAND": (2.0, ParamType.REAL32),
        "GF_ACTION": (2, ParamType.INT32),
        "SIM_MASS": (0.468, ParamType.REAL32),
        "SIM_DRAG": (0.15, ParamType.REAL32),
    }
    for name, (value, ptype) in expected.items():
        assert ps.get(name) == pytest.approx(value), name
        assert ps.spec(name).type == ptype, name
        assert ps.spec(name).description
    names = ps.names()
    assert len(names) == len(set(names)) == len(ps)
    assert all(len(n) <= 16 for n in names)
    assert names == ParamStore().names()  # stable order -> param_index
    assert ps.index("MPC_XY_CRUISE") == names.index("MPC_XY_CRUISE")


def test_unknown_names_raise_key_error() -> None:
    ps = ParamStore()
    with pytest.raises(KeyError):
        ps.get("NOT_A_PARAM")
    with pytest.raises(KeyError):
        ps.set("NOT_A_PARAM", 1.0)
    with pytest.raises(KeyError):
        ps.spec("mis_takeoff_alt")  # names are case-sensitive, as PX4


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("MIS_TAKEOFF_ALT", math.nan),
        ("MIS_TAKEOFF_ALT", math.inf),
        ("MIS_TAKEOFF_ALT", -1.0),
        ("MPC_XY_CRUISE", 1000.0),
        ("NAV_DLL_ACT", 2.5),  # INT32 must be integral
        ("GF_ACTION", 9),
    ],
)
def test_bad_values_are_rejected_and_leave_the_value(name: str, value: float) -> None:
    ps = ParamStore()
    before, rev = ps.get(name), ps.revision
    with pytest.raises(ValueError):
        ps.set(name, value)
    assert ps.get(name) == before
    assert ps.revision == rev
    assert not ps.is_modified(name)


def test_set_int_and_float() -> None:
    ps = ParamStore()
    ps.set("NAV_DLL_ACT", 2)
    assert ps.get("NAV_DLL_ACT") == 2.0 and ps.get_int("NAV_DLL_ACT") == 2
    ps.set("MPC_XY_CRUISE", 7.25)
    assert ps.get("MPC_XY_CRUISE") == 7.25
    assert ps.is_modified("MPC_XY_CRUISE")
    rev = ps.revision
    ps.set("MPC_XY_CRUISE", 7.25)  # same value: no revision bump
    assert ps.revision == rev
    ps.reset("MPC_XY_CRUISE")
    assert ps.get("MPC_XY_CRUISE") == 5.0 and not ps.is_modified("MPC_XY_CRUISE")


def test_sim_params_rebuild_eav_params() -> None:
    base = EavParams(mass_kg=0.8, drag_kd_n_s_m=0.2, wind=WindParams(mean_wind_ned_m_s=(1.0, 0.0, 0.0)))
    ps = ParamStore()
    ap = Autopilot(ps, base)
    # Not set by the user: the configured airframe wins.
    assert ps.get("SIM_MASS") == pytest.approx(0.8)
    assert ps.get("SIM_WIND_N") == pytest.approx(1.0)
    assert ap.eav_params() == base
    assert ap.eav_params() is ap.eav_params()  # cached between changes
    ps.set("SIM_MASS", 1.6)
    ps.set("SIM_WIND_E", -3.0)
    ps.set("SIM_GUST_STD", 0.5)
    new = ap.eav_params()
    assert new.mass_kg == pytest.approx(1.6)
    assert new.max_thrust_n == pytest.approx(base.max_thrust_n * 2.0)  # same thrust-to-weight
    assert new.wind.mean_wind_ned_m_s == pytest.approx((1.0, -3.0, 0.0))
    assert new.wind.gust_std_m_s == 0.5
    assert new.dt_s == base.dt_s and new.drag_kd_n_s_m == pytest.approx(0.2)


def test_user_set_sim_params_override_the_config() -> None:
    ps = ParamStore()
    ps.set("SIM_DRAG", 0.3)
    ap = Autopilot(ps, EavParams())
    assert ap.eav_params().drag_kd_n_s_m == pytest.approx(0.3)
    assert ps.get("SIM_MASS") == pytest.approx(EavParams().mass_kg)
