"""Frames lost by the frame-and-pose socket to a subscriber that keeps up (bench/RESULTS.md, session 20).

One process, one thread: a ZeroMQ PUB (sndhwm 2, as `video.queue_size`) sends a frame, a SUB receives it (or waits
--wait-ms), then the next is sent; --gap-ms of busy waiting after each receive spaces the sends. Two senders:

  zmq        a bare pyzmq PUB send (what FramePublisher.write did before session 20)
  publisher  viva_sitl's FramePublisher.write (reads ZMQ_EVENTS before each send: libzmq processes the subscriber's
             pending send credits, which its send path reads at most once per ~1 ms, max_command_delay)

A frame that does not arrive within --wait-ms counts as lost (a dropped PUB message never arrives late).

    python bench/probe_frame_socket_credit.py --n 1000 --gap-ms 0 0.5 1 2 --bytes 100 460800
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import zmq  # noqa: E402

from viva_sitl.frame import FrameMeta, RenderedFrame  # noqa: E402
from viva_sitl.video.frame_socket import FrameClient, FramePublisher, encode_message  # noqa: E402


def _frame(k: int, nbytes: int) -> RenderedFrame:
    w = max(1, nbytes // 3)
    eye = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    meta = FrameMeta(
        frame_counter=k,
        sim_time_s=k / 30,
        wall_time_s=0.0,
        pos_ned_m=(0.0, 0.0, -50.0),
        att_rpy_rad=(0.0, 0.0, 0.0),
        vel_ned_m_s=(0.0, 0.0, 0.0),
        footage_frame_index=k,
        width_px=w,
        height_px=1,
        intrinsics_k=eye,
        cam_rot_body=eye,
        cam_pos_body_m=(0.0, 0.0, 0.0),
        coverage=1.0,
    )
    return RenderedFrame(np.full((1, w, 3), k % 256, np.uint8), meta)


def run(sender: str, nbytes: int, gap_ms: float, n: int, wait_ms: int) -> tuple[int, float]:
    """(frames lost, microseconds per send-receive round)."""
    pub = FramePublisher("tcp://127.0.0.1:*", sndhwm=2)
    pub.open()
    assert pub._sock is not None
    try:
        with FrameClient(pub.bound_endpoint, latest_only=False, rcvhwm=100) as client:
            while client.receive(timeout_s=0.05) is None:  # ZeroMQ's slow joiner
                pub.write(_frame(0, 3))
            while client.receive(timeout_s=0.2) is not None:
                pass
            frames = [_frame(k, nbytes) for k in range(n)]
            raw = [encode_message(f) for f in frames]
            lost = 0
            t0 = time.perf_counter()
            for k in range(n):
                if sender == "zmq":
                    pub._sock.send_multipart(raw[k], flags=zmq.NOBLOCK, copy=False)
                else:
                    pub.write(frames[k])
                if client.receive(timeout_s=wait_ms / 1000) is None:
                    lost += 1
                end = time.perf_counter() + gap_ms / 1000
                while time.perf_counter() < end:
                    pass
            per = (time.perf_counter() - t0) / n * 1e6
    finally:
        pub.close()
    return lost, per


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--senders", nargs="+", choices=["zmq", "publisher"], default=["zmq", "publisher"])
    ap.add_argument("--bytes", nargs="+", type=int, default=[100, 460800], help="image bytes per frame")
    ap.add_argument("--gap-ms", nargs="+", type=float, default=[0.0, 0.5, 1.0, 2.0])
    ap.add_argument("--n", type=int, default=1000, help="frames per case")
    ap.add_argument(
        "--wait-ms", type=int, default=100, help="how long a receive waits before the frame counts lost"
    )
    args = ap.parse_args(argv)
    if args.n < 1 or args.wait_ms < 1 or min(args.bytes) < 3 or min(args.gap_ms) < 0:
        ap.error("--n and --wait-ms must be >= 1, --bytes >= 3, --gap-ms >= 0")
    print(f"zmq {zmq.zmq_version()} pyzmq {zmq.__version__}; sndhwm 2; {args.n} frames per case")
    print(f"{'sender':>10} {'bytes':>8} {'gap ms':>7} {'lost':>6} {'us/round':>9}")
    try:
        for nbytes in args.bytes:
            for gap in args.gap_ms:
                for sender in args.senders:
                    lost, per = run(sender, nbytes, gap, args.n, args.wait_ms)
                    print(f"{sender:>10} {nbytes:>8} {gap:>7.2f} {lost:>6} {per:>9.0f}", flush=True)
    except KeyboardInterrupt:
        print("probe_frame_socket_credit: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
