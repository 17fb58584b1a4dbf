"""MCAN channel configuration, node modes, filters and Message RAM (ECAN-Lite manual 13.4, 5.4.3 E)."""

from __future__ import annotations

import pytest
from ecanlite_mcan_kit import make_rig

from gatewaylab.bus import CanFrame, ErrorFrameEvent, ErrorKind
from gatewaylab.devices.ecanlite.mcan import NodeMode


def test_phase_e_apply_ok_retimes_controller() -> None:
    """5.4.3 E1..E32: CAN FD ISO 1 Mbit/s / 5 Mbit/s, 87.5 % both phases, apply -> 0x8001:02 = 0;
    the controller runs at the applied rates (13.4 'apply the current SDO configuration to the
    runtime MCAN channel')."""
    rig = make_rig()
    assert rig.configure(0, 1_000_000, 5_000_000, 875, s62=48, s64=12, s65=7, s66=7, s67=12, s68=7,
                         s69=0, s70=32, s71=0, s72=7, s73=32) == 0
    ctrl = rig.model.channels[0].controller
    assert ctrl is not None
    assert (ctrl.bitrate, ctrl.data_bitrate, ctrl.fd) == (1_000_000, 5_000_000, True)
    assert rig.model.channels[0].fd
    assert rig.r(0x9000, 9) & 0x0F == 0x0A          # status: run, fd_enabled
    # command sequence counts completed commands
    assert rig.r(0x8001, 5) >= 1


def test_bad_config_keeps_old() -> None:
    """13.4: 'If the configuration is illegal or exceeds the per-channel Message RAM budget, Apply
    status reports an error and the runtime channel does not switch to the new layout'."""
    rig = make_rig()
    assert rig.configure(0, 1_000_000, 5_000_000) == 0
    ctrl = rig.model.channels[0].controller
    assert ctrl is not None
    # 64 x 64 B FIFO0 elements on top of the default layout: over the RAM budget -> build fail 3
    rig.w(0x8001, 62, 64)
    rig.w(0x8001, 19, 250_000)
    rig.w(0x8001, 1, 1)
    assert rig.r(0x8001, 2) == 3
    assert ctrl.bitrate == 1_000_000
    assert rig.model.channels[0].runtime is not None
    assert rig.model.channels[0].runtime.rx_fifo0 == 48
    # classic data sizes free the RAM: the same counts now fit
    for s in (65, 66, 68, 72):
        rig.w(0x8001, s, 0)
    rig.w(0x8001, 1, 1)
    assert rig.r(0x8001, 2) == 0
    assert ctrl.bitrate == 250_000


@pytest.mark.parametrize(("sub", "value", "status"), [
    (8, 4, 1),          # node mode outside 0..3: fail
    (7, 2, 1),          # bit timing mode outside 0/1
    (19, 3_000_000, 3),  # nominal rate the 80 MHz clock cannot make: build fail
    (72, 8, 3),         # data size enum outside 0..7
    (70, 40, 3),        # more than 32 TX elements
])
def test_apply_status_codes(sub: int, value: int, status: int) -> None:
    """13.4 Apply status: 1 fail, 3 build fail (configuration conversion failed); old config kept."""
    rig = make_rig()
    before = rig.model.channels[0].runtime
    rig.w(0x8001, sub, value)
    rig.w(0x8001, 1, 1)
    assert rig.r(0x8001, 2) == status
    assert rig.model.channels[0].runtime is before


def test_manual_bit_timing_mode() -> None:
    """13.4 SI7 = 1: SI25..32 are used; SI19/20 are ignored."""
    rig = make_rig()
    for sub, v in ((7, 1), (19, 123), (25, 1), (26, 69), (27, 10), (28, 10), (29, 1), (30, 13), (31, 2), (32, 2)):
        rig.w(0x8001, sub, v)
    rig.w(0x8001, 1, 1)
    assert rig.r(0x8001, 2) == 0
    rt = rig.model.channels[0].runtime
    assert rt is not None and rt.nominal_bitrate == 1_000_000 and rt.data_bitrate == 5_000_000
    rig.w(0x8001, 26, 0)
    rig.w(0x8001, 1, 1)
    assert rig.r(0x8001, 2) == 3


def test_tdc_forced_in_register() -> None:
    """13.4 / 14.3: at 5M the firmware forces TDC on even with 0x8001:16 = 0 (DBTP.TDC, TDCR)."""
    rig = make_rig()
    assert rig.configure(0, 1_000_000, 5_000_000, s16=0) == 0
    rig.w(0xA000, 1, 0x000C)
    rig.w(0xA000, 2, 1)
    assert rig.r(0xA000, 3) == 0
    assert rig.r(0xA000, 5) >> 23 & 1
    rig.w(0xA000, 1, 0x0048)
    rig.w(0xA000, 2, 1)
    assert rig.r(0xA000, 5) == (14 << 8) | 14


def test_wrong_bitrate_hears_nothing_sees_errors() -> None:
    """16.3 'Are the baud rate, sample point ... consistent with the peer end?': a channel at
    another rate receives nothing and its error counters move (REC in 0x9000:01 ECR)."""
    rig = make_rig()
    assert rig.configure(0, 500_000, 2_000_000, 800) == 0       # the bus runs 1M/5M
    rig.buses[0].attach("acker")                               # a third node acknowledges
    for i in range(5):
        rig.peers[0].send(CanFrame(0x100 + i, b"\x01"))
    rig.run()
    ch = rig.model.channels[0]
    assert ch.pending_rx() == 0
    ecr = rig.r(0x9000, 1)
    assert (ecr >> 8) & 0x7F == 5                      # REC counted one per frame
    assert rig.r(0x9000, 2) & 7 == 2                   # PSR.LEC = form error
    # and its own frames never make it: bit errors until bus-off, reported as BUS_OFF results
    assert ch.submit(CanFrame(0x55, b"\x00"), "x") == 0
    rig.run(0.1)
    assert ("x", 5) in ch.take_tx_results()
    assert all(f.can_id != 0x55 for f, _ in rig.recorders[0].frames)
    assert rig.r(0x9000, 15) >= 1                      # bus-off counter (auto recovery since)
    # back at the bus's rate (the apply restarts the MCAN, ending bus-off) it hears again
    assert rig.configure(0, 1_000_000, 5_000_000) == 0
    rig.peers[0].send(CanFrame(0x222, b"\x02"))
    rig.run()
    assert [r.frame.can_id for r in ch.peek(8)] == [0x222]


def test_listen_mode_never_acks() -> None:
    """13.4 node mode 3 'listen': receives without acknowledging or sending (Controller
    listen_only): a lone peer gets ACK errors, the channel still sees the frames."""
    rig = make_rig()
    assert rig.configure(0, s8=NodeMode.LISTEN) == 0
    ch = rig.model.channels[0]
    assert ch.controller is not None and ch.controller.listen_only
    rig.peers[0].send(CanFrame(0x123, b"\x01"))
    rig.run(0.002)
    acks = [e for e in rig.recorders[0].events if isinstance(e, ErrorFrameEvent) and e.kind is ErrorKind.ACK]
    assert acks
    assert ch.submit(CanFrame(0x1, b""), None) == 3            # listen mode cannot send
    assert rig.r(0x9000, 9) & 7 == 5                           # state = listen


def test_internal_loopback() -> None:
    """13.4 node mode 2 'internal loopback': own frames come back to the channel, not on the bus."""
    rig = make_rig()
    assert rig.configure(0, s8=NodeMode.INTERNAL_LOOPBACK) == 0
    ch = rig.model.channels[0]
    assert ch.submit(CanFrame(0x321, b"\xAA"), "L") == 0
    rig.run()
    assert ch.take_tx_results() == [("L", 0)]
    assert [r.frame.can_id for r in ch.peek(8)] == [0x321]
    assert rig.recorders[0].frames == []


def test_disable_auto_retransmission_single_shot() -> None:
    """13.4 SI18 = 1 'Disable MCAN automatic retransmission': a frame nobody acknowledges is sent
    once and given up (TX_RESULT bus busy)."""
    rig = make_rig()
    assert rig.configure(0, s18=1) == 0
    rig.buses[0].detach(rig.peers[0])
    ch = rig.model.channels[0]
    assert ch.submit(CanFrame(0x10, b"\x01"), "s") == 0
    rig.run()
    assert ch.take_tx_results() == [("s", 2)]
    assert ch.controller is not None and ch.controller.tec == 8


def _filter(rig: object, ext: bool, index: int, ftype: int, action: int, id1: int, id2: int) -> None:
    base = 56 if ext else 50
    r = rig  # type: ignore[assignment]
    r.w(0x8001, 44 if ext else 43, index)  # type: ignore[attr-defined]
    for off, v in enumerate((ftype, action, 0, id1, id2)):
        r.w(0x8001, base + off, v)  # type: ignore[attr-defined]
    r.w(0x8001, 46 if ext else 45, 2)  # type: ignore[attr-defined]


def test_filters_and_non_match_rules() -> None:
    """13.4 filter editing window: count, index, type/action/id, entry cmd 2 save, apply;
    non-matching standard frames rejected with SI36 = 2, extended accepted (SI37 = 0), remote
    frames rejected with SI38 = 1."""
    rig = make_rig()
    rig.w(0x8001, 49, 2)
    _filter(rig, False, 0, 0, 1, 0x100, 0x10F)      # range 0x100..0x10F -> FIFO0
    _filter(rig, False, 1, 1, 3, 0x105, 0x200)      # dual id, reject (0x105 already accepted above)
    assert rig.r(0x8001, 47) == 0
    rig.w(0x8001, 55, 1)
    _filter(rig, True, 0, 2, 3, 0x1ABCDE00, 0x1FFFFF00)   # classic mask: reject 0x1ABCDExx
    assert rig.configure(0, s36=2, s37=0, s38=1) == 0
    frames = [CanFrame(0x105, b"\x01"), CanFrame(0x200, b"\x02"), CanFrame(0x300, b"\x03"),
              CanFrame(0x101, rtr=True, dlc=1), CanFrame(0x1ABCDE12, b"\x04", extended=True),
              CanFrame(0x1ABCDF12, b"\x05", extended=True)]
    for f in frames:
        rig.peers[0].send(f)
    rig.run()
    got = [(r.frame.can_id, r.frame.extended) for r in rig.model.channels[0].peek(32)]
    assert got[:1] == [(0x105, False)]
    rig.w(0x8021, 5, 8)
    rig.w(0x8021, 2, 1)
    got = [(r.frame.can_id, r.frame.extended) for r in rig.model.channels[0].peek(32)]
    assert got == [(0x105, False), (0x1ABCDF12, True)]


def test_entry_cmd_status_and_load() -> None:
    """13.4 Entry cmd 1 load / 3 clear, Entry status 1 'index is invalid' / 2 'command invalid';
    Std filter count above Std list max (64) is refused."""
    rig = make_rig()
    _filter(rig, False, 3, 2, 1, 0x80, 0x7F0)
    rig.w(0x8001, 50, 0)
    rig.w(0x8001, 53, 0)
    rig.w(0x8001, 45, 1)                             # load index 3 into the window
    assert (rig.r(0x8001, 50), rig.r(0x8001, 53), rig.r(0x8001, 54)) == (2, 0x80, 0x7F0)
    rig.w(0x8001, 43, 64)
    rig.w(0x8001, 45, 2)
    assert rig.r(0x8001, 47) == 1
    rig.w(0x8001, 44, 24)
    rig.w(0x8001, 46, 1)
    assert rig.r(0x8001, 48) == 1
    rig.w(0x8001, 45, 9)
    assert rig.r(0x8001, 47) == 2
    rig.w(0x8001, 43, 3)
    rig.w(0x8001, 45, 3)                             # clear
    rig.w(0x8001, 45, 1)
    assert rig.r(0x8001, 47) == 0 and rig.r(0x8001, 51) == 0
    from gatewaylab.od import SdoAbort
    with pytest.raises(SdoAbort):
        rig.w(0x8001, 49, 65)
    with pytest.raises(SdoAbort):
        rig.w(0x8001, 55, 25)
    assert rig.r(0x8001, 41) == 64 and rig.r(0x8001, 42) == 24


def test_element_data_size_truncates_and_pads() -> None:
    """13.4 data size 'only define the maximum data bytes stored in one MCAN Message RAM element':
    an 8-byte RX element keeps 8 bytes of a 16-byte FD frame (the rest reads 0); a TX element
    shorter than the frame is sent padded with 0xCC (M_CAN)."""
    rig = make_rig()
    assert rig.configure(0, s65=0, s72=0) == 0
    rig.peers[0].send(CanFrame(0x10, bytes(range(1, 17)), fd=True, brs=True))
    rig.run()
    (got,) = rig.model.channels[0].peek(8)
    assert got.frame.data == bytes(range(1, 9)) + bytes(8)
    assert rig.model.channels[0].submit(CanFrame(0x11, bytes(range(12)), fd=True), None) == 0
    rig.run()
    sent = rig.recorders[0].frames[-1][0]
    assert sent.data == bytes(range(8)) + b"\xCC" * 4


def test_classic_channel_refuses_fd_frames() -> None:
    """13.4 SI15 = 0 classic CAN: an FD frame cannot be sent (invalid channel result)."""
    rig = make_rig()
    assert rig.configure(0, 1_000_000, None) == 0
    ch = rig.model.channels[0]
    assert ch.classic and not ch.fd
    assert ch.submit(CanFrame(0x1, bytes(12), fd=True), None) == 3
    assert ch.submit(CanFrame(0x1, bytes(8)), "c") == 0
    rig.run()
    assert ch.take_tx_results() == [("c", 0)]


def test_unconnected_channel() -> None:
    """Issue 10: fewer controllers than 4 leave the rest unconnected: status word state 0."""
    rig = make_rig(channels=1)
    ch = rig.model.channels[3]
    assert ch.controller is None and not ch.enabled
    assert ch.status_word() & 7 == 0
    assert ch.submit(CanFrame(0x1, b""), None) == 3
    assert rig.configure(3) == 0                     # the configuration is still accepted


def test_tx_queue_mode_sends_by_priority() -> None:
    """13.4 SI69 '0=FIFO, 1=Queue; Queue is sorted by CAN ID arbitration priority'."""
    for mode, want in ((0, [0x300, 0x100, 0x200]), (1, [0x100, 0x200, 0x300])):
        rig = make_rig()
        assert rig.configure(0, s69=mode) == 0
        ch = rig.model.channels[0]
        for cid in (0x300, 0x100, 0x200):
            assert ch.submit(CanFrame(cid, b"\x01"), cid) == 0
        rig.run()
        assert [f.can_id for f, _ in rig.recorders[0].frames] == want
        assert sorted(ref for ref, _ in ch.take_tx_results()) == [0x100, 0x200, 0x300]  # type: ignore[type-var]


def test_priority_filter_sets_hpms() -> None:
    """13.5 SI8 'HPMS raw': a filter with action 5 (priority + FIFO0) stores the frame and reports
    the filter index and list in HPMS, IR.HPM set."""
    rig = make_rig()
    rig.w(0x8001, 55, 3)
    _filter(rig, True, 2, 1, 5, 0x1234567, 0x1234568)
    assert rig.configure(0) == 0
    rig.peers[0].send(CanFrame(0x1234568, b"\x09", extended=True))
    rig.run()
    assert rig.r(0x9000, 8) == (2 << 8) | (1 << 15) | (2 << 6)
    assert rig.r(0x9000, 3) >> 8 & 1
    assert [r.frame.can_id for r in rig.model.channels[0].peek(8)] == [0x1234568]


def test_restricted_mode_acks_but_never_sends() -> None:
    """13.4 node mode 1 'Restricted/monitor': the channel receives and acknowledges (a lone peer's
    frame is delivered without ACK errors) but transmits nothing."""
    rig = make_rig()
    assert rig.configure(0, s8=NodeMode.RESTRICTED) == 0
    ch = rig.model.channels[0]
    rig.peers[0].send(CanFrame(0x123, b"\x01"))
    rig.run()
    assert not [e for e in rig.recorders[0].events if isinstance(e, ErrorFrameEvent)]
    assert [r.frame.can_id for r in ch.peek(8)] == [0x123]
    assert ch.submit(CanFrame(0x1, b""), None) == 3
    assert ch.status_word() & 7 == 5


def test_install_twice_hooks_once() -> None:
    """Installing the same dictionary again refreshes values without doubling the hooks (one apply
    = one command sequence step, 13.4 SI5)."""
    rig = make_rig()
    rig.model.install(None, rig.od)
    seq = rig.r(0x8001, 5)
    rig.w(0x8001, 1, 1)
    assert rig.r(0x8001, 5) == seq + 1
