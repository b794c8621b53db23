"""`viva-sitl` command line: run the SITL, render one VAC frame, manage footage."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import sys
from pathlib import Path

from viva_sitl import __version__
from viva_sitl.cliargs import (
    OneLineErrors,
    add_cache_args,
    add_timing_flags,
    hfov,
    home,
    port,
    pose,
    positive_float,
)


def _footage_scale_flags(p: argparse.ArgumentParser) -> None:
    """--footage-alt/--footage-hfov/--footage-gsd: the footage's recording scale, beating its metadata files."""
    p.add_argument(
        "--footage-alt", type=positive_float, metavar="M", help="recording altitude of the footage (m)"
    )
    p.add_argument(
        "--footage-hfov", type=hfov, metavar="DEG", help="recording horizontal FoV of the footage (deg)"
    )
    p.add_argument(
        "--footage-gsd", type=positive_float, metavar="M_PER_PX", help="ground sample distance of the footage"
    )


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrors(
        prog="viva-sitl",
        description="A PX4-compatible MAVLink SITL whose vehicle flies inside real nadir drone footage.",
    )
    parser.add_argument("--version", action="version", version=f"viva-sitl {__version__}")
    parser.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser(
        "run", help="run the simulation as a MAVLink endpoint (PX4 SITL ports) with video out"
    )
    run.add_argument(
        "--footage", help="catalog name (synthetic, interchange, songdo-00003, ...) or a video/image path"
    )
    run.add_argument("--config", help="TOML config file (see configs/default.toml)")
    run.add_argument(
        "--home", type=home, metavar="LAT,LON[,ALT]",
        help="place the footage centre (the NED origin) here, as PX4_HOME_LAT/LON/ALT (default: PX4_HOME_* if "
        "set, else the footage's geo-reference, else PX4's 47.397742,8.545594,488)",
    )  # fmt: skip
    _footage_scale_flags(run)
    run.add_argument(
        "--speed",
        type=positive_float,
        help="sim seconds per wall second (default 1); MAVLink rates and timers are per sim second, as PX4 lockstep",
    )
    add_timing_flags(run, "[sim] timing")
    run.add_argument(
        "--pilot-pid", type=int, metavar="PID",
        help="lockstep/charged: watch this process's group as the pilot (default: the owner of the local UDP port "
        "the first MAVLink message came from)",
    )  # fmt: skip
    run.add_argument("--seed", type=int, help="random seed (disturbances, sensor noise)")
    run.add_argument("--duration", type=positive_float, help="stop after this many wall-clock seconds")
    run.add_argument(
        "--instance",
        type=int,
        help="vehicle N (0..200), as PX4 SITL -i N: sysid 1+N, API ports 14540+N (remote) and 14580+N (local), "
        "GCS local port 18570+N (the GCS remote stays 14550), RTP video 5600+4N, frame socket 5700+N",
    )
    run.add_argument("--listen", help="address to bind (default 127.0.0.1)")
    run.add_argument("--api-port", type=port, help="remote API/offboard port (default 14540+instance)")
    run.add_argument("--gcs-port", type=port, help="remote ground-station port (default 14550)")
    run.add_argument(
        "--api-local-port", type=port, help="local port of the API link (default 14580+instance)"
    )
    run.add_argument(
        "--gcs-local-port", type=port, help="local port of the GCS link (default 18570+instance)"
    )
    run.add_argument(
        "--video-port",
        type=port,
        help="UDP port the H.264 RTP stream goes to (RTCP on port+1; default 5600+4*instance, used as given)",
    )
    run.add_argument(
        "--mjpeg-port", type=port, help="also stream MJPEG over RTP to this UDP port (used as given)"
    )
    run.add_argument(
        "--frame-socket",
        help="ZeroMQ endpoint of the frame-and-pose socket (default tcp://127.0.0.1:5700+instance)",
    )
    run.add_argument(
        "--rtsp",
        nargs="?",
        const=-1,
        type=port,
        metavar="PORT",
        help="also serve the VAC over RTSP at rtsp://127.0.0.1:PORT/vac (the H.264 stream's encode, shared; "
        "default port 8554+instance; binds [video] rtsp_host)",
    )
    run.add_argument("--record", help="record the VAC stream to this video file")
    run.add_argument(
        "--no-video",
        action="store_true",
        help="no rendering, no video outputs and no camera component (MAVLink autopilot only)",
    )
    run.add_argument(
        "--run-dir",
        help="where run.json, trajectory.csv, telemetry.tlog, the SDP files and captures go "
        "(default ./runs/<YYYYmmdd-HHMMSS>; `viva-sitl replay RUN_DIR` opens it)",
    )
    tlog = run.add_mutually_exclusive_group()
    tlog.add_argument(
        "--tlog",
        metavar="PATH",
        help="record every MAVLink packet sent and received to this .tlog (default: <run-dir>/telemetry.tlog)",
    )
    tlog.add_argument("--no-tlog", action="store_true", help="do not record a .tlog")
    run.add_argument(
        "--signing-key",
        metavar="KEY",
        help="MAVLink 2 signing key (64 hex digits, or a passphrase: its SHA-256): outgoing messages are signed "
        "and unsigned ones rejected, as PX4 with MAV_SIGN_CFG=1 (a GCS may also set the key with SETUP_SIGNING)",
    )
    run.add_argument(
        "--dashboard-port",
        type=port,
        help="web dashboard port (default 8080+instance; when busy a free port is used; 0 = any free port)",
    )
    run.add_argument("--no-dashboard", action="store_true", help="do not serve the web dashboard")

    add_cache_args(run)
    replay = sub.add_parser(
        "replay",
        help="replay a recorded run (trajectory.csv, telemetry.tlog or a trial's trial_trajectory.csv) in the web "
        "dashboard",
    )
    replay.add_argument(
        "run_dir", metavar="RUN_DIR",
        help="the run directory of a `viva-sitl run` (--run-dir), or a trial folder of `viva-sitl trials run` "
        "(OUT/trials/NNNN)",
    )  # fmt: skip
    replay.add_argument("--footage", help="footage to replay over (default: the one run.json names)")
    replay.add_argument("--listen", help="address to bind (default 127.0.0.1)")
    replay.add_argument(
        "--dashboard-port", type=port, help="dashboard port (default 8080; when busy a free port is used)"
    )
    replay.add_argument(
        "--duration", type=positive_float, help="stop serving after this many wall-clock seconds"
    )
    run.add_argument(
        "--scenario",
        help="a landing trial's scenario file (written by `viva-sitl trials run`): start pose, footage and its "
        "start time, parameters, event schedule; the run ends when the trial does and writes its logs to --run-dir",
    )

    render = sub.add_parser("render", help="render one VAC frame at a pose")
    render.add_argument("--footage", help="catalog name or path (default: synthetic)")
    render.add_argument("--config", help="TOML config file")
    render.add_argument(
        "--pose", type=pose, required=True, help="north,east,alt,roll,pitch,yaw (m above ground, deg)"
    )
    render.add_argument(
        "--time", type=float, default=0.0, help="simulation time in s (selects the footage frame)"
    )
    render.add_argument("-o", "--output", required=True, help="output image (png/jpg)")
    _footage_scale_flags(render)

    add_cache_args(render)
    footage = sub.add_parser(
        "footage",
        help="footage catalog and ground truth: list | info | get | ingest | show | annotate",
        add_help=False,
    )
    footage.add_argument("rest", nargs=argparse.REMAINDER)
    trials = sub.add_parser(
        "trials", help="landing trials: run | fly | compare | show | scenarios", add_help=False
    )
    trials.add_argument("rest", nargs=argparse.REMAINDER)
    # perception (issue 9): own parsers in viva_sitl/perception/cli.py, dispatched in main()
    sub.add_parser("dataset", help="labelled VAC datasets: export", add_help=False)
    sub.add_parser(
        "perception",
        help="train and evaluate perception models: train-sr | train-segmenter | train-detector | eval",
        add_help=False,
    )
    return parser


def _cmd_render(args: argparse.Namespace) -> int:
    import cv2

    from viva_sitl.config import SimConfig
    from viva_sitl.dynamics import EavState
    from viva_sitl.sim import Simulator

    out = Path(args.output)
    if not cv2.haveImageWriter(str(out)):  # before rendering (cv2.imwrite would raise on it afterwards)
        what = f"extension {out.suffix!r}" if out.suffix else "a name without an extension"
        print(f"viva-sitl render: cannot write {out}: no image format for {what} (use .png or .jpg)",
              file=sys.stderr)  # fmt: skip
        return 2
    cfg = SimConfig.load(args.config)
    scale = {"footage_alt_m": args.footage_alt, "footage_hfov_deg": args.footage_hfov,
             "footage_gsd_m_per_px": args.footage_gsd}  # fmt: skip
    cfg = dataclasses.replace(cfg, **{k: v for k, v in scale.items() if v is not None})
    north, east, alt, roll, pitch, yaw = args.pose
    with Simulator(cfg, footage=args.footage or cfg.footage) as sim:
        state = EavState.at_rest(
            (north, east, -alt), yaw_rad=math.radians(yaw), roll_rad=math.radians(roll),
            pitch_rad=math.radians(pitch), dt_s=sim.params.dt_s,
        )  # fmt: skip
        state = dataclasses.replace(state, time_s=args.time)
        frame = sim.render(state)
    try:
        ok = cv2.imwrite(str(out), frame.image_bgr)
    except cv2.error:
        ok = False
    if not ok:
        print(
            f"viva-sitl render: cannot write {out} (unknown extension or unwritable directory)",
            file=sys.stderr,
        )
        return 2
    m = frame.meta
    print(
        f"wrote {out} ({m.width_px}x{m.height_px}, footage frame {m.footage_frame_index}, coverage {m.coverage:.2f})"
    )
    return 0


def apply_tile_environment() -> None:
    """The process's tile settings from the documented $VIVA_SITL_TILE_CACHE_MB / $VIVA_SITL_TILE_DECODE_THREADS /
    $VIVA_SITL_TILE_READ_AHEAD, read here on the top floor (the footage layer reads no environment); a bad value is
    one FootageError line."""
    from viva_sitl.footage.tiles import TileSettings, set_process_settings

    set_process_settings(TileSettings.from_environ(os.environ))


def apply_cache_args(args: argparse.Namespace) -> None:
    from viva_sitl.footage.autocache import CachePolicy, from_flags, set_policy

    base = CachePolicy()  # a fresh process's defaults, changed by the flags
    set_policy(from_flags(args.no_cache, args.cache_max_gb, args.tile_cache_dir, base, args.cache_compact))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["footage"]:  # the catalog has its own parser (and its own --help)
        from viva_sitl.cli_footage import footage_main

        return footage_main(argv[1:])
    if argv[:1] == ["trials"]:  # landing trials have their own parser (viva_sitl/evaluation/cli.py)
        from viva_sitl.evaluation.cli import trials_main

        return trials_main(argv[1:])
    if argv[:1] in (["dataset"], ["perception"]):  # perception extra: own parsers (and --help)
        from viva_sitl.perception.cli import dataset_main, perception_main

        return (dataset_main if argv[0] == "dataset" else perception_main)(argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=args.log_level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from viva_sitl.config import ConfigError
    from viva_sitl.footage import FootageError

    try:
        from viva_sitl.dashboard.server import DashboardError
    except ImportError:  # aiohttp not installed: the dashboard is off, its error cannot happen

        class DashboardError(ValueError):  # type: ignore[no-redef]
            pass

    try:
        if args.command in ("render", "run", "replay"):
            apply_tile_environment()
        if args.command in ("render", "run"):
            apply_cache_args(args)
        if args.command == "render":
            return _cmd_render(args)
        if args.command == "footage":
            from viva_sitl.cli_footage import footage_main

            return footage_main(args.rest)
        if args.command == "run":
            from viva_sitl.app import run_from_args

            return run_from_args(args)
        if args.command == "replay":
            from viva_sitl.app import replay_from_args

            return replay_from_args(args)
    except (ConfigError, FootageError, DashboardError) as exc:
        print(f"viva-sitl: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    parser.error(f"unknown command {args.command}")
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
