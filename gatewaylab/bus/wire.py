"""Sans-I/O codec of the cross-process bus protocol (documented in docs/bus-wire.md).

A stream (Unix socket or TCP on 127.0.0.1) of records, each ``u16 length`` (bytes after the
length field, little-endian) + ``u8 type`` + body. Reliable and ordered because the stream is.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import FrameError, LocalError, ProtocolError

__all__ = [
    "FILTER",
    "FRAME",
    "HELLO",
    "LENGTH",
    "MAX_FILTERS",
    "MAX_RECORD",
    "STATUS",
    "STATUS_DETAIL",
    "TIMEBASE",
    "TXDONE",
    "VERSION",
    "WELCOME",
    "AcceptanceFilter",
    "Bye",
    "ControllerStateCode",
    "ErrorCode",
    "FilterMatch",
    "Filters",
    "FrameFlags",
    "FrameRecord",
    "Hello",
    "Record",
    "RecordDecoder",
    "RecordType",
    "Status",
    "StatusKind",
    "TimeBase",
    "TxDone",
    "TxOutcome",
    "Welcome",
    "decode_body",
    "encode_bye",
    "encode_filters",
    "encode_frame",
    "encode_hello",
    "encode_status",
    "encode_timebase",
    "encode_txdone",
    "encode_welcome",
]


VERSION = 1
MAX_RECORD = 1 + 14 + 64 + 256  # the longest legal record body (a HELLO with a long name)

LENGTH = struct.Struct("<H")
HELLO = struct.Struct("<BB")           # version, options
WELCOME = struct.Struct("<BBII")       # version, flags, bitrate, data_bitrate
FRAME = struct.Struct("<IBBd")         # can_id, flags, dlc, timestamp
STATUS = struct.Struct("<BBHHd")       # kind, state, tec, rec, timestamp
STATUS_DETAIL = struct.Struct("<BB")   # optional tail of STATUS: error kind + transmitter, or the old state
TXDONE = struct.Struct("<BH")          # outcome, count
TIMEBASE = struct.Struct("<d")         # Unix time of bus time 0
FILTER = struct.Struct("<IIB")         # can_id, can_mask, match (one entry of a FILTER record)

#: The most acceptance filters one FILTER record carries (a client with more filters itself).
MAX_FILTERS = (MAX_RECORD - 1) // FILTER.size


class RecordType(IntEnum):
    """The type byte after a record's length field; selects the body layout (docs/bus-wire.md record table)."""

    HELLO = 0x01     # client -> server: version, options (bit 0 receive own, bit 1 CAN FD, bit 2 listen-only), name
    WELCOME = 0x02   # server -> client: version, flags (bit 0 FD bus), bitrates, bus name
    FRAME = 0x03     # both ways: one CAN (FD) frame; the server fills in the bus time
    STATUS = 0x04    # server -> client: an error frame or a controller state change
    BYE = 0x05       # either way: the sender closes; body is the reason (UTF-8)
    TXDONE = 0x06    # server -> client: frames of this client that left its transmit queue
    TIMEBASE = 0x07  # server -> client, right after WELCOME: Unix time of bus time 0
    FILTER = 0x08    # client -> server: acceptance filters; server -> client: filters in force


class FrameFlags:
    """Bits of a FRAME record's flags byte (docs/bus-wire.md, type 0x03); ``ALL`` lets decoding reject unknown bits."""

    EXTENDED = 0x01
    RTR = 0x02
    FD = 0x04
    BRS = 0x08
    ESI = 0x10
    ECHO = 0x20      # server -> client: the client's own frame, transmitted (receive-own option)
    ALL = 0x3F


class StatusKind(IntEnum):
    """The ``kind`` byte of a STATUS record: an error frame seen on the bus or a controller state change."""

    ERROR_FRAME = 1
    STATE = 2


class ErrorCode(IntEnum):
    """The error kind in the optional tail of an ERROR_FRAME STATUS (the bus's ErrorKind, docs/bus-wire.md)."""

    UNKNOWN = 0
    ACK = 1
    CRC = 2
    BIT = 3
    FORM = 4
    STUFF = 5


class TxOutcome(IntEnum):
    """The ``outcome`` of a TXDONE record: how a client's frames left its queue (docs/bus-wire.md "Transmit queue")."""

    TRANSMITTED = 0   # sent and acknowledged (or dropped by fault injection, as the sender sees it)
    ABORTED = 1       # given up by the controller: flushed at bus-off, single-shot after an error
    REFUSED = 2       # never queued: the controller refused it (bus-off, FD on a classic bus)


class FilterMatch(IntEnum):
    """The ``match`` byte of a FILTER entry: which identifier type the filter accepts (docs/bus-wire.md "Filters")."""

    ANY = 0           # standard and extended identifiers
    STANDARD = 1
    EXTENDED = 2


class ControllerStateCode(IntEnum):
    """The ``state`` byte of STATUS: the client's controller error state; send() waits only while error-active."""

    ERROR_ACTIVE = 0
    ERROR_PASSIVE = 1
    BUS_OFF = 2


@dataclass(frozen=True, slots=True)
class Hello:
    """A decoded HELLO: the first record of a client, with its protocol version, receive-own/FD/listen-only
    options and name."""

    version: int
    receive_own: bool
    fd: bool
    name: str
    listen_only: bool = False


@dataclass(frozen=True, slots=True)
class Welcome:
    """A decoded WELCOME, the server's answer to HELLO: whether the bus is CAN FD, its bitrates and its name."""

    version: int
    fd: bool
    bitrate: int
    data_bitrate: int
    bus_name: str


@dataclass(frozen=True, slots=True)
class FrameRecord:
    """A decoded FRAME: one CAN (FD) frame with its bus-time stamp; ``echo`` marks the client's own frame sent back."""

    frame: CanFrame
    timestamp: float
    echo: bool = False


@dataclass(frozen=True, slots=True)
class Status:
    """A decoded STATUS: an error frame or controller state change with the error counters, stamped in bus time."""

    kind: StatusKind
    state: ControllerStateCode
    tec: int
    rec: int
    timestamp: float
    #: ERROR_FRAME: why the error frame was sent and whether this client's controller transmitted
    error: ErrorCode = ErrorCode.UNKNOWN
    transmitter: bool = False
    #: STATE: the state before the change (None from a sender without the tail)
    old: ControllerStateCode | None = None


@dataclass(frozen=True, slots=True)
class Bye:
    """A decoded BYE: the peer closes the connection after it; ``reason`` says why (e.g. the malformed record)."""

    reason: str


@dataclass(frozen=True, slots=True)
class TxDone:
    """A decoded TXDONE: ``count`` of the client's frames left its transmit queue, which bounds its frames in flight."""

    outcome: TxOutcome
    count: int


@dataclass(frozen=True, slots=True)
class TimeBase:
    """A decoded TIMEBASE: the Unix time of bus time 0, to turn record timestamps into wall-clock time."""

    wall_epoch: float


@dataclass(frozen=True, slots=True)
class AcceptanceFilter:
    """``frame.can_id & can_mask == can_id & can_mask`` (python-can's and SocketCAN's rule)."""

    can_id: int
    can_mask: int
    match: FilterMatch = FilterMatch.ANY

    def accepts(self, frame: CanFrame) -> bool:
        """Whether ``frame`` passes; the server and a client filtering for itself apply this same rule."""
        if self.match is not FilterMatch.ANY and (self.match is FilterMatch.EXTENDED) != frame.extended:
            return False
        return (frame.can_id ^ self.can_id) & self.can_mask == 0


@dataclass(frozen=True, slots=True)
class Filters:
    """Acceptance filters; none means every frame passes."""

    filters: tuple[AcceptanceFilter, ...]


Record = Hello | Welcome | FrameRecord | Status | Bye | TxDone | TimeBase | Filters


def _record(rtype: RecordType, body: bytes) -> bytes:
    return LENGTH.pack(len(body) + 1) + bytes((rtype,)) + body


def encode_hello(name: str, receive_own: bool = False, fd: bool = True, listen_only: bool = False) -> bytes:
    """The HELLO record a client sends first to join a bus (name truncated to 255 bytes); a listen-only
    client's controller never transmits and never acknowledges (a bus monitor)."""
    opts = (1 if receive_own else 0) | (2 if fd else 0) | (4 if listen_only else 0)
    return _record(RecordType.HELLO, HELLO.pack(VERSION, opts) + name.encode()[:255])


def encode_welcome(bus_name: str, bitrate: int, data_bitrate: int | None) -> bytes:
    """The WELCOME record the server answers HELLO with; ``data_bitrate`` None announces a classic CAN bus."""
    body = WELCOME.pack(VERSION, 1 if data_bitrate else 0, bitrate, data_bitrate or 0)
    return _record(RecordType.WELCOME, body + bus_name.encode()[:255])


def encode_frame(frame: CanFrame, timestamp: float = 0.0, echo: bool = False) -> bytes:
    """A FRAME record for ``frame``; clients send timestamp 0, the server stamps bus time and flags echoes."""
    flags = ((FrameFlags.EXTENDED if frame.extended else 0) | (FrameFlags.RTR if frame.rtr else 0)
             | (FrameFlags.FD if frame.fd else 0) | (FrameFlags.BRS if frame.brs else 0)
             | (FrameFlags.ESI if frame.esi else 0) | (FrameFlags.ECHO if echo else 0))
    data = frame.data
    return LENGTH.pack(FRAME.size + 1 + len(data)) + b"\x03" + FRAME.pack(
        frame.can_id, flags, frame.dlc, timestamp) + data


def encode_status(kind: StatusKind, state: ControllerStateCode, tec: int, rec: int, t: float,
                  error: ErrorCode = ErrorCode.UNKNOWN, transmitter: bool = False,
                  old: ControllerStateCode | None = None) -> bytes:
    """A STATUS record for an error frame or state change; the counters saturate to fit their u16 fields.
    The tail says the error kind (and whether this client transmitted) or the state before a change."""
    detail = (STATUS_DETAIL.pack(error, 1 if transmitter else 0) if kind is StatusKind.ERROR_FRAME
              else STATUS_DETAIL.pack(old if old is not None else 0xFF, 0))
    return _record(RecordType.STATUS, STATUS.pack(kind, state, min(tec, 0xFFFF), min(rec, 0xFFFF), t) + detail)


def encode_bye(reason: str) -> bytes:
    """The BYE record sent just before closing, carrying the reason (truncated to fit one record)."""
    return _record(RecordType.BYE, reason.encode()[:MAX_RECORD - 1])


def encode_txdone(outcome: TxOutcome, count: int = 1) -> bytes:
    """A TXDONE record telling a client that ``count`` of its frames left its transmit queue with ``outcome``."""
    return _record(RecordType.TXDONE, TXDONE.pack(outcome, count))


def encode_timebase(wall_epoch: float) -> bytes:
    """The TIMEBASE record the server sends right after WELCOME, so clients can convert bus time to Unix time."""
    return _record(RecordType.TIMEBASE, TIMEBASE.pack(wall_epoch))


def encode_filters(filters: tuple[AcceptanceFilter, ...] | list[AcceptanceFilter]) -> bytes:
    """A FILTER record: a client's acceptance filters, or the server's echo of those in force (at most MAX_FILTERS)."""
    if len(filters) > MAX_FILTERS:
        raise LocalError(f"at most {MAX_FILTERS} filters fit in one FILTER record, got {len(filters)}")
    return _record(RecordType.FILTER, b"".join(
        FILTER.pack(f.can_id & 0x1FFFFFFF, f.can_mask & 0x1FFFFFFF, f.match) for f in filters))


def decode_body(rtype: int, body: bytes) -> Record:
    """Decode one record body; raises ProtocolError on anything malformed."""
    try:
        if rtype == RecordType.FRAME:
            if len(body) < FRAME.size:
                raise ProtocolError(f"FRAME record of {len(body)} bytes is too short")
            can_id, flags, dlc, ts = FRAME.unpack_from(body)
            if flags & ~FrameFlags.ALL:
                raise ProtocolError(f"unknown frame flags 0x{flags:02X}")
            rtr = bool(flags & FrameFlags.RTR)
            frame = CanFrame(can_id, body[FRAME.size:], bool(flags & FrameFlags.EXTENDED), rtr,
                             bool(flags & FrameFlags.FD), bool(flags & FrameFlags.BRS),
                             bool(flags & FrameFlags.ESI), dlc)
            return FrameRecord(frame, ts, bool(flags & FrameFlags.ECHO))
        if rtype == RecordType.HELLO:
            if len(body) < HELLO.size:
                raise ProtocolError("HELLO record too short")
            version, opts = HELLO.unpack_from(body)
            return Hello(version, bool(opts & 1), bool(opts & 2), body[HELLO.size:].decode(), bool(opts & 4))
        if rtype == RecordType.WELCOME:
            if len(body) < WELCOME.size:
                raise ProtocolError("WELCOME record too short")
            version, flags, br, dbr = WELCOME.unpack_from(body)
            return Welcome(version, bool(flags & 1), br, dbr, body[WELCOME.size:].decode())
        if rtype == RecordType.STATUS:
            if len(body) not in (STATUS.size, STATUS.size + STATUS_DETAIL.size):
                raise ProtocolError("STATUS record has the wrong size")
            kind, state, tec, rec, ts = STATUS.unpack_from(body)
            status = Status(StatusKind(kind), ControllerStateCode(state), tec, rec, ts)
            if len(body) == STATUS.size:
                return status
            a, b = STATUS_DETAIL.unpack_from(body, STATUS.size)
            if status.kind is StatusKind.ERROR_FRAME:
                return Status(status.kind, status.state, tec, rec, ts, ErrorCode(a), bool(b & 1))
            return Status(status.kind, status.state, tec, rec, ts, old=None if a == 0xFF else ControllerStateCode(a))
        if rtype == RecordType.BYE:
            return Bye(body.decode(errors="replace"))
        if rtype == RecordType.TXDONE:
            if len(body) != TXDONE.size:
                raise ProtocolError("TXDONE record has the wrong size")
            outcome, count = TXDONE.unpack(body)
            return TxDone(TxOutcome(outcome), count)
        if rtype == RecordType.TIMEBASE:
            if len(body) != TIMEBASE.size:
                raise ProtocolError("TIMEBASE record has the wrong size")
            return TimeBase(TIMEBASE.unpack(body)[0])
        if rtype == RecordType.FILTER:
            if len(body) % FILTER.size:
                raise ProtocolError(f"FILTER record of {len(body)} bytes is not a whole number of entries")
            return Filters(tuple(AcceptanceFilter(i & 0x1FFFFFFF, m & 0x1FFFFFFF, FilterMatch(k))
                                 for i, m, k in FILTER.iter_unpack(body)))
    except FrameError as exc:
        raise ProtocolError(f"invalid frame: {exc}") from None
    except (UnicodeDecodeError, ValueError) as exc:
        raise ProtocolError(f"malformed record: {exc}") from None
    raise ProtocolError(f"unknown record type 0x{rtype:02X}")


class RecordDecoder:
    """Incremental decoder: feed bytes as they arrive, get whole records out."""

    __slots__ = ("_buf",)

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[Record]:
        """Add bytes as they arrive and return the records now complete; raises ProtocolError on anything malformed."""
        buf = self._buf
        buf += data
        out: list[Record] = []
        pos = 0
        n = len(buf)
        while n - pos >= 3:
            (length,) = LENGTH.unpack_from(buf, pos)
            if length < 1 or length > MAX_RECORD:
                raise ProtocolError(f"record length {length} out of 1..{MAX_RECORD}")
            end = pos + 2 + length
            if end > n:
                break
            out.append(decode_body(buf[pos + 2], bytes(buf[pos + 3:end])))
            pos = end
        if pos:
            del buf[:pos]
        return out

    @property
    def buffered(self) -> int:
        """Bytes of an incomplete record held back (0 when the stream ended on a record boundary)."""
        return len(self._buf)
