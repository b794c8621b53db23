"""Parameter protocol (PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET -> PARAM_VALUE) as PX4's mavlink module.

PX4 encodes parameters bytewise: an INT32 parameter travels as its 4 raw bytes inside PARAM_VALUE.param_value
(a float field), a REAL32 one as the float itself. What PX4 does, reproduced here:
- PARAM_REQUEST_LIST: first a `_HASH_CHECK` PARAM_VALUE (index -1 = 65535, type UINT32, the CRC of all values:
  QGroundControl's cache key), then every parameter in index order, streamed at a bounded rate (PX4 sends up to 20
  per mavlink-loop iteration on UDP) by an owned task, so a 1000+ parameter list never blocks the loop. A second
  request while a list is streaming to the same peer restarts it at index 0 without the hash (as PX4).
  PARAM_SET `_HASH_CHECK` (QGC: "my cache is current") stops the stream to that peer.
- PARAM_REQUEST_READ by index (>= 0) or by name (index -1); `_HASH_CHECK` by name answers the hash.
- unknown name (read or set) or index: no PARAM_VALUE, a STATUSTEXT "[pm] unknown param: NAME" (clients time out
  and retry; PX4 logs PX4_ERR);
- PARAM_SET with a type that differs from the parameter's: no change, no PARAM_VALUE, STATUSTEXT
  "[pm] param types mismatch: NAME";
- PARAM_SET of an out-of-range value: stored and echoed as PX4 does (PX4 does not enforce min/max; QGC warns);
- a value no parameter can hold (NaN/inf float; our rule, PX4 would store it): no change, STATUSTEXT with the reason,
  and a PARAM_VALUE with the unchanged value so the client sees at once that the set did not take.
"""

from __future__ import annotations

import asyncio
import logging
import math
import struct
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.params import ParamStore, ParamType
from viva_sitl.autopilot.types import Severity
from viva_sitl.mavlink.base import MavMessage, Origin, Outbox, StatusSink

log = logging.getLogger(__name__)

PARAM_ID_CHARS = 16
HASH_PARAM = "_HASH_CHECK"
LIST_BURST = 20  # PARAM_VALUEs per burst (PX4: up to 20 per mavlink loop iteration on UDP)
LIST_BURST_PERIOD_S = 0.01  # one burst per this: 2000 parameters/s, a 1172-parameter list in ~0.6 s
MAX_LIST_STREAMS = 16  # peers listing at once; a new one replaces the oldest
# PX4 (MavlinkParametersManager::send_untransmitted) broadcasts every changed parameter again ~5 ms after the change,
# besides the direct PARAM_VALUE answering the PARAM_SET. MAVSDK relies on it: the answer to its own PARAM_SET is
# consumed by the set, only the second PARAM_VALUE reaches its parameter subscriptions (the failure plugin's cached
# SYS_FAILURE_EN, say).
UNTRANSMITTED_DELAY_S = 0.005


def encode_param_value(value: float, ptype: ParamType) -> float:
    """The float that goes into PARAM_VALUE.param_value: INT32 bytes reinterpreted as float32 (PX4 bytewise)."""
    if ptype == ParamType.INT32:
        return float(struct.unpack("<f", struct.pack("<i", int(value)))[0])
    return float(value)


def decode_param_value(wire: float, ptype: ParamType) -> float:
    """Inverse of encode_param_value: PARAM_SET.param_value -> the parameter's value."""
    if ptype == ParamType.INT32:
        return float(struct.unpack("<i", struct.pack("<f", wire))[0])
    return float(wire)


@dataclass
class _ListStream:
    origin: Origin
    next_index: int  # -1: the hash comes next


class ParamProtocol:
    def __init__(self, store: ParamStore, out: Outbox, statustext: StatusSink) -> None:
        self.store = store
        self.out = out
        self.statustext = statustext
        self.sets_accepted = 0
        self.sets_rejected = 0
        self.list_values_sent = 0
        self._streams: dict[tuple[object, tuple[str, int]], _ListStream] = {}
        self._untransmitted: dict[str, None] = {}  # changed by a PARAM_SET, broadcast again by run()
        self._wake = asyncio.Event()

    # --- messages -------------------------------------------------------------------------------
    def _value_msg(self, name: str) -> MavMessage:
        spec = self.store.spec(name)
        wire = encode_param_value(self.store.stored(name), spec.type)
        return mavlink2.MAVLink_param_value_message(
            name.encode("ascii")[:PARAM_ID_CHARS],
            wire,
            int(spec.type),
            len(self.store),
            self.store.index(name),
        )

    def _hash_msg(self) -> MavMessage:
        wire = struct.unpack("<f", struct.pack("<I", self.store.hash_check()))[0]
        return mavlink2.MAVLink_param_value_message(
            HASH_PARAM.encode("ascii"), wire, mavlink2.MAV_PARAM_TYPE_UINT32, len(self.store), 0xFFFF
        )

    # --- PARAM_REQUEST_LIST: paced by run() -------------------------------------------------------
    def handle_request_list(self, origin: Origin, msg: MavMessage) -> None:
        key = (origin.link, origin.addr)
        running = key in self._streams
        self._streams.pop(key, None)
        self._streams[key] = _ListStream(origin, 0 if running else -1)
        while len(self._streams) > MAX_LIST_STREAMS:
            del self._streams[next(iter(self._streams))]
        self._wake.set()

    def send_burst(self, n: int = LIST_BURST) -> None:
        """Up to `n` PARAM_VALUEs to every peer with a list in progress (run() calls this; tests may too)."""
        count = len(self.store)
        for key, st in list(self._streams.items()):
            for _ in range(n):
                if st.next_index < 0:
                    self.out.reply(st.origin, self._hash_msg())
                else:
                    self.out.reply(st.origin, self._value_msg(self.store.name_at(st.next_index)))
                    self.list_values_sent += 1
                st.next_index += 1
                if st.next_index >= count:
                    del self._streams[key]
                    break

    def send_untransmitted(self) -> None:
        """Broadcast once more every parameter a PARAM_SET changed since the last call (PX4's send_untransmitted)."""
        names, self._untransmitted = list(self._untransmitted), {}
        for name in names:
            self.out.broadcast(self._value_msg(name))

    async def run(self) -> None:
        """The owned task that paces list answers (a burst every LIST_BURST_PERIOD_S while any list streams) and
        re-announces changed parameters UNTRANSMITTED_DELAY_S after a PARAM_SET."""
        while True:
            if not self._streams and not self._untransmitted:
                self._wake.clear()
                await self._wake.wait()
            if self._untransmitted:
                await asyncio.sleep(UNTRANSMITTED_DELAY_S)
                try:
                    self.send_untransmitted()
                except Exception:  # a bug: log it, keep the task alive
                    log.exception("parameter change broadcast failed")
                    self._untransmitted.clear()
            if not self._streams:
                continue
            try:
                self.send_burst()
            except Exception:  # a bug: log it, drop the streams, keep the task alive
                log.exception("parameter list streaming failed")
                self._streams.clear()
            await asyncio.sleep(LIST_BURST_PERIOD_S)

    # --- PARAM_REQUEST_READ ----------------------------------------------------------------------
    def handle_request_read(self, origin: Origin, msg: MavMessage) -> None:
        index = int(msg.param_index)
        if index >= 0:
            try:
                name = self.store.name_at(index)
            except IndexError:
                self.statustext(origin, Severity.ERROR, f"[pm] unknown param ID: {index}")
                return
        else:
            name = str(msg.param_id)
            if name == HASH_PARAM:
                self.out.reply(origin, self._hash_msg())
                return
            if name not in self.store:
                self.statustext(origin, Severity.ERROR, f"[pm] unknown param: {name}")
                return
        self.out.reply(origin, self._value_msg(name))

    # --- PARAM_SET -------------------------------------------------------------------------------
    def handle_set(self, origin: Origin, msg: MavMessage) -> None:
        name = str(msg.param_id)
        if name == HASH_PARAM:  # QGC's cache matched: stop the list stream to this peer
            self._streams.pop((origin.link, origin.addr), None)
            return
        if name not in self.store:
            self.sets_rejected += 1
            self.statustext(origin, Severity.ERROR, f"[pm] unknown param: {name}")
            return
        spec = self.store.spec(name)
        if int(msg.param_type) != int(spec.type):
            self.sets_rejected += 1
            self.statustext(origin, Severity.ERROR, f"[pm] param types mismatch: {name}")
            return
        value = decode_param_value(float(msg.param_value), spec.type)
        before = self.store.stored(name)
        try:
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite")
            self.store.set(name, value)
        except (KeyError, ValueError) as exc:
            self.sets_rejected += 1
            self.statustext(origin, Severity.ERROR, f"[pm] {name} rejected: {exc}")
        else:
            self.sets_accepted += 1
            log.info("param %s = %s", name, self.store.stored(name))
            if (
                self.store.stored(name) != before
            ):  # PX4 re-announces a changed value (see UNTRANSMITTED_DELAY_S)
                self._untransmitted[name] = None
                self._wake.set()
        # PX4 announces the (new or unchanged) value to every link
        self.out.broadcast(self._value_msg(name))
