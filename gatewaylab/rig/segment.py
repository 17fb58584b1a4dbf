"""The rig's ``[ethercat]`` segment: the EtherCAT devices of a rig answering on a network interface.

Rig file::

    [ethercat]
    interface = "gl-ecat"  # one end of `gatewaylab net up gl-ecat`; the master uses gl-ecat-m
    pcap = "ecat.pcap"     # optional capture
    cpu = 1                # optional: pin the wire thread
    busy_poll = false      # optional: true polls the socket without ever blocking (burns a CPU)
    max_residence_ms = 2.0 # optional: frames older than this are dropped, never answered late (0: no limit)
    realtime = true        # optional: SCHED_FIFO for the wire thread and the rig's loop (root or CAP_SYS_NICE)
    switch_interval_us = 200  # the interpreter's thread switch interval while the wire runs (0: leave it)
    cable_m = 1.0          # optional: length of every cable (DC propagation delays, about 5 ns per metre)
    cables_m = "io2=20"    # optional: other lengths of the cables into some devices (NAME=METRES ...)
    redundant = "gl-ecat2" # optional: cable redundancy, the end cabled to the last slave's port 1 (a ring)
    hot_connect = "io2, io4"  # optional: heads of hot-connect groups (a head and the devices after it, up to the
                              # next head, are unplugged and plugged together: ec-hot-unplug / ec-hot-plug)
    eni = "machine.xml"    # optional: the segment an ENI describes, in its <Slave> order
    esi = ["esi/"]         # optional: ESI files or folders for the ENI's slaves (else built from the ENI alone)

Every device participant with ``is_ethercat = True`` and a ``slave`` attribute (an
:class:`~gatewaylab.ethercat.slave.Slave`) joins the segment, in rig-file order (position 0 first).
A simulated-clock rig builds the segment without a wire: drive it with the in-process master.
"""

from __future__ import annotations

import logging
import sys
import threading
from collections.abc import Sequence
from typing import Any

from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.esc_dc_clock import DEFAULT_CABLE_M
from gatewaylab.ethercat.residence import DEFAULT_MAX_RESIDENCE_MS
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire import REALTIME_PRIORITY, WireTransport, make_ordinary, make_realtime
from gatewaylab.ethercat.wire_pcap import PcapWriter
from gatewaylab.plugin.capabilities import EthercatDevice, ethercat_devices
from gatewaylab.plugin.participant import DeviceKind, Key, RigContext
from gatewaylab.rig.eni import EniSegment, build_eni_segment

__all__ = [
    "LOOP_PRIORITY",
    "SEGMENT_KEYS",
    "SEGMENT_KIND",
    "SWITCH_INTERVAL_US",
    "SegmentParticipant",
    "create_segment",
    "hot_connect_groups",
]


_log = logging.getLogger(__name__)
#: The interpreter's thread switch interval while a wire runs (docs/decisions.md: the latency tail).
SWITCH_INTERVAL_US = 200.0
#: ``realtime``: the SCHED_FIFO priority of the rig's loop thread (the thread that starts the participants
#: and runs the clock: CAN buses, drives), below the wire thread's: the wire waits for the interpreter lock
#: and ``clock.lock`` whenever the loop holds them, and an ordinary loop thread preempted by other processes
#: while holding them made the wire's replies late (docs/decisions.md: the numbers).
LOOP_PRIORITY = 5

SEGMENT_KEYS: dict[str, Key] = {
    "interface": Key(str, required=True, help='one end of `gatewaylab net up NAME`, e.g. interface = "gl-ecat"'),
    "pcap": Key(str),
    "cpu": Key(int, min=0, help="pin the wire thread to this CPU"),
    "busy_poll": Key(bool, False, help="poll the socket without ever blocking (one CPU at 100 per cent)"),
    "max_residence_ms": Key(float, DEFAULT_MAX_RESIDENCE_MS, min=0.0,
                            help="drop a frame older than this (kernel receive time to reply) instead of "
                                 "answering it late; 0: no limit"),
    "realtime": Key(bool, True, help="run the wire thread and the rig's loop SCHED_FIFO (root or CAP_SYS_NICE; "
                                     "one log line when not allowed)"),
    "switch_interval_us": Key(float, SWITCH_INTERVAL_US, min=0.0, max=5000.0,
                              help="the interpreter's thread switch interval while the wire runs; 0 leaves it"),
    "cable_m": Key(float, DEFAULT_CABLE_M, min=0.0, max=100.0,
                   help="length of every cable in metres (DC propagation delays: about 5 ns per metre)"),
    "cables_m": Key(str, help='lengths of the cables into some devices, e.g. cables_m = "io2=20 io3=0.5"'),
    "redundant": Key(str, help='cable redundancy: the second interface, cabled to the last slave\'s port 1, e.g. '
                               'redundant = "gl-ecat2"'),
    "hot_connect": Key(str, help='the heads of hot-connect groups, comma-separated device names, e.g. '
                                 'hot_connect = "io2, io4"'),
    "eni": Key(str, help="an ENI file (relative to the rig file's folder): the segment in its <Slave> order"),
    "esi": Key(list, help='ESI files or folders for the ENI\'s slaves, e.g. esi = ["esi/"]'),
}


class SegmentParticipant:
    """The ``[ethercat]`` section: the line of EtherCAT devices answering on a network interface."""

    name = "ethercat"

    def __init__(self, rig: RigContext, cfg: dict[str, Any], devices: Sequence[EthercatDevice]) -> None:
        cfg = SEGMENT_KIND.validate(cfg, "[ethercat]")
        self.interface: str = cfg["interface"]
        self.rig = rig
        self.devices = list(devices)
        self.eni: EniSegment | None = None
        if cfg["eni"] is not None:
            self.eni = build_eni_segment(rig, cfg["eni"], cfg["esi"], self.devices)
            self.devices = self.eni.devices
        elif cfg["esi"] is not None:
            raise ConfigError("[ethercat] esi = [...] names the ESI files of an ENI's slaves: give eni = \"PATH\" "
                              "too (a single ESI device is a [[device]] kind = \"esi\")")
        slaves = self.eni.slaves if self.eni is not None else [d.slave for d in self.devices]
        names = [o.name for o in self.eni.origins] if self.eni is not None else [d.name for d in self.devices]
        cables = _cables(cfg["cables_m"], names)
        for name, slave in zip(names, slaves, strict=True):
            slave.esc.clocks.cable_m = cables.get(name, float(cfg["cable_m"]))
        self.segment = Segment(slaves)
        #: cable redundancy: the interface cabled to the last slave's port 1, or None (a line)
        self.redundant: str | None = cfg["redundant"]
        if self.redundant is not None:
            self.segment.set_redundant(True)
        #: hot-connect groups: the head's name -> the positions of the group (the head and the devices after it,
        #: up to the next head)
        self.hot_groups: dict[str, list[int]] = hot_connect_groups(cfg["hot_connect"], names)
        self.pcap_path: str | None = cfg["pcap"]
        self.cpu: int | None = cfg["cpu"]
        self.busy_poll: bool = cfg["busy_poll"]
        self.max_residence_ms = float(cfg["max_residence_ms"])
        self.realtime: bool = cfg["realtime"]
        self.switch_interval_s = float(cfg["switch_interval_us"]) / 1e6
        self._switch_restore: tuple[float, float] | None = None   # (ours, the one before)
        self._loop_tid: int | None = None                          # the loop thread made real-time
        self.pcap: PcapWriter | None = None
        self.wire: WireTransport | None = None

    def start(self) -> None:
        """In real time, open the wire (and the capture) on the interface."""
        if not self.rig.realtime:
            return
        if self.pcap_path:
            self.pcap = PcapWriter(str(self.pcap_path))
        self.wire = WireTransport(self.segment, self.interface, self.rig.clock, busy_poll=self.busy_poll,
                                  pcap=self.pcap, cpu=self.cpu, max_residence_ms=self.max_residence_ms,
                                  realtime=self.realtime, redundant=self.redundant)
        if self.switch_interval_s > 0:
            # the wire thread waits for the interpreter lock while the rig's loop runs Python (CAN buses,
            # drives): at most one switch interval (5 ms by default) each time
            before = sys.getswitchinterval()
            sys.setswitchinterval(self.switch_interval_s)
            self._switch_restore = (sys.getswitchinterval(), before)
        if self.realtime and not self.busy_poll:
            self.rig.clock.call_soon(self._loop_realtime)   # the first event the rig's loop thread runs
        self.wire.start()

    def _loop_realtime(self) -> None:
        """SCHED_FIFO ``LOOP_PRIORITY`` for the calling thread (the rig's loop, which runs the clock's events),
        or one line saying why not."""
        if self.wire is None or self._loop_tid is not None:     # stopped meanwhile, or done
            return
        why = make_realtime(LOOP_PRIORITY)
        if why is None:
            self._loop_tid = threading.get_native_id()
            _log.info("[ethercat] realtime: the rig's loop thread runs SCHED_FIFO priority %d (the wire thread %d)",
                      LOOP_PRIORITY, REALTIME_PRIORITY)
        else:
            _log.warning("[ethercat] realtime = true, but this process may not use SCHED_FIFO (%s; it needs root or "
                         "CAP_SYS_NICE): the rig runs with ordinary priority, and EtherCAT replies may come late on "
                         "a loaded machine", why)

    def stop(self) -> None:
        """Stop the wire thread and close the capture."""
        if self.wire is not None:
            self.wire.stop()
            self.wire = None
        if self._loop_tid is not None:
            make_ordinary(self._loop_tid)
            self._loop_tid = None
        if self._switch_restore is not None:
            ours, before = self._switch_restore
            if sys.getswitchinterval() == ours:     # nobody changed it since
                sys.setswitchinterval(before)
            self._switch_restore = None
        if self.pcap is not None:
            self.pcap.close()
            self.pcap = None

    def wire_stats(self) -> dict[str, int] | None:
        """The wire's counters (frames in, out, dropped late, errors) while it runs, else None."""
        return None if self.wire is None else self.wire.stats()

    def ready_info(self) -> dict[str, Any]:
        """The interface and the slaves in position order, for the --ready-file."""
        info: dict[str, Any] = {"ethercat": {"interface": self.interface, "redundant": self.redundant, "slaves": [
            {"name": s.name, "position": i, "vendor_id": s.desc.vendor_id, "product_code": s.desc.product_code}
            for i, s in enumerate(self.segment.slaves)]}}
        if self.eni is not None:
            info["eni"] = self.eni.info()
        return info


def _cables(text: str | None, names: list[str]) -> dict[str, float]:
    """``cables_m``: "NAME=METRES ..." (spaces or commas between) -> {device name: metres}."""
    out: dict[str, float] = {}
    for item in (text or "").replace(",", " ").split():
        name, eq, value = item.partition("=")
        try:
            metres = float(value)
        except ValueError:
            metres = -1.0
        if not eq or not 0.0 <= metres <= 100.0:
            raise ConfigError(f"[ethercat]: cables_m item {item!r} is not NAME=METRES (0..100)")
        if name not in names:
            raise ConfigError(f"[ethercat]: cables_m names {name!r}, not an EtherCAT device of this rig "
                              f"({', '.join(names)})")
        out[name] = metres
    return out


def hot_connect_groups(heads: str | None, names: list[str]) -> dict[str, list[int]]:
    """The hot-connect groups of ``[ethercat] hot_connect`` (comma-separated heads) over the devices ``names`` in
    position order: head -> positions (the head and the devices after it up to the next head)."""
    if not heads:
        return {}
    wanted = [h.strip() for h in heads.split(",") if h.strip()]
    for head in wanted:
        if head not in names:
            raise ConfigError(f"[ethercat] hot_connect: {head!r} is not an EtherCAT device of this rig "
                              f"(devices: {', '.join(names)})")
    starts = sorted(names.index(h) for h in set(wanted))
    ends = [*starts[1:], len(names)]
    return {names[a]: list(range(a, b)) for a, b in zip(starts, ends, strict=True)}


def create_segment(rig: RigContext, cfg: dict[str, Any],
                   devices: Sequence[EthercatDevice] | None = None) -> SegmentParticipant:
    """The ``[ethercat]`` participant; without ``devices`` it takes the rig's EtherCAT devices built so far."""
    return SegmentParticipant(rig, cfg, ethercat_devices(rig.participants) if devices is None else devices)


SEGMENT_KIND = DeviceKind("ethercat", create_segment, SEGMENT_KEYS,
                          summary="the EtherCAT segment: the rig's EtherCAT devices on a network interface",
                          table="ethercat", single=True)
