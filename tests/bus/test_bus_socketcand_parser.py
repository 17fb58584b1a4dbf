"""The socketcand protocol core (gatewaylab/bus/socketcand.py) against upstream's doc/protocol.md and
src/state_*.c (linux-can/socketcand): golden vectors, byte-by-byte feeding, trailing garbage, and a
property test that nothing but protocol events comes out (issue 24, socketcand server)."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.bus import socketcand as sc
from gatewaylab.bus.frame import CanFrame


def opened(mode: sc.Mode = sc.Mode.BCM) -> sc.Session:
    s = sc.Session(("can0",))
    s.feed(b"< open can0 >")
    if mode is sc.Mode.RAW:
        s.feed(b"< rawmode >")
    return s


def test_handshake_as_python_can_does_it() -> None:
    """protocol.md 'Mode NO_BUS': '< hi >' greets, '< open can0 >' -> '< ok >' (BCM mode),
    '< rawmode >' -> '< ok >' (state_raw.c: a mode switch answers '< ok >')."""
    s = sc.Session(("can0",))
    assert s.greeting() == b"< hi >"
    assert s.feed(b"< open can0 >") == [sc.Opened("can0"), sc.Reply(b"< ok >")]
    assert s.mode is sc.Mode.BCM
    assert s.feed(b"< rawmode >") == [sc.ModeChanged(sc.Mode.RAW), sc.Reply(b"< ok >")]
    assert s.feed(b"< bcmmode >") == [sc.ModeChanged(sc.Mode.BCM), sc.Reply(b"< ok >")]


def test_unknown_bus_is_refused_and_the_connection_ends() -> None:
    """state_nobus.c: a bus not served -> '< error could not open bus >', STATE_SHUTDOWN."""
    s = sc.Session(("can0",))
    events = s.feed(b"< open vcan9 >< open can0 >")
    assert events == [sc.Close(b"< error could not open bus >", "client asked for bus 'vcan9'")]
    assert s.closed and s.feed(b"< open can0 >") == []


def test_bit_timing_and_control_mode_are_refused() -> None:
    """state_nobus.c '< can0 B ... >' / '< can0 C ... >': a configuration the interface refuses answers
    '< error configuring interface can0 >' and ends the connection (a rig bus's timing is its file's)."""
    s = sc.Session(("can0",))
    [close] = s.feed(b"< can0 B 1000000 875 0 0 0 0 0 0 >")
    assert isinstance(close, sc.Close) and close.data == b"< error configuring interface can0 >"
    s = sc.Session(("can0",))
    [close] = s.feed(b"< can0 X 1 >")
    assert isinstance(close, sc.Close) and close.data == b"< configuration operation not supported X >"


def test_unknown_commands_get_the_upstream_error() -> None:
    """state_raw.c / state_bcm.c / state_nobus.c: anything else -> '< error unknown command >'; a switch
    to the mode already in force is such a command (state_changed() is false)."""
    unknown = sc.Reply(b"< error unknown command >")
    assert sc.Session(("can0",)).feed(b"< echo >") == [unknown]
    s = opened(sc.Mode.RAW)
    assert s.feed(b"< rawmode >") == [unknown]
    assert s.feed(b"< subscribe 0 0 123 >") == [unknown]     # BCM only
    assert s.feed(b"< isotpmode >") == [unknown]             # not served (docs/decisions.md)
    assert s.feed(b"<>") == [unknown]
    assert opened().feed(b"< fdsend 123 0 1 aa >") == [unknown]   # CAN FD only in RAW mode


def test_echo() -> None:
    """protocol.md 'Echo command': '< echo >' is returned as it is, in BCM and RAW mode."""
    assert opened().feed(b"< echo >") == [sc.Reply(b"< echo >")]
    assert opened(sc.Mode.RAW).feed(b"< echo >") == [sc.Reply(b"< echo >")]


def test_send_golden_vectors() -> None:
    """protocol.md 'Send a single frame': '< send 123 0 >', '< send 1AAAAAAA 2 1 f1 >' (8 id digits:
    extended), and python-can's own form (hex DLC, unpadded lowercase bytes)."""
    s = opened(sc.Mode.RAW)
    assert s.feed(b"< send 123 0 >") == [sc.SendFrame(CanFrame(0x123))]
    assert s.feed(b"< send 1AAAAAAA 2 1 f1 >") == [sc.SendFrame(CanFrame(0x1AAAAAAA, b"\x01\xf1", extended=True))]
    assert s.feed(b"< send 00000123 1 ff >") == [sc.SendFrame(CanFrame(0x123, b"\xff", extended=True))]
    assert s.feed(b"< send 601 8 40 0 10 0 0 0 0 0 >") == [
        sc.SendFrame(CanFrame(0x601, bytes([0x40, 0, 0x10, 0, 0, 0, 0, 0])))]


def test_fd_send_both_upstream_dialects() -> None:
    """CAN FD in RAW mode: '< fdsend ID FLAGS LEN b ... >' (socketcand pull request 33, FLAGS: canfd_frame
    flags, BRS 0x01 ESI 0x02) and '< sendfd ID LEN b ... >' (branch rawmode-canfd, LEN decimal)."""
    s = opened(sc.Mode.RAW)
    data = bytes(range(12))
    text = " ".join(f"{b:x}" for b in data).encode()
    assert s.feed(b"< fdsend 123 1 12 " + text + b" >") == [sc.SendFrame(CanFrame(0x123, data, fd=True, brs=True))]
    assert s.feed(b"< sendfd 1FFFFFFF 12 " + text + b" >") == [
        sc.SendFrame(CanFrame(0x1FFFFFFF, data, extended=True, fd=True))]


def test_bcm_jobs_and_subscriptions_golden_vectors() -> None:
    """protocol.md 'Mode BCM' examples: add (every 1 s, every 10 us), update, delete, subscribe,
    unsubscribe."""
    s = opened()
    frame = CanFrame(0x123, bytes.fromhex("1122334455667788"))
    assert s.feed(b"< add 1 0 123 8 11 22 33 44 55 66 77 88 >") == [sc.AddJob(frame, 1.0)]
    assert s.feed(b"< add 0 10 123 8 11 22 33 44 55 66 77 88 >") == [sc.AddJob(frame, 10e-6)]
    assert s.feed(b"< update 123 3 11 22 33 >") == [sc.UpdateJob(CanFrame(0x123, b"\x11\x22\x33"))]
    assert s.feed(b"< delete 123 >") == [sc.DeleteJob(0x123, False)]
    assert s.feed(b"< subscribe 1 500000 123 >") == [sc.Subscribe(0x123, False, 1.5)]
    assert s.feed(b"< unsubscribe 1AAAAAAA >") == [sc.Unsubscribe(0x1AAAAAAA, True)]


def test_syntax_errors_are_events_not_answers() -> None:
    """state_raw.c: a malformed send is only logged (PRINT_ERROR), nothing is answered: DLC > 8, fewer
    bytes than the DLC, not hex, an 11-bit id above 0x7FF, a CAN FD length no DLC encodes."""
    s = opened(sc.Mode.RAW)
    for bad in (b"< send 123 9 1 2 3 4 5 6 7 8 9 >", b"< send 123 2 1 >", b"< send 12g 0 >",
                b"< send 800 0 >", b"< send 123 1 100 >", b"< send 0x12 0 >", b"< send 1_0 0 >",
                b"< sendfd 123 9 1 2 3 4 5 6 7 8 9 >", b"< send >", b"< send 123 A >"):
        [ev] = s.feed(bad)
        assert isinstance(ev, sc.SyntaxErrorEvent), bad
    assert s.syntax_errors == 10 and not s.closed


def test_byte_by_byte_feeding_gives_the_same_events() -> None:
    """receive_command(): an element is complete at its '>' however the bytes arrive."""
    stream = (b"< open can0 >< rawmode >< send 123 2 aa bb >< echo >"
              b"< fdsend 00000042 3 8 1 2 3 4 5 6 7 8 >")
    whole = sc.Session(("can0",)).feed(stream)
    s = sc.Session(("can0",))
    pieces = [ev for i in range(len(stream)) for ev in s.feed(stream[i:i + 1])]
    assert pieces == whole
    assert [type(e) for e in whole] == [sc.Opened, sc.Reply, sc.ModeChanged, sc.Reply, sc.SendFrame, sc.Reply,
                                        sc.SendFrame]


def test_garbage_between_and_after_elements_is_dropped() -> None:
    """receive_command(): bytes before a '<' are dropped; text after the last '>' without a '<' is
    garbage; a '<' waits for its '>'."""
    s = opened(sc.Mode.RAW)
    assert s.feed(b"junk\r\n< send 123 0 >\nmore junk") == [sc.SendFrame(CanFrame(0x123))]
    assert s.feed(b"\xff\x00< echo") == []
    assert s.feed(b" >trailing") == [sc.Reply(b"< echo >")]


def test_an_element_that_never_ends_closes_the_connection() -> None:
    """receive_command(): the buffer is MAXLEN (2 * 4095 + 100) bytes; a full buffer without '>' ends it."""
    s = opened(sc.Mode.RAW)
    assert s.feed(b"< send " + b"1" * 4000) == []
    [close] = s.feed(b"1" * (sc.MAX_ELEMENT - 4000))
    assert isinstance(close, sc.Close) and close.data == b""


def test_frames_out_golden_vectors() -> None:
    """protocol.md 'Frame transmission' example '< frame 123 23.424242 1A220344 >' (RAW: padded upper
    hex without spaces); state_bcm.c puts '%02X ' per byte; state_raw.c '< error %03X sec.usec >';
    CAN FD (PR 33) '< fdframe ID FLAGS sec.usec DATA >'."""
    assert sc.raw_frame(CanFrame(0x123, bytes.fromhex("1A220344")), 23.424242) == b"< frame 123 23.424242 1A220344 >"
    assert sc.raw_frame(CanFrame(0x123), 1.5) == b"< frame 123 1.500000  >"
    assert sc.raw_frame(CanFrame(0x1AAAAAAA, b"\x01", extended=True), 0.0000004) == \
        b"< frame 1AAAAAAA 0.000000 01 >"
    assert sc.bcm_frame(CanFrame(0x123, b"\x11\x22"), 2.0) == b"< frame 123 2.000000 11 22  >"
    assert sc.error_frame(sc.CAN_ERR_BUSOFF, 1795000000.25) == b"< error 040 1795000000.250000 >"
    fd = CanFrame(0x42, bytes(range(12)), fd=True, brs=True, esi=True)
    assert sc.raw_frame(fd, 3.9999999) == b"< fdframe 042 03 4.000000 000102030405060708090A0B >"


EVENT_TYPES = (sc.Reply, sc.Close, sc.Opened, sc.ModeChanged, sc.SendFrame, sc.AddJob, sc.UpdateJob, sc.DeleteJob,
               sc.Subscribe, sc.Unsubscribe, sc.SyntaxErrorEvent)
WORDS = [b"<", b">", b" ", b"open", b"can0", b"rawmode", b"bcmmode", b"send", b"sendfd", b"fdsend", b"add",
         b"update", b"delete", b"subscribe", b"unsubscribe", b"echo", b"123", b"1AAAAAAA", b"8", b"64", b"ff",
         b"0", b"B", b"C", b"\x00", b"\xff", b"-1", b"99999999999999999999999"]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.sampled_from(WORDS), st.binary(max_size=12)), max_size=60),
       st.integers(min_value=1, max_value=17))
def test_any_input_gives_only_protocol_events(parts: list[bytes], chunk: int) -> None:
    """Whatever a client sends, the core answers with socketcand events (never an exception), in any
    chunking, and a closed session stays closed."""
    data = b"".join(parts)
    s = sc.Session(("can0",))
    events = [ev for i in range(0, len(data), chunk) for ev in s.feed(data[i:i + chunk])]
    assert all(isinstance(ev, EVENT_TYPES) for ev in events)
    closes = [i for i, ev in enumerate(events) if isinstance(ev, sc.Close)]
    assert closes in ([], [len(events) - 1])
    assert events == sc.Session(("can0",)).feed(data)


def test_python_can_fd_messages_come_as_send_with_a_hex_length() -> None:
    """python-can's client (socketcand.py convert_can_message_to_ascii_message) writes every message as
    '< send ID LEN b ... >' with LEN = the DLC field in hex: over 8 bytes that is a CAN FD frame
    (no bit rate switch: the client cannot say it), LEN read as hex or decimal when the bytes agree."""
    s = opened(sc.Mode.RAW)
    data = bytes(range(12))
    text = " ".join(f"{b:x}" for b in data).encode()
    assert s.feed(b"< send 123 C " + text + b" >") == [sc.SendFrame(CanFrame(0x123, data, fd=True))]
    assert s.feed(b"< send 123 12 " + text + b" >") == [sc.SendFrame(CanFrame(0x123, data, fd=True))]
    big = bytes(64)
    assert s.feed(b"< send 1FFFFFFF 40 " + b"0 " * 64 + b">") == [
        sc.SendFrame(CanFrame(0x1FFFFFFF, big, extended=True, fd=True))]
    for bad in (b"< send 123 C " + text[:-2] + b" >",          # 11 bytes: no CAN FD length
                b"< send 123 8 " + text + b" >"):              # LEN says 8, 12 bytes follow
        [ev] = s.feed(bad)
        assert isinstance(ev, sc.SyntaxErrorEvent), bad


def test_a_client_asks_for_can_fd_with_rawmode_fd_or_by_sending_fd() -> None:
    """'< fdframe >' only for a client that asked: '< rawmode fd >' (this server's extension; upstream
    answers '< error unknown command >', so a client can probe) switches to RAW and asks; an fdsend/sendfd
    of the client's own says it speaks FD too. '< rawmode >' alone (python-can's handshake) does not."""
    s = opened(sc.Mode.RAW)
    assert not s.fd
    s = opened()
    assert s.feed(b"< rawmode fd >") == [sc.ModeChanged(sc.Mode.RAW), sc.Reply(b"< ok >")]
    assert s.fd and s.mode is sc.Mode.RAW
    assert s.feed(b"< rawmode fd >") == [sc.Reply(b"< ok >")]
    s = opened(sc.Mode.RAW)
    s.feed(b"< sendfd 123 12 " + b"0 " * 12 + b">")
    assert s.fd
