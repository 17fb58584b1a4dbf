"""Mailbox header codec and the slave's mailbox endpoint (ETG.1000.4 'Mailbox').

Header: length u16 (of the data after the header), address u16, channel:6/priority:2 u8,
type:4/counter:3 u8. The counter runs 1..7 (0 = not used); a request whose counter repeats the
previous one is a retransmission and is not executed again. Unknown protocols and broken headers
are answered with a mailbox error reply (type 0).
"""

from __future__ import annotations

import enum
import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from gatewaylab.ethercat.errors import FrameFormatError, MailboxErrorCode

__all__ = [
    "MAX_QUEUED",
    "MBX_ERROR",
    "MBX_HEADER",
    "MBX_HEADER_LEN",
    "Handler",
    "MailboxEndpoint",
    "MailboxMessage",
    "MailboxStats",
    "MailboxType",
    "decode_mailbox",
    "encode_mailbox",
    "error_reply",
]


MBX_HEADER = struct.Struct("<HHBB")
MBX_HEADER_LEN = 6
MBX_ERROR = struct.Struct("<HH")
#: Messages a slave keeps for the master at most (a firmware has a fixed number of mailbox buffers);
#: more are dropped and counted, so a master that never reads SM1 cannot grow the queue without end.
MAX_QUEUED = 256


class MailboxType(enum.IntEnum):
    """Mailbox protocol types (ETG.1000.4 mailbox header)."""
    ERROR = 0
    AOE = 1
    EOE = 2
    COE = 3
    FOE = 4
    SOE = 5
    VOE = 15


@dataclass(frozen=True, slots=True)
class MailboxMessage:
    """One mailbox message to send (type and payload)."""
    type: int
    data: bytes
    counter: int = 0
    address: int = 0
    channel: int = 0
    priority: int = 0


def encode_mailbox(msg: MailboxMessage) -> bytes:
    """A mailbox message with its 6-byte header."""
    return MBX_HEADER.pack(len(msg.data), msg.address, (msg.channel & 0x3F) | ((msg.priority & 3) << 6),
                           (msg.type & 0x0F) | ((msg.counter & 7) << 4)) + msg.data


def decode_mailbox(buf: bytes) -> MailboxMessage:
    """Parse a mailbox buffer (the SM area, padding after ``length`` ignored)."""
    if len(buf) < MBX_HEADER_LEN:
        raise FrameFormatError("mailbox shorter than its header")
    length, address, chp, tc = MBX_HEADER.unpack_from(buf, 0)
    if length > len(buf) - MBX_HEADER_LEN:
        raise FrameFormatError(f"mailbox length {length} exceeds the buffer")
    return MailboxMessage(tc & 0x0F, bytes(buf[MBX_HEADER_LEN:MBX_HEADER_LEN + length]), (tc >> 4) & 7,
                          address, chp & 0x3F, chp >> 6)


def error_reply(code: int) -> MailboxMessage:
    """Mailbox error reply: type 0, service 0x01, detail code."""
    return MailboxMessage(MailboxType.ERROR, MBX_ERROR.pack(0x0001, code))


#: A protocol handler: request data -> reply data list (CoE / FoE payloads, without mailbox header).
Handler = Callable[[bytes], list[bytes]]


@dataclass(slots=True)
class MailboxStats:
    """Counters of a mailbox endpoint."""
    received: int = 0
    sent: int = 0
    repeated: int = 0
    errors: int = 0
    #: messages dropped because MAX_QUEUED were waiting already
    dropped: int = 0


class MailboxEndpoint:
    """Receives SM0 buffers, dispatches by type, queues replies for SM1 with their own counter."""

    def __init__(self, put: Callable[[bytes], bool]) -> None:
        self._put = put
        self.handlers: dict[int, Handler] = {}
        self.queue: deque[bytes] = deque()
        self.stats = MailboxStats()
        self._last_counter = 0
        self._send_counter = 0

    def reset(self) -> None:
        """Leaving PREOP for INIT drops any pending conversation."""
        self.queue.clear()
        self._last_counter = 0

    def received(self, buf: bytes) -> None:
        """A mailbox write from the master: decode, check the counter, dispatch."""
        self.stats.received += 1
        try:
            msg = decode_mailbox(buf)
        except FrameFormatError:
            self.stats.errors += 1
            self.send(error_reply(MailboxErrorCode.INVALID_SIZE))
            return
        if msg.counter and msg.counter == self._last_counter:
            self.stats.repeated += 1
            return
        self._last_counter = msg.counter
        handler = self.handlers.get(msg.type)
        if handler is None:
            self.stats.errors += 1
            self.send(error_reply(MailboxErrorCode.UNSUPPORTED_PROTOCOL))
            return
        try:
            replies = handler(msg.data)
        except FrameFormatError:
            self.stats.errors += 1
            self.send(error_reply(MailboxErrorCode.SIZE_TOO_SHORT))
            return
        for data in replies:
            self.send(MailboxMessage(msg.type, data))

    def send(self, msg: MailboxMessage) -> None:
        """Queue a message (replies, emergencies, asynchronous answers) for the master."""
        self._send_counter = self._send_counter % 7 + 1
        raw = encode_mailbox(MailboxMessage(msg.type, msg.data, self._send_counter, msg.address,
                                            msg.channel, msg.priority))
        if len(self.queue) >= MAX_QUEUED:
            self.stats.dropped += 1
            return
        self.queue.append(raw)
        self.pump()

    def pump(self) -> None:
        """Move the next queued message into SM1 when the master has emptied it."""
        while self.queue:
            if not self._put(self.queue[0]):
                return
            self.queue.popleft()
            self.stats.sent += 1
            return
