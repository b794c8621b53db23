"""VideoPipeline: hands rendered frames to the outputs on worker threads; FrameScheduler: renders at the stream rate.

Nothing here touches asyncio: `submit()` never blocks (a full output queue drops its oldest waiting frame and counts
it), each output encodes on its own thread (one slow output does not hold the others back), and `stop()` joins the
threads and closes every output so that no file or stream is left half written.

    pipeline = VideoPipeline(config.video.with_instance(i), width, height)
    pipeline.start()                      # opens outputs, writes SDP files: print(pipeline.sdp_paths)
    scheduler = FrameScheduler(render, pipeline.submit, fps=config.video.fps)
    scheduler.start()                     # render(tick) -> RenderedFrame | None at 30 fps on its own thread
    ...
    scheduler.stop(); pipeline.stop(); log.info("video %s", pipeline.stats())
"""

from __future__ import annotations

import logging
import math
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from viva_sitl.frame import RenderedFrame
from viva_sitl.video.config import VideoConfig
from viva_sitl.video.frame_socket import FramePublisher
from viva_sitl.video.outputs import H264RtpOutput, MjpegRtpOutput, Mp4Recorder, VideoOutput
from viva_sitl.video.rtsp import RtspServer
from viva_sitl.video.stamp import stamp_counter, strip_size_px

log = logging.getLogger(__name__)

_TIMING_WINDOW = 1000  # per-output write times kept for the median / p95 (the last N frames)


def _percentile(values: Sequence[float], q: float) -> float:
    if not values:
        return math.nan
    return float(np.percentile(np.asarray(values), q))


class _OutputWorker:
    """One output, its bounded queue (drop-oldest) and its thread."""

    def __init__(self, output: VideoOutput, queue_size: int) -> None:
        self.output = output
        self.queue: deque[RenderedFrame] = deque()
        self.queue_size = queue_size
        self.cond = threading.Condition()
        self.stopping = False
        self.sent = 0
        self.dropped = 0
        self.errors = 0
        self.writing = False  # a frame taken from the queue is being written
        self.write_ms: deque[float] = deque(maxlen=_TIMING_WINDOW)
        self.wire_ms: deque[float] = deque(maxlen=_TIMING_WINDOW)  # pose sample (meta.wall_time_s) -> written
        self.thread = threading.Thread(target=self._run, name=f"video-{output.name}", daemon=True)

    def put(self, frame: RenderedFrame) -> bool:
        """Queue `frame`; False when the queue was full and its oldest frame was dropped to make room."""
        with self.cond:
            displaced = len(self.queue) >= self.queue_size
            if displaced:
                self.queue.popleft()
                self.dropped += 1
            self.queue.append(frame)
            self.cond.notify()
        return not displaced

    def _run(self) -> None:
        while True:
            with self.cond:
                while not self.queue and not self.stopping:
                    self.cond.wait()
                if not self.queue:  # stopping and drained
                    return
                frame = self.queue.popleft()
                self.writing = True
            t0 = time.perf_counter()
            try:
                self.output.write(frame)
            except Exception:
                self.writing = False
                self.errors += 1
                if self.errors == 1 or self.errors % 100 == 0:
                    log.exception("video output %s: write failed (%d errors)", self.output.name, self.errors)
                continue
            self.write_ms.append((time.perf_counter() - t0) * 1e3)
            self.wire_ms.append((time.time() - frame.meta.wall_time_s) * 1e3)
            self.sent += 1
            self.writing = False

    def stop(self, timeout_s: float) -> None:
        with self.cond:
            self.stopping = True
            self.cond.notify()
        if self.thread.is_alive():
            self.thread.join(timeout_s)
            if self.thread.is_alive():
                log.error("video output %s did not stop within %.1f s", self.output.name, timeout_s)

    def stats(self) -> dict[str, Any]:
        times = list(self.write_ms)
        wire = list(self.wire_ms)
        return {
            "sent": self.sent,
            "dropped": self.dropped,
            "errors": self.errors,
            "write_ms_median": statistics.median(times) if times else math.nan,
            "write_ms_p95": _percentile(times, 95),
            "pose_to_wire_ms_median": statistics.median(wire) if wire else math.nan,
            "pose_to_wire_ms_p95": _percentile(wire, 95),
        }


class VideoPipeline:
    """The video outputs of one vehicle, fed with RenderedFrame objects from any thread.

    `extra_outputs` are driven like the built-in ones (any object with name/open/write/close, see VideoOutput).
    """

    def __init__(
        self,
        config: VideoConfig,
        width: int,
        height: int,
        *,
        extra_outputs: Sequence[VideoOutput] = (),
    ) -> None:
        if width < 16 or height < 16 or width % 2 or height % 2:
            raise ValueError(f"video frame size must be even and >= 16 px, got {width}x{height}")
        if config.stamp_counter:
            sw, sh = strip_size_px()
            if width < sw or height < sh:
                raise ValueError(f"stamp_counter needs frames of at least {sw}x{sh} px, got {width}x{height}")
        self.config = config
        self.width, self.height = width, height
        outputs: list[VideoOutput] = []
        self._sdp: dict[str, Path] = {}
        sdp_dir = Path(config.sdp_dir)
        # the RTSP server gets the H.264 output's packets (one encode for both); without RTP the output only encodes
        self.rtsp: RtspServer | None = None
        if config.rtsp:
            self.rtsp = RtspServer(config.rtsp_host, config.rtsp_port, fps=config.fps)
        if config.h264_rtp or self.rtsp is not None:
            h264 = H264RtpOutput(
                config.host,
                config.h264_port,
                width,
                height,
                fps=config.fps,
                bitrate_kbps=config.bitrate_kbps,
                gop=config.gop,
                preset=config.x264_preset,
                sdp_path=sdp_dir / f"viva-sitl-h264-{config.h264_port}.sdp" if config.h264_rtp else None,
                end_of_frame_aud=config.h264_end_of_frame_aud,
                threads=config.x264_threads,
                send_rtp=config.h264_rtp,
                packet_sink=self.rtsp.feed if self.rtsp is not None else None,
            )
            outputs.append(h264)
        if config.mjpeg_rtp:
            mjpeg = MjpegRtpOutput(
                config.host,
                config.mjpeg_port,
                width,
                height,
                fps=config.fps,
                quality=config.jpeg_quality,
                sdp_path=sdp_dir / f"viva-sitl-mjpeg-{config.mjpeg_port}.sdp",
            )
            outputs.append(mjpeg)
        if config.frame_socket:
            self.publisher: FramePublisher | None = FramePublisher(
                config.frame_socket_endpoint,
                config.frame_socket_encoding,
                config.jpeg_quality,
                sndhwm=config.queue_size,
            )
            outputs.append(self.publisher)
        else:
            self.publisher = None
        if config.record_path:
            outputs.append(
                Mp4Recorder(
                    config.record_path,
                    width,
                    height,
                    fps=config.fps,
                    bitrate_kbps=config.bitrate_kbps,
                    preset=config.x264_preset,
                    threads=config.x264_threads,
                )
            )
        outputs.extend(extra_outputs)
        names = [o.name for o in outputs]
        if len(set(names)) != len(names):
            raise ValueError(f"video output names must be unique, got {names}")
        self._outputs = outputs
        self._workers: list[_OutputWorker] = []
        self._lock = threading.Lock()
        self._running = False
        self._stopped = False
        self.submitted = 0
        self.rejected = 0  # submitted while not running

    # -- lifecycle ---------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Open every output (writing SDP files, binding the frame socket) and start the worker threads.

        Raises ValueError naming the output when one cannot be opened; the ones already opened are closed again.
        """
        with self._lock:
            if self._running or self._stopped:
                raise RuntimeError("VideoPipeline can be started once")
            opened: list[VideoOutput] = []
            if self.rtsp is not None:
                self.rtsp.start()  # first: a taken RTSP port fails the start before any output is opened
            try:
                for out in self._outputs:
                    out.open()
                    opened.append(out)
            except BaseException:
                for out in reversed(opened):
                    try:
                        out.close()
                    except Exception:
                        log.exception("video output %s: close after failed start", out.name)
                if self.rtsp is not None:
                    self.rtsp.stop()
                raise
            for out in self._outputs:
                sdp = getattr(out, "sdp_path", None)
                if isinstance(sdp, Path):
                    self._sdp[out.name.removesuffix("_rtp")] = sdp
            self._workers = [_OutputWorker(out, self.config.queue_size) for out in self._outputs]
            for w in self._workers:
                w.thread.start()
            self._running = True
        log.info(
            "video outputs %s started (%dx%d @ %d fps); SDP: %s",
            ", ".join(o.name for o in self._outputs) or "none",
            self.width,
            self.height,
            self.config.fps,
            ", ".join(str(p) for p in self._sdp.values()) or "none",
        )
        if self.rtsp is not None:
            log.info("video RTSP: %s", self.rtsp.url)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Encode what is queued, join the worker threads, close every output (idempotent)."""
        with self._lock:
            if not self._running:
                self._stopped = True
                return
            self._running = False
            self._stopped = True
        for w in self._workers:
            w.stop(timeout_s)
        for w in self._workers:
            if w.thread.is_alive():
                continue  # still inside write(): closing under it would crash FFmpeg; the daemon thread dies with us
            try:
                w.output.close()
            except Exception:
                log.exception("video output %s: close failed", w.output.name)
        if self.rtsp is not None:
            self.rtsp.stop()

    def __enter__(self) -> VideoPipeline:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return self._running

    @property
    def sdp_paths(self) -> dict[str, Path]:
        """SDP files written at start: {"h264": path, "mjpeg": path} for the enabled RTP outputs."""
        return dict(self._sdp)

    @property
    def rtsp_url(self) -> str | None:
        """rtsp://host:port/vac when the RTSP server runs (the real port when the config said 0), else None."""
        return self.rtsp.url if self.rtsp is not None else None

    @property
    def frame_socket_endpoint(self) -> str | None:
        """The endpoint the frame socket is bound to (with the real port when the config said "tcp://host:*")."""
        if self.publisher is None:
            return None
        return self.publisher.bound_endpoint or self.publisher.endpoint

    # -- frames ------------------------------------------------------------------------------------------------
    def idle(self) -> bool:
        """True when every output has written (or dropped) every frame submitted so far (lockstep waits on it)."""
        return all(not w.queue and not w.writing for w in self._workers)

    def submit(self, frame: RenderedFrame) -> bool:
        """Queue `frame` for every output without blocking. Takes ownership of frame.image_bgr (do not modify it).

        Returns True when every output took it without dropping anything; False when the pipeline is not running
        (frame rejected) or some output's queue was full (its oldest waiting frame was dropped to make room).
        Raises ValueError for an image that is not (height, width, 3) uint8.
        """
        img = frame.image_bgr
        if img.shape != (self.height, self.width, 3) or img.dtype != np.uint8:
            raise ValueError(
                f"frame image must be ({self.height}, {self.width}, 3) uint8, got {img.shape} {img.dtype}"
            )
        if not img.flags.c_contiguous or (self.config.stamp_counter and not img.flags.writeable):
            frame = RenderedFrame(np.array(img, order="C", copy=True), frame.meta)
        if self.config.stamp_counter:
            stamp_counter(frame.image_bgr, frame.meta.frame_counter)
        with self._lock:  # held for microseconds; stop() holds it only to flip the state, never while joining
            if not self._running:
                self.rejected += 1
                return False
            self.submitted += 1
            ok = True
            for w in self._workers:
                ok = w.put(frame) and ok
        return ok

    def stats(self) -> dict[str, Any]:
        """Counters since start.

        submitted: frames accepted by submit(); rejected: submitted while not running;
        sent: the fewest frames any output wrote; dropped: the most frames any output dropped (queue full);
        dropped_pct: dropped / submitted * 100; encode_ms_median: the slowest output's median write time (ms);
        outputs: {name: {sent, dropped, errors, write_ms_median, write_ms_p95, pose_to_wire_ms_median,
        pose_to_wire_ms_p95}}; pose_to_wire is FrameMeta.wall_time_s -> the output has sent/written the frame
        (the last 1000 frames; meaningful when wall_time_s is the real sampling time).
        """
        per = {w.output.name: w.stats() for w in self._workers}
        sent = min((s["sent"] for s in per.values()), default=0)
        dropped = max((s["dropped"] for s in per.values()), default=0)
        medians = [s["write_ms_median"] for s in per.values() if not math.isnan(s["write_ms_median"])]
        if self.publisher is not None and self.publisher.name in per:
            per[self.publisher.name]["would_block"] = self.publisher.would_block
        out = {
            "submitted": self.submitted,
            "rejected": self.rejected,
            "sent": sent,
            "dropped": dropped,
            "dropped_pct": 100.0 * dropped / self.submitted if self.submitted else 0.0,
            "encode_ms_median": max(medians) if medians else math.nan,
            "outputs": per,
        }
        if self.rtsp is not None:
            out["rtsp"] = self.rtsp.stats()
        return out


class FrameScheduler:
    """Calls `render(tick)` at `fps` on its own thread and hands each frame to `submit` (e.g. VideoPipeline.submit).

    Tick k is due at start + k/fps. When rendering (plus submit) overruns so that later ticks are already past,
    they are skipped and counted in `late_skipped`: the stream stays on the wall clock instead of falling behind.
    The tick index is passed to `render`, which may use it as the frame counter (gaps then mark skipped ticks).
    `render` may return None (nothing to show yet); its exceptions are logged and counted, the loop goes on.
    """

    def __init__(
        self,
        render: Callable[[int], RenderedFrame | None],
        submit: Callable[[RenderedFrame], bool],
        fps: float,
        *,
        clock: Callable[[], float] = time.monotonic,
        name: str = "video-scheduler",
    ) -> None:
        if not (fps > 0 and math.isfinite(fps)):
            raise ValueError(f"fps must be a positive number, got {fps!r}")
        self.render = render
        self.submit = submit
        self.fps = fps
        self.clock = clock
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.ticks = 0  # ticks rendered or attempted
        self.rendered = 0
        self.late_skipped = 0
        self.render_errors = 0
        self.not_accepted = 0  # submit() returned False
        self._render_ms: deque[float] = deque(maxlen=_TIMING_WINDOW)

    def start(self) -> None:
        if self._thread.ident is not None:
            raise RuntimeError("FrameScheduler can be started once")
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread.ident is not None and self._thread.is_alive():
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.error(
                    "%s did not stop within %.1f s (render call still running)", self._thread.name, timeout_s
                )

    def __enter__(self) -> FrameScheduler:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        period = 1.0 / self.fps
        t0 = self.clock()
        tick = 0
        while not self._stop.is_set():
            delay = t0 + tick * period - self.clock()
            if delay > 0 and self._stop.wait(delay):
                return
            self.ticks += 1
            start = time.perf_counter()
            try:
                frame = self.render(tick)
                if frame is not None:
                    self.rendered += 1
                    if not self.submit(frame):
                        self.not_accepted += 1
            except Exception:
                self.render_errors += 1
                if self.render_errors == 1 or self.render_errors % 100 == 0:
                    log.exception("render of tick %d failed (%d errors)", tick, self.render_errors)
            self._render_ms.append((time.perf_counter() - start) * 1e3)
            # next tick: the first one not already over (a tick whose slot has passed is skipped, not rendered late)
            next_tick = max(tick + 1, math.floor((self.clock() - t0) / period))
            if next_tick > tick + 1:
                self.late_skipped += next_tick - tick - 1
            tick = next_tick

    def stats(self) -> dict[str, Any]:
        times = list(self._render_ms)
        return {
            "ticks": self.ticks,
            "rendered": self.rendered,
            "late_skipped": self.late_skipped,
            "render_errors": self.render_errors,
            "not_accepted": self.not_accepted,
            "render_ms_median": statistics.median(times) if times else math.nan,
            "render_ms_p95": _percentile(times, 95),
        }
