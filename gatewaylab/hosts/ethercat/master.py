"""In-process EtherCAT master: real frames through the same ESC code as the wire, no network needed.

It does what a small master library does (the QEC master manual's API is the model: slave info,
state changes, ``sdo_upload8/16/32``, FoE, ``pdo_read/pdo_write``, a cyclic callback): scan with
BRD/APWR, read the SII through the EEPROM interface, configure mailbox SMs, talk CoE/FoE through
the mailbox SMs, map process data with SMs + FMMUs and exchange it with one LRW per cycle.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass

from gatewaylab.common.clock import Clock, PeriodicTimer
from gatewaylab.common.errors import TimeoutError_
from gatewaylab.ethercat.coe import SDO, CoeService, InfoOpcode, coe_header
from gatewaylab.ethercat.datagram import MAX_DATAGRAM_DATA, Command, Datagram, Frame, decode_frame, encode_frame
from gatewaylab.ethercat.errors import (
    AlStatusError,
    FoeError,
    FrameFormatError,
    MasterError,
    SdoAbort,
    WorkingCounterError,
)
from gatewaylab.ethercat.esc import (
    REG_AL_CONTROL,
    REG_AL_STATUS,
    REG_DC_ACTIVATION,
    REG_DC_START_TIME,
    REG_DC_SYNC0_CYCLE,
    REG_DC_SYSTEM_TIME,
    REG_FMMU,
    REG_SII_CONTROL,
    REG_SII_DATA,
    REG_SM,
    REG_STATION_ADDRESS,
    AlState,
)
from gatewaylab.ethercat.foe import FOE_HEADER, FoeOpcode, foe_packet
from gatewaylab.ethercat.mailbox import MailboxMessage, MailboxType, decode_mailbox, encode_mailbox
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.sii import SiiInfo, parse_sii
from gatewaylab.od import sdo as sdo_codec

U16 = struct.Struct("<H")
U32 = struct.Struct("<I")
U64 = struct.Struct("<Q")
FMMU_REG = struct.Struct("<IHBBHBBB3x")
SM_REG = struct.Struct("<HHBBBB")
FIRST_STATION = 0x1001
#: Seconds between two polls of a mailbox that is not ready yet (SM1 empty, SM0 still full).
MAILBOX_POLL = 0.0005
#: Seconds before an FoE data packet that the slave answered with BUSY is sent again.
FOE_BUSY_RETRY = 0.01


@dataclass(slots=True)
class SlaveInfo:
    """What the master learnt about one slave, so every later call addresses it by position (QEC: getVendorID ...)."""

    position: int
    station: int
    sii: SiiInfo
    output_offset: int = 0
    output_bytes: int = 0
    input_offset: int = 0
    input_bytes: int = 0
    mbx_counter: int = 0
    boot: bool = False

    @property
    def mailbox_out(self) -> tuple[int, int]:
        """(start, size) of the SM0 mailbox to write requests to: the bootstrap one in BOOT, else the standard one."""
        b = self.sii.bootstrap_mailbox
        return (b[0], b[1]) if self.boot and b[1] else self.sii.mailbox_out

    @property
    def mailbox_in(self) -> tuple[int, int]:
        """(start, size) of the SM1 mailbox to read replies from: the bootstrap one in BOOT, else the standard one."""
        b = self.sii.bootstrap_mailbox
        return (b[2], b[3]) if self.boot and b[3] else self.sii.mailbox_in

    @property
    def name(self) -> str:
        """The SII device name, to tell slaves apart in messages and ready info."""
        return self.sii.name

    @property
    def vendor_id(self) -> int:
        """The SII vendor id, to check the slave is the expected device."""
        return self.sii.vendor_id

    @property
    def product_code(self) -> int:
        """The SII product code, to check the slave is the expected device."""
        return self.sii.product_code

    @property
    def revision(self) -> int:
        """The SII revision number, to check the slave is the expected device version."""
        return self.sii.revision

    @property
    def serial(self) -> int:
        """The SII serial number, to tell identical devices apart."""
        return self.sii.serial


@dataclass(frozen=True, slots=True)
class ObjectDescription:
    """One SDO information OD description: lets a master browse a dictionary it has no ESI for."""
    index: int
    data_type: int
    max_subindex: int
    object_code: int
    name: str


@dataclass(frozen=True, slots=True)
class EntryDescription:
    """One SDO information entry description: type, bit length and access of a subindex."""
    index: int
    subindex: int
    data_type: int
    bit_length: int
    access: int
    name: str


class Master:
    """A small EtherCAT master with real frames, so tests and teaching scripts drive slaves without a network."""

    def __init__(self, clock: Clock, segment: Segment | None = None,
                 link: Callable[[bytes], bytes | None] | None = None, *, timeout: float = 0.1,
                 capture: Callable[[float, bytes], None] | None = None) -> None:
        if segment is None and link is None:
            raise MasterError("a master needs a segment or a link")
        self.clock = clock
        self.segment = segment
        self.link = link
        self.timeout = timeout
        #: Called with (clock time, frame) for every frame out and back, e.g. ``PcapWriter.write``.
        self.capture = capture
        self.foe_busy_timeout = 10.0
        self.slaves: list[SlaveInfo] = []
        self.frames = 0
        self.lost_frames = 0
        self._index = 0
        self.image = bytearray()
        self.chunks: list[tuple[int, int]] = []
        self.outputs_size = 0
        self.expected_wkc = 0
        self.last_wkc = 0
        self._cyclic: PeriodicTimer | None = None

    # ------------------------------------------------------------------ frames
    def exchange(self, datagrams: list[Datagram]) -> tuple[Datagram, ...]:
        """Send one frame and return its datagrams as they came back: the one path every command takes."""
        raw = encode_frame(Frame(tuple(datagrams)))
        self.frames += 1
        if self.capture is not None:
            self.capture(self.clock.now(), raw)
        if self.segment is not None:
            buf = bytearray(raw)
            back: bytes | None = bytes(buf) if self.segment.process(buf) else None
        else:
            assert self.link is not None
            back = self.link(raw)
        if back is None:
            self.lost_frames += 1
            raise TimeoutError_("frame lost")
        if self.capture is not None:
            self.capture(self.clock.now(), back)
        return decode_frame(back).datagrams

    def _one(self, command: Command, address: int, data: bytes) -> Datagram:
        self._index = (self._index + 1) & 0xFF
        return self.exchange([Datagram(command, self._index, address, data)])[0]

    def _phys(self, command: Command, adp: int, ado: int, data: bytes) -> Datagram:
        return self._one(command, (adp & 0xFFFF) | (ado << 16), data)

    def fprd(self, station: int, ado: int, length: int) -> bytes:
        """Read a register of one configured slave (FPRD), raising unless exactly that slave answered."""
        d = self._phys(Command.FPRD, station, ado, bytes(length))
        if d.wkc != 1:
            raise WorkingCounterError(f"FPRD 0x{station:04X}:0x{ado:04X} wkc {d.wkc}", d.wkc)
        return d.data

    def fpwr(self, station: int, ado: int, data: bytes) -> None:
        """Write a register of one configured slave (FPWR), raising unless exactly that slave answered."""
        d = self._phys(Command.FPWR, station, ado, data)
        if d.wkc != 1:
            raise WorkingCounterError(f"FPWR 0x{station:04X}:0x{ado:04X} wkc {d.wkc}", d.wkc)

    # ------------------------------------------------------------------ scan
    def scan(self) -> list[SlaveInfo]:
        """Find the slaves (BRD), give them station addresses (APWR) and read their SII: the start of every session."""
        count = self._phys(Command.BRD, 0, 0x0000, b"\0\0").wkc
        self._phys(Command.BWR, 0, REG_AL_CONTROL, U16.pack(AlState.INIT | 0x10))
        self._phys(Command.BWR, 0, REG_FMMU, bytes(16 * 16))
        self._phys(Command.BWR, 0, REG_SM, bytes(8 * 16))
        self.slaves = []
        for pos in range(count):
            station = FIRST_STATION + pos
            d = self._phys(Command.APWR, -pos, REG_STATION_ADDRESS, U16.pack(station))
            if d.wkc != 1:
                raise WorkingCounterError(f"no slave at position {pos}", d.wkc)
            self.slaves.append(SlaveInfo(pos, station, parse_sii(self.read_sii(station))))
        return self.slaves

    def read_sii(self, station: int, max_bytes: int = 65536) -> bytes:
        """The SII image up to its END category, which tells the master the slave's mailboxes and SyncManagers."""
        out = bytearray()
        while len(out) < max_bytes:
            out += self.sii_read8(station, len(out) // 2)
            if len(out) >= 0x84 and self._sii_complete(out):
                break
        return bytes(out)

    @staticmethod
    def _sii_complete(img: bytearray) -> bool:
        pos = 0x80
        while pos + 4 <= len(img):
            kind, words = struct.unpack_from("<HH", img, pos)
            if kind == 0xFFFF:
                return True
            pos += 4 + 2 * words
        return False

    def sii_read8(self, station: int, word: int) -> bytes:
        """Read 8 bytes of the SII through the EEPROM interface, the unit of every SII read."""
        self.fpwr(station, REG_SII_CONTROL, U16.pack(0x0100) + U32.pack(word))
        status = U16.unpack(self.fprd(station, REG_SII_CONTROL, 2))[0]
        if status & 0x7800:
            raise WorkingCounterError(f"SII read error status 0x{status:04X}", status)
        return self.fprd(station, REG_SII_DATA, 8)

    def sii_write(self, station: int, word: int, value: int) -> int:
        """Write one SII word through the EEPROM interface (to test write protection and errors); returns its status."""
        self.fpwr(station, REG_SII_DATA, U16.pack(value))
        self.fpwr(station, REG_SII_CONTROL, U16.pack(0x0201) + U32.pack(word))
        return int(U16.unpack(self.fprd(station, REG_SII_CONTROL, 2))[0])

    def slave(self, position: int) -> SlaveInfo:
        """The scanned slave at a position, or a MasterError that says to scan first."""
        if not 0 <= position < len(self.slaves):
            raise MasterError(f"no slave at position {position} (scan first)")
        return self.slaves[position]

    # ------------------------------------------------------------------ states
    def al_status(self, position: int) -> tuple[int, int]:
        """(AL status, AL status code) of one slave: how a master learns a state change failed and why."""
        raw = self.fprd(self.slave(position).station, REG_AL_STATUS, 6)
        return U16.unpack_from(raw, 0)[0], U16.unpack_from(raw, 4)[0]

    def request_state(self, position: int, state: AlState, ack: bool = False) -> AlState:
        """Move one slave to an AL state (configuring its mailbox first), raising AlStatusError with its code."""
        s = self.slave(position)
        if state in (AlState.PREOP, AlState.BOOT):
            self._configure_mailbox(s, boot=state == AlState.BOOT)
        self.fpwr(s.station, REG_AL_CONTROL, U16.pack(int(state) | (0x10 if ack else 0)))
        status, code = self.al_status(position)
        s.boot = (status & 0x0F) == AlState.BOOT
        if status & 0x10 or (status & 0x0F) != state:
            raise AlStatusError(f"slave {position} refused {state.name}: AL status 0x{status:02X}", code)
        return AlState(status & 0x0F)

    def set_state(self, state: AlState) -> None:
        """Move every slave to an AL state, as masters do for the whole segment."""
        for s in self.slaves:
            self.request_state(s.position, state)

    def _configure_mailbox(self, s: SlaveInfo, boot: bool = False) -> None:
        if s.sii.mailbox_protocols == 0:
            return
        b = s.sii.bootstrap_mailbox
        (mo, mos), (mi, mis) = ((b[0], b[1]), (b[2], b[3])) if boot and b[1] else (s.sii.mailbox_out,
                                                                                    s.sii.mailbox_in)
        sms = SM_REG.pack(mo, mos, 0x26, 0, 1, 0) + SM_REG.pack(mi, mis, 0x22, 0, 1, 0)
        self.fpwr(s.station, REG_SM, sms)

    # ------------------------------------------------------------------ mailbox
    def _wait(self, check: Callable[[], bool]) -> None:
        """Poll ``check`` (it sends a frame) until it holds, waiting on the clock between polls."""
        deadline = self.clock.now() + self.timeout
        while not check():
            if self.clock.now() >= deadline:
                raise TimeoutError_("mailbox timeout")
            self.clock.wait(MAILBOX_POLL)

    def mailbox_exchange(self, position: int, mtype: int, data: bytes,
                         accept: Callable[[MailboxMessage], bool] | None = None) -> MailboxMessage:
        """Write a request into SM0 and return the first reply of the same type from SM1: the carrier of CoE and FoE."""
        s = self.slave(position)
        mo, mos = s.mailbox_out
        s.mbx_counter = s.mbx_counter % 7 + 1
        raw = encode_mailbox(MailboxMessage(mtype, data, s.mbx_counter))
        if len(raw) > mos:
            raise MasterError(f"mailbox message of {len(raw)} bytes exceeds {mos}")
        self._wait(lambda: self._phys(Command.FPWR, s.station, mo, raw.ljust(mos, b"\0")).wkc == 1)

        def wanted(m: MailboxMessage) -> bool:
            return m.type == MailboxType.ERROR or (m.type == mtype and (accept is None or accept(m)))

        msg = self._next_mailbox(position, wanted)
        if msg.type == MailboxType.ERROR:
            raise FrameFormatError(f"mailbox error reply {msg.data.hex()}")
        return msg

    # ------------------------------------------------------------------ CoE SDO
    def _sdo(self, position: int, req: bytes) -> bytes:
        def is_sdo(m: MailboxMessage) -> bool:
            return len(m.data) >= 2 and (m.data[1] >> 4) in (CoeService.SDO_REQUEST, CoeService.SDO_RESPONSE)

        msg = self.mailbox_exchange(position, MailboxType.COE, coe_header(CoeService.SDO_REQUEST) + req, is_sdo)
        body = msg.data[2:]
        if len(body) < SDO.size:
            raise FrameFormatError("SDO response too short")
        cmd, index, sub, word = SDO.unpack_from(body, 0)
        if cmd == 0x80:
            raise SdoAbort(word, f"SDO 0x{index:04X}:{sub} aborted")
        return body

    def sdo_upload(self, position: int, index: int, subindex: int = 0, complete: bool = False) -> bytes:
        """Read an object by CoE SDO (expedited, normal or segmented, as the slave answers)."""
        ca = 0x10 if complete else 0
        body = self._sdo(position, SDO.pack(sdo_codec.CS_UPLOAD_REQUEST | ca, index, subindex, 0))
        cmd, _i, _s, word = SDO.unpack_from(body, 0)
        if cmd & 0x02:                                  # expedited: the data is in the initiate
            return body[4:4 + (sdo_codec.expedited_size(cmd) or 4)]
        up = sdo_codec.ClientSegmentedUpload(word, bytearray(body[8:8 + word]))
        while not up.done:
            up.response(self._sdo(position, up.request()))
        return up.data[:word]

    def sdo_download(self, position: int, index: int, subindex: int, data: bytes,
                     complete: bool = False) -> None:
        """Write an object by CoE SDO: expedited up to 4 bytes, else normal, segmented when it does not fit."""
        ca = 0x10 if complete else 0
        if len(data) <= 4:
            request = sdo_codec.expedited_download_request(index, subindex, data)
            self._sdo(position, bytes((request[0] | ca,)) + request[1:])
            return
        s = self.slave(position)
        max_first = s.mailbox_out[1] - 16
        first = data[:max_first]
        self._sdo(position, SDO.pack(0x21 | ca, index, subindex, len(data)) + first)
        down = sdo_codec.ClientSegmentedDownload(data[len(first):], s.mailbox_out[1] - 9)
        while not down.done:
            down.response(self._sdo(position, down.next_segment()))

    def _typed_up(self, position: int, index: int, sub: int, fmt: str) -> int:
        raw = self.sdo_upload(position, index, sub)
        st = struct.Struct(fmt)
        if len(raw) != st.size:
            raise FrameFormatError(f"0x{index:04X}:{sub} has {len(raw)} bytes, not {st.size}")
        return int(st.unpack(raw)[0])

    def sdo_upload8(self, position: int, index: int, sub: int = 0) -> int:
        """Read an 8-bit object as an int (QEC sdo_upload8), checking its size."""
        return self._typed_up(position, index, sub, "<B")

    def sdo_upload16(self, position: int, index: int, sub: int = 0) -> int:
        """Read a 16-bit object as an int (QEC sdo_upload16), checking its size."""
        return self._typed_up(position, index, sub, "<H")

    def sdo_upload32(self, position: int, index: int, sub: int = 0) -> int:
        """Read a 32-bit object as an int (QEC sdo_upload32), checking its size."""
        return self._typed_up(position, index, sub, "<I")

    def sdo_upload64(self, position: int, index: int, sub: int = 0) -> int:
        """Read a 64-bit object as an int, checking its size."""
        return self._typed_up(position, index, sub, "<Q")

    def sdo_upload_str(self, position: int, index: int, sub: int = 0) -> str:
        """Read a VISIBLE_STRING object (names, versions) as text."""
        return self.sdo_upload(position, index, sub).decode("latin-1")

    def sdo_download8(self, position: int, index: int, sub: int, value: int) -> None:
        """Write an 8-bit object from an int (QEC sdo_download8)."""
        self.sdo_download(position, index, sub, struct.pack("<B", value))

    def sdo_download16(self, position: int, index: int, sub: int, value: int) -> None:
        """Write a 16-bit object from an int (QEC sdo_download16)."""
        self.sdo_download(position, index, sub, struct.pack("<H", value))

    def sdo_download32(self, position: int, index: int, sub: int, value: int) -> None:
        """Write a 32-bit object from an int (QEC sdo_download32)."""
        self.sdo_download(position, index, sub, struct.pack("<I", value))

    def sdo_download64(self, position: int, index: int, sub: int, value: int) -> None:
        """Write a 64-bit object from an int."""
        self.sdo_download(position, index, sub, struct.pack("<Q", value))

    # ------------------------------------------------------------------ SDO information
    def _info(self, position: int, opcode: int, data: bytes) -> list[bytes]:
        def is_info(m: MailboxMessage) -> bool:
            return len(m.data) >= 6 and (m.data[1] >> 4) == CoeService.SDO_INFO

        frags: list[bytes] = []
        msg = self.mailbox_exchange(position, MailboxType.COE,
                                    coe_header(CoeService.SDO_INFO) + bytes([opcode, 0, 0, 0]) + data, is_info)
        while True:
            op, frags_left = msg.data[2] & 0x7F, U16.unpack_from(msg.data, 4)[0]
            if op == InfoOpcode.ERROR:
                raise SdoAbort(U32.unpack_from(msg.data, 6)[0], "SDO information error")
            frags.append(msg.data[6:])
            if not frags_left:
                return frags
            msg = self._next_mailbox(position, is_info)

    def _next_mailbox(self, position: int, accept: Callable[[MailboxMessage], bool]) -> MailboxMessage:
        s = self.slave(position)
        mi, mis = s.mailbox_in
        out: list[MailboxMessage] = []

        def poll() -> bool:
            if not self.fprd(s.station, REG_SM + 8 + 5, 1)[0] & 0x08:
                return False
            d = self._phys(Command.FPRD, s.station, mi, bytes(mis))
            if d.wkc != 1:
                return False
            m = decode_mailbox(d.data)
            if accept(m):
                out.append(m)
                return True
            return False

        self._wait(poll)
        return out[0]

    def receive_emergency(self, position: int) -> tuple[int, int, bytes]:
        """The next CoE emergency (ETG.1000.6) the slave sent: (error code, error register, 5 data
        bytes); other mailbox messages read meanwhile are dropped. TimeoutError_ without one."""

        def is_emergency(m: MailboxMessage) -> bool:
            return m.type == MailboxType.COE and len(m.data) >= 10 and m.data[1] >> 4 == CoeService.EMERGENCY

        data = self._next_mailbox(position, is_emergency).data
        code, register = struct.unpack_from("<HB", data, 2)
        return code, register, bytes(data[5:10])

    def od_list(self, position: int, list_type: int = 1) -> list[int]:
        """The indexes of a slave's dictionary by SDO information (list type 1: all), to browse it without an ESI."""
        data = b"".join(self._info(position, InfoOpcode.OD_LIST_REQ, U16.pack(list_type)))
        return [U16.unpack_from(data, i)[0] for i in range(2, len(data) - 1, 2)]

    def object_description(self, position: int, index: int) -> ObjectDescription:
        """Name, type and size of one object by SDO information, to browse a dictionary without an ESI."""
        data = self._info(position, InfoOpcode.OD_REQ, U16.pack(index))[0]
        idx, dtype, max_sub, code = struct.unpack_from("<HHBB", data, 0)
        return ObjectDescription(idx, dtype, max_sub, code, data[6:].decode("latin-1"))

    def entry_description(self, position: int, index: int, subindex: int) -> EntryDescription:
        """Type, bit length, access and name of one subindex by SDO information."""
        data = self._info(position, InfoOpcode.ED_REQ, struct.pack("<HBB", index, subindex, 0))[0]
        idx, sub, _vi, dtype, bits, access = struct.unpack_from("<HBBHHH", data, 0)
        return EntryDescription(idx, sub, dtype, bits, access, data[10:].decode("latin-1"))

    # ------------------------------------------------------------------ FoE
    def _foe(self, position: int, packet: bytes) -> tuple[int, int, bytes]:
        msg = self.mailbox_exchange(position, MailboxType.FOE, packet)
        opcode, _r, word = FOE_HEADER.unpack_from(msg.data, 0)
        rest = msg.data[FOE_HEADER.size:]
        if opcode == FoeOpcode.ERR:
            raise FoeError(rest.decode("latin-1", "replace"), word)
        return opcode, word, rest

    def foe_write(self, position: int, name: str, data: bytes, password: int = 0) -> None:
        """Send a file by FoE (firmware updates), repeating a packet while the slave answers BUSY."""
        s = self.slave(position)
        max_data = s.mailbox_out[1] - 12
        opcode, word, _ = self._foe(position, foe_packet(FoeOpcode.WRQ, password, name.encode("latin-1")))
        if opcode != FoeOpcode.ACK or word != 0:
            raise FoeError("write request not acknowledged", 0x8000)
        packet = 0
        pos = 0
        while True:
            chunk = data[pos:pos + max_data]
            pos += len(chunk)
            packet += 1
            opcode, word, _ = self._foe(position, foe_packet(FoeOpcode.DATA, packet, chunk))
            deadline = self.clock.now() + self.foe_busy_timeout
            while opcode == FoeOpcode.BUSY:  # the slave needs time: repeat the packet later
                if self.clock.now() >= deadline:
                    raise TimeoutError_("FoE slave stayed busy")
                self.clock.wait(FOE_BUSY_RETRY)
                opcode, word, _ = self._foe(position, foe_packet(FoeOpcode.DATA, packet, chunk))
            if opcode != FoeOpcode.ACK or word != packet:
                raise FoeError(f"data packet {packet} not acknowledged", 0x8005)
            if len(chunk) < max_data:
                return

    def foe_read(self, position: int, name: str, password: int = 0) -> bytes:
        """Read a file by FoE (logs, configuration), acknowledging every data packet."""
        s = self.slave(position)
        max_data = s.mailbox_in[1] - 12
        out = bytearray()
        opcode, word, rest = self._foe(position, foe_packet(FoeOpcode.RRQ, password, name.encode("latin-1")))
        while True:
            if opcode != FoeOpcode.DATA:
                raise FoeError(f"unexpected FoE opcode {opcode}", 0x8004)
            out += rest
            if len(rest) < max_data:
                self._foe_ack_last(position, word)
                return bytes(out)
            opcode, word, rest = self._foe(position, foe_packet(FoeOpcode.ACK, word))

    def _foe_ack_last(self, position: int, packet: int) -> None:
        s = self.slave(position)
        mo, mos = s.mailbox_out
        s.mbx_counter = s.mbx_counter % 7 + 1
        raw = encode_mailbox(MailboxMessage(MailboxType.FOE, foe_packet(FoeOpcode.ACK, packet), s.mbx_counter))
        self._wait(lambda: self._phys(Command.FPWR, s.station, mo, raw.ljust(mos, b"\0")).wkc == 1)

    # ------------------------------------------------------------------ process data
    def config_map(self) -> int:
        """Read each slave's PDO assignment by SDO, program SM2/SM3 and FMMU0/1; returns the process image size."""
        out_off = 0
        for s in self.slaves:
            s.output_bytes = self._pdo_bytes(s, 0x1C12)
            s.output_offset = out_off
            out_off += s.output_bytes
        in_off = out_off
        for s in self.slaves:
            s.input_bytes = self._pdo_bytes(s, 0x1C13)
            s.input_offset = in_off
            in_off += s.input_bytes
        self.outputs_size = out_off
        self.image = bytearray(in_off)
        self.expected_wkc = 0
        for s in self.slaves:
            o_sm, i_sm = self._pd_sms(s)
            o_ctrl = s.sii.sync_managers[o_sm[1]][2]
            i_ctrl = s.sii.sync_managers[i_sm[1]][2]
            sms = SM_REG.pack(o_sm[0], s.output_bytes, o_ctrl, 0, 1 if s.output_bytes else 0, 0) + \
                SM_REG.pack(i_sm[0], s.input_bytes, i_ctrl, 0, 1 if s.input_bytes else 0, 0)
            self.fpwr(s.station, REG_SM + 8 * o_sm[1], sms)
            fmmus = FMMU_REG.pack(s.output_offset, s.output_bytes, 0, 7, o_sm[0], 0, 2,
                                  1 if s.output_bytes else 0) + \
                FMMU_REG.pack(s.input_offset, s.input_bytes, 0, 7, i_sm[0], 0, 1, 1 if s.input_bytes else 0)
            self.fpwr(s.station, REG_FMMU, fmmus)
        # Images larger than one datagram go out as several LRW frames; each slave counts in every
        # frame its outputs (+2) or inputs (+1) overlap.
        self.chunks = [(a, min(MAX_DATAGRAM_DATA, len(self.image) - a))
                       for a in range(0, len(self.image), MAX_DATAGRAM_DATA)]
        for a, n in self.chunks:
            for s in self.slaves:
                if s.output_bytes and s.output_offset < a + n and a < s.output_offset + s.output_bytes:
                    self.expected_wkc += 2
                if s.input_bytes and s.input_offset < a + n and a < s.input_offset + s.input_bytes:
                    self.expected_wkc += 1
        return len(self.image)

    @staticmethod
    def _pd_sms(s: SlaveInfo) -> tuple[tuple[int, int], tuple[int, int]]:
        """(start, SM index) of the outputs and inputs SyncManagers from the SII (types 3 and 4)."""
        outs = [(sm[0], i) for i, sm in enumerate(s.sii.sync_managers) if sm[4] == 3]
        ins = [(sm[0], i) for i, sm in enumerate(s.sii.sync_managers) if sm[4] == 4]
        if not outs or not ins:
            raise MasterError(f"slave {s.position} has no process data SyncManagers in its SII")
        return outs[0], ins[0]

    def _pdo_bytes(self, s: SlaveInfo, assign: int) -> int:
        if not s.sii.coe_details:
            return sum(ln for _st, ln, _c, _e, t in s.sii.sync_managers if t == (3 if assign == 0x1C12 else 4))
        bits = 0
        for i in range(1, self.sdo_upload8(s.position, assign, 0) + 1):
            pdo = self.sdo_upload16(s.position, assign, i)
            for j in range(1, self.sdo_upload8(s.position, pdo, 0) + 1):
                bits += self.sdo_upload32(s.position, pdo, j) & 0xFF
        return (bits + 7) // 8

    def exchange_process_data(self) -> int:
        """The cyclic exchange, one LRW frame per image chunk; returns the summed working counter (see expected_wkc)."""
        total = 0
        image = self.image
        for a, n in self.chunks:
            self._index = (self._index + 1) & 0xFF
            try:
                d = self.exchange([Datagram(Command.LRW, self._index, a, bytes(image[a:a + n]))])[0]
            except TimeoutError_:
                continue
            lo = max(a, self.outputs_size)
            if lo < a + n:
                image[lo:a + n] = d.data[lo - a:]
            total += d.wkc
        self.last_wkc = total
        return total

    def pdo_write(self, position: int, offset: int, data: bytes) -> None:
        """Put bytes into one slave's outputs in the image, sent with the next process data exchange."""
        s = self.slave(position)
        if offset + len(data) > s.output_bytes:
            raise MasterError(f"outputs of slave {position} are {s.output_bytes} bytes")
        start = s.output_offset + offset
        self.image[start:start + len(data)] = data

    def pdo_read(self, position: int, offset: int, length: int) -> bytes:
        """Bytes of one slave's inputs as the last process data exchange brought them."""
        s = self.slave(position)
        if offset + length > s.input_bytes:
            raise MasterError(f"inputs of slave {position} are {s.input_bytes} bytes")
        start = s.input_offset + offset
        return bytes(self.image[start:start + length])

    def pdo_write8(self, position: int, offset: int, value: int) -> None:
        """Put an 8-bit output into the image (QEC pdo_write8)."""
        self.pdo_write(position, offset, struct.pack("<B", value))

    def pdo_write16(self, position: int, offset: int, value: int) -> None:
        """Put a 16-bit output into the image (QEC pdo_write16)."""
        self.pdo_write(position, offset, struct.pack("<H", value))

    def pdo_write32(self, position: int, offset: int, value: int) -> None:
        """Put a 32-bit output into the image (QEC pdo_write32)."""
        self.pdo_write(position, offset, struct.pack("<I", value))

    def pdo_read8(self, position: int, offset: int) -> int:
        """An 8-bit input from the image (QEC pdo_read8)."""
        return int(self.pdo_read(position, offset, 1)[0])

    def pdo_read16(self, position: int, offset: int) -> int:
        """A 16-bit input from the image (QEC pdo_read16)."""
        return int(U16.unpack(self.pdo_read(position, offset, 2))[0])

    def pdo_read32(self, position: int, offset: int) -> int:
        """A 32-bit input from the image (QEC pdo_read32)."""
        return int(U32.unpack(self.pdo_read(position, offset, 4))[0])

    def start_cyclic(self, period: float, callback: Callable[[Master], None] | None = None) -> None:
        """Exchange process data every ``period`` seconds on the clock, then call ``callback``: the master's cycle."""
        self.stop_cyclic()

        def cycle() -> None:
            self.exchange_process_data()
            if callback is not None:
                callback(self)

        self._cyclic = self.clock.call_every(period, cycle)

    def stop_cyclic(self) -> None:
        """Stop the cycle started by start_cyclic (slaves with a watchdog then leave OP)."""
        if self._cyclic is not None:
            self._cyclic.cancel()
            self._cyclic = None

    # ------------------------------------------------------------------ DC
    def configure_sync0(self, position: int, cycle: float, start_delay: float = 0.01) -> None:
        """Program DC SYNC0 (cycle, start = system time + delay, activation) for slaves that run synchronous cycles."""
        s = self.slave(position)
        now = U64.unpack(self.fprd(s.station, REG_DC_SYSTEM_TIME, 8))[0]
        self.fpwr(s.station, REG_DC_SYNC0_CYCLE, U32.pack(round(cycle * 1e9)))
        self.fpwr(s.station, REG_DC_START_TIME, U64.pack(now + round(start_delay * 1e9)))
        self.fpwr(s.station, REG_DC_ACTIVATION, b"\x03")

    def bring_up(self, ack_errors: bool = False) -> None:
        """scan, PREOP, map, SAFEOP, one process data cycle, OP: what every master does before its cycle.
        ``ack_errors``: request PREOP with the error acknowledge bit, as a master re-initialising a line
        whose slaves report an AL error does (ETG.1000.6 AL control)."""
        self.scan()
        for s in self.slaves:
            self.request_state(s.position, AlState.PREOP, ack=ack_errors)
        self.config_map()
        self.set_state(AlState.SAFEOP)
        self.exchange_process_data()
        self.set_state(AlState.OP)

