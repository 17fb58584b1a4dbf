"""NMT slave and master, heartbeat producer/consumer and node guarding.

Manual: IDX Communication Guide 3.3.3.5 (NMT services, tables 3-11 and 3-12), 3.4 table 3-13
(default connection set); CiA 301 7.2.8.3 for heartbeat and guarding.
"""

from __future__ import annotations

import itertools

import canopen
import pytest
from canopen_testkit import barrier, remote_for, while_waiting

from gatewaylab.bus import CanFrame
from gatewaylab.canopen.nmt import (
    NmtCommand,
    NmtMaster,
    NmtMessage,
    NmtState,
    decode_error_control,
    decode_nmt,
    encode_heartbeat,
    encode_nmt,
)
from gatewaylab.od.aborts import SdoAbortCode


@pytest.mark.parametrize(("command", "cs"), [
    (NmtCommand.ENTER_PRE_OPERATIONAL, 0x80), (NmtCommand.RESET_COMMUNICATION, 0x82),
    (NmtCommand.RESET_NODE, 0x81), (NmtCommand.START_REMOTE_NODE, 0x01),
    (NmtCommand.STOP_REMOTE_NODE, 0x02),
])
@pytest.mark.parametrize("node_id", [0, 1, 5, 127])
def test_nmt_golden_frames(command: NmtCommand, cs: int, node_id: int) -> None:
    """IDX table 3-12: COB-ID 0, byte 0 = CS, byte 1 = node-id (0 = all nodes)."""
    frame = encode_nmt(command, node_id)
    assert frame == CanFrame(0x000, bytes([cs, node_id]))
    assert decode_nmt(frame) == NmtMessage(command, node_id)


@pytest.mark.parametrize("data", [b"", b"\x01", b"\x01\x05\x00", b"\x03\x05", b"\x01\x80"])
def test_nmt_decode_rejects_malformed(data: bytes) -> None:
    """IDX 3.3.3.5: the NMT object has two bytes and a known CS; anything else is ignored."""
    assert decode_nmt(CanFrame(0x000, data)) is None


def test_heartbeat_golden_frames() -> None:
    """CiA 301 7.2.8.3.2.2: heartbeat = 1 byte state on 0x700 + node-id; boot-up = state 0."""
    assert encode_heartbeat(5, NmtState.INITIALISING) == CanFrame(0x705, b"\x00")
    assert encode_heartbeat(5, NmtState.STOPPED) == CanFrame(0x705, b"\x04")
    assert encode_heartbeat(5, NmtState.OPERATIONAL) == CanFrame(0x705, b"\x05")
    assert encode_heartbeat(127, NmtState.PRE_OPERATIONAL) == CanFrame(0x77F, b"\x7F")
    assert decode_error_control(CanFrame(0x705, b"\x85")) == (5, NmtState.OPERATIONAL, True)
    assert decode_error_control(CanFrame(0x705, b"\x03")) is None


def test_boot_up_then_pre_operational(make_node, raw, sniffer, clock) -> None:
    """IDX table 3-11 transition 0: after initialisation a boot-up message, then Pre-operational."""
    node = make_node()
    clock.advance(0.001)
    assert [f for _, f in sniffer.frames] == [CanFrame(0x705, b"\x00")]
    assert node.nmt_state is NmtState.PRE_OPERATIONAL


def test_state_changes_from_python_canopen(make_node, network) -> None:
    """IDX table 3-11/3-12: start, stop, enter pre-operational addressed to the node."""
    node = make_node()
    remote = remote_for(network, node)
    seen: list[tuple[NmtState, NmtState]] = []
    node.on_nmt_change(lambda old, new: seen.append((old, new)))
    remote.nmt.state = "OPERATIONAL"
    barrier(remote)
    assert node.nmt_state is NmtState.OPERATIONAL
    remote.nmt.state = "STOPPED"
    remote.nmt.state = "PRE-OPERATIONAL"
    barrier(remote)
    assert node.nmt_state is NmtState.PRE_OPERATIONAL
    assert seen == [(NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL),
                    (NmtState.OPERATIONAL, NmtState.STOPPED),
                    (NmtState.STOPPED, NmtState.PRE_OPERATIONAL)]


def test_broadcast_and_addressed(make_node, raw) -> None:
    """IDX table 3-12: node-id 0 addresses all NMT slaves, n only node n."""
    a, b = make_node(5), make_node(6)
    raw.send(0, [0x01, 0])
    assert a.nmt_state is b.nmt_state is NmtState.OPERATIONAL
    raw.send(0, [0x02, 6])
    assert a.nmt_state is NmtState.OPERATIONAL and b.nmt_state is NmtState.STOPPED
    raw.send(0, [0x80, 7])
    assert a.nmt_state is NmtState.OPERATIONAL and b.nmt_state is NmtState.STOPPED
    raw.send(0, [0x80, 0])
    assert a.nmt_state is b.nmt_state is NmtState.PRE_OPERATIONAL


def test_reset_communication_and_reset_node(make_node, raw) -> None:
    """IDX table 3-11: reset communication restores communication parameters and boots up again;
    reset node also restores the application parameters (not stored ones)."""
    node = make_node()
    raw.sdo(5, [0x2B, 0x17, 0x10, 0x00, 0x64, 0x00])        # 0x1017 = 100 ms
    raw.sdo(5, [0x2F, 0x00, 0x60, 0x00, 0x09])              # 0x6000 = 9 (application)
    raw.send(0, [0x01, 5])
    raw.received.clear()
    raw.send(0, [0x82, 5])
    assert raw.take(0x705) == [CanFrame(0x705, b"\x00")]
    assert node.nmt_state is NmtState.PRE_OPERATIONAL
    assert node.get(0x1017) == 0 and node.get(0x6000) == 9
    raw.send(0, [0x81, 0])
    assert raw.take(0x705) == [CanFrame(0x705, b"\x00")]
    assert node.get(0x6000) == 3


def test_heartbeat_with_python_canopen(make_node, network, clock, sniffer) -> None:
    """CiA 301 7.2.8.3.2.2 / IDX 3.3.3.5: 0x1017 starts the producer; canopen sees the heartbeats."""
    node = make_node()
    remote = remote_for(network, node)
    remote.sdo[0x1017].raw = 100
    sniffer.clear()
    state = while_waiting(remote.nmt.state_update, lambda: remote.nmt.wait_for_heartbeat(5.0),
                          lambda: clock.advance(0.1))
    assert state == "PRE-OPERATIONAL"
    remote.nmt.state = "STOPPED"
    barrier_free = while_waiting(remote.nmt.state_update, lambda: remote.nmt.wait_for_heartbeat(5.0),
                                 lambda: clock.advance(0.1))
    assert barrier_free == "STOPPED"                         # heartbeats continue in Stopped
    clock.advance(0.5)
    beats = [t for t, f in sniffer.frames if f.can_id == 0x705]
    assert len(beats) >= 6
    gaps = {round(b - a, 6) for a, b in itertools.pairwise(beats[1:])}    # [0] is the boot-up
    assert gaps == {0.1}
    assert node.nmt_state is NmtState.STOPPED


def test_node_guarding_answered_with_toggle(make_node, raw, clock) -> None:
    """CiA 301 7.2.8.3.2.1: a remote frame on 0x700+id is answered with state and toggle bit,
    in every state (IDX table 3-11: Stopped keeps life guarding)."""
    make_node()
    clock.advance(0.001)
    raw.received.clear()
    answers = []
    for _ in range(3):
        raw.send(0x705, rtr=True, dlc=1)
        answers += [f.data for f in raw.take(0x705)]
    raw.send(0, [0x02, 5])
    raw.send(0x705, rtr=True, dlc=1)
    answers += [f.data for f in raw.take(0x705)]
    assert answers == [b"\x7F", b"\xFF", b"\x7F", b"\x84"]


def test_life_guarding_event_raises_emcy(make_node, raw, clock) -> None:
    """CiA 301 7.2.8.3.2.1: no guard request within guard time x life time factor -> EMCY 0x8130."""
    node = make_node()
    raw.sdo(5, [0x2B, 0x0C, 0x10, 0x00, 100, 0])
    raw.sdo(5, [0x2F, 0x0D, 0x10, 0x00, 3])
    raw.send(0x705, rtr=True, dlc=1)
    raw.received.clear()
    clock.advance(0.29)
    assert raw.take(0x85) == []
    clock.advance(0.02)
    assert [f.data for f in raw.take(0x85)] == [bytes([0x30, 0x81, 0x11, 0, 0, 0, 0, 0])]
    raw.send(0x705, rtr=True, dlc=1)
    assert [f.data for f in raw.take(0x85)] == [bytes(8)]   # error reset
    assert node.get(0x1001) == 0


def test_heartbeat_consumer_timeout_emcy(make_node, raw, clock) -> None:
    """CiA 301 7.5.2.20 / issue: 0x1016 monitors node 7; a missing heartbeat raises EMCY 0x8130,
    sets the communication bit of 0x1001 and enters 0x1003; a new heartbeat resets the error."""
    node = make_node()
    assert raw.sdo(5, [0x23, 0x16, 0x10, 0x01, 200, 0, 7, 0]) == bytes([0x60, 0x16, 0x10, 0x01, 0, 0, 0, 0])
    clock.advance(1.0)
    assert raw.take(0x85) == []                              # monitoring starts with the first heartbeat
    raw.send(0x707, [0x05])
    clock.advance(0.199)
    assert raw.take(0x85) == []
    clock.advance(0.002)
    assert [f.data for f in raw.take(0x85)] == [bytes([0x30, 0x81, 0x11, 7, 0, 0, 0, 0])]
    assert node.get(0x1001) == 0x11
    assert node.get(0x1003, 0) == 1 and node.get(0x1003, 1) == 0x0007_8130    # info: the node-id
    assert node.heartbeat.timed_out == {7}
    raw.send(0x707, [0x05])
    assert [f.data for f in raw.take(0x85)] == [bytes(8)]
    assert node.get(0x1001) == 0


def test_consumer_duplicate_node_refused(make_node, raw) -> None:
    """CiA 301 7.5.2.20: two 0x1016 entries for one node-id with a time != 0 -> 0x06040043."""
    make_node()
    raw.sdo(5, [0x23, 0x16, 0x10, 0x01, 200, 0, 7, 0])
    answer = raw.sdo(5, [0x23, 0x16, 0x10, 0x02, 100, 0, 7, 0])
    assert answer is not None and answer[0] == 0x80
    assert int.from_bytes(answer[4:], "little") == SdoAbortCode.GENERAL_PARAMETER_INCOMPATIBILITY


def test_nmt_master_sans_io(make_node, clock, vbus) -> None:
    """IDX table 3-12 from our NmtMaster; it tracks boot-up/heartbeat states and reports timeouts."""
    sent: list[CanFrame] = []
    ctrl = vbus.attach("master", on_frame=lambda f, t: master.on_frame(f, t))

    def send(frame: CanFrame) -> None:
        sent.append(frame)
        ctrl.send(frame)

    master = NmtMaster(clock, send)
    timeouts: list[int] = []
    master.add_timeout_listener(timeouts.append)
    node = make_node()
    clock.advance(0.001)
    assert master.states[5] is NmtState.INITIALISING           # boot-up seen
    master.start(5)
    master.stop(0)
    master.enter_pre_operational()
    master.reset_communication(5)
    master.reset_node(5)
    clock.advance(0.01)
    assert sent == [CanFrame(0, b"\x01\x05"), CanFrame(0, b"\x02\x00"), CanFrame(0, b"\x80\x00"),
                    CanFrame(0, b"\x82\x05"), CanFrame(0, b"\x81\x05")]
    node.set(0x1017, 0, 50)
    node.heartbeat.start()
    master.monitor(5, 0.12)
    clock.advance(0.5)
    assert master.states[5] is NmtState.PRE_OPERATIONAL and timeouts == []
    master.guard(5)
    master.guard(5)
    clock.advance(0.01)
    assert master.guard_errors == 0
    node.stop()
    clock.advance(0.2)
    assert timeouts == [5]


def test_unconfigured_node_waits_for_lss(make_node, raw, clock, sniffer) -> None:
    """CiA 305 / IDX 3.5: node-id 0xFF (None) sends no boot-up and takes no NMT, but its frame
    listeners see every frame; once it has a node-id, reset communication boots it."""
    node = make_node(node_id=None)
    seen: list[CanFrame] = []
    node.add_frame_listener(lambda f, t: seen.append(f))
    clock.advance(0.01)
    raw.send(0, [0x01, 0])
    assert sniffer.ids(0x7FF) == [] and node.nmt_state is NmtState.INITIALISING
    assert seen == [CanFrame(0, b"\x01\x00")]
    node.node_id = 9
    node.reset_communication()
    clock.advance(0.001)
    assert [f for _, f in sniffer.ids(0x709)] == [CanFrame(0x709, b"\x00")]
    assert node.get(0x1200, 1) == 0x609 and node.nmt_state is NmtState.PRE_OPERATIONAL


def test_python_canopen_nmt_broadcast(make_node, network) -> None:
    """IDX table 3-12 from python-canopen's network-wide NMT master."""
    a, b = make_node(5), make_node(6)
    remote = remote_for(network, a)
    network.nmt.state = "OPERATIONAL"
    barrier(remote)
    assert a.nmt_state is b.nmt_state is NmtState.OPERATIONAL
    assert isinstance(network.nmt, canopen.nmt.NmtMaster)


def test_guarding_from_python_canopen(make_node, network, sniffer) -> None:
    """CiA 301 7.2.8.3.2.1 interop: python-canopen's node guarding (periodic remote frames) gets
    our answers, which it decodes as the NMT state."""
    node = make_node()
    remote = remote_for(network, node)
    remote.nmt.state = "OPERATIONAL"
    remote.nmt.start_node_guarding(0.01)
    try:
        assert remote.nmt.wait_for_heartbeat(5.0) == "OPERATIONAL"
    finally:
        remote.nmt.stop_node_guarding()
    answers = [f.data for _, f in sniffer.ids(0x705) if not f.rtr]
    assert answers[:2] == [b"\x00", b"\x05"]          # boot-up, then the first guarding answer (toggle 0)
    assert all(a[0] & 0x7F == 0x05 for a in answers[1:])
    assert all((a[0] ^ b[0]) & 0x80 for a, b in itertools.pairwise(answers[1:]))


def test_id_filtered_frame_listener(make_node, raw, clock) -> None:
    """Contract (LSS/gateway plug-in): a listener for one identifier sees those standard frames in
    every NMT state, alongside the node's own services on the same identifier."""
    node = make_node()
    seen: list[CanFrame] = []
    node.add_frame_listener(lambda f, t: seen.append(f), can_id=0x605)
    raw.send(0x7E5, [0x04, 0x01])
    raw.send(0x605, [0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])
    assert raw.take(0x585) != []                     # the SDO server still answers
    raw.send(0, [0x02, 5])
    raw.send(0x605, [0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])
    assert raw.take(0x585) == []                     # Stopped: no SDO, the listener still sees it
    assert len(seen) == 2 and all(f.can_id == 0x605 for f in seen)
