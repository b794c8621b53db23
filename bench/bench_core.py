"""Steps per second of the headless API vs the reference implementation (viva-safeland 0.2.0), same run.

    /work/venv/bin/python bench/bench_core.py                       # defaults: 4K clip, 640x480 VAC, z = 50 m
    /work/venv/bin/python bench/bench_core.py --z 300 --rounds 5
    /work/venv/bin/python bench/bench_core.py --check-dynamics /tmp/golden.json

A "step" is what the reference's `DroneEnv.step` does: advance 1/30 s of physics, fetch the footage frame for
that time and render one 640x480 VAC frame. Ours is timed in several variants, so it is clear where time goes:

    ours_phys_250    physics only, 250 Hz EAV (8 or 9 EAV steps per 1/30 s)            vs ref (video)
    ours_phys_paper  physics only, EavParams.paper() (one 30 Hz step)                  vs ref (video)
    ours_decode_only no physics, no render: only decode the footage frame each step needs (the ceiling of a
                     full step over video: sim.footage.prefetch(index), i.e. PyAV decode, no conversion)
    ours_full_250    250 Hz physics + sim.render() (footage frame for the sim time + VAC)  vs ref (video)
    ours_full_paper  paper physics + sim.render()                                      vs ref (video)
    ours_full_250_plain / _paper_plain   as full_* with Simulator(region_render=False): the whole frame
                     converted to BGR and its pyramid built (the path before the region path)
    ours_full_250_prefetch / _paper_prefetch   as full_* with Simulator(prefetch=True)
    ours_ingest_250  as full_250 over our `footage ingest` copy (x264 tune=fastdecode)  vs ref (video)
    ours_ingest_levels_250  as ingest_250 over an ingest with a half-resolution copy, Simulator(footage_levels=True):
                     at pyramid level >= 1 it decodes the half-resolution video (NOT the same image: lossy copy)
    ours_still_250   as full_250 over frame 0 as a still image (no decode)             vs ref_still
    ours_still_paper as full_paper over the still                                      vs ref_still

In the *_250 variants one "step" (1/30 s) holds 8 or 9 physics steps and one render: that is what the API does
when a user steps 250 Hz physics and renders at the camera rate; the tables also give physics steps/s for them.

`ref` is DroneEnv over the 4K video (one decoded frame per step); `ref_still` is DroneEnv(fixed=True) over the
same video (its first frame, read once; 0.2.0 still copies the 4K frame every step, 0.2.5 no longer does).
`--ref-python-also PY ...`: further reference interpreters (e.g. viva-safeland 0.2.5 beside 0.2.0), timed in the same
rounds as `ref_<version>` / `ref_<version>_still` (version read from each interpreter); every ours-vs-reference ratio
(JSON `ratio_vs` / `cpu_ratio_vs`, stderr, markdown) is then given against each reference, labelled "vs <version>".

The reference runs in its own interpreter (Python >= 3.12, `--ref-python`) as a long-lived subprocess
(bench/reference/run_reference.py --serve), driven line by line, so rounds interleave A B A B ... and neither side
pays interpreter start-up inside a timed run. Footage: the shared 1080p interchange clip upscaled to 3840x2160
(libx264 ultrafast, `--frames` frames, into `--cache-dir`, with a DJI-style .SRT giving rel_alt for the reference
and a sibling .toml giving altitude and FoV for ours), generated once. Ours is `viva_sitl.sim.Simulator` with
`footage=PATH`. Wall time and CPU time (all threads) per step are both reported; `--report JSON` prints the tables.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

# first, as a user's program that imports it before cv2: its OpenCV settings (viva_sitl.opencv_pool) apply here
from viva_sitl import opencv_pool

# isort: split
import av
import cv2
import numpy as np
from numpy.typing import NDArray

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
SOURCE_CLIP = SHARED / "footage" / "interchange" / "interchange_1080p.mp4"
REF_SCRIPT = REPO / "bench" / "reference" / "run_reference.py"
DEFAULT_REF_PYTHON = "/work/venv312/bin/python"
# The reference cuts the .SRT path at the first "." of the whole path (viva/env.py:53), so the cache dir must not
# contain a dot (e.g. not ~/.cache); /tmp/viva-sitl-bench is fine.
DEFAULT_CACHE = Path("/tmp/viva-sitl-bench")
# Recording altitude that makes the interchange's 820 m ground width fit an 82.1 deg FoV (the reference's
# hard-coded FoV, and our CameraParams default): 820 / (2 tan 41.05 deg) = 471 m.
DEFAULT_REL_ALT_M = 471.0
DEFAULT_HFOV_DEG = 82.1
SONGDO_STILL = SHARED / "footage" / "songdo" / "00003.jpg"
SONGDO_REL_ALT_M = 3840 * 0.05 / (2.0 * math.tan(math.radians(DEFAULT_HFOV_DEG / 2.0)))  # ~0.05 m/px (README)


# ---------------------------------------------------------------------------------------------- footage


def size_arg(text: str) -> str:
    """argparse type of a view size "WxH" (each >= 8 px): the text itself, or argparse's one-line error."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be WxH, e.g. 640x480, got {text!r}") from None
    if w < 8 or h < 8:
        raise argparse.ArgumentTypeError(f"must be at least 8x8, got {text!r}")
    return text


def add_tile_cache_arg(ap: argparse.ArgumentParser) -> None:
    """`--tile-cache-mb` of the benches that fly over tile caches (see `apply_tile_cache`)."""
    ap.add_argument(
        "--tile-cache-mb", type=float, default=2.0,
        help="decoded-tile LRU in MiB ($VIVA_SITL_TILE_CACHE_MB, inherited by child processes; 256 = the library "
             "default). The bench clips are 30-60 frames and loop: a cap that holds a loop's tiles serves every "
             "later loop from memory, which footage longer than the cap never gets; 2 MiB (~10 tiles of 256 px) "
             "keeps no tile from one frame to the next, so every frame is decoded as over a real clip",
    )  # fmt: skip


def apply_tile_cache(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Check `--tile-cache-mb` (one argparse error line) and set it for this process and its children."""
    if not (math.isfinite(args.tile_cache_mb) and args.tile_cache_mb > 0):
        ap.error("--tile-cache-mb must be a number > 0")
    os.environ["VIVA_SITL_TILE_CACHE_MB"] = f"{args.tile_cache_mb:g}"
    apply_tile_environment()


def apply_tile_environment() -> None:
    """This process's tile settings from its $VIVA_SITL_TILE_* (the footage layer reads no environment: a bench is
    the top floor; its children read the variables themselves, a campaign's workers get them as an argument)."""
    from viva_sitl.footage.tiles import TileSettings, set_process_settings

    set_process_settings(TileSettings.from_environ(os.environ))


def make_clip(
    cache_dir: Path, frames: int, width: int = 3840, height: int = 2160, rel_alt_m: float = 471.0
) -> Path:
    """Upscale the first `frames` frames of the shared 1080p clip to width x height (x264 ultrafast), once."""
    if not SOURCE_CLIP.exists():
        raise SystemExit(f"shared footage missing: {SOURCE_CLIP}")
    cache_dir.mkdir(parents=True, exist_ok=True)
    stem = f"interchange_{width}x{height}_{frames}f"
    clip = cache_dir / f"{stem}.mp4"
    if not clip.exists():
        tmp = cache_dir / f"{stem}.part.mp4"
        t0 = time.perf_counter()
        with av.open(str(SOURCE_CLIP)) as ic, av.open(str(tmp), "w") as oc:
            src = ic.streams.video[0]
            rate = src.average_rate or 25
            st = oc.add_stream("libx264", rate=rate, options={"preset": "ultrafast", "crf": "23"})
            st.width, st.height, st.pix_fmt = width, height, "yuv420p"
            n = 0
            for frame in ic.decode(src):
                big = cv2.resize(
                    frame.to_ndarray(format="bgr24"), (width, height), interpolation=cv2.INTER_CUBIC
                )
                img: NDArray[np.uint8] = np.asarray(big, dtype=np.uint8)
                for pkt in st.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                    oc.mux(pkt)
                n += 1
                if n >= frames:
                    break
            for pkt in st.encode():
                oc.mux(pkt)
        tmp.replace(clip)
        print(f"# made {clip} ({n} frames, {time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    meta = clip.with_suffix(".toml")  # our footage metadata (sibling file); the reference ignores it
    if not meta.exists():
        meta.write_text(
            f'name = "{stem}"\nkind = "video"\npath = "{clip.name}"\nrecording_altitude_m = {rel_alt_m}\n'
            f'hfov_deg = {DEFAULT_HFOV_DEG}\nnotes = "bench: the shared interchange clip upscaled to 4K"\n',
            encoding="utf-8",
        )
    srt = clip.with_suffix(".SRT")
    if not srt.exists():
        # A DJI-style sidecar: the reference reads `rel_alt:` (viva/env.py:111), as does viva_sitl.footage.srt.
        lines = []
        for i in range(frames):
            a, b = i * 40, (i + 1) * 40
            lines.append(
                f"{i + 1}\n00:00:{a // 1000:02d},{a % 1000:03d} --> 00:00:{b // 1000:02d},{b % 1000:03d}\n"
                f'<font size="28">FrameCnt: {i + 1}, DiffTime: 40ms\n2026-11-22 06:00:00.000\n'
                f"[iso: 100] [shutter: 1/1000.0] [fnum: 1.7] [ev: 0] [focal_len: 24.00] "
                f"[latitude: 49.970247] [longitude: 36.307966] [rel_alt: {rel_alt_m:.3f} abs_alt: {rel_alt_m + 100:.3f}] "
                f"</font>\n"
            )
        srt.write_text("\n".join(lines), encoding="utf-8")
    return clip


def make_still(clip: Path, rel_alt_m: float) -> Path:
    """Frame 0 of the clip as a lossless PNG: the 'still' scenario (the reference's fixed=True reads the same frame)."""
    still = clip.with_name(clip.stem + "_frame0.png")
    if not still.exists():
        with av.open(str(clip)) as ic:
            frame = next(ic.decode(video=0)).to_ndarray(format="bgr24")
        tmp = still.with_name(still.stem + ".part.png")
        if not cv2.imwrite(str(tmp), frame, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
            raise SystemExit(f"cannot write {tmp}")
        tmp.replace(still)
    meta = still.with_suffix(
        ".toml"
    )  # our sibling metadata, so Simulator(footage=PATH) knows the ground scale
    if not meta.exists():
        meta.write_text(
            f'name = "{still.stem}"\nkind = "still"\npath = "{still.name}"\n'
            f"recording_altitude_m = {rel_alt_m}\nhfov_deg = {DEFAULT_HFOV_DEG}\n",
            encoding="utf-8",
        )
    return still


def make_ingest(clip: Path, levels: int = 1) -> Path:
    """Our `footage ingest` copy of the clip (x264 tune=fastdecode; full resolution, + half with levels=2), once."""
    from viva_sitl.footage.ingest import ingest

    dest = clip.with_name(clip.stem + ("_ingest" if levels == 1 else f"_ingest{levels}"))
    if not (dest / "footage.toml").exists():
        # the sibling <clip>.toml (make_clip) gives the ground scale that ingest writes into its footage.toml
        ingest(str(clip.with_suffix(".toml")), out_dir=dest, levels=levels, show_progress=False)
    return dest


# ---------------------------------------------------------------------------------------------- reference


class Reference:
    """run_reference.py --serve in the reference's interpreter; one timed run per `run()`."""

    def __init__(
        self,
        python: str,
        clip: Path,
        args: argparse.Namespace,
        fixed: bool = False,
        rel_alt_m: float | None = None,
    ) -> None:
        rel_alt = args.rel_alt if rel_alt_m is None else rel_alt_m
        cmd = [
            python, str(REF_SCRIPT), "--serve", "--video", str(clip), "--z", str(min(args.z, 0.9 * rel_alt)),
            "--psi-deg", str(args.yaw_deg), "--out-size", args.out_size, "--steps", str(args.steps),
            "--rel-alt", str(rel_alt), "--warmup", "1",
        ]  # fmt: skip
        if fixed:
            cmd.append("--fixed")
        # the reference as its users run it: OpenCV's defaults, not what viva_sitl set for this process
        self.proc = subprocess.Popen(
            cmd,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
            env=opencv_pool.user_environ(),
        )
        self.info = self._read()
        if not self.info.get("ready"):
            raise RuntimeError(f"reference did not start: {self.info}")

    def _read(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"reference process ended (rc={self.proc.poll()})")
        out: dict[str, Any] = json.loads(line)
        return out

    def ask(self, cmd: str) -> Any:
        assert self.proc.stdin is not None
        self.proc.stdin.write(cmd + "\n")
        self.proc.stdin.flush()
        return self._read()

    def run(self) -> tuple[float, float]:
        r = self.ask("run")
        return float(r["steps_per_s"]), float(r["cpu_ms_per_step"])

    def close(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            try:
                self.proc.stdin.write("quit\n")
                self.proc.stdin.flush()
                self.proc.wait(timeout=10)
            except (OSError, subprocess.TimeoutExpired):  # gone already (a Ctrl-C reached it too) or hung
                self.proc.kill()
                self.proc.wait()


def reference_label(version: str, taken: Any) -> str:
    """The "vs" label of a reference: its viva-safeland version, made unique among `taken` ("0.2.0#2", ...)."""
    label, n = version, 2
    while label in taken:
        label, n = f"{version}#{n}", n + 1
    return label


def viva_safeland_version(python: str) -> str | None:
    """The viva-safeland version installed in interpreter `python` (e.g. "0.2.5"); None when it is not."""
    probe = subprocess.run(
        [python, "-c", "import importlib.metadata as m; print(m.version('viva-safeland'))"],
        capture_output=True,
        text=True,
    )
    if probe.returncode != 0:
        return None
    return probe.stdout.strip() or None


def reference_available(python: str) -> str | None:
    """None when usable, else the reason to skip."""
    exe = shutil.which(python) if os.sep not in python else (python if os.path.exists(python) else None)
    if exe is None:
        return f"reference interpreter not found: {python} (create it: see bench/reference/NOTES.md)"
    if viva_safeland_version(python) is None:
        return f"viva-safeland is not installed in {python} (pip install viva-safeland==0.2.0)"
    return None


# ---------------------------------------------------------------------------------------------- ours


class Ours:
    """The headless API (viva_sitl.sim.Simulator), one comparable step = 1/30 s of physics (+ optional render)."""

    def __init__(
        self,
        clip: Path,
        args: argparse.Namespace,
        paper: bool,
        render: bool,
        region: bool = True,
        prefetch: bool = False,
        decode_only: bool = False,
        footage_levels: bool = False,
    ) -> None:
        from viva_sitl.camera import CameraParams
        from viva_sitl.config import SimConfig
        from viva_sitl.dynamics import EavCommand, EavParams
        from viva_sitl.sim import Simulator

        w, h = (int(v) for v in args.out_size.lower().split("x"))
        physics = EavParams.paper() if paper else EavParams()
        camera = CameraParams(width_px=w, height_px=h, hfov_deg=DEFAULT_HFOV_DEG)
        # footage by path, as the API contract says; the sibling .toml (make_clip/make_still) or the ingest folder's
        # footage.toml gives the recording altitude and FoV
        self.sim = Simulator(
            SimConfig(physics=physics, camera=camera),
            footage=str(clip),
            region_render=region,
            prefetch=prefetch,
            footage_levels=footage_levels,
        )
        self.decode_only = decode_only
        geom = self.sim.footage.geometry
        if (
            abs(geom.recording_altitude_m - args.rel_alt) > 1e-6
            or abs(geom.recording_hfov_deg - DEFAULT_HFOV_DEG) > 1e-6
        ):
            raise RuntimeError(f"footage metadata not picked up for {clip}: {geom}")
        self.cmd = EavCommand(0.0, 0.0, math.radians(-args.yaw_deg), physics.hover_thrust_n)
        self.render = render
        self.steps = args.steps
        self.z = args.z
        self.yaw_rad = math.radians(
            -args.yaw_deg
        )  # reference psi is CCW seen from above (z up); NED yaw is CW
        rate = 1.0 / physics.dt_s
        # EAV steps per reference step (1/30 s): 8 or 9 at 250 Hz so that k reference steps = round(k*250/30)
        self.schedule = [round((k + 1) * rate / 30.0) - round(k * rate / 30.0) for k in range(args.steps)]

    def run(self) -> tuple[float, float]:
        sim, cmd, schedule, render = self.sim, self.cmd, self.schedule, self.render
        sim.reset(seed=0, pos_ned_m=(0.0, 0.0, -self.z), yaw_rad=self.yaw_rad)
        if render:
            sim.render()  # as the reference's reset renders one view (untimed on both sides)
        if self.decode_only:
            return self._run_decode_only()
        c0 = time.process_time()
        t0 = time.perf_counter()
        for n in schedule:
            sim.step(cmd, n)
            if render:
                sim.render()
        dt = time.perf_counter() - t0
        cpu = time.process_time() - c0
        if abs(sim.state.altitude_m - self.z) > 1e-6:
            raise RuntimeError(f"hover drifted: altitude {sim.state.altitude_m} m")
        return self.steps / dt, 1e3 * cpu / self.steps

    def _run_decode_only(self) -> tuple[float, float]:
        """Decode (no conversion) the footage frame of each step's sim time: 1/30 s steps, as the full runs."""
        src = self.sim.footage
        prefetch = getattr(src, "prefetch", None)
        if prefetch is None:
            raise RuntimeError("decode_only needs a video footage")
        prefetch(0)
        c0 = time.process_time()
        t0 = time.perf_counter()
        for k in range(1, self.steps + 1):
            prefetch(src.frame_index_at(k / 30.0))
        dt = time.perf_counter() - t0
        cpu = time.process_time() - c0
        return self.steps / dt, 1e3 * cpu / self.steps

    def breakdown(self) -> dict[str, float]:
        """ms per step in physics (sim.step), footage decode (a video: `footage.prefetch(index)`, the decode alone;
        a still: nothing to do) and render (sim.render with the frame decoded: BGR conversion of the region the VAC
        reads, or of the whole frame with region_render=False, pyramid level, warp, metadata)."""
        sim, cmd = self.sim, self.cmd
        sim.reset(seed=0, pos_ned_m=(0.0, 0.0, -self.z), yaw_rad=self.yaw_rad)
        acc = {"physics_ms": 0.0, "decode_ms": 0.0, "render_ms": 0.0}
        fetches = 0
        last = -1
        pc = time.perf_counter
        prefetch = getattr(sim.footage, "prefetch", None)
        t_start = pc()
        for n in self.schedule:
            t0 = pc()
            sim.step(cmd, n)
            t1 = pc()
            acc["physics_ms"] += t1 - t0
            if self.render:
                index = sim.footage.frame_index_at(sim.state.time_s)
                if prefetch is not None:
                    # the level the last render decoded (footage_levels may read the half-resolution copy)
                    prefetch(index, getattr(sim, "_source_level_used", 0))
                t2 = pc()
                sim.render()
                t3 = pc()
                acc["decode_ms"] += t2 - t1
                acc["render_ms"] += t3 - t2
                fetches += index != last
                last = index
        total = pc() - t_start
        out = {k: 1e3 * v / self.steps for k, v in acc.items()}
        out["total_ms"] = 1e3 * total / self.steps
        out["new_footage_frames_per_step"] = fetches / self.steps
        return out

    def close(self) -> None:
        self.sim.close()


def open_bench_footage(clip: Path, args: argparse.Namespace, rel_alt_m: float | None = None) -> Any:
    """Our footage source for the clip, with the same recording altitude and FoV as the reference assumes."""
    from viva_sitl.footage import open_footage

    alt = args.rel_alt if rel_alt_m is None else rel_alt_m
    return open_footage(str(clip), altitude_m=alt, hfov_deg=DEFAULT_HFOV_DEG)


def psnr_db(a: Any, b: Any) -> float:

    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0**2 / mse)


def ours_quality(
    still: Path, args: argparse.Namespace, zs: list[float], rel_alt_m: float, supersample: int = 8
) -> list[dict[str, Any]]:
    """PSNR of our VAC view (yaw 0, the still) vs an area-averaged supersampled warp of the same homography,
    as run_reference.py's `quality` does for the reference."""

    from viva_sitl.camera import CameraParams, LazyPyramid, Renderer

    w, h = (int(v) for v in args.out_size.lower().split("x"))
    src = open_bench_footage(still, args, rel_alt_m)
    try:
        image = np.ascontiguousarray(src.frame(0))
        params = CameraParams(width_px=w, height_px=h, hfov_deg=DEFAULT_HFOV_DEG)
        renderer = Renderer(params, src.geometry)
        if (image.shape[1], image.shape[0]) != (src.geometry.width_px, src.geometry.height_px):
            raise RuntimeError("quality check expects the geometry at the image's own resolution")
        out = []
        for z in zs:
            res = renderer.render(LazyPyramid(image), (0.0, 0.0, -z), (0.0, 0.0, 0.0))
            k = supersample
            t = np.array([[k, 0, (k - 1) / 2], [0, k, (k - 1) / 2], [0, 0, 1]], np.float64)
            big = cv2.warpPerspective(
                image, t @ res.homography, (w * k, h * k), flags=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_CONSTANT, borderValue=tuple(float(c) for c in params.fill_bgr),
            )  # fmt: skip
            truth = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
            out.append(
                {
                    "z_m": z,
                    "footage_px_per_output_px": float(res.footage_px_per_vac_px),
                    "pyramid_level": int(res.pyramid_level),
                    "coverage": float(res.coverage),
                    "psnr_db": psnr_db(res.image_bgr, truth),
                }
            )
        return out
    finally:
        src.close()


# ---------------------------------------------------------------------------------------------- dynamics check


def check_dynamics(golden_path: Path) -> int:
    """Replay the reference's golden trajectory (golden_dynamics.py) through our EAV with EavParams.paper()."""

    from viva_sitl.dynamics import EavCommand, EavParams, EavState, step

    golden = json.loads(golden_path.read_text())
    params = replace(EavParams.paper(dt_s=1.0 / golden["fps"]))
    state = EavState.at_rest(golden["start_ned_m"], dt_s=params.dt_s)
    worst = 0.0
    for row in golden["steps"]:
        state = step(state, EavCommand(**row["cmd_ned"]), params)
        worst = max(worst, float(np.max(np.abs(state.pos_ned_m - np.asarray(row["pos_ned_m"])))))
    n = len(golden["steps"])
    print(json.dumps({"golden": str(golden_path), "steps": n, "max_abs_diff_m": worst, "ok": worst <= 1e-9}))
    return 0 if worst <= 1e-9 else 1


# ---------------------------------------------------------------------------------------------- report


def _markdown_head(result: dict[str, Any]) -> str:
    """The run's conditions, the first line of both markdown forms."""
    return (
        f"z = {result['z_m']} m, z_o = {result['rel_alt_m']} m, VAC {result['out_size']}, "
        f"{result['steps_per_run']} steps/run, {result['rounds']} interleaved rounds, "
        f"loadavg (1/5/15 min) at start {tuple(round(v, 2) for v in result['machine'].get('loadavg_start', ()))}, "
        f"at end {tuple(round(v, 2) for v in result['machine']['loadavg'])}"
    )


def to_markdown(result: dict[str, Any]) -> str:
    """The result as markdown tables (for bench/results_core.md)."""
    med, cpu = result["median_steps_per_s"], result["median_cpu_ms_per_step"]
    if "ratio_vs" in result:  # --ref-python-also: the ratios against each reference, by its version
        return _markdown_multi(result)
    lines = [
        _markdown_head(result),
        "",
        "| run | median steps/s | wall ms/step | ratio ours/ref (wall) | CPU ms/step | ratio ref/ours (CPU) | vs "
        "| sim s per wall s | physics steps/s |",
        "|---|---:|---:|---:|---:|---:|---|---:|---:|",
    ]
    for k, v in med.items():
        ref = _ref_of(k)
        ours = not k.startswith("ref") and ref in med
        r_wall = f"{v / med[ref]:.2f}x" if ours else ""
        r_cpu = f"{cpu[ref] / cpu[k]:.2f}x" if ours else ""
        # one step = 1/30 s of sim time; the *_250 variants make 250/30 physics steps in it
        phys = (
            f"{v * 250.0 / 30.0:.0f}" if "_250" in k else (f"{v:.0f}" if "paper" in k or k == "ref" else "")
        )
        lines.append(
            f"| {k} | {v:.1f} | {1e3 / v:.3f} | {r_wall} | {cpu[k]:.3f} | {r_cpu} | {ref if ours else ''} "
            f"| {v / 30.0:.2f} | {phys} |"
        )
    return "\n".join(lines + _markdown_tail(result)) + "\n"


def _markdown_multi(result: dict[str, Any]) -> str:
    """to_markdown's main table with one pair of ratio columns (wall, CPU) per reference, labelled by version."""
    med, cpu = result["median_steps_per_s"], result["median_cpu_ms_per_step"]
    runs: dict[str, list[str]] = result.get("reference_runs", {})
    wall_vs, cpu_vs = result["ratio_vs"], result["cpu_ratio_vs"]
    labels = list(wall_vs)
    video_runs = {v[0] for v in runs.values() if v}
    lines = [
        _markdown_head(result),
        "",
        "References, same rounds: "
        + "; ".join(f"viva-safeland {label}: {', '.join(keys)}" for label, keys in runs.items())
        + ". Ratios: wall = ours steps/s / the reference's, CPU = the reference's CPU ms/step / ours "
        "(the still variants vs the reference's still run).",
        "",
        "| run | median steps/s | wall ms/step | CPU ms/step | "
        + " | ".join(f"wall vs {label} | CPU vs {label}" for label in labels)
        + " | sim s per wall s | physics steps/s |",
        "|---|---:|---:|---:|" + "---:|---:|" * len(labels) + "---:|---:|",
    ]
    for k, v in med.items():
        cells = []
        for label in labels:
            w, c = wall_vs[label].get(k), cpu_vs[label].get(k)
            cells += ["" if w is None else f"{w:.2f}x", "" if c is None else f"{c:.2f}x"]
        phys = (
            f"{v * 250.0 / 30.0:.0f}"
            if "_250" in k
            else (f"{v:.0f}" if "paper" in k or k in video_runs else "")
        )
        lines.append(
            f"| {k} | {v:.1f} | {1e3 / v:.3f} | {cpu[k]:.3f} | "
            + " | ".join(cells)
            + f" | {v / 30.0:.2f} | {phys} |"
        )
    return "\n".join(lines + _markdown_tail(result)) + "\n"


def _markdown_tail(result: dict[str, Any]) -> list[str]:
    """The breakdown and anti-aliasing tables of to_markdown."""
    lines: list[str] = []
    bd = result.get("breakdown_ms_per_step") or {}
    if bd:
        lines += ["", "Breakdown, ms per step (one extra run after the rounds):", ""]
        keys: list[str] = []
        for row in bd.values():
            keys += [k for k in row if k not in keys]
        lines.append("| run | " + " | ".join(keys) + " |")
        lines.append("|---|" + "---:|" * len(keys))
        for name, row in bd.items():
            lines.append(
                f"| {name} | " + " | ".join(f"{row[k]:.3f}" if k in row else "" for k in keys) + " |"
            )
    q = result.get("quality_psnr_vs_area_average") or {}
    if q:
        lines += [
            "",
            "Anti-aliasing: PSNR of the VAC view vs an 8x8-supersampled, area-averaged warp of the same homography:",
            "",
            "| run | z m | footage px per VAC px | PSNR dB |",
            "|---|---:|---:|---:|",
        ]
        for name, rows in q.items():
            for r in rows:
                lines.append(
                    f"| {name} | {r['z_m']:.1f} | {r['footage_px_per_output_px']:.2f} | {r['psnr_db']:.1f} |"
                )
    return lines


# ---------------------------------------------------------------------------------------------- main


VARIANTS = (
    "phys_250", "phys_paper", "decode_only", "full_250", "full_paper", "full_250_plain", "full_paper_plain",
    "full_250_prefetch", "full_paper_prefetch", "ingest_250", "ingest_levels_250", "still_250", "still_paper",
)  # fmt: skip


def _ref_of(name: str, video: str = "ref", still: str = "ref_still") -> str:
    """The reference run an 'ours' variant is compared with: the still scenario with DroneEnv(fixed=True)."""
    return still if name.startswith("ours_still") else video


def _ratios(
    med: dict[str, float], cpu_med: dict[str, float], video: str = "ref", still: str = "ref_still"
) -> tuple[dict[str, float], dict[str, float]]:
    """(ours steps/s / the reference's, the reference's CPU ms per step / ours) for every 'ours' run, against the
    reference runs `video` / `still` (see _ref_of)."""
    wall = {k: v / med[_ref_of(k, video, still)] for k, v in med.items()
            if not k.startswith("ref") and _ref_of(k, video, still) in med}  # fmt: skip
    cpu = {k: cpu_med[_ref_of(k, video, still)] / v for k, v in cpu_med.items()
           if not k.startswith("ref") and _ref_of(k, video, still) in cpu_med}  # fmt: skip
    return wall, cpu


def machine() -> dict[str, Any]:
    model = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "nproc": os.cpu_count(),
        "cpu": model,
        "python": platform.python_version(),
        "opencv": cv2.__version__,
        "pyav": av.__version__,
        "loadavg": os.getloadavg(),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ref-python", default=DEFAULT_REF_PYTHON, help="interpreter with viva-safeland 0.2.0")
    ap.add_argument("--no-ref", action="store_true", help="time ours only")
    ap.add_argument(
        "--ref-python-also", nargs="*", default=[],
        help="further reference interpreters timed in the same rounds (e.g. viva-safeland 0.2.5's beside 0.2.0's): "
        "runs ref_<version> (+ ref_<version>_still), every ratio also vs each of them",
    )  # fmt: skip
    ap.add_argument(
        "--cache-dir", type=Path, default=DEFAULT_CACHE, help="where the 4K clip is generated (no dots)"
    )
    ap.add_argument("--frames", type=int, default=60, help="frames of the generated 4K clip")
    ap.add_argument("--rel-alt", type=float, default=DEFAULT_REL_ALT_M, help="recording altitude z_o, m")
    ap.add_argument("--z", type=float, default=50.0, help="hover altitude, m above ground")
    ap.add_argument("--yaw-deg", type=float, default=30.0, help="yaw (reference convention, CCW)")
    ap.add_argument("--out-size", type=size_arg, default="640x480")
    ap.add_argument("--steps", type=int, default=120, help="steps per timed run")
    ap.add_argument(
        "--rounds", type=int, default=5, help="interleaved rounds (each: ref, then every variant)"
    )
    ap.add_argument(
        "--variants", default=",".join(VARIANTS), help="comma-separated subset of: " + ", ".join(VARIANTS)
    )
    ap.add_argument("--check-dynamics", type=Path, default=None, help="golden JSON from golden_dynamics.py")
    ap.add_argument(
        "--quality-frac", type=float, nargs="*", default=[0.25, 0.5, 0.7],
        help="altitudes (fractions of the recording altitude, <= 0.75 keeps our 4:3 view inside the footage) "
        "for the anti-aliasing PSNR check (yaw 0, first frame); none to skip",
    )  # fmt: skip
    ap.add_argument("--markdown", type=Path, default=None, help="also write the tables as markdown here")
    ap.add_argument(
        "--report", type=Path, default=None, help="print the markdown tables of a saved --json and exit"
    )
    ap.add_argument("--json", type=Path, default=None, help="also write the result JSON here")
    # the clip by path opens through the automatic tile cache: with the library's 256 MiB LRU the 60-frame clip's
    # tiles would be served from memory after the warm-up, which no real clip gets
    add_tile_cache_arg(ap)
    args = ap.parse_args()
    apply_tile_cache(ap, args)

    if args.report is not None:
        print(to_markdown(json.loads(args.report.read_text())), end="")
        return 0
    if args.check_dynamics is not None:
        return check_dynamics(args.check_dynamics)
    if "." in str(args.cache_dir):
        raise SystemExit(
            f"--cache-dir must not contain a dot (the reference's SRT lookup breaks): {args.cache_dir}"
        )

    load_start = os.getloadavg()
    clip = make_clip(args.cache_dir, args.frames, rel_alt_m=args.rel_alt)
    still = make_still(clip, args.rel_alt)
    runners: dict[str, Any] = {}
    notes: list[str] = []
    wanted = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = set(wanted) - set(VARIANTS)
    if unknown:
        raise SystemExit(f"unknown variant(s) {sorted(unknown)}; known: {', '.join(VARIANTS)}")

    # the references, by their "vs" label (the viva-safeland version the interpreter reports): runs and interpreter
    refs: dict[str, tuple[str, str, str]] = {}  # label -> (video run, still run, python)
    for i, python in enumerate([args.ref_python, *args.ref_python_also]):
        skip = "disabled by --no-ref" if args.no_ref else reference_available(python)
        if skip is not None:
            notes.append(f"reference skipped: {skip}" if i == 0 else f"reference {python} skipped: {skip}")
            print(
                f"# SKIP reference: {skip}" if i == 0 else f"# SKIP reference {python}: {skip}",
                file=sys.stderr,
            )
            continue
        ref_run = Reference(python, clip, args)
        label = reference_label(str(ref_run.info.get("version", "unknown")), refs)
        key = "ref" if i == 0 else f"ref_{label}"
        runners[key] = ref_run
        still_key = "ref_still" if i == 0 else f"{key}_still"
        if any(v.startswith("still") for v in wanted):
            runners[still_key] = Reference(python, clip, args, fixed=True)
        refs[label] = (key, still_key, python)

    for name in wanted:
        paper = "paper" in name
        render = not name.startswith(("phys", "decode"))
        footage = still if name.startswith("still") else clip
        if name.startswith("ingest"):
            try:
                footage = make_ingest(clip, levels=2 if "levels" in name else 1)
            except ImportError as exc:
                notes.append(f"ours_{name} skipped: no ingest ({exc})")
                continue
        runners[f"ours_{name}"] = Ours(
            footage, args, paper=paper, render=render, region=not name.endswith("_plain"),
            prefetch=name.endswith("_prefetch"), decode_only=name == "decode_only",
            footage_levels="levels" in name,
        )  # fmt: skip

    for r in runners.values():  # warm-up (the reference already did one in --serve)
        if not isinstance(r, Reference):
            r.run()

    samples: dict[str, list[float]] = {k: [] for k in runners}
    cpu_samples: dict[str, list[float]] = {k: [] for k in runners}
    run_fns: dict[str, Callable[[], tuple[float, float]]] = {k: r.run for k, r in runners.items()}
    try:
        for i in range(args.rounds):
            for name, fn in run_fns.items():  # A B A B ...: every implementation once per round
                sps, cpu_ms = fn()
                samples[name].append(sps)
                cpu_samples[name].append(cpu_ms)
            line = "  ".join(f"{k}={v[-1]:.1f}" for k, v in samples.items())
            print(f"# round {i + 1}/{args.rounds}: steps/s {line}", file=sys.stderr)
        breakdown = {k: r.ask("breakdown") for k, r in runners.items() if isinstance(r, Reference)}
        breakdown.update(  # not for prefetch variants: the breakdown decodes inline, so it would time the same
            {
                k: r.breakdown()
                for k, r in runners.items()
                if isinstance(r, Ours) and r.render and "prefetch" not in k
            }
        )
        quality: dict[str, Any] = {}
        if args.quality_frac:
            # the soft upscaled clip, and a sharp native 4K still (Songdo, ~0.05 m/px -> z_o = 110.2 m at 82.1 deg)
            sources = [("interchange4k", still, args.rel_alt)]
            if SONGDO_STILL.exists():
                sources.append(("songdo4k", SONGDO_STILL, SONGDO_REL_ALT_M))
            for label, path, alt in sources:
                zs = [f * alt for f in args.quality_frac]
                for key, _still_key, python in refs.values():
                    ref = Reference(python, path, args, fixed=True, rel_alt_m=alt)
                    try:
                        quality[f"{key}_{label}"] = ref.ask("quality " + " ".join(str(z) for z in zs))
                    finally:
                        ref.close()
                quality[f"ours_{label}"] = ours_quality(path, args, zs, alt)
    finally:
        for r in runners.values():
            r.close()

    med = {k: statistics.median(v) for k, v in samples.items() if v}
    cpu_med = {k: statistics.median(v) for k, v in cpu_samples.items() if v}
    result: dict[str, Any] = {
        "machine": {**machine(), "loadavg_start": load_start},
        "clip": str(clip),
        "out_size": args.out_size,
        "z_m": args.z,
        "rel_alt_m": args.rel_alt,
        "steps_per_run": args.steps,
        "rounds": args.rounds,
        "reference": runners["ref"].info if "ref" in runners else None,
        "breakdown_ms_per_step": breakdown,
        "quality_psnr_vs_area_average": quality,
        "samples_steps_per_s": samples,
        "median_steps_per_s": med,
        "median_ms_per_step": {k: 1e3 / v for k, v in med.items()},
        "samples_cpu_ms_per_step": cpu_samples,
        "median_cpu_ms_per_step": cpu_med,
        "notes": notes,
    }
    # ours steps/s / the reference's, the reference's CPU ms per step / ours
    result["ratio_vs_ref"], result["cpu_ratio_vs_ref"] = _ratios(med, cpu_med)
    if args.ref_python_also:  # the same ratios against every reference, labelled by its version
        result["references_also"] = {
            keys[0]: runners[keys[0]].info for keys in refs.values() if keys[0] != "ref"
        }
        result["reference_runs"] = {
            label: [k for k in (v_run, s_run) if k in runners] for label, (v_run, s_run, _) in refs.items()
        }
        per_ref = {label: _ratios(med, cpu_med, v_run, s_run) for label, (v_run, s_run, _) in refs.items()}
        result["ratio_vs"] = {label: wall for label, (wall, _) in per_ref.items()}
        result["cpu_ratio_vs"] = {label: cpu for label, (_, cpu) in per_ref.items()}
    text = json.dumps(result, indent=2)
    print(text)
    if args.json is not None:
        args.json.write_text(text + "\n", encoding="utf-8")
    if args.markdown is not None:
        args.markdown.write_text(to_markdown(result), encoding="utf-8")

    if args.ref_python_also:
        print_multi_summary(result)
    else:
        print_summary(med, cpu_med)
    for impl, rows in quality.items():
        for q in rows:
            print(
                f"#   PSNR {impl:<18} z={q['z_m']:6.1f} m  {q['footage_px_per_output_px']:5.2f} footage px/px  "
                f"{q['psnr_db']:5.1f} dB",
                file=sys.stderr,
            )
    return 0


def print_summary(med: dict[str, float], cpu_med: dict[str, float]) -> None:
    """The stderr summary against the one reference (`ref`, `ref_still`)."""
    print("\n# median: steps/s (wall ms/step)  ratio ours/ref | CPU ms/step  ratio ref/ours", file=sys.stderr)
    for k, v in med.items():
        base = _ref_of(k)
        ours = not k.startswith("ref") and base in med
        ratio = f"{v / med[base]:7.2f}x" if ours else " " * 8
        cpu_ratio = f"{cpu_med[base] / cpu_med[k]:7.2f}x vs {base}" if ours else ""
        print(
            f"#   {k:<18} {v:9.1f} ({1e3 / v:7.3f} ms) {ratio} | {cpu_med[k]:7.3f} ms {cpu_ratio}",
            file=sys.stderr,
        )


def print_multi_summary(result: dict[str, Any]) -> None:
    """The stderr summary with --ref-python-also: the ratios against each reference, labelled by its version."""
    med, cpu_med = result["median_steps_per_s"], result["median_cpu_ms_per_step"]
    wall_vs, cpu_vs = result["ratio_vs"], result["cpu_ratio_vs"]
    print(
        "\n# median: steps/s (wall ms/step) | CPU ms/step | vs <viva-safeland version>: ratio ours/ref (wall), "
        "ref/ours (CPU)",
        file=sys.stderr,
    )
    for k, v in med.items():
        vs = "".join(
            f" | vs {label} {wall_vs[label][k]:6.2f}x wall {cpu_vs[label][k]:6.2f}x CPU"
            for label in wall_vs
            if k in wall_vs[label] and k in cpu_vs[label]
        )
        print(f"#   {k:<18} {v:9.1f} ({1e3 / v:7.3f} ms) | {cpu_med[k]:7.3f} ms{vs}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
