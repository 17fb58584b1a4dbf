"""The esd host library in process, where the emulator side can be poked: bus off, a lost working
counter, a lying or slow SDO answer, a foreign slave, the cyclic mode of python-can, two gateways on
one master, autobaud and no baud rate set in PREOP (manual 4.2, 5.1.3-5.1.5; note 'esd-mdp5000-queues')."""

from __future__ import annotations

import pytest
from esd_host_scenarios import echo_of, make_can_side, receive_n, run_inprocess

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import ConfigError, LocalError
from gatewaylab.devices.esd_can_ethercat.device import EsdGateway, create_esd_gateway
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.esd_can_ethercat import BitRate, CanStatus, EsdHost, ReadbackError, TxQueueFull
from gatewaylab.hosts.ethercat.backend import MasterTimeout
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.hosts.ethercat.master import Master


def _kit(chatter: bool = False) -> tuple[SimulatedClock, VirtualBus, EsdGateway, InProcessBackend]:
    clock = SimulatedClock()
    bus, gw, _heard = make_can_side(clock, chatter)
    return clock, bus, gw, InProcessBackend(Master(clock, Segment([gw.slave])))


def test_send_returns_on_the_tx_counter_before_the_frames_are_on_the_bus() -> None:
    """5.1.5.3 'Tx Counter Gateway ... the CAN Tx messages were copied' vs 5.1.5.1 'Tx Transaction
    Number ... last sent': on the simulated clock send() of 16 frames returns one cycle after
    writing, while the bus needs about 3 ms for them; completion comes later."""
    result, _heard = run_inprocess("transaction_numbers")
    assert result["completed_at_send_return"] is False


def test_bus_off_shows_in_status_and_status_pdo() -> None:
    """5.1.5.8 'Bus OFF (Read from CAN controller status byte)', 'Tx error counter'; 5.1.3.9: the
    same through 0x1A85 every cycle; after the recovery both read clear again."""
    clock, bus, gw, b = _kit()
    host = EsdHost(b)
    host.configure(status_pdo=True)
    host.start()
    assert gw.controller is not None
    bus.force_bus_off(gw.controller)
    host.cycle()
    status = host.status()
    assert status.bus_off and status.warning_limit and status.tx_errors == 255
    pdo = host.pdo_status()
    assert pdo is not None and pdo.bus_off and pdo.tx_errors == 255
    for _ in range(10):                                   # 128 x 11 recessive bits
        host.cycle()
        clock.wait(0.001)
    assert host.pdo_status() == CanStatus() and host.status() == CanStatus()


def test_wrong_working_counter_leaves_the_inputs_unused() -> None:
    """A cycle whose working counter is short brought no valid inputs: the handshake does not move
    (no batch counted accepted), the error is counted; frames stay queued."""
    _clock, _bus, _gw, b = _kit()
    host = EsdHost(b)
    host.configure()
    host.start()
    tn = host.queue([CanFrame(0x100, b"x")])[0]
    b.master.fpwr(b.master.slave(0).station, 0x0600, bytes(32))   # FMMUs off: the slave no longer counts
    assert [host.cycle() for _ in range(5)] == [False] * 5
    assert host.wkc_errors == 5 and not host.accepted(tn)


class _LyingBackend(InProcessBackend):
    """Reads back 0x8000:21 one higher than the gateway holds."""

    def sdo_upload(self, position: int, index: int, subindex: int, complete: bool = False) -> bytes:
        raw = super().sdo_upload(position, index, subindex, complete)
        return bytes([raw[0] + 1]) if (index, subindex) == (0x8000, 0x21) else raw


class _SlowBackend(InProcessBackend):
    """The first download of 0x8000:22 arrives but its answer is lost (a slow gateway, SOEM's timeout)."""

    lost = 0

    def sdo_download(self, position: int, index: int, subindex: int, data: bytes, complete: bool = False) -> None:
        super().sdo_download(position, index, subindex, data, complete)
        if (index, subindex) == (0x8000, 0x22) and not self.lost:
            self.lost += 1
            raise MasterTimeout("SDO download 0x8000:22: no answer")


def test_readback_mismatch_is_an_error_with_both_values() -> None:
    """Readback checks of the PREOP writes (as IgH's startup SDOs, issue 12): a value that reads back
    different raises ReadbackError naming the object and both values."""
    clock = SimulatedClock()
    _bus, gw, _heard = make_can_side(clock)
    host = EsdHost(_LyingBackend(Master(clock, Segment([gw.slave]))))
    with pytest.raises(ReadbackError) as exc:
        host.configure(rx_queue=8)
    assert (exc.value.index, exc.value.subindex, exc.value.wrote, exc.value.read) == (0x8000, 0x21, 8, 9)


def test_download_without_answer_is_judged_by_the_readback() -> None:
    """A download whose answer timed out but which the gateway applied is not repeated blindly:
    the readback shows the value, configuration goes on (one retry counted)."""
    clock = SimulatedClock()
    _bus, gw, _heard = make_can_side(clock)
    b = _SlowBackend(Master(clock, Segment([gw.slave])))
    host = EsdHost(b)
    layout = host.configure(tx_queue=5)
    assert layout.tx_messages == 5 and host.sdo_retries == 1 and b.lost == 1


def test_a_foreign_slave_is_refused() -> None:
    """5.1.3.5: vendor 0x17, product 2 identify the CAN-EtherCAT; another slave is a ConfigError."""
    clock = SimulatedClock()
    b = InProcessBackend(Master(clock, Segment([create_io_slave(clock, "io")])))
    with pytest.raises(ConfigError, match="not an esd CAN-EtherCAT"):
        EsdHost(b)
    with pytest.raises(ConfigError, match="no slave"):
        EsdHost(b, position=3)


def test_tx_limit_and_misuse() -> None:
    """Local misuse: queue before start (LocalError), more frames than the host keeps (TxQueueFull
    with the count), start before configure."""
    _clock, _bus, _gw, b = _kit()
    host = EsdHost(b, tx_limit=20)
    with pytest.raises(LocalError):
        host.start()
    with pytest.raises(LocalError):
        host.queue([CanFrame(1)])
    host.configure()
    host.start()
    host.queue([CanFrame(1)] * 15)
    with pytest.raises(TxQueueFull) as exc:
        host.queue([CanFrame(2)] * 6)
    assert exc.value.pending == 15


def test_external_cycle_as_python_can_drives_it() -> None:
    """The python-can layer calls cycle() from its cyclic thread; the blocking calls then only wait
    on the clock (here a 1 ms periodic timer on the simulated clock plays that thread)."""
    clock, _bus, _gw, b = _kit()
    host = EsdHost(b, external_cycle=True)
    host.configure()
    host.start()
    timer = clock.call_every(0.001, host.cycle)
    frames = [CanFrame(0x100 + i, bytes([i])) for i in range(20)]
    tns = host.send(frames)
    host.wait_sent(tns[-1])
    got = receive_n(host, 20, timeout=1.0)
    timer.cancel()
    assert [r.frame for r in got] == [echo_of(f) for f in frames]
    assert host.cycles > 5


def test_two_gateways_around_one_exchange() -> None:
    """One master, two gateways on two buses: before_exchange / after_exchange around one
    backend.exchange() per cycle; each gateway's handshake runs on its own image part."""
    clock = SimulatedClock()
    _b1, gw1, heard1 = make_can_side(clock)
    bus2 = VirtualBus(clock, "can1", bitrate=500_000)
    gw2 = create_esd_gateway(clock, bus2, "esd2", serial=2)
    heard2: list[CanFrame] = []
    bus2.attach("peer", on_frame=lambda f, t: heard2.append(f))
    b = InProcessBackend(Master(clock, Segment([gw1.slave, gw2.slave])))
    hosts = [EsdHost(b, 0), EsdHost(b, 1)]
    hosts[0].configure()
    hosts[1].configure(extended=True, tx_queue=4)
    b.config_map()
    b.request_state(AlState.SAFEOP)
    b.request_state(AlState.OP)
    for h in hosts:
        h.attach()
    tn1 = hosts[0].queue([CanFrame(0x10 + i) for i in range(20)])[-1]
    tn2 = hosts[1].queue([CanFrame(0x1000 + i, extended=True) for i in range(10)])[-1]
    for _ in range(50):
        for h in hosts:
            h.before_exchange()
        wkc, expected = b.exchange()
        for h in hosts:
            h.after_exchange(wkc, expected)
        clock.wait(0.001)
    assert hosts[0].completed(tn1) and hosts[1].completed(tn2)
    assert [f.can_id for f in heard1] == [0x10 + i for i in range(20)]
    assert [f.can_id for f in heard2] == [0x1000 + i for i in range(10)] and all(f.extended for f in heard2)


def test_autobaud_and_no_baudrate_set_in_preop() -> None:
    """5.1.5.9 and 4.2.1 (init commands at PREOP -> SAFEOP): configure() with NTCAN_AUTOBAUD comes up
    listen-only and sends once two other nodes revealed the rate; with NTCAN_NO_BAUDRATE (the
    default API value) frames are accepted but never sent, and nothing is received."""
    _clock, _bus, _gw, b = _kit(chatter=True)
    host = EsdHost(b)
    host.configure(bitrate=BitRate.autobaud())
    host.start()
    assert receive_n(host, 1, timeout=2.0)
    tn = host.send([CanFrame(0x123, b"auto")])[0]
    host.wait_sent(tn, timeout=2.0)
    host.configure(bitrate=BitRate.no_baudrate())
    host.start()
    assert host.read_bitrate() == (0xFF, 0x7FFFFFFF)
    tn = host.send([CanFrame(0x124)])[0]
    with pytest.raises(TimeoutError):
        host.wait_sent(tn, timeout=0.2)
    assert host.receive(timeout=0.2) == []


def test_reconfigure_restarts_the_handshake() -> None:
    """4.2: queue sizes change in PREOP only, and a new handshake starts with PREOP -> SAFEOP
    (counters 0): configure() stops it, start() begins again with transaction number 1."""
    _clock, _bus, _gw, b = _kit()
    host = EsdHost(b)
    host.configure()
    host.start()
    assert host.send([CanFrame(0x100)] * 3) == [1, 2, 3]
    layout = host.configure(tx_queue=2, rx_queue=2)
    assert (layout.output_bytes, layout.input_bytes) == (30, 28)
    with pytest.raises(LocalError):
        host.queue([CanFrame(0x100)])
    host.start()
    tns = host.send([CanFrame(0x200 + i) for i in range(5)])
    assert tns == [1, 2, 3, 4, 5]
    host.wait_sent(tns[-1])
    host.stop()
    assert b.state(0)[0] == AlState.PREOP


def test_sm_watchdog_fallback_is_recovered_with_the_counters_kept() -> None:
    """5.1.4.2 'Watchdog triggered ... due to missing process data (Outputs)': a master that stalls
    past the SM watchdog finds the gateway in SAFEOP (AL status 0x001B); the waiting calls see the
    wrong working counters, request OP again, and the handshake carries on where it was."""
    clock, _bus, _gw, b = _kit()
    host = EsdHost(b)
    host.configure()
    host.start()
    first = host.send([CanFrame(0x100 + i) for i in range(5)])
    host.wait_sent(first[-1])
    clock.wait(0.5)                                       # no process data for 500 ms
    assert b.state(0) == (AlState.SAFEOP, 0x001B)
    more = host.send([CanFrame(0x200 + i) for i in range(5)])
    host.wait_sent(more[-1])
    assert more == [6, 7, 8, 9, 10] and host.recoveries == 1
    assert host.statistics()["Watchdog triggered"] == 1
    assert not host.recover()


class _LossyMapBackend(InProcessBackend):
    """The first config_map loses a SyncManager write: SM2 keeps a wrong length."""

    maps = 0

    def config_map(self) -> int:
        size = super().config_map()
        self.maps += 1
        if self.maps == 1:
            self.master.fpwr(self.master.slave(0).station, 0x0812, (10).to_bytes(2, "little"))
        return size


def test_start_maps_again_after_a_lost_syncmanager_write() -> None:
    """ETG.1000.6 AL status 0x001D 'invalid output configuration' when SM2 does not match the mapping:
    start() acknowledges it in PREOP, maps again and reaches OP (one retry counted)."""
    clock = SimulatedClock()
    _bus, gw, _heard = make_can_side(clock)
    b = _LossyMapBackend(Master(clock, Segment([gw.slave])))
    host = EsdHost(b)
    host.configure()
    host.start()
    assert b.state(0) == (AlState.OP, 0) and host.map_retries == 1 and b.maps == 2
    tn = host.send([CanFrame(0x100)])[0]
    host.wait_sent(tn)
