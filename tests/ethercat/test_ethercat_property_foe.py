"""Property tests of the FoE server and the mailbox endpoint on bytes from outside (ETG.1000.6 FoE,
ETG.1000.4 mailbox header; issue 15: only the documented error types come out, the slave keeps serving)."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.ethercat.errors import FoeErrorCode, FrameFormatError
from gatewaylab.ethercat.foe import FOE_HEADER, FoeFiles, FoeOpcode, FoeServer, foe_packet
from gatewaylab.ethercat.mailbox import MailboxEndpoint, MailboxMessage, MailboxType, decode_mailbox, encode_mailbox

MBX = 128
OPCODES = st.one_of(st.sampled_from([int(o) for o in FoeOpcode]), st.integers(0, 255))
packet = st.one_of(
    st.binary(max_size=8),
    st.builds(lambda op, word, rest: FOE_HEADER.pack(op, 0, word) + rest, OPCODES,
              st.one_of(st.integers(0, 4), st.integers(0, 0xFFFFFFFF)), st.binary(max_size=MBX)),
)
ERROR_CODES = {int(c) for c in FoeErrorCode}


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(packet, min_size=1, max_size=12))
def test_foe_server_answers_spec_packets_or_raises_frame_format_error(packets: list[bytes]) -> None:
    """Any packet sequence: the server raises only FrameFormatError (a packet shorter than the FoE header,
    answered as a mailbox error), every reply is an FoE packet that fits the mailbox, errors carry an
    ETG.1000.6 FoE error code, and a clean write + read round trip works afterwards."""
    files = FoeFiles()
    server = FoeServer(files, MBX)
    for p in packets:
        try:
            replies = server.handle(p)
        except FrameFormatError:
            assert len(p) < FOE_HEADER.size
            continue
        for r in replies:
            assert len(r) <= MBX - 6 and r[0] in {int(o) for o in FoeOpcode}
            if r[0] == FoeOpcode.ERR:
                assert int.from_bytes(r[2:6], "little") in ERROR_CODES
    data = bytes(range(256)) * 2
    assert server.handle(foe_packet(FoeOpcode.WRQ, 0, b"after.bin")) == [foe_packet(FoeOpcode.ACK, 0)]
    step = MBX - 6 - FOE_HEADER.size
    chunks = [data[i:i + step] for i in range(0, len(data), step)] + [b""]
    for n, chunk in enumerate(chunks, 1):
        assert server.handle(foe_packet(FoeOpcode.DATA, n, chunk)) == [foe_packet(FoeOpcode.ACK, n)]
        if len(chunk) < step:
            break
    assert files.files["after.bin"] == data


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_mailbox_header_decoder_raises_only_frame_format_error(raw: bytes) -> None:
    """ETG.1000.4 mailbox header: a buffer shorter than the header or whose length field exceeds it is
    FrameFormatError; anything else decodes to a message of at most the buffer's payload."""
    try:
        msg = decode_mailbox(raw)
    except FrameFormatError:
        return
    assert len(msg.data) <= len(raw) - 6


@settings(max_examples=100, deadline=None)
@given(st.lists(st.binary(max_size=140), min_size=1, max_size=10))
def test_mailbox_endpoint_keeps_serving_after_garbage(buffers: list[bytes]) -> None:
    """Whatever the master writes into the mailbox, the endpoint never raises and a well-formed CoE
    request afterwards still reaches its handler and gets its answer queued."""
    sent: list[bytes] = []
    ep = MailboxEndpoint(lambda raw: sent.append(raw) or True)
    got: list[bytes] = []

    def coe(data: bytes) -> list[bytes]:
        got.append(data)
        return [b"answer"]

    ep.handlers[MailboxType.COE] = coe
    for b in buffers:
        ep.received(b.ljust(MBX, b"\0")[:MBX])
        ep.pump()
    got.clear()
    ep.reset()
    ep.received(encode_mailbox(MailboxMessage(MailboxType.COE, b"\x00\x20request", 3)).ljust(MBX, b"\0"))
    ep.pump()
    assert got == [b"\x00\x20request"]
