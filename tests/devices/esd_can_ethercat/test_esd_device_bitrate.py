"""Object 0xF800 'CAN Bus Parameter' on the in-process master (manual 5.1.5.9, 4.2.1, 4.3): table
index, API baud rate (table, numerical, register), listen-only, no baud rate, autobaud, wrong rate."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from gatewaylab.bus.frame import CanFrame
from gatewaylab.devices.esd_can_ethercat.webmodel import EsdWebModel
from gatewaylab.od import SdoAbort, SdoAbortCode


def _api(kit: Any, value: int) -> None:
    kit.master.sdo_download32(0, 0xF800, 5, value)


def _talk(kit: Any, n: int = 3, base: int = 0x600) -> list[CanFrame]:
    """The peer sends n frames; a third node acknowledges them (5.1.5.9 autobaud: 'at least two
    other CAN nodes communicating with each other')."""
    frames = [CanFrame(base + i, bytes([i])) for i in range(n)]
    for f in frames:
        kit.peer.send(f)
    return frames


def test_no_baud_rate_by_default_the_gateway_stays_passive(kit: Any) -> None:
    """5.1.5.9 NTCAN_NO_BAUDRATE (default 7FFFFFFFh): 'cannot receive or transmit any message; stays
    passive on CAN bus' (4.3: 'will only go active on the CAN bus after the baud rate has been set')."""
    kit.bus.attach("other")
    kit.op(baud_index=None)
    _talk(kit)
    kit.send([CanFrame(0x100, b"x")])
    kit.cycle(10)
    assert kit.heard == [] and kit.receive() == []
    m = kit.master
    assert m.sdo_upload32(0, 0x2010, 0x38) == 0
    assert m.sdo_upload32(0, 0x2010, 0x30) == 1 and m.sdo_upload32(0, 0x2010, 0x37) == 1   # requested, aborted
    assert EsdWebModel(kit.gw).can_status().bitrate_set == "0x7fffffff"


def test_a_lone_sender_is_not_acknowledged_by_a_passive_gateway(kit: Any) -> None:
    """5.1.5.9 'stays passive': no acknowledge either, so a lone sender sees ACK errors."""
    kit.op(baud_index=None)
    kit.peer.send(CanFrame(0x10, b"a"))
    kit.cycle(3)
    assert kit.peer.stats.tx_frames == 0 and kit.peer.stats.error_frames > 0


@pytest.mark.parametrize(("index", "rate"), [(0, 1_000_000), (1, 800_000), (2, 500_000), (3, 250_000),
                                             (4, 125_000), (5, 100_000), (6, 50_000)])
def test_table_6_indexes_set_the_controller(kit: Any, index: int, rate: int) -> None:
    """Table 6: 0xF800:02 = 0..6 -> 1000 .. 50 kbit/s; on the 500 kbit/s bus only index 2 receives."""
    kit.bus.attach("other")
    kit.op(baud_index=index)
    assert kit.gw.controller.bitrate == rate
    frames = _talk(kit)
    got = kit.receive_all()
    assert got == (frames if rate == 500_000 else [])


def test_api_table_index_numerical_and_register_rates(kit: Any) -> None:
    """Tables 7-9: 0xF800:02 = FFh uses 0xF800:05: a Table 9 index (2 = 500 kbit/s, Eh = 800),
    a numerical rate (UBRN), the AT91SAM9263 CAN_BR register (UBR); each reaches the controller."""
    kit.preop()
    gw = kit.gw
    for value, rate in ((0x00000002, 500_000), (0x0000000E, 800_000), (0x00000010, 83_333),
                        (0x20000000 | 250_000, 250_000),
                        (0x80000000 | 11 << 16 | 7 << 8 | 7 << 4 | 2, 500_000)):
        _api(kit, value)
        assert gw.controller.bitrate == rate and not gw.controller.listen_only, hex(value)
    view = EsdWebModel(gw).can_status()
    assert (view.bitrate_actual, view.time_quanta, view.sample_point) == (500_000, 20, 85.0)
    kit.master.sdo_download8(0, 0xF800, 2, 3)   # a table index wins over the API value
    assert gw.controller.bitrate == 250_000


def test_numerical_rate_runs_the_queues(kit: Any) -> None:
    """UBRN (Table 8 'Set bit rate to numerical value'): 500000 bit/s works on the 500 kbit/s bus."""
    kit.preop()
    _api(kit, 0x20000000 | 500_000)
    kit.op(baud_index=None)
    frames = _talk(kit)
    assert kit.receive_all() == frames
    kit.send([CanFrame(0x321, b"ok")])
    kit.cycle(3)
    assert kit.heard == [CanFrame(0x321, b"ok")]


def test_listen_only_receives_but_never_acknowledges_or_sends(kit: Any) -> None:
    """LOM (Table 8 'can only receive messages', 'without effecting other CAN nodes'): frames between
    two other nodes are received; a lone sender gets no acknowledge; Tx batches are aborted."""
    other = kit.bus.attach("other")
    kit.preop()
    _api(kit, 0x40000002)
    kit.op(baud_index=None)
    frames = _talk(kit)
    assert kit.receive_all() == frames
    kit.send([CanFrame(0x100, b"x")])
    kit.cycle(5)
    assert kit.heard == [] and kit.master.sdo_upload32(0, 0x2010, 0x37) == 1
    kit.bus.detach(other)
    errors = kit.peer.stats.error_frames
    kit.peer.send(CanFrame(0x10, b"a"))
    kit.cycle(3)
    assert kit.peer.stats.error_frames > errors and kit.receive() == []


def test_wrong_bit_rate_sees_error_frames_and_receives_nothing(kit: Any) -> None:
    """5.1.5.9 + issue 11: a rate that differs from the bus sees error frames (0x2010:36, REC in
    0xF108:21) and receives nothing (0x2010:38 stays 0)."""
    kit.bus.attach("other")
    kit.op(baud_index=3)   # 250 kbit/s on a 500 kbit/s bus
    _talk(kit, 5)
    assert kit.receive_all() == []
    m = kit.master
    assert m.sdo_upload32(0, 0x2010, 0x36) == 5
    assert m.sdo_upload32(0, 0x2010, 0x38) == 0
    assert m.sdo_upload8(0, 0xF108, 0x21) == 5
    assert EsdWebModel(kit.gw).can_status().error_frames == 5


def test_wrong_bit_rate_transmitter_goes_bus_off(kit: Any) -> None:
    """A frame sent at a foreign rate is a bit error each try (TEC += 8): bus off (0xF108:01), the
    frame aborted (0x2010:37)."""
    kit.op(baud_index=3)
    kit.send([CanFrame(0x100, b"x")])
    saw_bus_off = False
    for _ in range(20):
        kit.cycle()
        saw_bus_off |= kit.master.sdo_upload8(0, 0xF108, 1) == 1
    assert saw_bus_off and kit.heard == []
    assert kit.master.sdo_upload32(0, 0x2010, 0x37) >= 1


def test_autobaud_listens_until_two_nodes_reveal_the_rate(kit_factory: Callable[..., Any]) -> None:
    """NTCAN_AUTOBAUD (00FFFFFEh): 'initially act as Listen-Only', detect a table rate from traffic
    between at least two other nodes, then go active at it (5.1.5.9 'Automatic Baud Rate Detection')."""
    kit = kit_factory(bitrate=250_000)
    kit.preop()
    _api(kit, 0x00FFFFFE)
    kit.op(baud_index=None)
    kit.peer.send(CanFrame(0x10, b"a"))      # alone: nobody acknowledges, nothing is detected
    kit.cycle(3)
    assert kit.gw.detected == 0 and kit.gw.controller.listen_only
    kit.peer.flush_tx()
    other = kit.bus.attach("other")
    frames = _talk(kit, 20)
    got = kit.receive_all()
    assert kit.gw.detected == 250_000 and not kit.gw.controller.listen_only
    assert got and got == frames[len(frames) - len(got):]   # received from the detecting frame on
    kit.bus.detach(other)
    kit.send([CanFrame(0x321, b"hi")])        # active now: it sends and acknowledges
    kit.cycle(3)
    assert kit.heard[-1] == CanFrame(0x321, b"hi")
    view = EsdWebModel(kit.gw).can_status()
    assert view.bitrate_set == "0x00fffffe" and view.bitrate_actual == 250_000


def test_autobaud_on_a_silent_bus_never_sends(kit: Any) -> None:
    """While detecting the gateway is listen-only: Tx batches are aborted, nothing reaches the bus."""
    kit.preop()
    _api(kit, 0x00FFFFFE)
    kit.op(baud_index=None)
    kit.send([CanFrame(0x100, b"x")])
    kit.cycle(5)
    assert kit.heard == [] and kit.gw.detected == 0


@pytest.mark.parametrize(("sub", "value"), [(2, 7), (2, 8), (2, 0x20), (5, 0xA0000002), (5, 0x0000000A),
                                            (5, 0x0000000D), (5, 0x00000011), (5, 0x20000000 | 10_000),
                                            (5, 0x20000000 | 2_000_000), (5, 0x01000002)])
def test_values_outside_tables_6_to_10_are_refused(kit: Any, sub: int, value: int) -> None:
    """Table 6 (7, 8 'not allowed'), Table 8 ('UBR and UBRN cannot be set at the same time'), Table 9
    (Ah-Dh 'not allowed'), 7.3 (50 kbit/s .. 1 Mbit/s), reserved bits: SDO abort 0x06090030."""
    kit.preop()
    with pytest.raises(SdoAbort) as err:
        if sub == 2:
            kit.master.sdo_download8(0, 0xF800, 2, value)
        else:
            _api(kit, value)
    assert err.value.code == SdoAbortCode.VALUE_RANGE_EXCEEDED


def test_no_baudrate_leaves_the_bus_again(kit: Any) -> None:
    """'Leaving the CAN Bus': NTCAN_NO_BAUDRATE written later takes the gateway off the bus."""
    kit.bus.attach("other")
    kit.op()
    frames = _talk(kit, 2)
    assert kit.receive_all() == frames
    kit.master.sdo_download8(0, 0xF800, 2, 0xFF)
    _api(kit, 0x7FFFFFFF)
    _talk(kit, 2, base=0x700)
    assert kit.receive_all() == []
