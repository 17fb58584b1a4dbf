"""Helpers of the ECAN-Lite device tests (imported by name: every test folder has a ``conftest``):
four CAN FD buses on a simulated clock, the device on them, an in-process master, the bring-up of
manual 5.4.3, and a veth pair in a namespace for pysoem."""

from __future__ import annotations

import contextlib
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import wire_kit
from wire_kit import veth_namespace

from gatewaylab.bus import VirtualBus
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ecanlite.device import EcanLiteDevice
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master

#: The period of the in-process master's process data cycle.
CYCLE = 0.001


@dataclass
class Rig:
    """A device on four buses and a master that has scanned it (still in INIT)."""

    clock: SimulatedClock
    buses: list[VirtualBus]
    device: EcanLiteDevice
    master: Master

    def cycle(self, n: int = 1) -> int:
        """``n`` process data cycles of :data:`CYCLE`; the last working counter."""
        wkc = 0
        for _ in range(n):
            wkc = self.master.exchange_process_data()
            self.clock.advance(CYCLE)
        return wkc


def bring_up(rig: Rig, n: int = 8, tx_mask: int = 0x0F, rx_mask: int = 0x0F, tx_options: int = 0,
             rx_options: int = 0, tx_profile: int = 0, rx_profile: int = 0, budget: int = 0) -> None:
    """Manual 5.4.3 phases B-D, then SAFEOP and OP (phases A and E are the tests' business)."""
    m = rig.master
    m.set_state(AlState.PREOP)
    for assign, base in ((0x1C12, 0x1600), (0x1C13, 0x1A00)):          # phase B
        m.sdo_download8(0, assign, 0, 0)
        for i in range(n):
            m.sdo_download16(0, assign, i + 1, base + i)
        m.sdo_download8(0, assign, 0, n)
    for index, mask, options, profile in ((0x8010, tx_mask, tx_options, tx_profile),   # phase C
                                          (0x8011, rx_mask, rx_options, rx_profile)):
        m.sdo_download8(0, index, 3, n)
        m.sdo_download8(0, index, 4, mask)
        m.sdo_download8(0, index, 5, profile)
        m.sdo_download8(0, index, 6, budget)
        m.sdo_download8(0, index, 7, options)
        m.sdo_download8(0, index, 1, 1)
    for index in (0x8010, 0x8011):                                        # phase D
        assert m.sdo_upload8(0, index, 2) == 0
        assert m.sdo_upload16(0, index, 9) == 128 * n
    configure_channels(rig)                                               # phase E
    m.config_map()
    m.set_state(AlState.SAFEOP)
    m.exchange_process_data()
    m.set_state(AlState.OP)


def configure_channels(rig: Rig) -> None:
    """5.4.3 phase E for every connected channel: automatic bit timing at the bus's rates, CAN FD
    when the bus has a data rate, apply, status 0."""
    m = rig.master
    for k, bus in enumerate(rig.buses):
        index = 0x8001 + k
        fd = bus.data_bitrate is not None
        m.sdo_download8(0, index, 7, 0)
        m.sdo_download8(0, index, 15, 1 if fd else 0)
        m.sdo_download32(0, index, 19, bus.bitrate)
        if fd:
            m.sdo_download32(0, index, 20, bus.data_bitrate or 0)
        m.sdo_download8(0, index, 1, 1)
        assert m.sdo_upload8(0, index, 2) == 0, f"MCAN{k} apply status"


def make_rig(tmp_path: Path, n_buses: int = 4, fd: bool = True) -> Rig:
    clock = SimulatedClock()
    buses = [VirtualBus(clock, f"can{i}", 1_000_000, 5_000_000 if fd else None) for i in range(n_buses)]
    controllers = [b.attach(f"ecan.mcan{i}") for i, b in enumerate(buses)]
    device = EcanLiteDevice(clock, controllers, flash_path=tmp_path / "ecan.flash")
    master = Master(clock, Segment([device.slave]))
    master.scan()
    return Rig(clock, buses, device, master)




# ---------------------------------------------------------------------------------------- veth + pysoem
DRIVER = Path(__file__).with_name("ecanlite_soem_driver.py")


def net_capable() -> str | None:
    """None when we may create namespaces and raw sockets, else the reason to skip (tests/wire_kit.py)."""
    return wire_kit.net_capable("pysoem")


@dataclass(frozen=True)
class VethNs:
    """Emulator end in this namespace, master end inside ``namespace`` (as tests/ethercat)."""

    namespace: str
    emulator_iface: str
    master_iface: str

    def run_master(self, *args: str, timeout: float = 300.0) -> subprocess.CompletedProcess[str]:
        return subprocess.run(["ip", "netns", "exec", self.namespace, sys.executable, str(DRIVER),
                               self.master_iface, *args], capture_output=True, text=True, timeout=timeout,
                              check=False)


@contextlib.contextmanager
def veth_pair() -> Iterator[VethNs]:
    with veth_namespace("gl-ecan-", "gle") as (ns, emu, mst):
        yield VethNs(ns, emu, mst)
