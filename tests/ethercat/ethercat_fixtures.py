"""Fixtures of the EtherCAT tests: simulated segments of ``ethercat_io`` slaves, and a veth pair inside a
network namespace the test creates and deletes (for SOEM through pysoem). The conftests of tests/ethercat
and tests/hosts/ethercat import them."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from wire_kit import net_capable, veth_namespace

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ethercat_io.device import VENDOR_ID, create_io_slave
from gatewaylab.ethercat.description import DeviceDescription, ObjectDef, Pdo, PdoEntry
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.od import Access, DataType

DRIVER = Path(__file__).with_name("ethercat_soem_driver.py")


@pytest.fixture
def clock() -> SimulatedClock:
    return SimulatedClock()


def make_segment(clock: SimulatedClock, n: int = 3) -> Segment:
    """n I/O slaves with distinct names and revisions (SOEM copies SII info of identical neighbours)."""
    return Segment([create_io_slave(clock, f"GL-IO #{i}", serial=1000 + i, revision=i + 1) for i in range(n)])


@pytest.fixture
def segment(clock: SimulatedClock) -> Segment:
    return make_segment(clock)


@pytest.fixture
def master(clock: SimulatedClock, segment: Segment) -> Master:
    m = Master(clock, segment)
    m.scan()
    return m


@pytest.fixture
def chunked_description() -> DeviceDescription:
    """ECAN-Lite-like layout (ECAN-Lite manual 5.x): 24 RxPDO / TxPDO chunk maps 0x1600..0x1617 /
    0x1A00..0x1A17 of 8 x 16-byte entries (0x7000 + c*0x80 + u*0x10 / 0x6000 + ...), first 2 assigned."""

    def chunk(base: int, map_index: int, c: int, access: Access) -> tuple[Pdo, list[ObjectDef]]:
        entries = tuple(PdoEntry(base + c * 0x80 + u * 0x10, 1, 128, f"Chunk {c} unit {u}", DataType.OCTET_STRING)
                        for u in range(8))
        objs = [ObjectDef(e.index, e.name, subs=((e.name, DataType.OCTET_STRING, bytes(16), access),),
                          pdo_mappable=True) for e in entries]
        return Pdo(map_index + c, f"Chunk {c}", entries), objs

    rx = [chunk(0x7000, 0x1600, c, Access.RWW) for c in range(24)]
    tx = [chunk(0x6000, 0x1A00, c, Access.RO) for c in range(24)]
    return DeviceDescription(
        name="chunked", vendor_id=VENDOR_ID, product_code=0x00030001, outputs_start=0x1100, inputs_start=0x1D00,
        rx_pdos=tuple(p for p, _ in rx), tx_pdos=tuple(p for p, _ in tx),
        rx_assign=(0x1600, 0x1601), tx_assign=(0x1A00, 0x1A01),
        objects=tuple(o for _, objs in rx + tx for o in objs))


def _net_capable() -> str | None:
    """None when we may create namespaces and raw sockets, else the reason to skip (tests/wire_kit.py)."""
    return net_capable()


@dataclass(frozen=True)
class VethNs:
    """Emulator end in this namespace, master end inside ``namespace``."""

    namespace: str
    emulator_iface: str
    master_iface: str

    def run_master(self, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
        return subprocess.run(["ip", "netns", "exec", self.namespace, sys.executable, str(DRIVER),
                               self.master_iface, *args], capture_output=True, text=True, timeout=timeout,
                              check=False)


@pytest.fixture(scope="module")
def veth_ns() -> Iterator[VethNs]:
    reason = _net_capable()
    if reason is not None:
        pytest.skip(reason)
    with veth_namespace("gl-test-", "glt") as (ns, emu, mst):
        yield VethNs(ns, emu, mst)
