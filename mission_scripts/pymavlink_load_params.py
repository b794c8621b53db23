#!/usr/bin/env python3
"""Load a QGroundControl `.params` file into a PX4 autopilot with pymavlink, then read every value back.

What QGC's "Load from file" does, with nothing but pymavlink:

1. parse the file: `#` comments, then one parameter per line, tab separated:
   `vehicle-id  component-id  NAME  value  type` (type = MAV_PARAM_TYPE: 6 INT32, 9 REAL32, as QGC writes them);
   rows for other components (e.g. a camera) are skipped and counted;
2. bulk set, as MAVSDK's and QGC's parameter managers do: PARAM_SET for up to --window parameters at a time (INT32
   values travel bytewise in the float field, PX4's encoding), each one confirmed by its PARAM_VALUE echo and resent
   after --retry-s without one (PX4 never answers a name it does not know: those end as "unknown");
3. read everything back with PARAM_REQUEST_LIST (indexes still missing afterwards are fetched one by one with
   PARAM_REQUEST_READ) and compare each loaded value with the vehicle's.

It sends a GCS HEARTBEAT every second throughout (PX4's data-link-loss failsafe watches for it).

    viva-sitl run &
    python pymavlink_load_params.py udpin:0.0.0.0:14550 my_vehicle.params

Ends with `RESULT loaded=N verified=N unknown=K mismatched=M count=C list_s=S`. Exit status 0 when every parameter
was set and read back equal, 1 otherwise (unknown names, mismatches, a timeout: the message says which).
"""

from __future__ import annotations

import argparse
import math
import os
import struct
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")  # pymavlink reads this at import: speak MAVLink 2 as PX4 does
from _mission import failed, log  # noqa: E402
from pymavlink import mavutil  # noqa: E402

mavlink = mavutil.mavlink
INT_TYPES = {1, 2, 3, 4, 5, 6}  # MAV_PARAM_TYPE_UINT8 .. INT32: PX4 sends INT32 only
GCS_HEARTBEAT_PERIOD_S = 1.0


class LoadFailed(Exception):
    """A file, link or verification problem: the message is what the user sees."""


@dataclass(frozen=True)
class FileParam:
    name: str
    value: float
    ptype: int  # MAV_PARAM_TYPE

    @property
    def is_int(self) -> bool:
        return self.ptype in INT_TYPES


def parse_qgc_params(path: Path, component: int) -> tuple[list[FileParam], int]:
    """The rows of `path` for `component`, and how many rows were for other components."""
    params: list[FileParam] = []
    skipped = 0
    for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        cols = text.split()
        if len(cols) != 5:
            raise LoadFailed(
                f"{path}:{lineno}: expected 5 columns (vehicle comp name value type), got {len(cols)}"
            )
        try:
            comp, value, ptype = int(cols[1]), float(cols[3]), int(cols[4])
        except ValueError:
            raise LoadFailed(f"{path}:{lineno}: bad number in {text!r}") from None
        if comp != component:
            skipped += 1
            continue
        if len(cols[2]) > 16 or not math.isfinite(value):
            raise LoadFailed(f"{path}:{lineno}: bad parameter {cols[2]!r} = {cols[3]}")
        params.append(FileParam(cols[2], value, ptype))
    return params, skipped


def to_wire(p: FileParam) -> float:
    """PX4's bytewise encoding: an integer's 4 bytes inside the float field."""
    if p.is_int:
        return float(struct.unpack("<f", struct.pack("<i", int(p.value)))[0])
    return float(p.value)


def from_wire(msg: Any) -> float:
    if int(msg.param_type) in INT_TYPES:
        return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
    return float(msg.param_value)


def same(p: FileParam, got: float) -> bool:
    if p.is_int:
        return int(p.value) == int(got)
    want32 = struct.unpack("<f", struct.pack("<f", p.value))[0]
    return got == want32 or math.isclose(got, want32, rel_tol=1e-6, abs_tol=1e-9)


class Link:
    def __init__(self, url: str, timeout_s: float) -> None:
        self.conn = mavutil.mavlink_connection(url, source_system=255, source_component=190)
        self.last_hb = -math.inf
        hb = self.conn.wait_heartbeat(timeout=timeout_s)
        if hb is None:
            raise LoadFailed(f"no HEARTBEAT on {url} within {timeout_s:.0f} s")
        self.target = (self.conn.target_system, 1)

    def heartbeat(self) -> None:
        now = time.monotonic()
        if now - self.last_hb >= GCS_HEARTBEAT_PERIOD_S:
            self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self.last_hb = now

    def recv_param(self, timeout_s: float) -> Any:
        self.heartbeat()
        msg = self.conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=timeout_s)
        if msg is not None and msg.get_srcComponent() != self.target[1]:
            return None
        return msg


def bulk_set(link: Link, params: list[FileParam], window: int, retry_s: float, retries: int) -> list[str]:
    """PARAM_SET with at most `window` unconfirmed; returns the names never echoed (unknown to the vehicle)."""
    pending = {p.name: p for p in params}
    order = [p.name for p in params]
    in_flight: dict[str, tuple[float, int]] = {}  # name -> (last send time, sends)
    unknown: list[str] = []
    while pending:
        now = time.monotonic()
        for name in order:
            if len(in_flight) >= window:
                break
            if name in pending and name not in in_flight:
                in_flight[name] = (0.0, 0)
        for name, (sent_s, sends) in list(in_flight.items()):
            if now - sent_s < retry_s:
                continue
            if sends > retries:
                unknown.append(name)
                del in_flight[name]
                del pending[name]
                continue
            p = pending[name]
            link.conn.mav.param_set_send(*link.target, name.encode("ascii"), to_wire(p), p.ptype)
            in_flight[name] = (now, sends + 1)
        msg = link.recv_param(0.05)
        if msg is not None and msg.param_id in in_flight:
            p = pending.pop(msg.param_id)
            del in_flight[msg.param_id]
            if not same(p, from_wire(msg)):
                log(f"{p.name}: set {p.value:g}, vehicle answered {from_wire(msg):g}")
    return unknown


def read_all(link: Link, timeout_s: float) -> tuple[dict[str, float], int, float]:
    """Every parameter via PARAM_REQUEST_LIST (+ PARAM_REQUEST_READ by index for gaps): (values, count, seconds)."""
    t0 = time.monotonic()
    link.conn.mav.param_request_list_send(*link.target)
    by_index: dict[int, tuple[str, float]] = {}
    count = 0
    deadline = t0 + timeout_s
    quiet_since = time.monotonic()
    while time.monotonic() < deadline:
        msg = link.recv_param(0.1)
        if msg is None:
            if count and time.monotonic() - quiet_since > 1.0:  # the stream ended: fetch the gaps
                missing = [i for i in range(count) if i not in by_index]
                if not missing:
                    break
                for i in missing[:20]:
                    link.conn.mav.param_request_read_send(*link.target, b"", i)
                quiet_since = time.monotonic()
            continue
        quiet_since = time.monotonic()
        if msg.param_id == "_HASH_CHECK" or msg.param_index >= 65535:
            continue
        count = int(msg.param_count)
        by_index[int(msg.param_index)] = (msg.param_id, from_wire(msg))
        if count and len(by_index) >= count:
            break
    if not count or len(by_index) < count:
        raise LoadFailed(f"read back {len(by_index)} of {count or '?'} parameters within {timeout_s:.0f} s")
    return dict(by_index.values()), count, time.monotonic() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "url", nargs="?", default="udpin:0.0.0.0:14550", help="pymavlink connection (default PX4's GCS)"
    )
    ap.add_argument("params_file", type=Path, help="QGroundControl .params file")
    ap.add_argument("--component", type=int, default=1, help="load the rows of this component id (default 1)")
    ap.add_argument("--window", type=int, default=10, help="PARAM_SETs in flight at once")
    ap.add_argument("--retry-s", type=float, default=1.0, help="resend a PARAM_SET without echo after this")
    ap.add_argument("--retries", type=int, default=2, help="resends before a name counts as unknown")
    ap.add_argument(
        "--timeout", type=float, default=60.0, help="seconds for the connection and the read-back"
    )
    ap.add_argument("--allow-unknown", action="store_true", help="names the vehicle lacks are not a failure")
    args = ap.parse_args(argv)
    try:
        params, skipped = parse_qgc_params(args.params_file, args.component)
        log(
            f"{args.params_file}: {len(params)} parameters for component {args.component} ({skipped} other rows)"
        )
        link = Link(args.url, args.timeout)
        log(f"autopilot: system {link.target[0]}")
        t0 = time.monotonic()
        unknown = bulk_set(link, params, max(1, args.window), args.retry_s, max(0, args.retries))
        log(f"set {len(params) - len(unknown)} parameters in {time.monotonic() - t0:.2f} s")
        values, count, list_s = read_all(link, args.timeout)
        log(f"read back {count} parameters in {list_s:.2f} s")
        mismatched = [
            p.name
            for p in params
            if p.name not in unknown and (p.name not in values or not same(p, values[p.name]))
        ]
        for name in mismatched:
            log(
                f"MISMATCH {name}: file {next(p.value for p in params if p.name == name):g}, vehicle {values.get(name)}"
            )
        verified = len(params) - len(unknown) - len(mismatched)
        print(
            f"RESULT loaded={len(params)} verified={verified} unknown={len(unknown)} mismatched={len(mismatched)}"
            f" count={count} list_s={list_s:.2f} unknown_names={','.join(unknown) or '-'}",
            flush=True,
        )
        if mismatched:
            raise LoadFailed(
                f"{len(mismatched)} parameters read back different: {', '.join(mismatched[:10])}"
            )
        if unknown and not args.allow_unknown:
            raise LoadFailed(f"the vehicle has no parameter {', '.join(unknown[:10])} (never answered)")
    except LoadFailed as exc:
        return failed(str(exc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
