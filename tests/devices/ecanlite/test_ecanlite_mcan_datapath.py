"""RX cache, TX ring, data-path policies, status word and counters (ECAN-Lite manual 7, 13.2.2,
13.2.5, 13.5)."""

from __future__ import annotations

from ecanlite_mcan_kit import Rig, make_rig

from gatewaylab.bus import CanFrame
from gatewaylab.devices.ecanlite.mcan import DataPathPolicy, is_critical


def _rig() -> Rig:
    """One channel configured for its bus (1 Mbit/s / 5 Mbit/s, 87.5 %)."""
    rig = make_rig()
    assert rig.configure(0) == 0
    return rig


def _policy(rig: Rig, k: int = 0, **subs: int) -> int:
    for name, value in subs.items():
        rig.w(0x8021 + k, int(name[1:]), value)
    rig.w(0x8021 + k, 2, 1)
    return rig.r(0x8021 + k, 3)


def _burst(rig: Rig, ids: list[int]) -> None:
    for cid in ids:
        rig.peers[0].send(CanFrame(cid, b"\x00"))
    rig.run(0.05)


def test_active_control_word_default_and_packing() -> None:
    """13.2.2 SI20 'Active control word' packs Enable, RX min/max, RX policy, depth enum, RX
    overflow, critical, TX min/max, TX overflow, bus-off recovery at the table's bit positions."""
    rig = _rig()
    default = 1 | 2 << 8 | 1 << 12 | 2 << 14 | 1 << 16 | 1 << 18 | 4 << 24 | 1 << 28 | 1 << 30
    assert rig.r(0x8021, 20) == default
    assert _policy(rig, s4=1, s5=7, s6=3, s7=24, s8=2, s9=2, s11=3, s12=8, s13=2, s14=0) == 0
    assert rig.r(0x8021, 20) == (1 | 1 << 4 | 7 << 8 | 3 << 12 | 3 << 14 | 2 << 16 | 2 << 18 | 3 << 20
                                 | 8 << 24 | 2 << 28 | 0 << 30)


def test_policy_apply_rejects_bad_values_keeps_old() -> None:
    """13.2.2: budgets 0..8, depth legacy 0..3 or 8/16/24/32; a bad apply reports status 1 and the
    active policy (SI20) stays."""
    rig = _rig()
    before = rig.r(0x8021, 20)
    assert _policy(rig, s7=12) == 1
    assert rig.r(0x8021, 20) == before
    assert _policy(rig, s7=16, s5=9) == 1
    assert _policy(rig, s5=2, s4=3) == 1          # min above max
    assert rig.r(0x8021, 20) == before
    assert _policy(rig, s4=0, s7=0) == 0           # legacy enum 0 = 32 frames
    assert rig.model.channels[0].policy.depth == 32


def test_drain_budget_limits_peek() -> None:
    """13.2.2 SI5 'RX drain budget max' (default 2) with policy 1 'limited'; 'performance' drains
    within the configured limit of the PDO (everything pending)."""
    rig = _rig()
    _burst(rig, [0x100 + i for i in range(6)])
    ch = rig.model.channels[0]
    assert len(ch.peek(32)) == 2
    assert _policy(rig, s6=2) == 0
    assert len(ch.peek(32)) == 6
    assert len(ch.peek(4)) == 4
    ch.consume(4)
    assert [r.frame.can_id for r in ch.peek(32)] == [0x104, 0x105]
    assert rig.r(0x9020, 3) == 4 and rig.r(0x9020, 9) == 4


def test_rx_overflow_drop_newest_default() -> None:
    """13.2.2 RX overflow policy 1 'drop newest' (default), depth 2 = 16 frames: the cache keeps
    the first 16; 0x9020:05/07 and 0x9000:13 count the drops; the status word shows rx_pressure."""
    rig = _rig()
    _burst(rig, list(range(0x100, 0x100 + 20)))
    ch = rig.model.channels[0]
    assert ch.pending_rx() == 16
    assert rig.r(0x9020, 1) == 16 and rig.r(0x9020, 2) == 16
    assert (rig.r(0x9020, 5), rig.r(0x9020, 7), rig.r(0x9020, 6)) == (4, 4, 0)
    assert rig.r(0x9000, 13) == 4
    word = ch.status_word()
    assert word >> 6 & 1 and word >> 9 & 1 and (word >> 10) & 7 == 7
    assert _policy(rig, s6=2) == 0
    assert [r.frame.can_id for r in ch.peek(32)][-1] == 0x10F


def test_rx_overflow_drop_oldest() -> None:
    """13.2.2 policy 0 'drop oldest': keeps the newest 16 (explicit depth value 16)."""
    rig = _rig()
    assert _policy(rig, s8=0, s7=16, s6=2) == 0
    _burst(rig, list(range(0x100, 0x100 + 20)))
    ch = rig.model.channels[0]
    assert [r.frame.can_id for r in ch.peek(32)] == list(range(0x104, 0x114))
    assert rig.r(0x9020, 6) == 4


def test_critical_frames_preserved_under_burst() -> None:
    """13.2.2 policy 2 'preserve critical' with critical policy 1 'CANopen safety': under a burst
    that overflows an 8-frame cache, NMT, SYNC, EMCY and heartbeat frames survive and push out the
    oldest ordinary frames (0x9020:08 counts those drops)."""
    rig = _rig()
    assert _policy(rig, s7=1, s8=2, s9=1, s6=2) == 0               # depth 8
    ordinary = list(range(0x200, 0x20C))                             # 12 PDO-range frames
    critical = [0x000, 0x080, 0x082, 0x702]                          # NMT, SYNC, EMCY node 2, heartbeat 2
    _burst(rig, ordinary[:8] + critical + ordinary[8:])
    ids = [r.frame.can_id for r in rig.model.channels[0].peek(32)]
    assert len(ids) == 8
    assert all(c in ids for c in critical)
    assert rig.r(0x9020, 8) == 4                                     # four ordinary frames made room
    assert rig.r(0x9020, 7) == 4                                     # the four late ordinary frames dropped


def test_critical_classes() -> None:
    """13.2.2 critical frame policy 0 none / 1 CANopen safety / 2 CANopen all (adds SDO, TIME, LSS)."""
    nmt, sdo, pdo = CanFrame(0x000, b"\x01\x00"), CanFrame(0x581, bytes(8)), CanFrame(0x181, bytes(8))
    assert not is_critical(nmt, 0)
    assert is_critical(nmt, 1) and not is_critical(sdo, 1)
    assert is_critical(sdo, 2) and not is_critical(pdo, 2)
    assert not is_critical(CanFrame(0x080, b"", extended=True), 2)


def test_degraded_after_threshold() -> None:
    """13.2.2 RX overflow policy 3 'degraded' with SI16 'Degraded threshold': after that many drops
    0x9020:15 is non-zero and the status word warn bit is set; an apply clears it."""
    rig = _rig()
    assert _policy(rig, s7=8, s8=3, s16=3) == 0
    _burst(rig, list(range(0x100, 0x100 + 10)))
    assert rig.r(0x9020, 15) == 0
    _burst(rig, [0x300])
    assert rig.r(0x9020, 15) != 0
    assert rig.model.channels[0].status_word() >> 4 & 1
    assert _policy(rig) == 0
    assert rig.r(0x9020, 15) == 0


def test_tx_ring_results() -> None:
    """Chapter 10 TX_RESULT: frames handed to the MCAN finish with OK once acknowledged;
    take_tx_results reports each ref once, in order. 13.2.2 SI12 'TX budget max' (default 4):
    the fifth frame of a cycle waits for the next cycle (McanModel.on_cycle)."""
    rig = _rig()
    ch = rig.model.channels[0]
    for i in range(5):
        assert ch.submit(CanFrame(0x40 + i, bytes([i])), ("seq", i)) == 0
    assert ch.pending_tx() == 5
    assert (ch.status_word() >> 13) & 7 == 5
    rig.run()
    assert ch.take_tx_results() == [(("seq", i), 0) for i in range(4)]
    rig.model.on_cycle(rig.clock.now())
    rig.run()
    assert ch.take_tx_results() == [(("seq", 4), 0)]
    assert ch.take_tx_results() == []
    assert [f.can_id for f, _ in rig.recorders[0].frames] == [0x40 + i for i in range(5)]


def test_tx_fifo_full_policies() -> None:
    """13.2.2 TX overflow policy 1 'drop oldest' (default) gives up the oldest waiting frame (its
    result TX FIFO full, 0x9020:12 stale dropped); policy 0 'drop newest' refuses the new one with
    ResultCode 4; 0x9000:14 counts backpressure."""
    rig = _rig()
    assert rig.configure(0, s70=4) == 0
    ch = rig.model.channels[0]
    rig.buses[0].detach(rig.peers[0])                  # nobody acks: frames stay queued
    refs = [ch.submit(CanFrame(0x10 + i, b"\x01"), i) for i in range(4)]
    assert refs == [0, 0, 0, 0]
    assert ch.submit(CanFrame(0x20, b"\x01"), "new") == 0
    results = ch.take_tx_results()
    assert results == [(0, 4)]                          # the oldest frame was not on the wire yet
    assert rig.r(0x9020, 12) == 1
    assert _policy(rig, s13=0) == 0
    assert ch.submit(CanFrame(0x21, b"\x01"), "refused") == 4
    assert rig.r(0x9000, 14) >= 1 and rig.r(0x9020, 11) >= 1
    assert ch.status_word() >> 7 & 1


def test_tx_backoff_policy() -> None:
    """13.2.2 TX overflow policy 2 'backoff' with SI15 'Backoff base cycles': after a full FIFO
    the channel refuses for that many cycles (McanModel.on_cycle), then accepts again."""
    rig = _rig()
    assert rig.configure(0, s70=1) == 0
    assert _policy(rig, s13=2, s15=2) == 0
    ch = rig.model.channels[0]
    rig.buses[0].detach(rig.peers[0])
    assert ch.submit(CanFrame(0x10, b""), 0) == 0
    assert ch.submit(CanFrame(0x11, b""), 1) == 4
    rig.buses[0].attach("acker")
    rig.run()
    assert ch.submit(CanFrame(0x12, b""), 2) == 4          # still backing off
    rig.model.on_cycle(rig.clock.now())
    rig.model.on_cycle(rig.clock.now())
    assert ch.submit(CanFrame(0x13, b""), 3) == 0


def test_bus_off_recovery_policies() -> None:
    """13.2.2 SI14: 0 manual waits for the host (an apply restarts the MCAN), 1 auto recovers after
    128 x 11 recessive bits, 2 aggressive recovers at once; 0x9000:15 / 0x9020:13 count bus-offs,
    the status word shows state 3 and bit 5 while bus-off, queued frames end with ResultCode 5."""
    rig = _rig()
    ch = rig.model.channels[0]
    ctrl = ch.controller
    assert ctrl is not None
    assert _policy(rig, s14=0) == 0
    rig.buses[0].detach(rig.peers[0])
    assert ch.submit(CanFrame(0x10, b""), "q") == 0
    rig.buses[0].force_bus_off(ctrl)
    assert ("q", 5) in ch.take_tx_results()
    word = ch.status_word()
    assert word & 7 == 3 and word >> 5 & 1
    assert ch.submit(CanFrame(0x11, b""), None) == 5
    rig.run(0.1)
    assert ctrl.bus_off                                   # manual: still bus-off
    assert rig.r(0x9000, 15) == 1 and rig.r(0x9020, 13) == 1
    rig.w(0x8001, 1, 1)                                   # host recovery: apply restarts the MCAN
    assert not ctrl.bus_off
    assert _policy(rig, s14=1) == 0
    rig.buses[0].force_bus_off(ctrl)
    assert ctrl.bus_off
    rig.run(0.01)
    assert not ctrl.bus_off
    assert _policy(rig, s14=2) == 0
    rig.buses[0].force_bus_off(ctrl)
    rig.clock.advance(0)
    assert not ctrl.bus_off
    assert rig.r(0x9020, 14) == 2                          # auto + aggressive attempts
    assert rig.r(0x9000, 15) == 3


def test_event_flags_and_detail_pending() -> None:
    """Chapter 7 bit 8 detail_pending / 13.5 SI12 'latched warning/busoff/pressure/state-change':
    a bus-off latches flags and detail_pending; reading 0x9000:12 returns and clears them; SI16
    detail sequence moves."""
    rig = _rig()
    ch = rig.model.channels[0]
    assert ch.status_word() >> 8 & 1 == 0
    assert ch.controller is not None
    rig.buses[0].force_bus_off(ch.controller)
    assert ch.status_word() >> 8 & 1
    seq = rig.r(0x9000, 16)
    assert seq >= 1
    flags = rig.r(0x9000, 12)
    assert flags & 0x02 and flags & 0x10
    assert rig.r(0x9000, 12) == 0
    assert ch.status_word() >> 8 & 1 == 0


def test_error_passive_state_and_registers() -> None:
    """Chapter 7 state 4 'error' and warn bit; 13.5 ECR (TEC/REC) and PSR (EP/EW) from the
    controller's counters."""
    rig = _rig()
    ch = rig.model.channels[0]
    ctrl = ch.controller
    assert ctrl is not None
    rig.buses[0].detach(rig.peers[0])
    ch.submit(CanFrame(0x10, b""), None)
    rig.run(0.005)                                        # ACK errors: TEC climbs to 128 and stays
    assert ch.status_word() & 7 == 4 and ch.status_word() >> 4 & 1
    ecr, psr = rig.r(0x9000, 1), rig.r(0x9000, 2)
    assert ecr & 0xFF == ctrl.tec >= 128
    assert psr >> 5 & 1 and psr >> 6 & 1 and psr & 7 == 3           # EP, EW, LEC = ack error
    assert rig.r(0x9000, 3) >> 23 & 1                                # IR.EP
    assert rig.r(0x9000, 11) == 1


def test_policy_disabled_means_no_limits() -> None:
    """13.2.2 SI1 Enable = 0 'disable this channel data-path policy': no drain budget, cache at its
    32-frame maximum (0xF000:28)."""
    policy = DataPathPolicy.from_values({1: 0})
    assert not policy.enable and policy.control_word & 1 == 0
    rig = _rig()
    assert _policy(rig, s1=0) == 0
    _burst(rig, list(range(0x100, 0x100 + 40)))
    assert len(rig.model.channels[0].peek(64)) == 32
