"""Bit-identity check of the vehicle loop (autopilot + EAV physics) between two source trees.

    python bench/check_vehicle_identical.py --base /tmp/apbase [--new .]
    python bench/check_vehicle_identical.py --record out.npz          # record with the viva_sitl on PYTHONPATH

Each tree records, in its own process (PYTHONPATH = that tree), full per-step trajectories of a set of scenarios
covering the loop's code paths: ground start take-off + hold + land + auto-disarm, air start hold, offboard velocity /
position / attitude / body-rate streams (the Autopilot API the MAVLink endpoint calls), NaN setpoints (their
refusals), a mission with waypoints, loiter, speed change and RTL, offboard loss, the uploaded geofence, the footage
fence, wind + gusts + force noise, manual control in Position / Altitude / Stabilized, orbit, reposition, parameter
changes in flight and the ideal (paper) attitude. Recorded every step: position, previous position, attitude,
thrust, gust, landed, touchdown speed, time, the EAV command, mode, armed, landed state, battery, events. The two
recordings must be byte-equal (float arrays compared as bytes, so NaN and -0.0 count too).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def _scenarios() -> dict[str, Callable[[], dict[str, Any]]]:
    from viva_sitl.autopilot.geofence import CircleFence, Geofence
    from viva_sitl.autopilot.types import (
        AttitudeTarget,
        FlightMode,
        ManualInput,
        MissionCommand,
        MissionItem,
        OffboardFrame,
        PositionTarget,
    )
    from viva_sitl.config import SimConfig
    from viva_sitl.dynamics import EavParams, WindParams
    from viva_sitl.dynamics.rotation import quat_from_euler
    from viva_sitl.vehicle import Vehicle

    class Rec:
        def __init__(self, v: Vehicle) -> None:
            self.v = v
            self.rows: list[list[float]] = []
            self.cmds: list[tuple[float, float, float, float]] = []
            self.events: list[str] = []
            self.outcomes: list[str] = []
            ap_update = v.autopilot.update

            def update(now_s: float, state: Any) -> Any:
                cmd = ap_update(now_s, state)
                self.cmds.append((cmd.roll_rad, cmd.pitch_rad, cmd.yaw_rad, cmd.thrust_n))
                return cmd

            v.autopilot.update = update  # type: ignore[method-assign]

        def out(self, outcome: Any) -> None:
            self.outcomes.append(f"{int(outcome.result)}:{outcome.reason}")

        def step(self, n: int = 1, chunk: int = 1) -> None:
            v = self.v
            for _ in range(n // chunk):
                s = v.step(chunk)
                ap = v.autopilot
                td = s.touchdown_speed_m_s
                self.rows.append(
                    [*s.pos_ned_m, *s.prev_pos_ned_m, *s.att_rpy_rad, s.thrust_n, *s.gust_ned_m_s,
                     float(s.landed), math.nan if td is None else td, s.time_s, float(s.step),
                     float(ap.mode.custom_mode), float(ap.armed), float(ap.landed_state),
                     ap.battery_remaining, float(ap.mission_current_seq), ap.ctx.yaw_sp,
                     *ap.ctx.ctrl.vel_int_m_s2, *ap.ctx.ctrl.last_vel_sp_ned_m_s]
                )  # fmt: skip
                for e in ap.pop_events():
                    self.events.append(f"{e.time_s!r}|{int(e.severity)}|{e.text}|{e.mission_item_reached}")

        def result(self) -> dict[str, Any]:
            return {
                "rows": np.array(self.rows, dtype=np.float64),
                "cmds": np.array(self.cmds, dtype=np.float64),
                "events": json.dumps(self.events),
                "outcomes": json.dumps(self.outcomes),
                "types": json.dumps([type(x).__name__ for x in vars(self.v.state).values()]),
            }

    def vel_target(v: tuple[float, float, float], yaw: float | None = None, rate: float | None = None,
                   frame: OffboardFrame = OffboardFrame.LOCAL_NED) -> PositionTarget:  # fmt: skip
        return PositionTarget(vel_ned_m_s=v, yaw_rad=yaw, yaw_rate_rad_s=rate, frame=frame)

    def ground_takeoff_land() -> dict[str, Any]:
        with Vehicle(SimConfig(), geofence=False) as v:
            v.reset(seed=1, pos_ned_m=(0.0, 0.0, 0.0), yaw_rad=0.3)
            r = Rec(v)
            r.step(50)
            r.out(v.autopilot.arm(v.time_s))
            r.out(v.autopilot.takeoff(v.time_s, 6.0))
            r.step(250 * 8)
            r.out(v.autopilot.land(v.time_s))
            r.step(250 * 14)
            r.out(v.autopilot.arm(v.time_s))
            r.out(v.autopilot.set_mode(v.time_s, FlightMode.AUTO_TAKEOFF))
            r.step(250 * 3, chunk=25)
            r.out(v.autopilot.kill(v.time_s))
            r.step(250 * 4)
            return r.result()

    def air_hold() -> dict[str, Any]:
        with Vehicle(SimConfig(), geofence=False) as v:
            v.reset(seed=2, pos_ned_m=(3.0, -2.0, -20.0), yaw_rad=-2.0, vel_ned_m_s=(1.0, 0.5, -0.3))
            r = Rec(v)
            r.step(250 * 6)
            r.out(v.autopilot.reposition(v.time_s, 10.0, 5.0, -15.0, 1.0, speed_m_s=3.0))
            r.step(250 * 8)
            r.step(250 * 4, chunk=250)
            v.params.set("NAV_DLL_ACT", 2)  # ground-station link lost -> Return
            for _ in range(20):
                v.autopilot.gcs_heartbeat(v.time_s)
                r.step(250)
            r.step(250 * 10)
            return r.result()

    def offboard() -> dict[str, Any]:
        with Vehicle(SimConfig(), geofence=False) as v:
            v.reset(seed=3, pos_ned_m=(0.0, 0.0, -10.0), yaw_rad=0.0)
            r = Rec(v)
            ap = v.autopilot
            r.out(ap.set_position_target(v.time_s, vel_target((0.0, 0.0, 0.0))))
            r.out(ap.set_mode(v.time_s, FlightMode.OFFBOARD))
            targets = [
                vel_target((3.0, 1.0, 0.0), yaw=0.5),
                vel_target((-2.0, 4.0, -1.0), rate=0.4),
                vel_target((1.5, 0.0, 0.5), frame=OffboardFrame.BODY_NED),
                PositionTarget(pos_ned_m=(5.0, -3.0, -12.0), yaw_rad=-1.0),
                PositionTarget(pos_ned_m=(5.0, -3.0, -12.0), vel_ned_m_s=(0.5, 0.0, 0.0)),
                PositionTarget(acc_ned_m_s2=(0.5, -0.5, 0.0)),
                PositionTarget(pos_ned_m=(math.nan, 1.0, -10.0)),  # NaN: rejected
                PositionTarget(vel_ned_m_s=(math.inf, 0.0, 0.0)),  # inf: rejected
            ]
            for i, tgt in enumerate(targets):
                for _ in range(40):  # 20 Hz for 2 s
                    r.out(ap.set_position_target(v.time_s, tgt))
                    r.step(12 + (i % 2))
            for q_rpy, rates, thr in [
                ((0.1, -0.1, 0.2), None, 0.55),
                (None, (0.2, 0.0, 0.3), 0.5),
                ((math.nan, 0.0, 0.0), None, 0.5),  # NaN: rejected
            ]:
                q = None if q_rpy is None else quat_from_euler(*q_rpy)
                for _ in range(30):
                    r.out(ap.set_attitude_target(v.time_s, AttitudeTarget(q, rates, thr)))
                    r.step(12)
            r.out(ap.set_position_target(v.time_s, PositionTarget(pos_ned_m=(0.0, 0.0, -10.0))))
            r.step(250 * 3)  # stream lost: COM_OF_LOSS_T failsafe -> Hold
            return r.result()

    def mission_rtl() -> dict[str, Any]:
        with Vehicle(SimConfig(), geofence=False) as v:
            v.reset(seed=4, pos_ned_m=(0.0, 0.0, 0.0))
            r = Rec(v)
            ap = v.autopilot
            c = MissionCommand

            def item(seq: int, cmd: MissionCommand, n: float, e: float, d: float, **kw: Any) -> MissionItem:
                return MissionItem(
                    seq=seq, command=cmd, north_m=n, east_m=e, down_m=d, raw_command=int(cmd), **kw
                )

            items = [
                item(0, c.NAV_TAKEOFF, 0.0, 0.0, -8.0),
                item(1, c.NAV_WAYPOINT, 15.0, 0.0, -8.0, param4=90.0),
                item(2, c.DO_CHANGE_SPEED, 0.0, 0.0, 0.0, param1=1.0, param2=3.0),
                item(3, c.NAV_WAYPOINT, 15.0, 12.0, -12.0, param1=1.0),
                item(4, c.NAV_LOITER_TIME, 0.0, 12.0, -10.0, param1=2.0),
                item(5, c.DO_SET_CAM_TRIGG_DIST, 0.0, 0.0, 0.0, param1=4.0),
                item(6, c.NAV_WAYPOINT, -5.0, 5.0, -10.0),
                item(7, c.NAV_RETURN_TO_LAUNCH, 0.0, 0.0, 0.0),
            ]
            r.out(ap.set_mission(items))
            r.out(ap.set_mode(v.time_s, FlightMode.AUTO_MISSION))
            r.out(ap.arm(v.time_s))
            r.out(ap.mission_start(v.time_s))
            r.step(250 * 70, chunk=5)
            r.out(ap.arm(v.time_s))
            r.out(ap.takeoff(v.time_s, 5.0))
            r.step(250 * 6, chunk=5)
            r.out(ap.return_to_launch(v.time_s))
            r.step(250 * 25, chunk=5)
            return r.result()

    def fences() -> dict[str, Any]:
        out: dict[str, Any] = {}
        with Vehicle(SimConfig(), geofence=False) as v:
            v.params.set("GF_ACTION", 3)
            v.reset(seed=5, pos_ned_m=(0.0, 0.0, -10.0))
            r = Rec(v)
            ap = v.autopilot
            r.out(ap.set_geofence(Geofence(circles=(CircleFence((0.0, 0.0), 12.0),))))
            r.out(ap.reposition(v.time_s, 30.0, 0.0, -10.0, None))
            r.step(250 * 20, chunk=2)
            out.update({f"gf_{k}": x for k, x in r.result().items()})
        with Vehicle(SimConfig(), geofence=lambda n, e: n < 8.0) as v:
            v.reset(seed=6, pos_ned_m=(0.0, 0.0, -10.0))
            r = Rec(v)
            for action in (2, 5):  # Hold at the last point inside, then Land
                v.params.set("SIM_FTG_FENCE", 0)
                r.out(v.autopilot.reposition(v.time_s, 20.0, 2.0, -10.0, None))
                v.params.set("SIM_FTG_FENCE", action)
                r.step(250 * 12, chunk=2)
            out.update({f"ftg_{k}": x for k, x in r.result().items()})
        return out

    def wind_gusts() -> dict[str, Any]:
        gusty = EavParams(
            wind=WindParams(mean_wind_ned_m_s=(2.0, -1.0, 0.2), gust_std_m_s=0.8, force_noise_std_n=0.05)
        )
        with Vehicle(SimConfig(physics=gusty), geofence=False) as v:
            v.reset(seed=7, pos_ned_m=(0.0, 0.0, 0.0))
            r = Rec(v)
            r.out(v.autopilot.arm(v.time_s))
            r.out(v.autopilot.takeoff(v.time_s, 4.0))
            r.step(250 * 8)
            v.params.set("SIM_GUST_STD", 1.5)
            v.params.set("SIM_MASS", 0.6)
            v.params.set("MPC_XY_CRUISE", 7.0)
            r.out(v.autopilot.reposition(v.time_s, 10.0, 10.0, -6.0, 0.7))
            r.step(250 * 8)
            v.params.set("SIM_ATT_TAU", 0.0)  # instant tilt, rate-limited; unlimited yaw rate
            v.params.set("SIM_YAW_RATE_MAX", 0.0)
            r.out(v.autopilot.reposition(v.time_s, -5.0, 0.0, -8.0, -2.0))
            r.step(250 * 5)
            r.out(v.autopilot.land(v.time_s))
            r.step(250 * 10)
            return r.result()

    def manual() -> dict[str, Any]:
        with Vehicle(SimConfig(), geofence=False) as v:
            v.reset(seed=8, pos_ned_m=(0.0, 0.0, -8.0))
            r = Rec(v)
            ap = v.autopilot
            sticks = [ManualInput(0.5, 0.0, 0.5, 0.0), ManualInput(0.0, -0.7, 0.7, 0.3),
                      ManualInput(0.0, 0.0, 0.5, 0.0), ManualInput(-0.3, 0.4, 0.3, -0.5),
                      ManualInput(math.nan, 0.0, 0.5, 0.0)]  # fmt: skip
            r.out(ap.set_manual_input(v.time_s, sticks[0]))
            for mode in (FlightMode.POSCTL, FlightMode.ALTCTL, FlightMode.STABILIZED, FlightMode.POSCTL):
                r.out(ap.set_manual_input(v.time_s, sticks[0]))
                r.out(ap.set_mode(v.time_s, mode))
                for st in sticks:
                    for _ in range(25):  # 50 Hz for 0.5 s
                        r.out(ap.set_manual_input(v.time_s, st))
                        r.step(5)
            r.step(250 * 3)  # RC lost
            return r.result()

    def orbit_paper() -> dict[str, Any]:
        out: dict[str, Any] = {}
        with Vehicle(SimConfig(), geofence=False) as v:
            v.reset(seed=9, pos_ned_m=(0.0, 0.0, -15.0))
            r = Rec(v)
            r.out(v.autopilot.orbit(v.time_s, 8.0, 2.0, 0.0, (5.0, 0.0), None))
            r.step(250 * 15)
            out.update({f"orbit_{k}": x for k, x in r.result().items()})
        paper = EavParams(dt_s=1.0 / 250.0).with_ideal_attitude()
        with Vehicle(SimConfig(physics=paper), geofence=False) as v:
            v.reset(seed=10, pos_ned_m=(0.0, 0.0, -15.0), yaw_rad=3.0)
            r = Rec(v)
            r.out(v.autopilot.reposition(v.time_s, -8.0, 6.0, -20.0, -3.0))
            r.step(250 * 10)
            r.out(v.autopilot.land(v.time_s))
            r.step(250 * 20, chunk=10)
            out.update({f"paper_{k}": x for k, x in r.result().items()})
        return out

    return {
        "ground_takeoff_land": ground_takeoff_land,
        "air_hold": air_hold,
        "offboard": offboard,
        "mission_rtl": mission_rtl,
        "fences": fences,
        "wind_gusts": wind_gusts,
        "manual": manual,
        "orbit_paper": orbit_paper,
    }


def _trial_files(footage: Path) -> dict[str, Any]:
    """An in-process 60 s landing trial over `footage` (bench_trials' VisionDescend pilot, which reads every VAC
    frame): its trajectory CSV, events and end record, as written, byte for byte."""
    repo = Path(os.environ["PYTHONPATH"].split(os.pathsep)[0])
    sys.path.insert(0, str(repo))
    from bench.bench_trials import bench_spec
    from viva_sitl.evaluation.runner import run_inprocess_trial
    from viva_sitl.evaluation.spec import draw_scenarios

    spec = bench_spec(footage, 2)
    with tempfile.TemporaryDirectory() as d:
        run_inprocess_trial(spec, draw_scenarios(spec)[1], "bench.bench_trials:VisionDescend", Path(d) / "t")
        files = sorted(p for p in Path(d, "t").rglob("*") if p.is_file())
        return {f"trial/{p.name}": np.frombuffer(p.read_bytes(), dtype=np.uint8) for p in files}


def record(path: Path, trial_footage: Path | None = None) -> None:
    arrays: dict[str, Any] = {}
    for name, fn in _scenarios().items():
        for key, value in fn().items():
            arrays[f"{name}/{key}"] = np.asarray(value)
    if trial_footage is not None:
        arrays.update(_trial_files(trial_footage))
    np.savez(path, **arrays)


def _digest(a: np.ndarray) -> str:
    return hashlib.sha256(a.dtype.str.encode() + str(a.shape).encode() + a.tobytes()).hexdigest()[:16]


def compare(a_path: Path, b_path: Path) -> int:
    a, b = np.load(a_path), np.load(b_path)
    bad = 0
    for key in sorted(set(a.files) | set(b.files)):
        if key not in a.files or key not in b.files:
            print(f"MISSING {key}")
            bad += 1
            continue
        x, y = a[key], b[key]
        same = _digest(x) == _digest(y)
        info = f"shape {x.shape}" if x.dtype.kind in "fu" else f"{x.dtype}"
        print(f"{'same' if same else 'DIFF':4s}  {key:32s} {info:16s} {_digest(x)} {_digest(y)}")
        if not same:
            bad += 1
            if x.dtype.kind == "f" and x.shape == y.shape:
                rows = np.nonzero(np.any(x.view(np.uint64) != y.view(np.uint64), axis=-1))[0]
                print(
                    f"      first differing row {rows[0]} of {len(x)}; max |diff| {np.nanmax(np.abs(x - y)):.3g}"
                )
    n = len(set(a.files) | set(b.files))
    print(f"{n - bad}/{n} recordings byte-identical")
    return 1 if bad else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--record", type=Path, help="record with the viva_sitl on PYTHONPATH into this .npz")
    ap.add_argument("--base", type=Path, help="the reference tree (e.g. a git worktree at the base commit)")
    ap.add_argument(
        "--new", type=Path, default=Path(__file__).resolve().parents[1], help="the tree under test"
    )
    ap.add_argument("--trial-footage", type=Path, help="also compare an in-process landing trial's files over this "
                    "footage (e.g. /tmp/viva-sitl-bench/interchange_3840x2160_60f_tiles_jpeg)")  # fmt: skip
    args = ap.parse_args()
    for tree in (args.base, args.new):
        if tree is not None and not (tree / "viva_sitl" / "__init__.py").is_file():
            ap.error(f"{tree} is not a viva-sitl source tree (no viva_sitl/__init__.py)")
    if args.record:
        record(args.record, args.trial_footage)
        return 0
    if args.base is None:
        ap.error("--base or --record is required")
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for label, tree in (("base", args.base), ("new", args.new)):
            out = Path(tmp) / f"{label}.npz"
            env = {**os.environ, "PYTHONPATH": str(tree.resolve())}
            cmd = [sys.executable, __file__, "--record", str(out)]
            if args.trial_footage is not None:
                cmd += ["--trial-footage", str(args.trial_footage.resolve())]
            subprocess.run(cmd, env=env, check=True)
            paths.append(out)
        return compare(paths[0], paths[1])


if __name__ == "__main__":
    sys.exit(main())
