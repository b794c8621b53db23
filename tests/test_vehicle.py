"""The one vehicle loop (viva_sitl.vehicle.Vehicle): simulator + parameters + autopilot, stepped by the caller."""

from __future__ import annotations

import numpy as np
import pytest

from viva_sitl.autopilot import FlightMode, ParamStore
from viva_sitl.config import ConfigError, SimConfig
from viva_sitl.dynamics import EavParams, WindParams
from viva_sitl.vehicle import Vehicle


def _fly(v: Vehicle, seconds: float) -> list[tuple[float, float, float]]:
    out = []
    for _ in range(int(round(seconds / v.dt_s))):
        s = v.step(1)
        out.append((float(s.pos_ned_m[0]), float(s.pos_ned_m[1]), float(s.pos_ned_m[2])))
    return out


def test_arm_before_the_first_step_then_take_off_in_sim_time() -> None:
    with Vehicle(SimConfig(), geofence=False) as v:
        assert v.autopilot.arm(v.time_s).ok  # the autopilot has seen the initial state
        assert v.autopilot.takeoff(v.time_s, 4.0).ok
        state = v.step(int(round(12.0 / v.dt_s)))
        assert state.time_s == pytest.approx(12.0)
        assert v.steps == int(round(12.0 / v.dt_s))
        assert v.autopilot.mode == FlightMode.AUTO_LOITER
        assert state.altitude_m == pytest.approx(4.0, abs=0.3)
        frame = v.render()
        assert frame.meta.pos_ned_m == pytest.approx(tuple(state.pos_ned_m))
        assert frame.image_bgr.shape == (v.config.camera.height_px, v.config.camera.width_px, 3)


def test_sim_param_reaches_the_physics_on_the_next_step() -> None:
    with Vehicle(SimConfig(), geofence=False) as v:
        v.step(1)
        v.params.set("SIM_MASS", 1.3)
        assert v.sim.params.mass_kg != pytest.approx(1.3)
        v.step(1)
        assert v.sim.params.mass_kg == pytest.approx(1.3)
        assert v.sim.params is v.autopilot.eav_params()


def test_reset_reboots_the_autopilot_keeps_parameters_and_is_deterministic() -> None:
    gusty = EavParams(wind=WindParams(mean_wind_ned_m_s=(1.0, 0.0, 0.0), gust_std_m_s=0.5))
    store = ParamStore()
    store.set("MIS_TAKEOFF_ALT", 3.0)
    with Vehicle(SimConfig(physics=gusty), geofence=False, params=store) as v:
        runs = []
        for _ in range(2):
            v.reset(seed=7, pos_ned_m=(2.0, -1.0, 0.0), yaw_rad=0.5)
            assert not v.autopilot.armed and v.time_s == 0.0
            assert v.autopilot.home_ned_m == pytest.approx((2.0, -1.0, 0.0))
            assert v.autopilot.arm(v.time_s).ok and v.autopilot.takeoff(v.time_s).ok
            runs.append(_fly(v, 8.0))
        assert runs[0] == runs[1]  # same seed, same flight (gusts included)
        assert -runs[0][-1][2] == pytest.approx(3.0, abs=0.4)  # the parameter survived the reset
        v.reset(seed=8, pos_ned_m=(2.0, -1.0, 0.0), yaw_rad=0.5)
        assert v.autopilot.arm(v.time_s).ok and v.autopilot.takeoff(v.time_s).ok
        assert _fly(v, 8.0) != runs[0]  # another seed, other gusts


def test_air_start_and_custom_geofence() -> None:
    with Vehicle(SimConfig(), geofence=lambda n, e: n < 5.0) as v:
        v.reset(pos_ned_m=(0.0, 0.0, -10.0))
        assert v.autopilot.armed and v.autopilot.mode == FlightMode.AUTO_LOITER
        v.step(int(round(2.0 / v.dt_s)))
        assert np.asarray(v.state.pos_ned_m) == pytest.approx([0.0, 0.0, -10.0], abs=0.1)
        assert v.autopilot.reposition(v.time_s, 10.0, 0.0, -10.0, None).reason == (
            "Reposition denied: target outside footage"
        )


def test_heavier_airframe_from_config_hovers_and_an_unliftable_one_is_refused() -> None:
    cfg = SimConfig.from_dict({"physics": {"mass_kg": 2.0}})
    assert cfg.physics.max_thrust_n == pytest.approx(
        2.0 * cfg.physics.hover_thrust_n
    )  # thrust follows the mass
    with Vehicle(cfg, geofence=False) as v:
        assert v.autopilot.arm(v.time_s).ok and v.autopilot.takeoff(v.time_s, 5.0).ok
        v.step(int(round(15.0 / v.dt_s)))
        assert v.autopilot.mode == FlightMode.AUTO_LOITER
        assert v.state.altitude_m == pytest.approx(5.0, abs=0.3)
        v.step(int(round(3.0 / v.dt_s)))
        assert v.state.altitude_m == pytest.approx(5.0, abs=0.3)
    with pytest.raises(ConfigError) as err:
        SimConfig.from_dict({"physics": {"mass_kg": 2.0, "max_thrust_n": 9.0}})
    assert "cannot lift" in str(err.value) and "\n" not in str(err.value)
