"""The USB-to-CAN gateway of the IDX (guide chapter 5, 2.1.2.4, 2.1.3).

Requests for any node other than 0 or the IDX's own node id become CiA 301 SDO transfers to that
node (the SDO client is injected; it reports a node's abort code or 0x05040000 on silence).
SendNMTService puts the NMT frame (COB-ID 0) on the bus; SendLSS puts the 8 bytes on 0x7E5 and
ReadLSS hands out the next 0x7E4 frame that arrived since the last SendLSS, waiting up to the
given timeout on the clock.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.devices.maxon_idx.errors import IdxRemoteError, SdoAbortCode

__all__ = [
    "LSS_BACKLOG",
    "LSS_MASTER_COB_ID",
    "LSS_SLAVE_COB_ID",
    "NMT_COB_ID",
    "SDO_ABORT",
    "SDO_DOWNLOAD_EXPEDITED_NO_SIZE",
    "SDO_DOWNLOAD_RESPONSE",
    "SDO_REQUEST_BASE",
    "SDO_RESPONSE_BASE",
    "SDO_UPLOAD_REQUEST",
    "SDO_UPLOAD_RESPONSE",
    "CanGateway",
    "DownloadCallback",
    "SdoClientLike",
    "UploadCallback",
]


LSS_MASTER_COB_ID = 0x7E5
LSS_SLAVE_COB_ID = 0x7E4
NMT_COB_ID = 0x000
SDO_REQUEST_BASE = 0x600
SDO_RESPONSE_BASE = 0x580
#: CiA 301 expedited download, size not indicated (e=1, s=0): the server takes its object's size.
SDO_DOWNLOAD_EXPEDITED_NO_SIZE = 0x22
SDO_DOWNLOAD_RESPONSE = 0x60
SDO_UPLOAD_REQUEST = 0x40
SDO_UPLOAD_RESPONSE = 0x40
SDO_ABORT = 0x80
_SDO = struct.Struct("<BHB4s")
_SDO_ABORT = struct.Struct("<BHBI")
#: LSS slave messages kept between SendLSS and ReadLSS (several slaves may answer one request).
LSS_BACKLOG = 64

UploadCallback = Callable[[bytes | GatewaylabError], None]
DownloadCallback = Callable[[GatewaylabError | None], None]


@dataclass(slots=True)
class _Expedited:
    """The gateway's own expedited transfer in flight (ReadObject upload or WriteObject download)."""

    node_id: int
    index: int
    subindex: int
    upload: bool
    callback: Callable[[Any], None]
    timer: TimerHandle


class SdoClientLike(Protocol):
    """What the gateway needs of :class:`gatewaylab.canopen.sdo_client.SdoClient`."""

    def upload(self, node_id: int, index: int, subindex: int, callback: Callable[[Any], None], *,
               segmented: bool | None = None, block: bool = False) -> None:
        """Read an object of another node; the callback gets bytes or an SdoAbort."""

    def download(self, node_id: int, index: int, subindex: int, data: bytes,
                 callback: Callable[[Any], None]) -> None:
        """Write an object of another node; the callback gets None or an SdoAbort."""

    def on_frame(self, frame: CanFrame, t: float) -> None:
        """A frame from the bus for the client."""


class CanGateway:
    """Implements :class:`~.protocol.Gateway` on one CAN controller (the IDX's own node)."""

    def __init__(self, clock: Clock, send: Callable[[CanFrame], None], sdo: SdoClientLike,
                 on_own_nmt: Callable[[int], None] | None = None,
                 own_node_id: Callable[[], int | None] = lambda: None, sdo_timeout: float = 0.5) -> None:
        self.clock = clock
        self.send = send
        self.sdo = sdo
        self.sdo_timeout = sdo_timeout
        # Gateway SDO transfers run one at a time (several USB channels may ask at once).
        self._ops: deque[Callable[[], None]] = deque()
        self._op_running = False
        self._expedited: _Expedited | None = None
        self.on_own_nmt = on_own_nmt
        self.own_node_id = own_node_id
        self.lss_armed = False
        self.lss_backlog: deque[bytes] = deque(maxlen=LSS_BACKLOG)
        self._lss_wait: tuple[UploadCallback, TimerHandle] | None = None
        self.sdo_requests = 0

    # -- CAN input -----------------------------------------------------------------------------------
    def on_frame(self, frame: CanFrame, t: float) -> None:
        """Every frame the IDX's controller receives."""
        if frame.can_id == LSS_SLAVE_COB_ID and not frame.rtr and not frame.extended:
            self._lss_frame(bytes(frame.data).ljust(8, b"\x00")[:8])
            return
        ex = self._expedited
        if ex is not None and frame.can_id == SDO_RESPONSE_BASE + ex.node_id and len(frame.data) == 8:
            self._expedited_answer(bytes(frame.data))
            return
        self.sdo.on_frame(frame, t)

    # -- SDO ---------------------------------------------------------------------------------------
    def upload(self, node_id: int, index: int, subindex: int, callback: UploadCallback, *,
               segmented: bool) -> None:
        """ReadObject (``segmented=False``) -> a CiA 301 initiate upload taking the expedited answer
        only: a server that starts a segmented transfer (object > 4 bytes) is aborted with
        0x06070010 at once, as maxon's own library reads by expedited upload (notes).
        InitiateSegmentedRead -> the SDO client's upload, expedited or segmented, of any size."""
        self.sdo_requests += 1
        if not segmented:
            self._submit(lambda: self._start_expedited(node_id, index, subindex, None, callback))
            return

        def done(result: Any) -> None:
            self._op_done()
            callback(result)

        self._submit(lambda: self.sdo.upload(node_id, index, subindex, done, segmented=True))

    def download(self, node_id: int, index: int, subindex: int, data: bytes,
                 callback: DownloadCallback) -> None:
        """WriteObject -> CiA 301 expedited download with the size *not* indicated: the USB
        command always carries 4 bytes and only the server knows its object's size (2.1.2.1)."""
        self.sdo_requests += 1
        self._submit(lambda: self._start_expedited(node_id, index, subindex, data, callback))

    def _submit(self, op: Callable[[], None]) -> None:
        self._ops.append(op)
        if not self._op_running:
            self._next_op()

    def _next_op(self) -> None:
        if self._ops:
            self._op_running = True
            self._ops.popleft()()
        else:
            self._op_running = False

    def _op_done(self) -> None:
        self.clock.call_soon(self._next_op)

    def _start_expedited(self, node_id: int, index: int, subindex: int, data: bytes | None,
                         callback: Callable[[Any], None]) -> None:
        """One expedited transfer: ``data`` None = initiate upload, else expedited download."""
        timer = self.clock.call_later(self.sdo_timeout, self._expedited_timeout)
        self._expedited = _Expedited(node_id, index, subindex, data is None, callback, timer)
        if data is None:
            payload = _SDO.pack(SDO_UPLOAD_REQUEST, index, subindex, bytes(4))
        else:
            payload = _SDO.pack(SDO_DOWNLOAD_EXPEDITED_NO_SIZE, index, subindex, data.ljust(4, b"\x00"))
        self.send(CanFrame(SDO_REQUEST_BASE + node_id, payload))

    def _end_expedited(self, result: bytes | GatewaylabError | None) -> None:
        ex, self._expedited = self._expedited, None
        if ex is None:
            return
        ex.timer.cancel()
        self._op_done()
        ex.callback(result)

    def _expedited_answer(self, data: bytes) -> None:
        ex = self._expedited
        assert ex is not None
        cs, index, sub, value = _SDO_ABORT.unpack(data)
        if (index, sub) != (ex.index, ex.subindex):
            return                      # an answer for another object: not ours
        if cs == SDO_ABORT:
            self._end_expedited(IdxRemoteError(value, f"node {ex.node_id} aborted with 0x{value:08X}"))
        elif not ex.upload and cs == SDO_DOWNLOAD_RESPONSE:
            self._end_expedited(None)
        elif ex.upload and cs & 0xE0 == SDO_UPLOAD_RESPONSE and cs & 0x02:      # expedited (e = 1)
            n = (cs >> 2) & 0x03 if cs & 0x01 else 0                          # s = 1: 4 - n bytes
            self._end_expedited(bytes(data[4:8 - n]))
        elif ex.upload and cs & 0xE0 == SDO_UPLOAD_RESPONSE:                    # segmented (e = 0)
            self._abort_server(SdoAbortCode.LENGTH_MISMATCH)
            self._end_expedited(IdxRemoteError(SdoAbortCode.LENGTH_MISMATCH,
                                               f"node {ex.node_id} 0x{index:04X}:{sub:02X} is longer than "
                                               "4 bytes: use InitiateSegmentedRead"))
        else:
            self._abort_server(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
            self._end_expedited(IdxRemoteError(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN, f"SDO answer cs 0x{cs:02X}"))

    def _expedited_timeout(self) -> None:
        ex = self._expedited
        if ex is not None:
            self._abort_server(SdoAbortCode.SDO_PROTOCOL_TIMED_OUT)
            self._end_expedited(IdxRemoteError(SdoAbortCode.SDO_PROTOCOL_TIMED_OUT, f"node {ex.node_id} silent"))

    def _abort_server(self, code: int) -> None:
        ex = self._expedited
        if ex is not None:
            self.send(CanFrame(SDO_REQUEST_BASE + ex.node_id,
                               _SDO_ABORT.pack(SDO_ABORT, ex.index, ex.subindex, code)))

    # -- NMT ---------------------------------------------------------------------------------------
    def send_nmt(self, node_id: int, command: int) -> None:
        """2.1.2.4 / table 3-12: COB-ID 0, byte 0 = CS, byte 1 = node id (0 = all)."""
        self.send(CanFrame(NMT_COB_ID, bytes([command, node_id])))
        own = self.own_node_id()
        if self.on_own_nmt is not None and (node_id == 0 or node_id == own):
            # The IDX's controller does not receive its own frame; it obeys it like every node.
            self.clock.call_soon(self.on_own_nmt, command)

    # -- LSS ---------------------------------------------------------------------------------------
    def send_lss(self, data: bytes) -> None:
        """2.1.3.1: the LSS master message on 0x7E5; older unread slave answers are dropped."""
        self.lss_armed = True
        self.lss_backlog.clear()
        self.send(CanFrame(LSS_MASTER_COB_ID, data))

    def read_lss(self, timeout: float, callback: UploadCallback) -> None:
        """2.1.3.2: only after a SendLSS; the next 0x7E4 frame, else 0x05040000 after ``timeout``."""
        if not self.lss_armed:
            raise IdxRemoteError(SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE, "ReadLSS before any SendLSS")
        if self._lss_wait is not None:
            raise IdxRemoteError(SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE, "another ReadLSS is waiting")
        if self.lss_backlog:
            callback(self.lss_backlog.popleft())
            return
        handle = self.clock.call_later(max(timeout, 0.0), self._lss_timeout)
        self._lss_wait = (callback, handle)

    def _lss_timeout(self) -> None:
        wait, self._lss_wait = self._lss_wait, None
        if wait is not None:
            wait[0](IdxRemoteError(SdoAbortCode.SDO_PROTOCOL_TIMED_OUT, "no LSS slave message within the timeout"))

    def _lss_frame(self, data: bytes) -> None:
        wait, self._lss_wait = self._lss_wait, None
        if wait is None:
            self.lss_backlog.append(data)
            return
        wait[1].cancel()
        wait[0](data)
