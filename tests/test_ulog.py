"""The ULog writer (viva_sitl/ulog.py) and the PX4 topics of a flight (viva_sitl/flightlog.py), read back with pyulog,
PX4's own reader: the files parse, the topics and fields carry PX4's names, timestamps are monotonic and the
values are those of the simulated flight."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from viva_sitl.autopilot import FlightMode
from viva_sitl.config import SimConfig
from viva_sitl.flightlog import NAV_STATE, FlightLog
from viva_sitl.ulog import Topic, ULogFile, ULogWriter
from viva_sitl.vehicle import Vehicle

pyulog = pytest.importorskip("pyulog")

PX4_TOPICS = {
    "vehicle_local_position",
    "vehicle_global_position",
    "vehicle_attitude",
    "vehicle_status",
    "battery_status",
    "trajectory_setpoint",
    "failsafe_flags",
}


def test_ulog_file_round_trips_through_pyulog(tmp_path: Path) -> None:
    att = Topic("vehicle_attitude", (("float[4]", "q"), ("uint8_t", "quat_reset_counter")))
    pos = Topic("vehicle_local_position", (("float", "x"), ("double", "ref_lat"), ("bool", "xy_valid")))
    path = tmp_path / "a.ulg"
    with ULogFile(path, [att, pos], info={"sys_name": "viva-sitl", "ver_sw_release": 7},
                  params={"MIS_TAKEOFF_ALT": 2.5, "NAV_DLL_ACT": 2}, start_us=1000) as f:  # fmt: skip
        for i in range(10):
            f.write(att, 1000 + i * 100, ((1.0, 0.0, 0.0, float(i)), i))
            f.write(pos, 1000 + i * 100, (0.5 * i, 47.25, i % 2 == 0))
        f.log_text(4, 1500, "Low battery")
    u = pyulog.ULog(str(path))
    assert u.start_timestamp == 1000
    assert u.msg_info_dict["sys_name"] == "viva-sitl" and u.msg_info_dict["ver_sw_release"] == 7
    assert u.initial_parameters == {"MIS_TAKEOFF_ALT": 2.5, "NAV_DLL_ACT": 2}
    a = u.get_dataset("vehicle_attitude").data
    assert list(a["timestamp"]) == [1000 + i * 100 for i in range(10)]
    assert list(a["q[3]"]) == [float(i) for i in range(10)] and list(a["quat_reset_counter"]) == list(
        range(10)
    )
    p = u.get_dataset("vehicle_local_position").data
    assert p["x"][4] == pytest.approx(2.0) and p["ref_lat"][0] == 47.25 and list(p["xy_valid"][:2]) == [1, 0]
    # PX4 stores the level as the ASCII digit: pyulog names it
    assert [(m.log_level_str(), m.message) for m in u.logged_messages] == [("WARNING", "Low battery")]


def test_bad_topic_definitions_and_samples_are_refused() -> None:
    with pytest.raises(ValueError, match="not a ULog field type"):
        Topic("t", (("float32", "x"),))
    with pytest.raises(ValueError, match="implicit"):
        Topic("t", (("uint64_t", "timestamp"),))
    t = Topic("t", (("float[3]", "v"),))
    with pytest.raises(ValueError, match="array of 3"):
        t.pack(0, ((1.0, 2.0),))


def test_writer_thread_writes_everything_queued_before_close(tmp_path: Path) -> None:
    t = Topic("battery_status", (("float", "remaining"),))
    w = ULogWriter(tmp_path / "b.ulg", [t], max_queue=100000)
    for i in range(5000):
        assert w.log(t, i, (i / 5000.0,))
    w.close()
    assert w.dropped == 0 and w.samples == 5000 and not w.log(t, 9999, (0.0,))  # closed: refused
    d = pyulog.ULog(str(w.path)).get_dataset("battery_status").data
    assert len(d["timestamp"]) == 5000 and d["remaining"][-1] == pytest.approx(4999 / 5000.0)


def test_flight_log_of_a_takeoff_matches_the_simulated_states(tmp_path: Path) -> None:
    with Vehicle(SimConfig(), geofence=False) as v:
        flog = FlightLog(tmp_path / "log.ulg", v.geo, v.params, start_time_s=v.time_s)
        states: dict[int, tuple[float, float, float]] = {}
        assert v.autopilot.arm(v.time_s).ok and v.autopilot.takeoff(v.time_s, 4.0).ok
        for _ in range(int(round(8.0 / v.dt_s))):
            s = v.step(1)
            flog.step(s, v.autopilot)
            states[int(round(s.time_s * 1e6))] = (
                float(s.pos_ned_m[0]),
                float(s.pos_ned_m[1]),
                float(s.pos_ned_m[2]),
            )
        flog.step(s, v.autopilot)  # the same time again: skipped, one file keeps one clock
        lat, lon, alt = v.geo.ned_to_global(*(float(c) for c in s.pos_ned_m))
        flog.camera_capture(3, s.time_s, lat, lon, alt, 4.0, (1.0, 0.0, 0.0, 0.0), True)
        flog.text(4, s.time_s, "Low battery")
        assert flog.skipped_steps == 1
        flog.close()
    u = pyulog.ULog(str(tmp_path / "log.ulg"))
    names = {d.name for d in u.data_list}
    assert names >= PX4_TOPICS, names
    for d in u.data_list:
        ts = d.data["timestamp"]
        assert np.all(np.diff(ts.astype(np.int64)) > 0), f"{d.name}: timestamps not increasing"
    lp = u.get_dataset("vehicle_local_position").data
    assert 350 <= len(lp["timestamp"]) <= 410  # 50 Hz over 8 s
    for i in range(0, len(lp["timestamp"]), 37):
        x, y, z = states[int(lp["timestamp"][i])]
        assert (lp["x"][i], lp["y"][i], lp["z"][i]) == pytest.approx((x, y, z), abs=1e-4)
    assert lp["z"][-1] == pytest.approx(-4.0, abs=0.4)
    status = u.get_dataset("vehicle_status").data
    assert status["arming_state"][-1] == 2
    assert NAV_STATE[FlightMode.AUTO_TAKEOFF] in set(status["nav_state"])
    assert status["nav_state"][-1] == NAV_STATE[FlightMode.AUTO_LOITER]
    gp = u.get_dataset("vehicle_global_position").data
    assert gp["lat"][0] == pytest.approx(v.geo.lat_deg, abs=1e-6)
    assert gp["alt"][-1] == pytest.approx(v.geo.alt_amsl_m + 4.0, abs=0.5)
    q = u.get_dataset("vehicle_attitude").data
    norms = np.sqrt(sum(q[f"q[{i}]"] ** 2 for i in range(4)))
    assert np.allclose(norms, 1.0, atol=1e-5)
    bat = u.get_dataset("battery_status").data
    assert 0.0 < bat["remaining"][-1] <= 1.0 and bat["voltage_v"][-1] > 0
    sp = u.get_dataset("trajectory_setpoint").data
    assert math.isnan(sp["position[0]"][-1]) and np.isfinite(sp["velocity[2]"][-1])
    assert u.initial_parameters["MIS_TAKEOFF_ALT"] == pytest.approx(v.params.get("MIS_TAKEOFF_ALT"))
    cap = u.get_dataset("camera_capture").data
    assert list(cap["seq"]) == [3] and list(cap["result"]) == [1] and cap["lat"][0] == pytest.approx(lat)
    assert cap["timestamp"][0] >= lp["timestamp"][-1]  # never before the last logged step
    assert [m.message for m in u.logged_messages] == ["Low battery"]
