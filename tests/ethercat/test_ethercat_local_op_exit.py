"""A slave that leaves OP by itself stops counting outputs; one the master takes to SAFEOP does not.

ETG.1000.6 / ET1100 data sheet section II, register 0x0807 + 8n (PDI control of SyncManager n) bit 0
"Deactivate SyncManager": 1 = "SyncManager deactivated and reset. SyncManager locks access to Memory
area". SOES ``ESC_stopoutput`` and Beckhoff's slave stack deactivate the output SyncManager (SM2) when
the slave leaves OP by a local request (SM watchdog, AL status code 0x001B; a device error) and
activate it again on SAFEOP -> OP (``ESC_startoutput``); an LRW whose FMMU maps a locked buffer does
not increment the working counter for that write (ETG.1000.4 working counter: "successful" accesses
only). In an OP -> SAFEOP the master requests, SM2 stays active (IDX guide 4.2 table 4-16, "ignoring
new setpoint values of the Master": the writes are taken and counted, the device keeps safe values).
"""

from __future__ import annotations

import struct

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.ethercat.errors import AlStatusCode
from gatewaylab.ethercat.esc import REG_SM, REG_WD_TIME_SM, SM_PDI_DISABLE, AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master

SAFEOP_ERR = 0x14
# ethercat_io: outputs in SM2 (LRW write +2), inputs in SM3 (LRW read +1): 3 per slave, 9 for three.
FULL = 9
OUTPUT_SHARE = 2


def _sm2_pdi(segment: Segment, position: int) -> int:
    return segment.slaves[position].esc.mem[REG_SM + 8 * 2 + 7]


def _only_watchdog_of(master: Master, position: int) -> None:
    """SM watchdog time 0 (off) on every other slave, so that only ``position`` falls back."""
    for s in master.slaves:
        if s.position != position:
            master.fpwr(s.station, REG_WD_TIME_SM, struct.pack("<H", 0))


def test_watchdog_expiry_deactivates_sm2_and_lowers_the_working_counter(
        master: Master, clock: SimulatedClock, segment: Segment) -> None:
    """After an SM watchdog expiry the slave is SAFEOP + error 0x001B, 0x0807 of SM2 shows the
    SyncManager deactivated, and the LRW's working counter lacks that slave's output share (2); after
    the master's acknowledge and SAFEOP -> OP the counter is full again."""
    _only_watchdog_of(master, 1)
    master.bring_up()
    assert master.expected_wkc == FULL and master.exchange_process_data() == FULL
    master.start_cyclic(0.001)
    clock.advance(0.05)
    master.stop_cyclic()
    clock.advance(0.2)  # > 100 ms without outputs
    assert master.al_status(1) == (SAFEOP_ERR, AlStatusCode.SM_WATCHDOG)
    assert [master.al_status(p)[0] for p in (0, 2)] == [AlState.OP, AlState.OP]
    assert _sm2_pdi(segment, 1) & SM_PDI_DISABLE
    assert master.exchange_process_data() == FULL - OUTPUT_SHARE
    assert master.exchange_process_data() == FULL - OUTPUT_SHARE  # stays low: the SM stays locked
    # the acknowledge alone keeps it deactivated; SAFEOP -> OP activates it again
    master.request_state(1, AlState.SAFEOP, ack=True)
    assert master.al_status(1) == (AlState.SAFEOP, 0)
    assert master.exchange_process_data() == FULL - OUTPUT_SHARE
    master.request_state(1, AlState.OP)
    assert master.al_status(1) == (AlState.OP, 0)
    assert not _sm2_pdi(segment, 1) & SM_PDI_DISABLE
    assert master.exchange_process_data() == FULL
    master.pdo_write8(1, 0, 0x5A)
    master.exchange_process_data()
    assert segment.slaves[1].outputs[0] == 0x5A


def test_all_watchdogs_expire_then_every_output_share_is_missing(
        master: Master, clock: SimulatedClock, segment: Segment) -> None:
    """The issue's scene in process: the master pauses longer than the watchdog, every slave goes to
    SAFEOP + 0x001B, and the next cycles read a working counter of the inputs only (3 of 9)."""
    master.bring_up()
    master.start_cyclic(0.001)
    clock.advance(0.05)
    master.stop_cyclic()
    clock.advance(0.15)
    assert [master.al_status(p) for p in range(3)] == [(SAFEOP_ERR, AlStatusCode.SM_WATCHDOG)] * 3
    assert master.exchange_process_data() == FULL - 3 * OUTPUT_SHARE


def test_device_error_leaving_op_deactivates_sm2(master: Master, segment: Segment) -> None:
    """A device error (the application drops to SAFEOP + error by itself) stops SM2 as the watchdog does."""
    master.bring_up()
    segment.slaves[2].fault(0x0050)
    assert master.al_status(2) == (SAFEOP_ERR, 0x0050)
    assert _sm2_pdi(segment, 2) & SM_PDI_DISABLE
    assert master.exchange_process_data() == FULL - OUTPUT_SHARE
    master.request_state(2, AlState.SAFEOP, ack=True)
    master.request_state(2, AlState.OP)
    assert master.exchange_process_data() == FULL


def test_master_requested_safeop_keeps_outputs_counting(master: Master, segment: Segment) -> None:
    """OP -> SAFEOP requested by the master: SM2 stays active, the working counter stays full, the
    device keeps its safe outputs (IDX 4.2 table 4-16)."""
    master.bring_up()
    master.request_state(0, AlState.SAFEOP)
    assert master.al_status(0) == (AlState.SAFEOP, 0)
    assert not _sm2_pdi(segment, 0) & SM_PDI_DISABLE
    master.pdo_write8(0, 0, 0xFF)
    assert master.exchange_process_data() == FULL
    assert segment.slaves[0].outputs == bytes(len(segment.slaves[0].outputs))


def test_sm_change_in_safeop_after_a_watchdog_keeps_the_slave_in_safeop(
        master: Master, clock: SimulatedClock, segment: Segment) -> None:
    """The firmware's own deactivation is not a wrong SyncManager configuration: a master writing an
    SM register (here SM3's activate byte, unchanged) while SM2 is stopped leaves SAFEOP + 0x001B, not
    PREOP + 0x001D (SOES ESC_sm_act_event checks the master's configuration, not its own stop)."""
    _only_watchdog_of(master, 0)
    master.bring_up()
    clock.advance(0.2)
    assert master.al_status(0) == (SAFEOP_ERR, AlStatusCode.SM_WATCHDOG)
    station = master.slave(0).station
    act = master.fprd(station, REG_SM + 8 * 3 + 6, 1)
    master.fpwr(station, REG_SM + 8 * 3 + 6, act)
    assert master.al_status(0) == (SAFEOP_ERR, AlStatusCode.SM_WATCHDOG)
