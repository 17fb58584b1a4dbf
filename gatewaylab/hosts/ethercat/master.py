"""In-process EtherCAT master: real frames through the same ESC code as the wire, no network needed.

It does what a small master library does (the QEC master manual's API is the model: slave info,
state changes, ``sdo_upload8/16/32``, FoE, ``pdo_read/pdo_write``, a cyclic callback): scan with
BRD/APWR, read the SII through the EEPROM interface, configure mailbox SMs, talk CoE/FoE through
the mailbox SMs, map process data with SMs + FMMUs and exchange it with one LRW per cycle.

:class:`Master` is the class users construct; it is composed along SOEM's lines of parts, each in
its own module: :class:`~gatewaylab.hosts.ethercat.base.Port` (datagram exchange, ethercatbase),
:class:`~gatewaylab.hosts.ethercat.config.Configuration` (scan, SII, AL states, mapping,
ethercatconfig), :class:`~gatewaylab.hosts.ethercat.mailbox.Mailboxes` (SM0/SM1),
:class:`~gatewaylab.hosts.ethercat.coe.Coe`, :class:`~gatewaylab.hosts.ethercat.foe.Foe`,
:class:`~gatewaylab.hosts.ethercat.dc.Dc` and
:class:`~gatewaylab.hosts.ethercat.process_data.ProcessImage` (the LRW cycle, ethercatmain).
"""

from __future__ import annotations

from collections.abc import Callable

from gatewaylab.common.clock import Clock
from gatewaylab.ethercat.datagram import Datagram
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.mailbox import MailboxMessage
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.base import U8, U16, U32, U64, Port
from gatewaylab.hosts.ethercat.coe import Coe, EntryDescription, ObjectDescription
from gatewaylab.hosts.ethercat.config import Configuration, SlaveInfo
from gatewaylab.hosts.ethercat.dc import Dc
from gatewaylab.hosts.ethercat.foe import Foe
from gatewaylab.hosts.ethercat.mailbox import Mailboxes
from gatewaylab.hosts.ethercat.process_data import ProcessImage

__all__ = ["Master"]


class Master:
    """A small EtherCAT master with real frames, so tests and teaching scripts drive slaves without a network.

    Most methods hand the call to one of the parts (``port``, ``config``, ``mailbox``, ``coe``, ``foe``,
    ``dc``, ``process``), and that is deliberate: this class is the users' API -- the QEC master
    manual's calls (``sdo_upload8/16/32``, ``pdo_read``/``pdo_write``, state changes, a cyclic
    callback) that docs/ethercat.md, the device pages and the migration guide show on one object --
    while the parts are the implementation, split along SOEM's modules so each reads alone and can be
    used directly (``master.coe.sdo_upload``, ``master.port.phys``). New behaviour goes into a part;
    a method is added here only when users get a call they would look for on a master.
    """

    def __init__(self, clock: Clock, segment: Segment | None = None,
                 link: Callable[[bytes], bytes | None] | None = None, *, timeout: float = 0.1,
                 capture: Callable[[float, bytes], None] | None = None) -> None:
        self.clock = clock
        self.segment = segment
        self.link = link
        self.port = Port(clock, segment, link, timeout, capture)
        self.config = Configuration(self.port)
        self.mailbox = Mailboxes(self.port, self.config)
        self.coe = Coe(self.mailbox, self.config)
        self.foe = Foe(self.mailbox, self.config)
        self.dc = Dc(self.port, self.config)
        self.process = ProcessImage(self.port, self.config)

    # ------------------------------------------------------------------ settings and counters
    @property
    def timeout(self) -> float:
        """Seconds a mailbox poll may take before TimeoutError_."""
        return self.port.timeout

    @timeout.setter
    def timeout(self, value: float) -> None:
        self.port.timeout = value

    @property
    def capture(self) -> Callable[[float, bytes], None] | None:
        """Called with (clock time, frame) for every frame out and back, e.g. ``PcapWriter.write``."""
        return self.port.capture

    @capture.setter
    def capture(self, value: Callable[[float, bytes], None] | None) -> None:
        self.port.capture = value

    @property
    def foe_busy_timeout(self) -> float:
        """Seconds a slave may keep answering FoE BUSY to one data packet."""
        return self.foe.busy_timeout

    @foe_busy_timeout.setter
    def foe_busy_timeout(self, value: float) -> None:
        self.foe.busy_timeout = value

    @property
    def frames(self) -> int:
        """Frames sent so far, for statistics."""
        return self.port.frames

    @property
    def lost_frames(self) -> int:
        """Frames that did not come back, for statistics."""
        return self.port.lost_frames

    @property
    def slaves(self) -> list[SlaveInfo]:
        """The slaves of the last scan, by position."""
        return self.config.slaves

    @property
    def image(self) -> bytearray:
        """The process image: outputs of every slave, then their inputs."""
        return self.process.image

    @property
    def chunks(self) -> list[tuple[int, int]]:
        """(logical start, length) of each LRW datagram of a cycle."""
        return self.process.chunks

    @property
    def outputs_size(self) -> int:
        """Bytes of outputs at the start of the image."""
        return self.process.outputs_size

    @property
    def expected_wkc(self) -> int:
        """The working counter a cycle returns when every slave took part."""
        return self.process.expected_wkc

    @property
    def last_wkc(self) -> int:
        """The working counter of the last cycle."""
        return self.process.last_wkc

    # ------------------------------------------------------------------ frames
    def exchange(self, datagrams: list[Datagram]) -> tuple[Datagram, ...]:
        """Send one frame and return its datagrams as they came back: the one path every command takes."""
        return self.port.exchange(datagrams)

    def fprd(self, station: int, ado: int, length: int) -> bytes:
        """Read a register of one configured slave (FPRD), raising unless exactly that slave answered."""
        return self.port.fprd(station, ado, length)

    def fpwr(self, station: int, ado: int, data: bytes) -> None:
        """Write a register of one configured slave (FPWR), raising unless exactly that slave answered."""
        self.port.fpwr(station, ado, data)

    # ------------------------------------------------------------------ configuration
    def scan(self) -> list[SlaveInfo]:
        """Find the slaves (BRD), give them station addresses (APWR) and read their SII: the start of every session."""
        return self.config.scan()

    def read_sii(self, station: int, max_bytes: int = 65536) -> bytes:
        """The SII image up to its END category, which tells the master the slave's mailboxes and SyncManagers."""
        return self.config.read_sii(station, max_bytes)

    def sii_read8(self, station: int, word: int) -> bytes:
        """Read 8 bytes of the SII through the EEPROM interface, the unit of every SII read."""
        return self.config.sii_read8(station, word)

    def sii_write(self, station: int, word: int, value: int) -> int:
        """Write one SII word through the EEPROM interface (to test write protection and errors); returns its status."""
        return self.config.sii_write(station, word, value)

    def slave(self, position: int) -> SlaveInfo:
        """The scanned slave at a position, or a MasterError that says to scan first."""
        return self.config.slave(position)

    def al_status(self, position: int) -> tuple[int, int]:
        """(AL status, AL status code) of one slave: how a master learns a state change failed and why."""
        return self.config.al_status(position)

    def request_state(self, position: int, state: AlState, ack: bool = False) -> AlState:
        """Move one slave to an AL state (configuring its mailbox first), raising AlStatusError with its code."""
        return self.config.request_state(position, state, ack)

    def set_state(self, state: AlState) -> None:
        """Move every slave to an AL state, as masters do for the whole segment."""
        self.config.set_state(state)

    def config_map(self) -> int:
        """Read each slave's PDO assignment by SDO, program SM2/SM3 and FMMU0/1; returns the process image size."""
        return self.config.config_map(self.coe, self.process)

    # ------------------------------------------------------------------ mailbox, CoE
    def mailbox_exchange(self, position: int, mtype: int, data: bytes,
                         accept: Callable[[MailboxMessage], bool] | None = None) -> MailboxMessage:
        """Write a request into SM0 and return the first reply of the same type from SM1: the carrier of CoE and FoE."""
        return self.mailbox.exchange(position, mtype, data, accept)

    def sdo_upload(self, position: int, index: int, subindex: int = 0, complete: bool = False) -> bytes:
        """Read an object by CoE SDO (expedited, normal or segmented, as the slave answers)."""
        return self.coe.sdo_upload(position, index, subindex, complete)

    def sdo_download(self, position: int, index: int, subindex: int, data: bytes,
                     complete: bool = False) -> None:
        """Write an object by CoE SDO: expedited up to 4 bytes, else normal, segmented when it does not fit."""
        self.coe.sdo_download(position, index, subindex, data, complete)

    def sdo_upload8(self, position: int, index: int, sub: int = 0) -> int:
        """Read an 8-bit object as an int (QEC sdo_upload8), checking its size."""
        return self.coe.typed_upload(position, index, sub, U8)

    def sdo_upload16(self, position: int, index: int, sub: int = 0) -> int:
        """Read a 16-bit object as an int (QEC sdo_upload16), checking its size."""
        return self.coe.typed_upload(position, index, sub, U16)

    def sdo_upload32(self, position: int, index: int, sub: int = 0) -> int:
        """Read a 32-bit object as an int (QEC sdo_upload32), checking its size."""
        return self.coe.typed_upload(position, index, sub, U32)

    def sdo_upload64(self, position: int, index: int, sub: int = 0) -> int:
        """Read a 64-bit object as an int, checking its size."""
        return self.coe.typed_upload(position, index, sub, U64)

    def sdo_upload_str(self, position: int, index: int, sub: int = 0) -> str:
        """Read a VISIBLE_STRING object (names, versions) as text."""
        return self.coe.sdo_upload(position, index, sub).decode("latin-1")

    def sdo_download8(self, position: int, index: int, sub: int, value: int) -> None:
        """Write an 8-bit object from an int (QEC sdo_download8)."""
        self.coe.sdo_download(position, index, sub, U8.pack(value))

    def sdo_download16(self, position: int, index: int, sub: int, value: int) -> None:
        """Write a 16-bit object from an int (QEC sdo_download16)."""
        self.coe.sdo_download(position, index, sub, U16.pack(value))

    def sdo_download32(self, position: int, index: int, sub: int, value: int) -> None:
        """Write a 32-bit object from an int (QEC sdo_download32)."""
        self.coe.sdo_download(position, index, sub, U32.pack(value))

    def sdo_download64(self, position: int, index: int, sub: int, value: int) -> None:
        """Write a 64-bit object from an int."""
        self.coe.sdo_download(position, index, sub, U64.pack(value))

    def receive_emergency(self, position: int) -> tuple[int, int, bytes]:
        """The next CoE emergency (ETG.1000.6) the slave sent: (error code, error register, 5 data
        bytes); other mailbox messages read meanwhile are dropped. TimeoutError_ without one."""
        return self.coe.receive_emergency(position)

    def od_list(self, position: int, list_type: int = 1) -> list[int]:
        """The indexes of a slave's dictionary by SDO information (list type 1: all), to browse it without an ESI."""
        return self.coe.od_list(position, list_type)

    def object_description(self, position: int, index: int) -> ObjectDescription:
        """Name, type and size of one object by SDO information, to browse a dictionary without an ESI."""
        return self.coe.object_description(position, index)

    def entry_description(self, position: int, index: int, subindex: int) -> EntryDescription:
        """Type, bit length, access and name of one subindex by SDO information."""
        return self.coe.entry_description(position, index, subindex)

    # ------------------------------------------------------------------ FoE
    def foe_write(self, position: int, name: str, data: bytes, password: int = 0) -> None:
        """Send a file by FoE (firmware updates), repeating a packet while the slave answers BUSY."""
        self.foe.write(position, name, data, password)

    def foe_read(self, position: int, name: str, password: int = 0) -> bytes:
        """Read a file by FoE (logs, configuration), acknowledging every data packet."""
        return self.foe.read(position, name, password)

    # ------------------------------------------------------------------ process data
    def exchange_process_data(self) -> int:
        """The cyclic exchange, one LRW frame per image chunk; returns the summed working counter (see expected_wkc)."""
        return self.process.exchange()

    def pdo_write(self, position: int, offset: int, data: bytes) -> None:
        """Put bytes into one slave's outputs in the image, sent with the next process data exchange."""
        self.process.write(position, offset, data)

    def pdo_read(self, position: int, offset: int, length: int) -> bytes:
        """Bytes of one slave's inputs as the last process data exchange brought them."""
        return self.process.read(position, offset, length)

    def pdo_write8(self, position: int, offset: int, value: int) -> None:
        """Put an 8-bit output into the image (QEC pdo_write8)."""
        self.process.write_uint(position, offset, U8, value)

    def pdo_write16(self, position: int, offset: int, value: int) -> None:
        """Put a 16-bit output into the image (QEC pdo_write16)."""
        self.process.write_uint(position, offset, U16, value)

    def pdo_write32(self, position: int, offset: int, value: int) -> None:
        """Put a 32-bit output into the image (QEC pdo_write32)."""
        self.process.write_uint(position, offset, U32, value)

    def pdo_read8(self, position: int, offset: int) -> int:
        """An 8-bit input from the image (QEC pdo_read8)."""
        return self.process.read_uint(position, offset, U8)

    def pdo_read16(self, position: int, offset: int) -> int:
        """A 16-bit input from the image (QEC pdo_read16)."""
        return self.process.read_uint(position, offset, U16)

    def pdo_read32(self, position: int, offset: int) -> int:
        """A 32-bit input from the image (QEC pdo_read32)."""
        return self.process.read_uint(position, offset, U32)

    def start_cyclic(self, period: float, callback: Callable[[Master], None] | None = None) -> None:
        """Exchange process data every ``period`` seconds on the clock, then call ``callback``: the master's cycle."""
        process = self.process

        def cycle() -> None:
            process.exchange()
            if callback is not None:
                callback(self)

        process.start_cyclic(period, cycle)

    def stop_cyclic(self) -> None:
        """Stop the cycle started by start_cyclic (slaves with a watchdog then leave OP)."""
        self.process.stop_cyclic()

    # ------------------------------------------------------------------ DC, bring-up
    def configure_sync0(self, position: int, cycle: float, start_delay: float = 0.01) -> None:
        """Program DC SYNC0 (cycle, start = system time + delay, activation) for slaves that run synchronous cycles."""
        self.dc.configure_sync0(position, cycle, start_delay)

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
