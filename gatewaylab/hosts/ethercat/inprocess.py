"""The in-process :class:`~gatewaylab.hosts.ethercat.backend.MasterBackend`: the in-process
:class:`~gatewaylab.hosts.ethercat.master.Master` on a rig's segment (no root, simulated or real clock;
``InProcessBackend.from_rig(rig)``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import TimeoutError_
from gatewaylab.ethercat.errors import AlStatusError, MasterError, SdoAbort, WorkingCounterError
from gatewaylab.ethercat.esc import (
    REG_DC_ACTIVATION,
    REG_DC_START_TIME,
    REG_DC_SYNC0_CYCLE,
    REG_DC_SYSTEM_TIME,
    AlState,
)
from gatewaylab.ethercat.sii import SiiInfo
from gatewaylab.hosts.ethercat.backend import EntryInfo, MasterTimeout, ObjectInfo, ProgressFn, SlaveIdentity
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.hosts.ethercat.shared import (
    AL_ERROR,
    DC_START_DELAY,
    U32,
    U64,
    MailboxPort,
    await_state,
    register_read,
    register_write,
    state_of,
)

if TYPE_CHECKING:
    from gatewaylab.ethercat.segment import Segment

__all__ = ["InProcessBackend", "RigLike"]



# ---------------------------------------------------------------------------------------- in process
class RigLike(Protocol):
    """What :meth:`InProcessBackend.from_rig` needs of a rig (``gatewaylab.rig.runtime.Rig``)."""

    @property
    def clock(self) -> Clock:
        """The rig's clock, which the master waits on."""
        ...

    @property
    def participants(self) -> Sequence[Any]:
        """The rig's devices, where the master finds the EtherCAT segment."""
        ...


class _MasterRegisters:
    """:class:`~.shared.Registers` over the in-process master (configured addresses of its scan)."""

    def __init__(self, master: Master) -> None:
        self.master = master

    def read(self, position: int, address: int, length: int) -> bytes | None:
        try:
            return self.master.fprd(self.master.slave(position).station, address, length)
        except (TimeoutError_, WorkingCounterError):
            return None

    def write(self, position: int, address: int, data: bytes) -> bool:
        try:
            self.master.fpwr(self.master.slave(position).station, address, data)
        except (TimeoutError_, WorkingCounterError):
            return False
        return True


def _locked_link(segment: Segment, clock: Clock) -> Callable[[bytes], bytes | None]:
    """A master link through ``segment`` under the clock's lock (a rig's loop may run the devices), through
    the line faults the rig armed (ethercat/line_faults.py)."""
    lock: Any = clock.lock

    def link(raw: bytes) -> bytes | None:
        buf = bytearray(raw)
        with lock:
            faults = segment.line_faults
            if faults is not None and faults.engaged:
                ok = faults.serve_now(segment, buf, clock.now())
            else:
                ok = segment.process(buf)
        return bytes(buf) if ok else None

    return link


class InProcessBackend:
    """:class:`MasterBackend` over the in-process :class:`Master`: frames through the ESC code, no network."""

    def __init__(self, master: Master, *, preop: bool = True) -> None:
        self.master = master
        self.clock: Clock = master.clock
        self.wkc_errors = 0
        self.last_wkc = 0
        self._sii: dict[int, SiiInfo] = {}
        self._mapped = False
        self._mbx = MailboxPort(self.clock, _MasterRegisters(master), master.timeout, self._next_counter)
        if not master.slaves:
            self._call(master.scan)
        if preop:
            for s in master.slaves:
                if self.state(s.position)[0] == AlState.INIT:
                    self.request_state(AlState.PREOP, s.position)

    @classmethod
    def from_rig(cls, rig: RigLike, *, timeout: float = 0.1, preop: bool = True) -> InProcessBackend:
        """A master on the rig's EtherCAT segment (its ``[ethercat]`` section, or its EtherCAT devices
        in file order when it has none), frames under the rig clock's lock. Start the rig first so
        its devices run."""
        from gatewaylab.ethercat.segment import Segment as _Segment
        from gatewaylab.plugin.capabilities import ethercat_devices, segment_of

        segment = segment_of(rig.participants)
        if segment is None:
            devices = ethercat_devices(rig.participants)
            if not devices:
                raise MasterError("the rig has no EtherCAT devices")
            segment = _Segment([d.slave for d in devices])
        master = Master(rig.clock, link=_locked_link(segment, rig.clock), timeout=timeout)
        return cls(master, preop=preop)

    # -- helpers -----------------------------------------------------------------------------
    def _next_counter(self, position: int) -> int:
        s = self.master.slave(position)
        s.mbx_counter = s.mbx_counter % 7 + 1
        return s.mbx_counter

    def _call(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """Run a master call, turning its timeout into :class:`MasterTimeout`."""
        try:
            return fn(*args, **kwargs)
        except MasterTimeout:
            raise
        except TimeoutError_ as exc:
            raise MasterTimeout(str(exc)) from None

    def _positions(self, position: int | None) -> list[int]:
        if position is None:
            return [s.position for s in self.master.slaves]
        self.master.slave(position)
        return [position]

    # -- MasterBackend -----------------------------------------------------------------------
    def slaves(self) -> list[SlaveIdentity]:
        """The slaves of the scan, in line order."""
        return [SlaveIdentity(s.position, s.station, s.name, s.vendor_id, s.product_code, s.revision, s.serial)
                for s in self.master.slaves]

    def al_status(self, position: int) -> tuple[int, int]:
        """(AL status register with the error flag, AL status code)."""
        status, code = self._call(self.master.al_status, position)
        return int(status), int(code)

    def state(self, position: int) -> tuple[AlState, int]:
        """(AL state, AL status code) of one slave."""
        status, code = self.al_status(position)
        return state_of(status), code

    def request_state(self, state: AlState, position: int | None = None, timeout: float = 5.0) -> AlState:
        """Request ``state`` (all slaves, or one) and wait until reached; an error flag acknowledges
        first. Raises AlStatusError with the slave's code when refused, MasterTimeout when not reached."""
        m = self.master
        for pos in self._positions(position):
            status, _code = self.al_status(pos)
            try:
                self._call(m.request_state, pos, state, ack=bool(status & AL_ERROR))
            except AlStatusError:
                pass  # checked below: the slave may still be on its way
            await_state(self, pos, state, timeout, exchanging=self._mapped)
            m.slave(pos).boot = state == AlState.BOOT
        return state

    def sdo_upload(self, position: int, index: int, subindex: int, complete: bool = False) -> bytes:
        """CoE SDO upload (expedited, normal or segmented; complete access with ``complete``)."""
        return bytes(self._call(self.master.sdo_upload, position, index, subindex, complete))

    def sdo_download(self, position: int, index: int, subindex: int, data: bytes, complete: bool = False) -> None:
        """CoE SDO download (expedited, normal or segmented; complete access with ``complete``)."""
        self._call(self.master.sdo_download, position, index, subindex, data, complete)

    def object_info(self, position: int, index: int) -> ObjectInfo:
        """One object and its entries by SDO Information."""
        d = self._call(self.master.object_description, position, index)
        entries = []
        for sub in range(d.max_subindex + 1):
            try:
                e = self._call(self.master.entry_description, position, index, sub)
            except SdoAbort:
                continue  # a gap in an array/record
            entries.append(EntryInfo(sub, e.data_type, e.bit_length, e.access, e.name))
        return ObjectInfo(d.index, d.object_code, d.data_type, d.max_subindex, d.name, tuple(entries))

    def object_dictionary(self, position: int) -> list[ObjectInfo]:
        """Every object of the slave's dictionary by SDO Information (OD list, then descriptions)."""
        return [self.object_info(position, i) for i in self._call(self.master.od_list, position)]

    def foe_read(self, position: int, name: str, password: int = 0, *, progress: ProgressFn | None = None) -> bytes:
        """Read a file by FoE; FoeError carries the slave's FoE error code."""
        self.master.slave(position)
        return self._mbx.foe_read(position, name, password, progress)

    def foe_write(self, position: int, name: str, data: bytes, password: int = 0, *,
                  progress: ProgressFn | None = None) -> None:
        """Write a file by FoE (BUSY answers repeat the packet); FoeError carries the slave's code."""
        self.master.slave(position)
        self._mbx.foe_write(position, name, data, password, progress)

    def sii_read(self, position: int) -> bytes:
        """The SII EEPROM image up to its END category."""
        return bytes(self._call(self.master.read_sii, self.master.slave(position).station))

    def reg_read(self, position: int, address: int, length: int) -> bytes:
        """ESC registers by configured-address read (FPRD), IgH's ``reg_read``; MasterTimeout unanswered."""
        self.master.slave(position)
        return register_read(_MasterRegisters(self.master), position, address, length)

    def reg_write(self, position: int, address: int, data: bytes) -> None:
        """ESC registers by configured-address write (FPWR), IgH's ``reg_write``."""
        self.master.slave(position)
        register_write(_MasterRegisters(self.master), position, address, data)

    def sii_info(self, position: int) -> SiiInfo:
        """The parsed SII the scan read (identity, mailboxes, SyncManagers)."""
        return self.master.slave(position).sii

    def config_map(self) -> int:
        """PDO assignment by SDO -> SM2/SM3 and FMMUs; returns the process image size (no state change)."""
        size = int(self._call(self.master.config_map))
        self._mapped = True
        return size

    def configure_dc(self, position: int, cycle_ns: int, shift_ns: int = 0) -> None:
        """SYNC0 every ``cycle_ns`` (0 switches it off), first pulse on a cycle boundary + ``shift_ns``."""
        m = self.master
        station = m.slave(position).station
        if cycle_ns <= 0:
            self._call(m.fpwr, station, REG_DC_ACTIVATION, b"\x00")
            return
        now = U64.unpack(self._call(m.fprd, station, REG_DC_SYSTEM_TIME, 8))[0]
        start = now + round(DC_START_DELAY * 1e9)
        start = (start // cycle_ns + 1) * cycle_ns + shift_ns
        self._call(m.fpwr, station, REG_DC_ACTIVATION, b"\x00")
        self._call(m.fpwr, station, REG_DC_SYNC0_CYCLE, U32.pack(cycle_ns))
        self._call(m.fpwr, station, REG_DC_START_TIME, U64.pack(start))
        self._call(m.fpwr, station, REG_DC_ACTIVATION, b"\x03")

    def outputs(self, position: int) -> memoryview:
        """The slave's RxPDO bytes in the image: write them, the next :meth:`exchange` sends them."""
        s = self.master.slave(position)
        if not self._mapped:
            raise MasterError("config_map first")
        return memoryview(self.master.image)[s.output_offset:s.output_offset + s.output_bytes]

    def inputs(self, position: int) -> bytes:
        """The slave's TxPDO bytes as the last :meth:`exchange` brought them."""
        s = self.master.slave(position)
        if not self._mapped:
            raise MasterError("config_map first")
        return bytes(self.master.image[s.input_offset:s.input_offset + s.input_bytes])

    def exchange(self) -> tuple[int, int]:
        """One process-data cycle (LRW); returns (working counter, expected) and counts mismatches."""
        wkc = int(self.master.exchange_process_data())
        expected = self.master.expected_wkc
        self.last_wkc = wkc
        if wkc != expected:
            self.wkc_errors += 1
        return wkc, expected

    def close(self) -> None:
        """Stop a cycle the master may run; the segment stays with its owner (the rig)."""
        self.master.stop_cyclic()
