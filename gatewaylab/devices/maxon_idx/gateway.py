"""The USB-to-CAN gateway of the IDX (guide chapter 5, 2.1.2.4, 2.1.3).

Requests for any node other than 0 or the IDX's own node id become CiA 301 SDO transfers to that
node (the SDO client is injected; it reports a node's abort code or 0x05040000 on silence).
SendNMTService puts the NMT frame (COB-ID 0) on the bus; SendLSS puts the 8 bytes on 0x7E5 and
ReadLSS hands out the next 0x7E4 frame that arrived since the last SendLSS, waiting up to the
given timeout on the clock.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any, Protocol

from ...bus.frame import CanFrame
from ...common.clock import Clock, TimerHandle
from ...common.errors import GatewaylabError
from .errors import ErrorCode, IdxRemoteError

LSS_MASTER_COB_ID = 0x7E5
LSS_SLAVE_COB_ID = 0x7E4
NMT_COB_ID = 0x000
#: LSS slave messages kept between SendLSS and ReadLSS (several slaves may answer one request).
LSS_BACKLOG = 64

UploadCallback = Callable[[bytes | GatewaylabError], None]
DownloadCallback = Callable[[GatewaylabError | None], None]


class SdoClientLike(Protocol):
    """What the gateway needs of :class:`gatewaylab.canopen.sdo_client.SdoClient`."""

    def upload(self, node_id: int, index: int, sub: int, callback: Callable[[Any], None], *,
               segmented: bool | None = None, block: bool = False) -> None: ...

    def download(self, node_id: int, index: int, sub: int, data: bytes,
                 callback: Callable[[Any], None]) -> None: ...

    def on_frame(self, frame: CanFrame, t: float) -> None: ...


class CanGateway:
    """Implements :class:`~.protocol.Gateway` on one CAN controller (the IDX's own node)."""

    def __init__(self, clock: Clock, send: Callable[[CanFrame], None], sdo: SdoClientLike,
                 on_own_nmt: Callable[[int], None] | None = None,
                 own_node_id: Callable[[], int | None] = lambda: None) -> None:
        self.clock = clock
        self.send = send
        self.sdo = sdo
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
        self.sdo.on_frame(frame, t)

    # -- SDO ---------------------------------------------------------------------------------------
    def upload(self, node_id: int, index: int, subindex: int, callback: UploadCallback, *,
               segmented: bool) -> None:
        """ReadObject -> SDO initiate upload (the server picks expedited for <= 4 bytes);
        InitiateSegmentedRead -> the same, accepting a segmented answer of any size."""
        self.sdo_requests += 1
        self.sdo.upload(node_id, index, subindex, callback, segmented=None)

    def download(self, node_id: int, index: int, subindex: int, data: bytes,
                 callback: DownloadCallback) -> None:
        self.sdo_requests += 1
        self.sdo.download(node_id, index, subindex, data, callback)

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
            raise IdxRemoteError(ErrorCode.WRONG_DEVICE_STATE, "ReadLSS before any SendLSS")
        if self._lss_wait is not None:
            raise IdxRemoteError(ErrorCode.WRONG_DEVICE_STATE, "another ReadLSS is waiting")
        if self.lss_backlog:
            callback(self.lss_backlog.popleft())
            return
        handle = self.clock.call_later(max(timeout, 0.0), self._lss_timeout)
        self._lss_wait = (callback, handle)

    def _lss_timeout(self) -> None:
        wait, self._lss_wait = self._lss_wait, None
        if wait is not None:
            wait[0](IdxRemoteError(ErrorCode.SDO_TIMEOUT, "no LSS slave message within the timeout"))

    def _lss_frame(self, data: bytes) -> None:
        wait, self._lss_wait = self._lss_wait, None
        if wait is None:
            self.lss_backlog.append(data)
            return
        wait[1].cancel()
        wait[0](data)
