"""End to end: PX4's parameter set on a `viva-sitl run` subprocess.

- a QGroundControl `.params` file loaded with pymavlink (mission_scripts/pymavlink_load_params.py: bulk PARAM_SET,
  PARAM_REQUEST_LIST read-back), then checked independently by another peer with PARAM_REQUEST_READ;
- MAVSDK's param plugin: get/set of arbitrary PX4 parameters and get_all_params (the whole list);
- `[params]` in a config file: unknown names and non-numbers stop start-up with one line naming the key.
"""

from __future__ import annotations

import asyncio
import struct
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from sitl_process import REPO_ROOT, MavlinkPeer, SitlProcess, run_script

pytestmark = pytest.mark.e2e

# (name, value, MAV_PARAM_TYPE) as QGC saves them; wired and stored-only parameters, INT32 and REAL32, one value
# outside PX4's documented range (MC_ROLL_P max 12: stored as PX4 stores it).
QGC_ROWS: list[tuple[str, float, int]] = [
    ("MPC_XY_CRUISE", 7.5, 9),
    ("MIS_TAKEOFF_ALT", 4.0, 9),
    ("NAV_DLL_ACT", 2, 6),
    ("COM_DL_LOSS_T", 15, 6),
    ("MPC_XY_VEL_P_ACC", 2.1, 9),
    ("COM_RC_IN_MODE", 1, 6),
    ("SYS_AUTOSTART", 4010, 6),
    ("MC_ROLL_P", 15.0, 9),
    ("MC_PITCHRATE_P", 0.12, 9),
    ("EKF2_GPS_CTRL", 5, 6),
    ("EKF2_HGT_REF", 0, 6),
    ("RTL_RETURN_ALT", 35.0, 9),
    ("GF_MAX_HOR_DIST", 500.0, 9),
    ("MC_ORBIT_RAD_MAX", 250.0, 9),
    ("SDLOG_MODE", 1, 6),
    ("CBRK_SUPPLY_CHK", 894281, 6),
    ("LNDMC_Z_VEL_MAX", 0.4, 9),
    ("RC_MAP_THROTTLE", 3, 6),
    ("COM_RCL_EXCEPT", 4, 6),
    ("BAT_LOW_THR", 0.2, 9),
]


def _write_qgc_params(path: Path, rows: list[tuple[str, float, int]], extra: str = "") -> None:
    lines = [
        "# Onboard parameters for Vehicle 1",
        "#",
        "# Stack: PX4 Pro",
        "# Vehicle: Multi-Rotor",
        "#",
        "# Vehicle-Id Component-Id Name Value Type",
    ]
    for name, value, ptype in rows:
        text = str(int(value)) if ptype == 6 else f"{value:.18g}"
        lines.append(f"1\t1\t{name}\t{text}\t{ptype}")
    lines.append("1\t100\tCAM_EV_TRIG_MODE\t1\t6")  # a camera component's row: not for the autopilot
    path.write_text("\n".join(lines) + "\n" + extra, encoding="utf-8")


def _read_int(peer: MavlinkPeer, name: str) -> int:
    raw = peer.get_param(name)
    return int(struct.unpack("<i", struct.pack("<f", raw))[0])


@pytest.mark.slow  # a viva-sitl process
def test_qgc_params_file_loads_and_reads_back(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer], tmp_path: Path
) -> None:
    params_file = tmp_path / "vehicle.params"
    _write_qgc_params(params_file, QGC_ROWS)
    run = run_script(
        "pymavlink_load_params.py", [sitl.ports.pymavlink_url, str(params_file), "--timeout", "60"], 120
    )
    assert run.returncode == 0, run.describe()
    assert run.result["loaded"] == str(len(QGC_ROWS)) and run.result["verified"] == str(len(QGC_ROWS))
    assert run.result["unknown"] == "0" and run.result["mismatched"] == "0"
    assert int(run.result["count"]) > 1000  # the whole PX4 set came back in the list

    # independently of the script: another peer on the GCS port reads values one by one
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    assert peer.get_param("MPC_XY_CRUISE") == pytest.approx(7.5)
    assert peer.get_param("MC_ROLL_P") == pytest.approx(15.0)  # out of documented range: stored, as PX4
    assert peer.get_param("MC_PITCHRATE_P") == pytest.approx(0.12)
    assert _read_int(peer, "SYS_AUTOSTART") == 4010
    assert _read_int(peer, "COM_RC_IN_MODE") == 1
    assert _read_int(peer, "CBRK_SUPPLY_CHK") == 894281
    assert _read_int(peer, "NAV_DLL_ACT") == 2
    assert sitl.alive


@pytest.mark.slow  # a viva-sitl process
def test_qgc_params_file_with_unknown_names_is_reported(sitl: SitlProcess, tmp_path: Path) -> None:
    params_file = tmp_path / "other_firmware.params"
    _write_qgc_params(params_file, [("MPC_XY_CRUISE", 6.0, 9), ("ARSPD_FBW_MIN", 9.0, 9), ("Q_ENABLE", 1, 6)])
    run = run_script(
        "pymavlink_load_params.py",
        [sitl.ports.pymavlink_url, str(params_file), "--retry-s", "0.5", "--timeout", "60"],
        120,
    )
    # PX4 never answers a PARAM_SET of a name it lacks: the loader reports the two ArduPilot names, sets the rest
    assert run.returncode == 1, run.describe()
    assert "ARSPD_FBW_MIN" in run.stderr and "Q_ENABLE" in run.stderr
    assert run.result["unknown"] == "2" and run.result["verified"] == "1"


@pytest.mark.slow  # a viva-sitl process + MAVSDK
def test_mavsdk_param_plugin_arbitrary_px4_params(sitl: SitlProcess) -> None:
    mavsdk = pytest.importorskip("mavsdk.asyncio", reason="MAVSDK 4.x (pip install mavsdk>=4) not installed")
    from mavsdk.asyncio.plugins.param.param import ParamAsync

    async def scenario() -> None:
        config = mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION)
        async with mavsdk.Mavsdk(config) as drone:
            await drone.add_any_connection(sitl.ports.mavsdk_url)
            system = await drone.first_autopilot(timeout_s=20.0)
            par = ParamAsync(system)
            assert await par.get_param_float("MPC_XY_VEL_P_ACC") == pytest.approx(2.4)
            assert await par.get_param_int("COM_RC_IN_MODE") == 3
            assert await par.get_param_int("SYS_AUTOSTART") == 4001
            # upload_params-style bulk set of PX4 parameters our autopilot only stores
            await par.set_param_float("MPC_XY_VEL_P_ACC", 3.0)
            await par.set_param_int("COM_RC_IN_MODE", 4)
            await par.set_param_int("SYS_AUTOSTART", 4001)
            await par.set_param_float("MC_YAWRATE_P", 0.3)
            assert await par.get_param_float("MPC_XY_VEL_P_ACC") == pytest.approx(3.0)
            assert await par.get_param_int("COM_RC_IN_MODE") == 4
            assert await par.get_param_float("MC_YAWRATE_P") == pytest.approx(0.3)
            everything = await par.get_all_params()
            ints = {p.name: p.value for p in everything.int_params}
            floats = {p.name: p.value for p in everything.float_params}
            assert len(ints) + len(floats) > 1000
            assert ints["COM_RC_IN_MODE"] == 4 and floats["MPC_XY_VEL_P_ACC"] == pytest.approx(3.0)
            assert "_HASH_CHECK" not in ints and "_HASH_CHECK" not in floats

    asyncio.run(asyncio.wait_for(scenario(), 120.0))


@pytest.mark.parametrize(
    ("table", "needle"),
    [
        ("NOT_A_PARAMX = 3", "[params].NOT_A_PARAMX: unknown PX4 parameter"),
        ('MPC_XY_CRUISE = "fast"', "[params].MPC_XY_CRUISE: expected a number"),
        ("NAV_DLL_ACT = 2.5", "[params].NAV_DLL_ACT:"),
        ("MPC_XY_CRUISE = nan", "[params].MPC_XY_CRUISE:"),
    ],
)
def test_config_params_are_checked_at_load(tmp_path: Path, table: str, needle: str) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text(f"[params]\nMIS_TAKEOFF_ALT = 3.0\n{table}\n", encoding="utf-8")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "viva_sitl",
            "run",
            "--no-video",
            "--config",
            str(cfg),
            "--listen",
            "127.0.0.1",
        ],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr  # one line, no traceback
    assert lines[0].startswith("viva-sitl: ") and needle in lines[0] and str(cfg) in lines[0]


@pytest.mark.slow  # viva-sitl processes
def test_config_params_apply_at_start_and_mav_sys_id_follows_the_instance(
    sitl_factory: Callable[..., SitlProcess], peer_factory: Callable[[int], MavlinkPeer], tmp_path: Path
) -> None:
    cfg = tmp_path / "params.toml"
    cfg.write_text("[params]\nMC_ROLL_P = 7.0\nCOM_RC_IN_MODE = 2\nMPC_XY_CRUISE = 25.0\n", encoding="utf-8")
    sitl = sitl_factory(instance=1, extra_args=["--config", str(cfg)])
    peer = peer_factory(sitl.ports.gcs)
    hb = peer.wait_autopilot()
    assert hb.get_srcSystem() == 2
    target = (2, 1)
    assert peer.get_param("MC_ROLL_P", target=target) == pytest.approx(7.0)
    # above PX4's documented max (20): stored and reported as set, with one warning at start-up
    assert peer.get_param("MPC_XY_CRUISE", target=target) == pytest.approx(25.0)
    assert "MPC_XY_CRUISE = 25 is outside PX4's range [3, 20]" in sitl.stderr_text()
    raw = peer.get_param("COM_RC_IN_MODE", target=target)
    assert struct.unpack("<i", struct.pack("<f", raw))[0] == 2
    raw = peer.get_param("MAV_SYS_ID", target=target)
    assert struct.unpack("<i", struct.pack("<f", raw))[0] == 2  # as PX4 SITL -i 1
