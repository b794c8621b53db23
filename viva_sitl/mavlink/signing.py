"""MAVLink 2 message signing, PX4-style.

PX4's model (src/modules/mavlink/mavlink_sign_control.cpp, parameter MAV_SIGN_CFG):
- MAV_SIGN_CFG 0: signing off: every message is accepted, signed or not.
- MAV_SIGN_CFG 1 (signing on except on USB links) and 2 (always): a message must carry a valid signature. RADIO_STATUS,
  ADSB_VEHICLE and COLLISION are accepted unsigned. All our links are UDP (never USB), so 1 and 2 behave the same.
  Without a key every unsigned message is rejected on UDP.
- The key comes from SETUP_SIGNING (32-byte key + initial timestamp), which is itself subject to the rules above
  (with signing on it must be signed with the current key); PX4 stores it on the SD card. Here the key can also come
  from the config (`[mavlink] signing_key`) or the command line (`--signing-key`), and lives for the run.
- Once a key is set, every outgoing message is signed (PX4 sets MAVLINK_SIGNING_FLAG_SIGN_OUTGOING).

Rejected messages are dropped before any handler sees them and counted (`unsigned_rejected` in the stats).
"""

from __future__ import annotations

import hashlib
import os
import re
import time

from pymavlink.dialects.v20 import common as mavlink2

__all__ = [
    "SigningState",
    "parse_key",
    "ALWAYS_ACCEPTED_UNSIGNED",
    "SIGN_CFG_OFF",
    "SIGN_CFG_NON_USB",
    "SIGN_CFG_ALWAYS",
]

M = mavlink2
SIGN_CFG_OFF = 0
SIGN_CFG_NON_USB = 1
SIGN_CFG_ALWAYS = 2
ALWAYS_ACCEPTED_UNSIGNED = frozenset(
    {M.MAVLINK_MSG_ID_RADIO_STATUS, M.MAVLINK_MSG_ID_ADSB_VEHICLE, M.MAVLINK_MSG_ID_COLLISION}
)
SIGNING_EPOCH_UNIX_S = (
    1420070400.0  # 2015-01-01T00:00:00Z: the signing timestamp counts 10 us units from here
)
_HEX_KEY = re.compile(r"^(?:0x)?([0-9a-fA-F]{64})$")


def parse_key(text: str) -> bytes:
    """A 32-byte signing key from 64 hex digits, or else the SHA-256 of a passphrase (MAVProxy's `signing setup`,
    QGroundControl's key entry). ValueError for an empty key."""
    text = text.strip()
    if not text:
        raise ValueError("the MAVLink signing key must not be empty")
    m = _HEX_KEY.match(text)
    if m is not None:
        return bytes.fromhex(m.group(1))
    return hashlib.sha256(text.encode("utf-8")).digest()


def signing_timestamp_now() -> int:
    """The current signing timestamp (10 us units since 2015-01-01 UTC)."""
    return int((time.time() - SIGNING_EPOCH_UNIX_S) * 100_000)


class SigningState:
    """The vehicle's signing key and MAV_SIGN_CFG, shared by every parser and encoder of the endpoint.

    `revision` changes with every key/mode change: parsers and encoders re-apply the state when it does."""

    def __init__(self, key: bytes | None = None, sign_cfg: int = SIGN_CFG_OFF) -> None:
        if key is not None and len(key) != 32:
            raise ValueError(f"a MAVLink signing key has 32 bytes, got {len(key)}")
        if sign_cfg not in (SIGN_CFG_OFF, SIGN_CFG_NON_USB, SIGN_CFG_ALWAYS):
            raise ValueError(f"MAV_SIGN_CFG must be 0, 1 or 2, got {sign_cfg}")
        self.key = key
        self.sign_cfg = sign_cfg
        self.initial_timestamp = signing_timestamp_now()
        self.revision = 0
        self._unknown_key = os.urandom(32)  # checks with no key configured: no signature can match it

    @property
    def required(self) -> bool:
        return self.sign_cfg != SIGN_CFG_OFF

    def set_key(self, key: bytes, initial_timestamp: int) -> None:
        """SETUP_SIGNING: a new key (an all-zero key and timestamp 0 clears it, as PX4)."""
        if len(key) != 32:
            raise ValueError(f"a MAVLink signing key has 32 bytes, got {len(key)}")
        self.key = None if (not any(key) and initial_timestamp == 0) else bytes(key)
        self.initial_timestamp = max(int(initial_timestamp), signing_timestamp_now())
        self.revision += 1

    def apply_to_parser(self, mav: mavlink2.MAVLink) -> None:
        sig = mav.signing
        sig.stream_timestamps = {}
        sig.timestamp = 0  # accept any new stream; replays within a stream are refused by its timestamps
        if not self.required:
            sig.secret_key = None  # MAV_SIGN_CFG 0: no checks at all
            sig.allow_unsigned_callback = None
            return
        sig.secret_key = self.key if self.key is not None else self._unknown_key
        sig.allow_unsigned_callback = _accept_unsigned

    def apply_to_encoder(self, mav: mavlink2.MAVLink, link_id: int) -> None:
        sig = mav.signing
        sig.secret_key = self.key
        sig.sign_outgoing = self.key is not None
        sig.link_id = link_id & 0xFF
        sig.timestamp = max(sig.timestamp, self.initial_timestamp)


def _accept_unsigned(_mav: mavlink2.MAVLink, msgid: int) -> bool:
    return msgid in ALWAYS_ACCEPTED_UNSIGNED
