"""The esd host library's scenarios as functions of a MasterBackend, run against every backend.

``test_esd_host_scenarios.py`` calls each with an :class:`InProcessBackend` on a simulated clock,
and (as root) ``esd_host_driver.py`` calls the same function with a :class:`PysoemBackend` inside a
network namespace against the same gateway served on the other veth end. The CAN side is
:func:`make_can_side`: the gateway on a 500 kbit/s bus with an echo node answering every frame
with identifier + 0x100 (same data, same kind), and with ``chatter`` two more nodes exchanging
frame 0x7F0 every 10 ms (automatic bit rate detection needs two other nodes). Each scenario
returns a small JSON-able dict; only ``EsdHost`` calls touch the gateway (no peeking), waiting is
``backend.clock.wait`` inside the library.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import Clock, SimulatedClock
from gatewaylab.common.errors import FrameError, LocalError
from gatewaylab.devices.esd_can_ethercat.device import EsdGateway, create_esd_gateway
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.esd_can_ethercat import (
    BitRate,
    CanStatus,
    EsdHost,
    FilterArea,
    RxFrame,
    RxOverflowError,
    api_numerical,
    api_register,
    api_table,
)
from gatewaylab.hosts.esd_can_ethercat.config import NTCAN_USER_BAUDRATE, NTCAN_USER_BAUDRATE_NUM
from gatewaylab.hosts.ethercat.backend import MasterBackend, MasterTimeout
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.od import SdoAbort

CHATTER_ID = 0x7F0
ECHO_OFFSET = 0x100
#: Generous seconds for anything that must happen (real time on a shared machine; free when simulated).
T = 20.0
#: AT91SAM9263 CAN_BR for 500 kbit/s at 120 MHz: BRP 11 (x12), PROPAG 7, PHASE1 6, PHASE2 3 = 20 tq.
CAN_BR_500K = 0x000B0763


def echo_of(frame: CanFrame) -> CanFrame:
    """What the echo node answers."""
    return CanFrame(frame.can_id + ECHO_OFFSET, frame.data, extended=frame.extended, rtr=frame.rtr, dlc=frame.dlc)


def make_can_side(clock: Clock, chatter: bool = False) -> tuple[VirtualBus, EsdGateway, list[CanFrame]]:
    """The gateway ("esd1", serial 0x4711) on a 500 kbit/s bus with the echo node; returns the
    bus, the gateway and the frames the echo node heard (chatter excluded)."""
    bus = VirtualBus(clock, "can0", bitrate=500_000)
    gw = create_esd_gateway(clock, bus, "esd1", serial=0x4711, update_duration=1.0)
    heard: list[CanFrame] = []
    echo = bus.attach("echo")

    def answer(frame: CanFrame, t: float) -> None:
        if frame.can_id == CHATTER_ID and not frame.extended:
            return
        heard.append(frame)
        echo.send(echo_of(frame))

    echo.on_frame = answer
    if chatter:
        talker = bus.attach("talker")
        bus.attach("listener")
        clock.call_every(0.01, lambda: talker.send(CanFrame(CHATTER_ID, b"chat")))
    return bus, gw, heard


def _raises(exc_type: type[BaseException], fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    try:
        fn(*args, **kwargs)
    except exc_type as exc:
        return exc
    raise AssertionError(f"{getattr(fn, '__name__', fn)} did not raise {exc_type.__name__}")


def receive_n(host: EsdHost, n: int, timeout: float = T) -> list[RxFrame]:
    """Receive until ``n`` frames came (or the timeout passed)."""
    got: list[RxFrame] = []
    deadline = host.clock.now() + timeout
    while len(got) < n and host.clock.now() < deadline:
        got += host.receive(timeout=0.05)
    return got


def drain(host: EsdHost, quiet: float = 0.05, longest: float = 1.0) -> list[RxFrame]:
    """Receive until nothing came for ``quiet`` seconds (or ``longest`` passed: chatter never stops)."""
    got: list[RxFrame] = []
    deadline = host.clock.now() + longest
    while host.clock.now() < deadline:
        more = host.receive(timeout=quiet)
        if not more:
            break
        got += more
    return got


def _frames(got: list[RxFrame]) -> list[CanFrame]:
    return [r.frame for r in got]


def _js(frames: list[CanFrame]) -> list[list[Any]]:
    return [[f.can_id, f.data.hex(), f.extended, f.rtr] for f in frames]


def _started(b: MasterBackend, **config: Any) -> EsdHost:
    host = EsdHost(b)
    host.configure(**config)
    host.start(timeout=T)
    return host


# ------------------------------------------------------------------------------------ scenarios
def check_batches_11bit(b: MasterBackend) -> dict[str, Any]:
    """Note 'Sending' 1-4 and 'Receiving' 1-3, manual 5.1.5.1/5.1.5.3: 40 frames (data, empty, RTR)
    go out as batches of 16, 16 and 8 in order with transaction numbers 1..40; the echoes come
    back as several Rx batches (at most 16 each), in order, stamped, every batch acknowledged;
    0x2010 counts them (5.1.4.2)."""
    host = EsdHost(b)
    layout = host.configure(bitrate=BitRate.table6(2))
    assert (layout.extended, layout.output_bytes, layout.input_bytes) == (False, 198, 168)   # 4.2
    host.start(timeout=T)
    frames = [CanFrame(0x100 + i, bytes([i]) * (i % 9)) for i in range(38)]
    frames += [CanFrame(0x140, b"", rtr=True, dlc=3), CanFrame(0x141)]
    tns = host.send(frames, timeout=T)
    assert tns == list(range(1, 41))
    hs = host.handshake
    assert hs is not None and hs.tx_batches == 3
    assert all(host.accepted(t) for t in tns)
    host.wait_sent(tns[-1], timeout=T)
    assert all(host.completed(t) for t in tns)
    got = receive_n(host, 40)
    assert _frames(got) == [echo_of(f) for f in frames]
    times = [r.timestamp for r in got]
    assert times == sorted(times)
    sizes: dict[int, int] = {}
    for r in got:
        sizes[r.batch] = sizes.get(r.batch, 0) + 1
    assert len(sizes) >= 3 and max(sizes.values()) <= 16
    assert hs.rx_batches == len(sizes)
    st = host.statistics()
    assert (st["CAN Frames TX Requested"], st["CAN Frames TX"], st["CAN Frames RX"]) == (40, 40, 40)
    assert (st["CANDriver TX Frames"], st["CANDriver TX RTR Frames"]) == (39, 1)
    assert (st["CANDriver RX Frames"], st["CANDriver RX RTR Frames"]) == (39, 1)
    return {"sent": _js(frames)}


def check_transaction_numbers(b: MasterBackend) -> dict[str, Any]:
    """5.1.5.1 'Tx Transaction Number: the transaction number of the last sent Tx' and note
    'Sending' 4: completion follows the input Tx Transaction Number; frames complete in order (the
    completed ones are always a prefix); accepted (Tx counter, 'copied') comes before completed."""
    host = _started(b)
    tns = host.queue([CanFrame(0x300 + i, b"tn") for i in range(20)])
    assert tns == list(range(1, 21))
    assert not host.accepted(tns[0]) and not host.completed(tns[0])    # nothing exchanged yet
    hs = host.handshake
    assert hs is not None
    reported: list[int] = []
    deadline = host.clock.now() + T
    cycles = 0
    while not host.completed(tns[-1]):
        assert host.clock.now() < deadline, "not completed in time"
        host.cycle()
        cycles += 1
        if cycles % 50 == 0:
            host.recover()          # a master stalled past the SM watchdog (a loaded machine) carries on
        host.clock.wait(host.cycle_time)
        done = [host.completed(t) for t in tns]
        assert done == sorted(done, reverse=True), "completion is not in order"
        assert all(host.accepted(t) for t, d in zip(tns, done, strict=True) if d)
        if hs.in_tn and (not reported or reported[-1] != hs.in_tn):
            reported.append(hs.in_tn)
    assert reported == sorted(reported) and reported[-1] == 20
    host.wait_sent(tns[3], timeout=0.0)                     # already complete: returns at once
    _raises(LocalError, host.completed, 4000)               # never handed out
    # send() returns on the Tx counter ('copied'), before the 16 frames are on the bus
    batch = host.send([CanFrame(0x310 + i, bytes(8)) for i in range(16)], timeout=T)
    completed_at_return = host.completed(batch[-1])
    host.wait_sent(batch[-1], timeout=T)
    assert drain(host) and batch == list(range(21, 37))
    return {"reported": reported, "completed_at_send_return": completed_at_return}


def check_29bit(b: MasterBackend) -> dict[str, Any]:
    """5.1.5.2/5.1.5.4 and 4.2 ('the 198 bytes for the outputs will change to 262 byte'): 0x8000:20
    bit 0 selects the 29-bit queues; extended, standard and RTR frames travel with their flags."""
    host = EsdHost(b)
    layout = host.configure(extended=True)
    assert (layout.extended, layout.output_bytes, layout.input_bytes) == (True, 262, 232)
    host.start(timeout=T)
    frames = [CanFrame(0x1ABCD00 + i, bytes([i]) * 8, extended=True) for i in range(20)]
    frames += [CanFrame(0x123, b"std"), CanFrame(0x1FFFFE00, b"", extended=True, rtr=True, dlc=2)]
    tns = host.send(frames, timeout=T)
    host.wait_sent(tns[-1], timeout=T)
    got = receive_n(host, len(frames))
    assert _frames(got) == [echo_of(f) for f in frames]
    st = host.statistics()
    assert (st["CANDriver TX Frames Ext."], st["CANDriver TX Frames"], st["CANDriver TX RTR Frames Ext."]) == (20, 1, 1)
    assert (st["CANDriver RX Frames Ext."], st["CANDriver RX Frames"], st["CANDriver RX RTR Frames Ext."]) == (20, 1, 1)
    return {"sent": _js(frames)}


def check_queue_resize(b: MasterBackend) -> dict[str, Any]:
    """5.1.5.5 Rx/Tx queue size: 0x8000:22 = 4, :21 = 3 resize the image (6 + 4 x 12 = 54 B out,
    8 + 3 x 10 = 38 B in, read back from 0x1600/0x1A00); 10 frames go as batches of 4, 4, 2 and
    come back in batches of at most 3."""
    host = EsdHost(b)
    layout = host.configure(tx_queue=4, rx_queue=3)
    assert (layout.tx_messages, layout.rx_messages, layout.output_bytes, layout.input_bytes) == (4, 3, 54, 38)
    host.start(timeout=T)
    frames = [CanFrame(0x180 + i, bytes([i, i])) for i in range(10)]
    tns = host.send(frames, timeout=T)
    hs = host.handshake
    assert hs is not None and hs.tx_batches == 3
    host.wait_sent(tns[-1], timeout=T)
    got = receive_n(host, 10)
    assert _frames(got) == [echo_of(f) for f in frames]
    sizes: dict[int, int] = {}
    for r in got:
        sizes[r.batch] = sizes.get(r.batch, 0) + 1
    assert len(sizes) >= 4 and max(sizes.values()) <= 3
    return {"batches": sorted(sizes.values())}


def check_queue_limits(b: MasterBackend) -> dict[str, Any]:
    """5.1.5.5 '* Also limited by SM size/configuration': the largest queues (11-bit 148 Tx / 203 Rx,
    29-bit 111 / 145) give the sizes the mapping reads back; beyond them SdoAbort 0x06090031, a
    queue of 0 0x06090032; 29-bit refused while the sizes would not fit it; 0x8000 in OP 0x08000022."""
    host = EsdHost(b)
    big = host.configure(tx_queue=148, rx_queue=203)
    assert (big.output_bytes, big.input_bytes) == (6 + 148 * 12, 8 + 203 * 10)
    big29 = host.configure(extended=True, tx_queue=111, rx_queue=145)
    assert (big29.output_bytes, big29.input_bytes) == (6 + 111 * 16, 8 + 145 * 14)
    codes = [_raises(SdoAbort, host.configure, tx_queue=149).code,
             _raises(SdoAbort, host.configure, rx_queue=0).code,
             _raises(SdoAbort, host.configure, extended=True, tx_queue=148).code]
    assert codes == [0x06090031, 0x06090032, 0x06090031]
    host.configure()
    host.start(timeout=T)
    in_op = _raises(SdoAbort, b.sdo_download, 0, 0x8000, 0x21, b"\x08").code
    assert in_op == 0x08000022                            # 5.1.4.1/5.1.5.5 NOTICE: PREOP only
    assert host.layout is not None and host.layout.output_bytes == 198
    return {"codes": codes}


def check_filters(b: MasterBackend) -> dict[str, Any]:
    """5.1.5.6: identifier areas (bytes 0-3 first, 4-7 last; bits 31/63 for 29-bit): only echoes
    inside 0x200..0x204 and 0x1000000..0x1000010 (29-bit) reach the master; malformed areas are
    refused with their abort codes."""
    areas = (FilterArea(0x200, 0x204), FilterArea(0x1000000, 0x1000010, extended=True))
    host = EsdHost(b)
    host.configure(extended=True, filters=areas)
    assert host.read_filters() == areas
    host.start(timeout=T)
    frames = [CanFrame(0x100 + i, b"f") for i in range(10)]
    frames += [CanFrame(0xFFFF0A + i, b"F", extended=True) for i in range(9)]
    tns = host.send(frames, timeout=T)
    host.wait_sent(tns[-1], timeout=T)
    got = _frames(drain(host, quiet=0.1))
    want = [echo_of(f) for f in frames if 0x200 <= echo_of(f).can_id <= 0x204 and not f.extended]
    want += [echo_of(f) for f in frames if f.extended and echo_of(f).can_id <= 0x1000010]
    assert got == want and len(want) == 12
    st = host.statistics()
    assert st["CAN Frames RX"] == 12 and st["CANDriver RX Frames"] + st["CANDriver RX Frames Ext."] == 19
    one_bit = _raises(SdoAbort, b.sdo_download, 0, 0x8001, 1, (0x80000100 | 0x1FF << 32).to_bytes(8, "little"))
    reversed_area = _raises(SdoAbort, b.sdo_download, 0, 0x8001, 1, (0x300 | 0x200 << 32).to_bytes(8, "little"))
    assert (one_bit.code, reversed_area.code) == (0x06090030, 0x06090036)
    return {"received": _js(got)}


def _send_ok(host: EsdHost, can_id: int) -> None:
    tns = host.send([CanFrame(can_id, b"ok")], timeout=T)
    host.wait_sent(tns[-1], timeout=T)


def _chatter(got: list[RxFrame]) -> int:
    return sum(1 for r in got if r.frame.can_id == CHATTER_ID)


def check_bitrates(b: MasterBackend) -> dict[str, Any]:
    """5.1.5.9 (Tables 6-10) on a 500 kbit/s bus with two other nodes talking: the Table 6 index,
    Table 9 through the API baud rate, a numerical rate (UBRN), the CAN_BR register (UBR) all send
    and receive; listen-only (LOM) receives and never sends (frames aborted, 0x2010:37, never
    completed); NTCAN_NO_BAUDRATE receives nothing; a wrong rate sees error frames and receives
    nothing; NTCAN_AUTOBAUD detects the rate from the traffic, then sends."""
    host = _started(b, bitrate=BitRate.table6(2))
    out: dict[str, Any] = {}
    for i, (name, rate) in enumerate([("table6", BitRate.table6(2)), ("table9", BitRate.api_value(api_table(2))),
                                      ("numerical", BitRate.api_value(api_numerical(500_000))),
                                      ("register", BitRate.api_value(api_register(CAN_BR_500K)))]):
        host.set_bitrate(rate)
        index, api = host.read_bitrate()
        assert index == rate.index and (rate.index != 0xFF or api == rate.api)
        drain(host)
        _send_ok(host, 0x400 + i)
        out[name] = _chatter(receive_n(host, 3, timeout=1.0))
        assert out[name] >= 1, name
    # listen-only: receives, never sends
    host.set_bitrate(BitRate.api_value(api_table(2, listen_only=True)))
    drain(host)
    aborted = host.statistics()["CANDriver Aborted Frames"]
    tn = host.send([CanFrame(0x410, b"lom")], timeout=T)[0]
    assert host.accepted(tn)
    _raises(MasterTimeout, host.wait_sent, tn, timeout=0.2)
    assert host.statistics()["CANDriver Aborted Frames"] == aborted + 1
    out["listen_only_rx"] = _chatter(receive_n(host, 2, timeout=1.0))
    assert out["listen_only_rx"] >= 1
    # wrong rate: error frames, nothing received
    host.set_bitrate(BitRate.table6(3))
    drain(host)
    errors = host.statistics()["CANDriver Error Frames"]
    assert host.receive(timeout=0.1) == []
    assert host.statistics()["CANDriver Error Frames"] > errors
    # no baud rate: off the bus (the talker recovers meanwhile, should the wrong rate have hurt it)
    host.set_bitrate(BitRate.no_baudrate())
    drain(host)
    assert host.receive(timeout=0.2) == []
    # autobaud: listen-only until the chatter reveals 500 kbit/s, then active
    host.set_bitrate(BitRate.autobaud())
    assert host.read_bitrate() == (0xFF, 0x00FFFFFE)
    seen: list[RxFrame] = []
    deadline = host.clock.now() + T
    while not _chatter(seen) and host.clock.now() < deadline:
        seen += host.receive(timeout=0.05)
    out["autobaud_rx"] = _chatter(seen)
    assert out["autobaud_rx"] >= 1, f"autobaud: no chatter in {T} s, received {_js(_frames(seen))}"
    _send_ok(host, 0x420)
    host.set_bitrate(BitRate.table6(2))
    _send_ok(host, 0x421)
    return out


def check_status_statistics(b: MasterBackend) -> dict[str, Any]:
    """5.1.5.8 / 5.1.3.9: 0xF108 by SDO and through the 0x1A85 PDO (6 more input bytes) read all
    clear on a healthy bus; 5.1.4.2: 0x2010 by name, counting sent and received frames, reset by
    writing :01."""
    host = EsdHost(b)
    layout = host.configure(status_pdo=True)
    assert layout.status_pdo and layout.input_bytes == 168 + 6
    host.start(timeout=T)
    host.cycle()
    assert host.pdo_status() == CanStatus() and host.status() == CanStatus()
    st = host.statistics()
    assert len(st) == 32 and {"Reset", "Watchdog triggered", "CAN Frames TX Requested", "CANDriver FIFO overrun",
                              "CANDriver TX RTR Frames Ext."} <= set(st)
    host.reset_statistics()
    tns = host.send([CanFrame(0x500 + i, b"s") for i in range(5)], timeout=T)
    host.wait_sent(tns[-1], timeout=T)
    assert len(receive_n(host, 5)) == 5
    st = host.statistics()
    counts = [st[k] for k in ("CAN Frames TX Requested", "CAN Frames TX", "CAN Frames RX", "CANDriver TX Frames",
                              "CANDriver RX Frames", "CANDriver Error Frames", "CANDriver FIFO overrun")]
    assert counts == [5, 5, 5, 5, 5, 0, 0]
    host.reset_statistics()
    st = host.statistics()
    assert [st[k] for k in ("CAN Frames TX", "CAN Frames RX", "CANDriver RX Frames")] == [0, 0, 0]
    return {"reset_ms": st["Reset"]}


def check_rx_overflow(b: MasterBackend) -> dict[str, Any]:
    """5.1.5.8 'Rx overflow' and 5.1.4.2 'CANDriver FIFO overrun': with a local Rx queue of one frame
    (0x8000:23) the twelve echoes overrun it while the master acknowledges batch by batch; receive()
    raises RxOverflowError once with the lost count, the frames that made it follow; lost +
    received = 12, never silent."""
    host = _started(b, status_pdo=True, local_rx_queue=1)
    frames = [CanFrame(0x100 + i, bytes([i])) for i in range(12)]
    tns = host.send(frames, timeout=T)
    host.wait_sent(tns[-1], timeout=T)
    got: list[RxFrame] = []
    lost: int | None = None
    deadline = host.clock.now() + T
    while host.clock.now() < deadline:
        try:
            more = host.receive(timeout=0.1)
        except RxOverflowError as exc:
            assert lost is None, "reported twice"
            lost = exc.count
            continue
        if not more and lost is not None:
            break
        got += more
    assert lost is not None and lost >= 1 and len(got) + lost == 12
    status = host.status()
    pdo = host.pdo_status()
    assert status.rx_overflow and pdo is not None and pdo.rx_overflow
    assert host.statistics()["CANDriver FIFO overrun"] == lost
    echoes = iter(echo_of(f) for f in frames)
    assert all(f in echoes for f in _frames(got)), "received frames out of order"
    return {"lost": lost, "received": len(got)}


def check_errors(b: MasterBackend) -> dict[str, Any]:
    """Errors carry wire codes: 0xF800 values Tables 6-10 refuse (index 7, Table 9 Ah 'not allowed',
    UBR with UBRN) -> SdoAbort 0x06090030; local misuse (queue before start, a 29-bit frame on the
    11-bit queues 5.1.5.3, an FD frame) -> LocalError / FrameError."""
    host = EsdHost(b)
    codes = [_raises(SdoAbort, host.configure, bitrate=BitRate.table6(7)).code,
             _raises(SdoAbort, host.configure, bitrate=BitRate.api_value(api_table(0xA))).code,
             _raises(SdoAbort, host.configure,
                     bitrate=BitRate.api_value(NTCAN_USER_BAUDRATE | NTCAN_USER_BAUDRATE_NUM | 500_000)).code]
    assert codes == [0x06090030] * 3
    _raises(LocalError, host.queue, [CanFrame(0x100)])
    host.configure()
    host.start(timeout=T)
    _raises(FrameError, host.queue, [CanFrame(0x1000, extended=True)])
    _raises(FrameError, host.queue, [CanFrame(0x100, bytes(12), fd=True)])
    _send_ok(host, 0x101)
    return {"codes": codes}


def run_inprocess(name: str) -> tuple[dict[str, Any], list[CanFrame]]:
    """The scenario with an InProcessBackend on a simulated clock; returns its result and what the
    echo node heard."""
    fn, chatter = SCENARIOS[name]
    clock = SimulatedClock()
    _bus, gw, heard = make_can_side(clock, chatter)
    backend = InProcessBackend(Master(clock, Segment([gw.slave])))
    try:
        return fn(backend), heard
    finally:
        backend.close()
        gw.stop()


#: name -> (scenario, chatter on the bus)
SCENARIOS: dict[str, tuple[Callable[[MasterBackend], dict[str, Any]], bool]] = {
    "batches_11bit": (check_batches_11bit, False),
    "transaction_numbers": (check_transaction_numbers, False),
    "29bit": (check_29bit, False),
    "queue_resize": (check_queue_resize, False),
    "queue_limits": (check_queue_limits, False),
    "filters": (check_filters, False),
    "bitrates": (check_bitrates, True),
    "status_statistics": (check_status_statistics, False),
    "rx_overflow": (check_rx_overflow, False),
    "errors": (check_errors, False),
}
