"""Parameter protocol (PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET -> PARAM_VALUE) with PX4's encoding.

PX4 encodes parameters bytewise: an INT32 parameter travels as its 4 raw bytes inside PARAM_VALUE.param_value
(a float field), a REAL32 one as the float itself. PX4's answers to bad requests, reproduced here:
- unknown name (read or set): no PARAM_VALUE, a STATUSTEXT "[pm] unknown param: NAME" (clients time out and retry);
- PARAM_SET with a type that differs from the parameter's: no change, STATUSTEXT "[pm] param types mismatch";
- a value our ParamStore refuses (out of range, NaN): no change, STATUSTEXT with the reason, and a PARAM_VALUE with
  the unchanged value so the client sees at once that the set did not take.
"""

from __future__ import annotations

import logging
import math
import struct

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.params import ParamStore, ParamType
from viva_sitl.autopilot.types import Severity
from viva_sitl.mavlink.base import MavMessage, Origin, Outbox, StatusSink

log = logging.getLogger(__name__)

PARAM_ID_CHARS = 16


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


class ParamProtocol:
    def __init__(self, store: ParamStore, out: Outbox, statustext: StatusSink) -> None:
        self.store = store
        self.out = out
        self.statustext = statustext
        self.sets_accepted = 0
        self.sets_rejected = 0

    def _value_msg(self, name: str, index: int, count: int) -> MavMessage:
        spec = self.store.spec(name)
        wire = encode_param_value(self.store.get(name), spec.type)
        return mavlink2.MAVLink_param_value_message(
            name.encode("ascii")[:PARAM_ID_CHARS], wire, int(spec.type), count, index
        )

    def handle_request_list(self, origin: Origin, msg: MavMessage) -> None:
        names = self.store.names()
        for i, name in enumerate(names):
            self.out.reply(origin, self._value_msg(name, i, len(names)))

    def handle_request_read(self, origin: Origin, msg: MavMessage) -> None:
        names = self.store.names()
        index = int(msg.param_index)
        if index >= 0:
            if index >= len(names):
                self.statustext(origin, Severity.ERROR, f"[pm] param index out of range: {index}")
                return
            name = names[index]
        else:
            name = str(msg.param_id)
            if name not in names:
                self.statustext(origin, Severity.ERROR, f"[pm] unknown param: {name}")
                return
            index = names.index(name)
        self.out.reply(origin, self._value_msg(name, index, len(names)))

    def handle_set(self, origin: Origin, msg: MavMessage) -> None:
        names = self.store.names()
        name = str(msg.param_id)
        if name not in names:
            self.sets_rejected += 1
            self.statustext(origin, Severity.ERROR, f"[pm] unknown param: {name}")
            return
        spec = self.store.spec(name)
        if int(msg.param_type) != int(spec.type):
            self.sets_rejected += 1
            self.statustext(origin, Severity.ERROR, f"[pm] param types mismatch: {name}")
            return
        value = decode_param_value(float(msg.param_value), spec.type)
        try:
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite")
            self.store.set(name, value)
        except (KeyError, ValueError) as exc:
            self.sets_rejected += 1
            self.statustext(origin, Severity.ERROR, f"[pm] {name} rejected: {exc}")
        else:
            self.sets_accepted += 1
            log.info("param %s = %s", name, self.store.get(name))
        # PX4 announces the (new or unchanged) value to every link
        self.out.broadcast(self._value_msg(name, names.index(name), len(names)))
