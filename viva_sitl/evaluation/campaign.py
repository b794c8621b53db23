"""A campaign: N trials of one pilot over the scenarios drawn from (spec, seed), in parallel, resumable.

    results = run_campaign(spec, pilot="descend", out_dir=Path("out"), jobs=4)          # Python API
    viva-sitl trials run SPEC.toml --pilot descend --n 20 --jobs 4 -o out                 # the same from the CLI

Backends: "local" (default): `jobs` worker processes, each fed one trial at a time over its own pipe, so the
parent always knows which trial a worker runs; a worker past the trial's wall limit is stopped (SIGTERM: it ends the
processes its trial started; then SIGKILL) and that trial fails with end = wall_timeout, the others go on.
"ray": one Ray task per trial (`ray.init(address)`; a task past the wall limit is cancelled).

Each finished trial is written at once to OUT/trials/NNNN/result.json (next to its logs, results.py); Ctrl-C keeps
them and `--resume` runs only the trials whose result is missing or an infrastructure error (an OUT that holds
another run is refused: results.check_out_dir). Results do not
depend on the backend or the job count: every trial is a pure function of (spec, scenario, pilot).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from queue import Empty
from typing import Any

from viva_sitl.evaluation.pilots import is_inprocess, make_pilot
from viva_sitl.evaluation.results import (
    INFRA_ENDS,
    Campaign,
    Row,
    _save_row,
    check_out_dir,
    clear_results,
    finished_trials,
    load_finished,
    mark_infra,
    run_record,
    trial_dir,
)
from viva_sitl.evaluation.scoring import COLUMNS, score_trial
from viva_sitl.evaluation.spec import Scenario, TrialSpec, draw_scenarios
from viva_sitl.footage import autocache


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
        row = failed_row(spec, scenario, "trial_error", f"{type(exc).__name__}: {exc}")
    row["pilot"] = pilot
    return row


def failed_row(spec: TrialSpec, scenario: Scenario, end: str, detail: str) -> Row:
    """The row of a trial that produced no flight log (its worker died or hung)."""
    from viva_sitl.evaluation.monitor import TrialLog

    log = TrialLog(end=end, end_detail=detail)
    row = mark_infra(score_trial(scenario, log, None, spec))
    # no flight log: what the log would have measured is unavailable, not 0 (a 0 would pull the means down)
    for key in (
        "end_t_s",
        "flight_time_s",
        "path_length_m",
        "energy_wh",
        "time_outside_footage_s",
        "failsafes",
    ):
        row[key] = None
    return row


# ----------------------------------------------------------------------------------------- local pool


def _share_cores(threads: int) -> None:
    """A trial worker's footage decode threads: the cores left to it. With as many workers as cores, a tile
    cache's decode pool only adds hand-offs (measured: 6-trial jpeg-tile campaigns 8-10 % faster with 1)."""
    from viva_sitl.footage.tiles import DECODE_THREADS_ENV

    os.environ.setdefault(DECODE_THREADS_ENV, str(threads))  # the user's own setting wins


def _use_cache_policy(cache_policy: Any) -> None:
    """A worker (spawned: no state of the parent's) opens footage under the campaign's automatic-cache policy
    (`trials run --no-cache / --cache-max-gb`, or the caller's `autocache.set_policy`)."""
    if cache_policy is not None:
        from viva_sitl.footage import autocache

        autocache.set_policy(cache_policy)


def _ray_one(spec: TrialSpec, scenario: Scenario, pilot: str, out_dir: Path, slot: int, video: bool,
             cache_policy: Any = None) -> Row:  # fmt: skip
    _share_cores(1)  # the task reserved one CPU (num_cpus=1)
    _use_cache_policy(cache_policy)
    return run_one(spec, scenario, pilot, out_dir, slot, video)


def _worker(slot: int, conn: Connection, results: Any, spec: TrialSpec, pilot: str, out_dir: str, video: bool,
            threads: int, cache_policy: Any = None) -> None:  # fmt: skip
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us with SIGTERM
    _share_cores(threads)
    _use_cache_policy(cache_policy)

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
           wall_limit_s: float) -> Iterator[tuple[int, Row]]:  # fmt: skip
    ctx = mp.get_context("spawn")
    results = ctx.Queue()
    queue = list(todo)
    by_index = {s.index: s for s in todo}
    slots: dict[int, _Slot] = {}
    threads = max(1, (os.cpu_count() or 1) // max(1, jobs))

    def start(slot: int) -> _Slot:
        parent, child = ctx.Pipe()
        p = ctx.Process(target=_worker, args=(slot, child, results, spec, pilot, str(out_dir), video, threads,
                                              autocache.policy()),
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
                        yield idx, {**failed_row(spec, by_index[idx], "wall_timeout" if not dead else "worker_died",
                                                 why), "pilot": pilot}  # fmt: skip
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


def _ray(spec: TrialSpec, pilot: str, todo: list[Scenario], out_dir: Path, jobs: int, video: bool,
         wall_limit_s: float, address: str | None) -> Iterator[tuple[int, Row]]:  # fmt: skip
    try:
        import ray
    except ImportError:
        raise RuntimeError("the ray backend needs Ray: pip install 'viva-sitl[trials-ray]'") from None
    started = False
    if not ray.is_initialized():
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
        started = True
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(_ray_one)
        queue = list(todo)
        running: dict[Any, tuple[int, float]] = {}
        slot = 0
        while queue or running:
            while queue and len(running) < jobs:
                sc = queue.pop(0)
                ref = task.remote(spec, sc, pilot, out_dir, slot % max(jobs, 1), video, autocache.policy())
                slot += 1
                running[ref] = (sc.index, time.monotonic())
            done, _ = ray.wait(list(running), num_returns=1, timeout=0.5)
            for ref in done:
                idx, _t = running.pop(ref)
                try:
                    row = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - a task that failed in Ray itself
                    row = {**failed_row(spec, _by(todo, idx), "worker_died", f"ray: {exc}"), "pilot": pilot}
                yield idx, row
            now = time.monotonic()
            for ref, (idx, t0) in list(running.items()):
                if now - t0 > wall_limit_s:
                    ray.cancel(ref, force=True)
                    running.pop(ref)
                    yield idx, {**failed_row(spec, _by(todo, idx), "wall_timeout",
                                             f"trial took more than {wall_limit_s:g} s of wall time"), "pilot": pilot}  # fmt: skip
    finally:
        if started:
            ray.shutdown()


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
) -> Campaign:
    """Run (or resume) a campaign and write results.json / results.csv / report.html to out_dir. Ctrl-C keeps the
    finished trials (reports written for them) and re-raises KeyboardInterrupt after that.

    An out_dir that holds results is refused (ValueError, one line) unless `resume` (the same spec, seed, n, pilot
    and timing: only the missing trials run) or `force` (what it held is removed first). n / seed override the
    spec's; the campaign's spec (and results.json) says what was drawn."""
    from viva_sitl.evaluation.report import write_reports
    from viva_sitl.footage.tiles import check_tile_environment

    pilot = pilot or spec.pilot
    if is_inprocess(pilot):
        _importable_cwd()
        make_pilot(pilot)  # a pilot that cannot be made fails here with one line, not once per trial
    check_tile_environment()  # so does a bad $VIVA_SITL_TILE_*, which every worker would read
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
        gen = _local(spec, pilot, todo, out, jobs, video, limit)
    elif backend == "ray":
        gen = _ray(spec, pilot, todo, out, jobs, video, limit, address)
    else:
        raise ValueError(f"unknown backend {backend!r} (local, ray)")
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
