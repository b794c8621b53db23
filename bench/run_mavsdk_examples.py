"""Run the official MAVSDK-Python examples, unchanged, against `viva-sitl run` and tabulate pass / fail.

    python bench/run_mavsdk_examples.py --examples /tmp/mavsdk-examples/examples --python /tmp/mavsdk3/bin/python
    python bench/run_mavsdk_examples.py ... --only goto do_orbit --out bench/results_mavsdk_examples.md

The examples (mavlink/MAVSDK-Python `examples/`, classic gRPC API) are not part of this repository: fetch them and
give their directory; `--python` is a virtual environment with `pip install 'mavsdk==3.*' anyio tqdm` (mavsdk ships
mavsdk_server). Each example gets a fresh `viva-sitl run` (synthetic field, PX4's default home, the default
airframe, video on) on PX4's default API port 14540, so the example's own connection string works; when 14540 is
taken, `--instance N` moves viva-sitl to 14540+N and the example runs from a temporary copy whose connection
string alone is rewritten (reported in the notes). A passive pymavlink observer on the ground-station port records
what the vehicle did, so "pass" means the example exited as its author intended AND the vehicle did what the
example asked (reached the goto target, orbited at the radius, landed, ...), not only that nothing raised.
Examples that loop forever (goto, telemetry) pass when the vehicle / output shows the expected behaviour; the
script then ends them.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from sitl_process import MavlinkPeer, SitlPorts, SitlProcess, free_tcp_port, free_udp_ports  # noqa: E402

PX4_API_PORT = 14540
HOME_LAT, HOME_LON = 47.397742, 8.545594  # PX4's default home (viva-sitl's default for the synthetic field)
EARTH_R_M = 6_371_000.0


def ground_dist_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Equirectangular distance; exact enough over a few hundred metres."""
    dn = math.radians(lat2 - lat1) * EARTH_R_M
    de = math.radians(lon2 - lon1) * EARTH_R_M * math.cos(math.radians(lat1))
    return math.hypot(dn, de)


def positions(obs: MavlinkPeer) -> list[tuple[float, float, float]]:
    """(lat, lon, relative alt m) from GLOBAL_POSITION_INT."""
    return [(m.lat / 1e7, m.lon / 1e7, m.relative_alt / 1000.0) for m in obs.messages("GLOBAL_POSITION_INT")]


def max_rel_alt_m(obs: MavlinkPeer) -> float:
    return max((p[2] for p in positions(obs)), default=float("nan"))


def landed(obs: MavlinkPeer) -> bool:
    """On the ground at the end: EXTENDED_SYS_STATE says ON_GROUND (the example may exit before the auto-disarm)."""
    ext = obs.latest("EXTENDED_SYS_STATE", component=1)
    pos = positions(obs)
    return ext is not None and ext.landed_state == 1 and bool(pos) and pos[-1][2] < 0.5


def statustexts(obs: MavlinkPeer) -> list[str]:
    return [m.text for m in obs.messages("STATUSTEXT")]


Check = Callable[[MavlinkPeer, str], tuple[bool, str]]


def flew_and_landed(min_alt_m: float) -> Check:
    def check(obs: MavlinkPeer, out: str) -> tuple[bool, str]:
        peak = max_rel_alt_m(obs)
        ok = peak >= min_alt_m and landed(obs)
        return ok, f"peak {peak:.1f} m, {'landed' if landed(obs) else 'NOT landed'}"

    return check


def flew(min_alt_m: float) -> Check:
    def check(obs: MavlinkPeer, out: str) -> tuple[bool, str]:
        peak = max_rel_alt_m(obs)
        return peak >= min_alt_m, f"peak {peak:.1f} m"

    return check


def reached(lat: float, lon: float, rel_alt_m: float, tol_m: float = 3.0) -> Check:
    def check(obs: MavlinkPeer, out: str) -> tuple[bool, str]:
        best = min(
            (ground_dist_m(lat, lon, p[0], p[1]) + abs(p[2] - rel_alt_m) for p in positions(obs)),
            default=math.inf,
        )
        return best <= tol_m, f"closest approach to target {best:.1f} m (horizontal + vertical)"

    return check


def orbited(lat: float, lon: float, radius_m: float) -> Check:
    def check(obs: MavlinkPeer, out: str) -> tuple[bool, str]:
        status = obs.messages("ORBIT_EXECUTION_STATUS")
        dists = [ground_dist_m(lat, lon, p[0], p[1]) for p in positions(obs)]
        near = [d for d in dists if abs(d - radius_m) < 1.5]
        # A quarter of the samples at the radius: the orbit itself (60 s of the example's ~80 s in the air).
        ok = bool(status) and len(near) > len(dists) / 4
        return (
            ok,
            f"{len(status)} ORBIT_EXECUTION_STATUS, {len(near)}/{len(dists)} positions at {radius_m:g}+-1.5 m",
        )

    return check


def no_check(obs: MavlinkPeer, out: str) -> tuple[bool, str]:
    return True, ""


@dataclass
class Example:
    name: str  # file stem in the examples directory
    expect: str  # what a pass looks like, in words
    must_print: tuple[str, ...] = ()  # regexes the example's output must contain
    check: Check = no_check  # what the vehicle must have done (observer)
    args: tuple[str, ...] = ()  # {url} is replaced by the example's connection string
    timeout_s: float = 120.0
    runs_forever: bool = False  # the example never exits: pass when `done` holds, then it is ended
    done: Check | None = None  # for runs_forever: condition to end it early
    px4: str = "passes"  # what PX4 SITL does (from its documented behaviour)
    kind: str = "flight"
    # viva-sitl's config for this example (TOML text, passed as `run --config`): the airframe it needs, as PX4 SITL
    # needs gz_x500_gimbal for gimbal.py
    config_toml: str = ""


EXAMPLES: list[Example] = [
    Example("takeoff_and_land", "arms, takes off, lands", ("-- Landing",), flew(2.0)),
    Example(
        "telemetry_takeoff_and_land",
        "arms, takes off, lands; prints in_air / position",
        ("-- Landing",),
        flew(2.0),
    ),
    Example(
        "goto",
        "takes off, flies to 47.397606, 8.543060 at home+20 m (192 m west of home)",
        ("Staying connected",),
        runs_forever=True,
        done=reached(47.397606, 8.543060, 20.0),
    ),
    Example(
        "mission",
        "uploads and flies the mission, RTL, lands",
        (r"Mission progress: (\d+)/\1\b",),
        flew_and_landed(10),
    ),
    Example("mission_raw", "uploads a 2-item raw mission (PX4 default-home coordinates)", ("-- Done",)),
    Example(
        "mission_import",
        "imports example-mission.plan (mission + rally points), uploads both",
        ("Mission uploaded",),
    ),
    Example("geofence", "uploads an inclusion polygon around home", ("Geofence uploaded!",)),
    Example(
        "do_orbit",
        "takes off, orbits 47.398036, 8.545015 at r = 10 m, RTL",
        ("--- Landing",),
        orbited(47.398036222362471, 8.5450146439425509, 10.0),
    ),
    Example("offboard_position_ned", "offboard NED position setpoints", ("-- Stopping offboard",), flew(2.0)),
    Example("offboard_velocity_ned", "offboard NED velocity setpoints", ("-- Stopping offboard",), flew(2.0)),
    Example(
        "offboard_velocity_body", "offboard body velocity setpoints", ("-- Stopping offboard",), flew(2.0)
    ),
    Example("offboard_attitude", "offboard attitude setpoints", ("-- Stopping offboard",), flew(0.5)),
    Example(
        "offboard_position_velocity_ned",
        "offboard position + velocity feed-forward",
        ("-- Stopping offboard",),
        flew(2.0),
    ),
    Example(
        "offboard_from_csv/offboard_from_csv",
        "offboard trajectory from active.csv",
        ("-- Disarming",),
        flew(1.0),
    ),
    Example(
        "manual_control",
        "takes off, random manual inputs in Position mode",
        ("-- Starting manual control",),
        runs_forever=True,
        timeout_s=60,
        done=flew(1.0),
    ),
    Example("follow_me_example", "Follow Me mode with a moving target", ("-- Landing",), flew(1.0)),
    Example("all_params", "lists every parameter", (r"MPC_XY_VEL_MAX|NAV_ACC_RAD|COM_",), kind="params"),
    Example(
        "upload_params",
        "uploads a QGC .params file",
        ("Params uploaded!",),
        args=("{url}", "{params_file}"),
        kind="params",
    ),
    Example("firmware_version", "prints the flight software version", (r"flight_sw_major",), kind="info"),
    Example(
        "telemetry",
        "streams position, battery, flight mode",
        (r"Position", r"Battery:", r"GPS info", r"In air"),
        runs_forever=True,
        timeout_s=30,
        kind="telemetry",
    ),
    Example(
        "telemetry_flight_mode", "prints the flight mode", (r"FlightMode",), runs_forever=True, timeout_s=30
    ),
    Example(
        "telemetry_is_armed_is_in_air",
        "prints armed / in air",
        (r"Is_armed:", r"(?i)in_air"),
        runs_forever=True,
        timeout_s=30,
        kind="telemetry",
    ),
    Example(
        "telemetry_status_text",
        "prints STATUSTEXT",
        ("-- Connected to drone!",),
        runs_forever=True,
        timeout_s=30,
        kind="telemetry",
    ),
    Example("highres_imu", "prints HIGHRES_IMU", (r"X Acceleration",), runs_forever=True, timeout_s=30),
    Example("camera", "camera mode, photo, video", (), kind="camera"),
    Example(
        "gimbal",
        "gimbal control",
        ("Back to horizontal",),
        kind="camera",
        config_toml='[camera]\nmount = "gimbal"\n',
        px4="passes with the gz_x500_gimbal airframe",
    ),  # fmt: skip
    Example("calibration", "sensor calibrations", (), kind="info", px4="passes (SITL: simulated sensors)"),
    Example("send_status_message", "sends a STATUSTEXT from the companion", (), kind="info"),
    Example("shell", "MAVLink shell (nsh)", (), kind="info", runs_forever=True, timeout_s=20),
    Example(
        "logfile_download", "lists / downloads ULog files", (), kind="info", px4="passes (ULog over MAVLink)"
    ),
    Example("failure_injection", "injects a sensor failure (SYS_FAILURE_EN)", (), kind="info"),
    Example("tune", "plays a tune", (), kind="info"),
    Example("ftp_list_dir", "lists a directory over MAVLink FTP (serial connection string)", (), kind="ftp"),
    Example(
        "ftp_download_file", "downloads a file over MAVLink FTP (serial connection string)", (), kind="ftp"
    ),
]

PARAMS_FILE = """# Onboard parameters for Vehicle 1
#
# Vehicle-Id Component-Id Name Value Type
1\t1\tMPC_XY_VEL_MAX\t8.000000000000000000\t9
1\t1\tMIS_TAKEOFF_ALT\t3.000000000000000000\t9
1\t1\tCOM_RC_IN_MODE\t1\t6
"""


def port_free_udp(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return False
    return True


@dataclass
class Result:
    example: Example
    result: str  # pass / fail / missing
    returncode: int | None
    wall_s: float
    notes: str
    output_tail: str = field(default="", repr=False)


def run_one(
    ex: Example,
    examples_dir: Path,
    python: str,
    workdir: Path,
    speed: float,
    keep_logs: Path | None,
    sitl_args: tuple[str, ...] = (),
) -> Result:
    script = examples_dir / f"{ex.name}.py"
    if not script.exists():
        return Result(ex, "missing", None, 0.0, f"{script.name} not in the examples directory")
    instance = 0
    while not port_free_udp(PX4_API_PORT + instance):
        instance += 1
    api_port = PX4_API_PORT + instance
    notes: list[str] = []
    run_dir = workdir / ex.name.replace("/", "_")
    run_dir.mkdir(parents=True, exist_ok=True)
    # A copy in a temporary directory (with its sibling files: example-mission.plan, active.csv); the connection
    # string alone is rewritten when the port had to move.
    src_dir = script.parent
    copy_dir = run_dir / "example"
    shutil.copytree(src_dir, copy_dir, dirs_exist_ok=True, ignore=shutil.ignore_patterns("__pycache__"))
    copy = copy_dir / script.name
    url = f"udpin://0.0.0.0:{api_port}"
    if instance:
        text = copy.read_text().replace(":14540", f":{api_port}")
        copy.write_text(text)
        notes.append(f"port 14540 busy: --instance {instance}, connection string edited to :{api_port}")
    params_file = run_dir / "example.params"
    params_file.write_text(PARAMS_FILE)
    args = [a.format(url=url, params_file=params_file) for a in ex.args]

    gcs_port, api_local, gcs_local, video_port = free_udp_ports(4)
    ports = SitlPorts(api=api_port, gcs=gcs_port, api_local=api_local, gcs_local=gcs_local)
    extra: tuple[str, ...] = sitl_args
    if sitl_args:
        notes.append(f"viva-sitl {' '.join(sitl_args)}")
    if ex.config_toml:
        cfg = run_dir / "viva-sitl.toml"
        cfg.write_text(ex.config_toml)
        extra += ("--config", str(cfg))
        notes.append(f"viva-sitl --config: {ex.config_toml.strip()!r}")
    sitl = SitlProcess(
        workdir=run_dir, ports=ports, speed=speed, video_port=video_port, frame_socket_port=free_tcp_port(),
        extra_args=extra,
    )  # fmt: skip
    observer = MavlinkPeer(gcs_port)
    observer.heartbeat = False  # passive: the ground-station port only listens
    t0 = time.monotonic()
    rc: int | None = None
    out = ""
    ended_early = False
    try:
        sitl.start()
        observer.wait_autopilot(30.0)
        with (run_dir / "example.log").open("w+") as log:
            proc = subprocess.Popen(
                [python, "-u", copy.name, *args],
                cwd=copy.parent,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
            deadline = time.monotonic() + ex.timeout_s
            while proc.poll() is None and time.monotonic() < deadline:
                if ex.runs_forever and ex.done is not None and ex.done(observer, "")[0]:
                    ended_early = True
                    break
                time.sleep(0.5)
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
                try:
                    proc.wait(5)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
                rc = None
            else:
                rc = proc.returncode
            log.seek(0)
            out = log.read()
    except Exception as exc:  # noqa: BLE001 - a failed start is a row of the table, not the end of the run
        notes.append(f"harness: {exc}".splitlines()[0])
    finally:
        wall = time.monotonic() - t0
        observer.close()
        sitl.stop()
    if keep_logs is not None:
        keep_logs.mkdir(parents=True, exist_ok=True)
        (keep_logs / f"{ex.name.replace('/', '_')}.log").write_text(out)
        shutil.copy(sitl.stderr_path, keep_logs / f"{ex.name.replace('/', '_')}.sitl.log")

    missing = [p for p in ex.must_print if not re.search(p, out)]
    ok_out = not missing
    check = ex.done if ex.runs_forever and ex.done is not None else ex.check
    ok_vehicle, vnote = check(observer, out)
    if ex.runs_forever:
        ok_exit = rc is None or rc == 0
        notes.append(
            "ended by the harness after its check passed" if ended_early else "ran until the timeout"
        )
    else:
        ok_exit = rc == 0
        if rc is None:
            notes.append(f"did not finish within {ex.timeout_s:.0f} s")
    errors = [ln.strip() for ln in out.splitlines() if re.search(r"Error|error:|Exception|Traceback", ln)]
    errors = [e for e in errors if "DeprecationWarning" not in e]
    if vnote:
        notes.append(vnote)
    if missing:
        notes.append(f"output lacks {missing}")
    if errors and not (ok_exit and ok_out and ok_vehicle):
        notes.append(errors[-1][:160])
    texts = [t for t in statustexts(observer) if re.search(r"denied|reject|refus|unsupported|fail", t, re.I)]
    if texts:
        notes.append(f"STATUSTEXT: {texts[-1]}")
    result = "pass" if ok_exit and ok_out and ok_vehicle else "fail"
    return Result(ex, result, rc, wall, "; ".join(notes), out[-2000:])


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--examples", type=Path, required=True, help="MAVSDK-Python's examples/ directory")
    parser.add_argument("--python", required=True, help="python of a venv with mavsdk==3.* installed")
    parser.add_argument("--only", nargs="+", help="example names to run (default: all in the table)")
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--out", type=Path, help="write the markdown table here (default: stdout only)")
    parser.add_argument("--logs", type=Path, help="keep each example's output and viva-sitl's log here")
    parser.add_argument(
        "--sitl-arg",
        action="append",
        default=[],
        help="one more `viva-sitl run` argument for every example (repeatable; e.g. --sitl-arg=--no-video)",
    )
    args = parser.parse_args()
    version = subprocess.run(
        [args.python, "-c", "import importlib.metadata as m; print(m.version('mavsdk'))"],
        capture_output=True,
        text=True,
        check=False,
    ).stdout.strip()
    selected = [
        e for e in EXAMPLES if not args.only or e.name in args.only or e.name.split("/")[-1] in args.only
    ]
    rows: list[Result] = []
    with tempfile.TemporaryDirectory(prefix="viva-mavsdk-examples-") as tmp:
        for ex in selected:
            res = run_one(
                ex, args.examples, args.python, Path(tmp), args.speed, args.logs, tuple(args.sitl_arg)
            )
            rows.append(res)
            print(f"{ex.name}: {res.result} ({res.wall_s:.0f} s) {res.notes}", flush=True)
    lines = [
        f"MAVSDK-Python {version} (classic API, mavsdk_server bundled); `viva-sitl run --speed {args.speed:g}` "
        "(synthetic field, PX4 default home, video on); each example unchanged, fresh viva-sitl per example.",
        "",
        "| example | MAVSDK | command | result | wall s | expected | notes |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cmd = f"`timeout {r.example.timeout_s:.0f} python {r.example.name.split('/')[-1]}.py"
        cmd += (" " + " ".join(r.example.args) if r.example.args else "") + "`"
        lines.append(
            f"| {r.example.name} | {version} | {cmd} | **{r.result}** | {r.wall_s:.0f} | {r.example.expect} | "
            f"{r.notes.replace('|', '/')} |"
        )
    table = "\n".join(lines)
    print(table)
    if args.out:
        args.out.write_text(table + "\n")
    return 0 if all(r.result == "pass" for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
