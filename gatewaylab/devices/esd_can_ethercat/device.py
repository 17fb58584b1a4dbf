"""The esd CAN-EtherCAT gateway (manual chapter 5): an EtherCAT slave with one CAN controller.

Sans-I/O: :class:`EsdGateway` is the :class:`~gatewaylab.ethercat.slave.SlaveApplication` of one
:class:`~gatewaylab.ethercat.slave.Slave` and owns one :class:`~gatewaylab.bus.bus.Controller`
on a :class:`~gatewaylab.bus.bus.VirtualBus`; everything runs on the injected clock.

The MDP 5000 counter handshake (5.1.5.1-5.1.5.4, shared note ``esd-mdp5000-queues``):

* Tx: when the output Tx counter differs from the input Tx counter the gateway copies Number of
  Tx Messages messages into its local Tx queue (0x8000:24 deep) and sets the input Tx counter
  equal; the frames go to the controller one after the other, in order; the input Tx
  Transaction Number is that of the last frame the bus reported sent (TxDoneEvent).
* Rx: frames passing the 0x8001 filter wait in the local Rx queue (0x8000:23 deep); whenever the
  input Rx counter equals the output Rx counter the gateway writes up to 0x8000:21 of them, sets
  Number of Rx Messages and increments the input Rx counter; the master acknowledges by setting
  its Rx counter equal. A full local queue counts 0x2010:35 'FIFO overrun' and sets 0xF108:03.

The CAN controller side (bit rate, status, statistics, firmware) is :class:`~.controller.EsdController`,
which :class:`EsdGateway` builds on.
"""

from __future__ import annotations

from collections import deque
from typing import Any

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.controller import (
    BusEvent,
    ErrorFrameEvent,
    ErrorKind,
    ErrorState,
    StateChangeEvent,
    TxAbortedEvent,
    TxDoneEvent,
)
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.timing import classic_bits
from gatewaylab.common.clock import Clock
from gatewaylab.devices.esd_can_ethercat import bitrate as br
from gatewaylab.devices.esd_can_ethercat.codec import (
    IN_HEADER,
    OUT_HEADER,
    RX_SIZE,
    TX_SIZE,
    MessageError,
    decode_tx11,
    decode_tx29,
    encode_rx11,
    encode_rx29,
    input_size,
)
from gatewaylab.devices.esd_can_ethercat.controller import EsdController, FirmwareFiles
from gatewaylab.devices.esd_can_ethercat.objects import (
    DEFAULT_LOCAL_QUEUE,
    DEFAULT_QUEUE,
    FLAG_29BIT,
    FLAGS,
    LOCAL_RX,
    LOCAL_TX,
    RX_QUEUE,
    TX_QUEUE,
    esd_description,
    max_rx_queue,
    max_tx_queue,
    resize_queues,
)
from gatewaylab.ethercat.errors import AlStatusCode
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.slave import Slave
from gatewaylab.od import Entry, ObjectDictionary, SdoAbort, SdoAbortCode

__all__ = ["EsdGateway", "create_esd_gateway"]


class EsdGateway(EsdController):
    """One esd CAN-EtherCAT: ``slave`` (the EtherCAT side) and ``controller`` (the CAN side).

    ``update_duration``: seconds a firmware update takes before the reboot (5.3: about 3 minutes on
    the real device; a few seconds here, on the clock). Call :meth:`start` to attach to the bus.
    """

    #: The handshake parses the raw outputs: up to 148 Tx messages are not decoded into 0x7000 every
    #: cycle; a CoE read of 0x7000/0x7001 decodes them from the outputs image.
    store_outputs = False

    def __init__(self, clock: Clock, bus: VirtualBus | None, name: str = "CAN-EtherCAT", serial: int = 0,
                 update_duration: float = 3.0) -> None:
        super().__init__(clock, bus, name, serial, update_duration)
        # configuration from 0x8000 (applied in PREOP) and 0x8001
        self.extended = False
        self.rx_queue_size = DEFAULT_QUEUE
        self.tx_queue_size = DEFAULT_QUEUE
        self.local_rx_size = DEFAULT_LOCAL_QUEUE
        self.local_tx_size = DEFAULT_LOCAL_QUEUE
        self._filter_std: bytearray | None = None
        self._filter_ext: list[tuple[int, int]] | None = None
        # queues and handshake state
        self.rx_local: deque[CanFrame] = deque()
        self.tx_local: deque[tuple[int, CanFrame]] = deque()
        self._inflight: deque[tuple[int, CanFrame]] = deque()
        self._tx_pending = False
        self._in_tx = 0
        self._in_rx = 0
        self._num_rx = 0
        self._tx_tn = 0
        self._out_rx = 0
        self._op = False
        self._img = bytearray(input_size(False, DEFAULT_QUEUE))
        #: (29-bit, Rx queue, Tx queue) the queue objects and mappings were last built for
        self._layout = (False, DEFAULT_QUEUE, DEFAULT_QUEUE)
        self.slave = Slave(clock, esd_description(serial), self, FirmwareFiles(self), name=name)

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        """Attach the CAN controller to the bus (passive until a bit rate is set: 4.3, 5.1.5.9)."""
        if self.bus is not None and self.controller is None:
            self.controller = self.bus.attach(self.name, on_frame=self._on_frame, on_event=self._on_event,
                                              listen_only=True)
            self._apply_bitrate()

    def stop(self) -> None:
        """Detach from the bus; cancel timers."""
        for handle in (self._autobaud_next, self._update_timer):
            if handle is not None:
                handle.cancel()
        self._autobaud_next = self._update_timer = None
        if self.controller is not None and self.bus is not None:
            self.bus.detach(self.controller)
        self.controller = None

    # ------------------------------------------------------------------ dictionary hooks
    def setup_od(self, slave: Slave, od: ObjectDictionary) -> None:
        """0x8000 validated and applied, 0x8001 compiled, 0xF800 decoded and applied, 0x2010
        refreshed on read and reset on write, 0xF108 refreshed on read."""
        od.add_validator(0x8000, self._check_config)
        od.add_reaction(0x8000, lambda entry, value: self._apply_config())
        od.add_validator(0x8001, self._check_filter)
        od.add_reaction(0x8001, lambda entry, value: self._compile_filter())
        od.add_validator(0xF800, self._check_bitrate)
        od.add_reaction(0xF800, lambda entry, value: self._apply_bitrate())
        od.add_reaction(0x2010, self._reset_statistics)
        od.on_read(0x2010, lambda index, sub: self._refresh_statistics())
        od.on_read(0xF108, lambda index, sub: self._refresh_status())

    def _check_config(self, entry: Entry, value: Any) -> None:
        """5.1.5.5: queue sizes 1 .. what SM3/SM2 and the mapping objects allow (0x06090031/32);
        29-bit mode only when the present queue sizes fit it."""
        od = self.slave.od
        sub, value = entry.subindex, int(value)
        extended = bool(value & FLAG_29BIT) if sub == FLAGS else self.extended
        rx = value if sub == RX_QUEUE else int(od.get(0x8000, RX_QUEUE))
        tx = value if sub == TX_QUEUE else int(od.get(0x8000, TX_QUEUE))
        if sub in (RX_QUEUE, TX_QUEUE, LOCAL_RX, LOCAL_TX) and value < 1:
            raise SdoAbort(SdoAbortCode.VALUE_TOO_LOW, "a queue holds at least one message")
        if rx > max_rx_queue(extended) or tx > max_tx_queue(extended):
            raise SdoAbort(SdoAbortCode.VALUE_TOO_HIGH,
                           f"at most {max_rx_queue(extended)} Rx / {max_tx_queue(extended)} Tx messages fit")

    def _apply_config(self, rebuild: bool = False) -> None:
        """New 0x8000 values: queue objects, mappings and local queues follow (4.2: a master that
        reads the mapping afterwards gets the new sizes). The objects are rebuilt only when the
        layout changed (or ``rebuild``, after a reboot reset them): a write that keeps the sizes,
        or sets a local queue depth, costs no rebuild (a master's SDO answer stays in time)."""
        od = self.slave.od
        self.extended = bool(int(od.get(0x8000, FLAGS)) & FLAG_29BIT)
        self.rx_queue_size = int(od.get(0x8000, RX_QUEUE))
        self.tx_queue_size = int(od.get(0x8000, TX_QUEUE))
        self.local_rx_size = int(od.get(0x8000, LOCAL_RX))
        self.local_tx_size = int(od.get(0x8000, LOCAL_TX))
        layout = (self.extended, self.rx_queue_size, self.tx_queue_size)
        if rebuild or layout != self._layout:
            resize_queues(od, *layout)
            self._img = bytearray(input_size(self.extended, self.rx_queue_size))
            self._layout = layout
        while len(self.rx_local) > self.local_rx_size:
            self.rx_local.pop()
            self.stats.fifo_overrun += 1

    @staticmethod
    def _check_filter(entry: Entry, value: Any) -> None:
        """5.1.5.6: bytes 0-3 first, 4-7 last identifier; bits 31 and 63 both set for 29 bit."""
        if entry.subindex == 0:
            return
        value = int(value)
        first, last = value & 0xFFFFFFFF, value >> 32
        ext = bool(first & 0x80000000)
        if ext != bool(last & 0x80000000):
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "bits 31 and 63 must both be set for 29-bit IDs")
        first, last = first & 0x7FFFFFFF, last & 0x7FFFFFFF
        if first > last:
            raise SdoAbort(SdoAbortCode.MAX_LESS_THAN_MIN, "first identifier above the last")
        if last > (0x1FFFFFFF if ext else 0x7FF):
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "identifier out of range")

    def _compile_filter(self) -> None:
        """0x8001 as a table of standard identifiers and a list of extended ranges; subindex 0 = 0:
        everything passes (5.1.5.6 'In case this object is not configured ...')."""
        od = self.slave.od
        n = int(od.get(0x8001, 0))
        if n == 0:
            self._filter_std = self._filter_ext = None
            return
        std = bytearray(0x800)
        ext: list[tuple[int, int]] = []
        for i in range(1, n + 1):
            value = int(od.get(0x8001, i))
            first, last = value & 0x7FFFFFFF, (value >> 32) & 0x7FFFFFFF
            if value & 0x80000000:
                ext.append((first, last))
            else:
                std[first:last + 1] = b"\x01" * (last + 1 - first)
        self._filter_std, self._filter_ext = std, ext

    def _passes(self, frame: CanFrame) -> bool:
        std = self._filter_std
        if std is None:
            return True
        if not frame.extended:
            return bool(std[frame.can_id])
        assert self._filter_ext is not None
        return any(lo <= frame.can_id <= hi for lo, hi in self._filter_ext)

    # ------------------------------------------------------------------ hooks of the controller side
    def _take_back_frames(self) -> None:
        """Frames the controller has not sent yet go back to the head of the local Tx queue."""
        self._return_inflight()

    def _bitrate_applied(self) -> None:
        """Listen-only and no bit rate abort what waits (5.1.5.9); otherwise the next frame goes out."""
        if not self._may_send():
            self._abort_local()
        self._feed()

    def _return_inflight(self) -> None:
        """Frames the controller has not sent yet go back to the head of the local Tx queue."""
        ctrl = self.controller
        if ctrl is not None:
            ctrl.flush_tx()
        while self._inflight:
            self.tx_local.appendleft(self._inflight.pop())

    def _abort_local(self) -> None:
        """Listen-only and no baud rate never send (5.1.5.9): queued frames are aborted (0x2010:37)."""
        self.stats.aborted += len(self.tx_local)
        self.tx_local.clear()

    # ------------------------------------------------------------------ CAN side
    def _on_frame(self, frame: CanFrame, t: float) -> None:
        """The CAN handler: count, filter, queue, deliver when the master is ready. 11-bit queues
        (0x6000, 5.1.5.1) cannot carry a 29-bit identifier: in 11-bit mode such frames are only counted."""
        t0 = self.clock.now()
        st = self.stats
        st.rx.count(frame)
        st.rx_bits += classic_bits(frame.extended, len(frame.data))
        if self.setting.mode is br.Mode.AUTOBAUD and not self.detected:
            self._autobaud_found()
        if (self.extended or not frame.extended) and self._passes(frame):
            if len(self.rx_local) >= self.local_rx_size:
                st.fifo_overrun += 1
                self._refresh_status()
            else:
                self.rx_local.append(frame)
                if self._op and self._in_rx == self._out_rx:
                    self._deliver()
        self._can.add(self.clock.now() - t0)

    def _on_event(self, event: BusEvent) -> None:
        if isinstance(event, TxDoneEvent):
            self._tx_done(event.frame)
        elif isinstance(event, ErrorFrameEvent):
            self.stats.error_frames += 1
            if (event.kind is ErrorKind.FORM and self.setting.mode is br.Mode.AUTOBAUD and not self.detected
                    and self._autobaud_next is None):
                self._autobaud_next = self.clock.call_soon(self._autobaud_step)
            self._refresh_status()
        elif isinstance(event, TxAbortedEvent):
            self.stats.aborted += 1
            if self._inflight and self._inflight[0][1] is event.frame:
                self._inflight.popleft()
        elif isinstance(event, StateChangeEvent):
            self._refresh_status()
            if event.new is ErrorState.ERROR_ACTIVE:
                self._feed()

    def _feed(self) -> None:
        """Hand the next frame of the local Tx queue to the controller (one at a time, in order)."""
        if self._inflight or not self.tx_local or not self._can_send():
            return
        ctrl = self.controller
        assert ctrl is not None
        item = self.tx_local.popleft()
        self._inflight.append(item)
        self.stats.tx_forwarded += 1
        ctrl.send(item[1])

    def _tx_done(self, frame: CanFrame) -> None:
        """The bus sent a frame: its transaction number becomes the input Tx Transaction Number."""
        if not self._inflight or self._inflight[0][1] is not frame:
            return
        tn, _ = self._inflight.popleft()
        self.stats.tx.count(frame)
        self._tx_tn = tn
        self._write_header()
        if self._tx_pending:
            self._take_tx(self.slave.outputs)
        self._feed()

    # ------------------------------------------------------------------ EtherCAT side
    def on_transition(self, slave: Slave, old: AlState, new: AlState) -> int:
        """PREOP -> SAFEOP: 0x1C12 must assign 0x1600, 0x1C13 0x1A00 first (5.1.3.7, 5.1.3.8)."""
        if old == AlState.PREOP and new == AlState.SAFEOP:
            od = slave.od
            if int(od.get(0x1C12, 0)) != 1 or int(od.get(0x1C12, 1)) != 0x1600:
                return AlStatusCode.INVALID_OUTPUT_MAPPING
            n = int(od.get(0x1C13, 0))
            assigned = [int(od.get(0x1C13, i)) for i in range(1, n + 1)]
            if not assigned or assigned[0] != 0x1A00 or any(p != 0x1A85 for p in assigned[1:]):
                return AlStatusCode.INVALID_INPUT_MAPPING
        return 0

    def on_state(self, slave: Slave, old: AlState, new: AlState, code: int) -> None:
        """A new handshake from PREOP -> SAFEOP; the SM watchdog counts 0x2010:08 (5.1.4.2:
        'watchdog value is calculated by ESC registers 0x0400 and 0x0420')."""
        if code == AlStatusCode.SM_WATCHDOG:
            self.stats.watchdog += 1
        if new == AlState.SAFEOP and old == AlState.PREOP:
            self._in_tx = self._in_rx = self._num_rx = self._tx_tn = self._out_rx = 0
            self._tx_pending = False
            self._img = bytearray(input_size(self.extended, self.rx_queue_size))
            slave.write_inputs(bytes(self._img))
        self._op = new == AlState.OP

    def on_outputs(self, slave: Slave, data: bytes) -> None:
        """The cyclic handler: a new Tx batch when the output Tx counter changed, new Rx frames
        when the master acknowledged the last ones (output Rx counter == input Rx counter)."""
        clock = self.clock
        t0 = clock.now()
        out_tx, out_rx, _num = OUT_HEADER.unpack_from(data, 0)
        self._out_rx = out_rx
        if out_tx != self._in_tx:
            self._take_tx(data)
        if out_rx == self._in_rx and self.rx_local:
            self._deliver()
        ctrl = self.controller
        if ctrl is not None and (ctrl.tec, ctrl.rec) != self._status_cache[4:6]:
            self._refresh_status()
        self._cyclic.add(clock.now() - t0)

    def _take_tx(self, data: bytes) -> None:
        """Copy Number of Tx Messages (at most the Tx queue size) into the local Tx queue once it
        has room for them, then set the input Tx counter equal to the output's (5.1.5.3)."""
        if len(data) < OUT_HEADER.size:
            return
        out_tx, _out_rx, num = OUT_HEADER.unpack_from(data, 0)
        if out_tx == self._in_tx:
            self._tx_pending = False
            return
        n = min(num, self.tx_queue_size, (len(data) - OUT_HEADER.size) // TX_SIZE[self.extended])
        queued = len(self.tx_local) + len(self._inflight)
        if queued + n > self.local_tx_size and queued:
            self._tx_pending = True   # the local queue is full: the master waits for the counter
            return
        self._tx_pending = False
        st = self.stats
        st.tx_requested += n
        sending = self._may_send()
        decode = decode_tx29 if self.extended else decode_tx11
        size = TX_SIZE[self.extended]
        room = self.local_tx_size - queued
        for i in range(n):
            try:
                msg = decode(data, OUT_HEADER.size + i * size)
            except MessageError:
                st.aborted += 1
                continue
            if not sending or room <= 0:
                st.aborted += 1
                continue
            self.tx_local.append((msg.transaction, msg.frame))
            room -= 1
        self._in_tx = out_tx
        self._write_header()
        self._feed()

    def _deliver(self) -> None:
        """Write up to the Rx queue size frames, Number of Rx Messages, increment the input Rx counter."""
        if not self._op or self._in_rx != self._out_rx or not self.rx_local:
            return
        n = min(len(self.rx_local), self.rx_queue_size)
        img = self._img
        size = RX_SIZE[self.extended]
        encode = encode_rx29 if self.extended else encode_rx11
        pos = IN_HEADER.size
        pop = self.rx_local.popleft
        for _ in range(n):
            img[pos:pos + size] = encode(pop())
            pos += size
        self._num_rx = n
        self._in_rx = (self._in_rx + 1) & 0xFFFF
        self.stats.rx_copied += n
        IN_HEADER.pack_into(img, 0, self._in_tx, self._in_rx, n, self._tx_tn)
        self.slave.write_inputs(bytes(img[:pos]))

    def _write_header(self) -> None:
        IN_HEADER.pack_into(self._img, 0, self._in_tx, self._in_rx, self._num_rx, self._tx_tn)
        if self.slave.state in (AlState.SAFEOP, AlState.OP):
            self.slave.write_inputs(bytes(self._img[:IN_HEADER.size]))

    # ------------------------------------------------------------------ reboot
    def reboot(self) -> None:
        """Restart (6.1.3, and the end of a firmware update): settings back to their defaults,
        queues and statistics cleared, the controller off the bus, EtherCAT state INIT."""
        if self._update_timer is not None:
            self._update_timer.cancel()
            self._update_timer = None
        self.reboots += 1
        od = self.slave.od
        od.reset_values(range(0x1600, 0x10000))
        od.put(0x100A, 0, self.firmware_version)
        self._apply_config(rebuild=True)
        self._compile_filter()
        self.rx_local.clear()
        self.tx_local.clear()
        self._return_inflight()
        self.tx_local.clear()
        self._in_tx = self._in_rx = self._num_rx = self._tx_tn = self._out_rx = 0
        self._tx_pending = False
        self._started_at = self.clock.now()
        self.reset_statistics()
        od.put(0x2010, 1, 0)
        self._status_cache = ()
        self._apply_bitrate()
        self.slave.esc.force_state(AlState.INIT)


def create_esd_gateway(clock: Clock, bus: VirtualBus | None, name: str = "CAN-EtherCAT", serial: int = 0,
                       update_duration: float = 3.0, start: bool = True) -> EsdGateway:
    """A gateway attached to ``bus`` (started unless ``start=False``): its ``slave`` goes in a segment."""
    gw = EsdGateway(clock, bus, name, serial, update_duration)
    if start:
        gw.start()
    return gw

