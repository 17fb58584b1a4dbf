"""The MCAN data-path controls that act on the channel: TX budgets (13.2.2 SI11/12), RX FIFO0 /
FIFO1 / RX buffer routing with element counts, op modes and status (13.4 SI61..68, 13.5 RXFnS)
and register-service writes that re-program the channel (13.6 write whitelist)."""

from __future__ import annotations

from ecanlite_mcan_kit import Rig, make_rig
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.bus import CanFrame
from gatewaylab.devices.ecanlite.mcan import WRITE_WHITELIST, ChannelState, NodeMode

# M_CAN IR bits (13.5 'IR raw').
RF0N, RF1N, RF1F, RF1L = 1 << 0, 1 << 4, 1 << 6, 1 << 7


def _policy(rig: Rig, k: int = 0, **subs: int) -> int:
    for name, value in subs.items():
        rig.w(0x8021 + k, int(name[1:]), value)
    rig.w(0x8021 + k, 2, 1)
    return rig.r(0x8021 + k, 3)


def _filter(rig: Rig, index: int, ftype: int, action: int, id1: int, id2: int, *, ext: bool = False) -> None:
    """13.4 'Typical filter configuration process' steps 3-5 for one element."""
    base = 56 if ext else 50
    rig.w(0x8001, 44 if ext else 43, index)
    for off, v in enumerate((ftype, action, 0, id1, id2)):
        rig.w(0x8001, base + off, v)
    rig.w(0x8001, 46 if ext else 45, 2)
    assert rig.r(0x8001, 48 if ext else 47) == 0


def _reg(rig: Rig, cmd: int, offset: int, value: int = 0, k: int = 0) -> int:
    """13.6 'Write register process': offset, value, command; the status."""
    rig.w(0xA000 + k, 1, offset)
    rig.w(0xA000 + k, 4, value)
    rig.w(0xA000 + k, 2, cmd)
    return rig.r(0xA000 + k, 3)


def _sent(rig: Rig) -> list[int]:
    return [f.can_id for f, _ in rig.recorders[0].frames]


# --------------------------------------------------------------------------------- TX budgets (13.2.2)
def test_tx_budget_max_limits_frames_per_cycle() -> None:
    """13.2.2 SI12 'TX budget max: Maximum TX service budget per cycle, 0..8': with max 2, six
    frames submitted in one cycle reach the bus two per cycle, in order; the rest wait in the
    firmware TX ring and count as TX pending (0x9000:11, status word bits 13..15)."""
    rig = make_rig()
    assert rig.configure(0) == 0
    assert _policy(rig, s11=1, s12=2) == 0
    assert rig.r(0x8021, 20) >> 20 & 0xFF == 1 | 2 << 4          # SI20 packs TX min 20..23, max 24..27
    ch = rig.model.channels[0]
    for i in range(6):
        assert ch.submit(CanFrame(0x100 + i, bytes([i])), i) == 0
    assert rig.r(0x9000, 11) == 6 and ch.status_word() >> 13 & 7 == 6
    rig.run()
    assert _sent(rig) == [0x100, 0x101]
    rig.model.on_cycle(rig.clock.now())
    rig.run()
    assert _sent(rig) == [0x100, 0x101, 0x102, 0x103]
    rig.model.on_cycle(rig.clock.now())
    rig.run()
    assert _sent(rig) == [0x100 + i for i in range(6)]
    assert [ref for ref, _ in ch.take_tx_results()] == list(range(6))
    assert rig.r(0x9000, 11) == 0


def test_tx_budget_off_when_policy_disabled_and_ring_shares_fifo_capacity() -> None:
    """13.2.2 SI1 Enable = 0 'disable this channel data-path policy': no TX budget, every frame goes
    to the MCAN at once. With the policy on, frames waiting for budget still count against the
    TX FIFO/queue size (13.4 SI70): a full ring answers the TX overflow policy (0 = ResultCode 4)."""
    rig = make_rig()
    assert rig.configure(0, s70=4) == 0
    ch = rig.model.channels[0]
    assert _policy(rig, s12=1, s13=0) == 0
    for i in range(4):
        assert ch.submit(CanFrame(0x10 + i, b"\x01"), i) == 0
    assert ch.submit(CanFrame(0x20, b"\x01"), "over") == 4
    assert rig.r(0x9020, 11) == 1
    rig.run()
    assert _sent(rig) == [0x10]
    assert _policy(rig, s1=0) == 0
    rig.model.on_cycle(rig.clock.now())          # no budget: the ring empties in one service
    rig.run()
    assert _sent(rig) == [0x10, 0x11, 0x12, 0x13]
    for i in range(4):
        assert ch.submit(CanFrame(0x30 + i, b"\x01"), i) == 0
    rig.run()
    assert _sent(rig)[4:] == [0x30, 0x31, 0x32, 0x33]


def test_tx_ring_frames_end_with_bus_off_result() -> None:
    """13.2.2 / chapter 10: a frame still waiting for TX budget when the channel is bus-off is
    reported with ResultCode 5 'bus off' at the next service, never sent."""
    rig = make_rig()
    assert rig.configure(0) == 0
    assert _policy(rig, s12=1, s14=0) == 0       # manual recovery: stays bus-off
    ch = rig.model.channels[0]
    ctrl = ch.controller
    assert ctrl is not None
    assert ch.submit(CanFrame(0x10, b""), "first") == 0
    assert ch.submit(CanFrame(0x11, b""), "waiting") == 0
    ctrl.tec = 256
    ctrl.bus.detach(rig.peers[0])
    rig.run(0.1)
    assert "waiting" not in dict(ch.take_tx_results())      # still in the TX ring, not in the MCAN
    rig.model.on_cycle(rig.clock.now())
    assert dict(ch.take_tx_results()) == {"waiting": 5}
    assert all(f.can_id != 0x11 for f, _ in rig.recorders[0].frames)


# ------------------------------------------------------------------ RX FIFO0 / FIFO1 / buffers (13.4)
def test_filter_routes_to_fifo1_with_its_own_size_and_blocking_mode() -> None:
    """13.4 SI63/64 'RX FIFO1 op mode 0=blocking ... When full, new frames do not overwrite old
    frames', 'RX FIFO1 size ... can be used with filters for selected frames': a filter with action
    2 (FIFO1) stores 0x200 in FIFO1 (2 elements); the third is lost (RXF1S full + lost, IR RF1L,
    0x9020:07 dropped new) while FIFO0 keeps taking non-matching frames. 13.5 SI5 'RXF1S raw'."""
    rig = make_rig()
    rig.w(0x8001, 49, 1)
    _filter(rig, 0, 1, 2, 0x200, 0x200)                   # dual id 0x200 -> FIFO1
    assert rig.configure(0, s64=2) == 0
    for data in (b"\x01", b"\x02", b"\x03"):
        rig.peers[0].send(CanFrame(0x200, data))
    rig.peers[0].send(CanFrame(0x100, b"\x04"))
    rig.run()
    rxf1s, rxf0s = rig.r(0x9000, 5), rig.r(0x9000, 4)
    assert rxf1s & 0x7F == 2 and rxf1s >> 24 & 1 and rxf1s >> 25 & 1
    assert rxf0s & 0x7F == 1 and not rxf0s >> 24 & 1 and not rxf0s >> 25 & 1
    ir = rig.r(0x9000, 3)
    assert ir & RF1N and ir & RF1F and ir & RF1L and ir & RF0N
    assert rig.r(0x9020, 7) == 1 and rig.r(0x9020, 5) == 1
    assert _policy(rig, s5=8) == 0
    assert [(r.frame.can_id, r.frame.data, r.fifo) for r in rig.model.channels[0].peek(8)] == [
        (0x200, b"\x01", 1), (0x200, b"\x02", 1), (0x100, b"\x04", 0)]
    assert _reg(rig, 1, 0x00B0) == 0 and rig.r(0xA000, 5) >> 16 & 0x7F == 2     # RXF1C F1S
    rig.model.channels[0].consume(3)
    assert rig.r(0x9000, 5) & 0x7F == 0 and rig.r(0x9000, 4) & 0x7F == 0


def test_fifo_overwrite_mode_keeps_the_newest() -> None:
    """13.4 SI61 'RX FIFO0 op mode' (0 = blocking, M_CAN 1 = overwrite): in overwrite mode a full
    FIFO0 gives up its oldest frame for the new one (0x9020:06 dropped old)."""
    rig = make_rig()
    assert rig.configure(0, s61=1, s62=2) == 0
    for i in range(4):
        rig.peers[0].send(CanFrame(0x300 + i, b"\x00"))
    rig.run()
    assert [r.frame.can_id for r in rig.model.channels[0].peek(8)] == [0x302, 0x303]
    assert rig.r(0x9020, 6) == 2 and rig.r(0xA000 + 0, 3) == 0
    assert _reg(rig, 1, 0x00A0) == 0 and rig.r(0xA000, 5) >> 31 == 1        # RXF0C F0OM


def test_non_match_rule_and_rx_buffer_routing() -> None:
    """13.4 SI36 'Accept non-match std' 1 = accept into FIFO1 (M_CAN GFC.ANFS); filter action 7 stores
    into the RX buffers (SI67 'RX buffer count ... used directly only when filters route to RXBUF'):
    with 1 RX buffer the second frame for it is dropped."""
    rig = make_rig()
    rig.w(0x8001, 49, 1)
    _filter(rig, 0, 0, 7, 0x700, 0x7FF)                   # range 0x700..0x7FF -> RX buffer
    assert rig.configure(0, s36=1, s67=1) == 0
    for cid in (0x123, 0x701, 0x702):
        rig.peers[0].send(CanFrame(cid, b"\x01"))
    rig.run()
    assert [(r.frame.can_id, r.fifo) for r in rig.model.channels[0].peek(8)] == [(0x123, 1), (0x701, 2)]
    assert rig.r(0x9000, 5) & 0x7F == 1 and rig.r(0x9000, 4) & 0x7F == 0
    assert rig.r(0x9020, 7) == 1


def test_each_fifo_has_its_element_data_size() -> None:
    """13.4 SI65/66 'RX FIFO0/FIFO1 element data size enumeration ... only define the maximum data
    bytes stored in one MCAN Message RAM element': a 64 B CAN FD frame routed to FIFO1 with data
    size 0 (8 B) keeps 8 bytes and its DLC; the same frame in FIFO0 (64 B) arrives whole."""
    rig = make_rig()
    rig.w(0x8001, 49, 1)
    _filter(rig, 0, 1, 2, 0x222, 0x222)
    assert rig.configure(0, s66=0) == 0
    payload = bytes(range(64))
    rig.peers[0].send(CanFrame(0x222, payload, fd=True))
    rig.peers[0].send(CanFrame(0x111, payload, fd=True))
    rig.run()
    got = {r.frame.can_id: r.frame.data for r in rig.model.channels[0].peek(8)}
    assert got[0x222] == payload[:8] + bytes(56) and got[0x111] == payload


# ------------------------------------------------------------------ register writes re-program (13.6)
def _engineering(rig: Rig) -> None:
    rig.w(0xB000, 1, 1)      # 13.6 step 1 / 13.7: a state that allows debug access


def test_nbtp_write_retimes_the_channel() -> None:
    """13.6 whitelist 'NBTP Nominal bit timing and prescaler': a write re-times the running channel:
    at 500 kbit/s on a 1 Mbit/s bus it hears nothing and sees form errors; writing the 1 Mbit/s
    timing back makes it hear again. 0x8001 keeps the requested configuration."""
    rig = make_rig()
    assert rig.configure(0) == 0
    _engineering(rig)
    ch = rig.model.channels[0]
    ctrl = ch.controller
    assert ctrl is not None
    rig.buses[0].attach("acker")
    nbtp_1m = (10 - 1) << 25 | (1 - 1) << 16 | (69 - 1) << 8 | (10 - 1)
    nbtp_500k = (30 - 1) << 25 | (1 - 1) << 16 | (129 - 1) << 8 | (30 - 1)
    assert _reg(rig, 2, 0x001C, nbtp_500k) == 0
    assert ctrl.bitrate == 500_000
    assert _reg(rig, 1, 0x001C) == 0 and rig.r(0xA000, 5) == nbtp_500k
    rig.peers[0].send(CanFrame(0x123, b"\x01"))
    rig.run()
    assert ch.pending_rx() == 0 and rig.r(0x9000, 2) & 7 == 2          # PSR.LEC form error
    assert rig.r(0x8001, 19) == 1_000_000
    assert _reg(rig, 2, 0x001C, nbtp_1m) == 0
    rig.peers[0].send(CanFrame(0x124, b"\x02"))
    rig.run()
    assert [r.frame.can_id for r in ch.peek(8)] == [0x124]


def test_bad_timing_write_is_denied_and_apply_restores() -> None:
    """13.6 Status 2 'write denied ... not recommended to write through SDO': an NBTP value the MCAN
    cannot run (NTSEG2 field 0 = 1 tq, below M_CAN's 2) changes nothing; 13.4 Apply command 1
    'Apply the current SDO configuration to the runtime MCAN channel' undoes a register write."""
    rig = make_rig()
    assert rig.configure(0) == 0
    _engineering(rig)
    ctrl = rig.model.channels[0].controller
    assert ctrl is not None
    assert _reg(rig, 2, 0x001C, (1 << 16) | (10 << 8) | 0) == 2
    assert ctrl.bitrate == 1_000_000
    assert _reg(rig, 2, 0x001C, (3 << 16) | (14 << 8) | 3) == 0     # 80 MHz / (4 x 20 tq) = 1 Mbit/s
    assert _reg(rig, 2, 0x001C, (7 << 16) | (14 << 8) | 3) == 0     # 500 kbit/s
    assert ctrl.bitrate == 500_000
    rig.w(0x8001, 1, 1)
    assert rig.r(0x8001, 2) == 0 and ctrl.bitrate == 1_000_000


def test_dbtp_write_retimes_the_data_phase() -> None:
    """13.6 whitelist 'DBTP Data bit timing and prescaler': the data rate of the running channel
    follows (2 Mbit/s: DBRP 1, 40 tq); TDC (DBTP bit 23) as written below 5 Mbit/s."""
    rig = make_rig()
    assert rig.configure(0) == 0
    _engineering(rig)
    ctrl = rig.model.channels[0].controller
    assert ctrl is not None and ctrl.data_bitrate == 5_000_000
    dbtp = (1 - 1) << 16 | (31 - 1) << 8 | (8 - 1) << 4 | (8 - 1)
    assert _reg(rig, 2, 0x000C, dbtp) == 0
    assert ctrl.data_bitrate == 2_000_000
    assert _reg(rig, 1, 0x000C) == 0 and rig.r(0xA000, 5) == dbtp


def test_cccr_and_test_writes_change_the_node_mode() -> None:
    """13.6 whitelist 'CCCR CC control' / 'TEST Test register': MON = bus monitoring (listen: no
    send, status state 5), DAR = no automatic retransmission, TEST.LBCK = internal loopback;
    writing the plain CAN FD value back returns to normal operation."""
    rig = make_rig()
    assert rig.configure(0) == 0
    _engineering(rig)
    ch = rig.model.channels[0]
    ctrl = ch.controller
    assert ctrl is not None
    fd = 1 << 8 | 1 << 9
    assert _reg(rig, 2, 0x0018, fd | 1 << 5) == 0
    assert ch.runtime is not None and ch.runtime.node_mode is NodeMode.LISTEN and ctrl.listen_only
    assert ch.state() is ChannelState.LISTEN and ch.submit(CanFrame(0x1, b""), None) == 3
    assert _reg(rig, 2, 0x0018, fd | 1 << 6) == 0
    assert not ctrl.listen_only and not ctrl.auto_retransmit
    assert _reg(rig, 2, 0x0010, 1 << 4) == 0
    assert ch.submit(CanFrame(0x321, b"\xAA"), "L") == 0
    rig.run()
    assert [r.frame.can_id for r in ch.peek(8)] == [0x321] and _sent(rig) == []
    ch.consume(1)
    assert _reg(rig, 2, 0x0010, 0) == 0
    assert ch.submit(CanFrame(0x322, b"\xBB"), "N") == 0
    rig.run()
    assert _sent(rig) == [0x322]


def test_gfc_and_xidam_writes_change_acceptance() -> None:
    """13.6 whitelist 'GFC Global filter configuration' (ANFS 4..5 = 2: reject non-matching
    standard frames; RRFE: reject extended remote frames) and 'XIDAM Extended ID AND mask'
    (an extended classic filter then matches through the mask)."""
    rig = make_rig()
    rig.w(0x8001, 55, 1)
    _filter(rig, 0, 1, 1, 0x00000042, 0x00000042, ext=True)   # dual id 0x42 -> FIFO0
    assert rig.configure(0, s37=2) == 0
    _engineering(rig)
    assert _reg(rig, 2, 0x0080, 2 << 4 | 2 << 2) == 0
    assert _reg(rig, 2, 0x0090, 0xFF) == 0
    for f in (CanFrame(0x100, b"\x01"), CanFrame(0x1ABCDE42, b"\x02", extended=True)):
        rig.peers[0].send(f)
    rig.run()
    assert [r.frame.can_id for r in rig.model.channels[0].peek(8)] == [0x1ABCDE42]
    assert _reg(rig, 1, 0x0080) == 0 and rig.r(0xA000, 5) == 2 << 4 | 2 << 2


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(sorted(WRITE_WHITELIST)),
                          st.one_of(st.integers(0, 0xFFFFFFFF), st.sampled_from([0, 0x100, 0x120, 0x10, 0x30]))),
                max_size=12),
       st.integers(0, 8), st.integers(0, 1))
def test_random_register_writes_only_status_codes(writes: list[tuple[int, int]], budget: int, enable: int) -> None:
    """13.6: any whitelisted write with any value answers status 0 or 2 (never a crash), the channel
    keeps carrying frames or reporting TX_RESULT codes 0..5, and 0x8001:01 = 1 brings the SDO
    configuration back (13.4 apply) so frames flow again at the bus's rate."""
    rig = make_rig()
    assert rig.configure(0) == 0
    assert _policy(rig, s1=enable, s12=budget) == 0
    _engineering(rig)
    ch = rig.model.channels[0]
    for offset, value in writes:
        assert _reg(rig, 2, offset, value) in (0, 2)
        assert ch.submit(CanFrame(0x77, b"\x01"), "r") in range(6)
        rig.model.on_cycle(rig.clock.now())
        rig.run(0.002)
    rig.w(0x8001, 1, 1)
    assert rig.r(0x8001, 2) == 0
    for _ in range(3):
        rig.model.on_cycle(rig.clock.now())
        rig.run(0.02)
    assert all(code in range(6) for _ref, code in ch.take_tx_results())
    ch.consume(ch.pending_rx())
    rig.peers[0].send(CanFrame(0x7FF, b"\x02"))
    rig.run(0.01)
    assert [r.frame.can_id for r in ch.peek(32)] == [0x7FF]
