"""SDO server (CiA 301 7.2.4): expedited, segmented and block transfers with CRC.

One server channel (0x1200). The state machine is driven by received request frames and by a
timeout on the node's clock; every failure is answered with the abort code of IDX guide
chapter 6. Object access goes through :meth:`Node.read` / :meth:`Node.write`, so SDO sees exactly
the access rights, lengths and limits that the contract promises.
"""

from __future__ import annotations

import struct
from enum import Enum
from typing import TYPE_CHECKING

from ..bus.frame import CanFrame
from ..common.clock import TimerHandle
from .crc import crc16_ccitt
from .errors import (
    COMMAND_SPECIFIER_UNKNOWN,
    CRC_ERROR,
    GENERAL_ERROR,
    INVALID_BLOCK_SIZE,
    INVALID_SEQUENCE_NUMBER,
    LENGTH_MISMATCH,
    LENGTH_TOO_LOW,
    OUT_OF_MEMORY,
    SDO_PROTOCOL_TIMED_OUT,
    TOGGLE_BIT_NOT_ALTERNATED,
    SdoAbort,
)

if TYPE_CHECKING:
    from ..od import Entry
    from .node import Node

#: command byte, index, sub-index (CiA 301 figure 20 ff.)
SDO_HEADER = struct.Struct("<BHB")
SDO_HEADER_U32 = struct.Struct("<BHBI")
#: Initiate upload response command byte for an expedited answer of n bytes, and its padding.
_EXPEDITED_CS = (b"", b"\x4F", b"\x4B", b"\x47", b"\x43")
_PAD = (b"", b"\x00\x00\x00", b"\x00\x00", b"\x00", b"")
#: Largest object a segmented or block download may carry before "out of memory".
MAX_TRANSFER = 1 << 20


def _announced_size(data: bytes, entry: Entry) -> int:
    """The size a segmented or block download announces, checked against the object (CiA 301
    7.2.4.3.3 / 7.2.4.3.9: too large for the server, or not the size of a fixed-size object)."""
    size: int = struct.unpack_from("<I", data, 4)[0]
    if size > MAX_TRANSFER:
        raise SdoAbort(OUT_OF_MEMORY)
    fixed = entry.size
    if fixed is not None and size != fixed:
        raise SdoAbort(LENGTH_TOO_LOW if size < fixed else LENGTH_MISMATCH)
    return size


class SdoServerState(Enum):
    IDLE = "idle"
    DOWNLOAD_SEGMENTED = "download segmented"
    UPLOAD_SEGMENTED = "upload segmented"
    BLOCK_DOWNLOAD = "block download (sub-block)"
    BLOCK_DOWNLOAD_END = "block download (end)"
    BLOCK_UPLOAD_START = "block upload (wait for start)"
    BLOCK_UPLOAD = "block upload (wait for ack)"
    BLOCK_UPLOAD_END = "block upload (wait for end)"


_IDLE = SdoServerState.IDLE


class SdoServer:
    """The default SDO server of a :class:`Node`."""

    def __init__(self, node: Node, timeout: float = 1.0, block_size: int = 127) -> None:
        self.node = node
        #: Seconds without the next request before a transfer is aborted with 0x05040000.
        self.timeout = timeout
        #: Block size the server asks for in block download (1..127).
        self.block_size = block_size
        self.state = SdoServerState.IDLE
        self.rx_cob_id = 0
        self.tx_cob_id = 0
        self.index = 0
        self.sub = 0
        self._buf = bytearray()
        self._data = b""
        self._pos = 0
        self._size: int | None = None
        self._toggle = 0
        self._timer: TimerHandle | None = None
        # block transfers
        self._crc = False
        self._blksize = 127
        self._ackseq = 0
        self._sub_block: list[bytes] = []
        self._block_start = 0
        self._sent = 0
        self._last_sent = False
        #: Expedited upload answers by payload: frames are immutable, polling repeats them.
        self._frames: dict[bytes, CanFrame] = {}
        #: Counters: requests answered, aborts sent, frames ignored (wrong DLC or RTR).
        self.requests = 0
        self.aborts_sent = 0
        self.ignored = 0

    # -- plumbing ------------------------------------------------------------------------------
    def _send(self, payload: bytes) -> None:
        self.node.send(CanFrame(self.tx_cob_id, payload))

    def _abort(self, code: int, index: int | None = None, sub: int | None = None) -> None:
        self._reset()
        self.aborts_sent += 1
        self._send(SDO_HEADER_U32.pack(0x80, self.index if index is None else index,
                                       self.sub if sub is None else sub, code))

    def _reset(self) -> None:
        self.state = SdoServerState.IDLE
        self._buf = bytearray()
        self._data = b""
        self._sub_block = []
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

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

    def _arm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = self.node.clock.call_later(self.timeout, self._timed_out)

    def _timed_out(self) -> None:
        self._timer = None
        if self.state is not SdoServerState.IDLE:
            self._abort(SDO_PROTOCOL_TIMED_OUT)

    # -- entry point ---------------------------------------------------------------------------
    def on_frame(self, frame: CanFrame, t: float) -> None:
        data = frame.data
        if frame.rtr or len(data) != 8:
            self.ignored += 1     # CiA 301: SDO frames have DLC 8; shorter ones are not answered
            return
        self.requests += 1
        try:
            if data[0] == 0x40 and self.state is _IDLE:
                self._fast_upload(data)     # the most frequent request, kept short
                return
            self._dispatch(data)
        except SdoAbort as exc:
            self._abort(exc.code)
        except Exception:  # device hook misbehaved: answer, never crash the bus
            self.node.stats["hook_errors"] = self.node.stats.get("hook_errors", 0) + 1
            self._abort(GENERAL_ERROR)

    def _fast_upload(self, data: bytes) -> None:
        node = self.node
        index = data[1] | (data[2] << 8)
        sub = data[3]
        self.index, self.sub = index, sub
        value = node.read(index, sub)
        n = len(value)
        if 0 < n <= 4:
            payload = _EXPEDITED_CS[n] + data[1:4] + value + _PAD[n]
            cache = self._frames
            frame = cache.get(payload)
            if frame is None or frame.can_id != self.tx_cob_id:
                if len(cache) >= 512:
                    cache.clear()
                frame = cache[payload] = CanFrame(self.tx_cob_id, payload)
            node.send(frame)
        else:
            self._start_upload(index, sub, value)

    def _dispatch(self, data: bytes) -> None:
        cs = data[0]
        state = self.state
        if state is SdoServerState.BLOCK_DOWNLOAD:
            if cs == 0x80:
                self._reset()           # client abort during a sub-block (sequence 0 is never a segment)
                return
            self._block_segment(data)
            return
        ccs = cs >> 5
        if ccs == 4:                    # abort from the client: no answer
            self._reset()
            return
        if ccs == 1:
            self._initiate_download(data)
        elif ccs == 2:
            self._initiate_upload(data)
        elif ccs == 0:
            self._download_segment(data)
        elif ccs == 3:
            self._upload_segment(data)
        elif ccs == 6:
            if cs & 0x01:
                self._block_download_end(data)
            else:
                self._block_download_initiate(data)
        elif ccs == 5:
            sub_cmd = cs & 0x03
            if sub_cmd == 0:
                self._block_upload_initiate(data)
            elif sub_cmd == 3:
                self._block_upload_start(cs)
            elif sub_cmd == 2:
                self._block_upload_ack(data)
            else:
                self._block_upload_end(cs)
        else:
            self._unknown(data)

    def _unknown(self, data: bytes) -> None:
        if self.state is SdoServerState.IDLE:
            _, index, sub = SDO_HEADER.unpack_from(data)
            self.index, self.sub = index, sub
        raise SdoAbort(COMMAND_SPECIFIER_UNKNOWN)

    def _begin(self, data: bytes) -> tuple[int, int]:
        """A new initiate request ends any transfer in progress (CiA 301: the new one wins)."""
        _, index, sub = SDO_HEADER.unpack_from(data)
        self._reset()
        self.index, self.sub = index, sub
        return index, sub

    # -- expedited / segmented download --------------------------------------------------------
    def _initiate_download(self, data: bytes) -> None:
        cs = data[0]
        index, sub = self._begin(data)
        node = self.node
        entry = node.check_writable(index, sub)
        if cs & 0x02:                                   # expedited
            unspecified = entry.size if entry.size is not None and entry.size <= 4 else 4
            size = 4 - ((cs >> 2) & 0x03) if cs & 0x01 else unspecified
            node.write(index, sub, data[4:4 + size])
            self._send(SDO_HEADER_U32.pack(0x60, index, sub, 0))
            return
        self._size = _announced_size(data, entry) if cs & 0x01 else None
        self.state = SdoServerState.DOWNLOAD_SEGMENTED
        self._toggle = 0
        self._buf = bytearray()
        self._send(SDO_HEADER_U32.pack(0x60, index, sub, 0))
        self._arm()

    def _download_segment(self, data: bytes) -> None:
        if self.state is not SdoServerState.DOWNLOAD_SEGMENTED:
            self._unknown(data)
        cs = data[0]
        toggle = (cs >> 4) & 1
        if toggle != self._toggle:
            raise SdoAbort(TOGGLE_BIT_NOT_ALTERNATED)
        n = (cs >> 1) & 0x07
        self._buf += data[1:8 - n]
        if len(self._buf) > MAX_TRANSFER:
            raise SdoAbort(OUT_OF_MEMORY)
        if cs & 0x01:
            payload = bytes(self._buf)
            if self._size is not None and len(payload) != self._size:
                raise SdoAbort(LENGTH_TOO_LOW if len(payload) < self._size else LENGTH_MISMATCH)
            index, sub = self.index, self.sub
            self._reset()
            self.node.write(index, sub, payload)
        else:
            self._toggle ^= 1
            self._arm()
        self._send(bytes((0x20 | (toggle << 4), 0, 0, 0, 0, 0, 0, 0)))

    # -- expedited / segmented upload ----------------------------------------------------------
    def _initiate_upload(self, data: bytes) -> None:
        index, sub = self._begin(data)
        value = self.node.read(index, sub)
        self._start_upload(index, sub, value)

    def _start_upload(self, index: int, sub: int, value: bytes) -> None:
        n = len(value)
        if 0 < n <= 4:
            self._send(SDO_HEADER.pack(0x43 | ((4 - n) << 2), index, sub) + value + bytes(4 - n))
            return
        self.state = SdoServerState.UPLOAD_SEGMENTED
        self._data = value
        self._pos = 0
        self._toggle = 0
        self._send(SDO_HEADER_U32.pack(0x41, index, sub, n))
        self._arm()

    def _upload_segment(self, data: bytes) -> None:
        if self.state is not SdoServerState.UPLOAD_SEGMENTED:
            self._unknown(data)
        toggle = (data[0] >> 4) & 1
        if toggle != self._toggle:
            raise SdoAbort(TOGGLE_BIT_NOT_ALTERNATED)
        pos = self._pos
        chunk = self._data[pos:pos + 7]
        self._pos = pos + len(chunk)
        last = self._pos >= len(self._data)
        n = 7 - len(chunk)
        if last:
            self._reset()
        else:
            self._toggle ^= 1
            self._arm()
        self._send(bytes(((toggle << 4) | (n << 1) | (1 if last else 0),)) + chunk + bytes(n))

    # -- block download ------------------------------------------------------------------------
    def _block_download_initiate(self, data: bytes) -> None:
        cs = data[0]
        index, sub = self._begin(data)
        if cs & 0x18:       # bits 4..3 are reserved
            raise SdoAbort(COMMAND_SPECIFIER_UNKNOWN)
        entry = self.node.check_writable(index, sub)
        self._crc = bool(cs & 0x04)
        self._size = _announced_size(data, entry) if cs & 0x02 else None
        self.state = SdoServerState.BLOCK_DOWNLOAD
        self._buf = bytearray()
        self._sub_block = []
        self._ackseq = 0
        self._blksize = self.block_size
        self._send(SDO_HEADER.pack(0xA4, index, sub) + bytes((self._blksize, 0, 0, 0)))
        self._arm()

    def _block_segment(self, data: bytes) -> None:
        cs = data[0]
        seq = cs & 0x7F
        last = bool(cs & 0x80)
        if seq == 0 or seq > self._blksize:
            raise SdoAbort(INVALID_SEQUENCE_NUMBER)
        if seq == self._ackseq + 1:
            self._ackseq = seq
            self._sub_block.append(data[1:8])
        else:
            last = False    # a segment after a lost one is discarded; the client repeats it
        if seq == self._blksize or last or (cs & 0x80):
            for seg in self._sub_block:
                self._buf += seg
            if len(self._buf) > MAX_TRANSFER:
                raise SdoAbort(OUT_OF_MEMORY)
            self._sub_block = []
            ackseq = self._ackseq
            self._ackseq = 0
            if last:
                self.state = SdoServerState.BLOCK_DOWNLOAD_END
            self._send(bytes((0xA2, ackseq, self._blksize, 0, 0, 0, 0, 0)))
        self._arm()

    def _block_download_end(self, data: bytes) -> None:
        if self.state is not SdoServerState.BLOCK_DOWNLOAD_END:
            self._unknown(data)
        n = (data[0] >> 2) & 0x07
        payload = bytes(self._buf[:len(self._buf) - n])
        if self._size is not None and len(payload) != self._size:
            raise SdoAbort(LENGTH_TOO_LOW if len(payload) < self._size else LENGTH_MISMATCH)
        if self._crc:
            client_crc = struct.unpack_from("<H", data, 1)[0]
            if crc16_ccitt(payload) != client_crc:
                raise SdoAbort(CRC_ERROR)
        index, sub = self.index, self.sub
        self._reset()
        self.node.write(index, sub, payload)
        self._send(bytes((0xA1, 0, 0, 0, 0, 0, 0, 0)))

    # -- block upload --------------------------------------------------------------------------
    def _block_upload_initiate(self, data: bytes) -> None:
        cs = data[0]
        index, sub = self._begin(data)
        blksize, pst = data[4], data[5]
        if cs & 0x18:
            raise SdoAbort(COMMAND_SPECIFIER_UNKNOWN)
        if not 1 <= blksize <= 127:
            raise SdoAbort(INVALID_BLOCK_SIZE)
        value = self.node.read(index, sub)
        if pst and len(value) <= pst:
            # Protocol switch threshold: answer with the normal upload protocol (CiA 301 7.2.4.3.13)
            self._start_upload(index, sub, value)
            return
        self._crc = bool(cs & 0x04)
        self._data = value
        self._pos = 0
        self._blksize = blksize
        self.state = SdoServerState.BLOCK_UPLOAD_START
        # sc only when the client asked for CRCs: some clients check it whenever the server offers it.
        self._send(SDO_HEADER_U32.pack(0xC2 | (0x04 if self._crc else 0), index, sub, len(value)))
        self._arm()

    def _block_upload_start(self, cs: int) -> None:
        if self.state is not SdoServerState.BLOCK_UPLOAD_START or cs != 0xA3:
            raise SdoAbort(COMMAND_SPECIFIER_UNKNOWN)
        self._send_sub_block()

    def _send_sub_block(self) -> None:
        self.state = SdoServerState.BLOCK_UPLOAD
        data = self._data
        pos = self._block_start = self._pos
        total = len(data)
        seq = 0
        last = False
        while seq < self._blksize and not last:
            seq += 1
            chunk = data[pos:pos + 7]
            pos += 7
            last = pos >= total
            self._send(bytes(((0x80 if last else 0) | seq,)) + chunk + bytes(7 - len(chunk)))
        self._sent = seq
        self._last_sent = last
        self._arm()

    def _block_upload_ack(self, data: bytes) -> None:
        if self.state is not SdoServerState.BLOCK_UPLOAD:
            raise SdoAbort(COMMAND_SPECIFIER_UNKNOWN)
        ackseq, blksize = data[1], data[2]
        if ackseq > self._sent:
            raise SdoAbort(INVALID_SEQUENCE_NUMBER)
        if not 1 <= blksize <= 127:
            raise SdoAbort(INVALID_BLOCK_SIZE)
        self._blksize = blksize
        self._pos = min(self._block_start + 7 * ackseq, len(self._data))
        if self._last_sent and ackseq == self._sent:
            total = len(self._data)
            used = total - 7 * ((total - 1) // 7) if total else 0
            n = 7 - used
            crc = crc16_ccitt(self._data)
            self.state = SdoServerState.BLOCK_UPLOAD_END
            self._send(struct.pack("<BH5x", 0xC1 | (n << 2), crc))
            self._arm()
            return
        self._send_sub_block()

    def _block_upload_end(self, cs: int) -> None:
        if self.state is not SdoServerState.BLOCK_UPLOAD_END or cs != 0xA1:
            raise SdoAbort(COMMAND_SPECIFIER_UNKNOWN)
        self._reset()


