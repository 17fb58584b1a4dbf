"""SYNC (CiA 301 7.2.5; IDX guide 3.3.3.3): consumer on COB-ID 0x1005 with the SYNC counter 0x1019.

On each SYNC the node (1) applies the data of synchronous RPDOs received since the previous
SYNC, (2) calls the device's SYNC listeners, (3) samples and sends its synchronous TPDOs. With
0x1019 = 0 the SYNC carries no data; with 2..240 it carries the counter (1 byte). Any other length
is answered with EMCY 0x8240. Bit 30 of 0x1005 makes the node the SYNC producer with the period
of 0x1006 (us).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Final

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.emcy import EMCY_UNEXPECTED_SYNC_LENGTH, ERR_COMMUNICATION
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.common.clock import PeriodicTimer
from gatewaylab.od import Entry
from gatewaylab.od.aborts import SdoAbort, SdoAbortCode

if TYPE_CHECKING:
    from gatewaylab.canopen.node import Node

__all__ = ["AddHandler", "Sync"]


AddHandler = Callable[[int, Callable[[CanFrame, float], None]], None]
_OPERATIONAL: Final = NmtState.OPERATIONAL


class Sync:
    """SYNC consumer (and optional producer) of a :class:`Node`."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.cob_id = 0x80
        self.overflow = 0
        self.producer = False
        self.period = 0.0
        self.counter = 0
        #: ``cb(counter, t)`` for device code; counter is None when the SYNC carries no data.
        self.listeners: list[Callable[[int | None, float], None]] = []
        self.received = 0
        self._timer: PeriodicTimer | None = None
        node.add_validator(0x1005, self._validate_cob_id)
        node.add_validator(0x1019, self._validate_overflow)
        for index in (0x1005, 0x1006, 0x1019):
            node.add_reaction(index, lambda e, v: self._reconfigure())

    def _validate_cob_id(self, entry: Entry, value: Any) -> None:
        if value & 0x20000000:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "SYNC: only 11-bit identifiers")
        if value & 0x40000000 and self.producer and (value & 0x7FF) != self.cob_id:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "SYNC: change the COB-ID of an active producer")

    def _validate_overflow(self, entry: Entry, value: Any) -> None:
        if value == 1 or value > 240:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "SYNC counter overflow: 0 or 2..240")
        if self.node.od.get(0x1006, 0) != 0:
            raise SdoAbort(SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE, "0x1006 is not 0 (CiA 301 7.5.2.22)")

    def configure(self) -> None:
        """Read 0x1005 (COB-ID, producer bit), 0x1006 (period) and 0x1019 (counter overflow) again."""
        od = self.node.od
        cob = od.get(0x1005, 0)
        self.cob_id = cob & 0x7FF
        self.producer = bool(cob & 0x40000000)
        self.period = od.get(0x1006, 0) * 1e-6
        self.overflow = od.get(0x1019, 0)
        self.counter = 0

    def _reconfigure(self) -> None:
        self.halt()
        self.configure()
        self.node.rebuild_dispatch()
        self.nmt_changed(self.node.nmt_state)

    def register(self, add: AddHandler) -> None:
        """A SYNC consumer receives the SYNC COB-ID through the node's dispatch."""
        if not self.producer:
            add(self.cob_id, self.on_frame)

    def halt(self) -> None:
        """Stop producing SYNCs (the node stops or leaves the running NMT states)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def nmt_changed(self, state: NmtState) -> None:
        """A producer sends SYNCs in Pre-operational and Operational only (CiA 301 7.2.5)."""
        running = state is NmtState.PRE_OPERATIONAL or state is NmtState.OPERATIONAL
        if running and self.producer and self.period > 0:
            if self._timer is None:
                self._timer = self.node.clock.call_every(self.period, self._produce)
        else:
            self.halt()

    def _produce(self) -> None:
        counter: int | None = None
        if self.overflow:
            self.counter = self.counter % self.overflow + 1
            counter = self.counter
        self.node.send(CanFrame(self.cob_id, b"" if counter is None else bytes((counter,))))
        self._consume(counter, self.node.clock.now())

    def on_frame(self, frame: CanFrame, t: float) -> None:
        """A received SYNC: checked against 0x1019 (counter or none) and passed to the PDOs."""
        if frame.rtr:
            return
        data = frame.data
        expected = 1 if self.overflow else 0
        if len(data) != expected:
            self.node.count("sync_length_errors")
            self.node.emcy.raise_error(EMCY_UNEXPECTED_SYNC_LENGTH, ERR_COMMUNICATION, bytes((len(data),)))
            return
        self._consume(data[0] if data else None, t)

    def _consume(self, counter: int | None, t: float) -> None:
        self.received += 1
        node = self.node
        if node.emcy.active and EMCY_UNEXPECTED_SYNC_LENGTH in node.emcy.active:
            node.emcy.clear_error(EMCY_UNEXPECTED_SYNC_LENGTH)
        operational = node.nmt_state is _OPERATIONAL
        if operational:
            node.pdo.apply_sync_rpdos()
        if self.listeners:
            for listener in list(self.listeners):
                listener(counter, t)
        if operational:
            node.pdo.on_sync(counter)
