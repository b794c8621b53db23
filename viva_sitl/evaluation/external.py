"""External pilots: the user's program (MAVSDK / pymavlink script, companion code) flown unchanged, per trial, against
its own `viva-sitl run --scenario FILE --instance K --speed S` on ports nobody else uses.

    viva-sitl trials run SPEC --pilot "{python} mission_scripts/mavsdk_takeoff_land.py {mavsdk_url} --altitude 10"

The pilot command is split like a shell line (no shell runs it) and these placeholders are filled in; the same
values are in its environment:

    placeholder        environment               value
    {mavsdk_url}       VIVA_SITL_MAVSDK_URL      udpin://127.0.0.1:P   (the API link: viva-sitl sends there)
    {pymavlink_url}    VIVA_SITL_PYMAVLINK_URL   udpin:127.0.0.1:G     (the ground-station link)
    {api_port}         VIVA_SITL_API_PORT        P
    {gcs_port}         VIVA_SITL_GCS_PORT        G
    {frame_socket}     VIVA_SITL_FRAME_SOCKET    tcp://127.0.0.1:F     (frame-and-pose socket; with trials.frames)
    {scenario}         VIVA_SITL_SCENARIO        the scenario file (JSON, schema vivasitl.scenario.v1): start,
                                                 land_at_s (the "land now" time), footage, failures, limits
    {trial_dir}        VIVA_SITL_TRIAL_DIR       where this trial's logs go
    {instance}         VIVA_SITL_INSTANCE        K (sysid K+1)
    {speed}            VIVA_SITL_SPEED           the speed factor S
    {grpc_port}        VIVA_SITL_GRPC_PORT       a free TCP port for a mavsdk_server (classic gRPC API)
    {python}           -                         this Python interpreter

"Land now" also reaches the pilot over MAVLink, as a STATUSTEXT (severity ALERT) "Emergency: land now".

The vehicle process ends the trial itself (touchdown + disarm, crash, leaving the footage, timeout), writes the
logs and prints `viva-sitl trial: {...}`; the pilot then gets PILOT_EXIT_GRACE_S to exit on its own (the vehicle
still answers), then both are stopped. A pilot that exits with a non-zero code before that ends its trial at once
as pilot_error with its last stderr lines (one that exits with 0 leaves the vehicle to end it). The pilot's stdout
and stderr go to pilot.log as printed (bytes: anything is fine). Every process runs in its own process group and is ended (SIGINT, SIGTERM, then
SIGKILL of the group) on every exit path, including Ctrl-C and the trial's wall limit; on Linux they also get
PR_SET_PDEATHSIG, so they die with the worker even if it is killed outright.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import shlex
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any

from viva_sitl import opencv_pool
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.events import EventKind
from viva_sitl.evaluation.monitor import TrialLog
from viva_sitl.evaluation.runner import limits_of, world_of
from viva_sitl.evaluation.scoring import ScoreRow, score_trial
from viva_sitl.evaluation.session import TRIAL_PREFIX, write_scenario_file
from viva_sitl.evaluation.spec import Scenario, TrialSpec
from viva_sitl.footage import autocache
from viva_sitl.footage.tiles.settings import process_settings

READY_PREFIX = "viva-sitl ready"
START_TIMEOUT_S = 60.0
PILOT_EXIT_GRACE_S = 5.0  # wall seconds a pilot gets to exit on its own after its trial ended


def _pdeathsig() -> None:  # runs in the child between fork and exec
    with contextlib.suppress(Exception):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def free_ports(kind: int, count: int) -> list[int]:
    socks = []
    try:
        for _ in range(count):
            s = socket.socket(socket.AF_INET, kind)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [int(s.getsockname()[1]) for s in socks]
    finally:
        for s in socks:
            s.close()


def _start(cmd: list[str], env: dict[str, str] | None = None, cwd: str | None = None, *,
           split_stderr: bool = False) -> subprocess.Popen[bytes]:  # fmt: skip
    """Bytes, not text: a program may print anything (non-UTF-8 too); the logs keep it as printed."""
    return subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE if split_stderr else subprocess.STDOUT, env=env,
        cwd=cwd, start_new_session=True, preexec_fn=_pdeathsig if sys.platform.startswith("linux") else None,
    )  # fmt: skip


def stop_group(p: subprocess.Popen[bytes], grace_s: float = 3.0) -> int | None:
    """End a process and everything in its group: SIGINT, then SIGTERM, then SIGKILL."""
    for sig, wait in ((signal.SIGINT, grace_s), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
        if p.poll() is not None:
            break
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(p.pid, sig)
        with contextlib.suppress(subprocess.TimeoutExpired):
            p.wait(wait)
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(p.pid, signal.SIGKILL)  # stragglers of the group (a mavsdk_server the script started)
    return p.poll()


class _Pump(threading.Thread):
    """Copies one output stream of a process to a log file (bytes as printed) and remembers its last lines and the
    lines we wait for. Survives anything: undecodable bytes, a log that cannot be written (it keeps draining the
    pipe, so the process never blocks on a full one)."""

    def __init__(self, stream: IO[bytes] | None, log: IO[bytes], watch: tuple[str, ...],
                 lock: threading.Lock | None = None) -> None:  # fmt: skip
        super().__init__(daemon=True)
        assert stream is not None
        self.stream, self.log, self.watch = stream, log, watch
        self.lock = lock or threading.Lock()
        self.hits: dict[str, str] = {}
        self.tail: list[str] = []
        self.event = threading.Event()

    def run(self) -> None:
        try:
            for raw in self.stream:
                with self.lock, contextlib.suppress(OSError, ValueError):
                    self.log.write(raw)
                    self.log.flush()
                line = raw.decode("utf-8", errors="replace")
                self.tail = (self.tail + [line.rstrip()])[-20:]
                for w in self.watch:
                    if line.startswith(w):
                        self.hits[w] = line
                        self.event.set()
        except (OSError, ValueError):  # the pipe closed under us (the process was stopped)
            pass
        finally:
            self.event.set()

    def last(self, k: int = 3) -> str:
        """The last k non-empty lines, joined with ' | '."""
        return " | ".join([x.strip() for x in self.tail if x.strip()][-k:])


def trial_wall_limit_s(spec: TrialSpec) -> float:
    """Wall seconds an external trial may take: 3x its sim timeout at its speed, more when the clock stops for
    the pilot's computing (lockstep / charged: a pilot computing 300 ms per frame at 30 fps runs at 0.1x)."""
    if spec.timing == "realtime":
        return 90.0 + 3.0 * spec.timeout_s / spec.speed
    return 120.0 + 20.0 * spec.timeout_s / min(spec.speed, 1.0)


def pilot_command(template: str, values: dict[str, str]) -> list[str]:
    try:
        return [part.format(**values) for part in shlex.split(template)]
    except (KeyError, IndexError) as exc:
        raise ValueError(f"pilot command {template!r}: unknown placeholder {exc} (known: "
                         f"{', '.join('{' + k + '}' for k in values)})") from None  # fmt: skip


def run_external_trial(
    spec: TrialSpec,
    scenario: Scenario,
    command: str | None,
    trial_dir: Path,
    *,
    slot: int = 0,
    video: bool = False,
    wall_limit_s: float | None = None,
    frames: bool = False,
    api_port: int | None = None,
    gcs_port: int | None = None,
    video_port: int | None = None,
    sitl_args: Sequence[str] = (),
    on_ready: Callable[[str], None] | None = None,
    abort_on_interrupt: bool = False,
) -> ScoreRow:
    """Fly one trial against its own `viva-sitl run --scenario`; return the scored row.

    command None: no pilot program: a person flies it (the dashboard page, QGroundControl, a gamepad: `trials
    fly`). api_port / gcs_port / video_port: where the vehicle sends its MAVLink and H.264 RTP (default: free
    ports). sitl_args: more
    `viva-sitl run` options. on_ready: called with `viva-sitl run`'s ready line. abort_on_interrupt (main thread
    only): Ctrl-C / SIGTERM end the trial as "aborted" (the vehicle process writes its logs, the row is scored)
    instead of raising; a second Ctrl-C does not cut the cleanup short."""
    wall0 = time.perf_counter()
    trial_dir.mkdir(parents=True, exist_ok=True)
    limits = limits_of(spec)
    scen_path = trial_dir / "scenario.json"
    write_scenario_file(scen_path, scenario, limits)
    api, gcs, api_local, gcs_local, rtp = free_ports(socket.SOCK_DGRAM, 5)
    api = api if api_port is None else api_port
    gcs = gcs if gcs_port is None else gcs_port
    rtp = rtp if video_port is None else video_port
    frame_port, grpc_port = free_ports(socket.SOCK_STREAM, 2)
    frame_url = f"tcp://127.0.0.1:{frame_port}"
    instance = slot % 250
    sitl_cmd = [
        sys.executable, "-m", "viva_sitl", "--log-level", "WARNING", "run", "--scenario", str(scen_path),
        "--instance", str(instance), "--speed", f"{spec.speed:g}", "--api-port", str(api), "--gcs-port", str(gcs),
        "--api-local-port", str(api_local), "--gcs-local-port", str(gcs_local), "--video-port", str(rtp),
        "--frame-socket", frame_url, "--run-dir", str(trial_dir),
    ]  # fmt: skip
    if spec.timing != "realtime":
        sitl_cmd += ["--timing", spec.timing, "--pilot-cpu-factor", f"{spec.pilot_cpu_factor:g}",
                     "--pilot-latency-ms", f"{spec.pilot_latency_ms:g}"]  # fmt: skip
    sitl_cmd += autocache.policy_cli_args()  # the campaign's --no-cache / --cache-max-gb
    sitl_cmd += list(sitl_args)
    if video:
        sitl_cmd += ["--record", str(trial_dir / "vac.mp4")]
    elif not frames:
        sitl_cmd.append("--no-video")
    values = {
        "mavsdk_url": f"udpin://127.0.0.1:{api}", "pymavlink_url": f"udpin:127.0.0.1:{gcs}", "api_port": str(api),
        "gcs_port": str(gcs), "frame_socket": frame_url, "scenario": str(scen_path.resolve()),
        "trial_dir": str(trial_dir.resolve()), "instance": str(instance), "speed": f"{spec.speed:g}",
        "grpc_port": str(grpc_port), "python": sys.executable,
    }  # fmt: skip
    pcmd = pilot_command(command, values) if command is not None else None
    # this process's tile settings (a campaign worker's: an argument, not its environment) reach the `viva-sitl run`
    # child as the documented variables, which it reads on its top floor
    tile_env = process_settings().to_environ()
    sitl_env = {**os.environ, **tile_env}
    # the pilot: the user's program gets the environment without what viva_sitl set for its own OpenCV
    env = {**opencv_pool.user_environ(), **tile_env}
    env.update({f"VIVA_SITL_{k.upper()}": v for k, v in values.items() if k != "python"})
    env["PYTHONUNBUFFERED"] = "1"
    limit = wall_limit_s if wall_limit_s is not None else trial_wall_limit_s(spec)
    sitl: subprocess.Popen[bytes] | None = None
    pilot: subprocess.Popen[bytes] | None = None
    end_override: tuple[TrialEnd, str] | None = None
    pilot_note = ""
    aborted = threading.Event()
    old_handlers: dict[int, Any] = {}
    if abort_on_interrupt:
        for sig in (signal.SIGINT, signal.SIGTERM):
            old_handlers[sig] = signal.signal(sig, lambda *_: aborted.set())
    plog_path = trial_dir / "pilot.log" if pcmd is not None else Path(os.devnull)
    with (trial_dir / "sitl.log").open("wb") as slog, plog_path.open("wb") as plog:
        try:
            sitl = _start(sitl_cmd, env=sitl_env)
            spump = _Pump(sitl.stdout, slog, (READY_PREFIX, TRIAL_PREFIX))
            spump.start()
            t_start = time.monotonic()
            while READY_PREFIX not in spump.hits:
                if sitl.poll() is not None and not spump.is_alive():
                    break
                if time.monotonic() - t_start > START_TIMEOUT_S or aborted.is_set():
                    break
                spump.event.wait(0.2)
                spump.event.clear()
            if aborted.is_set():
                end_override = (TrialEnd.ABORTED, "stopped by the user before the trial started")
            elif READY_PREFIX not in spump.hits:
                tail = " | ".join(spump.tail[-3:])
                end_override = (TrialEnd.SITL_ERROR, f"viva-sitl run did not start: {tail}"[:400])
            else:
                if on_ready is not None:
                    on_ready(spump.hits[READY_PREFIX].rstrip())
                try:
                    pilot = _start(pcmd, env=env, split_stderr=True) if pcmd is not None else None
                except OSError as exc:
                    assert pcmd is not None
                    end_override = (TrialEnd.PILOT_ERROR, f"cannot start the pilot {pcmd[0]!r}: {exc}")
                if pilot is not None:
                    plock = threading.Lock()  # stdout and stderr into the one pilot.log, line by line
                    ppump = _Pump(pilot.stdout, plog, (), plock)
                    epump = _Pump(pilot.stderr, plog, (), plock)
                    ppump.start()
                    epump.start()
                while end_override is None and sitl.poll() is None and TRIAL_PREFIX not in spump.hits:
                    if aborted.is_set():
                        end_override = (
                            TrialEnd.ABORTED,
                            "stopped by the user (Ctrl-C) before the trial ended",
                        )
                        break
                    if time.perf_counter() - wall0 > limit:
                        end_override = (
                            TrialEnd.WALL_TIMEOUT,
                            f"trial took more than {limit:g} s of wall time",
                        )
                        break
                    if pilot is not None and pilot.poll() is not None and not pilot_note:
                        rc = pilot.returncode
                        if rc != 0:  # a failed pilot (missing script or package, a crash) fails its trial now
                            ppump.join(2.0)
                            epump.join(2.0)
                            last = epump.last() or ppump.last()
                            why = (
                                f"-{signal.Signals(-rc).name}"
                                if rc < 0 and -rc in signal.valid_signals()
                                else rc
                            )
                            end_override = (TrialEnd.PILOT_ERROR, f"pilot exited with code {why} before the trial ended"
                                            + (f": {last}"[:400] if last else ""))  # fmt: skip
                            pilot_note = f"pilot exited with code {rc}"
                            break
                        pilot_note = (
                            "pilot exited with code 0 before the trial ended"  # e.g. a mission uploader
                        )
                    time.sleep(0.1)
        finally:
            if pilot is not None:
                if end_override is None:  # trial over: a script that waits for the disarm exits by itself
                    with contextlib.suppress(subprocess.TimeoutExpired):
                        pilot.wait(PILOT_EXIT_GRACE_S)
                if not pilot_note:
                    if pilot.poll() is None:
                        pilot_note = (
                            f"pilot still running at the end of the trial (stopped: {stop_group(pilot)})"
                        )
                    else:
                        pilot_note = f"pilot exited with code {pilot.returncode}"
                stop_group(pilot)  # and its process group (e.g. a mavsdk_server the script started)
            if sitl is not None:
                stop_group(sitl, grace_s=5.0)
            for signum, handler in old_handlers.items():
                signal.signal(signum, handler)
    try:
        log = TrialLog.read(trial_dir)
    except (FileNotFoundError, ValueError, KeyError) as exc:
        log = TrialLog(end=TrialEnd.SITL_ERROR, end_detail=f"no trial log from viva-sitl run: {exc}")
    if end_override is not None and (
        log.end in (None, TrialEnd.SITL_STOPPED)
        or end_override[0] == TrialEnd.SITL_ERROR
        or (
            end_override[0] == TrialEnd.ABORTED and log.end == TrialEnd.SITL_ERROR
        )  # stopped before it started
    ):
        log.end, log.end_detail = end_override
        if log.end == TrialEnd.ABORTED:  # the vehicle logged its stop; say why it stopped
            log.events.append(
                {
                    "t_s": log.end_t_s,
                    "kind": EventKind.END,
                    "text": f"aborted: {log.end_detail}",
                    "severity": 4,
                }
            )
    if pilot_note and log.end not in (TrialEnd.LANDED, TrialEnd.PILOT_ERROR):
        log.end_detail = f"{log.end_detail}; {pilot_note}"
    if pilot_note:
        log.events.append({"t_s": log.end_t_s, "kind": EventKind.PILOT, "text": pilot_note, "severity": 6})
    log.write(trial_dir)
    row = score_trial(scenario, log, world_of(scenario.footage), spec)
    add_timing_columns(row, spec.timing, log.timing)
    row["wall_s"] = round(time.perf_counter() - wall0, 3)
    return row


def add_timing_columns(row: ScoreRow, timing: str, record: dict[str, Any] | None) -> None:
    """The clock a trial ran on and what its pilot experienced (end.json "timing", viva_sitl.timing):
    timing_ok False marks a trial whose result depended on the machine (a starved realtime pilot, a lockstep
    pilot never idle, or no pilot process found to watch)."""
    rec = record or {}
    row["timing"] = timing
    row["pilot_cpu_factor"] = rec.get("pilot_cpu_factor")
    row["pilot_latency_ms"] = rec.get("pilot_latency_ms")
    row["pilot_cpu_s"] = rec.get("pilot_cpu_s")
    row["pilot_run_delay_s"] = rec.get("pilot_run_delay_s")
    if timing == "realtime":
        row["timing_ok"] = None if not rec.get("pilot_pid") else not rec.get("starved", False)
    else:
        row["timing_ok"] = bool(rec.get("lockstep_held", False))
