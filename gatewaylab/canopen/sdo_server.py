"""SDO server (CiA 301 7.2.4): expedited, segmented and block transfers with CRC.

One server channel (0x1200). The state machine is driven by received request frames and by a
timeout on the node's clock; every failure is answered with the abort code of IDX guide
chapter 6. Object access goes through :meth:`Node.read` / :meth:`Node.write` (the node's dictionary
with the node's access policy), so SDO sees exactly the access rights, lengths and limits that the
contract promises (both modules compiled: native calls).
"""

from __future__ import annotations

from collections.abc import Callable
from enum import Enum
from typing import TYPE_CHECKING, Final

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.od import SdoAbort, SdoAbortCode, check_length, decode
from gatewaylab.od import sdo as codec
from gatewaylab.od.sdo import (
    SDO_HEADER,
    SDO_HEADER_U32,
    BlockReceiver,
    BlockSender,
    BlockUploadSub,
    ClientCommand,
    SegmentedDownload,
    SegmentedUpload,
)

if TYPE_CHECKING:
    from gatewaylab.canopen.node import Node
    from gatewaylab.od import Entry

#: Initiate upload response command byte for an expedited answer of n bytes, and its padding.
_EXPEDITED_CS: Final = (b"", b"\x4F", b"\x4B", b"\x47", b"\x43")
_PAD: Final = (b"", b"\x00\x00\x00", b"\x00\x00", b"\x00", b"")
#: Largest object a segmented or block download may carry before "out of memory".
MAX_TRANSFER: Final = 1 << 20


def _announced_size(data: bytes, entry: Entry) -> int:
    """The size a segmented or block download announces, checked against the object (CiA 301
    7.2.4.3.3 / 7.2.4.3.9: too large for the server, or not the size of a fixed-size object, or
    longer than a string object holds: 0x06070012)."""
    size = data[4] | (data[5] << 8) | (data[6] << 16) | (data[7] << 24)
    check_length(entry, size)
    if size > MAX_TRANSFER:
        raise SdoAbort(SdoAbortCode.OUT_OF_MEMORY)
    if entry.size is not None:
        codec.check_size(size, entry.size)
    return size


def _limit(entry: Entry) -> tuple[int, SdoAbortCode]:
    """Most bytes a download may bring without announcing its size, and the abort past them."""
    limit = entry.max_length
    if limit is not None and limit < MAX_TRANSFER:
        return limit, SdoAbortCode.LENGTH_TOO_HIGH
    return MAX_TRANSFER, SdoAbortCode.OUT_OF_MEMORY


class SdoServerState(Enum):
    """Where a server channel is in a transfer (the rows of the dispatch table)."""

    IDLE = "idle"
    DOWNLOAD_SEGMENTED = "download segmented"
    UPLOAD_SEGMENTED = "upload segmented"
    BLOCK_DOWNLOAD = "block download (sub-block)"
    BLOCK_DOWNLOAD_END = "block download (end)"
    BLOCK_UPLOAD_START = "block upload (wait for start)"
    BLOCK_UPLOAD = "block upload (wait for ack)"
    BLOCK_UPLOAD_END = "block upload (wait for end)"

    #: Members are singletons compared by identity: hash them by identity too, in C (Enum's
    #: own ``__hash__`` is Python code, run on every change of state to find its dispatch row).
    __hash__ = object.__hash__


#: The states as constants: compiled, a Final global is a static, an attribute of the Enum class a lookup.
_IDLE: Final = SdoServerState.IDLE
_DOWNLOAD_SEGMENTED: Final = SdoServerState.DOWNLOAD_SEGMENTED
_UPLOAD_SEGMENTED: Final = SdoServerState.UPLOAD_SEGMENTED
_BLOCK_DOWNLOAD: Final = SdoServerState.BLOCK_DOWNLOAD


class SdoServer:
    """The default SDO server of a :class:`Node`: a (state, client command specifier) table
    dispatches every request; segments go through the codec shared with the client and CoE."""

    def __init__(self, node: Node, timeout: float = 1.0, block_size: int = 127) -> None:
        self.node = node
        self._clock: Clock = node.clock
        #: Seconds without the next request before a transfer is aborted with 0x05040000.
        self.timeout = timeout
        #: Block size the server asks for in block download (1..127).
        self.block_size = block_size
        self._state = SdoServerState.IDLE
        #: The dispatch table's row of the present state: handler by client command specifier.
        self._row = _ROWS[SdoServerState.IDLE]
        self.rx_cob_id = 0
        self.tx_cob_id = 0
        self.index = 0
        self.subindex = 0
        self._download: SegmentedDownload | None = None
        self._upload: SegmentedUpload | None = None
        #: The one timeout timer (pending or None) and the time the transfer in progress times out:
        #: a request moves the deadline, not the timer (no handle per segment).
        self._timer: TimerHandle | None = None
        self._deadline = 0.0
        # block transfers: the server receives a block download and sends a block upload
        self._receiver: BlockReceiver | None = None
        self._sender: BlockSender | None = None
        self._size: int | None = None
        #: Most bytes the block download in progress may bring, and the abort past them.
        self._block_limit: tuple[int, SdoAbortCode] = (MAX_TRANSFER, SdoAbortCode.OUT_OF_MEMORY)
        self._crc = False
        #: Answers by payload: frames are immutable, and polling, acknowledges and initiate
        #: responses repeat them (a dictionary lookup instead of a new frame; data segments never).
        self._frames: dict[bytes, CanFrame] = {}
        #: Counters: requests answered, aborts sent, frames ignored (wrong DLC or RTR).
        self.requests = 0
        self.aborts_sent = 0
        self.ignored = 0

    @property
    def state(self) -> SdoServerState:
        """Where the channel is in a transfer."""
        return self._state

    @state.setter
    def state(self, state: SdoServerState) -> None:
        self._state = state
        self._row = _ROWS[state]

    # -- plumbing ------------------------------------------------------------------------------
    def _send(self, payload: bytes) -> None:
        """An answer that repeats (expedited uploads, acknowledges, initiate responses): the frame
        from the cache by payload when it was sent before."""
        cache = self._frames
        frame = cache.get(payload)
        if frame is None or frame.can_id != self.tx_cob_id:
            if len(cache) >= 512:
                cache.clear()
            frame = cache[payload] = CanFrame(self.tx_cob_id, payload)
        self._send_frame(frame)

    def _send_data(self, payload: bytes) -> None:
        """A segment of an object's data (segmented or block upload): a new frame, the cache would
        only fill with payloads that do not come again."""
        self._send_frame(CanFrame(self.tx_cob_id, payload))

    def _send_frame(self, frame: CanFrame) -> None:
        self.node.send(frame)

    def _abort(self, code: int) -> None:
        self._reset()
        self.aborts_sent += 1
        self._send(codec.abort(self.index, self.subindex, code))

    def _reset(self) -> None:
        self.state = _IDLE
        self._download = None
        self._upload = None
        self._receiver = None
        self._sender = None

    def configure(self) -> None:
        """Take the COB-IDs from 0x1200 (bit 31 set = server not valid)."""
        od = self.node.od
        rx, tx = od.get(0x1200, 1), od.get(0x1200, 2)
        valid = not (rx & 0x80000000 or tx & 0x80000000)
        self.rx_cob_id = rx & 0x7FF if valid else 0
        self.tx_cob_id = tx & 0x7FF if valid else 0

    def cancel(self) -> None:
        """Drop any transfer in progress without a frame (NMT reset, node stop)."""
        self._reset()
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _arm(self) -> None:
        """The transfer times out ``timeout`` seconds from now. One timer at most: a timer still
        pending (armed earlier, maybe by a finished transfer) stays and finds the new deadline when
        it runs, so a segment costs a float store, not a scheduled and a cancelled event."""
        clock = self._clock
        self._deadline = deadline = clock.now() + self.timeout
        if self._timer is None:
            self._timer = clock.call_at(deadline, self._timed_out)

    def _timed_out(self) -> None:
        handle = self._timer
        self._timer = None
        if self._state is _IDLE or handle is None:
            return          # the transfer ended (or was cancelled) before its deadline
        clock = self._clock
        if clock.now() < self._deadline:
            self._timer = handle            # the client answered since: wait for the new deadline
            clock.reschedule(handle, self._deadline)
            return
        self._abort(SdoAbortCode.SDO_PROTOCOL_TIMED_OUT)

    # -- entry point ---------------------------------------------------------------------------
    def on_frame(self, frame: CanFrame, t: float) -> None:
        """One request frame from the client (COB-ID 0x600 + node-id by default)."""
        data = frame.data
        if frame.rtr or len(data) != 8:
            self.ignored += 1     # CiA 301: SDO frames have DLC 8; shorter ones are not answered
            return
        self.requests += 1
        try:
            state = self._state
            if data[0] == codec.CS_UPLOAD_REQUEST and state is _IDLE:
                self._fast_upload(data)     # the most frequent request, kept short
                return
            if state is _BLOCK_DOWNLOAD:
                if data[0] == codec.CS_ABORT:
                    self._reset()       # client abort during a sub-block (sequence 0 is never a segment)
                else:
                    self._block_segment(data)
                return
            self._row[data[0] >> 5](self, data)
        except SdoAbort as exc:
            self._abort(exc.code)
        except Exception:  # device hook misbehaved: answer, never crash the bus
            self.node.count("hook_errors")
            self._abort(SdoAbortCode.GENERAL_ERROR)

    def _fast_upload(self, data: bytes) -> None:
        index = data[1] | (data[2] << 8)
        sub = data[3]
        self.index, self.subindex = index, sub
        value = self.node.read(index, sub)
        n = len(value)
        if 0 < n <= 4:
            self._send(_EXPEDITED_CS[n] + data[1:4] + value + _PAD[n])
        else:
            self._start_upload(index, sub, value)

    def _writable(self, index: int, sub: int) -> Entry:
        return self.node.check_writable(index, sub)

    def _unknown(self, data: bytes) -> None:
        if self._state is _IDLE:
            self.index, self.subindex = data[1] | (data[2] << 8), data[3]
        raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)

    def _client_abort(self, data: bytes) -> None:
        self._reset()       # abort from the client: no answer

    def _begin(self, data: bytes) -> tuple[int, int]:
        """A new initiate request ends any transfer in progress (CiA 301: the new one wins)."""
        index = data[1] | (data[2] << 8)
        sub = data[3]
        self._reset()
        self.index, self.subindex = index, sub
        return index, sub

    # -- expedited / segmented download --------------------------------------------------------
    def _initiate_download(self, data: bytes) -> None:
        cs = data[0]
        index, sub = self._begin(data)
        entry = self._writable(index, sub)
        if cs & 0x02:                                   # expedited
            size = codec.expedited_size(cs)
            if size is None:
                size = entry.size if entry.size is not None and entry.size <= 4 else 4
            self.node.store(entry, decode(entry, data[4:4 + size]))   # access checked above
            self._send(codec.download_response(index, sub))
            return
        size = _announced_size(data, entry) if cs & 0x01 else None
        limit, over = _limit(entry)
        self._download = SegmentedDownload(index, sub, size, limit, over)
        self.state = _DOWNLOAD_SEGMENTED
        self._send(codec.download_response(index, sub))
        self._arm()

    def _download_segment(self, data: bytes) -> None:
        transfer = self._download
        assert transfer is not None
        toggle, last = transfer.segment(data)
        if last:
            codec.check_size(len(transfer.buf), transfer.size)
            self._reset()
            self.node.write(transfer.index, transfer.subindex, bytes(transfer.buf))
        else:
            self._arm()
        self._send(codec.segment_ack(0x20, toggle))

    # -- expedited / segmented upload ----------------------------------------------------------
    def _initiate_upload(self, data: bytes) -> None:
        index, sub = self._begin(data)
        value = self.node.read(index, sub)
        self._start_upload(index, sub, value)

    def _start_upload(self, index: int, sub: int, value: bytes) -> None:
        n = len(value)
        if 0 < n <= 4:
            self._send(codec.expedited_upload_response(index, sub, value))
            return
        self.state = _UPLOAD_SEGMENTED
        self._upload = SegmentedUpload(index, sub, value)
        self._send(SDO_HEADER_U32.pack(codec.CS_UPLOAD_SEGMENTED_RESPONSE, index, sub, n))
        self._arm()

    def _upload_segment(self, data: bytes) -> None:
        transfer = self._upload
        assert transfer is not None
        reply, last = transfer.segment(data[0])
        if last:
            self._reset()
        else:
            self._arm()
        self._send_data(reply)

    # -- block download ------------------------------------------------------------------------
    def _block_download(self, data: bytes) -> None:
        if data[0] & 0x01:
            if self.state is not SdoServerState.BLOCK_DOWNLOAD_END:
                self._unknown(data)
            self._block_download_end(data)
        else:
            self._block_download_initiate(data)

    def _block_download_initiate(self, data: bytes) -> None:
        cs = data[0]
        index, sub = self._begin(data)
        if cs & 0x18:       # bits 4..3 are reserved
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
        entry = self._writable(index, sub)
        self._crc = bool(cs & 0x04)
        self._size = _announced_size(data, entry) if cs & 0x02 else None
        self._block_limit = _limit(entry)
        self.state = SdoServerState.BLOCK_DOWNLOAD
        self._receiver = BlockReceiver(self.block_size)
        self._send(SDO_HEADER.pack(codec.CS_BLOCK_DOWNLOAD_INITIATE_RESPONSE, index, sub)
                   + bytes((self.block_size, 0, 0, 0)))
        self._arm()

    def _block_segment(self, data: bytes) -> None:
        receiver = self._receiver
        assert receiver is not None
        ack = receiver.segment(data)
        if ack is not None:
            limit, over = self._block_limit
            if len(receiver.buf) > limit:
                raise SdoAbort(over)
            if receiver.last:
                self.state = SdoServerState.BLOCK_DOWNLOAD_END
            self._send(ack)
        self._arm()

    def _block_download_end(self, data: bytes) -> None:
        receiver = self._receiver
        assert receiver is not None
        payload = receiver.end(data, self._size, self._crc)
        index, sub = self.index, self.subindex
        self._reset()
        self.node.write(index, sub, payload)
        self._send(bytes((codec.CS_BLOCK_END_RESPONSE, 0, 0, 0, 0, 0, 0, 0)))

    # -- block upload --------------------------------------------------------------------------
    def _block_upload(self, data: bytes) -> None:
        sub_cmd = data[0] & 0x03
        if sub_cmd == BlockUploadSub.INITIATE:
            self._block_upload_initiate(data)
        elif sub_cmd == BlockUploadSub.START:
            self._block_upload_start(data[0])
        elif sub_cmd == BlockUploadSub.ACK:
            self._block_upload_ack(data)
        else:
            self._block_upload_end(data[0])

    def _block_upload_initiate(self, data: bytes) -> None:
        cs = data[0]
        index, sub = self._begin(data)
        blksize, pst = data[4], data[5]
        if cs & 0x18:
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
        if not 1 <= blksize <= 127:
            raise SdoAbort(SdoAbortCode.INVALID_BLOCK_SIZE)
        value = self.node.read(index, sub)
        if pst and len(value) <= pst:
            # Protocol switch threshold: answer with the normal upload protocol (CiA 301 7.2.4.3.13)
            self._start_upload(index, sub, value)
            return
        self._crc = bool(cs & 0x04)
        self._sender = BlockSender(value, blksize)
        self.state = SdoServerState.BLOCK_UPLOAD_START
        # sc only when the client asked for CRCs: some clients check it whenever the server offers it.
        self._send(SDO_HEADER_U32.pack(0xC2 | (0x04 if self._crc else 0), index, sub, len(value)))
        self._arm()

    def _block_upload_start(self, cs: int) -> None:
        if self.state is not SdoServerState.BLOCK_UPLOAD_START or cs != codec.CS_BLOCK_UPLOAD_START:
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
        self._send_sub_block()

    def _send_sub_block(self) -> None:
        sender = self._sender
        assert sender is not None
        self.state = SdoServerState.BLOCK_UPLOAD
        for segment in sender.sub_block():
            self._send_data(segment)
        self._arm()

    def _block_upload_ack(self, data: bytes) -> None:
        sender = self._sender
        if self.state is not SdoServerState.BLOCK_UPLOAD or sender is None:
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
        if sender.ack(data):
            self.state = SdoServerState.BLOCK_UPLOAD_END
            self._send(sender.end(crc=True))
            self._arm()
            return
        self._send_sub_block()

    def _block_upload_end(self, cs: int) -> None:
        if self.state is not SdoServerState.BLOCK_UPLOAD_END or cs != codec.CS_BLOCK_END_RESPONSE:
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
        self._reset()


_Handler = Callable[["SdoServer", bytes], None]


def _dispatch_table() -> dict[tuple[SdoServerState, int], _Handler]:
    """(state, client command specifier) -> handler; anything missing is 'command unknown'.
    Initiate requests are valid in every state (a new transfer ends the one in progress)."""
    table: dict[tuple[SdoServerState, int], _Handler] = {}
    for state in SdoServerState:
        table[(state, ClientCommand.INITIATE_DOWNLOAD)] = SdoServer._initiate_download
        table[(state, ClientCommand.INITIATE_UPLOAD)] = SdoServer._initiate_upload
        table[(state, ClientCommand.BLOCK_DOWNLOAD)] = SdoServer._block_download
        table[(state, ClientCommand.BLOCK_UPLOAD)] = SdoServer._block_upload
        table[(state, ClientCommand.ABORT)] = SdoServer._client_abort
    table[(SdoServerState.DOWNLOAD_SEGMENTED, ClientCommand.DOWNLOAD_SEGMENT)] = SdoServer._download_segment
    table[(SdoServerState.UPLOAD_SEGMENTED, ClientCommand.UPLOAD_SEGMENT)] = SdoServer._upload_segment
    return table


_DISPATCH = _dispatch_table()
#: The table as one row per state, indexed by the command specifier (0..7): no hashing on the hot path.
_ROWS: Final[dict[SdoServerState, tuple[_Handler, ...]]] = {
    state: tuple(_DISPATCH.get((state, ccs), SdoServer._unknown) for ccs in range(8)) for state in SdoServerState}
