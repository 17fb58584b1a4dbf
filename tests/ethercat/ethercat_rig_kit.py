"""In-process rigs of every EtherCAT device kind on a simulated clock, and the master's normal
re-initialisation of a line (issue 21: storms and SyncManagers over the registers).

``kind_rig(tmp_path, kinds)`` writes a rig file with one ``[[device]]`` per entry of ``kinds`` (one CAN
bus for the gateways) and an ``[ethercat]`` segment, and returns the started rig and its segment.
``reinitialise(clock, segment)`` is what a master does to a line it finds in an unknown state
(KickCAT ``Bus::resetSlaves`` + ``init``, IgH's slave configuration): every FMMU and SyncManager
cleared, DC SYNC activation off, watchdog divider and times set, INIT with error acknowledge, then
the bring-up to OP.
"""

from __future__ import annotations

import struct
from pathlib import Path

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.ethercat.datagram import Command, Datagram
from gatewaylab.ethercat.esc import REG_DC_ACTIVATION, REG_WD_DIVIDER, REG_WD_TIME_PDI, REG_WD_TIME_SM
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.runtime import Rig

KINDS = ("ecanlite", "esd_can_ethercat", "ethercat_drive", "ethercat_io")
_EXTRA = {"ecanlite": 'channels = ["can0"]\n', "esd_can_ethercat": 'bus = "can0"\n'}


def rig_text(kinds: tuple[str, ...] | list[str], interface: str = "gl-none", clock: str = "simulated") -> str:
    """A rig file: one CAN bus, the devices in order (names ``{kind}{i}``), the [ethercat] segment."""
    out = [f'clock = "{clock}"', "[[bus]]", 'name = "can0"', "bitrate = 500000"]
    for i, kind in enumerate(kinds):
        out += ["[[device]]", f'kind = "{kind}"', f'name = "{kind}{i}"', f"serial = {100 + i}",
                _EXTRA.get(kind, "")]
    out += ["[ethercat]", f'interface = "{interface}"', ""]
    return "\n".join(out)


def kind_rig(tmp_path: Path, kinds: tuple[str, ...] | list[str]) -> tuple[Rig, SimulatedClock, Segment]:
    """A started simulated-clock rig with ``kinds`` on its segment (end it with ``rig.close()``)."""
    path = tmp_path / "rig.toml"
    path.write_text(rig_text(kinds))
    rig = Rig.from_file(path)
    rig.start()
    segment = next(p for p in rig.participants if getattr(p, "name", "") == "ethercat").segment  # type: ignore[attr-defined]
    assert isinstance(rig.clock, SimulatedClock)
    return rig, rig.clock, segment


def reinitialise(clock: SimulatedClock, segment: Segment, cycles: int = 20) -> Master:
    """The normal re-initialisation of a line (INIT + SM/FMMU reset + bring-up), then ``cycles`` process
    data cycles 1 ms apart, each with the expected working counter; returns the master."""
    m = Master(clock, segment)
    reset = [Datagram.physical(Command.BWR, 0, 0, REG_DC_ACTIVATION, b"\0"),
             Datagram.physical(Command.BWR, 0, 0, REG_WD_DIVIDER, struct.pack("<H", 2498)),  # 100 us ticks
             Datagram.physical(Command.BWR, 0, 0, REG_WD_TIME_PDI, struct.pack("<H", 1000)),
             Datagram.physical(Command.BWR, 0, 0, REG_WD_TIME_SM, struct.pack("<H", 1000))]  # 100 ms
    m.exchange(reset)
    m.bring_up(ack_errors=True)
    for i in range(cycles):
        clock.advance(0.001)
        wkc = m.exchange_process_data()
        assert wkc == m.expected_wkc, f"cycle {i}: wkc {wkc} != {m.expected_wkc}"
    return m
