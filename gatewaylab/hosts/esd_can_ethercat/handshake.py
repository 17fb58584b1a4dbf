"""The master's side of the MDP 5000 counter handshake, sans-I/O (manual 5.1.5.1-5.1.5.4,
docs/devices/esd_can_ethercat-host.md).

:class:`Handshake` works on the bytes of one gateway's outputs and inputs and nothing else; the
caller (:class:`~.gateway.EsdHost`, or any master loop) calls :meth:`Handshake.write_outputs`
before and :meth:`Handshake.read_inputs` after each process-data exchange.

Sending (note 'Sending' 1-4): frames wait in a pending queue, each with its transaction number.
When the input Tx counter equals the output Tx counter (the gateway copied the previous batch),
up to the Tx queue size of them (0x8000:22) go into the Tx messages, Number of Tx Messages is set
and the output Tx counter incremented; the batch counts as *accepted* once the input Tx counter
equals it again. The gateway sends in order and reports in the input Tx Transaction Number the
last frame it actually sent, so that number *completes* it and every frame accepted before it.

Receiving (note 'Receiving' 1-3): when the input Rx counter differs from the output Rx counter,
Number of Rx Messages frames are read, stamped with the time of the reading and buffered; the
output Rx counter is set equal (the acknowledgement) in the next outputs. A full buffer defers the
acknowledgement, so the gateway keeps the frames (its local queue, 0x8000:23, and then its 'FIFO
overrun' count 0x2010:35 take the excess: nothing is lost silently).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import FrameError, LocalError, RemoteError
from gatewaylab.devices.esd_can_ethercat.codec import (
    IN_HEADER,
    OUT_HEADER,
    RX_SIZE,
    TX_SIZE,
    CanStatus,
    MessageError,
    decode_rx11,
    decode_rx29,
    decode_status_pdo,
    encode_tx11,
    encode_tx29,
)
from gatewaylab.hosts.esd_can_ethercat.config import QueueLayout

__all__ = [
    "DEFAULT_RX_LIMIT",
    "DEFAULT_TX_LIMIT",
    "TN_MODULO",
    "Handshake",
    "RxFrame",
    "RxOverflowError",
    "TransactionNumbers",
    "TxQueueFull",
]


#: Transaction numbers are u16 (5.1.5.3 bits 0-15); 0 is never handed out, so the input Tx
#: Transaction Number 0 after PREOP -> SAFEOP ('nothing sent yet') completes nothing.
TN_MODULO = 0x10000
#: Frames the host keeps between queue() and their completion at most: well below the 65,535
#: transaction numbers, so a number in use is never handed out again.
DEFAULT_TX_LIMIT = 8192
#: Received frames buffered before the host stops acknowledging Rx batches.
DEFAULT_RX_LIMIT = 8192


class TxQueueFull(LocalError):
    """More frames queued than the host keeps (``pending``: frames waiting or not yet completed)."""

    def __init__(self, message: str, pending: int) -> None:
        super().__init__(message)
        self.pending = pending


class RxOverflowError(RemoteError):
    """The gateway's local Rx queue overran: 0xF108:03 'Rx overflow' is set and ``count`` frames
    were lost so far (0x2010:35 'CANDriver FIFO overrun'; None when not read)."""

    def __init__(self, message: str, count: int | None) -> None:
        super().__init__(message)
        self.count = count


@dataclass(frozen=True, slots=True)
class RxFrame:
    """One received frame with the clock time of the cycle whose inputs brought it."""

    frame: CanFrame
    timestamp: float
    batch: int          # the input Rx counter of its batch


class TransactionNumbers:
    """The esd API's transaction numbers (5.1.5.1), shared by every implementation of that API:
    1..FFFFh in issue order, then 1 again; a number is *accepted* once the gateway took the batch
    carrying it and *completed* once it and every frame before it are done (the completed ones are
    always a prefix, as the input Tx Transaction Number reports them)."""

    def __init__(self, tx_limit: int) -> None:
        if not 0 < tx_limit < TN_MODULO // 2:
            raise LocalError(f"tx_limit must be 1..{TN_MODULO // 2 - 1}")
        self.tx_limit = tx_limit
        self._next_tn = 1
        self._seq = 0                         # issue order of transaction numbers
        self._seq_of: dict[int, int] = {}     # transaction number -> its latest issue
        self.accepted_seq = 0
        self.completed_seq = 0

    def _number(self, batch: list[CanFrame], *, extended: bool, in_use: int) -> list[int]:
        """Transaction numbers for ``batch`` (all or none): FrameError for a frame the esd queues
        cannot carry, TxQueueFull when the host would keep more than ``tx_limit`` frames."""
        for f in batch:
            if f.fd:
                raise FrameError("the esd queues carry classic CAN frames only (5.1.5.3: 0..8 bytes)")
            if f.extended and not extended:
                raise FrameError(f"29-bit frame 0x{f.can_id:X} needs the 29-bit queues (0x8000:20 bit 0, "
                                 "manual 5.1.5.4)")
        if in_use + len(batch) > self.tx_limit:
            raise TxQueueFull(f"{in_use} frames queued or in flight, {len(batch)} more exceed "
                              f"the limit of {self.tx_limit}", in_use)
        tns = []
        for _ in batch:
            tn = self._next_tn
            self._next_tn = tn % (TN_MODULO - 1) + 1          # 1 .. 0xFFFF, then 1 again
            self._seq += 1
            self._seq_of[tn] = self._seq
            tns.append(tn)
        return tns

    def _issue(self, tn: int) -> int:
        try:
            return self._seq_of[tn]
        except KeyError:
            raise LocalError(f"transaction number {tn} was not handed out") from None

    def accepted(self, tn: int) -> bool:
        """The gateway took the batch carrying ``tn`` (esd: its Tx counter came back; ECAN-Lite: the
        image carrying it went through)."""
        return self._issue(tn) <= self.accepted_seq

    def completed(self, tn: int) -> bool:
        """The gateway is done with ``tn`` and every frame before it (in-order sending; a frame the
        gateway aborted completes with the next one sent)."""
        return self._issue(tn) <= self.completed_seq


class Handshake(TransactionNumbers):
    """Counter handshake of one gateway on its output and input bytes (no I/O, no clock)."""

    def __init__(self, layout: QueueLayout, *, tx_counter: int = 0, rx_counter: int = 0,
                 tx_limit: int = DEFAULT_TX_LIMIT, rx_limit: int = DEFAULT_RX_LIMIT) -> None:
        super().__init__(tx_limit)
        if layout.tx_messages < 1 or layout.rx_messages < 1:
            raise LocalError("the layout needs at least one Tx and one Rx message")
        if rx_limit < layout.rx_messages:
            raise LocalError(f"rx_limit {rx_limit} cannot hold one Rx batch of {layout.rx_messages}")
        self.layout = layout
        self.rx_limit = rx_limit
        self.out_tx = tx_counter & 0xFFFF     # output Tx Counter Application
        self.out_rx = rx_counter & 0xFFFF     # output Rx Counter Application
        self.in_tx = -1                       # input Tx Counter Gateway (-1: no inputs seen yet)
        self.in_rx = -1
        self.in_tn = 0                        # input Tx Transaction Number
        self._num_tx = 0
        self._pending: deque[tuple[int, CanFrame]] = deque()
        self._batch: list[int] = []           # written, not yet acknowledged by the Tx counter
        self._copied: deque[int] = deque()    # acknowledged (copied), not yet reported sent
        self._copied_set: set[int] = set()
        self._received: deque[RxFrame] = deque()
        self.status: CanStatus | None = None  # from the 0x1A85 PDO when assigned
        self._overflow_seen = False
        self._overflow_new = False
        # counters for the application and tests
        self.tx_batches = 0
        self.rx_batches = 0
        self.rx_frames = 0
        self.rx_deferred = 0                  # cycles an Rx batch waited for buffer room
        self.rx_invalid = 0                   # Rx messages no CAN frame can carry (skipped)

    # ------------------------------------------------------------------ Tx
    def submit(self, frames: Iterable[CanFrame]) -> list[int]:
        """Queue ``frames`` in order; returns their transaction numbers. Raises TxQueueFull (nothing
        queued) when the host would keep more than ``tx_limit`` frames."""
        batch = list(frames)
        in_use = len(self._pending) + len(self._batch) + len(self._copied)
        tns = self._number(batch, extended=self.layout.extended, in_use=in_use)
        self._pending.extend(zip(tns, batch, strict=True))
        return tns

    @property
    def pending(self) -> int:
        """Frames not yet written into a batch."""
        return len(self._pending)

    @property
    def in_flight(self) -> int:
        """Frames written or accepted, not yet completed."""
        return len(self._batch) + len(self._copied)

    def write_outputs(self, out: memoryview | bytearray) -> bool:
        """Fill the outputs before an exchange; True when a new Tx batch went in."""
        new = False
        if not self._batch and self._pending and self.in_tx == self.out_tx:
            size = TX_SIZE[self.layout.extended]
            encode = encode_tx29 if self.layout.extended else encode_tx11
            n = min(len(self._pending), self.layout.tx_messages)
            pos = OUT_HEADER.size
            for _ in range(n):
                tn, frame = self._pending.popleft()
                out[pos:pos + size] = encode(tn, frame)
                pos += size
                self._batch.append(tn)
            self._num_tx = n
            self.out_tx = (self.out_tx + 1) & 0xFFFF
            self.tx_batches += 1
            new = True
        OUT_HEADER.pack_into(out, 0, self.out_tx, self.out_rx, self._num_tx)
        return new

    # ------------------------------------------------------------------ inputs
    def read_inputs(self, data: bytes | bytearray | memoryview, now: float) -> None:
        """Take the inputs after an exchange: Tx acknowledgement, completion, a new Rx batch, status."""
        if len(data) < IN_HEADER.size:
            return
        in_tx, in_rx, num, tn = IN_HEADER.unpack_from(data, 0)
        if self._batch and in_tx == self.out_tx:
            last = self._batch[-1]
            self._copied.extend(self._batch)
            self._copied_set.update(self._batch)
            self._batch.clear()
            self.accepted_seq = self._seq_of[last]
        self.in_tx, self.in_tn = in_tx, tn
        if tn in self._copied_set:
            while self._copied:
                done = self._copied.popleft()
                self._copied_set.discard(done)
                if done == tn:
                    self.completed_seq = self._seq_of[done]
                    break
        self.in_rx = in_rx
        if in_rx != self.out_rx:
            self._take_rx(data, in_rx, num, now)
        offset = self.layout.status_offset
        if offset is not None and len(data) >= offset + 6:
            self.status = status = decode_status_pdo(data, offset)
            if status.rx_overflow and not self._overflow_seen:
                self._overflow_new = True
            self._overflow_seen = status.rx_overflow

    def _take_rx(self, data: bytes | bytearray | memoryview, in_rx: int, num: int, now: float) -> None:
        size = RX_SIZE[self.layout.extended]
        n = min(num, self.layout.rx_messages, (len(data) - IN_HEADER.size) // size)
        if len(self._received) + n > self.rx_limit:
            self.rx_deferred += 1          # not acknowledged: the gateway keeps the batch
            return
        decode = decode_rx29 if self.layout.extended else decode_rx11
        for i in range(n):
            try:
                frame = decode(data, IN_HEADER.size + i * size)
            except MessageError:
                self.rx_invalid += 1       # no CAN frame carries it: counted, the batch still acknowledged
                continue
            self._received.append(RxFrame(frame, now, in_rx))
        self.out_rx = in_rx
        self.rx_batches += 1
        self.rx_frames += n

    def take_received(self, limit: int | None = None) -> list[RxFrame]:
        """The buffered frames, oldest first (at most ``limit``)."""
        q = self._received
        n = len(q) if limit is None else min(limit, len(q))
        return [q.popleft() for _ in range(n)]

    @property
    def buffered(self) -> int:
        """Received frames not taken yet."""
        return len(self._received)

    def overflow_reported(self) -> bool:
        """True once per rise of the 0x1A85 PDO's 'Rx overflow' bit (then False until it rises again)."""
        new, self._overflow_new = self._overflow_new, False
        return new
