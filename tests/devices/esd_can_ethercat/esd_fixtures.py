"""Fixtures of the esd CAN-EtherCAT device and host tests (their conftests import them): one gateway on a
500 kbit/s virtual bus with a peer node, driven by the in-process master on a simulated clock
(:class:`EsdKit` speaks the MDP 5000 counter handshake the way master code does, shared note
'esd-mdp5000-queues'); and a veth pair in a test-made network namespace for pysoem (driver script
``esd_soem_driver.py``)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from wire_kit import net_capable, veth_namespace

from gatewaylab.bus import Controller, VirtualBus
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.esd_can_ethercat.codec import (
    IN_HEADER,
    OUT_HEADER,
    RX_SIZE,
    TX_SIZE,
    decode_rx11,
    decode_rx29,
    encode_tx11,
    encode_tx29,
)
from gatewaylab.devices.esd_can_ethercat.device import EsdGateway, create_esd_gateway
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master

DRIVER = Path(__file__).with_name("esd_soem_driver.py")
BITRATE = 500_000
CYCLE = 0.001


class EsdKit:
    """The gateway, its bus with a peer node, and a master that speaks the counter handshake."""

    def __init__(self, clock: SimulatedClock, bus: VirtualBus, gw: EsdGateway, master: Master,
                 peer: Controller, heard: list[CanFrame]) -> None:
        self.clock = clock
        self.bus = bus
        self.gw = gw
        self.master = master
        self.peer = peer
        self.heard = heard          # frames the peer received from the bus
        self.tx_counter = 0
        self.rx_counter = 0
        self.extended = False

    # -- states
    def preop(self) -> None:
        self.master.request_state(0, AlState.PREOP)

    def op(self, baud_index: int | None = 2) -> None:
        """PREOP, optional 0xF800:02, map (reading the mapping by SDO), SAFEOP, OP (4.3)."""
        if self.gw.slave.state != AlState.PREOP:
            self.preop()
        if baud_index is not None:
            self.master.sdo_download8(0, 0xF800, 2, baud_index)
        self.extended = bool(self.master.sdo_upload16(0, 0x8000, 0x20) & 1)
        self.master.config_map()
        self.master.set_state(AlState.SAFEOP)
        self.master.exchange_process_data()
        self.master.set_state(AlState.OP)
        self.tx_counter = self.rx_counter = 0

    # -- process data
    def cycle(self, n: int = 1) -> None:
        """n EtherCAT cycles of 1 ms with the CAN bus running in between."""
        for _ in range(n):
            self.master.exchange_process_data()
            self.clock.advance(CYCLE)

    def inputs(self) -> tuple[int, int, int, int]:
        """(Tx counter, Rx counter, Number of Rx messages, Tx transaction number) as the master sees them."""
        return IN_HEADER.unpack(self.master.pdo_read(0, 0, IN_HEADER.size))

    def write_batch(self, frames: list[CanFrame], first_tn: int = 1, counter: int | None = None) -> None:
        """Tx messages, NumTx and a new output Tx counter into the outputs (5.1.5.3)."""
        encode = encode_tx29 if self.extended else encode_tx11
        body = b"".join(encode(first_tn + i, f) for i, f in enumerate(frames))
        self.tx_counter = (self.tx_counter + 1) & 0xFFFF if counter is None else counter
        self.master.pdo_write(0, 0, OUT_HEADER.pack(self.tx_counter, self.rx_counter, len(frames)) + body)

    def send(self, frames: list[CanFrame], first_tn: int = 1, max_cycles: int = 20) -> int:
        """A batch: written when the counters are equal, then cycles until the gateway acknowledged
        it (input Tx counter == output Tx counter); returns the cycles that took."""
        assert self.inputs()[0] == self.tx_counter, "previous batch not acknowledged"
        self.write_batch(frames, first_tn)
        for n in range(1, max_cycles + 1):
            self.cycle()
            if self.inputs()[0] == self.tx_counter:
                return n
        raise AssertionError("the gateway did not acknowledge the Tx batch")

    def receive(self, max_cycles: int = 20) -> list[CanFrame]:
        """One Rx batch: wait for a new input Rx counter, read NumRx messages, acknowledge (5.1.5.1)."""
        for _ in range(max_cycles):
            self.cycle()
            _tx, rx, num, _tn = self.inputs()
            if rx != self.rx_counter:
                size = RX_SIZE[self.extended]
                raw = self.master.pdo_read(0, IN_HEADER.size, num * size)
                decode = decode_rx29 if self.extended else decode_rx11
                frames = [decode(raw, i * size) for i in range(num)]
                self.rx_counter = rx
                self.master.pdo_write(0, 2, self.rx_counter.to_bytes(2, "little"))
                return frames
        return []

    def receive_all(self, max_batches: int = 100) -> list[CanFrame]:
        out: list[CanFrame] = []
        for _ in range(max_batches):
            got = self.receive(max_cycles=5)
            if not got:
                break
            out += got
        return out

    @property
    def out_size(self) -> int:
        return self.master.slaves[0].output_bytes

    @property
    def in_size(self) -> int:
        return self.master.slaves[0].input_bytes

    def tx_message_size(self) -> int:
        return TX_SIZE[self.extended]


@pytest.fixture
def clock() -> SimulatedClock:
    return SimulatedClock()


def make_kit(clock: SimulatedClock | None = None, bitrate: int = BITRATE) -> EsdKit:
    """A gateway ("esd1", serial 0x1234) and a peer on a bus, the master scanned (INIT)."""
    clock = clock or SimulatedClock()
    bus = VirtualBus(clock, "can0", bitrate=bitrate)
    gw = create_esd_gateway(clock, bus, "esd1", serial=0x1234, update_duration=3.0)
    heard: list[CanFrame] = []
    peer = bus.attach("peer", on_frame=lambda f, t: heard.append(f))
    master = Master(clock, Segment([gw.slave]))
    master.scan()
    return EsdKit(clock, bus, gw, master, peer, heard)


@pytest.fixture
def kit(clock: SimulatedClock) -> EsdKit:
    return make_kit(clock)


@pytest.fixture
def kit_factory() -> Callable[..., EsdKit]:
    """Fresh kits inside one test (hypothesis examples)."""
    return make_kit


# ---------------------------------------------------------------------------------- veth + pysoem
def _net_capable() -> str | None:
    """None when we may create namespaces and raw sockets, else the reason to skip (tests/wire_kit.py)."""
    return net_capable()


@dataclass(frozen=True)
class EsdVeth:
    """Emulator end here, master end inside ``namespace``."""

    namespace: str
    emulator_iface: str
    master_iface: str

    def run_master(self, *args: str, timeout: float = 180.0) -> subprocess.CompletedProcess[str]:
        return subprocess.run(["ip", "netns", "exec", self.namespace, sys.executable, str(DRIVER),
                               self.master_iface, *args], capture_output=True, text=True, timeout=timeout,
                              check=False)


@pytest.fixture(scope="module")
def esd_veth() -> Iterator[EsdVeth]:
    reason = _net_capable()
    if reason is not None:
        pytest.skip(reason)
    with veth_namespace("gl-esd-", "gle") as (ns, emu, mst):
        yield EsdVeth(ns, emu, mst)
