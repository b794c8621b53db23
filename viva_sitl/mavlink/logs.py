"""The MAVLink log protocol (LOG_REQUEST_LIST / LOG_ENTRY / LOG_REQUEST_DATA / LOG_DATA / LOG_ERASE /
LOG_REQUEST_END) over the run's ULog files, answering as PX4's mavlink_log_handler does:

    LOG_REQUEST_LIST(start, end)  -> a snapshot of the logs (size and date taken now; the log being written is listed
                                     with the size written so far), then one LOG_ENTRY per id in [start, end] clamped
                                     to the logs there are; ids count from 0, last_log_num = the last id sent.
                                     No logs: one LOG_ENTRY with id 0, num_logs 0 (MAVSDK reads it as "no logs").
    LOG_REQUEST_DATA(id, ofs, n)  -> LOG_DATA of 90 bytes each from ofs, up to n bytes or the listed size, streamed
                                     a few at a time (a burst would overflow a client's UDP buffer). Past the end:
                                     one LOG_DATA with count 0 at ofs. An unknown id, or a request before any list:
                                     no answer (PX4 ignores both).
    LOG_REQUEST_END               -> stops a transfer, forgets the list.
    LOG_ERASE                     -> deletes the listed logs (PX4 deletes its log directory), except a log still being
                                     written: this vehicle keeps the current run's log (its writer holds it open).

The files come from `set_source(fn)`: fn() -> [(path, being_written)], oldest first (the app passes the run's
ULog). No files, no source: the vehicle has no logs.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.mavlink.base import MavMessage, Origin, Outbox

log = logging.getLogger(__name__)
M = mavlink2

DATA_LEN = 90  # LOG_DATA.data is uint8_t[90]
BATCH = 16  # LOG_DATA messages sent per pump turn
PUMP_INTERVAL_S = 0.002  # wall seconds between turns: ~720 kB/s, far below a loopback UDP buffer's limits

LogSource = Callable[[], "list[tuple[Path, bool]]"]


@dataclass(frozen=True)
class LogEntry:
    path: Path
    size: int
    time_utc: int
    active: bool


@dataclass
class _Transfer:
    origin: Origin
    log_id: int
    entry: LogEntry
    ofs: int
    remaining: int
    file: BinaryIO | None


class LogProtocol:
    def __init__(self, out: Outbox) -> None:
        self.out = out
        self._source: LogSource | None = None
        self._entries: list[LogEntry] | None = None  # the last listing (None: no list requested)
        self._transfer: _Transfer | None = None
        self._pump_handle: asyncio.Handle | None = None
        self.entries_sent = 0
        self.data_sent = 0
        self.bytes_sent = 0
        self.requests_ignored = 0

    def set_source(self, source: LogSource | None) -> None:
        self._source = source

    # --- listing --------------------------------------------------------------------------
    def _scan(self) -> list[LogEntry]:
        out: list[LogEntry] = []
        if self._source is None:
            return out
        try:
            files = self._source()
        except Exception:  # a source that fails lists nothing; never an exception into the endpoint
            log.exception("log source failed")
            return out
        for path, active in files:
            try:
                st = os.stat(path)
            except OSError:
                continue
            out.append(LogEntry(Path(path), int(st.st_size), int(st.st_mtime), bool(active)))
        return out[:0xFFFF]

    def handle_request_list(self, origin: Origin, msg: MavMessage) -> None:
        start, end = int(msg.start), int(msg.end)
        if self._entries is None or start == 0:  # a new request (PX4: start 0 rescans)
            self._end_transfer()
            self._entries = self._scan()
        entries = self._entries
        n = len(entries)
        if n == 0:
            self._send_entry(origin, 0, 0, 0, 0, 0)
            return
        first = min(start, n - 1)
        last = min(end, n - 1)
        for i in range(first, last + 1):
            e = entries[i]
            self._send_entry(origin, i, n, last, e.time_utc, e.size)

    def _send_entry(self, origin: Origin, log_id: int, num: int, last: int, time_utc: int, size: int) -> None:
        self.out.reply(
            origin,
            M.MAVLink_log_entry_message(
                log_id & 0xFFFF, num & 0xFFFF, last & 0xFFFF, time_utc & 0xFFFFFFFF, size & 0xFFFFFFFF
            ),
        )
        self.entries_sent += 1

    # --- data -----------------------------------------------------------------------------
    def handle_request_data(self, origin: Origin, msg: MavMessage) -> None:
        entries = self._entries
        log_id, ofs, count = int(msg.id), int(msg.ofs), int(msg.count)
        if entries is None or log_id >= len(entries):
            self.requests_ignored += 1  # PX4: no list yet, or no such log -> no answer
            log.debug(
                "LOG_REQUEST_DATA for log %d ignored (%s)",
                log_id,
                "no list" if entries is None else "unknown",
            )
            return
        entry = entries[log_id]
        t = self._transfer
        file = t.file if t is not None and t.log_id == log_id else None
        if t is not None and file is None and t.file is not None:
            t.file.close()
        if file is None:
            try:
                file = open(entry.path, "rb")  # noqa: SIM115 -- closed when the transfer ends
            except OSError as exc:
                log.warning("cannot open log %s: %s", entry.path, exc)
                file = None
        remaining = max(0, min(count, entry.size - ofs)) if ofs < entry.size else 0
        self._transfer = _Transfer(origin, log_id, entry, ofs, remaining, file)
        self._schedule()

    def _schedule(self) -> None:
        if self._pump_handle is not None:
            return
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # no loop (a direct call in a test): send everything now
            while self._transfer is not None:
                self._pump_once()
            return
        self._pump_handle = loop.call_soon(self._pump)

    def _pump(self) -> None:
        self._pump_handle = None
        self._pump_once()
        if self._transfer is not None:
            self._pump_handle = asyncio.get_running_loop().call_later(PUMP_INTERVAL_S, self._pump)

    def _pump_once(self) -> None:
        t = self._transfer
        if t is None:
            return
        for _ in range(BATCH):
            n = min(DATA_LEN, t.remaining)
            data = b""
            if n > 0 and t.file is not None:
                try:
                    t.file.seek(t.ofs)
                    data = t.file.read(n)
                except OSError as exc:
                    log.warning("reading log %s failed: %s", t.entry.path, exc)
                    data = b""
            self.out.reply(
                t.origin,
                M.MAVLink_log_data_message(
                    t.log_id, t.ofs & 0xFFFFFFFF, len(data), data.ljust(DATA_LEN, b"\0")
                ),
            )
            self.data_sent += 1
            self.bytes_sent += len(data)
            t.ofs += len(data)
            t.remaining -= len(data)
            if (
                len(data) < DATA_LEN or t.remaining <= 0
            ):  # the last piece (PX4: a short read ends the transfer)
                self._transfer = None
                if t.file is not None:  # keep nothing open between requests
                    t.file.close()
                return

    def _end_transfer(self) -> None:
        t, self._transfer = self._transfer, None
        if t is not None and t.file is not None:
            t.file.close()
        if self._pump_handle is not None:
            self._pump_handle.cancel()
            self._pump_handle = None

    # --- end / erase ----------------------------------------------------------------------
    def handle_request_end(self, origin: Origin, msg: MavMessage) -> None:
        self._end_transfer()
        self._entries = None

    def handle_erase(self, origin: Origin, msg: MavMessage) -> None:
        self._end_transfer()
        self._entries = None
        for entry in self._scan():
            if entry.active:
                log.info("LOG_ERASE: %s is being written, kept", entry.path)
                continue
            with contextlib.suppress(OSError):
                entry.path.unlink()
                log.info("LOG_ERASE: deleted %s", entry.path)

    def close(self) -> None:
        self._end_transfer()


__all__ = ["DATA_LEN", "LogEntry", "LogProtocol"]
