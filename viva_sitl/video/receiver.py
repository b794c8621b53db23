"""A low-latency PyAV receiver for the RTP streams (opened from their SDP file), for tests, benches and companion code.

    with RtpReceiver(pipeline.sdp_paths["h264"]) as rx:      # opening takes ~2 s: FFmpeg probes the stream
        for wall_time_s, image_bgr in rx.frames():
            counter = read_counter(image_bgr)               # with VideoConfig(stamp_counter=True)

The same stream opens in OpenCV (FFmpeg backend) when OPENCV_FFMPEG_CAPTURE_OPTIONS="protocol_whitelist;file,udp,rtp"
is in the environment before cv2 is imported: cv2.VideoCapture(sdp_path, cv2.CAP_FFMPEG).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import av
import numpy as np
from numpy.typing import NDArray

OPENCV_CAPTURE_OPTIONS = (
    "protocol_whitelist;file,udp,rtp"  # value of the OPENCV_FFMPEG_CAPTURE_OPTIONS variable
)


class RtpReceiver:
    """Decodes an RTP stream described by an SDP file; yields (time.time() at decode, BGR image)."""

    def __init__(self, sdp_path: str | Path, *, timeout_s: float = 5.0, low_delay: bool = True) -> None:
        path = Path(sdp_path)
        if not path.is_file():
            raise ValueError(f"SDP file {str(path)!r} does not exist")
        options = {"protocol_whitelist": "file,udp,rtp"}
        if low_delay:
            # short probing: open in ~0.1 s instead of ~1.4 s and start at the next keyframe without a backlog
            # ("fflags nobuffer" instead would discard the probed keyframe and start one GOP later)
            options.update(
                {
                    "flags": "low_delay",
                    "reorder_queue_size": "0",
                    "analyzeduration": "100000",
                    "probesize": "32768",
                }
            )
        try:
            self._container = av.open(str(path), format="sdp", options=options, timeout=timeout_s)
        except av.FFmpegError as exc:
            raise ValueError(f"cannot open RTP stream of {str(path)!r}: {exc}") from None
        if not self._container.streams.video:
            self._container.close()
            raise ValueError(f"{str(path)!r} describes no video stream")
        stream = self._container.streams.video[0]
        stream.thread_type = "SLICE"  # frame threading adds a frame of delay per thread
        self.decoded = 0
        self.decode_errors = 0

    def frames(self) -> Iterator[tuple[float, NDArray[np.uint8]]]:
        """Decoded frames until the stream times out (no packet for timeout_s) or the receiver is closed."""
        stream = self._container.streams.video[0]
        try:
            for packet in self._container.demux(stream):
                try:
                    decoded = packet.decode()
                except av.InvalidDataError:
                    self.decode_errors += 1  # a lost packet: the decoder recovers at the next keyframe
                    continue
                for frame in decoded:
                    image: NDArray[np.uint8] = frame.to_ndarray(format="bgr24")  # type: ignore[assignment]
                    self.decoded += 1
                    yield time.time(), image
        except (av.FFmpegError, OSError):
            return  # timeout or closed

    def close(self) -> None:
        self._container.close()

    def __enter__(self) -> RtpReceiver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
