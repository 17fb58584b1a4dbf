"""The sans-I/O Tx bookkeeping of the esd API on the ECAN-Lite (issue 13 part 2): transaction
numbers as the esd hands them out (esd manual 5.1.5.3, 1..FFFFh), whole batches (5.1.5.3 'Number
of Tx Messages'), TX_RESULT matching by (RefPacketSeq, RefFrameIndex) and completion as a prefix
(ECAN-Lite manual 10; esd 5.1.5.1 'transaction number of the last sent Tx')."""

from __future__ import annotations

import pytest

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import FrameError, LocalError
from gatewaylab.devices.ecanlite.stream import TxResultCode
from gatewaylab.hosts.esd_can_ethercat import TxQueueFull
from gatewaylab.migrate.txbook import TxBook


def _publish(book: TxBook, seq: int) -> list[int]:
    batch = book.take_batch()
    book.published((tn, f, (seq, i)) for i, (tn, f) in enumerate(batch))
    return [tn for tn, _f in batch]


def test_whole_batches_within_the_tx_fifo() -> None:
    """A batch is at most the Tx queue size and only given when the TX FIFO (room 8) holds all of
    it; the next waits for results (chapter 12 'put into the frame area as a whole')."""
    book = TxBook(5, 8, extended=False, tx_limit=100)
    tns = book.submit(CanFrame(0x100 + i) for i in range(12))
    assert tns == list(range(1, 13))
    assert _publish(book, 1) == [1, 2, 3, 4, 5]
    assert book.take_batch() == [] and book.held == 1              # 5 open + 5 > 8
    assert book.on_result(1, 0, TxResultCode.OK) == (1, CanFrame(0x100))
    assert book.on_result(1, 1, TxResultCode.OK) is not None
    assert _publish(book, 2) == [6, 7, 8, 9, 10]                   # 3 open + 5 <= 8
    assert book.take_batch(hold=True) == []                        # bus off: held


def test_completion_is_a_prefix_and_failures_complete() -> None:
    """Results may come in any order; a transaction completes only when every one before it has a
    final code; 'queued' (1) is not final; a failed code (5 bus off) completes and is kept."""
    book = TxBook(4, 32, extended=True, tx_limit=100)
    book.submit([CanFrame(0x1ABCDEF, b"x", extended=True), CanFrame(1), CanFrame(2), CanFrame(3)])
    _publish(book, 7)
    assert not book.accepted(1) and book.accept() == 4 and book.accepted(4)
    assert book.on_result(7, 1, TxResultCode.QUEUED) is None
    assert book.on_result(7, 1, TxResultCode.OK) is not None
    assert not book.completed(1) and not book.completed(2)
    assert book.on_result(7, 0, TxResultCode.BUS_OFF) is not None
    assert book.completed(2) and not book.completed(3)
    assert (book.result(1), book.result(2), book.result(3)) == (TxResultCode.BUS_OFF, TxResultCode.OK, None)
    assert book.on_result(9, 0, TxResultCode.OK) is None and book.unmatched == 1
    with pytest.raises(LocalError):
        book.completed(99)


def test_refusals_queue_nothing_and_numbers_wrap() -> None:
    """TxQueueFull / FrameError leave nothing queued; numbers run 1..FFFFh and wrap to 1 (0 never)."""
    book = TxBook(16, 32, extended=False, tx_limit=10)
    with pytest.raises(TxQueueFull):
        book.submit(CanFrame(i) for i in range(11))
    with pytest.raises(FrameError):
        book.submit([CanFrame(1), CanFrame(0x1000, extended=True)])
    with pytest.raises(FrameError):
        book.submit([CanFrame(1, bytes(12), fd=True)])
    assert book.pending == 0
    book._next_tn = 0xFFFF                                          # as after 65,534 transactions
    assert book.submit([CanFrame(1), CanFrame(2)]) == [0xFFFF, 1]
    with pytest.raises(LocalError):
        TxBook(33, 32, extended=False, tx_limit=10)
