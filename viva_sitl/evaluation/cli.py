"""`viva-sitl trials run | fly | compare | show | scenarios | search`."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

from viva_sitl.cliargs import add_cache_args, add_timing_flags, positive_float
from viva_sitl.cliargs import nonneg_int as _nonneg_int
from viva_sitl.cliargs import port as _port
from viva_sitl.cliargs import pos_int as _pos_int
from viva_sitl.evaluation.ends import TrialEnd


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="viva-sitl trials", description="Randomized landing trials: run, compare, show."
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run N trials of a pilot over the scenarios of a spec")
    r.add_argument("spec", help="trial spec (TOML), e.g. configs/trials/synthetic_emergency.toml")
    r.add_argument(
        "--pilot",
        help="descend | oracle | package.module:Class (in-process) | a command line (external program; "
        "placeholders {mavsdk_url} {pymavlink_url} {scenario} {frame_socket} {python} ..., see "
        "viva_sitl/evaluation/external.py); default: the spec's trials.pilot",
    )
    r.add_argument("--n", type=_pos_int, help="number of trials (default: the spec's trials.n)")
    r.add_argument("--seed", type=_nonneg_int, help="scenario seed (default: the spec's trials.seed)")
    r.add_argument("--jobs", type=_pos_int, help=f"parallel trials (default: cores = {os.cpu_count()})")
    r.add_argument(
        "-o", "--out", default=None, help="output directory (default: trials-out/<spec name>-<pilot>)"
    )
    r.add_argument("--backend", choices=["local", "ray"], default="local")
    r.add_argument(
        "--address",
        help="with --backend ray: the cluster to run on, HOST:PORT as `ray start --head --port PORT` printed "
        "(the current directory is shipped to it; token auth: RAY_AUTH_MODE=token RAY_AUTH_TOKEN=...; see the "
        "README's Ray section); default: a local Ray started for this run",
    )
    g = r.add_mutually_exclusive_group()
    g.add_argument(
        "--resume", action="store_true",
        help="complete the run in OUT: keep its finished trials, run the rest (and its infrastructure errors); "
        "refused unless OUT holds the same spec, seed, n, pilot and timing",
    )  # fmt: skip
    g.add_argument(
        "--force", action="store_true",
        help="replace what OUT holds (its results and trials/NNNN folders are removed first)",
    )  # fmt: skip
    r.add_argument(
        "--trial", type=_nonneg_int, action="append", help="run only trial K (repeatable): reproduce it"
    )
    r.add_argument("--video", action="store_true", help="also record each trial's VAC video (vac.mp4)")
    r.add_argument(
        "--no-ulog", action="store_true",
        help="in-process pilots: write no per-trial PX4 ULog (log.ulg), as the spec's trials.ulog = false; saves "
        "+26-39 %% wall per trial, the results do not change",
    )  # fmt: skip
    r.add_argument(
        "--frames", action="store_true",
        help="external pilots: render the VAC and serve the frame-and-pose socket ({frame_socket}), as the "
        "spec's trials.frames = true; the scenarios do not change",
    )  # fmt: skip
    r.add_argument(
        "--speed", type=float,
        help="external pilots: the `viva-sitl run --speed` factor (default: the spec's trials.speed); a slow "
        "pilot (e.g. CPU vision) needs a lower one; the scenarios do not change",
    )  # fmt: skip
    add_timing_flags(r, "the spec's trials.timing")
    add_cache_args(
        r
    )  # --no-cache / --cache-max-gb / --tile-cache-dir, as on `viva-sitl run`; every trial's too
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    from viva_sitl.evaluation.human import MAVSDK_API_PORT, QGC_GCS_PORT, QGC_VIDEO_PORT

    f = sub.add_parser(
        "fly",
        help="fly trial K yourself (dashboard page, keys, gamepad or QGroundControl), scored like a program",
    )
    f.add_argument("spec", help="trial spec (TOML), e.g. configs/trials/synthetic_emergency.toml")
    f.add_argument(
        "--trial", type=_nonneg_int, required=True, help="the scenario to fly (as trials run --trial K)"
    )
    f.add_argument("--n", type=_pos_int, help="number of trials of the spec (default: the spec's trials.n)")
    f.add_argument("--seed", type=_nonneg_int, help="scenario seed (default: the spec's trials.seed)")
    f.add_argument("-o", "--out", help="output directory (default: trials-out/<spec name>-<name>-trial-K)")
    f.add_argument(
        "--speed", type=positive_float, default=1.0, help="sim seconds per wall second (default 1)"
    )
    f.add_argument("--name", default="human", help="the pilot's name in the results (default: human)")
    f.add_argument(
        "--dashboard-port", type=_port, help="dashboard port (default 8080; when busy a free port)"
    )
    f.add_argument("--api-port", type=_port, default=MAVSDK_API_PORT,
                   help=f"remote API port the vehicle sends to (default {MAVSDK_API_PORT}, MAVSDK's)")  # fmt: skip
    f.add_argument("--gcs-port", type=_port, default=QGC_GCS_PORT,
                   help=f"remote ground-station port (default {QGC_GCS_PORT}: QGroundControl connects by itself)")  # fmt: skip
    f.add_argument("--video-port", type=_port, default=QGC_VIDEO_PORT,
                   help=f"UDP port of the H.264 RTP video (default {QGC_VIDEO_PORT}: QGroundControl shows it)")  # fmt: skip
    c = sub.add_parser(
        "compare",
        help="paired statistics of two runs over the same scenarios; three or more (or --baseline): a leaderboard",
    )
    c.add_argument(
        "runs", nargs="+", metavar="OUT_DIR",
        help="OUT_DIRs of runs: two = A B (paired statistics, B - A); more: a ranked table against --baseline",
    )  # fmt: skip
    c.add_argument(
        "--baseline", help="the OUT_DIR every other run is compared with (a leaderboard; default: the first)"
    )
    c.add_argument(
        "--allow-mismatch", action="store_true",
        help="compare runs that differ in timing, pilot CPU factor, speed, spec or viva-sitl version (refused "
        "otherwise): a WARNING and the differences go into the output",
    )  # fmt: skip
    c.add_argument("-o", "--out", help="write the comparison as JSON here")
    c.add_argument(
        "--html", help="write the comparison as a self-contained HTML page here (every pair listed; a "
        "leaderboard's page: default leaderboard.html)",
    )  # fmt: skip
    su = sub.add_parser(
        "suite", help="frozen benchmark suites: list | run SUITE --pilot ... -o OUT | card OUT"
    )
    ss = su.add_subparsers(dest="suite_cmd", required=True)
    ss.add_parser("list", help="the shipped suites: id, splits, content hash, whether their footage is here")
    sh = ss.add_parser(
        "hash", help="a suite's content hashes as its [frozen] tables (to publish a new version)"
    )
    sh.add_argument("suite", help="suite name or file")
    sr = ss.add_parser("run", help="fly a pilot (and the descend baseline) over a suite's splits")
    sr.add_argument("suite", help="suite name (see `trials suite list`) or a suite file")
    sr.add_argument("--pilot", required=True, help="as `trials run --pilot`")
    sr.add_argument(
        "-o", "--out", required=True, help="output directory (OUT/dev, OUT/test, OUT/baseline/...)"
    )
    sr.add_argument(
        "--split", choices=["dev", "test", "all"], default="all", help="which split (default: all)"
    )
    sr.add_argument("--jobs", type=_pos_int, help=f"parallel trials (default: cores = {os.cpu_count()})")
    sr.add_argument(
        "--limit", type=_pos_int,
        help="fly only the first K scenarios of each split (a smoke run; its card says PARTIAL: not citable)",
    )  # fmt: skip
    sg = sr.add_mutually_exclusive_group()
    sg.add_argument("--resume", action="store_true", help="complete the suite run in OUT")
    sg.add_argument("--force", action="store_true", help="replace what OUT holds")
    sr.add_argument("--no-progress", action="store_true", help="no progress bar")
    sk = ss.add_parser("card", help="write OUT/card.md + OUT/card.json: the citable result of a suite run")
    sk.add_argument("out", help="OUT of `trials suite run`")
    rp = sub.add_parser("report", help="write OUT_DIR/report.html again from its results.json")
    rp.add_argument("out", help="OUT_DIR of a run")
    s = sub.add_parser("show", help="summary of a run, or one trial")
    s.add_argument("out", help="OUT_DIR of a run")
    s.add_argument("--trial", type=_nonneg_int, help="show this trial's row, scenario and events")
    sc = sub.add_parser("scenarios", help="list the scenarios a spec draws (no flight)")
    sc.add_argument("spec")
    sc.add_argument("--n", type=_pos_int)
    sc.add_argument("--seed", type=_nonneg_int)
    from viva_sitl.evaluation.search import add_search_parser

    add_search_parser(sub)
    return p


def _print_summary(doc: dict[str, Any]) -> None:
    from viva_sitl.evaluation.report import infra_line

    agg = doc["aggregate"]
    print(f"{doc['spec']['name']} [{doc['pilot']}]: {doc['trials_done']}/{doc['trials_total']} trials"
          f"{'' if doc['complete'] else ' (incomplete: --resume completes the rest)'}")  # fmt: skip
    if agg["success_rate"] is not None:
        lo, hi = agg["success_rate_ci95_wilson"]
        print(f"  {agg['criterion']}: {agg['success']}/{agg['success_judged']} = {100 * agg['success_rate']:.1f} % "
              f"(95 % CI {100 * lo:.1f}-{100 * hi:.1f} %)")  # fmt: skip
    elif agg.get("n") == 0 and doc["trials_done"]:
        print(f"  {agg['criterion']}: unavailable (no trial flew)")
    else:
        print(f"  {agg['criterion']}: unavailable (no ground truth)")
    print("  ends: " + ", ".join(f"{k} {v}" for k, v in agg["ends"].items()))
    infra = infra_line(agg)
    if infra is not None:
        print(f"  {infra}: left out of the success rate and the scores; --resume runs them again")
    for key in (
        "touchdown_speed_m_s",
        "min_dist_person_m",
        "min_dist_object_m",
        "risk_level",
        "time_to_land_s",
    ):
        st = agg["scores"][key]
        if st["n"] and "counts" in st:  # ordinal (risk level): the distribution, never a mean
            levels = ", ".join(f"{lv}: {c}" for lv, c in st["counts"].items())
            print(f"  {key}: trials per level {levels}; median {st['median']}, n {st['n']}")
        elif st["n"]:
            print(f"  {key}: mean {st['mean']} (95 % CI {st['mean_ci95'][0]}..{st['mean_ci95'][1]}), "
                  f"median {st['median']}, n {st['n']}")  # fmt: skip
        else:
            print(f"  {key}: unavailable")


def trials_main(argv: list[str]) -> int:
    from viva_sitl.config import ConfigError

    args = build_parser().parse_args(argv)
    try:
        if args.cmd in ("run", "fly", "report", "suite", "search"):  # the commands that open footage
            from viva_sitl.footage.tiles import TileSettings, set_process_settings

            # the top floor reads the documented $VIVA_SITL_TILE_* once (a bad value: one line, before any trial);
            # a campaign hands the settings to its workers as an argument
            set_process_settings(TileSettings.from_environ(os.environ))
        if args.cmd == "run":
            return _run(args)
        if args.cmd == "fly":
            return _fly(args)
        if args.cmd == "compare":
            return _compare(args)
        if args.cmd == "show":
            return _show(args)
        if args.cmd == "report":
            return _report(args)
        if args.cmd == "suite":
            return _suite(args)
        if args.cmd == "search":
            from viva_sitl.evaluation.search import search_main

            return search_main(args)
        if args.cmd == "scenarios":
            from viva_sitl.evaluation.spec import draw_scenarios, load_spec

            spec = load_spec(args.spec)
            for s in draw_scenarios(spec, args.n, args.seed):
                print(json.dumps(s.to_dict()))
            return 0
    except (ConfigError, ValueError, RuntimeError) as exc:
        print(f"viva-sitl trials: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `trials scenarios SPEC | head`: the reader has what it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit's flush
        return 0
    except OSError as exc:  # an output path that cannot be written, a directory that cannot be read
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"viva-sitl trials: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    return 2


def check_external_pilot(pilot: str) -> None:
    """A pilot command whose program does not exist fails here with one line, not as N failed trials (a typo
    such as `--pilot decsend` is an external command to the runner). Commands starting with a placeholder
    ({python}) are left to the trial."""
    import shlex
    import shutil

    from viva_sitl.evaluation.pilots import BUILTIN_PILOTS, is_inprocess

    if is_inprocess(pilot):
        return
    try:
        argv = shlex.split(pilot)
    except ValueError as exc:
        raise ValueError(f"pilot command {pilot!r}: {exc}") from None
    if not argv:
        raise ValueError("--pilot is empty")
    prog = argv[0]
    if "{" in prog:
        return
    if shutil.which(prog) is None:
        where = "not an executable file" if os.sep in prog else "not found on PATH"
        raise ValueError(
            f"pilot {pilot!r}: program {prog!r} {where} (built-in pilots: {', '.join(sorted(BUILTIN_PILOTS))}; "
            'a Python class: package.module:Class; a script: "{python} path/to/script.py {mavsdk_url}")'
        )


# the highest --speed at which an external pilot's own wall-clock timers are known not to trip PX4's failsafes:
# mission_scripts/mavsdk_precision_land.py lands at 8x in lockstep and ends pilot_error ("Data link regained ...
# Failsafe activated") in 5 of 24 trials at 16x and 32x (bench/results_trials.md §7): MAVSDK heartbeats once per
# wall second against COM_DL_LOSS_T = 10 sim s
WALL_TIMER_SAFE_SPEED = 8.0


def fast_external_note(pilot: str, speed: float) -> str | None:
    """The line `trials run` prints when an external pilot flies faster than WALL_TIMER_SAFE_SPEED (None: none)."""
    from viva_sitl.evaluation.pilots import is_inprocess

    if is_inprocess(pilot) or speed <= WALL_TIMER_SAFE_SPEED:
        return None
    return (
        f"note: --speed {speed:g} with an external pilot: its own wall-clock timers see {speed:g}x time; MAVSDK "
        f"pilots (1 Hz heartbeat vs COM_DL_LOSS_T = 10 s, 20 Hz offboard re-send vs COM_OF_LOSS_T = 1 s) can trip "
        f'PX4\'s failsafes above {WALL_TIMER_SAFE_SPEED:g}x (README "Timing")'
    )


def _run(args: argparse.Namespace) -> int:
    from viva_sitl.evaluation.campaign import finished_trials, run_campaign
    from viva_sitl.evaluation.spec import load_spec
    from viva_sitl.footage import autocache

    spec = load_spec(args.spec)
    if args.frames:
        spec = dataclasses.replace(spec, frames=True)
    if args.speed is not None:
        if not (math.isfinite(args.speed) and args.speed > 0):
            raise ValueError(f"--speed must be a positive number, got {args.speed:g}")
        spec = dataclasses.replace(spec, speed=args.speed)
    if args.timing is not None:
        spec = dataclasses.replace(spec, timing=args.timing)
    if args.pilot_cpu_factor is not None:
        spec = dataclasses.replace(spec, pilot_cpu_factor=args.pilot_cpu_factor)
    if args.pilot_latency_ms is not None:
        spec = dataclasses.replace(spec, pilot_latency_ms=args.pilot_latency_ms)
    if args.no_ulog:
        spec = dataclasses.replace(spec, ulog=False)
    pilot = args.pilot or spec.pilot
    check_external_pilot(pilot)
    note = fast_external_note(pilot, spec.speed)
    if note is not None:
        print(f"viva-sitl trials: {note}", file=sys.stderr)
    if args.address is not None and args.backend != "ray":
        raise ValueError("--address is a Ray cluster's: give --backend ray too")
    safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in pilot.split("/")[-1])[:40]
    name = f"{spec.name}-{safe}" + ("-trial-" + "-".join(map(str, args.trial)) if args.trial else "")
    out = Path(args.out) if args.out else Path("trials-out") / name
    try:
        # run_campaign hands this process's automatic-cache policy to the trials' workers; the flags change it
        # for this campaign only (an in-process caller's own policy is restored after)
        with autocache.using_policy(
            autocache.from_flags(
                args.no_cache, args.cache_max_gb, args.tile_cache_dir, compact=args.cache_compact
            )
        ):
            camp = run_campaign(
                spec, pilot, out, n=args.n, seed=args.seed, jobs=args.jobs, backend=args.backend,
                address=args.address, resume=args.resume, force=args.force, only=args.trial, video=args.video,
                progress=not args.no_progress,
            )  # fmt: skip
    except KeyboardInterrupt:
        from viva_sitl.evaluation.report import read_results

        doc = read_results(out)
        print(f"\ninterrupted: {doc['trials_done']} of {doc['trials_total']} trials kept in {out}; "
              f"rerun with --resume to complete the rest", file=sys.stderr)  # fmt: skip
        return 130
    from viva_sitl.evaluation.report import read_results

    _print_summary(read_results(out))
    print(f"  report: {out / 'report.html'}  results: {out / 'results.csv'}, {out / 'results.json'}")
    _say_if_no_figures("  ")
    ran = {s.index for s in camp.scenarios}
    beyond = [k for k in finished_trials(out) if k not in ran]
    if beyond:  # e.g. --resume --trial 2 in a run of 4: the others' results stay on disk, outside this report
        print(f"  note: {len(beyond)} finished trial(s) not in this run's scenarios ({_span(beyond)}) stay in "
              f"{out / 'trials'}; not in this report")  # fmt: skip
    infra = camp.infra_errors()
    if infra:  # the harness failed: not a result of the pilot, so not a success of the run
        first = infra[0]  # what failed (e.g. a Ray worker that cannot import the pilot), not only how many
        print(f"  first harness error: trial {first['trial']}: {first['end']}: {first.get('end_detail') or '?'}",
              file=sys.stderr)  # fmt: skip
        return 3
    return 0 if camp.complete else 1


def _span(indices: list[int]) -> str:
    """'trial 3', 'trials 2-3' (contiguous), 'trials 2, 5, 9' or 'trials 2, 5, 9, ...' (sorted indices)."""
    if len(indices) == 1:
        return f"trial {indices[0]}"
    if indices[-1] - indices[0] == len(indices) - 1:
        return f"trials {indices[0]}-{indices[-1]}"
    return "trials " + ", ".join(map(str, indices[:3])) + (", ..." if len(indices) > 3 else "")


def _fly(args: argparse.Namespace) -> int:
    from viva_sitl.evaluation.campaign import refuse_other_run
    from viva_sitl.evaluation.human import fly_trial
    from viva_sitl.evaluation.spec import load_spec

    spec = load_spec(args.spec)
    # the spec as drawn from: results.json's spec.n / spec.seed say what --n / --seed chose
    spec = dataclasses.replace(spec, n=spec.n if args.n is None else args.n,
                               seed=spec.seed if args.seed is None else args.seed)  # fmt: skip
    safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in args.name)[:40]
    out = Path(args.out) if args.out else Path("trials-out") / f"{spec.name}-{safe}-trial-{args.trial}"
    refuse_other_run(out, spec.name, args.name)
    try:
        row = fly_trial(
            spec, args.trial, out, speed=args.speed, pilot=args.name,
            dashboard_port=args.dashboard_port, api_port=args.api_port, gcs_port=args.gcs_port,
            video_port=args.video_port, say=lambda line: print(line, flush=True),
        )  # fmt: skip
    except KeyboardInterrupt:  # outside the flight itself (drawing the scenario, writing the report)
        print(f"\ninterrupted: what was written is in {out}", file=sys.stderr)
        return 130
    td = (f"touchdown N{row['touchdown_north_m']:.1f} E{row['touchdown_east_m']:.1f} at "
          f"{row['touchdown_speed_m_s']:.2f} m/s" if row["touchdown_north_m"] is not None else "no touchdown")  # fmt: skip
    print(f"trial {row['trial']} [{args.name}]: {row['end']} ({row['end_detail']}); {td}; success {row['success']}"
          f"{' (' + row['criterion_failures'] + ')' if row['criterion_failures'] else ''}", flush=True)  # fmt: skip
    tdir = out / "trials" / f"{row['trial']:04d}"
    print(
        f"  results: {out / 'results.json'}, {out / 'results.csv'}  replay: viva-sitl replay {tdir}",
        flush=True,
    )
    _say_if_no_figures("  ")
    return 130 if row["end"] == TrialEnd.ABORTED else 0


def _mismatch_gate(docs: list[tuple[str, dict[str, Any]]], base: int, allow: bool) -> list[str] | None:
    """The differences in conditions between each run and the baseline run, one line each; None = refused
    (printed on stderr, one line per difference), [] = comparable."""
    from viva_sitl.evaluation.compare import run_mismatches

    base_dir, base_doc = docs[base]
    diffs: list[str] = []
    for i, (d, doc) in enumerate(docs):
        if i != base:
            diffs += [f"{base_dir} vs {d}: {line}" for line in run_mismatches(base_doc, doc, base_dir, d)]
    if diffs and not allow:
        print("viva-sitl trials: compare refused: the runs were not made under the same conditions "
              "(--allow-mismatch compares them anyway):", file=sys.stderr)  # fmt: skip
        for line in diffs:
            print(f"  differs: {line}", file=sys.stderr)
        return None
    for line in diffs:
        print(f"WARNING: not the same conditions: {line}")
    return diffs


def _compare(args: argparse.Namespace) -> int:
    from viva_sitl.evaluation.report import compare_docs, read_results

    if len(args.runs) < 2:
        raise ValueError("compare needs at least two OUT_DIRs")
    if args.baseline is not None or len(args.runs) > 2:
        return _leaderboard(args)
    args.a, args.b = args.runs
    a, b = read_results(args.a), read_results(args.b)
    diffs = _mismatch_gate([(args.a, a), (args.b, b)], 0, args.allow_mismatch)
    if diffs is None:
        return 2
    res = compare_docs(a, b)
    res["mismatches"] = diffs
    if not res["pairs"]:
        raise ValueError(
            f"{args.a} and {args.b} have no trial in common (pairs match on trial index and scenario seed): "
            "run both pilots on the same spec with the same --seed"
        )
    if args.out:
        Path(args.out).write_text(json.dumps(res, indent=1))
    if args.html:
        from viva_sitl.evaluation.report import render_compare_html

        Path(args.html).write_text(render_compare_html(res, args.a, args.b))
    s = res["success"]
    print(f"A = {res['a']['pilot']} ({args.a}), B = {res['b']['pilot']} ({args.b}): {res['pairs']} paired trials, "
          f"same scenarios: {res['same_scenarios']}")  # fmt: skip
    if res["unmatched_a"] or res["unmatched_b"]:
        print(f"  unpaired: {res['unmatched_a']} trials only in A, {res['unmatched_b']} only in B (left out)")
    if not res["same_scenarios"]:
        print(
            "  WARNING: the runs were drawn from different scenarios: pairs match by trial index and seed only"
        )
    if s["judged_pairs"]:
        print(f"  success A {100 * s['rate_a']:.1f} %  B {100 * s['rate_b']:.1f} %  (B - A {100 * s['diff_b_minus_a']:+.1f} "
              f"points, 95 % CI {100 * s['diff_ci95'][0]:+.1f}..{100 * s['diff_ci95'][1]:+.1f}); both {s['both']}, "
              f"only A {s['only_a']}, only B {s['only_b']}, neither {s['neither']}; McNemar p = {s['mcnemar_p']}")  # fmt: skip
    else:
        print("  success: unavailable (no ground truth)")
    for key, d in res["scores"].items():
        if d["pairs"] and d.get("ordinal"):  # risk level: levels, never a mean difference
            print(f"  {key:32s} B lower in {d['b_lower']}, same {d['same']}, higher {d['b_higher']} of {d['pairs']} "
                  f"pairs (median A {d['median_a']}, B {d['median_b']}; sign test p = {d['sign_test_p']})")  # fmt: skip
        elif d["pairs"]:
            print(f"  {key:32s} A {d['mean_a']:>9} B {d['mean_b']:>9}  B-A {d['mean_diff_b_minus_a']:>9} "
                  f"(95 % CI {d['diff_ci95'][0]}..{d['diff_ci95'][1]}), {d['pairs']} pairs")  # fmt: skip
        else:
            print(f"  {key:32s} unavailable (no pair has it on both sides)")
    if args.html:
        print(f"  page: {args.html}")
    return 0


def _leaderboard(args: argparse.Namespace) -> int:
    """Three or more runs (or --baseline): every run paired with the baseline, ranked, written as a page."""
    from viva_sitl.evaluation.compare import leaderboard, render_leaderboard_html
    from viva_sitl.evaluation.report import read_results

    dirs = [str(_run_dir(p)) for p in args.runs]
    if len(set(dirs)) != len(dirs):
        raise ValueError("the same OUT_DIR is given twice")
    base = str(_run_dir(args.baseline)) if args.baseline is not None else dirs[0]
    if base not in dirs:
        dirs.insert(0, base)  # --baseline B A C: B joins the runs
    docs = [(d, read_results(d)) for d in dirs]
    diffs = _mismatch_gate(docs, dirs.index(base), args.allow_mismatch)
    if diffs is None:
        return 2
    board = leaderboard(docs, dirs.index(base))
    if not board["shared_trials"]:
        raise ValueError("the runs have no trial in common with each other (pairs match on trial index and "
                         "scenario seed): run every pilot on the same spec with the same --seed")  # fmt: skip
    board["mismatches"] = diffs
    page = Path(args.html or "leaderboard.html")
    page.write_text(render_leaderboard_html(board, dict(docs), diffs))
    if args.out:
        Path(args.out).write_text(json.dumps(board, indent=1))
    print(f"leaderboard against {board['baseline_pilot']} ({base}): {board['shared_trials']} shared scenarios, "
          f"same scenarios: {board['same_scenarios']}; p-values Holm-adjusted over {len(dirs) - 1} comparisons")  # fmt: skip
    for e in board["runs"]:
        rate = "unavailable" if e["rate"] is None else f"{100 * e['rate']:5.1f} %"
        v = e.get("vs_baseline")
        vs = ("baseline" if v is None else f"vs baseline {v['wins']} W / {v['losses']} L / {v['ties']} ties, "
              f"McNemar p {v['mcnemar_p']}, Holm p {v['holm_p']}")  # fmt: skip
        print(f"  {e['rank']}. {e['pilot'][:40]:40s} success {e['success']}/{e['judged']} {rate}  {vs}")
    print(f"  page: {page}")
    return 0


def _suite(args: argparse.Namespace) -> int:
    from viva_sitl.evaluation import suites

    if args.suite_cmd == "list":
        for name in suites.suite_names():
            su = suites.load_suite(name)
            parts = []
            for split, spec in su.splits.items():
                frozen = str(su.frozen.get(split, {}).get("sha256", "?"))[:12]
                parts.append(f"{split}: {spec.n} trials over {', '.join(spec.footage)} (sha256 {frozen})")
            try:
                for spec in su.splits.values():
                    for f in spec.footage:
                        suites.footage_hash(f)
                here = "available"
            except Exception as exc:  # noqa: BLE001 - a footage that is not on this machine
                here = f"unavailable here ({str(exc).splitlines()[0][:80]})"
            print(f"{su.id}  {su.title}; {'; '.join(parts)}; {here}")
        return 0
    if args.suite_cmd == "hash":
        su = suites.load_suite(args.suite)
        for split, spec in su.splits.items():
            h = suites.split_hashes(spec)
            foot = ", ".join(f'"{k}" = "{v}"' for k, v in h["footage"].items())
            print(f'[frozen.{split}]\nsha256 = "{h["sha256"]}"\nscenarios = "{h["scenarios"]}"\n'
                  f'scoring = "{h["scoring"]}"\nfootage = {{ {foot} }}')  # fmt: skip
        return 0
    if args.suite_cmd == "run":
        su = suites.load_suite(args.suite)
        check_external_pilot(args.pilot)
        out = Path(args.out)
        splits = suites.SPLITS if args.split == "all" else (args.split,)
        rec = suites.run_suite(su, args.pilot, out, splits=splits, jobs=args.jobs, limit=args.limit,
                               resume=args.resume, force=args.force, progress=not args.no_progress)  # fmt: skip
        print(f"{rec['suite']} (sha256 {rec['suite_sha256'][:16]}) [{args.pilot}]: {out / 'suite.json'}; "
              f"the card: viva-sitl trials suite card {out}")  # fmt: skip
        return 0
    c = suites.card(Path(args.out))
    for split, s in c["splits"].items():
        sr, sg = s["success"], s["safety_gain_vs_descend"]
        rate = "n/a" if sr["rate"] is None else f"{100 * sr['rate']:.1f} %"
        gain = "n/a" if sg["value"] is None else f"{sg['value']:+.2f}"
        print(f"{c['suite']} {split} [{c['pilot']}]: success {sr['k']}/{sr['judged']} = {rate}, safety gain over "
              f"descend {gain}{' (PARTIAL: not citable)' if c['partial'] else ''}")  # fmt: skip
    print(f"  card: {Path(args.out) / 'card.md'}, {Path(args.out) / 'card.json'}")
    return 0


def _run_dir(path: str) -> Path:
    """OUT_DIR from OUT_DIR or its results.json (read_results takes both)."""
    p = Path(path)
    return p.parent if p.name == "results.json" and not p.is_dir() else p


def _report(args: argparse.Namespace) -> int:
    from viva_sitl.evaluation.report import read_results, render_html

    out = _run_dir(args.out)
    doc = read_results(out)
    tmp = out / "report.html.tmp"
    tmp.write_text(render_html(doc, out))
    tmp.replace(out / "report.html")
    print(f"report: {out / 'report.html'} ({doc['trials_done']} of {doc['trials_total']} trials)")
    _say_if_no_figures("")
    return 0


def _say_if_no_figures(indent: str) -> None:
    from viva_sitl.evaluation.report import figures_missing_note

    note = figures_missing_note()
    if note:
        print(indent + note)


def _show(args: argparse.Namespace) -> int:
    from viva_sitl.evaluation.report import read_results

    doc = read_results(args.out)
    if args.trial is None:
        _print_summary(doc)
        return 0
    rows = {r["trial"]: r for r in doc["rows"]}
    if args.trial not in rows:
        raise ValueError(f"trial {args.trial} is not in {args.out} (done: {sorted(rows)[:20]}...)")
    print(json.dumps(rows[args.trial], indent=1))
    ev = _run_dir(args.out) / "trials" / f"{args.trial:04d}" / "events.jsonl"
    if ev.exists():
        for line in ev.read_text().splitlines():
            e = json.loads(line)
            print(f"  t={e['t_s']:8.3f}  {e['kind']:10s} {e['text']}")
    return 0
