"""The rig's ``[ethercat]`` segment: the EtherCAT devices of a rig answering on a network interface.

Rig file::

    [ethercat]
    interface = "gl-ecat"  # one end of `gatewaylab net up gl-ecat`; the master uses gl-ecat-m
    pcap = "ecat.pcap"     # optional capture
    cpu = 1                # optional: pin the wire thread
    busy_poll = false      # optional: true polls the socket without ever blocking (burns a CPU)
    max_residence_ms = 2.0 # optional: frames older than this are dropped, never answered late (0: no limit)

Every device participant with ``is_ethercat = True`` and a ``slave`` attribute (an
:class:`~gatewaylab.ethercat.slave.Slave`) joins the segment, in rig-file order (position 0 first).
A simulated-clock rig builds the segment without a wire: drive it with the in-process master.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from gatewaylab.ethercat.residence import DEFAULT_MAX_RESIDENCE_MS
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import WireTransport
from gatewaylab.ethercat.wire_pcap import PcapWriter
from gatewaylab.plugin.capabilities import EthercatDevice, ethercat_devices
from gatewaylab.plugin.participant import DeviceKind, Key, RigContext

SEGMENT_KEYS: dict[str, Key] = {
    "interface": Key(str, required=True, help='one end of `gatewaylab net up NAME`, e.g. interface = "gl-ecat"'),
    "pcap": Key(str),
    "cpu": Key(int, min=0, help="pin the wire thread to this CPU"),
    "busy_poll": Key(bool, False, help="poll the socket without ever blocking (one CPU at 100 per cent)"),
    "max_residence_ms": Key(float, DEFAULT_MAX_RESIDENCE_MS, min=0.0,
                            help="drop a frame older than this (kernel receive time to reply) instead of "
                                 "answering it late; 0: no limit"),
}


class SegmentParticipant:
    """The ``[ethercat]`` section: the line of EtherCAT devices answering on a network interface."""

    name = "ethercat"

    def __init__(self, rig: RigContext, cfg: dict[str, Any], devices: Sequence[EthercatDevice]) -> None:
        cfg = SEGMENT_KIND.validate(cfg, "[ethercat]")
        self.interface: str = cfg["interface"]
        self.rig = rig
        self.devices = list(devices)
        self.segment = Segment([d.slave for d in self.devices])
        self.pcap_path: str | None = cfg["pcap"]
        self.cpu: int | None = cfg["cpu"]
        self.busy_poll: bool = cfg["busy_poll"]
        self.max_residence_ms = float(cfg["max_residence_ms"])
        self.pcap: PcapWriter | None = None
        self.wire: WireTransport | None = None

    def start(self) -> None:
        """In real time, open the wire (and the capture) on the interface."""
        if not self.rig.realtime:
            return
        if self.pcap_path:
            self.pcap = PcapWriter(str(self.pcap_path))
        self.wire = WireTransport(self.segment, self.interface, self.rig.clock, busy_poll=self.busy_poll,
                                  pcap=self.pcap, cpu=self.cpu, max_residence_ms=self.max_residence_ms)
        self.wire.start()

    def stop(self) -> None:
        """Stop the wire thread and close the capture."""
        if self.wire is not None:
            self.wire.stop()
            self.wire = None
        if self.pcap is not None:
            self.pcap.close()
            self.pcap = None

    def wire_stats(self) -> dict[str, int] | None:
        """The wire's counters (frames in, out, dropped late, errors) while it runs, else None."""
        return None if self.wire is None else self.wire.stats()

    def ready_info(self) -> dict[str, Any]:
        """The interface and the slaves in position order, for the --ready-file."""
        return {"ethercat": {"interface": self.interface, "slaves": [
            {"name": s.name, "position": i, "vendor_id": s.desc.vendor_id, "product_code": s.desc.product_code}
            for i, s in enumerate(self.segment.slaves)]}}


def create_segment(rig: RigContext, cfg: dict[str, Any],
                   devices: Sequence[EthercatDevice] | None = None) -> SegmentParticipant:
    """The ``[ethercat]`` participant; without ``devices`` it takes the rig's EtherCAT devices built so far."""
    return SegmentParticipant(rig, cfg, ethercat_devices(rig.participants) if devices is None else devices)


SEGMENT_KIND = DeviceKind("ethercat", create_segment, SEGMENT_KEYS,
                          summary="the EtherCAT segment: the rig's EtherCAT devices on a network interface",
                          table="ethercat", single=True)
