"""The esd API's transaction numbers carried by ECAN-Lite TX_RESULTs, sans-I/O.

:class:`TxBook` is the Tx bookkeeping of :class:`~gatewaylab.migrate.esdqueue.EsdQueueOnEcanLite`
without any I/O: frames wait in order with their transaction numbers (1..FFFFh, then 1 again, as
the esd host library's :class:`~gatewaylab.hosts.esd_can_ethercat.Handshake` hands them
out); :meth:`TxBook.take_batch` gives a whole batch of at most the Tx queue size (esd 0x8000:22)
when the MCAN TX FIFO has room for all of it, or nothing; :meth:`TxBook.published` files each
frame under its (RefPacketSeq, RefFrameIndex) (ECAN-Lite chapter 10); :meth:`TxBook.accept` marks
what was published as accepted (the image reached the device); :meth:`TxBook.on_result` takes a
TX_RESULT. A transaction is *completed* when it and every one before it have a final result,
so the completed ones are always a prefix, as with the esd's input Tx Transaction Number (5.1.5.1).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import LocalError
from gatewaylab.devices.ecanlite.stream import TxResultCode
from gatewaylab.hosts.esd_can_ethercat.handshake import TransactionNumbers

__all__ = ["TxBook"]

#: ResultCode 1 'queued' is not final (chapter 10: 'entered the local transmission queue').
FINAL = frozenset(c for c in TxResultCode if c != TxResultCode.QUEUED)


class TxBook(TransactionNumbers):
    """Transaction numbers, batches and completion of one esd queue on one MCAN channel (no I/O)."""

    def __init__(self, tx_queue: int, tx_room: int, *, extended: bool, tx_limit: int) -> None:
        super().__init__(tx_limit)
        if not 0 < tx_queue <= tx_room:
            raise LocalError(f"Tx queue size {tx_queue} must be 1..{tx_room} (the TX FIFO takes a batch whole)")
        self.tx_queue = tx_queue
        self.tx_room = tx_room
        self.extended = extended
        self._pending: deque[tuple[int, CanFrame]] = deque()
        self._taken = 0                                    # given out by take_batch, not yet published
        self._unaccepted: list[int] = []                   # published, the image not yet through
        self._inflight: deque[int] = deque()               # published, in order, until completed
        self._by_ref: dict[tuple[int, int], int] = {}      # (RefPacketSeq, RefFrameIndex) -> tn
        self._frames: dict[int, CanFrame] = {}             # published frames without a final result
        self._results: dict[int, TxResultCode] = {}        # final results not yet a completed prefix
        self._outcome: dict[int, TxResultCode] = {}        # results of completed tns (the recent ones)
        self._open = 0                                     # published without a final result: TX FIFO use
        #: TX_RESULTs naming no (sequence, index) of the table (e.g. from before a restart).
        self.unmatched = 0
        #: take_batch calls that gave nothing though frames waited (no room, or held).
        self.held = 0

    # ------------------------------------------------------------------ queueing
    def submit(self, frames: Iterable[CanFrame]) -> list[int]:
        """Queue ``frames`` in order; their transaction numbers. FrameError (a frame the esd queues
        cannot carry) or TxQueueFull (beyond ``tx_limit``): nothing is queued."""
        batch = list(frames)
        tns = self._number(batch, extended=self.extended,
                           in_use=len(self._pending) + self._taken + len(self._inflight))
        for tn, f in zip(tns, batch, strict=True):
            self._outcome.pop(tn, None)
            self._pending.append((tn, f))
        return tns

    def take_batch(self, hold: bool = False) -> list[tuple[int, CanFrame]]:
        """The next batch, whole (at most ``tx_queue`` frames), when none is between take and publish,
        the TX FIFO has room for all of it and ``hold`` is False; else nothing."""
        if self._taken or not self._pending:
            return []
        n = min(len(self._pending), self.tx_queue)
        if hold or self._open + n > self.tx_room:
            self.held += 1
            return []
        self._taken = n
        return [self._pending.popleft() for _ in range(n)]

    def published(self, refs: Iterable[tuple[int, CanFrame, tuple[int, int]]]) -> None:
        """The taken batch is in a committed RxPDO image: (tn, frame, (seq, index)) of each frame."""
        for tn, frame, ref in refs:
            self._by_ref[ref] = tn
            self._frames[tn] = frame
            self._unaccepted.append(tn)
            self._inflight.append(tn)
            self._open += 1
        self._taken = 0

    @property
    def taken(self) -> bool:
        """A batch was taken and is not published yet."""
        return self._taken > 0

    @property
    def unaccepted(self) -> bool:
        """A published batch's image has not been through an exchange with a complete working counter."""
        return bool(self._unaccepted)

    def accept(self) -> int:
        """The published images went through: their frames are accepted; how many."""
        n = len(self._unaccepted)
        if n:
            self.accepted_seq = self._seq_of[self._unaccepted[-1]]
            self._unaccepted.clear()
        return n

    def on_result(self, seq: int, index: int, code: int) -> tuple[int, CanFrame] | None:
        """A TX_RESULT: for a final code, the (tn, frame) it completes; None for 'queued' or a result
        naming no frame of the table (counted in ``unmatched``)."""
        result = TxResultCode(code)
        if result not in FINAL:
            return None
        tn = self._by_ref.pop((seq, index), None)
        if tn is None:
            self.unmatched += 1
            return None
        self._results[tn] = result
        self._open -= 1
        frame = self._frames.pop(tn)
        while self._inflight and self._inflight[0] in self._results:
            done = self._inflight.popleft()
            self._outcome[done] = self._results.pop(done)
            self.completed_seq = self._seq_of[done]
        if len(self._outcome) > 2 * self.tx_limit:
            for old in list(self._outcome)[:self.tx_limit]:
                del self._outcome[old]
        return tn, frame

    # ------------------------------------------------------------------ queries
    def result(self, tn: int) -> TxResultCode | None:
        """The final TX_RESULT of a completed ``tn``; None while it is not completed."""
        self._issue(tn)
        return self._outcome.get(tn)

    @property
    def pending(self) -> int:
        """Frames not yet taken."""
        return len(self._pending)

    @property
    def in_flight(self) -> int:
        """Frames published and not yet completed."""
        return len(self._inflight)
