"""pymavlink as a codec only: decoding one UDP datagram at a time, and per-link encoders.

pymavlink's parser keeps state across calls: a truncated frame would swallow the start of the next datagram. Every
datagram is therefore parsed from a clean parser state, and after a frame that fails its length/CRC check the
parser resynchronises one byte after that frame's start marker, so garbage cannot hide a valid frame behind it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.mavlink.base import MavMessage
from viva_sitl.mavlink.signing import SigningState, signing_timestamp_now


def message_id(name: str) -> int:
    """MAVLink message id by name ("ATTITUDE" -> 30); ValueError for unknown names."""
    msgid = getattr(mavlink2, f"MAVLINK_MSG_ID_{name.upper()}", None)
    if not isinstance(msgid, int):
        raise ValueError(f"unknown MAVLink message name {name!r}")
    return msgid


# A datagram from a real client holds one or a few frames; adversarial garbage full of start markers would
# otherwise cost one CRC per byte. Past this many decode attempts the rest of the datagram is dropped (counted).
MAX_ATTEMPTS_PER_DATAGRAM = 256


@dataclass
class ParseResult:
    messages: list[MavMessage] = field(default_factory=list)
    bad_frames: int = 0  # frames with a bad CRC/length/header, or truncated at the end of the datagram
    garbage_bytes: int = 0  # bytes skipped while looking for a start marker
    unknown: int = 0  # well-formed frames whose message id is not in the dialect
    unsigned_rejected: int = 0  # signing required: frames without a valid signature (dropped whole)


class DatagramParser:
    """Decoder for one peer (one parser per peer address). `parse(datagram)` never raises on bad input."""

    def __init__(self, signing: SigningState | None = None) -> None:
        self._mav = mavlink2.MAVLink(None)
        self._mav.robust_parsing = True  # bad data comes back as MAVLink_bad_data instead of raising
        self._signing = signing
        self._signing_rev = -1

    def _reset(self, buf: bytearray, index: int) -> None:
        mav = self._mav
        mav.buf = buf
        mav.buf_index = index
        mav.expected_length = mavlink2.HEADER_LEN_V1 + 2
        mav.have_prefix_error = False

    def parse(self, datagram: bytes) -> ParseResult:
        result = ParseResult()
        buf = bytearray(datagram)
        mav = self._mav
        if self._signing is not None and self._signing.revision != self._signing_rev:
            self._signing.apply_to_parser(mav)
            self._signing_rev = self._signing.revision
        self._reset(buf, 0)
        for _ in range(MAX_ATTEMPTS_PER_DATAGRAM):
            if mav.buf_len() <= 0:
                break
            start = mav.buf_index
            try:
                msg = mav.parse_char(b"")
            except Exception:  # pymavlink should not raise with robust_parsing; if it does, resync past it
                msg = mavlink2.MAVLink_bad_data(bytes(buf[start : start + 1]), "decoder exception")
            if msg is None:
                # a frame that needs more bytes than the datagram holds: truncated; look for a frame after its marker
                result.bad_frames += 1
                self._reset(buf, start + 1)
                continue
            if isinstance(msg, mavlink2.MAVLink_bad_data):
                if msg.reason == "Bad prefix":
                    result.garbage_bytes += len(msg.data)
                elif msg.reason == "Invalid signature":
                    # a whole, well-formed frame: skipped (the parser's index is already past it)
                    result.unsigned_rejected += 1
                else:
                    result.bad_frames += 1
                    self._reset(buf, start + 1)
                continue
            if isinstance(msg, mavlink2.MAVLink_unknown):
                result.unknown += 1
                continue
            result.messages.append(msg)
        else:
            if mav.buf_len() > 0:
                result.garbage_bytes += mav.buf_len()
        self._reset(bytearray(), 0)
        return result


class Encoder:
    """One outgoing MAVLink 2 stream (per link and component: each has its own sequence number)."""

    def __init__(
        self, sysid: int, compid: int, signing: SigningState | None = None, link_id: int = 0
    ) -> None:
        self.mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self._signing = signing
        self._signing_rev = -1
        self._link_id = link_id

    def pack(self, msg: MavMessage) -> bytes:
        signing = self._signing
        if signing is not None:
            if signing.revision != self._signing_rev:
                signing.apply_to_encoder(self.mav, self._link_id)
                self._signing_rev = signing.revision
            if self.mav.signing.sign_outgoing:  # the timestamp follows the clock (never backwards)
                self.mav.signing.timestamp = max(self.mav.signing.timestamp, signing_timestamp_now())
        buf = bytes(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256
        return buf
