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
"""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass, fields
from typing import Any

from gatewaylab.bus.bus import (
    BusEvent,
    Controller,
    ErrorFrameEvent,
    ErrorKind,
    ErrorState,
    StateChangeEvent,
    TxAbortedEvent,
    TxDoneEvent,
    VirtualBus,
)
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.timing import classic_bits
from gatewaylab.common.clock import Clock, TimerHandle
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
from gatewaylab.devices.esd_can_ethercat.objects import (
    API_BAUD,
    BAUD_INDEX,
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
from gatewaylab.ethercat.errors import AlStatusCode, FoeError, FoeErrorCode
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.slave import Slave, SlaveApplication
from gatewaylab.od import Entry, ObjectDictionary, SdoAbort, SdoAbortCode

#: 5.3: the file name a firmware update is written to by FoE, and its password.
FIRMWARE_FILE = "firmwareUpdate"
FIRMWARE_PASSWORD = 0
#: A firmware file may start with this line to carry its version (docs/devices/esd_can_ethercat.md).
FIRMWARE_HEADER = re.compile(rb"\ACAN-EtherCAT firmware (\d{1,3}(?:\.\d{1,3}){0,3})[\r\n\0]")
#: Figure 39: the update's output, line by line (shown as the update proceeds).
UPDATE_LINES = ("End of file found. All good.", "Unpacking updater. Please wait...", "img_upd.raw",
                "Flashing updater and rebooting...")
#: ISO 11898-1 error warning limit (0xF108:02 'Warning Limit reached').
WARNING_LIMIT = 96
CYCLIC_WINDOW, CAN_WINDOW = 10_000, 1_000   # 5.1.4.2: "within its last 10000 / 1000 calls"


@dataclass(slots=True)
class GatewayStats:
    """The counters behind 0x2010 (5.1.4.2) and the web page's CAN statistics (Figure 41)."""

    watchdog: int = 0            # 0x2010:08
    tx_requested: int = 0        # :30
    tx_forwarded: int = 0        # :31
    rx_copied: int = 0           # :32
    fifo_overrun: int = 0        # :35
    error_frames: int = 0        # :36
    aborted: int = 0             # :37
    rx_std: int = 0              # :38
    rx_std_rtr: int = 0          # :39
    rx_ext: int = 0              # :3A
    rx_ext_rtr: int = 0          # :3B
    tx_std: int = 0              # :3C
    tx_std_rtr: int = 0          # :3D
    tx_ext: int = 0              # :3E
    tx_ext_rtr: int = 0          # :3F
    rx_bytes: int = 0
    tx_bytes: int = 0
    rx_bits: int = 0             # Figure 41 'Rcv bits' (stuffing as the bus model counts it)


class _Window:
    """Handler times in microseconds over the last ``size`` calls (min/max/avg of 5.1.4.2)."""

    __slots__ = ("busy", "size", "values")

    def __init__(self, size: int) -> None:
        self.size = size
        self.values: deque[int] = deque(maxlen=size)
        self.busy = 0.0   # seconds spent since the last CPU usage reading

    def add(self, seconds: float) -> None:
        self.values.append(int(seconds * 1e6))
        self.busy += seconds

    def summary(self) -> tuple[int, int, int]:
        v = self.values
        return (min(v), max(v), sum(v) // len(v)) if v else (0, 0, 0)


class EsdGateway(SlaveApplication):
    """One esd CAN-EtherCAT: ``slave`` (the EtherCAT side) and ``controller`` (the CAN side).

    ``update_duration``: seconds a firmware update takes before the reboot (5.3: about 3 minutes on
    the real device; a few seconds here, on the clock). Call :meth:`start` to attach to the bus.
    """

    #: The handshake parses the raw outputs: up to 148 Tx messages are not decoded into 0x7000 every
    #: cycle; a CoE read of 0x7000/0x7001 decodes them from the outputs image.
    store_outputs = False

    def __init__(self, clock: Clock, bus: VirtualBus | None, name: str = "CAN-EtherCAT", serial: int = 0,
                 update_duration: float = 3.0) -> None:
        self.clock = clock
        self.bus = bus
        self.name = name
        self.serial = serial
        self.update_duration = update_duration
        self.controller: Controller | None = None
        self.stats = GatewayStats()
        self._cyclic = _Window(CYCLIC_WINDOW)
        self._can = _Window(CAN_WINDOW)
        self._started_at = clock.now()
        self._cpu_read_at = clock.now()
        self.setting: br.BitRateSetting = br.no_baudrate()
        self.detected: int = 0            # autobaud: the rate found (0 while detecting)
        self._autobaud_index = 0
        self._autobaud_next: TimerHandle | None = None
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
        self._status_cache: tuple[Any, ...] = ()
        # firmware update (5.3, 6.1.2)
        self.firmware_version = esd_description().software_version
        self._update_timer: TimerHandle | None = None
        self._update_started = 0.0
        self._update_version: str | None = None
        self.updates = 0
        self.reboots = 0
        self.slave = Slave(clock, esd_description(serial), self, _FirmwareFiles(self), name=name)

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

    def _check_bitrate(self, entry: Entry, value: Any) -> None:
        """5.1.5.9: Table 6 indexes 0..6 or 255; API values per Tables 7-10 (else 0x06090030)."""
        try:
            if entry.subindex == BAUD_INDEX:
                br.from_index(int(value))
            elif entry.subindex == API_BAUD:
                br.from_api(int(value))
        except br.BitRateError as exc:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, str(exc)) from None

    # ------------------------------------------------------------------ bit rate
    def _effective_setting(self) -> br.BitRateSetting:
        od = self.slave.od
        table = br.from_index(int(od.get(0xF800, BAUD_INDEX)))
        return table if table is not None else br.from_api(int(od.get(0xF800, API_BAUD)))

    def _apply_bitrate(self) -> None:
        """Put the controller in the mode 0xF800 asks for: off the bus (NTCAN_NO_BAUDRATE),
        listen-only while detecting (NTCAN_AUTOBAUD), or at a rate, active or listen-only (LOM)."""
        self.setting = setting = self._effective_setting()
        if self._autobaud_next is not None:
            self._autobaud_next.cancel()
            self._autobaud_next = None
        self.detected = 0
        ctrl, bus = self.controller, self.bus
        if ctrl is None or bus is None:
            return
        self._return_inflight()
        if setting.mode is br.Mode.NONE:
            bus.disconnect(ctrl)
            ctrl.listen_only = True
        elif setting.mode is br.Mode.AUTOBAUD:
            self._autobaud_index = 0
            ctrl.listen_only = True
            ctrl.bitrate = br.TABLE9[br.AUTOBAUD_ORDER[0]]
            bus.reconnect(ctrl)
        else:
            ctrl.listen_only = setting.listen_only
            ctrl.bitrate = setting.bitrate
            bus.reconnect(ctrl)
        if not self._may_send():
            self._abort_local()
        self._feed()
        self._refresh_status()

    def _return_inflight(self) -> None:
        """Frames the controller has not sent yet go back to the head of the local Tx queue."""
        ctrl = self.controller
        if ctrl is not None:
            ctrl.flush_tx()
        while self._inflight:
            self.tx_local.appendleft(self._inflight.pop())

    def _can_send(self) -> bool:
        ctrl = self.controller
        return (ctrl is not None and ctrl.connected and not ctrl.listen_only
                and ctrl.state is not ErrorState.BUS_OFF)

    def _may_send(self) -> bool:
        """The bit rate setting lets the gateway send (not off the bus, listen-only or still detecting)."""
        s = self.setting
        return not (s.mode is br.Mode.NONE or (s.listen_only and not self.detected))

    def _abort_local(self) -> None:
        """Listen-only and no baud rate never send (5.1.5.9): queued frames are aborted (0x2010:37)."""
        self.stats.aborted += len(self.tx_local)
        self.tx_local.clear()

    def _autobaud_step(self) -> None:
        """A frame at a foreign rate (form error): try the next rate of the table."""
        self._autobaud_next = None
        ctrl = self.controller
        if ctrl is None or self.setting.mode is not br.Mode.AUTOBAUD or self.detected:
            return
        self._autobaud_index = (self._autobaud_index + 1) % len(br.AUTOBAUD_ORDER)
        ctrl.bitrate = br.TABLE9[br.AUTOBAUD_ORDER[self._autobaud_index]]

    def _autobaud_found(self) -> None:
        """A frame received without error between two other nodes: the rate is found, go active."""
        ctrl = self.controller
        assert ctrl is not None
        self.detected = ctrl.bitrate
        ctrl.listen_only = False
        self._feed()

    def actual_timing(self) -> br.BitTiming | None:
        """The controller's bit timing now (a detected autobaud rate included)."""
        if self.setting.mode is br.Mode.AUTOBAUD:
            return br.timing_for(self.detected) if self.detected else None
        return self.setting.timing

    # ------------------------------------------------------------------ CAN side
    def _on_frame(self, frame: CanFrame, t: float) -> None:
        """The CAN handler: count, filter, queue, deliver when the master is ready. 11-bit queues
        (0x6000, 5.1.5.1) cannot carry a 29-bit identifier: in 11-bit mode such frames are only counted."""
        t0 = self.clock.now()
        st = self.stats
        if frame.extended:
            if frame.rtr:
                st.rx_ext_rtr += 1
            else:
                st.rx_ext += 1
        elif frame.rtr:
            st.rx_std_rtr += 1
        else:
            st.rx_std += 1
        st.rx_bytes += len(frame.data)
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
        st = self.stats
        if frame.extended:
            if frame.rtr:
                st.tx_ext_rtr += 1
            else:
                st.tx_ext += 1
        elif frame.rtr:
            st.tx_std_rtr += 1
        else:
            st.tx_std += 1
        st.tx_bytes += len(frame.data)
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

    # ------------------------------------------------------------------ status and statistics
    def _refresh_status(self) -> None:
        """0xF108 from the controller (5.1.5.8): bus off, warning limit, Rx overflow, REC, TEC."""
        ctrl = self.controller
        tec = ctrl.tec if ctrl is not None else 0
        rec = ctrl.rec if ctrl is not None else 0
        bus_off = ctrl is not None and ctrl.state is ErrorState.BUS_OFF
        status = (bus_off, tec >= WARNING_LIMIT or rec >= WARNING_LIMIT or bus_off,
                  self.stats.fifo_overrun > 0, min(rec, 255), tec, rec)
        if status == self._status_cache:
            return
        self._status_cache = status
        self.slave.od.put_many(((0xF108, 1), (0xF108, 2), (0xF108, 3), (0xF108, 0x21), (0xF108, 0x22)),
                               (status[0], status[1], status[2], status[3], min(tec, 255)))

    def statistics(self) -> dict[int, int]:
        """0x2010 subindex -> value now (5.1.4.2)."""
        st = self.stats
        cmin, cmax, cavg = self._cyclic.summary()
        hmin, hmax, havg = self._can.summary()
        now = self.clock.now()
        span = now - self._cpu_read_at
        usage = 0 if span <= 0 else min(100, round(100 * (self._cyclic.busy + self._can.busy) / span))
        self._cpu_read_at = now
        self._cyclic.busy = self._can.busy = 0.0
        return {0x02: cmin, 0x03: cmax, 0x04: cavg, 0x05: hmin, 0x06: hmax, 0x07: havg, 0x08: st.watchdog,
                0x20: usage, 0x21: 0, 0x30: st.tx_requested, 0x31: st.tx_forwarded, 0x32: st.rx_copied,
                0x34: 0, 0x35: st.fifo_overrun, 0x36: st.error_frames, 0x37: st.aborted, 0x38: st.rx_std,
                0x39: st.rx_std_rtr, 0x3A: st.rx_ext, 0x3B: st.rx_ext_rtr, 0x3C: st.tx_std, 0x3D: st.tx_std_rtr,
                0x3E: st.tx_ext, 0x3F: st.tx_ext_rtr}

    def _refresh_statistics(self) -> None:
        od = self.slave.od
        for sub, value in self.statistics().items():
            od.put(0x2010, sub, value & 0xFFFFFFFF)

    def _reset_statistics(self, entry: Entry, value: Any) -> None:
        """5.1.4.2 'Reset': writing resets the statistics; reading then shows the time of the reset
        in milliseconds since the device started."""
        if entry.subindex != 1:
            return
        self.reset_statistics()

    def reset_statistics(self) -> None:
        """Zero every counter of 0x2010 (and the web page's statistics)."""
        for f in fields(GatewayStats):
            setattr(self.stats, f.name, 0)
        self._cyclic = _Window(CYCLIC_WINDOW)
        self._can = _Window(CAN_WINDOW)
        self._cpu_read_at = self.clock.now()
        self.slave.od.put(0x2010, 1, round(1000 * (self.clock.now() - self._started_at)) & 0xFFFFFFFF)
        self._refresh_status()

    # ------------------------------------------------------------------ firmware update and reboot
    def start_update(self, data: bytes) -> None:
        """Begin a firmware update with ``data`` (FoE 5.3 or the web page 6.1.2): after
        ``update_duration`` on the clock the device takes the version the file carries and reboots."""
        if self._update_timer is not None:
            raise ValueError("a firmware update is already running")
        if not data:
            raise ValueError("the firmware file is empty")
        m = FIRMWARE_HEADER.match(data[:64])
        self._update_version = m.group(1).decode("ascii") if m else None
        self._update_started = self.clock.now()
        self.updates += 1
        self._update_timer = self.clock.call_later(self.update_duration, self._finish_update)

    def update_progress(self) -> str | None:
        """Figure 39's output so far; None when no update runs."""
        if self._update_timer is None:
            return None
        part = (self.clock.now() - self._update_started) / self.update_duration if self.update_duration > 0 else 1
        shown = 2 + int(part * (len(UPDATE_LINES) - 1))
        return "\n".join(UPDATE_LINES[:min(shown, len(UPDATE_LINES))]) + "\n"

    @property
    def updating(self) -> bool:
        """A firmware update is running."""
        return self._update_timer is not None

    def _finish_update(self) -> None:
        self._update_timer = None
        if self._update_version is not None:
            self.firmware_version = self._update_version
        self.reboot()

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


class _FirmwareFiles:
    """FoE of 5.3: ``firmwareUpdate`` with password 0, in BOOT only (0x8008 'bootstrap only' in
    any other state); nothing to read."""

    def __init__(self, gateway: EsdGateway) -> None:
        self.gateway = gateway

    def foe_read(self, name: str, password: int) -> bytes:
        """The gateway offers no files."""
        raise FoeError(f"no file {name!r}", FoeErrorCode.NOT_FOUND)

    def foe_check_write(self, name: str, password: int) -> None:
        """The write request itself is refused (before any data) for another file name, another
        state than BOOT or another password."""
        if name != FIRMWARE_FILE:
            raise FoeError(f"no file {name!r} (only {FIRMWARE_FILE!r})", FoeErrorCode.NOT_FOUND)
        if self.gateway.slave.state != AlState.BOOT:
            raise FoeError("firmware updates only in BOOT", FoeErrorCode.BOOTSTRAP_ONLY)
        if password != FIRMWARE_PASSWORD:
            raise FoeError("wrong password", FoeErrorCode.NO_RIGHTS)

    def foe_write(self, name: str, password: int, data: bytes) -> None:
        """Start the update, or refuse with the FoE error code."""
        g = self.gateway
        self.foe_check_write(name, password)
        try:
            g.start_update(data)
        except ValueError as exc:
            raise FoeError(str(exc), FoeErrorCode.ILLEGAL) from None


def create_esd_gateway(clock: Clock, bus: VirtualBus | None, name: str = "CAN-EtherCAT", serial: int = 0,
                       update_duration: float = 3.0, start: bool = True) -> EsdGateway:
    """A gateway attached to ``bus`` (started unless ``start=False``): its ``slave`` goes in a segment."""
    gw = EsdGateway(clock, bus, name, serial, update_duration)
    if start:
        gw.start()
    return gw

