"""Rig participants: the ``ethercat_io`` device and the ``[ethercat]`` segment on a network interface.

Rig file::

    [[device]]
    kind = "ethercat_io"
    name = "io1"           # optional; serial = 1, revision = 1 optional
    [ethercat]
    interface = "gl-ecat"  # one end of `gatewaylab net up gl-ecat`; the master uses gl-ecat-m
    pcap = "ecat.pcap"     # optional capture
    cpu = 1                # optional: pin the busy-polling wire thread

Every device participant with ``is_ethercat = True`` and a ``slave`` attribute (an
:class:`~gatewaylab.ethercat.slave.Slave`) joins the segment, in rig-file order (position 0 first).
A simulated-clock rig builds the segment without a wire: drive it with the in-process master.
"""

from __future__ import annotations

from typing import Any, Protocol

from ..common.errors import ConfigError
from .io_device import create_io_slave
from .segment import Segment
from .slave import Slave
from .wire import WireTransport
from .wire_pcap import PcapWriter


class EtherCATDevice(Protocol):
    """What a device participant offers the segment (ECAN-Lite and esd CAN-EtherCAT do the same)."""

    name: str
    is_ethercat: bool
    slave: Slave


class IoDevice:
    """``[[device]] kind = "ethercat_io"``: the generic loop-back I/O slave."""

    is_ethercat = True

    def __init__(self, rig: Any, cfg: dict[str, Any]) -> None:
        self.name = str(cfg.get("name", "ethercat_io"))
        serial = cfg.get("serial", 0)
        revision = cfg.get("revision", 1)
        if not isinstance(serial, int) or not isinstance(revision, int):
            raise ConfigError(f"[[device]] {self.name}: serial and revision must be integers")
        self.slave = create_io_slave(rig.clock, self.name, serial=serial, revision=revision)

    def start(self) -> None:
        """Nothing to open: the segment owns the wire."""

    def stop(self) -> None:
        """Nothing to release."""

    def ready_info(self) -> dict[str, Any]:
        return {}


def create_io_device(rig: Any, cfg: dict[str, Any]) -> IoDevice:
    return IoDevice(rig, cfg)


class SegmentParticipant:
    """The ``[ethercat]`` section: the line of EtherCAT devices answering on a network interface."""

    name = "ethercat"

    def __init__(self, rig: Any, cfg: dict[str, Any], devices: list[Any]) -> None:
        interface = cfg.get("interface")
        if not isinstance(interface, str) or not interface:
            raise ConfigError('[ethercat] needs interface = "NAME" (create one with `gatewaylab net up NAME`)')
        unknown = set(cfg) - {"interface", "pcap", "cpu", "busy_poll"}
        if unknown:
            raise ConfigError(f"[ethercat]: unknown keys {sorted(unknown)}")
        self.interface = interface
        self.rig = rig
        self.devices = list(devices)
        self.segment = Segment([d.slave for d in self.devices])
        self.pcap_path = cfg.get("pcap")
        cpu = cfg.get("cpu")
        self.cpu = cpu if isinstance(cpu, int) else None
        self.busy_poll = bool(cfg.get("busy_poll", True))
        self.pcap: PcapWriter | None = None
        self.wire: WireTransport | None = None

    def start(self) -> None:
        if not self.rig.realtime:
            return
        if self.pcap_path:
            self.pcap = PcapWriter(str(self.pcap_path))
        self.wire = WireTransport(self.segment, self.interface, self.rig.clock, busy_poll=self.busy_poll,
                                  pcap=self.pcap, cpu=self.cpu)
        self.wire.start()

    def stop(self) -> None:
        if self.wire is not None:
            self.wire.stop()
            self.wire = None
        if self.pcap is not None:
            self.pcap.close()
            self.pcap = None

    def ready_info(self) -> dict[str, Any]:
        return {"ethercat": {"interface": self.interface, "slaves": [
            {"name": s.name, "position": i, "vendor_id": s.desc.vendor_id, "product_code": s.desc.product_code}
            for i, s in enumerate(self.segment.slaves)]}}


def create_segment(rig: Any, cfg: dict[str, Any], devices: list[Any]) -> SegmentParticipant:
    return SegmentParticipant(rig, cfg, devices)
