"""PDOs: remapping by CiA 301 rules, transmission types, SYNC, RTR, events and PDO length errors.

Manual: IDX Communication Guide 3.3.3.1 (PDO object, triggering modes), 3.3.3.3 (SYNC), 3.4
table 3-13 (default COB-IDs), chapter 6 table 6-20 (mapping abort codes); CiA 301 7.2.2 and
7.5.2.35-38 for the parameter rules.
"""

from __future__ import annotations

import struct

import pytest
from canopen_testkit import RawClient, barrier, remote_for, while_waiting

from gatewaylab.bus import CanFrame
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.od.aborts import SdoAbort, SdoAbortCode


def wr(raw: RawClient, index: int, sub: int, value: int, size: int = 4) -> int:
    """Expedited SDO download of ``value``; 0 on success, else the abort code."""
    cs = 0x23 | ((4 - size) << 2)
    answer = raw.sdo(5, struct.pack("<BHB", cs, index, sub) + value.to_bytes(size, "little").ljust(4, b"\0"))
    assert answer is not None
    return 0 if answer[0] == 0x60 else int.from_bytes(answer[4:], "little")


def map_tpdo(raw: RawClient, n: int, entries: list[int], trans_type: int, cob: int | None = None,
             inhibit: int = 0, event: int = 0, rtr: bool = True) -> None:
    """Configure TPDO n (0-based) by the CiA 301 procedure, via SDO."""
    cob = 0x185 + 0x100 * n if cob is None else cob
    assert wr(raw, 0x1800 + n, 1, cob | 0x80000000) == 0
    assert wr(raw, 0x1800 + n, 2, trans_type, 1) == 0
    assert wr(raw, 0x1800 + n, 3, inhibit, 2) == 0
    assert wr(raw, 0x1800 + n, 5, event, 2) == 0
    assert wr(raw, 0x1A00 + n, 0, 0, 1) == 0
    for i, e in enumerate(entries, 1):
        assert wr(raw, 0x1A00 + n, i, e) == 0
    assert wr(raw, 0x1A00 + n, 0, len(entries), 1) == 0
    assert wr(raw, 0x1800 + n, 1, cob | (0 if rtr else 0x40000000)) == 0


def test_default_connection_set(make_node) -> None:
    """IDX table 3-13: PDO COB-IDs 0x180/0x200/0x280/... + node-id, SDO 0x580/0x600, EMCY 0x80 + id."""
    node = make_node(node_id=0x22)
    assert [node.get(0x1800 + n, 1) for n in range(4)] == [0x1A2, 0x2A2, 0x3A2, 0x4A2]
    assert [node.get(0x1400 + n, 1) for n in range(4)] == [0x222, 0x322, 0x422, 0x522]
    assert (node.get(0x1200, 1), node.get(0x1200, 2), node.get(0x1014)) == (0x622, 0x5A2, 0xA2)
    assert node.get(0x1005) == 0x80


def test_remap_with_python_canopen_and_receive_on_sync(make_node, network, clock) -> None:
    """IDX 3.3.3.1 c) synchronized: after canopen's tpdo.save() the node sends the mapped values
    on every SYNC; canopen decodes them with the mapping it wrote."""
    node = make_node()
    remote = remote_for(network, node)
    remote.tpdo.read()
    tpdo = remote.tpdo[1]
    assert tpdo.cob_id == 0x185 and tpdo.trans_type == 255 and len(tpdo.map) == 0
    tpdo.clear()
    tpdo.add_variable(0x2000)
    tpdo.add_variable(0x2003)
    tpdo.add_variable(0x200B)
    tpdo.trans_type = 1
    tpdo.enabled = True
    remote.tpdo.save()
    assert node.get(0x1A00, 0) == 3
    assert [node.get(0x1A00, s) for s in (1, 2, 3)] == [0x20000020, 0x20030010, 0x200B0008]
    remote.nmt.state = "OPERATIONAL"
    node.set(0x2000, 0, 0xDEADBEEF)
    node.set(0x2003, 0, -42)
    stamp = while_waiting(tpdo.receive_condition, lambda: tpdo.wait_for_reception(5.0),
                          lambda: network.sync.transmit())
    assert stamp is not None
    assert tpdo.map[0].raw == 0xDEADBEEF and tpdo.map[1].raw == -42 and tpdo.map[2].raw == -1
    remote.tpdo.read()                                   # reads back what it saved
    assert [v.index for v in remote.tpdo[1].map] == [0x2000, 0x2003, 0x200B]


def test_rpdo_remap_and_reception(make_node, network, raw) -> None:
    """IDX 3.3.3.1: an RPDO (type 255) writes its mapped objects at once, a synchronous one at the next SYNC."""
    node = make_node()
    remote = remote_for(network, node)
    written: list[tuple[int, int, int]] = []
    node.on_write(0x2011, lambda i, s, v: written.append((i, s, v)))
    remote.rpdo.read()
    rpdo = remote.rpdo[1]
    rpdo.clear()
    rpdo.add_variable(0x2011)
    rpdo.add_variable(0x2007)
    rpdo.trans_type = 255
    rpdo.enabled = True
    remote.rpdo.save()
    remote.nmt.state = "OPERATIONAL"
    rpdo.map[0].raw = 0x4242
    rpdo.map[1].raw = -77
    rpdo.transmit()
    barrier(remote)
    assert node.get(0x2011) == 0x4242 and node.get(0x2007) == -77
    assert written == [(0x2011, 0, 0x4242)]
    # synchronous RPDO: the value is taken over with the next SYNC
    assert wr(raw, 0x1400, 1, 0x205 | 0x80000000) == 0
    assert wr(raw, 0x1400, 2, 1, 1) == 0
    assert wr(raw, 0x1400, 1, 0x205) == 0
    raw.send(0x205, struct.pack("<Hi", 0x1111, 5))
    assert node.get(0x2011) == 0x4242
    raw.send(0x80)
    assert node.get(0x2011) == 0x1111 and node.get(0x2007) == 5


def test_transmission_type_every_nth_sync_and_counter(make_node, raw, sniffer) -> None:
    """IDX 3.3.3.3 / CiA 301: type n sends on every n-th SYNC; with a SYNC counter and a start
    value the first transmission waits for that counter value."""
    make_node()
    map_tpdo(raw, 0, [0x20000020], 3)
    raw.send(0, [0x01, 5])
    sniffer.clear()
    for _ in range(9):
        raw.send(0x80)
    assert len(sniffer.ids(0x185)) == 3
    # SYNC counter 0x1019 = 10, start value 4
    raw.send(0, [0x80, 5])
    assert wr(raw, 0x1019, 0, 10, 1) == 0
    assert wr(raw, 0x1800, 1, 0x185 | 0x80000000) == 0
    assert wr(raw, 0x1800, 6, 4, 1) == 0
    assert wr(raw, 0x1800, 2, 2, 1) == 0
    assert wr(raw, 0x1800, 1, 0x185) == 0
    raw.send(0, [0x01, 5])
    sniffer.clear()
    sent_after = []
    for counter in range(1, 9):
        raw.send(0x80, [counter])
        if sniffer.ids(0x185):
            sent_after.append(counter)
            sniffer.clear()
    assert sent_after == [5, 7]           # starts counting at SYNC 4, sends every 2nd


def test_sync_length_error_emcy(make_node, raw) -> None:
    """CiA 301 7.2.5: a SYNC whose length does not match 0x1019 -> EMCY 0x8240."""
    node = make_node()
    raw.received.clear()
    raw.send(0x80, [1])
    assert [f.data[:3] for f in raw.take(0x85)] == [bytes([0x40, 0x82, 0x11])]
    assert node.stats["sync_length_errors"] == 1


def test_event_driven_with_event_timer_and_inhibit(make_node, raw, sniffer, clock) -> None:
    """IDX 3.3.3.1 a) event-driven: type 255 sends when a mapped value changes and every event
    timer period; the inhibit time (x100 us) spaces transmissions."""
    node = make_node()
    map_tpdo(raw, 0, [0x20110010], 255, inhibit=500, event=100)     # 50 ms inhibit, 100 ms timer
    raw.send(0, [0x01, 5])
    sniffer.clear()
    t0 = clock.now()
    clock.advance(0.35)
    times = [round(t - t0, 4) for t, _ in sniffer.ids(0x185)]
    assert [round(x, 2) for x in times] == [0.1, 0.2, 0.3]
    sniffer.clear()
    node.set(0x2011, 0, 1)                # change 50 ms after the last one: goes at once
    node.set(0x2011, 0, 2)                # within the inhibit time: delayed
    node.set(0x2011, 0, 3)                # coalesced with the pending one
    start = clock.now()
    clock.advance(0.06)
    frames = [(round(t - start, 4), f.data) for t, f in sniffer.ids(0x185)]
    assert [d for _, d in frames] == [b"\x01\x00", b"\x03\x00"]
    assert frames[1][0] >= 0.05 - 0.0002


def test_event_reception_in_python_canopen(make_node, network, clock) -> None:
    """IDX 3.3.3.1 a): python-canopen receives the event-timer TPDO when simulated time passes."""
    node = make_node()
    remote = remote_for(network, node)
    remote.tpdo.read()
    tpdo = remote.tpdo[2]
    tpdo.clear()
    tpdo.add_variable(0x2007)
    tpdo.trans_type = 254
    tpdo.event_timer = 20
    tpdo.enabled = True
    remote.tpdo.save()
    remote.nmt.state = "OPERATIONAL"
    node.set(0x2007, 0, -99)                  # an event at once

    def later() -> None:
        with clock.lock:
            clock.advance(0.02)

    barrier(remote)
    assert tpdo.map[0].raw == -99
    node.od.values[(0x2007, 0)] = 1234        # no event: only the timer sends it
    stamp = while_waiting(tpdo.receive_condition, lambda: tpdo.wait_for_reception(5.0), later)
    assert stamp is not None and tpdo.map[0].raw == 1234


def test_empty_mapping_is_no_pdo(make_node, raw) -> None:
    """CiA 301 7.5.2.36: with sub-index 0 = 0 the PDO is disabled: no frame on SYNC or RTR."""
    make_node()
    assert wr(raw, 0x1800, 1, 0x80000185) == 0
    assert wr(raw, 0x1800, 2, 1, 1) == 0
    assert wr(raw, 0x1800, 1, 0x185) == 0
    raw.send(0, [0x01, 5])
    raw.received.clear()
    raw.send(0x80)
    raw.send(0x185, rtr=True)
    assert raw.take(0x185) == []


def test_type_0_sends_on_sync_after_an_event(make_node, raw, sniffer) -> None:
    """CiA 301 7.2.2.2: type 0 (acyclic synchronous) sends at a SYNC only after an event."""
    node = make_node()
    map_tpdo(raw, 0, [0x20110010], 0)
    raw.send(0, [0x01, 5])
    sniffer.clear()
    raw.send(0x80)
    assert sniffer.ids(0x185) == []
    node.set(0x2011, 0, 9)
    assert sniffer.ids(0x185) == []
    raw.send(0x80)
    raw.send(0x80)
    assert [f.data for _, f in sniffer.ids(0x185)] == [b"\x09\x00"]


def test_rtr_types_252_253(make_node, raw, network) -> None:
    """IDX 3.3.3.1 b) polling by remote frames: 253 samples at the request, 252 at the last SYNC;
    with COB-ID bit 30 set (no RTR allowed) the request is ignored."""
    node = make_node()
    map_tpdo(raw, 0, [0x20110010], 253)
    map_tpdo(raw, 1, [0x20110010], 252)
    raw.send(0, [0x01, 5])
    raw.received.clear()
    node.set(0x2011, 0, 0x0102)
    raw.send(0x185, rtr=True, dlc=2)
    assert [f.data for f in raw.take(0x185)] == [b"\x02\x01"]
    raw.send(0x80)                         # 252 samples 0x0102 now
    node.set(0x2011, 0, 0x0304)
    raw.send(0x285, rtr=True, dlc=2)
    assert [f.data for f in raw.take(0x285)] == [b"\x02\x01"]
    raw.send(0, [0x80, 5])
    assert wr(raw, 0x1800, 1, 0x185 | 0xC0000000) == 0
    assert wr(raw, 0x1800, 1, 0x185 | 0x40000000) == 0
    raw.send(0, [0x01, 5])
    raw.send(0x185, rtr=True, dlc=2)
    assert raw.take(0x185) == []
    remote = remote_for(network, node)
    remote.tpdo.read()
    assert remote.tpdo[2].trans_type == 252 and remote.tpdo[1].rtr_allowed is False


def test_rpdo_length_errors_answered_with_emcy(make_node, raw) -> None:
    """Issue / CiA 301 7.2.2: a too short RPDO is not processed -> EMCY 0x8210; a too long one is
    processed -> EMCY 0x8220; a good one resets the error."""
    node = make_node()
    assert wr(raw, 0x1400, 1, 0x205 | 0x80000000) == 0
    assert wr(raw, 0x1600, 0, 0, 1) == 0
    assert wr(raw, 0x1600, 1, 0x20000020) == 0
    assert wr(raw, 0x1600, 0, 1, 1) == 0
    assert wr(raw, 0x1400, 1, 0x205) == 0
    raw.send(0, [0x01, 5])
    raw.received.clear()
    raw.send(0x205, [1, 2, 3])
    assert [f.data for f in raw.take(0x85)] == [bytes([0x10, 0x82, 0x11, 1, 3, 0, 0, 0])]
    assert node.get(0x2000) == 0x12345678
    raw.send(0x205, [1, 2, 3, 4])
    assert [f.data for f in raw.take(0x85)] == [bytes(8)]
    raw.send(0x205, [5, 6, 7, 8, 9])
    assert [f.data for f in raw.take(0x85)] == [bytes([0x20, 0x82, 0x11, 1, 5, 0, 0, 0])]
    assert node.get(0x2000) == 0x08070605
    assert node.stats["rpdo_length_errors"] == 2


def test_no_pdo_outside_operational(make_node, raw, sniffer, clock) -> None:
    """IDX 3.3.3.5: PDOs only in Operational; Pre-operational and Stopped neither send nor take them."""
    node = make_node()
    map_tpdo(raw, 0, [0x20110010], 255, event=10)
    assert wr(raw, 0x1400, 1, 0x205 | 0x80000000) == 0
    assert wr(raw, 0x1600, 1, 0x20110010) == 0
    assert wr(raw, 0x1600, 0, 1, 1) == 0
    assert wr(raw, 0x1400, 1, 0x205) == 0
    sniffer.clear()
    clock.advance(0.1)
    raw.send(0x205, [7, 7])
    assert sniffer.ids(0x185) == [] and node.get(0x2011) == 0x1111
    raw.send(0, [0x01, 5])
    clock.advance(0.055)
    assert len(sniffer.ids(0x185)) == 5
    raw.send(0, [0x02, 5])
    sniffer.clear()
    clock.advance(0.1)
    raw.send(0x205, [7, 7])
    assert sniffer.ids(0x185) == [] and node.get(0x2011) == 0x1111
    assert node.nmt_state is NmtState.STOPPED


@pytest.mark.parametrize(("steps", "code"), [
    # mapping while the PDO is valid
    ([(0x1A00, 0, 0, 1)], SdoAbortCode.UNSUPPORTED_ACCESS),
    ([(0x1A00, 1, 0x20000020, 4)], SdoAbortCode.UNSUPPORTED_ACCESS),
    # entry while sub-index 0 is not 0
    ([(0x1800, 1, 0x80000185, 4), (0x1A00, 1, 0x20000020, 4), (0x1A00, 0, 1, 1), (0x1A00, 1, 0x20110010, 4)],
     SdoAbortCode.SUBINDEX_CANNOT_BE_WRITTEN),
    # not mappable / not existing / wrong direction / wrong length
    ([(0x1800, 1, 0x80000185, 4), (0x1A00, 1, 0x20090040, 4)], SdoAbortCode.OBJECT_NOT_MAPPABLE),
    ([(0x1800, 1, 0x80000185, 4), (0x1A00, 1, 0x30000020, 4)], SdoAbortCode.OBJECT_NOT_MAPPABLE),
    ([(0x1800, 1, 0x80000185, 4), (0x1A00, 1, 0x20050020, 4)], SdoAbortCode.OBJECT_NOT_MAPPABLE),
    ([(0x1400, 1, 0x80000205, 4), (0x1600, 1, 0x20040008, 4)], SdoAbortCode.OBJECT_NOT_MAPPABLE),
    ([(0x1800, 1, 0x80000185, 4), (0x1A00, 1, 0x20000010, 4)], SdoAbortCode.GENERAL_PARAMETER_INCOMPATIBILITY),
    # more than 64 bits
    ([(0x1800, 1, 0x80000185, 4), (0x1A00, 1, 0x200A0040, 4), (0x1A00, 2, 0x20110010, 4),
      (0x1A00, 0, 2, 1)], SdoAbortCode.PDO_LENGTH_EXCEEDED),
    ([(0x1800, 1, 0x80000185, 4), (0x1A00, 0, 9, 1)], SdoAbortCode.VALUE_RANGE_EXCEEDED),
    # communication parameters
    ([(0x1800, 1, 0x186, 4)], SdoAbortCode.VALUE_RANGE_EXCEEDED),                 # new COB-ID while valid
    ([(0x1800, 1, 0x80000185, 4), (0x1800, 1, 0x705, 4)], SdoAbortCode.VALUE_RANGE_EXCEEDED),   # reserved
    ([(0x1800, 1, 0xA0000185, 4)], SdoAbortCode.VALUE_RANGE_EXCEEDED),            # 29-bit
    ([(0x1800, 2, 245, 1)], SdoAbortCode.VALUE_RANGE_EXCEEDED),
    ([(0x1400, 2, 252, 1)], SdoAbortCode.VALUE_RANGE_EXCEEDED),
    ([(0x1800, 3, 10, 2)], SdoAbortCode.UNSUPPORTED_ACCESS),                      # inhibit time while valid
])
def test_mapping_rules_abort_codes(make_node, raw, steps: list[tuple[int, int, int, int]], code: int) -> None:
    """CiA 301 7.5.2.36/38 with IDX table 6-20 codes: disable via COB-ID bit 31 before remapping,
    sub-index 0 = 0 before changing entries, only mappable objects, at most 64 bits."""
    make_node()
    *setup, (index, sub, value, size) = steps
    for s in setup:
        assert wr(raw, *s) == 0, s
    assert wr(raw, index, sub, value, size) == code


def test_dummy_mapping_in_rpdo(make_node, raw) -> None:
    """CiA 301 7.4.7.1: dummy entries (data type indices) skip bytes of an RPDO."""
    node = make_node()
    assert wr(raw, 0x1400, 1, 0x80000205) == 0
    assert wr(raw, 0x1600, 1, 0x00060010) == 0          # UNSIGNED16 dummy
    assert wr(raw, 0x1600, 2, 0x20110010) == 0
    assert wr(raw, 0x1600, 0, 2, 1) == 0
    assert wr(raw, 0x1400, 1, 0x205) == 0
    raw.send(0, [0x01, 5])
    raw.send(0x205, [0xFF, 0xFF, 0x34, 0x12])
    assert node.get(0x2011) == 0x1234


def test_tpdo_frame_golden(make_node, raw) -> None:
    """IDX 3.3.3.1: the mapped values are packed little-endian in mapping order."""
    node = make_node()
    map_tpdo(raw, 0, [0x20000020, 0x20110010, 0x200C0008, 0x200B0008], 1)
    node.set(0x2000, 0, 0x01020304)
    node.set(0x2011, 0, 0xA0B0)
    raw.send(0, [0x01, 5])
    raw.received.clear()
    raw.send(0x80)
    assert raw.take(0x185) == [CanFrame(0x185, bytes([4, 3, 2, 1, 0xB0, 0xA0, 1, 0xFF]))]


def test_dictionary_put_notifies_subscribers_of_changes_only() -> None:
    """Change notification for event-driven PDOs (CiA 301 7.2.2: a TPDO of type 254/255 is sent
    on a change of a mapped value): ``put`` stores, says whether the value changed and calls the
    key's listeners only then; the returned function ends the subscription."""
    from gatewaylab.od import Access, DataType, ObjectDictionary

    od = ObjectDictionary(5)
    od.add_variable(0x2000, "a", DataType.INTEGER16, Access.RW, 0, pdo_mappable=True)
    od.add_variable(0x2001, "b", DataType.INTEGER16, Access.RW, 0, pdo_mappable=True)
    seen: list[tuple[tuple[int, int], object]] = []
    unsubscribe = od.subscribe((0x2000, 0), lambda key, value: seen.append((key, value)))
    assert od.put(0x2000, 0, 7) is True
    assert od.put(0x2000, 0, 7) is False          # same value: no event
    assert od.put(0x2001, 0, 3) is True           # another key: not this listener's
    assert seen == [((0x2000, 0), 7)]
    assert od.values[(0x2000, 0)] == 7 and od.values[(0x2001, 0)] == 3
    unsubscribe()
    assert od.put(0x2000, 0, 8) is True
    assert seen == [((0x2000, 0), 7)]
    unsubscribe()                                 # ending it twice is harmless
    with pytest.raises(SdoAbort):
        od.put(0x3000, 0, 1)                      # no such object


def test_remap_moves_the_event_subscription(make_node, raw, sniffer, clock) -> None:
    """CiA 301 7.5.2.36 re-mapping: an event-driven TPDO (type 255) follows the objects it maps
    now: a change of an object mapped before the remap no longer sends it."""
    node = make_node()
    map_tpdo(raw, 0, [0x20110010], 255)
    raw.send(0, [0x01, 5])
    sniffer.clear()
    node.set(0x2011, 0, 4)
    clock.advance(0.01)
    assert [f.data for _, f in sniffer.ids(0x185)] == [b"\x04\x00"]
    map_tpdo(raw, 0, [0x20070020], 255)           # 0x2011 no longer mapped
    sniffer.clear()
    node.set(0x2011, 0, 5)
    clock.advance(0.01)
    assert sniffer.ids(0x185) == []
    node.set(0x2007, 0, -2)
    clock.advance(0.01)
    assert [f.data for _, f in sniffer.ids(0x185)] == [struct.pack("<i", -2)]
