"""Sans-I/O SDO client (CiA 301 7.2.4): expedited, segmented and block transfers.

Requests go out through ``send``; answers come in through :meth:`SdoClient.on_frame`. One transfer
per server node runs at a time, the others wait in a queue. A transfer ends with exactly one
callback: the data (upload) or None (download) on success, :class:`SdoAbort` otherwise — the
server's abort code, 0x05040000 when no answer came within ``timeout`` (the client then sends that
abort to the server), or the code of the protocol error the client detected.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import LocalError
from gatewaylab.od import SdoAbort, SdoAbortCode
from gatewaylab.od import sdo as codec
from gatewaylab.od.sdo import SDO_HEADER, SDO_HEADER_U32, ServerCommand

__all__ = ["DownloadCallback", "SdoClient", "UploadCallback"]


UploadCallback = Callable[[bytes | SdoAbort], None]
DownloadCallback = Callable[[SdoAbort | None], None]


class _Phase(Enum):
    INITIATE = "initiate"
    SEGMENTS = "segments"
    BLOCK_SUB = "block sub-block"
    BLOCK_END = "block end"


@dataclass(slots=True)
class _Transfer:
    node_id: int
    index: int
    subindex: int
    upload: bool
    callback: Callable[[Any], None]
    data: bytes = b""
    segmented: bool | None = None
    block: bool = False
    phase: _Phase = _Phase.INITIATE
    #: the segmented transfer's client half (od/sdo.py), made when the server chose segments
    upload_segments: codec.ClientSegmentedUpload | None = None
    download_segments: codec.ClientSegmentedDownload | None = None
    #: the block transfer's halves (od/sdo.py): the client receives a block upload, sends a block download
    block_receiver: codec.BlockReceiver | None = None
    block_sender: codec.BlockSender | None = None
    size: int | None = None
    crc: bool = False
    timer: TimerHandle | None = None
    size_indicated: bool = True


class SdoClient:
    """An SDO client for any number of server nodes on one bus."""

    def __init__(self, clock: Clock, send: Callable[[CanFrame], None], timeout: float = 0.5,
                 block_size: int = 127) -> None:
        self.clock = clock
        self._send = send
        self.timeout = timeout
        self.block_size = block_size
        self._active: dict[int, _Transfer] = {}
        self._queues: dict[int, deque[_Transfer]] = {}
        self._cob_ids: dict[int, tuple[int, int]] = {}
        self._by_response: dict[int, int] = {}

    # -- configuration ---------------------------------------------------------------------------
    def set_cob_ids(self, node_id: int, request: int, response: int) -> None:
        """Use other COB-IDs than 0x600/0x580 + node-id for ``node_id``'s server."""
        self._cob_ids[node_id] = (request, response)

    def _request_id(self, node_id: int) -> int:
        return self._cob_ids.get(node_id, (0x600 + node_id, 0))[0]

    def _response_id(self, node_id: int) -> int:
        return self._cob_ids.get(node_id, (0, 0x580 + node_id))[1]

    def busy(self, node_id: int) -> bool:
        """True while a transfer to ``node_id`` is in progress (later ones wait in its queue)."""
        return node_id in self._active

    # -- API -------------------------------------------------------------------------------------
    def upload(self, node_id: int, index: int, subindex: int, callback: UploadCallback, *,
               segmented: bool | None = None, block: bool = False) -> None:
        """Read (index, subindex) of ``node_id``; ``block`` uses the block upload protocol.

        ``segmented`` is accepted for symmetry with :meth:`download` but has no effect: in an
        SDO upload the server chooses expedited or segmented (CiA 301 7.2.4.3.6).
        """
        self._enqueue(_Transfer(node_id, index, subindex, True, callback, segmented=segmented, block=block))

    def download(self, node_id: int, index: int, subindex: int, data: bytes, callback: DownloadCallback, *,
                 segmented: bool | None = None, block: bool = False, size_indicated: bool = True) -> None:
        """Write ``data`` to (index, subindex); expedited up to 4 bytes unless ``segmented`` or ``block``.

        ``size_indicated=False`` leaves the size indicator (bit s) clear in the initiate request
        (CiA 301 7.2.4.3.3): an expedited download is then ``0x22`` with the data padded to 4 bytes
        with zeros (the server takes the object's own length), a segmented one ``0x20`` with no
        size. Block downloads always indicate the size.
        """
        self._enqueue(_Transfer(node_id, index, subindex, False, callback, bytes(data), segmented, block,
                                size_indicated=size_indicated))

    def cancel_all(self) -> None:
        """Forget every transfer without callbacks (the owner is shutting down)."""
        for tr in self._active.values():
            if tr.timer is not None:
                tr.timer.cancel()
        self._active.clear()
        self._queues.clear()
        self._by_response.clear()

    def _enqueue(self, tr: _Transfer) -> None:
        if not 1 <= tr.node_id <= 127 or not 0 <= tr.index <= 0xFFFF or not 0 <= tr.subindex <= 0xFF:
            raise LocalError(f"bad SDO address node {tr.node_id} 0x{tr.index:X}:{tr.subindex:X}")
        if tr.node_id in self._active:
            self._queues.setdefault(tr.node_id, deque()).append(tr)
            return
        self._begin(tr)

    def _begin(self, tr: _Transfer) -> None:
        self._active[tr.node_id] = tr
        self._by_response[self._response_id(tr.node_id)] = tr.node_id
        if tr.upload:
            if tr.block:
                self._req(tr, SDO_HEADER.pack(0xA4, tr.index, tr.subindex) + bytes((self.block_size, 0, 0, 0)))
            else:
                self._req(tr, SDO_HEADER_U32.pack(codec.CS_UPLOAD_REQUEST, tr.index, tr.subindex, 0))
            return
        data = tr.data
        if tr.block:
            tr.crc = True
            self._req(tr, SDO_HEADER_U32.pack(0xC6, tr.index, tr.subindex, len(data)))
        elif len(data) <= 4 and data and not tr.segmented:
            self._req(tr, codec.expedited_download_request(tr.index, tr.subindex, data, tr.size_indicated))
        elif tr.size_indicated:
            self._req(tr, SDO_HEADER_U32.pack(0x21, tr.index, tr.subindex, len(data)))
        else:
            self._req(tr, SDO_HEADER_U32.pack(0x20, tr.index, tr.subindex, 0))

    # -- plumbing --------------------------------------------------------------------------------
    def _req(self, tr: _Transfer, payload: bytes, arm: bool = True) -> None:
        if arm:
            if tr.timer is not None:
                tr.timer.cancel()
            tr.timer = self.clock.call_later(self.timeout, self._timed_out, tr)
        self._send(CanFrame(self._request_id(tr.node_id), payload))

    def _finish(self, tr: _Transfer, result: Any) -> None:
        if tr.timer is not None:
            tr.timer.cancel()
            tr.timer = None
        if self._active.get(tr.node_id) is tr:
            del self._active[tr.node_id]
            self._by_response.pop(self._response_id(tr.node_id), None)
        queue = self._queues.get(tr.node_id)
        tr.callback(result)
        if queue and tr.node_id not in self._active:
            nxt = queue.popleft()
            if not queue:
                del self._queues[tr.node_id]
            self._begin(nxt)

    def _fail(self, tr: _Transfer, code: int, tell_server: bool = True) -> None:
        if tell_server:
            self._req(tr, codec.abort(tr.index, tr.subindex, code), arm=False)
        self._finish(tr, SdoAbort(code))

    def _timed_out(self, tr: _Transfer) -> None:
        tr.timer = None
        if self._active.get(tr.node_id) is tr:
            self._fail(tr, SdoAbortCode.SDO_PROTOCOL_TIMED_OUT)

    # -- responses -------------------------------------------------------------------------------
    def on_frame(self, frame: CanFrame, t: float) -> None:
        """A frame from the bus: the answer of the server a transfer is waiting for."""
        node_id = self._by_response.get(frame.can_id)
        if node_id is None or frame.rtr or frame.extended:
            return
        tr = self._active.get(node_id)
        if tr is None:
            return
        data = frame.data
        if len(data) != 8:
            return
        cs = data[0]
        if tr.phase is _Phase.BLOCK_SUB and tr.upload:
            self._block_upload_segment(tr, data)
            return
        if cs == codec.CS_ABORT:
            self._finish(tr, SdoAbort(struct.unpack_from("<I", data, 4)[0]))
            return
        try:
            if tr.upload:
                if tr.block:
                    self._block_upload_response(tr, data)
                else:
                    self._upload_response(tr, data)
            elif tr.block:
                self._block_download_response(tr, data)
            else:
                self._download_response(tr, data)
        except SdoAbort as exc:
            self._fail(tr, exc.code)

    def _check_mux(self, tr: _Transfer, data: bytes) -> None:
        _, index, subindex = SDO_HEADER.unpack_from(data)
        if index != tr.index or subindex != tr.subindex:
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN, "answer for another object")

    def _upload_response(self, tr: _Transfer, data: bytes) -> None:
        cs = data[0]
        if tr.phase is _Phase.INITIATE:
            if cs >> 5 != ServerCommand.INITIATE_UPLOAD:
                raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
            self._check_mux(tr, data)
            if cs & 0x02:
                n = (cs >> 2) & 0x03 if cs & 0x01 else 0
                self._finish(tr, bytes(data[4:8 - n]))
                return
            size = struct.unpack_from("<I", data, 4)[0] if cs & 0x01 else None
            tr.phase = _Phase.SEGMENTS
            tr.upload_segments = codec.ClientSegmentedUpload(size)
            self._req(tr, tr.upload_segments.request())
            return
        up = tr.upload_segments
        assert up is not None
        if up.response(data):
            self._finish(tr, up.data)
            return
        self._req(tr, up.request())

    def _download_response(self, tr: _Transfer, data: bytes) -> None:
        cs = data[0]
        if tr.phase is _Phase.INITIATE:
            if cs != 0x60:
                raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
            self._check_mux(tr, data)
            if len(tr.data) <= 4 and tr.data and not tr.segmented:
                self._finish(tr, None)
                return
            tr.phase = _Phase.SEGMENTS
            tr.download_segments = codec.ClientSegmentedDownload(tr.data)
            self._req(tr, tr.download_segments.next_segment())
            return
        down = tr.download_segments
        assert down is not None
        down.response(data)
        if down.done:
            self._finish(tr, None)
            return
        self._req(tr, down.next_segment())

    # -- block upload ----------------------------------------------------------------------------
    def _block_upload_response(self, tr: _Transfer, data: bytes) -> None:
        cs = data[0]
        if tr.phase is _Phase.INITIATE:
            if cs & 0xE1 != 0xC0:
                raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
            self._check_mux(tr, data)
            tr.crc = bool(cs & 0x04)
            tr.size = struct.unpack_from("<I", data, 4)[0] if cs & 0x02 else None
            tr.phase = _Phase.BLOCK_SUB
            tr.block_receiver = codec.BlockReceiver(self.block_size)
            self._req(tr, bytes((codec.CS_BLOCK_UPLOAD_START,)) + bytes(7))
            return
        # block end
        if cs & 0xE3 != 0xC1:
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
        receiver = tr.block_receiver
        assert receiver is not None
        payload = receiver.end(data, tr.size, tr.crc, short=SdoAbortCode.LENGTH_MISMATCH)
        self._req(tr, bytes((codec.CS_BLOCK_END_RESPONSE,)) + bytes(7), arm=False)
        self._finish(tr, payload)

    def _block_upload_segment(self, tr: _Transfer, data: bytes) -> None:
        if data[0] == codec.CS_ABORT:          # the server aborted (sequence 0 is never a segment)
            self._finish(tr, SdoAbort(struct.unpack_from("<I", data, 4)[0]))
            return
        receiver = tr.block_receiver
        assert receiver is not None
        try:
            ack = receiver.segment(data)
        except SdoAbort as exc:
            self._fail(tr, exc.code)
            return
        if ack is None:
            self._arm(tr)
            return
        if receiver.last:
            tr.phase = _Phase.BLOCK_END
        self._req(tr, ack)

    def _arm(self, tr: _Transfer) -> None:
        if tr.timer is not None:
            tr.timer.cancel()
        tr.timer = self.clock.call_later(self.timeout, self._timed_out, tr)

    # -- block download --------------------------------------------------------------------------
    def _block_download_response(self, tr: _Transfer, data: bytes) -> None:
        cs = data[0]
        if tr.phase is _Phase.INITIATE:
            if cs & 0xE3 != 0xA0:
                raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
            self._check_mux(tr, data)
            tr.crc = bool(cs & 0x04)
            if not 1 <= data[4] <= 127:
                raise SdoAbort(SdoAbortCode.INVALID_BLOCK_SIZE)
            tr.block_sender = codec.BlockSender(tr.data, data[4])
            self._send_sub_block(tr)
            return
        if tr.phase is _Phase.BLOCK_SUB:
            if cs & 0xE3 != 0xA2:
                raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
            sender = tr.block_sender
            assert sender is not None
            if sender.ack(data):
                tr.phase = _Phase.BLOCK_END
                self._req(tr, sender.end(tr.crc))
                return
            self._send_sub_block(tr)
            return
        if cs & 0xE3 != 0xA1:
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
        self._finish(tr, None)

    def _send_sub_block(self, tr: _Transfer) -> None:
        sender = tr.block_sender
        assert sender is not None
        tr.phase = _Phase.BLOCK_SUB
        for segment in sender.sub_block():
            self._req(tr, segment)
