"""MAVLink FTP (FILE_TRANSFER_PROTOCOL, message 110) server side: an empty, read-only file system that answers at once.

viva-sitl has no onboard files to offer (no parameter file, no component-metadata JSON, no logs), so it does not
advertise MAV_PROTOCOL_CAPABILITY_FTP. Clients that try FTP anyway -- MAVProxy's parameter download, QGroundControl's
component-metadata download, pymavlink's `mavftp` -- get a definite answer on the first try instead of a timeout, and
fall back (MAVProxy and pymavlink to PARAM_REQUEST_LIST, QGC to its built-in PX4 metadata):

    ResetSessions                       -> ACK (no sessions exist)
    TerminateSession                    -> ACK
    OpenFileRO / CalcFileCRC32          -> NAK FileNotFound
    ListDirectory "" or "/"             -> NAK EOF (an empty root directory); any other path -> NAK FileNotFound
    ReadFile / BurstReadFile            -> NAK InvalidSession (no file can be open)
    CreateFile, OpenFileWO, WriteFile, TruncateFile, RemoveFile, Rename, Create/RemoveDirectory
                                        -> NAK FileProtected (read-only)
    anything else                       -> NAK UnknownCommand

Replies follow the protocol: seq = request seq + 1, same session, req_opcode = the request's opcode, opcode ACK (128)
or NAK (129) with the error code in data[0], addressed to the requesting system/component.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.mavlink.base import MavMessage, Origin, Outbox

HEADER = struct.Struct("<HBBBBBBI")  # seq, session, opcode, size, req_opcode, burst_complete, padding, offset
PAYLOAD_BYTES = 251
DATA_BYTES = PAYLOAD_BYTES - HEADER.size  # 239


class Op(enum.IntEnum):
    NONE = 0
    TERMINATE_SESSION = 1
    RESET_SESSIONS = 2
    LIST_DIRECTORY = 3
    OPEN_FILE_RO = 4
    READ_FILE = 5
    CREATE_FILE = 6
    WRITE_FILE = 7
    REMOVE_FILE = 8
    CREATE_DIRECTORY = 9
    REMOVE_DIRECTORY = 10
    OPEN_FILE_WO = 11
    TRUNCATE_FILE = 12
    RENAME = 13
    CALC_FILE_CRC32 = 14
    BURST_READ_FILE = 15
    ACK = 128
    NAK = 129


class FtpError(enum.IntEnum):
    NONE = 0
    FAIL = 1
    FAIL_ERRNO = 2
    INVALID_DATA_SIZE = 3
    INVALID_SESSION = 4
    NO_SESSIONS_AVAILABLE = 5
    EOF = 6
    UNKNOWN_COMMAND = 7
    FILE_EXISTS = 8
    FILE_PROTECTED = 9
    FILE_NOT_FOUND = 10


_WRITES = frozenset(
    {
        Op.CREATE_FILE,
        Op.OPEN_FILE_WO,
        Op.WRITE_FILE,
        Op.TRUNCATE_FILE,
        Op.REMOVE_FILE,
        Op.RENAME,
        Op.CREATE_DIRECTORY,
        Op.REMOVE_DIRECTORY,
    }
)


@dataclass(frozen=True)
class FtpRequest:
    seq: int
    session: int
    opcode: int
    size: int
    offset: int
    data: bytes

    @classmethod
    def unpack(cls, payload: bytes | list[int]) -> FtpRequest | None:
        raw = bytes(payload)
        if len(raw) < HEADER.size:
            return None
        seq, session, opcode, size, _req, _burst, _pad, offset = HEADER.unpack_from(raw)
        return cls(seq, session, opcode, size, offset, raw[HEADER.size : HEADER.size + min(size, DATA_BYTES)])

    @property
    def path(self) -> str:
        return self.data.split(b"\0", 1)[0].decode("utf-8", errors="replace")


def reply_payload(req: FtpRequest, opcode: Op, data: bytes = b"") -> bytes:
    """The 251-byte payload of the answer to `req`."""
    head = HEADER.pack(
        (req.seq + 1) & 0xFFFF, req.session, int(opcode), len(data), req.opcode & 0xFF, 0, 0, 0
    )
    return (head + data).ljust(PAYLOAD_BYTES, b"\0")


def answer(req: FtpRequest) -> tuple[Op, FtpError | None]:
    """What this empty read-only file system answers to `req` (ACK with no data, or NAK with an error)."""
    op = req.opcode
    if op in (Op.RESET_SESSIONS, Op.TERMINATE_SESSION):
        return Op.ACK, None
    if op in (Op.OPEN_FILE_RO, Op.CALC_FILE_CRC32):
        return Op.NAK, FtpError.FILE_NOT_FOUND
    if op == Op.LIST_DIRECTORY:
        return Op.NAK, FtpError.EOF if req.path.strip("/") == "" else FtpError.FILE_NOT_FOUND
    if op in (Op.READ_FILE, Op.BURST_READ_FILE):
        return Op.NAK, FtpError.INVALID_SESSION
    if op in _WRITES:
        return Op.NAK, FtpError.FILE_PROTECTED
    return Op.NAK, FtpError.UNKNOWN_COMMAND


class FtpServer:
    def __init__(self, out: Outbox) -> None:
        self.out = out
        self.requests = 0
        self.naks = 0

    def handle(self, origin: Origin, msg: MavMessage) -> None:
        req = FtpRequest.unpack(msg.payload)
        if req is None or req.opcode in (Op.ACK, Op.NAK):
            return  # not a request (or another server's reply): nothing to answer
        self.requests += 1
        opcode, error = answer(req)
        data = b"" if error is None else bytes([int(error)])
        if error is not None:
            self.naks += 1
        self.out.reply(
            origin,
            mavlink2.MAVLink_file_transfer_protocol_message(
                0, origin.sysid, origin.compid, list(reply_payload(req, opcode, data))
            ),
        )
