"""The IgH package's MCAN Port layer (manual 15.1, 15.4, 15.5.2): CAN / CAN FD over the PDO stream.

Configuration: a channel mask per direction and classic or FD channel setup (bit rates, sample
point ranges, TDC, Message RAM, 13.4), appended to the adapter's startup queue with an apply
status check per channel. Per cycle: :meth:`McanPort.cycle_begin` parses every slave's TxPDO
(6.1 receiving order, chapter 8 packets, chapter 10 TX_RESULT), the application calls
:meth:`~McanPort.receive` and :meth:`~McanPort.send_can` / :meth:`~McanPort.send_canfd` /
:meth:`~McanPort.schedule_can` / :meth:`~McanPort.schedule_canfd`, and :meth:`~McanPort.cycle_end`
writes the RxPDO (seq commit, CRC16, ALIGN4 by the active layout) and runs the exchange.
:meth:`~McanPort.exchange` is the one-call form for scripts (15.4).

The PDO writer and parser are :mod:`gatewaylab.devices.ecanlite.stream` (``encode_into``,
``commit_state``, ``decode_stream``): the device's own codec, never a second copy of the format.
A rejected TxPDO keeps its :class:`~gatewaylab.devices.ecanlite.stream.ParseDiag` (the package's
parse_diag: offset, packet end, ctrl, seq, payload_len, crc, layout_id, ch, dlc, tsf, kind).
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import LocalError
from gatewaylab.devices.ecanlite.stream import (
    TIMESTAMP_UNIT_S,
    CanPacket,
    Commit,
    HeaderFlags,
    Option,
    ParseDiag,
    StreamError,
    StreamLayout,
    Tsf,
    TxResultCode,
    TxResultPacket,
    commit_state,
    decode_stream,
    encode_into,
    packet_size,
)
from gatewaylab.hosts.ecanlite.adapter import CycleStatus, EcanAdapter, StartupSdo

__all__ = ["ChannelConfig", "McanPort", "MessageRam", "PortConfig", "RxFrame", "TxResult", "TxTicket"]

#: The MCAN channel config objects 0x8001..0x8004 (13.4).
CHANNEL_CONFIG = 0x8001
#: 0x8021..0x8024 data path control of MCAN0..3 (13.2.2).
DATA_PATH = 0x8021


def drain_all_sdos(position: int, channel: int) -> list[StartupSdo]:
    """The data path policy that hands the master every received frame (13.2.2): RX drain budget
    max 8 with policy 2 'performance', RX cache depth 32, applied with its status checked. The
    device's defaults (drain at most 2 frames per cycle into a 16-frame cache) lose frames on any
    bus carrying more than 2 frames per cycle."""
    i = DATA_PATH + channel
    u8 = StartupSdo.u8
    return [u8(position, i, 5, 8, "RX drain budget max"), u8(position, i, 6, 2, "RX budget policy: performance"),
            u8(position, i, 7, 32, "RX cache depth 32"), u8(position, i, 2, 1, "apply data path policy"),
            StartupSdo.expect(position, i, 3, b"\x00", f"CAN{channel} data path policy apply status")]


@dataclass(frozen=True, slots=True)
class MessageRam:
    """Message RAM layout of one channel (13.4 SI 61..73); data sizes are the MCAN enum (7 = 64 B)."""

    rx_fifo0_size: int = 48
    rx_fifo1_size: int = 12
    rx_fifo0_data: int = 7
    rx_fifo1_data: int = 7
    rx_buffers: int = 12
    rx_buffer_data: int = 7
    tx_queue_mode: int = 0
    tx_fifo_size: int = 32
    tx_buffers: int = 0
    tx_buffer_data: int = 7
    tx_event_fifo: int = 32

    @classmethod
    def classic(cls) -> MessageRam:
        """Classic CAN: 8-byte elements to save RAM (5.4.3 phase E note)."""
        return cls(rx_fifo0_data=0, rx_fifo1_data=0, rx_buffer_data=0, tx_buffer_data=0)


@dataclass(frozen=True, slots=True)
class ChannelConfig:
    """One MCAN channel (``igh_mcan_port_set_classic_channel`` / ``..._fd_channel``, 13.4)."""

    bitrate: int = 1_000_000
    data_bitrate: int = 0
    fd: bool = False
    nominal_sp: tuple[int, int] = (750, 875)     # 0.1 %, SI 21/22
    data_sp: tuple[int, int] = (750, 875)        # SI 23/24
    tdc: bool = True                             # SI 16 (forced on at >= 5 Mbit/s by the firmware)
    tdc_offset: int = 0                          # SI 33, 0 = automatic
    tdc_filter: int = 0                          # SI 34
    non_iso: bool = False
    node_mode: int = 0                           # SI 8: 0 normal, 2 internal loopback, ...
    ram: MessageRam = field(default_factory=MessageRam.classic)
    #: also write :func:`drain_all_sdos` (0x802x); False keeps the device's data path defaults
    drain_all: bool = False

    @classmethod
    def classic(cls, bitrate: int = 1_000_000, sample_point: tuple[int, int] = (750, 875)) -> ChannelConfig:
        """A classic CAN channel with the classic Message RAM layout."""
        return cls(bitrate, 0, False, sample_point, sample_point, False, ram=MessageRam.classic())

    @classmethod
    def canfd(cls, bitrate: int = 1_000_000, data_bitrate: int = 5_000_000,
              nominal_sp: tuple[int, int] = (750, 875), data_sp: tuple[int, int] = (750, 875),
              tdc: bool = True) -> ChannelConfig:
        """A CAN FD channel (data phase, TDC) with the CAN FD default Message RAM layout."""
        return cls(bitrate, data_bitrate, True, nominal_sp, data_sp, tdc, ram=MessageRam())

    def sdos(self, position: int, channel: int) -> list[StartupSdo]:
        """5.4.3 phase E for this channel, apply, and the apply status check."""
        i = CHANNEL_CONFIG + channel
        u8, u16, u32 = StartupSdo.u8, StartupSdo.u16, StartupSdo.u32
        r = self.ram
        q = [u8(position, i, 7, 0, "automatic bit timing"), u8(position, i, 8, self.node_mode, "node mode"),
             u8(position, i, 9, int(self.non_iso), "non-ISO"), u8(position, i, 15, int(self.fd), "FD enable"),
             u32(position, i, 19, self.bitrate, "nominal bit rate"),
             u16(position, i, 21, self.nominal_sp[0], "nominal SP min"),
             u16(position, i, 22, self.nominal_sp[1], "nominal SP max")]
        if self.fd:
            q += [u8(position, i, 16, int(self.tdc), "TDC enable"),
                  u32(position, i, 20, self.data_bitrate, "data bit rate"),
                  u16(position, i, 23, self.data_sp[0], "data SP min"),
                  u16(position, i, 24, self.data_sp[1], "data SP max"),
                  u8(position, i, 33, self.tdc_offset, "TDC offset"),
                  u8(position, i, 34, self.tdc_filter, "TDC filter")]
        for sub, value, what in ((61, 0, "RX FIFO0 mode"), (62, r.rx_fifo0_size, "RX FIFO0 size"),
                                 (63, 0, "RX FIFO1 mode"), (64, r.rx_fifo1_size, "RX FIFO1 size"),
                                 (65, r.rx_fifo0_data, "RX FIFO0 data"), (66, r.rx_fifo1_data, "RX FIFO1 data"),
                                 (67, r.rx_buffers, "RX buffers"), (68, r.rx_buffer_data, "RX buffer data"),
                                 (69, r.tx_queue_mode, "TX FIFO/queue"), (70, r.tx_fifo_size, "TX FIFO size"),
                                 (71, r.tx_buffers, "TX buffers"), (72, r.tx_buffer_data, "TX buffer data"),
                                 (73, r.tx_event_fifo, "TX event FIFO")):
            q.append(u8(position, i, sub, value, what))
        q.append(u8(position, i, 1, 1, "apply channel"))
        q.append(StartupSdo.expect(position, i, 2, b"\x00", f"CAN{channel} apply status"))
        if self.drain_all:
            q += drain_all_sdos(position, channel)
        return q


@dataclass(frozen=True, slots=True)
class PortConfig:
    """``igh_mcan_port_config_t``: masks per direction, channels, profile and options of one slave.

    ``tx_mask`` is the TxPDO / 0x8010 mask (channels the slave uploads), ``rx_mask`` the RxPDO /
    0x8011 mask (channels the master sends on); ``channels`` maps a channel to its setup, and only
    those are configured. ``tx_result`` turns on TX_RESULT (0x8010:07 bit 0), ``align4`` ALIGN4
    both ways (8.3.1).
    """

    channels: Mapping[int, ChannelConfig] = field(default_factory=lambda: {0: ChannelConfig.classic()})
    tx_mask: int = -1                # -1: the channels configured
    rx_mask: int = -1
    profile: int = 0
    budget: int = 0
    tx_result: bool = False
    align4: bool = False

    @property
    def masks(self) -> tuple[int, int]:
        """The (TxPDO, RxPDO) channel masks: the configured channels unless set explicitly."""
        configured = sum(1 << ch for ch in self.channels)
        return (configured if self.tx_mask < 0 else self.tx_mask, configured if self.rx_mask < 0 else self.rx_mask)

    @property
    def options(self) -> tuple[int, int]:
        """(0x8010:07, 0x8011:07) option flags (9.1)."""
        a4 = Option.ALIGN_4_ENABLE if self.align4 else 0
        return (int(a4 | (Option.TX_RESULT_ENABLE if self.tx_result else 0)), int(a4))


@dataclass(frozen=True, slots=True)
class RxFrame:
    """A frame the slave received on one of its channels (``igh_mcan_rx_frame_t``)."""

    slave: int
    channel: int
    frame: CanFrame
    time: float          # clock time of the cycle that brought it
    seq: int             # TxPDO sequence
    timestamp: int = 0   # delta16 ticks (profiles 1/5), else 0
    #: the device's bus receive instant on this host's clock, from a delta16/delta32 timestamp
    #: (profiles 1/5, 8.4); None without one
    received: float | None = None


@dataclass(frozen=True, slots=True)
class TxTicket:
    """Where a sent frame went: RxPDO sequence and frame index (chapter 10 RefPacketSeq/RefFrameIndex)."""

    request: int
    slave: int
    channel: int
    seq: int
    index: int


@dataclass(frozen=True, slots=True)
class TxResult:
    """A TX_RESULT matched to its request (chapter 10); ``request`` -1 when no request matches."""

    request: int
    slave: int
    channel: int
    seq: int
    index: int
    code: TxResultCode
    frame: CanFrame | None


@dataclass(slots=True)
class _Pending:
    request: int
    packet: CanPacket


@dataclass(slots=True)
class _SlavePort:
    """The per-slave state of the writer and the parser."""

    k: int
    position: int
    tx_layout: StreamLayout
    rx_layout: StreamLayout
    queue: deque[_Pending] = field(default_factory=deque)
    seq: int = 0
    last_in: bytes | None = None
    in_seq: int | None = None
    status_words: tuple[int, int, int, int] = (0, 0, 0, 0)
    header_flags: HeaderFlags = field(default_factory=lambda: HeaderFlags(0))
    published: dict[int, list[_Pending]] = field(default_factory=dict)
    accepted: set[int] = field(default_factory=set)


class McanPort:
    """CAN / CAN FD through the ECAN-Lite slaves of one :class:`EcanAdapter` (15.1 MCAN Port).

    Build it before ``adapter.start()``: it sets every slave's masks and options and appends the
    channel setup to the startup queue (``igh_mcan_port_apply_config``).
    """

    #: How many published RxPDO images are remembered to match late TX_RESULTs.
    TICKET_HISTORY = 64
    #: Cycles an RxPDO image carrying frames is sent again while the working counter stays wrong
    #: (the device takes a repeated image as a no-op, 13.8); after that its frames count as
    #: ``unconfirmed_frames`` and new images go out (a line that keeps failing must not stop sending).
    RESEND_LIMIT = 100

    def __init__(self, adapter: EcanAdapter, config: PortConfig | Mapping[int, PortConfig] | None = None) -> None:
        self.adapter = adapter
        self.clock = adapter.clock
        configs = config if isinstance(config, Mapping) else dict.fromkeys(range(adapter.slave_count),
                                                                           config or PortConfig())
        self.configs: dict[int, PortConfig] = {}
        self._slaves: list[_SlavePort] = []
        for k in range(adapter.slave_count):
            cfg = configs.get(k, PortConfig())
            self.configs[k] = cfg
            s = adapter.slave(k)
            tx_mask, rx_mask = cfg.masks
            tx_opt, rx_opt = cfg.options
            s = replace(s, tx_mask=tx_mask, rx_mask=rx_mask, profile=cfg.profile, budget=cfg.budget,
                        tx_options=tx_opt, rx_options=rx_opt)
            adapter.set_slave(k, s)
            for ch, chcfg in sorted(cfg.channels.items()):
                if not 0 <= ch <= 3:
                    raise LocalError(f"MCAN channel {ch} is not 0..3")
                for sdo in chcfg.sdos(s.position, ch):
                    adapter.add_startup_sdo(sdo)
            self._slaves.append(_SlavePort(k, s.position, s.tx_layout, s.rx_layout))
        self._requests = itertools.count(1)
        self._rx: deque[RxFrame] = deque()
        self._results: deque[TxResult] = deque()
        self._resends = 0
        # clock times of the last three exchanges: the TxPDO read at the last one was built by the
        # device at the one before, its delta timestamps count from the build before that (8.4)
        self._exchanges: deque[float] = deque(maxlen=3)
        self.parse_errors = 0
        self.last_parse_error: StreamError | None = None
        self.torn_images = 0
        self.lost_images = 0
        self.incomplete_images = 0      # overflow_sat != 0 or STREAM_TRUNCATED (6.1 step 8)
        self.device_overflow = 0        # sum of overflow_sat
        self.held_frames = 0            # frames that waited a cycle: the RxPDO frame area was full
        self.frames_sent = 0
        #: frames of images given up after RESEND_LIMIT wrong working counters (maybe never sent)
        self.unconfirmed_frames = 0
        self.frames_received = 0
        self._unparsed = False

    # ------------------------------------------------------------------ sending
    def _slave(self, k: int) -> _SlavePort:
        try:
            return self._slaves[k]
        except IndexError:
            raise LocalError(f"no adapter slave {k}") from None

    def send_packet(self, slave: int, packet: CanPacket) -> int:
        """Queue a packet for the next RxPDO; returns its request number (TX_RESULT matching).

        The layout's rules are checked now (:class:`StreamEncodeError` with the LastPDOError the
        device would report, e.g. a channel outside the RxPDO mask)."""
        sp = self._slave(slave)
        if packet.scheduled and not self.adapter.config.dc_sync0:
            raise LocalError("scheduled transmit needs DC SYNC0 (8.4, 13.8: LastPDOError 16 otherwise)")
        if packet.ctrl not in sp.accepted or packet.tsf:   # a control word is judged once (as the codec)
            packet_size(packet, sp.rx_layout)
            sp.accepted.add(packet.ctrl)
        request = next(self._requests)
        sp.queue.append(_Pending(request, packet))
        return request

    def send_can(self, slave: int, channel: int, can_id: int, data: bytes = b"", *, extended: bool = False,
                 rtr: bool = False, dlc: int = -1) -> int:
        """``igh_mcan_port_send_can``: one classic frame in the next cycle."""
        if extended or rtr or dlc != -1:
            return self.send_packet(slave, CanPacket.of(channel, can_id, extended, rtr=rtr, data=bytes(data), dlc=dlc))
        return self.send_packet(slave, CanPacket.classic(channel, can_id, bytes(data)))

    def send_canfd(self, slave: int, channel: int, can_id: int, data: bytes = b"", *, extended: bool = False,
                   brs: bool = True) -> int:
        """``igh_mcan_port_send_canfd``: one CAN FD frame (BRS by default) in the next cycle."""
        return self.send_packet(slave, CanPacket.of(channel, can_id, extended, fd=True, brs=brs, data=bytes(data)))

    def schedule_can(self, slave: int, channel: int, can_id: int, data: bytes = b"", *, offset_ns: int,
                     tag: int = 0, extended: bool = False) -> int:
        """``igh_mcan_port_schedule_can``: sent ``offset_ns`` after the next SYNC0 (8.4 TSF_FULL64 format 1)."""
        return self.send_packet(slave, CanPacket.of(channel, can_id, extended, data=bytes(data), tsf=Tsf.FULL64,
                                                 scheduled=True, offset_ns=offset_ns, tag=tag & 0xFFFF))

    def schedule_canfd(self, slave: int, channel: int, can_id: int, data: bytes = b"", *, offset_ns: int,
                       tag: int = 0, extended: bool = False, brs: bool = True) -> int:
        """``igh_mcan_port_schedule_canfd``: a CAN FD frame at SYNC0 + ``offset_ns`` (8.4)."""
        return self.send_packet(slave, CanPacket.of(channel, can_id, extended, fd=True, brs=brs, data=bytes(data),
                                                 tsf=Tsf.FULL64, scheduled=True, offset_ns=offset_ns,
                                                 tag=tag & 0xFFFF))

    def send_frame(self, slave: int, channel: int, frame: CanFrame) -> int:
        """A bus :class:`CanFrame` as it is (classic, remote or FD)."""
        return self.send_packet(slave, self.frame_packet(channel, frame))

    @staticmethod
    def frame_packet(channel: int, frame: CanFrame) -> CanPacket:
        """The RxPDO packet that carries ``frame`` on ``channel`` (send now, 8.1)."""
        return CanPacket(channel, frame)

    def fits_next_image(self, slave: int, packet: CanPacket) -> bool:
        """Whether ``packet`` still goes out with the next RxPDO: the frames queued for ``slave`` and
        it fit into one frame area (chapter 12; at most 255 packets, 6). A sender that waits for
        this never queues more than one image ahead (python-can's send timeout)."""
        sp = self._slave(slave)
        layout = sp.rx_layout
        align4 = layout.align4
        used = 0
        for pend in sp.queue:
            raw = pend.packet.raw_size
            used += (raw + 3) & ~3 if align4 else raw
        return len(sp.queue) < 255 and used + packet_size(packet, layout) <= layout.frame_area_bytes

    def pending(self, slave: int | None = None) -> int:
        """Frames queued and not yet in a published RxPDO."""
        return sum(len(s.queue) for s in self._slaves if slave is None or s.k == slave)

    # ------------------------------------------------------------------ receiving
    def receive(self, max_frames: int | None = None) -> list[RxFrame]:
        """``igh_mcan_port_receive``: frames parsed by :meth:`cycle_begin`, oldest first."""
        out: list[RxFrame] = []
        rx = self._rx
        while rx and (max_frames is None or len(out) < max_frames):
            out.append(rx.popleft())
        return out

    def take_tx_results(self) -> list[TxResult]:
        """TX_RESULT packets matched to their requests (chapter 10), oldest first."""
        out = list(self._results)
        self._results.clear()
        return out

    def status_words(self, slave: int) -> tuple[int, int, int, int]:
        """The chapter-7 channel status words of the last TxPDO."""
        return self._slave(slave).status_words

    def header_flags(self, slave: int) -> HeaderFlags:
        """header_flags of the last TxPDO (chapter 6)."""
        return self._slave(slave).header_flags

    @property
    def last_parse_diag(self) -> ParseDiag | None:
        """parse_diag of the last rejected TxPDO (16.2)."""
        return self.last_parse_error.diag if self.last_parse_error is not None else None

    # ------------------------------------------------------------------ the cycle
    def cycle_begin(self) -> None:
        """Parse every slave's TxPDO from the last exchange (6.1 receiving order)."""
        self._unparsed = False
        now = self.clock.now()
        for sp in self._slaves:
            self._parse(sp, self.adapter.txpdo(sp.k), now)

    def parse(self, slave: int, image: bytes) -> None:
        """Parse one TxPDO image of ``slave`` (:meth:`cycle_begin` does it for the exchanged ones)."""
        self._parse(self._slave(slave), image, self.clock.now())

    def _parse(self, sp: _SlavePort, image: bytes, now: float) -> None:
        if not any(image[:16]):
            return                     # nothing published yet (SAFEOP start)
        try:
            commit = commit_state(image, sp.last_in)
        except StreamError as exc:
            self._parse_error(exc)
            return
        if commit is Commit.SAME:
            return
        if commit is Commit.TORN:
            self.torn_images += 1
            return
        sp.last_in = image
        try:
            decoded = decode_stream(image, sp.tx_layout)
        except StreamError as exc:
            self._parse_error(exc)
            return
        h = decoded.header
        seq = h.seq_begin
        if sp.in_seq is not None:
            gap = (seq - sp.in_seq - 1) & 0xFFFF
            if gap and gap < 0x8000:
                self.lost_images += gap
        sp.in_seq = seq
        sp.status_words = h.channel_status
        sp.header_flags = h.header_flags
        if h.incomplete:
            self.incomplete_images += 1
            self.device_overflow += h.overflow_sat
        base = self._exchanges[0] if len(self._exchanges) == 3 else None
        for p in decoded.packets:
            if type(p) is CanPacket:
                received = None
                if p.tsf and base is not None and not p.scheduled and p.tsf is not Tsf.FULL64:
                    received = base + _signed_ticks(p.timestamp, p.tsf) * TIMESTAMP_UNIT_S
                self._rx.append(RxFrame(sp.k, p.channel, p.frame, now, seq, p.timestamp, received))
                self.frames_received += 1
            elif type(p) is TxResultPacket:
                pend = sp.published.get(p.ref_packet_seq)
                match = pend[p.ref_frame_index] if pend is not None and p.ref_frame_index < len(pend) else None
                self._results.append(TxResult(match.request if match else -1, sp.k, p.channel, p.ref_packet_seq,
                                              p.ref_frame_index, p.result, match.packet.frame if match else None))

    def _parse_error(self, exc: StreamError) -> None:
        self.parse_errors += 1
        self.last_parse_error = exc

    def cycle_end(self) -> CycleStatus:
        """Publish every slave's RxPDO (a new sequence each cycle) and run the exchange.

        After a cycle whose working counter was wrong, an image that carried frames is sent again,
        unchanged, until a cycle is complete (at most RESEND_LIMIT times): the device takes an
        identical image as an idempotent no-op (13.8) and a lost one as new, so no frame is lost
        or sent twice. An image without frames is simply followed by the next one."""
        last = self.adapter.last
        carrying = [len(sp.published.get(sp.seq, ())) for sp in self._slaves]
        resend = last is not None and not last.complete and any(carrying)
        if resend and self._resends >= self.RESEND_LIMIT:
            self.unconfirmed_frames += sum(carrying)
            resend = False
        self._resends = self._resends + 1 if resend else 0
        if not resend:
            for sp in self._slaves:
                self._publish(sp)
        if self._unparsed:          # the last exchange's TxPDO was not read: parse it now, lose nothing
            self.cycle_begin()
        status = self.adapter.exchange()
        self._exchanges.append(status.time)
        self._unparsed = True
        return status

    def _publish(self, sp: _SlavePort) -> None:
        layout = sp.rx_layout
        room = layout.frame_area_bytes
        align4 = layout.align4
        take: list[_Pending] = []
        while sp.queue and len(take) < 255:
            raw = sp.queue[0].packet.raw_size
            size = (raw + 3) & ~3 if align4 else raw
            if size > room:
                break
            room -= size
            take.append(sp.queue.popleft())
        self.held_frames += len(sp.queue)
        sp.seq = (sp.seq + 1) & 0xFFFF or 1
        buf = self.adapter.rxpdo(sp.k)
        encode_into(buf, layout, sp.seq, [p.packet for p in take])
        if take:
            sp.published[sp.seq] = take
            self.frames_sent += len(take)
            if len(sp.published) > self.TICKET_HISTORY:
                del sp.published[next(iter(sp.published))]

    def tickets(self, slave: int) -> list[TxTicket]:
        """Where the frames of the remembered RxPDO images went (sequence, index)."""
        sp = self._slave(slave)
        return [TxTicket(p.request, slave, p.packet.channel, seq, i)
                for seq, pend in sp.published.items() for i, p in enumerate(pend)]

    def exchange(self, frames: Iterable[tuple[int, int, CanFrame]] = ()) -> list[RxFrame]:
        """``igh_mcan_port_exchange`` for scripts: queue (slave, channel, frame), one full cycle, what came in."""
        for slave, channel, frame in frames:
            self.send_frame(slave, channel, frame)
        self.cycle_end()
        self.adapter.wait_period()
        self.cycle_begin()
        return self.receive()

    def run_cycles(self, n: int) -> list[RxFrame]:
        """``n`` cycles of :meth:`exchange` with nothing new to send; everything received."""
        out: list[RxFrame] = []
        for _ in range(n):
            out += self.exchange()
        return out


def frames_of(rx: Sequence[RxFrame], slave: int | None = None, channel: int | None = None) -> list[CanFrame]:
    """The bus frames of ``rx``, optionally of one slave / channel."""
    return [r.frame for r in rx if (slave is None or r.slave == slave) and (channel is None or r.channel == channel)]


def _signed_ticks(ticks: int, tsf: Tsf) -> int:
    """A delta16/delta32 timestamp as a signed difference: a frame the device received before the
    cycle's time base (left over from an earlier image) counts back, not 65 ms forward (8.4 'handle
    wrap as an unsigned difference')."""
    bits = 16 if tsf is Tsf.DELTA16 else 32
    return ticks - (1 << bits) if ticks >> (bits - 1) else ticks
