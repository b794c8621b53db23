"""The frame-and-pose socket: every VAC frame with the ground truth it was rendered at, over ZeroMQ.

Transport: a ZeroMQ PUB socket bound by the simulator (default `tcp://127.0.0.1:5700`, + instance), any number of SUB
clients. ZeroMQ (pyzmq) gives message framing, reconnects and per-client high-water marks for free; PUB never blocks
the sender: a client that reads too slowly loses messages (at its high-water mark), never the simulator.

Wire format `vivasitl.frame.v1`: one ZeroMQ multipart message per frame, three parts:

    part 0  topic   the ASCII bytes  b"vivasitl.frame.v1"  (subscribe to it; a future format gets a new topic)
    part 1  meta    UTF-8 JSON object:
                      "schema":            "vivasitl.frame.v1"
                      "frame_counter":     int, 0, 1, 2, ... per run
                      "sim_time_s":        float, simulation time of the pose
                      "wall_time_s":       float, time.time() when the pose was sampled
                      "pos_ned_m":         [n, e, d] vehicle position (m, NED, origin = footage centre on the ground)
                      "att_rpy_rad":       [roll, pitch, yaw] vehicle attitude FRD->NED (rad)
                      "vel_ned_m_s":       [vn, ve, vd] (m/s)
                      "footage_frame_index": int
                      "width_px", "height_px": int, the VAC image size
                      "intrinsics_k":      3x3 list, pinhole K of the VAC (pixels)
                      "cam_rot_body":      3x3 list, R^b_v: camera axes (x right, y down, z optical) in FRD
                      "cam_pos_body_m":    [x, y, z] camera position in FRD (m)
                      "coverage":          float, fraction of VAC pixels that see footage
                      "lat_deg", "lon_deg", "alt_amsl_m": float or null (geo-referenced footage only)
                      "image":             {"encoding": "bgr24" | "jpeg", "shape": [h, w, 3], "dtype": "uint8"}
                      "sent_wall_time_s":  float, time.time() when the message was sent
    part 2  image   "bgr24": h*w*3 bytes, uint8 BGR, row-major (numpy.frombuffer(...).reshape(shape));
                    "jpeg":  a baseline JPEG file (cv2.imdecode(..., cv2.IMREAD_COLOR) gives BGR)

All FrameMeta fields (viva_sitl.frame.FrameMeta.to_dict) appear at the top level; clients must ignore keys they do
not know (new keys may be added without a new topic). Minimal client without viva_sitl:

    import json, zmq, numpy as np
    s = zmq.Context().socket(zmq.SUB); s.connect("tcp://127.0.0.1:5700"); s.subscribe(b"vivasitl.frame.v1")
    topic, meta, img = s.recv_multipart(); meta = json.loads(meta)
    image = np.frombuffer(img, np.uint8).reshape(meta["image"]["shape"])   # when meta["image"]["encoding"] == "bgr24"
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from typing import Any

import cv2
import numpy as np
import zmq
from numpy.typing import NDArray

from viva_sitl.frame import RenderedFrame
from viva_sitl.video.config import FrameEncoding

TOPIC = b"vivasitl.frame.v1"
SCHEMA = "vivasitl.frame.v1"


def encode_message(
    frame: RenderedFrame, encoding: FrameEncoding = FrameEncoding.RAW, jpeg_quality: int = 80
) -> list[bytes | memoryview]:
    """The three message parts of `frame` (the image part of a RAW message shares memory with the frame)."""
    img = frame.image_bgr
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"frame image must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
    if encoding is FrameEncoding.JPEG:
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if not ok:
            raise ValueError("JPEG encoding of the frame failed")
        payload: bytes | memoryview = buf.tobytes()
    else:
        payload = memoryview(np.ascontiguousarray(img)).cast("B")  # type: ignore[arg-type]
    meta: dict[str, Any] = {"schema": SCHEMA}
    meta.update(frame.meta.to_dict())
    meta["image"] = {"encoding": encoding.value, "shape": list(img.shape), "dtype": "uint8"}
    meta["sent_wall_time_s"] = time.time()
    return [TOPIC, _dumps(meta), payload]


def _dumps(meta: dict[str, Any]) -> bytes:
    def clean(v: Any) -> Any:  # strict JSON: NaN/inf (e.g. unknown altitude) become null
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, list | tuple):
            return [clean(x) for x in v]
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        return v

    return json.dumps(clean(meta), separators=(",", ":"), allow_nan=False).encode()


def decode_message(parts: list[bytes] | list[zmq.Frame]) -> tuple[NDArray[np.uint8], dict[str, Any]]:
    """(image_bgr, meta) of one received message; ValueError for anything that is not a v1 frame message."""
    if len(parts) != 3:
        raise ValueError(f"frame message must have 3 parts, got {len(parts)}")
    raw = [p.bytes if isinstance(p, zmq.Frame) else bytes(p) for p in parts[:2]]
    if raw[0] != TOPIC:
        raise ValueError(f"unknown frame message topic {raw[0][:40]!r}")
    try:
        meta = json.loads(raw[1])
        info = meta["image"]
        shape = tuple(int(x) for x in info["shape"])
        enc = FrameEncoding(info["encoding"])
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"bad frame metadata: {exc}") from None
    if len(shape) != 3 or shape[2] != 3:
        raise ValueError(f"bad image shape {shape}")
    buf = parts[2].buffer if isinstance(parts[2], zmq.Frame) else parts[2]
    if enc is FrameEncoding.RAW:
        arr = np.frombuffer(buf, dtype=np.uint8)
        if arr.size != shape[0] * shape[1] * shape[2]:
            raise ValueError(f"image part has {arr.size} bytes, shape {shape} needs {math.prod(shape)}")
        image = arr.reshape(shape).copy()  # writable and independent of the ZeroMQ buffer
    else:
        decoded = cv2.imdecode(np.frombuffer(buf, dtype=np.uint8), cv2.IMREAD_COLOR)
        if decoded is None or decoded.shape != shape:
            raise ValueError("image part is not a JPEG of the announced shape")
        image = decoded.astype(np.uint8, copy=False)
    return image, meta


class FramePublisher:
    """A video output: publishes every frame on a ZeroMQ PUB socket (wire format in this module's docstring)."""

    name = "frame_socket"

    def __init__(
        self,
        endpoint: str,
        encoding: FrameEncoding = FrameEncoding.RAW,
        jpeg_quality: int = 80,
        sndhwm: int = 2,
    ) -> None:
        self.endpoint = endpoint
        self.encoding = encoding
        self.jpeg_quality = jpeg_quality
        self.sndhwm = sndhwm
        self._ctx: zmq.Context[zmq.Socket[bytes]] | None = None
        self._sock: zmq.Socket[bytes] | None = None
        self.would_block = 0  # messages ZeroMQ refused (PUB at its high-water mark); counted, never waited on
        self.bound_endpoint = ""  # the endpoint actually bound (a "tcp://...:*" endpoint gets its port here)

    def open(self) -> None:
        self._ctx = zmq.Context()
        sock = self._ctx.socket(zmq.PUB)
        sock.setsockopt(zmq.SNDHWM, self.sndhwm)
        sock.setsockopt(zmq.LINGER, 0)
        try:
            sock.bind(self.endpoint)
        except zmq.ZMQError as exc:
            sock.close(0)
            self._ctx.term()
            self._ctx = None
            raise ValueError(f"frame socket: cannot bind {self.endpoint!r}: {exc}") from None
        self.bound_endpoint = sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self._sock = sock

    def write(self, frame: RenderedFrame) -> None:
        if self._sock is None:
            raise RuntimeError("FramePublisher.write before open()")
        parts = encode_message(frame, self.encoding, self.jpeg_quality)
        # The PUB judges whether a subscriber's queue is full (sndhwm messages) from credits its I/O thread sends back
        # as messages leave; the sending thread reads those credits on send at most once per ~1 ms (libzmq's command
        # throttle, max_command_delay). Frames sent less than ~1 ms apart were therefore dropped silently even for a
        # subscriber that had received every earlier one: 1 frame in 3 in a send-receive loop, so a quick lockstep
        # pilot's frames depended on the machine's speed (bench/probe_frame_socket_credit.py). Reading ZMQ_EVENTS
        # processes the pending credits first: only a subscriber that is really behind loses frames.
        self._sock.getsockopt(zmq.EVENTS)
        try:
            self._sock.send_multipart(parts, flags=zmq.NOBLOCK, copy=False)
        except zmq.Again:
            self.would_block += 1

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close(0)
            self._sock = None
        if self._ctx is not None:
            self._ctx.term()
            self._ctx = None


class FrameClient:
    """Receives frames from a FramePublisher.

        with FrameClient("tcp://127.0.0.1:5700") as client:
            for image_bgr, meta in client.frames(timeout_s=5.0):
                ...

    A slow client never backs up the sender: the receive high-water mark is small (`rcvhwm` messages), and with
    `latest_only` each step drains what has arrived and yields only the newest frame (meta["skipped"] says how many
    older ones it passed over).
    """

    def __init__(self, endpoint: str, *, latest_only: bool = True, rcvhwm: int = 2) -> None:
        if rcvhwm < 1:
            raise ValueError(f"rcvhwm must be >= 1, got {rcvhwm}")
        self.endpoint = endpoint
        self.latest_only = latest_only
        self._ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
        self._sock = self._ctx.socket(zmq.SUB)
        self._sock.setsockopt(zmq.RCVHWM, rcvhwm)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.SUBSCRIBE, TOPIC)
        try:
            self._sock.connect(endpoint)
        except zmq.ZMQError as exc:
            self.close()
            raise ValueError(f"frame client: cannot connect to {endpoint!r}: {exc}") from None
        self.received = 0
        self.skipped = 0

    def receive(self, timeout_s: float | None = None) -> tuple[NDArray[np.uint8], dict[str, Any]] | None:
        """The next frame (the newest one waiting, with latest_only), or None after `timeout_s` without one."""
        if self._sock.closed:
            raise RuntimeError("FrameClient is closed")
        timeout_ms = None if timeout_s is None else max(0, int(timeout_s * 1000))
        if not self._sock.poll(timeout_ms, zmq.POLLIN):
            return None
        parts = self._sock.recv_multipart(copy=False)
        skipped = 0
        if self.latest_only:
            while self._sock.poll(0, zmq.POLLIN):
                parts = self._sock.recv_multipart(copy=False)
                skipped += 1
        image, meta = decode_message(parts)
        meta["skipped"] = skipped
        self.received += 1
        self.skipped += skipped
        return image, meta

    def frames(self, timeout_s: float | None = 5.0) -> Iterator[tuple[NDArray[np.uint8], dict[str, Any]]]:
        """Yield (image_bgr, meta) until no frame arrives for `timeout_s` seconds (None: wait forever)."""
        while True:
            item = self.receive(timeout_s)
            if item is None:
                return
            yield item

    def close(self) -> None:
        if not self._sock.closed:
            self._sock.close(0)
        if not self._ctx.closed:
            self._ctx.term()

    def __enter__(self) -> FrameClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
