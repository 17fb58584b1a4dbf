"""Property tests: random frames and mailbox contents never crash the slaves, never corrupt them,
and every frame the ESC cannot parse is dropped and counted (DEVELOPERS.md 'Every parser')."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.datagram import Command, Datagram, Frame, decode_frame, encode_frame
from gatewaylab.ethercat.errors import FrameFormatError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.mailbox import MailboxMessage, MailboxType, encode_mailbox
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master

ETH = b"\xff" * 6 + b"\x02\x00\x00\x00\x00\x01" + b"\x88\xa4"
VALID_STATES = {int(s) for s in AlState}


def fresh() -> tuple[SimulatedClock, Segment]:
    clock = SimulatedClock()
    return clock, Segment([create_io_slave(clock, f"F{i}", revision=i + 1) for i in range(2)])


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=200))
def test_random_payload_is_processed_or_counted(payload: bytes) -> None:
    """Segment and codec agree on which frames are malformed; those are counted, never answered."""
    _clock, seg = fresh()
    buf = bytearray(ETH + payload)
    try:
        decode_frame(bytes(buf))
        parses = True
    except FrameFormatError:
        parses = False
    answered = seg.process(buf)
    assert answered == parses
    assert seg.stats.bad_frames == (0 if parses else 1)
    for s in seg.slaves:
        assert s.esc.al_status & 0x0F in VALID_STATES


datagram = st.builds(
    Datagram,
    command=st.sampled_from(list(Command)),
    index=st.integers(0, 255),
    address=st.one_of(st.integers(0, 0xFFFFFFFF), st.integers(0, 0x1FFF).map(lambda a: (a << 16) | 0x0000),
                      st.integers(0, 0x1FFF).map(lambda a: (a << 16) | 0x1001)),
    data=st.binary(min_size=1, max_size=64),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(datagram, min_size=1, max_size=4))
def test_random_datagrams_leave_slaves_usable(dgs: list[Datagram]) -> None:
    """After any well-formed datagrams, state stays valid and a master can still bring the slaves to OP
    (unless the datagrams rewrote the SII EEPROM, which a master may legitimately do)."""
    clock, seg = fresh()
    eeproms = [bytes(s.esc.eeprom) for s in seg.slaves]
    buf = bytearray(encode_frame(Frame(tuple(dgs))))
    assert seg.process(buf)
    back = decode_frame(buf).datagrams
    assert len(back) == len(dgs)
    for s in seg.slaves:
        assert s.esc.al_status & 0x0F in VALID_STATES
    clock.advance(0.5)
    if [bytes(s.esc.eeprom) for s in seg.slaves] != eeproms:
        return
    m = Master(clock, seg)
    m.bring_up(ack_errors=True)
    assert m.exchange_process_data() == m.expected_wkc


@settings(max_examples=100, deadline=None)
@given(st.sampled_from([MailboxType.COE, MailboxType.FOE, MailboxType.EOE, 0, 7]), st.binary(max_size=120),
       st.integers(0, 7))
def test_random_mailbox_messages_never_break_the_mailbox(mtype: int, data: bytes, counter: int) -> None:
    """Any mailbox content gets an answer or is ignored; the next SDO upload still works."""
    clock, seg = fresh()
    m = Master(clock, seg)
    m.scan()
    m.request_state(0, AlState.PREOP)
    s = m.slaves[0]
    raw = encode_mailbox(MailboxMessage(mtype, data, counter))[:128].ljust(128, b"\0")
    m.fpwr(s.station, 0x1000, raw)
    s.mbx_counter = counter  # a master never repeats the counter of its previous request
    slave = seg.slaves[0]
    slave.esc.mailbox_clear(1)
    slave.mailbox.queue.clear()
    assert m.sdo_upload32(0, 0x1018, 1) == slave.desc.vendor_id


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=40), st.sampled_from([0x02, 0x08, 0x01, 0x03, 0x0F]))
def test_coe_server_answers_only_spec_messages(body: bytes, service: int) -> None:
    """Any CoE request yields either a mailbox error (FrameFormatError, too short) or well-formed CoE
    replies: SDO responses, aborts with a QEC A.5 code, or SDO Information replies/errors. Every SDO
    request is answered by exactly one reply, except the client's abort transfer (CiA 301 7.2.4.3:
    unconfirmed); every SDO Information request by at least one (a response or an error, ETG.1000.6
    SDO Information)."""
    from gatewaylab.devices.ethercat_io.device import io_description
    from gatewaylab.ethercat.coe import CoeServer, coe_header
    from gatewaylab.ethercat.errors import SdoAbortCode
    from gatewaylab.ethercat.slave import build_od

    server = CoeServer(build_od(io_description()), 128, lambda: 0x02)
    codes = {int(c) for c in SdoAbortCode}
    try:
        replies = server.handle(coe_header(service) + body)
    except FrameFormatError:
        return
    if service == 0x02:
        client_abort = body[0] >> 5 == 4
        assert len(replies) == (0 if client_abort else 1)
    else:
        assert service == 0x08 and replies      # other services are not served (FrameFormatError above)
    for reply in replies:
        kind = reply[1] >> 4
        assert kind in (2, 3, 8) and len(reply) <= 128 - 6
        if kind == 2:
            assert reply[2] == 0x80 and int.from_bytes(reply[6:10], "little") in codes
        if kind == 8 and reply[2] & 0x7F == 7:
            assert int.from_bytes(reply[6:10], "little") in codes


@settings(max_examples=200, deadline=None)
@given(st.lists(datagram, min_size=1, max_size=3), st.binary(max_size=30))
def test_trailing_bytes_after_the_datagrams_are_ignored(dgs: list[Datagram], garbage: bytes) -> None:
    """Ethernet padding (or anything) after the EtherCAT length does not change the datagrams."""
    raw = encode_frame(Frame(tuple(dgs)))
    assert decode_frame(raw + garbage).datagrams == decode_frame(raw).datagrams == tuple(dgs)
