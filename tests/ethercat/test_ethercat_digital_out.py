"""Output SyncManagers on the ESC's Digital I/O Output Data register, register by register.

ET1100 data sheet section II, 0x0F00:0x0F03 "Digital I/O Output Data" (ECAT r/w): a digital output terminal
without a microcontroller (an EL2008) drives its outputs from there, and its ESI places the outputs
SyncManager on it (``<Sm StartAddress="#x0f00" ControlByte="#x44" DefaultSize="1">Outputs</Sm>``: buffered,
ECAT writes, watchdog trigger). The ESC runs such a SyncManager as one in process RAM (buffer complete: SM
status write event, the newest buffer for the PDI, the SM watchdog triggered; an FMMU writing there) and
refuses every other SyncManager over the registers (AL status 0x0017 "invalid SyncManager configuration",
ETG.1000.6). Data sheet section I (digital outputs, process data watchdog): when the SM watchdog expires the
digital outputs go to 0; the firmware's local exit from OP deactivates the SyncManager (0x0807 bit 0).
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.esi.device import esi_slave
from gatewaylab.devices.esi.reader import read_esi_file
from gatewaylab.ethercat.datagram import Command, Datagram
from gatewaylab.ethercat.errors import AlStatusCode, AlStatusError
from gatewaylab.ethercat.esc import FMMU_REG, REG_FMMU, REG_SM, SM_REG, AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.slave import Slave
from gatewaylab.hosts.ethercat.master import Master

EL2008 = Path(__file__).resolve().parent.parent / "devices" / "esi" / "data" / "GL-test-EL1xxx-EL2xxx.xml"
STATION = 0x1001
LOGICAL = 0x0001_0000
WRITE_EVENT = 0x01           # SM status 0x0805 bit 0: a buffer was written (3-buffer mode)
SM_PDI_DISABLE = 0x01        # 0x0807 bit 0: SyncManager deactivated by the PDI


def _line() -> tuple[SimulatedClock, Slave, Master]:
    clock = SimulatedClock()
    slave = esi_slave(clock, read_esi_file(EL2008, "EL2008"), "do")
    master = Master(clock, Segment([slave]))
    master.scan()
    master.set_state(AlState.PREOP)
    return clock, slave, master


def _one(master: Master, dgram: Datagram) -> Datagram:
    return master.exchange([dgram])[0]


def _fpwr(master: Master, ado: int, data: bytes) -> int:
    return _one(master, Datagram.physical(Command.FPWR, 0, STATION, ado, data)).wkc


def _lwr(master: Master, address: int, data: bytes) -> int:
    return _one(master, Datagram(Command.LWR, 0, address, data)).wkc


def _to_op(master: Master, sm: bytes = SM_REG.pack(0x0F00, 1, 0x44, 0, 1, 0)) -> None:
    """SM0 on 0x0F00 and FMMU0 (write) from the logical byte LOGICAL onto it, as SOEM's config_map and
    TwinCAT's InitCmds program an EL2008; then SAFEOP and OP."""
    master.fpwr(STATION, REG_SM, sm)
    master.fpwr(STATION, REG_FMMU, FMMU_REG.pack(LOGICAL, 1, 0, 7, 0x0F00, 0, 2, 1))
    master.set_state(AlState.SAFEOP)
    master.set_state(AlState.OP)


def test_the_sii_places_the_outputs_where_the_esi_does() -> None:
    """ETG.2010 SyncManager category: the EL2008's outputs SyncManager (SM0) as its ESI says (start 0x0F00,
    1 byte, control 0x44), so a master configuring from the SII (SOEM's config_map) programs it there."""
    _clock, _slave, master = _line()
    assert master.slave(0).sii.sync_managers[0][:3] == (0x0F00, 1, 0x44)


def test_a_buffered_output_sm_on_0x0f00_runs_as_one_in_ram() -> None:
    """FPWR of SM0 (0x0F00, 1 byte, 0x44, enable): the ESC activates it (no refused SyncManager); an FPWR of
    the buffer is accepted (working counter 1), sets the write event in the SM status (0x0805) and hands the
    buffer to the PDI; an FPRD of 0x0F00 reads the byte back (ECAT r/w)."""
    _clock, slave, master = _line()
    esc = slave.esc
    master.fpwr(STATION, REG_SM, SM_REG.pack(0x0F00, 1, 0x44, 0, 1, 0))
    assert esc.sm_active(0) and esc.stats.refused_sms == 0
    assert _fpwr(master, 0x0F00, b"\xa5") == 1
    assert esc.sm_status(0) & WRITE_EVENT
    assert esc.pdi_outputs[0] == b"\xa5"
    assert master.fprd(STATION, 0x0F00, 1) == b"\xa5"


def test_the_fmmu_write_lands_on_0x0f00_and_reaches_the_device_in_op() -> None:
    """SAFEOP and OP accepted with SM0 and FMMU0 on 0x0F00; a logical write (LWR, working counter 1) lands in
    the register, the device acts on it (its outputs, one BOOL object 0x70n0:01 per bit)."""
    _clock, slave, master = _line()
    _to_op(master)
    assert master.al_status(0) == (AlState.OP, 0)
    assert _lwr(master, LOGICAL, b"\x3c") == 1
    assert master.fprd(STATION, 0x0F00, 1) == b"\x3c"
    assert slave.outputs == b"\x3c"
    assert [int(slave.od.get(0x7000 + 0x10 * i, 1)) for i in range(8)] == [0, 0, 1, 1, 1, 1, 0, 0]


def test_a_bitwise_fmmu_writes_only_its_bits_of_0x0f00() -> None:
    """A bit-wise FMMU (ETG.1000.4 FMMU: logical start bit 0, stop bit 3, physical start bit 4), as SOEM
    packs a 4-channel terminal: the logical nibble lands in bits 4..7 of 0x0F00, bits 0..3 keep theirs."""
    _clock, _slave, master = _line()
    _to_op(master)
    master.fpwr(STATION, REG_FMMU + 16, FMMU_REG.pack(LOGICAL + 0x100, 1, 0, 3, 0x0F00, 4, 2, 1))
    assert _lwr(master, LOGICAL, b"\x05") == 1
    assert _lwr(master, LOGICAL + 0x100, b"\x0a") == 1
    assert master.fprd(STATION, 0x0F00, 1) == b"\xa5"


def test_watchdog_expiry_clears_the_outputs_and_the_pdi_locks_the_sm() -> None:
    """ET1100 data sheet I (process data watchdog, digital outputs): the SM watchdog (0x44 bit 6: this SM
    triggers it; 100 ms by default, 0x0400/0x0420) expires without output writes: the outputs go to 0 (the
    register holds 0), the slave drops to SAFEOP + error with 0x001B, and the firmware deactivates the
    SyncManager (0x0807 bit 0, "SyncManager locks access to Memory area"): the next output write and a read
    of the buffer are refused (working counter 0) until the master takes the slave through a state change."""
    clock, slave, master = _line()
    _to_op(master)
    assert _lwr(master, LOGICAL, b"\xff") == 1
    clock.advance(0.05)
    assert _lwr(master, LOGICAL, b"\xf0") == 1          # a write within the time re-triggers it
    clock.advance(0.09)
    assert master.al_status(0) == (AlState.OP, 0) and slave.outputs == b"\xf0"
    clock.advance(0.2)
    assert master.al_status(0) == (AlState.SAFEOP | 0x10, AlStatusCode.SM_WATCHDOG)
    assert slave.esc.pdi_read(0x0F00, 1) == b"\x00"
    assert slave.outputs == b"\x00" and slave.esc.stats.watchdog_expiries == 1
    assert slave.esc.mem[REG_SM + 7] & SM_PDI_DISABLE
    assert _lwr(master, LOGICAL, b"\x0f") == 0
    assert _one(master, Datagram.physical(Command.FPRD, 0, STATION, 0x0F00, b"\0")).wkc == 0
    assert slave.esc.pdi_read(0x0F00, 1) == b"\x00"
    master.request_state(0, AlState.SAFEOP, ack=True)
    master.request_state(0, AlState.OP)
    assert _lwr(master, LOGICAL, b"\x0f") == 1
    assert slave.outputs == b"\x0f" and master.fprd(STATION, 0x0F00, 1) == b"\x0f"


def test_without_the_window_nothing_changes_for_sms_in_ram() -> None:
    """A slave whose SyncManagers all lie in process RAM runs no SyncManager on the register (the window's
    list stays empty, so its accesses never look at it) and a write of 0x0F00 raises no SyncManager event."""
    _clock, slave, master = _line()
    master.fpwr(STATION, REG_SM, SM_REG.pack(0x1000, 1, 0x44, 0, 1, 0))
    assert slave.esc.memory.io_sms == () and slave.esc.sm_active(0)
    assert _fpwr(master, 0x0F00, b"\x11") == 1
    assert not slave.esc.sm_status(0) & WRITE_EVENT and 0 not in slave.esc.pdi_outputs


@pytest.mark.parametrize(("start", "length", "control"), [
    (0x0F00, 5, 0x44),      # past 0x0F03
    (0x0F02, 4, 0x44),      # past 0x0F03
    (0x0E00, 1, 0x44),      # below the register (0x0E00: power-on values)
    (0x0F10, 1, 0x44),      # general purpose outputs, not the digital output register
    (0x0F00, 1, 0x46),      # 1-buffer (mailbox) mode
    (0x0F00, 1, 0x00),      # the master reads it: an inputs SyncManager
], ids=["length-5", "0x0F02-4", "0x0E00", "0x0F10", "mailbox-mode", "ecat-reads"])
def test_any_other_sm_over_the_registers_is_refused(start: int, length: int, control: int) -> None:
    """Anything but a buffered output SyncManager inside 0x0F00:0x0F03 stays refused: the ESC does not
    activate it (counted), a write of its area raises no SyncManager event, and PREOP -> SAFEOP answers AL
    status code 0x0017 (invalid SyncManager configuration, ETG.1000.6)."""
    _clock, slave, master = _line()
    esc = slave.esc
    master.fpwr(STATION, REG_SM, SM_REG.pack(start, length, control, 0, 1, 0))
    assert not esc.sm_active(0) and esc.stats.refused_sms == 1
    _fpwr(master, start, bytes(length))
    assert not esc.sm_status(0) & WRITE_EVENT and 0 not in esc.pdi_outputs
    with pytest.raises(AlStatusError):
        master.request_state(0, AlState.SAFEOP)
    assert master.al_status(0) == (AlState.PREOP | 0x10, AlStatusCode.INVALID_SM_CONFIG)
    assert struct.unpack("<H", master.fprd(STATION, 0x0134, 2))[0] == 0x0017
