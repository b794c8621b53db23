"""A campaign: N trials of one pilot over the scenarios drawn from (spec, seed), in parallel, resumable.

    results = run_campaign(spec, pilot="descend", out_dir=Path("out"), jobs=4)          # Python API
    viva-sitl trials run SPEC.toml --pilot descend --n 20 --jobs 4 -o out                 # the same from the CLI

Backends: "local" (default): `jobs` worker processes, each fed one trial at a time over its own pipe, so the
parent always knows which trial a worker runs; a worker past the trial's wall limit is stopped (SIGTERM: it ends the
processes its trial started; then SIGKILL) and that trial fails with end = wall_timeout, the others go on.
"ray": one Ray task per trial (`ray.init(address)`; a task past the wall limit is cancelled). On an existing cluster
(`address`, e.g. one `ray start --head` made) the driver's working directory is shipped with the job (Ray's runtime_env
working_dir, .gitignore/.rayignore honoured, .git/.venv/results left out), so `--pilot mymod:Cls` imports there as it
does here; OUT is made absolute on the driver, and a worker that sees OUT (the same machine, or storage shared at the
same path) runs in the driver's directory and writes its trial folder there; one that does not (another machine)
runs in the shipped copy and sends its trial folder back to the driver. Connection failures (nothing at the address,
token authentication) are one line (RuntimeError), not a Ray traceback.

Each finished trial is written at once to OUT/trials/NNNN/result.json (next to its logs, results.py); Ctrl-C keeps
them and `--resume` runs only the trials whose result is missing or an infrastructure error (an OUT that holds
another run is refused: results.check_out_dir). Results do not
depend on the backend or the job count: every trial is a pure function of (spec, scenario, pilot).
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import io
import json
import multiprocessing as mp
import os
import signal
import socket
import sys
import tarfile
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from queue import Empty
from typing import Any

from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.pilots import is_inprocess, make_pilot
from viva_sitl.evaluation.results import (
    INFRA_ENDS,
    Campaign,
    Row,
    _save_row,
    as_row,
    check_out_dir,
    clear_results,
    finished_trials,
    load_finished,
    mark_infra,
    run_record,
    trial_dir,
)
from viva_sitl.evaluation.scoring import COLUMNS, ScoreRow, score_trial
from viva_sitl.evaluation.spec import Scenario, TrialSpec, draw_scenarios
from viva_sitl.footage import autocache
from viva_sitl.footage.tiles.settings import TileSettings, process_settings, set_process_settings


def default_wall_limit_s(spec: TrialSpec, pilot: str) -> float:
    """Wall seconds one trial may take before it is stopped: generous (loaded machines), finite (hung pilots)."""
    if is_inprocess(pilot):
        return 120.0 + 4.0 * spec.timeout_s
    from viva_sitl.evaluation.external import trial_wall_limit_s

    return trial_wall_limit_s(spec)


def run_one(spec: TrialSpec, scenario: Scenario, pilot: str, out_dir: Path, slot: int, video: bool) -> Row:
    """One trial in this process (any backend calls this): in-process or external by the pilot's form."""
    tdir = trial_dir(out_dir, scenario.index)
    tdir.mkdir(parents=True, exist_ok=True)
    scenario.write(tdir / "scenario.json")
    try:
        if is_inprocess(pilot):
            from viva_sitl.evaluation.runner import run_inprocess_trial

            row = run_inprocess_trial(spec, scenario, pilot, tdir, video=video,
                                      wall_limit_s=default_wall_limit_s(spec, pilot) * 0.9)  # fmt: skip
        else:
            from viva_sitl.evaluation.external import run_external_trial

            row = run_external_trial(spec, scenario, pilot, tdir, slot=slot, video=video, frames=spec.frames,
                                     wall_limit_s=default_wall_limit_s(spec, pilot) * 0.9)  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - one trial's failure never takes the campaign down
        row = failed_row(spec, scenario, TrialEnd.TRIAL_ERROR, f"{type(exc).__name__}: {exc}")
    row["pilot"] = pilot
    return as_row(row)


def failed_row(spec: TrialSpec, scenario: Scenario, end: TrialEnd, detail: str) -> ScoreRow:
    """The row of a trial that produced no flight log (its worker died or hung)."""
    from viva_sitl.evaluation.monitor import TrialLog

    log = TrialLog(end=end, end_detail=detail)
    row = score_trial(scenario, log, None, spec)
    if end.infra:  # as results.mark_infra: an infrastructure error judges nothing
        row["success"], row["criterion_failures"] = None, ""
    # no flight log: what the log would have measured is unavailable, not 0 (a 0 would pull the means down)
    row["end_t_s"] = row["flight_time_s"] = row["path_length_m"] = None
    row["energy_wh"] = row["time_outside_footage_s"] = None
    row["failsafes"] = None
    return row


# ----------------------------------------------------------------------------------------- local pool


def worker_threads(jobs: int) -> int:
    """The cores left to each of `jobs` trial workers: their tile decode threads unless the user chose them."""
    return max(1, (os.cpu_count() or 1) // max(1, jobs))


def init_trial_worker(
    cache_policy: autocache.CachePolicy | None, tiles: TileSettings | None, threads: int
) -> None:
    """A trial worker (spawned: no state of the parent's; a campaign's, a Ray task, a search's pool) opens footage
    as its parent asked, handed as arguments, not through its environment: under the automatic-cache policy
    (`--no-cache / --cache-max-gb`, or the caller's `autocache.set_policy`) and the tile settings, decoding on the
    `threads` cores left to it unless the user chose the threads. With as many workers as cores, a tile cache's
    decode pool only adds hand-offs (measured: 6-trial jpeg-tile campaigns 8-10 % faster with 1)."""
    set_process_settings((tiles if tiles is not None else TileSettings()).or_threads(threads))
    if cache_policy is not None:
        autocache.set_policy(cache_policy)


def _ray_one(spec: TrialSpec, scenario: Scenario, pilot: str, out_dir: str, slot: int, video: bool,
             driver_cwd: str, marker: str, cache_policy: Any = None,
             tiles: Any = None) -> tuple[Row, bytes | None]:  # fmt: skip
    """One trial on a Ray worker: (row, None) when it wrote its trial folder into the driver's OUT (the worker sees
    the driver's marker file there), else (row, the folder as a .tar.gz) for the driver to unpack."""
    # (cache_policy, tiles: Any, not CachePolicy / TileSettings: ray's typed .remote() overloads stop at 7 typed
    # parameters)
    init_trial_worker(cache_policy, tiles, 1)  # the task reserved one CPU (num_cpus=1)
    shared = os.path.exists(marker)
    if shared and os.path.isdir(driver_cwd):
        # the driver's own files: relative paths (footage, an external pilot's script) resolve as they do there
        os.chdir(driver_cwd)
    if shared:
        row, packed = run_one(spec, scenario, pilot, Path(out_dir), slot, video), None
    else:
        with tempfile.TemporaryDirectory(prefix="viva-ray-trial-") as tmp:
            row = run_one(spec, scenario, pilot, Path(tmp), slot, video)
            packed = _pack_dir(trial_dir(Path(tmp), scenario.index))
    if row.get("end") in INFRA_ENDS:
        # where it failed: an import that works on the driver may not on this node
        where = f"Ray worker on {socket.gethostname()}, cwd {os.getcwd()}"
        row["end_detail"] = f"{row.get('end_detail')} ({where})"
    return row, packed


def _pack_dir(folder: Path) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        if folder.is_dir():
            tar.add(folder, arcname=".")
    return buf.getvalue()


def _unpack_dir(data: bytes, folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        tar.extractall(folder, filter="data")  # the data filter: no absolute paths, links out or devices


def _worker(slot: int, conn: Connection, results: Any, spec: TrialSpec, pilot: str, out_dir: str, video: bool,
            threads: int, cache_policy: autocache.CachePolicy | None = None,
            tiles: TileSettings | None = None) -> None:  # fmt: skip
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us with SIGTERM
    init_trial_worker(cache_policy, tiles, threads)

    def _term(*_: object) -> None:
        raise SystemExit(143)  # unwinds: the trial's finally blocks end the processes it started

    signal.signal(signal.SIGTERM, _term)
    while True:
        try:
            task = conn.recv()
        except EOFError:
            return
        if task is None:
            return
        scenario = task
        row = run_one(spec, scenario, pilot, Path(out_dir), slot, video)
        results.put((slot, scenario.index, row))


@dataclass
class _Slot:
    proc: Any
    conn: Connection
    index: int | None = None
    since: float = 0.0


def _local(spec: TrialSpec, pilot: str, todo: list[Scenario], out_dir: Path, jobs: int, video: bool,
           wall_limit_s: float, tiles: TileSettings) -> Iterator[tuple[int, Row]]:  # fmt: skip
    ctx = mp.get_context("spawn")
    results = ctx.Queue()
    queue = list(todo)
    by_index = {s.index: s for s in todo}
    slots: dict[int, _Slot] = {}
    threads = worker_threads(jobs)

    def start(slot: int) -> _Slot:
        parent, child = ctx.Pipe()
        p = ctx.Process(target=_worker, args=(slot, child, results, spec, pilot, str(out_dir), video, threads,
                                              autocache.policy(), tiles),
                        name=f"viva-trial-{slot}", daemon=True)  # fmt: skip
        p.start()
        child.close()
        return _Slot(p, parent)

    def feed(slot: int) -> None:
        s = slots[slot]
        if queue:
            sc = queue.pop(0)
            s.index, s.since = sc.index, time.monotonic()
            s.conn.send(sc)
        else:
            s.index = None

    def stop(s: _Slot) -> None:
        if s.proc.is_alive():
            s.proc.terminate()
            s.proc.join(10.0)
        if s.proc.is_alive():
            s.proc.kill()
            s.proc.join(5.0)
        s.conn.close()

    try:
        for k in range(min(jobs, len(queue))):
            slots[k] = start(k)
            feed(k)
        pending = len(todo)
        while pending:
            try:
                slot, index, row = results.get(timeout=0.5)
            except Empty:  # nothing finished: check the workers
                now = time.monotonic()
                for k, s in list(slots.items()):
                    if s.index is None:
                        continue
                    dead = not s.proc.is_alive()
                    if dead or now - s.since > wall_limit_s:
                        idx = s.index
                        why = (f"worker died (exit code {s.proc.exitcode})" if dead
                               else f"trial took more than {wall_limit_s:g} s of wall time (pilot hung?)")  # fmt: skip
                        stop(s)
                        pending -= 1
                        yield idx, {**failed_row(spec, by_index[idx],
                                                 TrialEnd.WORKER_DIED if dead else TrialEnd.WALL_TIMEOUT, why), "pilot": pilot}  # fmt: skip
                        slots[k] = start(k)
                        feed(k)
                continue
            s = slots[slot]
            if s.index != index:
                continue  # a late result from a worker already given up on
            pending -= 1
            yield index, row
            feed(slot)
    finally:
        for s in slots.values():
            with contextlib.suppress(Exception):
                s.conn.send(None)
        deadline = time.monotonic() + 2.0
        for s in slots.values():
            s.proc.join(max(0.0, deadline - time.monotonic()))
            stop(s)


# ----------------------------------------------------------------------------------------- ray


def _ray_init(address: str | None, out_abs: Path) -> bool:
    """Connect (or start a local Ray) unless this process already has Ray; True when it did (and so shuts it
    down). Before OUT is touched: a cluster that cannot be reached leaves no empty run behind."""
    try:
        import ray
    except ImportError:
        raise RuntimeError("the ray backend needs Ray: pip install 'viva-sitl[trials-ray]'") from None
    if ray.is_initialized():
        return False
    _ray_connect(ray, address, out_abs)
    return True


def _ray(spec: TrialSpec, pilot: str, todo: list[Scenario], out_dir: Path, jobs: int, video: bool,
         wall_limit_s: float, started: bool, tiles: TileSettings) -> Iterator[tuple[int, Row]]:  # fmt: skip
    import ray

    out_abs = out_dir.resolve()  # the driver's OUT, whatever directory the workers run in
    # a worker that sees this file writes into OUT itself; one that does not sends its trial folder back
    marker = out_abs / f".ray-driver-{uuid.uuid4().hex}"
    marker.write_text(f"{socket.gethostname()} {os.getpid()}\n")
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(_ray_one)
        queue = list(todo)
        running: dict[Any, tuple[int, float]] = {}
        slot = 0
        while queue or running:
            while queue and len(running) < jobs:
                sc = queue.pop(0)
                ref = task.remote(spec, sc, pilot, str(out_abs), slot % max(jobs, 1), video, os.getcwd(),
                                  str(marker), autocache.policy(), tiles)  # fmt: skip
                slot += 1
                running[ref] = (sc.index, time.monotonic())
            done, _ = ray.wait(list(running), num_returns=1, timeout=0.5)
            for ref in done:
                idx, _t = running.pop(ref)
                try:
                    row, packed = ray.get(ref)
                    if packed is not None:
                        _unpack_dir(packed, trial_dir(out_abs, idx))
                except Exception as exc:  # noqa: BLE001 - a task that failed in Ray itself
                    lines = str(exc).strip().splitlines()  # a task's error ends with the error itself
                    detail = f"ray: {type(exc).__name__}: {lines[-1] if lines else ''}"
                    row = {**failed_row(spec, _by(todo, idx), TrialEnd.WORKER_DIED, detail), "pilot": pilot}
                yield idx, row
            now = time.monotonic()
            for ref, (idx, t0) in list(running.items()):
                if now - t0 > wall_limit_s:
                    ray.cancel(ref, force=True)
                    running.pop(ref)
                    yield idx, {**failed_row(spec, _by(todo, idx), TrialEnd.WALL_TIMEOUT,
                                             f"trial took more than {wall_limit_s:g} s of wall time"), "pilot": pilot}  # fmt: skip
    finally:
        marker.unlink(missing_ok=True)
        if started:
            ray.shutdown()


# what is never shipped to a cluster with the driver's working directory (besides .gitignore / .rayignore)
RAY_SHIP_EXCLUDES = (".git", ".venv", "venv", "__pycache__", ".mypy_cache", ".pytest_cache", ".ruff_cache",
                     "node_modules", "trials-out")  # fmt: skip


def ray_runtime_env(cwd: Path, out_abs: Path) -> dict[str, Any]:
    """The runtime_env of a job on an existing cluster: the driver's directory, less OUT and the excludes."""
    excludes = list(RAY_SHIP_EXCLUDES)
    with contextlib.suppress(ValueError):
        rel = out_abs.relative_to(cwd.resolve())
        if rel.parts:
            excludes.append("/" + rel.as_posix())  # gitignore syntax: anchored at the working dir
    return {"working_dir": str(cwd), "excludes": excludes}


def _ray_connect(ray: Any, address: str | None, out_abs: Path) -> None:
    """ray.init: a local Ray (address None), or the cluster at `address` with the driver's directory shipped;
    RuntimeError with one line naming the fix when the cluster cannot be reached or refuses this driver."""
    if address is None:
        ray.init(include_dashboard=False, log_to_driver=False)
        return
    _probe_ray_address(address)
    cwd = Path.cwd()
    try:
        ray.init(address=address, include_dashboard=False, log_to_driver=False,
                 runtime_env=ray_runtime_env(cwd, out_abs))  # fmt: skip
    except ConnectionError as exc:
        raise RuntimeError(f"cannot connect to the Ray cluster at {address}: {_first_line(exc)}") from None
    except ValueError as exc:  # Ray refuses a working directory over its package size limit
        raise RuntimeError(
            f"cannot ship the working directory {cwd} to the Ray cluster: {_first_line(exc)} (run from the "
            "directory of your pilot, or list big files in a .rayignore there)"
        ) from None
    except Exception as exc:
        from ray.exceptions import AuthenticationError

        if isinstance(exc, AuthenticationError):
            raise RuntimeError(ray_auth_hint(address)) from None
        raise


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def ray_auth_hint(address: str) -> str:
    """The one line a driver refused by a token-authenticated cluster prints (Ray >= 2.5x: `ray start --head`
    turns token authentication on when the head has a token, e.g. ~/.ray/auth_token, which any local
    `ray.init()` writes; a driver given an explicit address never turns it on by itself)."""
    if os.environ.get("RAY_AUTH_MODE", "").lower() == "token":
        return (f"the Ray cluster at {address} refused this driver's token (RAY_AUTH_MODE=token): give it the "
                "head's token (`ray get-auth-token` on the head) in RAY_AUTH_TOKEN, a file named by "
                "RAY_AUTH_TOKEN_PATH, or ~/.ray/auth_token")  # fmt: skip
    return (f"the Ray cluster at {address} uses token authentication: run the driver with RAY_AUTH_MODE=token and "
            "the head's token in RAY_AUTH_TOKEN (print it on the head: `ray get-auth-token`), a file named by "
            "RAY_AUTH_TOKEN_PATH, or ~/.ray/auth_token")  # fmt: skip


def _probe_ray_address(address: str) -> None:
    """Before ray.init (which retries for ~20-40 s and logs a warning a second): nothing listening at the
    address, or a cluster refusing this driver's authentication, is one line at once."""
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or "://" in address:
        return  # "auto", ray://...: left to ray.init
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=5.0).close()
    except OSError as exc:
        raise RuntimeError(
            f"no Ray cluster at {address} ({exc.strerror or exc}): start one there with `ray start --head "
            f"--port {port}`, or give the address it printed"
        ) from None
    try:  # Ray's own GCS client: what ray.init connects with (a private name: without it, ray.init says it)
        gcs_client = importlib.import_module("ray._raylet").GcsClient
        from ray.exceptions import AuthenticationError
    except (ImportError, AttributeError):
        return
    with _stderr_to_devnull():  # its C++ side logs every failed try on fd 2
        try:
            gcs_client(address=address)
        except AuthenticationError:
            raise RuntimeError(ray_auth_hint(address)) from None
        except Exception:  # noqa: BLE001 - anything else: ray.init says it
            return


@contextlib.contextmanager
def _stderr_to_devnull() -> Iterator[None]:
    sys.stderr.flush()
    saved = os.dup(2)
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)


def _by(todo: list[Scenario], idx: int) -> Scenario:
    return next(s for s in todo if s.index == idx)


# ----------------------------------------------------------------------------------------- campaign


def _preload_report_modules() -> None:
    # only an early import: write_reports imports matplotlib (and says when it is missing) for itself
    with contextlib.suppress(Exception):
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot  # noqa: F401


def refuse_other_run(out: Path, spec_name: str, pilot: str) -> None:
    """OUT holding another pilot's or another spec's results is not overwritten (a copy-pasted -o would lose a
    run); the same pilot and spec run again (or --resume) are fine: the trials are deterministic."""
    try:
        doc = json.loads((out / "results.json").read_text())
        held = (str(doc["pilot"]), str(doc["spec"]["name"]))
    except (OSError, ValueError, KeyError, TypeError):
        return  # no run there (or no readable one): nothing to lose
    if held != (pilot, spec_name):
        raise ValueError(
            f"{out} holds the results of pilot {held[0]!r} on spec {held[1]!r}: give this run (pilot {pilot!r}, "
            f"spec {spec_name!r}) its own -o, or delete that directory"
        )


def run_campaign(
    spec: TrialSpec,
    pilot: str | None = None,
    out_dir: Path | str = "trials-out",
    *,
    n: int | None = None,
    seed: int | None = None,
    jobs: int | None = None,
    backend: str = "local",
    address: str | None = None,
    resume: bool = False,
    force: bool = False,
    only: list[int] | None = None,
    video: bool = False,
    progress: bool = True,
    wall_limit_s: float | None = None,
    on_row: Callable[[Row], None] | None = None,
    tiles: TileSettings | None = None,
) -> Campaign:
    """Run (or resume) a campaign and write results.json / results.csv / report.html to out_dir. Ctrl-C keeps the
    finished trials (reports written for them) and re-raises KeyboardInterrupt after that.

    An out_dir that holds results is refused (ValueError, one line) unless `resume` (the same spec, seed, n, pilot
    and timing: only the missing trials run) or `force` (what it held is removed first). n / seed override the
    spec's; the campaign's spec (and results.json) says what was drawn. `tiles`: how the workers read tile caches
    (None: this process's, `tiles.set_process_settings`; decode threads not chosen: the cores each worker is left),
    handed to them as an argument."""
    from viva_sitl.evaluation.report import write_reports

    pilot = pilot or spec.pilot
    if is_inprocess(pilot):
        _importable_cwd()
        make_pilot(pilot)  # a pilot that cannot be made fails here with one line, not once per trial
    tile_settings = tiles if tiles is not None else process_settings()
    out = Path(out_dir)
    spec = dataclasses.replace(
        spec, n=spec.n if n is None else n, seed=spec.seed if seed is None else seed, pilot=pilot
    )
    scenarios = all_scenarios = draw_scenarios(spec)
    if only is not None:
        bad = [k for k in only if not 0 <= k < len(scenarios)]
        if bad:
            raise ValueError(f"--trial {bad[0]}: no such trial (0..{len(scenarios) - 1})")
        scenarios = [scenarios[k] for k in only]
    check_out_dir(out, run_record(spec, pilot), resume=resume, force=force)
    if backend not in ("local", "ray"):
        raise ValueError(f"unknown backend {backend!r} (local, ray)")
    # connected before OUT is touched (one that cannot be reached leaves no empty run); shut down by _ray, or at
    # exit by Ray itself should what comes before _ray runs fail
    ray_started = _ray_init(address, out.resolve()) if backend == "ray" else False
    out.mkdir(parents=True, exist_ok=True)
    if force:
        clear_results(out)
    jobs = max(1, jobs or os.cpu_count() or 1)
    camp = Campaign(spec, pilot, scenarios, out, backend=backend, jobs=jobs)
    if resume:
        camp.rows = load_finished(out, scenarios, pilot)
        if only is not None:
            # --resume --trial K: the run in OUT keeps its other finished trials (their infrastructure errors
            # too, as they are): results.json and the report go on covering the whole run, not K alone
            chosen = set(only)
            kept = load_finished(
                out, [s for s in all_scenarios if s.index not in chosen], pilot, keep_infra=True
            )
            if kept:
                camp.scenarios = all_scenarios
                camp.rows.update(kept)
    todo = [s for s in scenarios if s.index not in camp.rows]
    limit = wall_limit_s if wall_limit_s is not None else default_wall_limit_s(spec, pilot)
    by_index = {s.index: s for s in all_scenarios}
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(scenarios), initial=len(scenarios) - len(todo), unit="trial", desc=f"{spec.name} [{pilot}]",
                   dynamic_ncols=True)  # fmt: skip
    # the report draws with matplotlib (~0.6 s of CPU + font-cache reads to import): import it while the last trials
    # fly, once fewer trials are left than cores (a core is then idle), not after the last one; nor at the start of a
    # campaign that fills every core, where it would take CPU from the workers' own start-up
    preload = threading.Thread(target=_preload_report_modules, name="viva-report-preload", daemon=True)
    cores = os.cpu_count() or 1
    left = len(todo)  # trials not finished yet

    def preload_if_a_core_is_idle() -> None:
        if 0 < min(left, jobs) < cores and preload.ident is None:
            preload.start()

    preload_if_a_core_is_idle()
    if backend == "local":
        gen: Iterator[tuple[int, Row]] = _local(spec, pilot, todo, out, jobs, video, limit, tile_settings)
    else:
        gen = _ray(spec, pilot, todo, out, jobs, video, limit, ray_started, tile_settings)
    try:
        for idx, row in gen:
            left -= 1
            preload_if_a_core_is_idle()
            camp.rows[idx] = row = mark_infra(row)
            _save_row(out, by_index[idx], row)
            if on_row is not None:
                on_row(row)
            if bar is not None:
                ok = sum(1 for r in camp.rows.values() if r.get("success"))
                bar.set_postfix_str(f"success {ok}/{len(camp.rows)}", refresh=False)
                bar.update(1)
    except KeyboardInterrupt:
        camp.interrupted = True
    finally:
        with contextlib.suppress(Exception):
            gen.close()  # type: ignore[attr-defined]
        if bar is not None:
            bar.close()
        if preload.is_alive():
            preload.join()
        write_reports(camp)
    if camp.interrupted:
        raise KeyboardInterrupt
    return camp


def _importable_cwd() -> None:
    """`--pilot mymod:Cls` finds mymod.py in the current directory, as `python -m` would (the `viva-sitl` script's
    sys.path starts at its own bin folder); spawned workers inherit the parent's sys.path."""
    cwd = os.getcwd()
    if "" not in sys.path and cwd not in sys.path:
        sys.path.insert(0, cwd)


MEASURED_COLUMNS = ("wall_s", "pilot_cpu_s", "pilot_run_delay_s")  # what the machine did, not what was flown


def rows_equal(a: list[Row], b: list[Row]) -> bool:
    """Same results apart from wall time and the pilot's measured CPU (what 'identical whatever the backend and
    job count' means)."""
    strip = [{k: v for k, v in r.items() if k not in MEASURED_COLUMNS} for r in a]
    strip_b = [{k: v for k, v in r.items() if k not in MEASURED_COLUMNS} for r in b]
    return strip == strip_b


__all__ = [
    "COLUMNS",
    "INFRA_ENDS",
    "Campaign",
    "finished_trials",
    "load_finished",
    "refuse_other_run",
    "rows_equal",
    "run_campaign",
    "run_one",
    "trial_dir",
]
