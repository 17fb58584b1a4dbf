"""Storms of mutated master frames against every EtherCAT device kind, in process on a simulated clock
(issue 21: "A storm test per EtherCAT kind: mutated frames (commands, addresses incl. register areas,
lengths, SM/FMMU programming over registers) then a normal master re-initialisation must reach OP with
all slaves", for 3 seeds)."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from ethercat_rig_kit import KINDS, kind_rig, reinitialise
from ethercat_storm import MasterTemplates, mutated_storm

from gatewaylab.ethercat.errors import AlStatusCode
from gatewaylab.ethercat.esc import AlState
from gatewaylab.hosts.ethercat.config import FIRST_STATION
from gatewaylab.hosts.ethercat.master import Master

FRAMES = 1500
VALID_STATES = {int(s) for s in AlState}
VALID_CODES = {int(c) for c in AlStatusCode}


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("kind", KINDS)
def test_storm_of_mutated_frames_then_reinitialisation_reaches_op(tmp_path: Path, kind: str, seed: int) -> None:
    """Two slaves of ``kind`` in OP, then mutated master frames: SyncManagers and FMMUs programmed over the
    registers (ET1100 data sheet II: registers 0x0000-0x0FFF, process RAM from 0x1000; such a SyncManager
    is not activated), CoE requests into the mailbox, commands, addresses and lengths changed. Every frame
    is processed without an exception escaping the segment, no read-only register takes the master's
    data (AL status always holds a defined state, ETG.1000.6 AL status code table), the SII is untouched,
    and the master's normal re-initialisation (INIT + acknowledge, every SM/FMMU reset, bring-up) reaches
    OP with both slaves and runs process data with the expected working counter."""
    rig, clock, seg = kind_rig(tmp_path, [kind, kind])
    try:
        Master(clock, seg).bring_up()
        assert all(s.state == AlState.OP for s in seg.slaves)
        eeproms = [bytes(s.esc.eeprom) for s in seg.slaves]
        mailboxes = [(*s.desc.mailbox_out, *s.desc.mailbox_in) if s.has_mailbox else (0, 0, 0, 0)
                     for s in seg.slaves]
        templates = MasterTemplates([FIRST_STATION + i for i in range(len(seg.slaves))], mailboxes)
        for i, raw in enumerate(mutated_storm(seed, FRAMES, templates)):
            seg.process(bytearray(raw))
            if i % 20 == 0:
                clock.advance(0.001)
            for s in seg.slaves:
                status = s.esc.al_status
                assert status & 0x0F in VALID_STATES and not status & ~0x1F, hex(status)
                assert s.esc.al_status_code in VALID_CODES | {0}, hex(s.esc.al_status_code)
        assert seg.stats.datagram_errors == 0, list(seg.stats.errors)
        assert [bytes(s.esc.eeprom) for s in seg.slaves] == eeproms
        assert seg.stats.frames > FRAMES // 2
        refused = sum(s.esc.stats.refused_sms for s in seg.slaves)
        assert refused > 0  # the storm did program SyncManagers over the registers
        clock.advance(0.7)  # a device restart a storm may have caused (ECAN-Lite: 0.5 s off the line) is over
        reinitialise(clock, seg)
        assert [s.state for s in seg.slaves] == [AlState.OP, AlState.OP]
        assert seg.stats.datagram_errors == 0, list(seg.stats.errors)
    finally:
        rig.close()


def test_storm_keeps_every_sii_whatever_frames_the_line_drops(tmp_path: Path) -> None:
    """The user-path storm beside another real-time rig (the emulator drops the frames it could not answer
    within ``max_residence_ms``): with a fifth of the frames lost, the earlier generator's FMMUs over the
    EEPROM interface (0x0502 write enable + command, 0x0504 address, 0x0508 data) let a logical datagram
    rewrite one word of a slave's SII -- the SyncManager category's length -- and SOEM then mapped that
    slave's process data at physical 0x0000 and overwrote its station address and AL control (ECAN-Lite
    unreachable, PREOP + 0x0012). ET1100 data sheet I (FMMU: any physical address) and II (0x0502: a
    write command with write enable programs the EEPROM): a real ESC does the same, so a storm that must
    leave a line SOEM can re-initialise keeps every FMMU from writing there; every SII stays as it was."""
    rig, clock, seg = kind_rig(tmp_path, list(KINDS))
    try:
        Master(clock, seg).bring_up()
        eeproms = [bytes(s.esc.eeprom) for s in seg.slaves]
        mailboxes = [(*s.desc.mailbox_out, *s.desc.mailbox_in) if s.has_mailbox else (0, 0, 0, 0)
                     for s in seg.slaves]
        templates = MasterTemplates([FIRST_STATION + i for i in range(len(seg.slaves))], mailboxes)
        lost = random.Random(0)
        served = 0
        for raw in mutated_storm(1, 6000, templates):
            clock.advance(0.0005)
            if lost.random() < 0.2:
                continue  # dropped late: never reached the slaves
            seg.process(bytearray(raw))
            served += 1
        assert served > 4000
        assert [bytes(s.esc.eeprom) for s in seg.slaves] == eeproms
    finally:
        rig.close()
