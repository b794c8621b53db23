"""Time the REFERENCE implementation (viva-safeland 0.2.0 or 0.2.5, `viva.DroneEnv`) stepping in rgb_array mode.

Runs under the reference's own interpreter (Python >= 3.12), e.g.:

    /work/venv312/bin/python bench/reference/run_reference.py --video /tmp/viva-sitl-bench/interchange_4k.mp4

One "step" is `env.step(actions)`: read the next footage frame (cv2.VideoCapture, one frame per step),
copy it (0.2.0; 0.2.5 no longer copies), one Verlet step of the paper's model at dt = 1/render_fps, warpPerspective
of the full 4K frame to the drone view. `--with-render` also calls `env.render()` (the 1280x720 composite of the
rgb_array mode). 0.2.5 runs with its DroneEnv defaults (hover_z, hover_xy, perspective camera); everything here
drives both versions the same, except `quality`'s camera call (0.2.5: get_drone_view(frame, state, roll, pitch, yaw)).

Output: one JSON object on stdout. With `--serve`, the script reads commands from stdin instead, one per line
("run" -> time one run and print one JSON line; "quit"), so a driver can interleave it with another
implementation (A B A B ...) without paying the interpreter start-up per run.
"""

from __future__ import annotations

import argparse
import contextlib
import inspect
import io
import json
import math
import statistics
import sys
import time
from typing import Any

import cv2
import numpy as np

with contextlib.redirect_stdout(io.StringIO()):  # pygame prints a banner on import; keep stdout pure JSON
    import viva
    from viva import DroneEnv

try:
    from importlib.metadata import version as _pkg_version

    REF_VERSION = _pkg_version("viva-safeland")
except Exception:  # pragma: no cover - metadata missing
    REF_VERSION = "unknown"


def parse_size(text: str) -> tuple[int, int] | None:
    if text == "native":
        return None
    w, h = text.lower().split("x")
    return int(w), int(h)


def make_env(args: argparse.Namespace) -> DroneEnv:
    with contextlib.redirect_stdout(sys.stderr):  # its resolution/altitude warnings go to stderr
        env = DroneEnv(
            render_mode="rgb_array",
            video=args.video,
            render_fps=args.fps,
            terminated_step=10**9,
            fixed=args.fixed,
            rel_alt_value=args.rel_alt,
        )
    size = parse_size(args.out_size)
    if size is not None:
        # DroneEnv hard-codes a 480x288 drone view (env.py:46); the Camera reads `output` at every step
        # (simulator.py:121,187), so setting it gives the same VAC size as ours without touching its code.
        env.drone_view_size = np.array(size)
        env.simulator.camera.output = np.array(size, dtype=np.int32)
    return env


def reset(env: DroneEnv, args: argparse.Namespace) -> np.ndarray:
    with contextlib.redirect_stdout(sys.stderr):
        obs, _info = env.reset(x=0.0, y=0.0, z=args.z, psi_deg_init=args.psi_deg)
    return obs


def one_run(env: DroneEnv, args: argparse.Namespace) -> dict[str, Any]:
    """Reset (untimed), then time `args.steps` env.step calls with a fixed hover action."""
    reset(env, args)
    action = [0.0, 0.0, 0.0, 0.0]  # normalised (roll, pitch, yaw rate, thrust offset): exact hover
    terminated_any = False
    c0 = time.process_time()  # CPU time of all threads: less sensitive to other load on a shared machine
    t0 = time.perf_counter()
    for _ in range(args.steps):
        # env.step scales the array in place (env.py:253-255): hand it a fresh one each step
        obs, terminated, _info = env.step(np.array(action, dtype=np.float64))
        terminated_any |= bool(terminated)
        if args.with_render:
            env.render()
    dt = time.perf_counter() - t0
    cpu = time.process_time() - c0
    z = env.simulator.drone.state[0].pos.z
    return {
        "steps": args.steps,
        "seconds": dt,
        "steps_per_s": args.steps / dt,
        "ms_per_step": 1e3 * dt / args.steps,
        "cpu_ms_per_step": 1e3 * cpu / args.steps,
        "obs_shape": list(obs.shape),
        "final_z_m": z,
        "terminated": terminated_any,
    }


def breakdown(env: DroneEnv, args: argparse.Namespace) -> dict[str, float]:
    """ms per step spent in frame read, physics and warp, by wrapping the reference's own methods."""
    acc = {"read_frame_ms": 0.0, "physics_ms": 0.0, "warp_ms": 0.0}
    orig_update = env._update_frame
    orig_move = env.simulator.drone.move
    orig_view = env.simulator.camera.get_drone_view

    def timed(fn: Any, key: str) -> Any:
        def wrapper(*a: Any, **k: Any) -> Any:
            t = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                acc[key] += 1e3 * (time.perf_counter() - t)

        return wrapper

    env._update_frame = timed(orig_update, "read_frame_ms")
    env.simulator.drone.move = timed(orig_move, "physics_ms")
    env.simulator.camera.get_drone_view = timed(orig_view, "warp_ms")
    try:
        reset(env, args)
        for k in acc:
            acc[k] = 0.0
        t0 = time.perf_counter()
        for _ in range(args.steps):
            env.step(np.zeros(4))
        total = 1e3 * (time.perf_counter() - t0)
    finally:
        del env._update_frame, env.simulator.drone.move, env.simulator.camera.get_drone_view
    out = {k: v / args.steps for k, v in acc.items()}
    out["total_ms"] = total / args.steps
    out["other_ms"] = (
        out["total_ms"] - sum(acc.values()) / args.steps
    )  # frame.copy(), action scaling, info dict
    return out


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(255.0**2 / mse)


def quality(env: DroneEnv, args: argparse.Namespace, z_m: float) -> dict[str, float]:
    """PSNR of the reference's view (yaw 0, frame 0) vs an area-averaged (supersampled) rendering of the same
    homography: its aliasing error alone (the geometry is the reference's own)."""
    saved = args.z, args.psi_deg
    args.z, args.psi_deg = z_m, 0.0  # yaw 0: the view is an axis-aligned part of the footage, fully inside it
    try:
        obs = reset(env, args)  # reset renders the view at the reset pose from the first footage frame
    finally:
        args.z, args.psi_deg = saved
    frame = env.frame
    cam = env.simulator.camera
    state = env.simulator.drone.state[0]
    if "pitch" in inspect.signature(cam.get_drone_view).parameters:  # 0.2.5: (frame, state, roll, pitch, yaw)
        d = env.simulator.drone
        _view, pts = cam.get_drone_view(frame, state, d.roll_deg, d.pitch_deg, d.psi_deg)
    else:  # 0.2.0: (frame, state, yaw) with the yaw negated
        _view, pts = cam.get_drone_view(frame, state, -env.simulator.drone.psi_deg)
    w, h = (int(v) for v in cam.output)
    dst = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], np.float32)
    m = cv2.getPerspectiveTransform(pts.astype(np.float32), dst)
    k = args.supersample
    # big pixel b <-> small pixel j with b = k j + (k-1)/2, so area-averaging k x k blocks lands on j's centre
    t = np.array([[k, 0, (k - 1) / 2], [0, k, (k - 1) / 2], [0, 0, 1]], np.float64)
    big = cv2.warpPerspective(frame, t @ m, (w * k, h * k), flags=cv2.INTER_LINEAR, borderValue=(255, 0, 0))
    truth = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
    roi_w = float(np.linalg.norm(pts[1] - pts[0]))
    return {
        "z_m": z_m,
        "footage_px_per_output_px": roi_w / w,
        "psnr_db": psnr(obs, truth),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--video", required=True, help="footage path (a sidecar <stem>.SRT gives rel_alt)")
    ap.add_argument("--rel-alt", type=float, default=None, help="recording altitude (default: from the .SRT)")
    ap.add_argument("--fps", type=int, default=30, help="DroneEnv render_fps (its dt = 1/fps)")
    ap.add_argument("--z", type=float, default=50.0, help="drone altitude at reset, m")
    ap.add_argument("--psi-deg", type=float, default=30.0, help="yaw at reset, deg (reference convention)")
    ap.add_argument("--out-size", default="640x480", help="drone view WxH, or 'native' (480x288)")
    ap.add_argument("--steps", type=int, default=120, help="steps per timed run")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=1, help="untimed runs first")
    ap.add_argument(
        "--fixed", action="store_true", help="DroneEnv(fixed=True): the video's first frame as a still"
    )
    ap.add_argument("--with-render", action="store_true", help="also call env.render() each step")
    ap.add_argument("--breakdown", action="store_true", help="add a per-phase breakdown run")
    ap.add_argument("--quality-z", type=float, nargs="*", default=[], help="altitudes for the PSNR check")
    ap.add_argument("--supersample", type=int, default=8)
    ap.add_argument("--serve", action="store_true", help="read 'run'/'quit' lines on stdin")
    args = ap.parse_args()

    env = make_env(args)
    info = {
        "impl": "viva-safeland",
        "version": REF_VERSION,
        "module": viva.__file__,
        "python": sys.version.split()[0],
        "opencv": cv2.__version__,
        "cv2_threads": cv2.getNumThreads(),
        "rel_alt_m": env.height,
        "out_size": [int(v) for v in env.simulator.camera.output],
        "dt_s": env.simulator.drone.dt,
        "z_m": args.z,
        "steps": args.steps,
        "with_render": args.with_render,
        "fixed": args.fixed,
    }
    for _ in range(args.warmup):
        one_run(env, args)

    if args.serve:
        print(json.dumps({"ready": True, **info}), flush=True)
        for line in sys.stdin:
            cmd = line.strip()
            if cmd == "run":
                print(json.dumps(one_run(env, args)), flush=True)
            elif cmd == "breakdown":
                print(json.dumps(breakdown(env, args)), flush=True)
            elif cmd.startswith("quality"):
                zs = [float(v) for v in cmd.split()[1:]]
                print(json.dumps([quality(env, args, z) for z in zs]), flush=True)
            elif cmd in ("quit", ""):
                break
            else:
                print(json.dumps({"error": f"unknown command {cmd!r}"}), flush=True)
        return 0

    runs = [one_run(env, args) for _ in range(args.runs)]
    sps = [r["steps_per_s"] for r in runs]
    result: dict[str, Any] = {
        **info,
        "runs": runs,
        "median_steps_per_s": statistics.median(sps),
        "median_ms_per_step": 1e3 / statistics.median(sps),
        "median_cpu_ms_per_step": statistics.median(r["cpu_ms_per_step"] for r in runs),
    }
    if args.breakdown:
        result["breakdown"] = breakdown(env, args)
    if args.quality_z:
        result["quality"] = [quality(env, args, z) for z in args.quality_z]
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # Ctrl-C reaches the served process too: its parent bench says "interrupted"
        sys.exit(130)
