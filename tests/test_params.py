"""ParamStore: PX4's parameter set (names, types, defaults, ranges), PX4's storage rules, the wired/stored split, the
_HASH_CHECK value, and the SIM_* parameters that rebuild the EAV parameters.

The expected values here are typed from PX4's parameter reference (docs.px4.io, "Parameter Reference"), not read
from viva_sitl/data/px4_params.tsv or the wired table: a wrong generator, a wrong filter or a wrong merge fails them.
"""

from __future__ import annotations

import math
import re
import struct
from pathlib import Path

import pytest

from viva_sitl.autopilot import Autopilot, ParamStore, ParamType
from viva_sitl.autopilot.params import ParamSpec
from viva_sitl.dynamics import EavParams, WindParams

INT, F = ParamType.INT32, ParamType.REAL32

# name: (type, default, min, max) from PX4's parameter reference; None = no documented bound.
PX4_FACTS: dict[str, tuple[ParamType, float, float | None, float | None]] = {
    "MPC_XY_CRUISE": (F, 5.0, 3.0, 20.0),
    "MPC_XY_VEL_P_ACC": (F, 2.4, 1.2, 5.0),  # default: ours (PX4 1.8), see the wired table
    "COM_RC_IN_MODE": (INT, 3, 0, 4),
    "COM_DL_LOSS_T": (INT, 10, 5, 300),
    "NAV_DLL_ACT": (INT, 0, 0, 6),
    "GF_ACTION": (INT, 2, 0, 5),
    "MIS_TAKEOFF_ALT": (F, 2.5, 0.0, 100.0),  # PX4 documents min 0 only; 100 is our safety bound
    "RTL_RETURN_ALT": (F, 60.0, 0.0, 150.0),
    "MPC_TILTMAX_AIR": (F, 45.0, 20.0, 89.0),
    "MPC_THR_HOVER": (F, 0.5, 0.1, 0.8),
    "BAT_LOW_THR": (F, 0.15, 0.12, 0.5),
    "MC_ROLL_P": (F, 6.5, 0.0, 12.0),
    "MC_YAW_P": (F, 2.8, 0.0, 5.0),
    "MC_ROLLRATE_P": (F, 0.15, 0.01, 0.5),
    "EKF2_GPS_CTRL": (INT, 7, 0, 15),
    "MC_ORBIT_RAD_MAX": (F, 1000.0, 1.0, 10000.0),
    "CBRK_SUPPLY_CHK": (INT, 0, 0, 894281),
    "MAV_SYS_ID": (INT, 1, 1, 250),
    "SYS_AUTOSTART": (INT, 4001, 0, 9999999),  # PX4 SITL's default airframe (gz_x500), not the metadata's 0
    "MAV_TYPE": (INT, 2, 0, 22),  # a quadrotor, as our HEARTBEAT says
    "COM_RCL_EXCEPT": (INT, 0, 0, 31),
    "SDLOG_MODE": (INT, 0, None, None),
}


@pytest.mark.parametrize("name", sorted(PX4_FACTS))
def test_px4_facts(name: str) -> None:
    ptype, default, lo, hi = PX4_FACTS[name]
    ps = ParamStore()
    spec = ps.spec(name)
    assert spec.type == ptype
    assert ps.stored(name) == pytest.approx(default) and ps.get(name) == pytest.approx(default)
    if lo is not None:
        assert spec.min == pytest.approx(lo)
    if hi is not None:
        assert spec.max == pytest.approx(hi)


def test_the_set_is_a_multicopter_px4_sitl_set() -> None:
    ps = ParamStore()
    names = ps.names()
    assert 1100 <= len(names) <= 1300  # PX4 SITL (gz_x500) lists ~1000-1200
    assert names == sorted(names)  # PX4's order (param_index) is by name
    assert len(set(names)) == len(names)
    assert all(re.fullmatch(r"[A-Z0-9_]{1,16}", n) for n in names)
    # other vehicle types are out, every multicopter / commander / estimator family is in
    for prefix in ("FW_", "VT_", "GND_", "RWTO_", "UUV_", "NPFG_", "ASPD_", "LPE_", "TEST_"):
        assert not [n for n in names if n.startswith(prefix)], prefix
    for prefix, at_least in (
        ("MPC_", 40),
        ("MC_", 30),
        ("COM_", 50),
        ("EKF2_", 100),
        ("RC", 100),
        ("NAV_", 10),
    ):
        assert sum(n.startswith(prefix) for n in names) >= at_least, prefix
    ints = sum(ps.spec(n).type == ParamType.INT32 for n in names)
    assert 300 < ints < len(names) - 300  # both types are well represented


def _read_param_names(package: Path) -> set[str]:
    """Every PX4-style name the autopilot package reads (string literals), from its source."""
    names: set[str] = set()
    for path in package.rglob("*.py"):  # the package and its subpackages (autopilot/tasks)
        if path.name != "params.py":
            names |= set(re.findall(r'"([A-Z][A-Z0-9]*_[A-Z0-9_]+)"', path.read_text(encoding="utf-8")))
    return names


def test_wired_means_read_by_the_autopilot() -> None:
    import viva_sitl.autopilot as ap_pkg

    ps = ParamStore()
    read = {n for n in _read_param_names(Path(ap_pkg.__file__).parent) if n in ps}
    wired = {n for n in ps.names() if ps.spec(n).wired}
    assert read == wired, (sorted(read - wired), sorted(wired - read))
    assert "MPC_XY_CRUISE" in wired and "COM_RC_IN_MODE" not in wired


def test_unknown_names_raise_key_error() -> None:
    ps = ParamStore()
    with pytest.raises(KeyError):
        ps.get("NOT_A_PARAM")
    with pytest.raises(KeyError):
        ps.set("NOT_A_PARAM", 1.0)
    with pytest.raises(KeyError):
        ps.spec("mis_takeoff_alt")  # names are case-sensitive, as PX4


def test_out_of_range_is_stored_as_px4_and_constrained_for_use() -> None:
    ps = ParamStore()
    ps.set("MPC_XY_CRUISE", 1000.0)  # PX4's param_set does not enforce the documented max (20)
    assert ps.stored("MPC_XY_CRUISE") == 1000.0
    assert ps.get("MPC_XY_CRUISE") == 20.0
    ps.set("GF_ACTION", 9)
    assert ps.stored("GF_ACTION") == 9 and ps.get_int("GF_ACTION") == 5
    ps.set("COM_RC_IN_MODE", -3)  # a stored-only parameter keeps what was set
    assert ps.stored("COM_RC_IN_MODE") == -3


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("MIS_TAKEOFF_ALT", math.nan),
        ("MIS_TAKEOFF_ALT", math.inf),
        ("MIS_TAKEOFF_ALT", 1e39),  # no float32 holds it
        ("NAV_DLL_ACT", 2.5),  # INT32 must be integral
        ("SYS_AUTOSTART", 2.0**31),  # and fit an int32
        ("COM_RC_IN_MODE", "fast"),
    ],
)
def test_values_no_parameter_can_hold_are_rejected(name: str, value: float) -> None:
    ps = ParamStore()
    before, rev = ps.stored(name), ps.revision
    with pytest.raises(ValueError):
        ps.set(name, value)
    assert ps.stored(name) == before
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
    with pytest.raises(IndexError):
        ps.name_at(len(ps))
    assert ps.name_at(ps.index("MPC_XY_CRUISE")) == "MPC_XY_CRUISE"


def _crc32_bitwise(data: bytes, crc: int) -> int:
    """Reflected CRC-32 (polynomial 0xEDB88320) without pre/post inversion, bit by bit."""
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xEDB88320 if crc & 1 else crc >> 1
    return crc


def test_hash_check_is_px4s_crc_over_names_and_values() -> None:
    specs = [
        ParamSpec("A_INT", ParamType.INT32, -7),
        ParamSpec("B_FLOAT", ParamType.REAL32, 0.25),
        ParamSpec("C_VOLATILE", ParamType.INT32, 3, volatile=True),
    ]
    ps = ParamStore(specs)
    crc = _crc32_bitwise(b"A_INT", 0)
    crc = _crc32_bitwise(struct.pack("<i", -7), crc)
    crc = _crc32_bitwise(b"B_FLOAT", crc)
    crc = _crc32_bitwise(struct.pack("<f", 0.25), crc)
    assert ps.hash_check() == crc
    ps.set("C_VOLATILE", 4)  # volatile parameters are not part of the hash
    assert ps.hash_check() == crc
    ps.set("B_FLOAT", 0.5)
    assert ps.hash_check() != crc


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


def test_sim_attitude_params_set_the_airframe_response() -> None:
    ps = ParamStore()
    ap = Autopilot(ps, EavParams())
    # defaults = PX4's: tau = 1/MC_ROLL_P, 1/MC_YAW_P; rate limits = MC_ROLLRATE_MAX, MC_YAWRATE_MAX
    assert ps.get("SIM_ATT_TAU") == pytest.approx(1.0 / ps.get("MC_ROLL_P"))
    assert ps.get("SIM_YAW_TAU") == pytest.approx(1.0 / ps.get("MC_YAW_P"))
    assert ps.get("SIM_RP_RATE_MAX") == ps.get("MC_ROLLRATE_MAX") == ps.get("MC_PITCHRATE_MAX")
    assert ps.get("SIM_YAW_RATE_MAX") == ps.get("MC_YAWRATE_MAX")
    assert ap.eav_params() == EavParams()
    for name in ("SIM_ATT_TAU", "SIM_YAW_TAU", "SIM_RP_RATE_MAX", "SIM_YAW_RATE_MAX"):
        ps.set(name, 0.0)
    assert ap.eav_params().ideal_attitude  # live over PARAM_SET: the paper's instant attitude
    ps.set("SIM_ATT_TAU", 0.25)
    assert ap.eav_params().attitude_tau_s == 0.25
    # the paper airframe in the config: the parameters report its zeros
    ps2 = ParamStore()
    assert Autopilot(ps2, EavParams.paper()).eav_params() == EavParams.paper()
    assert ps2.get("SIM_ATT_TAU") == 0.0 and ps2.get("SIM_YAW_RATE_MAX") == 0.0
