"""maxon USB frame codec: DLE/STX sync, byte stuffing, word-wise CRC-CCITT (IDX guide 2.2).

A frame on the wire is ``DLE STX OpCode Len Data[0..Len-1] CRC`` with every DLE (0x90) between
OpCode and CRC inclusive doubled (2.2.4). Len counts 16-bit words (0..143, 2.2.2), words are sent
low byte first (2.2.5). The CRC (2.2.3) is CRC-CCITT over the word array ``(Len<<8|OpCode),
Data..., 0``; that equals CRC-16/XMODEM (``binascii.crc_hqx``) over the big-endian bytes of the
words, and the CRC over a whole received frame (CRC word included) is zero.

Sans-I/O: :func:`encode_frame` is a pure function and :class:`FrameDecoder` takes bytes in any
chunking and reports events through a callback; the frame timeout runs on the injected clock.
"""

from __future__ import annotations

import binascii
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import LocalError

__all__ = [
    "DEFAULT_FRAME_TIMEOUT",
    "DLE",
    "MAX_LEN_WORDS",
    "STX",
    "CrcFailed",
    "DecoderEvent",
    "DecoderStats",
    "DiscardReason",
    "Frame",
    "FrameDecoder",
    "FrameDiscarded",
    "FrameReceived",
    "RxState",
    "crc_ccitt",
    "encode_frame",
    "frame_body",
    "stuff",
]


DLE = 0x90
STX = 0x02
MAX_LEN_WORDS = 143
#: 0x2006 "USB Frame Timeout" default (guide 2.2.6, table 2-4), in seconds.
DEFAULT_FRAME_TIMEOUT = 0.5
_DLE_B = bytes([DLE])
_DLE2_B = bytes([DLE, DLE])
_SYNC = bytes([DLE, STX])


def _swap_words(data: bytes | bytearray) -> bytes:
    """Little-endian words -> big-endian words (swap each byte pair); ``len(data)`` is even."""
    out = bytearray(len(data))
    out[0::2] = data[1::2]
    out[1::2] = data[0::2]
    return bytes(out)


def crc_ccitt(body: bytes | bytearray) -> int:
    """The guide's ``CalcFieldCRC`` over ``body`` (OpCode, Len, data) with the zero CRC word appended.

    Appending a zero word to the MSB-first CRC register gives the plain XMODEM CRC of the words,
    so ``crc_hqx`` over the byte-swapped words is the guide's algorithm exactly.
    """
    if len(body) % 2:
        raise LocalError("the CRC runs over whole words")
    return binascii.crc_hqx(_swap_words(body), 0)


def stuff(data: bytes) -> bytes:
    """Double every DLE (guide 2.2.4)."""
    return data.replace(_DLE_B, _DLE2_B)


@dataclass(frozen=True, slots=True)
class Frame:
    """One unstuffed frame: ``opcode`` and the ``data`` words as little-endian bytes."""

    opcode: int
    data: bytes = b""

    def __post_init__(self) -> None:
        if not 0 <= self.opcode <= 0xFF:
            raise LocalError(f"opcode 0x{self.opcode:X} is not a byte")
        if len(self.data) % 2:
            raise LocalError("frame data must be whole words (pad odd lengths)")
        if len(self.data) // 2 > MAX_LEN_WORDS:
            raise LocalError(f"frame data of {len(self.data) // 2} words exceeds Len {MAX_LEN_WORDS}")

    @property
    def length(self) -> int:
        """The Len field: number of data words."""
        return len(self.data) // 2


def frame_body(frame: Frame) -> bytes:
    """OpCode, Len, data and CRC, before stuffing (what the CRC check sees)."""
    head = bytes((frame.opcode, frame.length)) + frame.data
    crc = crc_ccitt(head)
    return head + bytes((crc & 0xFF, crc >> 8))


def encode_frame(frame: Frame) -> bytes:
    """The stuffed byte stream of ``frame`` as it goes on the wire (guide 2.2.8 steps 1-8)."""
    return _SYNC + stuff(frame_body(frame))


# -- decoder --------------------------------------------------------------------------------------
class DiscardReason(Enum):
    """Why a partial frame was dropped without an answer."""

    LEN_TOO_LONG = "Len above 143"
    TIMEOUT = "USB frame timeout expired"
    RESYNC = "DLE STX inside a frame"
    BAD_ESCAPE = "DLE followed by neither DLE nor STX"


@dataclass(frozen=True, slots=True)
class FrameReceived:
    """Decoder event: a complete frame whose CRC checks (2.2.3), for the slave to execute or the host to read."""

    frame: Frame


@dataclass(frozen=True, slots=True)
class CrcFailed:
    """A complete frame whose CRC does not check; the slave answers 0x05040004."""

    opcode: int
    data: bytes


@dataclass(frozen=True, slots=True)
class FrameDiscarded:
    """Decoder event: a partial frame dropped unanswered (e.g. 2.2.6 frame timeout), with the reason and bytes."""

    reason: DiscardReason
    partial: bytes


DecoderEvent = FrameReceived | CrcFailed | FrameDiscarded


class RxState(Enum):
    """Where :class:`FrameDecoder` is in the DLE STX framing and DLE stuffing (guide 2.2.2, 2.2.4)."""

    HUNT = "hunt"            # looking for DLE
    SYNC = "sync"            # saw DLE, expecting STX
    BODY = "body"            # inside a frame
    BODY_DLE = "body-dle"    # inside a frame, saw DLE


class DecoderStats:
    """Counters of one :class:`FrameDecoder` (frames, CRC errors, discards, timeouts...) for diagnosis."""

    __slots__ = ("crc_errors", "discarded", "frames", "garbage_bytes", "timeouts")

    def __init__(self) -> None:
        self.frames = 0
        self.crc_errors = 0
        self.discarded = 0
        self.timeouts = 0
        self.garbage_bytes = 0


class FrameDecoder:
    """Byte stream -> frames, resynchronising on DLE STX (guide 2.2.2, 2.2.4, 2.2.6).

    ``timeout`` (seconds, ``None`` = never) bounds a whole frame from its DLE STX: when it expires
    before the CRC arrived the partial frame is dropped (2.2.6 "the timeout is handled over a
    complete frame"). It is read at every frame start, so writes to 0x2006 apply to the next frame.
    """

    def __init__(self, clock: Clock, on_event: Callable[[DecoderEvent], None],
                 timeout: Callable[[], float | None] | float | None = DEFAULT_FRAME_TIMEOUT) -> None:
        self.clock = clock
        self.on_event = on_event
        self._timeout = timeout
        self.state = RxState.HUNT
        self.stats = DecoderStats()
        self._buf = bytearray()
        self._need = 0
        self._timer: TimerHandle | None = None

    def _timeout_value(self) -> float | None:
        t = self._timeout
        return t() if callable(t) else t

    def reset(self) -> None:
        """Forget any partial frame."""
        self._cancel_timer()
        self._buf.clear()
        self.state = RxState.HUNT

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _start_frame(self) -> None:
        self._buf.clear()
        self._need = 2
        self.state = RxState.BODY
        self._cancel_timer()
        timeout = self._timeout_value()
        if timeout is not None and timeout > 0:
            self._timer = self.clock.call_later(timeout, self._expired)

    def _expired(self) -> None:
        self._timer = None
        if self.state in (RxState.BODY, RxState.BODY_DLE):
            self.stats.timeouts += 1
            self._discard(DiscardReason.TIMEOUT)

    def _discard(self, reason: DiscardReason) -> None:
        partial = bytes(self._buf)
        self._cancel_timer()
        self._buf.clear()
        self.state = RxState.HUNT
        self.stats.discarded += 1
        self.on_event(FrameDiscarded(reason, partial))

    def _body_byte(self, b: int) -> None:
        buf = self._buf
        buf.append(b)
        n = len(buf)
        if n == 2:
            if b > MAX_LEN_WORDS:
                self._discard(DiscardReason.LEN_TOO_LONG)
                return
            self._need = 4 + 2 * b
        elif n == self._need:
            self._complete()

    def _complete(self) -> None:
        body = bytes(self._buf)
        self._cancel_timer()
        self._buf.clear()
        self.state = RxState.HUNT
        if binascii.crc_hqx(_swap_words(body), 0) != 0:
            self.stats.crc_errors += 1
            self.on_event(CrcFailed(body[0], body[2:-2]))
            return
        self.stats.frames += 1
        self.on_event(FrameReceived(Frame(body[0], body[2:-2])))

    def feed(self, data: bytes) -> None:
        """Take received bytes in any chunking; events go to ``on_event`` in stream order."""
        for b in data:
            state = self.state
            if state is RxState.BODY:
                if b == DLE:
                    self.state = RxState.BODY_DLE
                else:
                    self._body_byte(b)
            elif state is RxState.BODY_DLE:
                if b == DLE:
                    self.state = RxState.BODY
                    self._body_byte(DLE)
                elif b == STX:
                    self._discard(DiscardReason.RESYNC)
                    self._start_frame()
                else:
                    self._discard(DiscardReason.BAD_ESCAPE)
                    self.stats.garbage_bytes += 1
            elif state is RxState.HUNT:
                if b == DLE:
                    self.state = RxState.SYNC
                else:
                    self.stats.garbage_bytes += 1
            else:  # SYNC
                if b == STX:
                    self._start_frame()
                elif b != DLE:
                    self.state = RxState.HUNT
                    self.stats.garbage_bytes += 2
                else:
                    self.stats.garbage_bytes += 1
