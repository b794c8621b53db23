"""A streaming ULog writer (PX4's log format, https://docs.px4.io/main/en/dev_log/ulog_file_format.html).

    topic = Topic("vehicle_attitude", (("float[4]", "q"), ("float", "rollspeed")))
    with ULogFile("log.ulg", [topic], info={"sys_name": "viva-sitl"}, params={"MIS_TAKEOFF_ALT": 2.5}) as f:
        f.write(topic, timestamp_us, ([1.0, 0.0, 0.0, 0.0], 0.0))
    ULogWriter: the same behind a bounded queue and a writer thread (`log()` never blocks; a full queue drops the
    sample and the file gets a dropout message, as PX4's logger does when its buffer overflows).

pyulog (the reference reader) has `ULog.write_ulog`, but it writes a whole parsed log from memory; a simulator
needs to append while it flies and let a client download the part written so far, so this module writes the
format itself: the 16-byte header, the flag-bits message, then the definitions section (format, info, parameter
messages) and the data section (add_logged subscriptions, data, logged strings, dropouts). Every topic's first
field is `uint64_t timestamp` (microseconds, the log's clock); fields are packed little-endian without padding
(the ULog format string describes exactly what is written, so readers need no padding fields).

Writes go to the file whole messages at a time (unbuffered), so the file size is always at a message boundary:
a reader of a log still being written (MAVLink LOG_REQUEST_DATA of the current log) gets a parsable prefix.
"""

from __future__ import annotations

import logging
import math
import os
import struct
import threading
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

MAGIC = b"ULog\x01\x12\x35"
VERSION = 1
SYNC_MAGIC = bytes((0x2F, 0x73, 0x13, 0x20, 0x25, 0x0C, 0xBB, 0x12))

_TYPES: dict[str, str] = {
    "int8_t": "b",
    "uint8_t": "B",
    "int16_t": "h",
    "uint16_t": "H",
    "int32_t": "i",
    "uint32_t": "I",
    "int64_t": "q",
    "uint64_t": "Q",
    "float": "f",
    "double": "d",
    "bool": "?",
    "char": "c",
}

# PX4 logging levels of 'L' messages (syslog-like, as the characters '0'..'7')
LOG_LEVELS = {0: b"0", 1: b"1", 2: b"2", 3: b"3", 4: b"4", 5: b"5", 6: b"6", 7: b"7"}


def _field_struct(type_name: str) -> tuple[str, int]:
    """('f', 1) for 'float', ('f', 4) for 'float[4]'; ValueError for a type ULog does not have."""
    base, count = type_name, 1
    if type_name.endswith("]") and "[" in type_name:
        base, _, n = type_name[:-1].partition("[")
        count = int(n)
        if count < 1:
            raise ValueError(f"ULog array size must be >= 1: {type_name!r}")
    if base not in _TYPES:
        raise ValueError(f"not a ULog field type: {type_name!r}")
    return _TYPES[base], count


@dataclass(frozen=True)
class Topic:
    """A logged message format: `fields` after the implicit first field `uint64_t timestamp`."""

    name: str
    fields: tuple[tuple[str, str], ...]  # (type, name), e.g. ("float[4]", "q")
    multi_id: int = 0
    _struct: struct.Struct = field(init=False, repr=False, compare=False)
    _arrays: tuple[int, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.name or any(c in self.name for c in ":;[] "):
            raise ValueError(f"bad ULog topic name {self.name!r}")
        fmt, arrays = "<Q", []
        for type_name, name in self.fields:
            code, count = _field_struct(type_name)
            fmt += f"{count}{code}" if count > 1 else code
            arrays.append(count)
            if name == "timestamp":
                raise ValueError("'timestamp' is implicit (the first field of every topic)")
        object.__setattr__(self, "_struct", struct.Struct(fmt))
        object.__setattr__(self, "_arrays", tuple(arrays))

    @property
    def format_string(self) -> str:
        return f"{self.name}:uint64_t timestamp;" + "".join(f"{t} {n};" for t, n in self.fields)

    @property
    def size(self) -> int:
        return self._struct.size

    def pack(self, timestamp_us: int, values: Sequence[Any]) -> bytes:
        """The data bytes of one sample (arrays given as sequences of their length)."""
        if len(values) != len(self._arrays):
            raise ValueError(f"{self.name}: {len(self._arrays)} values expected, got {len(values)}")
        flat: list[Any] = [int(timestamp_us)]
        for value, count in zip(values, self._arrays, strict=True):
            if count > 1:
                if len(value) != count:
                    raise ValueError(f"{self.name}: array of {count} expected, got {len(value)}")
                flat.extend(value)
            else:
                flat.append(value)
        return self._struct.pack(*flat)


def _msg(kind: bytes, payload: bytes) -> bytes:
    if len(payload) > 0xFFFF:
        raise ValueError(f"ULog message too long ({len(payload)} bytes)")
    return struct.pack("<HB", len(payload), kind[0]) + payload


def _info_value(value: Any) -> tuple[str, bytes]:
    """(ULog type, bytes) of an info value: str -> char[N], bool/int -> int32_t, float -> float."""
    if isinstance(value, str):
        raw = value.encode("utf-8")
        return f"char[{len(raw)}]", raw
    if isinstance(value, bool | int):
        return "int32_t", struct.pack("<i", int(value))
    if isinstance(value, float):
        return "float", struct.pack("<f", value)
    raise TypeError(f"ULog info value must be str, int or float, got {type(value).__name__}")


def header(start_us: int) -> bytes:
    return MAGIC + bytes([VERSION]) + struct.pack("<Q", int(start_us))


def flag_bits() -> bytes:
    """No compat/incompat flags (no appended data): any ULog reader may read the file."""
    return _msg(b"B", bytes(8) + bytes(8) + struct.pack("<3Q", 0, 0, 0))


def format_msg(topic: Topic) -> bytes:
    return _msg(b"F", topic.format_string.encode("ascii"))


def info_msg(key: str, value: Any) -> bytes:
    type_name, raw = _info_value(value)
    k = f"{type_name} {key}".encode("ascii")
    return _msg(b"I", bytes([len(k)]) + k + raw)


def param_msg(name: str, value: float | int) -> bytes:
    """PX4 parameters are int32_t or float."""
    if isinstance(value, bool | int):
        k, raw = f"int32_t {name}".encode("ascii"), struct.pack("<i", int(value))
    else:
        k, raw = f"float {name}".encode("ascii"), struct.pack("<f", float(value))
    return _msg(b"P", bytes([len(k)]) + k + raw)


def add_logged_msg(msg_id: int, topic: Topic) -> bytes:
    return _msg(b"A", struct.pack("<BH", topic.multi_id, msg_id) + topic.name.encode("ascii"))


def data_msg(msg_id: int, payload: bytes) -> bytes:
    return _msg(b"D", struct.pack("<H", msg_id) + payload)


def logging_msg(level: int, timestamp_us: int, text: str) -> bytes:
    return _msg(
        b"L", LOG_LEVELS.get(level, b"6") + struct.pack("<Q", int(timestamp_us)) + text.encode("utf-8")
    )


def dropout_msg(duration_ms: int) -> bytes:
    return _msg(b"O", struct.pack("<H", max(0, min(0xFFFF, int(duration_ms)))))


def sync_msg() -> bytes:
    return _msg(b"S", SYNC_MAGIC)


class ULogFile:
    """Writes one ULog file synchronously (ULogWriter runs this on its own thread). Topics are fixed at open."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        topics: Iterable[Topic],
        *,
        info: Mapping[str, Any] | None = None,
        params: Mapping[str, float | int] | None = None,
        start_us: int = 0,
    ) -> None:
        self.path = Path(path)
        self.topics = list(topics)
        self._ids: dict[tuple[str, int], int] = {}
        self._raw = open(self.path, "wb", buffering=0)  # noqa: SIM115 -- closed by close()
        self.bytes_written = 0
        self.samples = 0
        self.last_timestamp_us = int(start_us)
        out = [header(start_us), flag_bits()]
        for t in self.topics:
            if (t.name, t.multi_id) in self._ids:
                raise ValueError(f"topic {t.name} instance {t.multi_id} given twice")
            if all(o.name != t.name for o in self.topics[: self.topics.index(t)]):
                out.append(format_msg(t))
            self._ids[(t.name, t.multi_id)] = len(self._ids)
        for key, value in (info or {}).items():
            out.append(info_msg(key, value))
        for name, value in (params or {}).items():
            if isinstance(value, bool | int) or (isinstance(value, float) and math.isfinite(value)):
                out.append(param_msg(name, value))
        for t in self.topics:
            out.append(add_logged_msg(self._ids[(t.name, t.multi_id)], t))
        self._write(b"".join(out))

    def _write(self, buf: bytes) -> None:
        view = memoryview(buf)
        while view:
            n = self._raw.write(view)
            if n is None:  # pragma: no cover - a non-blocking file never occurs here
                continue
            view = view[n:]
            self.bytes_written += n

    def encode(self, topic: Topic, timestamp_us: int, values: Sequence[Any]) -> bytes:
        return data_msg(self._ids[(topic.name, topic.multi_id)], topic.pack(timestamp_us, values))

    def write(self, topic: Topic, timestamp_us: int, values: Sequence[Any]) -> None:
        self.write_raw(self.encode(topic, timestamp_us, values), timestamp_us)

    def write_raw(self, buf: bytes, timestamp_us: int = 0, samples: int = 1) -> None:
        self._write(buf)
        self.samples += samples
        self.last_timestamp_us = max(self.last_timestamp_us, int(timestamp_us))

    def log_text(self, level: int, timestamp_us: int, text: str) -> None:
        self._write(logging_msg(level, timestamp_us, text))

    def dropout(self, duration_ms: int) -> None:
        self._write(dropout_msg(duration_ms))

    def close(self) -> None:
        if not self._raw.closed:
            self._raw.close()

    def __enter__(self) -> ULogFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_TEXT = object()  # queue marker of a logged string
WRITER_PERIOD_S = 0.02  # the writer thread drains the queue this often (wall time)


class ULogWriter:
    """A ULogFile behind a bounded queue and a writer thread: `log()` and `text()` cost a length test and a
    deque append on the caller's thread (the physics loop: no lock, no wake-up), the packing and the file I/O happen
    on the writer thread, which drains the queue every WRITER_PERIOD_S. A full queue drops the sample (counted; a
    dropout message marks the gap, as PX4's logger does when its buffer overflows). `close()` writes what is queued
    and closes the file."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        topics: Iterable[Topic],
        *,
        info: Mapping[str, Any] | None = None,
        params: Mapping[str, float | int] | None = None,
        start_us: int = 0,
        max_queue: int = 20000,
    ) -> None:
        self.file = ULogFile(path, topics, info=info, params=params, start_us=start_us)
        self.path = self.file.path
        self._queue: deque[tuple[Any, int, Any]] = deque()  # append/popleft are atomic under the GIL
        self.max_queue = int(max_queue)
        self.dropped = 0
        self.write_errors = 0
        self._dropped_reported = 0
        self._closed = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="viva-ulog", daemon=True)
        self._thread.start()

    # --- producer side (any thread, never blocks) -------------------------------------------
    def log(self, topic: Topic, timestamp_us: int, values: Sequence[Any]) -> bool:
        q = self._queue
        if self._closed or len(q) >= self.max_queue:
            self.dropped += not self._closed
            return False
        q.append((topic, timestamp_us, values))
        return True

    def text(self, level: int, timestamp_us: int, text: str) -> bool:
        q = self._queue
        if self._closed or len(q) >= self.max_queue:
            self.dropped += not self._closed
            return False
        q.append((_TEXT, int(timestamp_us), (int(level), text)))
        return True

    @property
    def bytes_written(self) -> int:
        return self.file.bytes_written

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def samples(self) -> int:
        return self.file.samples

    def close(self, timeout_s: float = 10.0) -> None:
        """Write what is queued, then close the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._thread.join(timeout_s)
        self.file.close()

    # --- writer thread ------------------------------------------------------------------------
    def _drain(self) -> bool:
        """Write what is queued now; False when the file cannot be written any more."""
        q = self._queue
        f = self.file
        parts: list[bytes] = []
        n = 0
        last_us = f.last_timestamp_us
        if self.dropped != self._dropped_reported:
            self._dropped_reported = self.dropped
            parts.append(dropout_msg(1))  # samples lost here: mark the gap
        for _ in range(len(q)):
            topic, ts, values = q.popleft()
            try:
                if topic is _TEXT:
                    parts.append(logging_msg(values[0], ts, values[1]))
                else:
                    parts.append(f.encode(topic, ts, values))
                    n += 1
                    last_us = max(last_us, int(ts))
            except (ValueError, TypeError, struct.error, KeyError) as exc:  # a bad sample: skipped, counted
                self.write_errors += 1
                log.debug("ulog: sample of %s skipped: %s", getattr(topic, "name", "text"), exc)
        if not parts:
            return True
        try:
            f.write_raw(b"".join(parts), last_us, n)
        except (OSError, ValueError) as exc:  # disk full, file closed: stop writing, keep the run going
            self.write_errors += 1
            log.warning("ulog: cannot write %s: %s", f.path, exc)
            return False
        return True

    def _run(self) -> None:
        while True:
            stopping = self._stop.wait(WRITER_PERIOD_S)
            if not self._drain():
                break
            if stopping:
                self._drain()  # anything appended while the last drain ran
                break
        self._queue.clear()


__all__ = ["Topic", "ULogFile", "ULogWriter"]
