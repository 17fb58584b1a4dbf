"""The IDX USB slave: one request at a time, every request answered (guide 2.2.1, 2.2.7, chapter 5).

Sans-I/O: bytes come in through :meth:`IdxSlave.receive`, replies leave through the ``send``
callback. Object access goes to two small interfaces so the state machine can be tested alone:

* :class:`ObjectAccess` -- the IDX's own object dictionary (node id 0 or the IDX's own node id),
* :class:`Gateway` -- everything that goes to the CAN bus (SDO to other nodes, NMT, LSS).

Errors raised by either (anything with a wire ``code``) become the reply's error DWORD here, at
one boundary.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Protocol

from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import ConfigError, GatewaylabError
from gatewaylab.devices.maxon_idx.codec import (
    DEFAULT_FRAME_TIMEOUT,
    CrcFailed,
    DecoderEvent,
    FrameDecoder,
    FrameDiscarded,
    FrameReceived,
    encode_frame,
)
from gatewaylab.devices.maxon_idx.commands import (
    MAX_SEGMENT,
    InitiateSegmentedRead,
    InitiateSegmentedReadReply,
    InitiateSegmentedWrite,
    NmtCommand,
    ReadLss,
    ReadLssReply,
    ReadObject,
    ReadObjectReply,
    Reply,
    Request,
    SegmentRead,
    SegmentReadReply,
    SegmentWrite,
    SegmentWriteReply,
    SendLss,
    SendNmtService,
    StatusReply,
    WriteObject,
    decode_request,
    error_reply,
)
from gatewaylab.devices.maxon_idx.errors import IdxRemoteError, SdoAbortCode

__all__ = [
    "MAX_QUEUED",
    "DownloadCallback",
    "Gateway",
    "IdxSlave",
    "ObjectAccess",
    "SlaveState",
    "SlaveStats",
    "Transfer",
    "UploadCallback",
]


#: Requests held while one executes (a host should wait for each answer, guide 2.2.8 D).
MAX_QUEUED = 64

UploadCallback = Callable[[bytes | GatewaylabError], None]
DownloadCallback = Callable[[GatewaylabError | None], None]


class ObjectAccess(Protocol):
    """The IDX's own object dictionary, accessed exactly as an SDO client would."""

    def read(self, index: int, subindex: int) -> bytes:
        """The wire form of an object (raises with the chapter 6 code)."""

    def write(self, index: int, subindex: int, data: bytes) -> None:
        """Write the wire form of an object (raises with the chapter 6 code)."""

    def value_size(self, index: int, subindex: int) -> int | None:
        """Bytes of a fixed-size value, None for variable-size ones; raises if the object is missing."""
        ...

    def check_write(self, index: int, subindex: int) -> None:
        """Raise (with the chapter 6 code) when the object is missing or cannot be written."""
        ...


class Gateway(Protocol):
    """The CAN side (guide chapter 5): SDO client to other nodes, NMT and LSS master messages."""

    def upload(self, node_id: int, index: int, subindex: int, callback: UploadCallback, *,
               segmented: bool) -> None:
        """SDO upload from another node on CAN (guide chapter 5)."""

    def download(self, node_id: int, index: int, subindex: int, data: bytes,
                 callback: DownloadCallback) -> None:
        """SDO download to another node on CAN (guide chapter 5)."""

    def send_nmt(self, node_id: int, command: int) -> None:
        """Send an NMT command on CAN."""

    def send_lss(self, data: bytes) -> None:
        """Send an LSS master message on CAN."""

    def read_lss(self, timeout: float, callback: UploadCallback) -> None:
        """Wait up to ``timeout`` for an LSS slave message."""


class SlaveState(Enum):
    """Guide 2.2.7: the slave waits for a frame, executes it, answers, and waits again."""

    IDLE = "idle"
    EXECUTING = "executing"   # a gateway or LSS request is waiting for the CAN bus


class Transfer(Enum):
    """The segmented transfer a host has in progress."""
    NONE = "none"
    SEGMENTED_READ = "segmented-read"
    SEGMENTED_WRITE = "segmented-write"


_TRANSITIONS: dict[tuple[SlaveState, str], SlaveState] = {
    (SlaveState.IDLE, "sync"): SlaveState.IDLE,
    (SlaveState.IDLE, "async"): SlaveState.EXECUTING,
    (SlaveState.EXECUTING, "answered"): SlaveState.IDLE,
}


@dataclass(slots=True)
class SlaveStats:
    """Counters of the USB slave (requests, replies, error replies)."""
    requests: int = 0
    replies: int = 0
    error_replies: int = 0
    crc_errors: int = 0
    discarded_frames: int = 0
    overflows: int = 0
    errors_by_code: dict[int, int] = field(default_factory=dict)


@dataclass(slots=True)
class _SegState:
    kind: Transfer = Transfer.NONE
    node_id: int = 0
    index: int = 0
    subindex: int = 0
    data: bytearray = field(default_factory=bytearray)
    offset: int = 0
    total: int = 0
    toggle: bool = False       # the toggle the next segment must carry


class IdxSlave:
    """One USB command channel of an IDX (one per connected host)."""

    def __init__(self, clock: Clock, objects: ObjectAccess, gateway: Gateway,
                 own_node_id: Callable[[], int | None], send: Callable[[bytes], None],
                 frame_timeout: Callable[[], float | None] | float | None = DEFAULT_FRAME_TIMEOUT,
                 segment_size: int = MAX_SEGMENT) -> None:
        if not 1 <= segment_size <= MAX_SEGMENT:
            raise ConfigError(f"segment size must be 1..{MAX_SEGMENT}")
        self.clock = clock
        self.objects = objects
        self.gateway = gateway
        self.own_node_id = own_node_id
        self.send = send
        self.segment_size = segment_size
        self.decoder = FrameDecoder(clock, self._on_decoder_event, frame_timeout)
        self.state = SlaveState.IDLE
        self.stats = SlaveStats()
        self._queue: deque[DecoderEvent] = deque()
        self._pumping = False
        self._seg = _SegState()
        self._generation = 0

    def close(self) -> None:
        """The host went away: drop partial input, queued requests and any pending gateway answer."""
        self.decoder.reset()
        self._queue.clear()
        self._seg = _SegState()
        self._generation += 1
        self.state = SlaveState.IDLE

    # -- input ------------------------------------------------------------------------------------
    def receive(self, data: bytes) -> None:
        """Bytes from the host, in any chunking."""
        self.decoder.feed(data)

    def _on_decoder_event(self, event: DecoderEvent) -> None:
        if isinstance(event, FrameDiscarded):
            self.stats.discarded_frames += 1
            return
        # Requests that arrive while one executes wait their turn: never two answers at once.
        if len(self._queue) >= MAX_QUEUED:
            self.stats.overflows += 1         # a host ignoring 2.2.8 D; the IDX would lose it too
            return
        self._queue.append(event)
        self._pump()

    def _pump(self) -> None:
        if self._pumping:
            return
        self._pumping = True
        try:
            while self.state is SlaveState.IDLE and self._queue:
                self._execute(self._queue.popleft())
        finally:
            self._pumping = False

    # -- output -----------------------------------------------------------------------------------
    def _reply(self, reply: Reply) -> None:
        self.stats.replies += 1
        if reply.error:
            self.stats.error_replies += 1
            by_code = self.stats.errors_by_code
            by_code[reply.error] = by_code.get(reply.error, 0) + 1
        self.send(encode_frame(reply.to_frame()))

    def _go(self, event: str) -> None:
        self.state = _TRANSITIONS[(self.state, event)]

    def _async_done(self, generation: int, reply: Reply) -> None:
        if generation != self._generation or self.state is not SlaveState.EXECUTING:
            return
        self._go("answered")
        self._reply(reply)
        self._pump()

    def _begin_async(self) -> int:
        self._generation += 1
        self._go("async")
        return self._generation

    # -- dispatch ---------------------------------------------------------------------------------
    def _execute(self, event: DecoderEvent) -> None:
        if isinstance(event, CrcFailed):
            # Guide 2.2.2 note: a bad CRC is answered with a frame carrying the CRC error code.
            self.stats.crc_errors += 1
            self._reply(StatusReply(SdoAbortCode.CRC_ERROR))
            return
        assert isinstance(event, FrameReceived)
        self.stats.requests += 1
        opcode = event.frame.opcode
        try:
            request = decode_request(event.frame)
            reply = self._dispatch(request)
        except GatewaylabError as exc:
            if self.state is SlaveState.EXECUTING:   # a gateway refused synchronously
                self._generation += 1
                self._go("answered")
            self._reply(error_reply(opcode, _code_of(exc)))
            return
        if reply is not None:
            self._go("sync")
            self._reply(reply)

    def _is_local(self, node_id: int) -> bool:
        return node_id == 0 or node_id == self.own_node_id()

    def _check_remote(self, node_id: int) -> None:
        if not 1 <= node_id <= 127:
            raise IdxRemoteError(SdoAbortCode.VALUE_RANGE_EXCEEDED, f"node id {node_id} outside 1..127")

    def _dispatch(self, req: Request) -> Reply | None:
        """Execute ``req``; returns the reply, or None when it will come from a gateway callback."""
        if isinstance(req, ReadObject):
            return self._read_object(req)
        if isinstance(req, InitiateSegmentedRead):
            return self._initiate_read(req)
        if isinstance(req, SegmentRead):
            return self._segment_read(req)
        if isinstance(req, WriteObject):
            return self._write_object(req)
        if isinstance(req, InitiateSegmentedWrite):
            return self._initiate_write(req)
        if isinstance(req, SegmentWrite):
            return self._segment_write(req)
        if isinstance(req, SendNmtService):
            return self._send_nmt(req)
        if isinstance(req, SendLss):
            self.gateway.send_lss(req.data)
            return StatusReply()
        return self._read_lss(req)

    # ReadObject (2.1.1.1) --------------------------------------------------------------------------
    def _read_object(self, req: ReadObject) -> Reply | None:
        if self._is_local(req.node_id):
            return ReadObjectReply(0, _fit4(self.objects.read(req.index, req.subindex)))
        self._check_remote(req.node_id)
        gen = self._begin_async()

        def done(result: bytes | GatewaylabError) -> None:
            if isinstance(result, GatewaylabError):
                reply: Reply = ReadObjectReply(_code_of(result))
            elif len(result) > 4:
                reply = ReadObjectReply(SdoAbortCode.LENGTH_MISMATCH)
            else:
                reply = ReadObjectReply(0, result.ljust(4, b"\x00"))
            self._async_done(gen, reply)

        self.gateway.upload(req.node_id, req.index, req.subindex, done, segmented=False)
        return None

    # Segmented read (2.1.1.2, 2.1.1.3) ---------------------------------------------------------------
    def _start_read(self, req: InitiateSegmentedRead, value: bytes) -> InitiateSegmentedReadReply:
        n = min(len(value), self.segment_size)
        # Even when the initiate reply carried everything, one SegmentRead is still answered (an
        # empty last segment) for hosts that loop until the last-segment bit.
        self._seg = _SegState(Transfer.SEGMENTED_READ, req.node_id, req.index, req.subindex,
                              bytearray(value), n, len(value), False)
        return InitiateSegmentedReadReply(0, len(value), value[:n])

    def _initiate_read(self, req: InitiateSegmentedRead) -> Reply | None:
        self._seg = _SegState()
        if self._is_local(req.node_id):
            return self._start_read(req, self.objects.read(req.index, req.subindex))
        self._check_remote(req.node_id)
        gen = self._begin_async()

        def done(result: bytes | GatewaylabError) -> None:
            if isinstance(result, GatewaylabError):
                reply: Reply = InitiateSegmentedReadReply(_code_of(result))
            else:
                reply = self._start_read(req, result)
            self._async_done(gen, reply)

        self.gateway.upload(req.node_id, req.index, req.subindex, done, segmented=True)
        return None

    def _segment_read(self, req: SegmentRead) -> Reply:
        seg = self._seg
        if seg.kind is not Transfer.SEGMENTED_READ:
            raise IdxRemoteError(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN, "SegmentRead without InitiateSegmentedRead")
        if req.toggle != seg.toggle:
            self._seg = _SegState()
            raise IdxRemoteError(SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED)
        chunk = bytes(seg.data[seg.offset:seg.offset + self.segment_size])
        seg.offset += len(chunk)
        seg.toggle = not seg.toggle
        last = seg.offset >= seg.total
        if last:
            self._seg = _SegState()
        return SegmentReadReply(0, req.toggle, last, chunk)

    # WriteObject (2.1.2.1) ---------------------------------------------------------------------------
    def _write_object(self, req: WriteObject) -> Reply | None:
        if self._is_local(req.node_id):
            size = self.objects.value_size(req.index, req.subindex)
            if size is not None and size > 4:
                raise IdxRemoteError(SdoAbortCode.LENGTH_MISMATCH,
                                     f"object of {size} bytes needs a segmented write")
            self.objects.write(req.index, req.subindex, req.data if size is None else req.data[:size])
            return StatusReply()
        self._check_remote(req.node_id)
        gen = self._begin_async()

        def done(result: GatewaylabError | None) -> None:
            self._async_done(gen, StatusReply(0 if result is None else _code_of(result)))

        self.gateway.download(req.node_id, req.index, req.subindex, req.data, done)
        return None

    # Segmented write (2.1.2.2, 2.1.2.3) --------------------------------------------------------------
    def _initiate_write(self, req: InitiateSegmentedWrite) -> Reply:
        self._seg = _SegState()
        if not self._is_local(req.node_id):
            # 2.1.2.2 "Note that gateway communication is not supported."
            raise IdxRemoteError(SdoAbortCode.UNSUPPORTED_ACCESS, "segmented write through the gateway")
        # 0x06020000 / 0x06010002 / 0x06070010 now, not after the host has sent every segment.
        self.objects.check_write(req.index, req.subindex)
        size = self.objects.value_size(req.index, req.subindex)
        if size is not None and req.total_length != size:
            raise IdxRemoteError(SdoAbortCode.LENGTH_MISMATCH,
                                 f"{req.total_length} bytes announced for an object of {size}")
        self._seg = _SegState(Transfer.SEGMENTED_WRITE, req.node_id, req.index, req.subindex,
                              bytearray(), 0, req.total_length, False)
        return StatusReply()

    def _segment_write(self, req: SegmentWrite) -> Reply:
        seg = self._seg
        if seg.kind is not Transfer.SEGMENTED_WRITE:
            raise IdxRemoteError(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN, "SegmentWrite without InitiateSegmentedWrite")
        if req.toggle != seg.toggle:
            self._seg = _SegState()
            raise IdxRemoteError(SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED)
        seg.data += req.data
        seg.toggle = not seg.toggle
        if len(seg.data) > seg.total or (req.last and len(seg.data) != seg.total):
            self._seg = _SegState()
            raise IdxRemoteError(SdoAbortCode.LENGTH_MISMATCH,
                                 f"{len(seg.data)} bytes written, {seg.total} announced")
        if req.last:
            self._seg = _SegState()
            self.objects.write(seg.index, seg.subindex, bytes(seg.data))
        return SegmentWriteReply(0, len(req.data), req.toggle)

    # NMT and LSS (2.1.2.4, 2.1.3) --------------------------------------------------------------------
    def _send_nmt(self, req: SendNmtService) -> Reply:
        if req.node_id > 127:
            raise IdxRemoteError(SdoAbortCode.VALUE_RANGE_EXCEEDED, f"node id {req.node_id} outside 0..127")
        try:
            NmtCommand(req.command)
        except ValueError:
            raise IdxRemoteError(SdoAbortCode.VALUE_RANGE_EXCEEDED, f"NMT command {req.command}") from None
        self.gateway.send_nmt(req.node_id, req.command)
        return StatusReply()

    def _read_lss(self, req: ReadLss) -> Reply | None:
        gen = self._begin_async()

        def done(result: bytes | GatewaylabError) -> None:
            if isinstance(result, GatewaylabError):
                self._async_done(gen, ReadLssReply(_code_of(result)))
            else:
                self._async_done(gen, ReadLssReply(0, result))

        self.gateway.read_lss(req.timeout_ms / 1000.0, done)
        return None


def _fit4(data: bytes) -> bytes:
    if len(data) > 4:
        raise IdxRemoteError(SdoAbortCode.LENGTH_MISMATCH,
                             f"object of {len(data)} bytes: use InitiateSegmentedRead")
    return data.ljust(4, b"\x00")


def _code_of(exc: GatewaylabError) -> int:
    code = exc.code
    return SdoAbortCode.GENERAL_ERROR if code is None or code == 0 else code
