"""EtherCAT unplug / replug as the in-process master sees it (issue 14 'Break'; docs/faults.md).

ETG.1000.4 / ET1100 datasheet: a datagram's working counter counts the slaves that executed it, so
a slave that is gone lowers the WKC of the cyclic LRW; an ESC closes a port without link and loops
the frame back, so the slaves behind an unplugged one are cut off too; a device that powers on
starts in INIT (AL status 0x0001).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gatewaylab.ethercat.datagram import Command
from gatewaylab.ethercat.errors import WorkingCounterError
from gatewaylab.ethercat.esc import REG_AL_STATUS, AlState
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.faults_core import FaultRefused
from gatewaylab.rig.runtime import Rig

RIG = """
clock = "simulated"
[[device]]
kind = "ethercat_io"
name = "io-a"
[[device]]
kind = "ethercat_io"
name = "io-b"
serial = 7
[[device]]
kind = "ethercat_io"
name = "io-c"
serial = 8
[ethercat]
interface = "gl-none"
"""


def _master(rig: Rig) -> Master:
    segment = next(p for p in rig.participants if p.name == "ethercat").segment  # type: ignore[attr-defined]
    master = Master(rig.clock, segment)
    master.bring_up()
    return master


def test_unplugged_device_lowers_the_working_counter_and_returns_in_init(tmp_path: Path) -> None:
    """Unplug io-b: the LRW working counter drops by what io-b and io-c (behind it) contributed, a
    read of io-b's AL status gets no answer (WKC 0); replugged, io-b answers again with AL status INIT
    while io-a and io-c stayed in OP (ETG.1000.6 AL state machine: power-on = INIT)."""
    path = tmp_path / "rig.toml"
    path.write_text(RIG)
    with Rig.from_file(path) as rig:
        rig.start()
        m = _master(rig)
        full = m.exchange_process_data()
        assert full == m.expected_wkc and all(m.al_status(i)[0] == AlState.OP for i in range(3))
        answer = rig.faults.ethercat_unplug("io-b")
        assert answer["unreachable"] == ["io-b", "io-c"]
        cut = m.exchange_process_data()
        assert cut < full and cut > 0                    # io-a still answers
        with pytest.raises(WorkingCounterError):
            m.al_status(1)
        assert m.al_status(0)[0] == AlState.OP
        answer = rig.faults.ethercat_replug("io-b")
        assert answer["al_status"] == AlState.INIT
        # powered on: its configured station address is gone (FPRD unanswered), by position
        # (auto-increment) it answers with AL status INIT; io-c behind it kept its state
        with pytest.raises(WorkingCounterError):
            m.al_status(1)
        d = m.port.phys(Command.APRD, -1, REG_AL_STATUS, b"\0\0")
        assert d.wkc == 1 and int.from_bytes(d.data, "little") == AlState.INIT
        assert m.port.phys(Command.BRD, 0, REG_AL_STATUS, b"\0\0").wkc == 3
        assert m.al_status(2)[0] == AlState.OP
        assert m.exchange_process_data() < full          # io-b takes no process data in INIT


def test_unplugging_the_first_device_loses_every_frame(tmp_path: Path) -> None:
    """Nothing is linked to the master's port: frames never come back (the master counts them lost)."""
    path = tmp_path / "rig.toml"
    path.write_text(RIG)
    with Rig.from_file(path) as rig:
        rig.start()
        m = _master(rig)
        rig.faults.ethercat_unplug("io-a")
        assert m.exchange_process_data() == 0
        assert m.lost_frames >= 1
        rig.faults.ethercat_replug("io-a")
        assert m.port.phys(Command.BRD, 0, REG_AL_STATUS, b"\0\0").wkc == 3
        with pytest.raises(FaultRefused):
            rig.faults.ethercat_unplug("nope")
