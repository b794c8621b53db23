"""`.tlog` telemetry logs: every MAVLink packet the vehicle sends or accepts, as MAVProxy/QGroundControl write them.

The format: for each packet an 8-byte big-endian UNIX timestamp in microseconds, then the raw MAVLink frame.
pymavlink (`mavutil.mavlink_connection("x.tlog")`), MAVExplorer and QGroundControl's log replay read it.

Writing costs one bytes join per packet on the event loop: records collect in memory and go to the file in one
write per flush (the endpoint flushes about once a wall second and on stop), so a crash loses at most the last
second. A write error (disk full, removed directory) is reported once and stops the log; the vehicle flies on.
"""

from __future__ import annotations

import logging
import struct
import time
from pathlib import Path

log = logging.getLogger(__name__)

__all__ = ["TlogWriter"]

_TIMESTAMP = struct.Struct(">Q")
MAX_PENDING_BYTES = 4 * 1024 * 1024  # flush early past this (a burst between two periodic flushes)


class TlogWriter:
    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("wb")
        self._pending: list[bytes] = []
        self._pending_bytes = 0
        self.packets = 0
        self.bytes_written = 0
        self.failed = False

    def write(self, frame: bytes, unix_time_s: float | None = None) -> None:
        """Record one raw MAVLink frame (stamped now unless told)."""
        if self.failed:
            return
        t = time.time() if unix_time_s is None else unix_time_s
        record = _TIMESTAMP.pack(int(t * 1e6)) + frame
        self._pending.append(record)
        self._pending_bytes += len(record)
        self.packets += 1
        if self._pending_bytes >= MAX_PENDING_BYTES:
            self.flush()

    def flush(self) -> None:
        if self.failed or not self._pending:
            return
        data = b"".join(self._pending)
        self._pending.clear()
        self._pending_bytes = 0
        try:
            self._file.write(data)
            self._file.flush()
        except OSError as exc:
            self.failed = True
            log.error("tlog %s: write failed (%s); telemetry logging stopped", self.path, exc)
            return
        self.bytes_written += len(data)

    def close(self) -> None:
        self.flush()
        try:
            self._file.close()
        except OSError as exc:
            log.error("tlog %s: close failed (%s)", self.path, exc)
