"""Golden-frame and state tests of the LSS slave machine (CiA 305 V3.0; IDX guide 3.5)."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.canopen.lss import (
    ActivateBitTiming,
    AdoptNodeId,
    LssAddress,
    LssSlaveMachine,
    LssState,
    Reply,
    encode_fastscan,
)

ADDR = LssAddress(0x000000FB, 0x60500000, 0x00010002, 0x00001002)


def frame(hexstr: str) -> bytes:
    data = bytes.fromhex(hexstr.replace(" ", ""))
    assert len(data) == 8
    return data


def replies(actions: list) -> list[str]:
    return [a.data.hex(" ").upper() for a in actions if isinstance(a, Reply)]


def configured_machine(node_id: int | None = 5) -> LssSlaveMachine:
    m = LssSlaveMachine(ADDR, node_id, 0, store=lambda nid, bt: 0)
    assert m.on_request(frame("04 01 00 00 00 00 00 00")) == []
    assert m.state is LssState.CONFIGURATION
    return m


def test_switch_state_global_golden() -> None:
    """IDX guide 3.5.2.1 fig. 3-25: cs 0x04, mode 1 = configuration, 0 = waiting; no answer."""
    m = LssSlaveMachine(ADDR, 5)
    assert m.state is LssState.WAITING
    assert m.on_request(frame("04 01 00 00 00 00 00 00")) == []
    assert m.state is LssState.CONFIGURATION
    assert m.on_request(frame("04 00 00 00 00 00 00 00")) == []
    assert m.state is LssState.WAITING


def test_switch_state_selective_golden() -> None:
    """IDX guide 3.5.2.2 fig. 3-26: 0x40..0x43 carry vendor/product/revision/serial; the one
    addressed slave answers cs 0x44 and enters configuration."""
    m = LssSlaveMachine(ADDR, 5)
    assert replies(m.on_request(frame("40 FB 00 00 00 00 00 00"))) == []
    assert replies(m.on_request(frame("41 00 00 50 60 00 00 00"))) == []
    assert replies(m.on_request(frame("42 02 00 01 00 00 00 00"))) == []
    assert replies(m.on_request(frame("43 02 10 00 00 00 00 00"))) == ["44 00 00 00 00 00 00 00"]
    assert m.state is LssState.CONFIGURATION


def test_switch_state_selective_other_serial_is_silent() -> None:
    """IDX guide 3.5.2.2: only the slave whose LSS address matches answers."""
    m = LssSlaveMachine(ADDR, 5)
    for data in ("40 FB 00 00 00 00 00 00", "41 00 00 50 60 00 00 00", "42 02 00 01 00 00 00 00",
                 "43 03 10 00 00 00 00 00"):
        assert m.on_request(frame(data)) == []
    assert m.state is LssState.WAITING


def test_configure_node_id_golden() -> None:
    """IDX guide 3.5.2.3 fig. 3-27: answer cs 0x11, error code 0 ok / 1 out of range (1..127, 0xFF)."""
    m = configured_machine()
    assert replies(m.on_request(frame("11 22 00 00 00 00 00 00"))) == ["11 00 00 00 00 00 00 00"]
    assert m.pending_node_id == 0x22
    assert replies(m.on_request(frame("11 80 00 00 00 00 00 00"))) == ["11 01 00 00 00 00 00 00"]
    assert replies(m.on_request(frame("11 00 00 00 00 00 00 00"))) == ["11 01 00 00 00 00 00 00"]
    assert replies(m.on_request(frame("11 FF 00 00 00 00 00 00"))) == ["11 00 00 00 00 00 00 00"]
    assert m.pending_node_id == 0xFF


def test_configure_bit_timing_golden() -> None:
    """IDX guide 3.5.2.4 fig. 3-28: selector 0 + table index; error 1 = bit timing not supported."""
    m = configured_machine()
    assert replies(m.on_request(frame("13 00 02 00 00 00 00 00"))) == ["13 00 00 00 00 00 00 00"]
    assert m.pending_bit_timing == 2
    assert replies(m.on_request(frame("13 00 05 00 00 00 00 00"))) == ["13 01 00 00 00 00 00 00"]
    assert replies(m.on_request(frame("13 01 02 00 00 00 00 00"))) == ["13 01 00 00 00 00 00 00"]
    assert replies(m.on_request(frame("13 00 09 00 00 00 00 00"))) == ["13 01 00 00 00 00 00 00"]


def test_activate_bit_timing_golden() -> None:
    """IDX guide 3.5.2.5 fig. 3-29: cs 0x15 + switch delay in ms (u16); no answer."""
    m = configured_machine()
    m.on_request(frame("13 00 03 00 00 00 00 00"))
    actions = m.on_request(frame("15 64 00 00 00 00 00 00"))
    assert actions == [ActivateBitTiming(250_000, 0.1)]


def test_store_configuration_golden() -> None:
    """IDX guide 3.5.2.6 fig. 3-31: answer 0x17 with error 0 ok / 1 not supported / 2 media error."""
    stored: list[tuple[int, int]] = []

    def store(nid: int, bt: int) -> int:
        stored.append((nid, bt))
        return 0

    m = LssSlaveMachine(ADDR, 5, 0, store=store)
    m.on_request(frame("04 01 00 00 00 00 00 00"))
    m.on_request(frame("11 09 00 00 00 00 00 00"))
    assert replies(m.on_request(frame("17 00 00 00 00 00 00 00"))) == ["17 00 00 00 00 00 00 00"]
    assert stored == [(9, 0)]
    m2 = LssSlaveMachine(ADDR, 5)
    m2.on_request(frame("04 01 00 00 00 00 00 00"))
    assert replies(m2.on_request(frame("17 00 00 00 00 00 00 00"))) == ["17 01 00 00 00 00 00 00"]
    m3 = LssSlaveMachine(ADDR, 5, 0, store=lambda nid, bt: 2)
    m3.on_request(frame("04 01 00 00 00 00 00 00"))
    assert replies(m3.on_request(frame("17 00 00 00 00 00 00 00"))) == ["17 02 00 00 00 00 00 00"]


@pytest.mark.parametrize(("cs", "value"), [(0x5A, ADDR.vendor_id), (0x5B, ADDR.product_code),
                                           (0x5C, ADDR.revision), (0x5D, ADDR.serial)])
def test_inquire_identity_golden(cs: int, value: int) -> None:
    """IDX guide 3.5.2.7-3.5.2.10: answer repeats cs and carries the 0x1018 sub-index (u32 LE)."""
    m = configured_machine()
    expected = bytes((cs,)) + struct.pack("<I", value) + bytes(3)
    assert replies(m.on_request(bytes((cs,)) + bytes(7))) == [expected.hex(" ").upper()]


def test_inquire_node_id_golden() -> None:
    """IDX guide 3.5.2.11: cs 0x5E answers the active node-ID (0xFF when not configured)."""
    assert replies(configured_machine(5).on_request(frame("5E 00 00 00 00 00 00 00"))) == [
        "5E 05 00 00 00 00 00 00"]
    assert replies(configured_machine(None).on_request(frame("5E 00 00 00 00 00 00 00"))) == [
        "5E FF 00 00 00 00 00 00"]


def test_configuration_services_ignored_in_waiting() -> None:
    """IDX guide table 3-14: configure/inquire/store/activate are 'no' in LSS state Waiting."""
    m = LssSlaveMachine(ADDR, 5, 0, store=lambda nid, bt: 0)
    for cs in (0x11, 0x13, 0x15, 0x17, 0x5A, 0x5B, 0x5C, 0x5D, 0x5E):
        assert m.on_request(bytes((cs, 1)) + bytes(6)) == []
    assert m.pending_node_id == 5
    assert m.stats.ignored == 9


def test_selective_ignored_in_configuration() -> None:
    """IDX guide table 3-14: switch state selective is 'no' in LSS state Configuration."""
    m = configured_machine()
    for data in ("40 FB 00 00 00 00 00 00", "41 00 00 50 60 00 00 00", "42 02 00 01 00 00 00 00",
                 "43 02 10 00 00 00 00 00"):
        assert m.on_request(frame(data)) == []


def identify(m: LssSlaveMachine, rev: tuple[int, int], ser: tuple[int, int],
             vendor: int = 0xFB) -> list[str]:
    out: list[str] = []
    values = (vendor, ADDR.product_code, rev[0], rev[1], ser[0], ser[1])
    for i, v in enumerate(values):
        out += replies(m.on_request(bytes((0x46 + i,)) + struct.pack("<I", v) + bytes(3)))
    return out


@pytest.mark.parametrize("state", [False, True])
def test_identify_remote_slave_ranges(state: bool) -> None:
    """IDX guide 3.5.2.12: inclusive revision/serial ranges; matching slaves answer cs 0x4F,
    in both LSS states (table 3-14)."""
    m = configured_machine() if state else LssSlaveMachine(ADDR, 5)
    assert identify(m, (0, 0xFFFFFFFF), (0, 0xFFFFFFFF)) == ["4F 00 00 00 00 00 00 00"]
    assert identify(m, (ADDR.revision, ADDR.revision), (ADDR.serial, ADDR.serial)) == [
        "4F 00 00 00 00 00 00 00"]
    assert identify(m, (0, 0xFFFFFFFF), (ADDR.serial + 1, 0xFFFFFFFF)) == []
    assert identify(m, (0, ADDR.revision - 1), (0, 0xFFFFFFFF)) == []
    assert identify(m, (0, 0xFFFFFFFF), (0, 0xFFFFFFFF), vendor=0xFC) == []


def test_identify_non_configured_golden() -> None:
    """IDX guide 3.5.2.13: only slaves with node-ID 0xFF answer cs 0x50."""
    assert replies(LssSlaveMachine(ADDR, None).on_request(frame("4C 00 00 00 00 00 00 00"))) == [
        "50 00 00 00 00 00 00 00"]
    assert LssSlaveMachine(ADDR, 7).on_request(frame("4C 00 00 00 00 00 00 00")) == []


def test_fastscan_walk_finds_address() -> None:
    """CiA 305 Fastscan (IDX guide table 3-14 'LSS Fastscan'): 0x80 resets, then 32 bit checks
    per LSS sub; the slave answers 0x4F while the checked bits match and enters configuration
    after the last sub."""
    m = LssSlaveMachine(ADDR, None)
    assert replies(m.on_request(encode_fastscan(0, 0x80, 0, 0))) == ["4F 00 00 00 00 00 00 00"]
    found = [0, 0, 0, 0]
    for sub in range(4):
        for bit in range(31, -1, -1):
            if not replies(m.on_request(encode_fastscan(found[sub], bit, sub, sub))):
                found[sub] |= 1 << bit
        assert replies(m.on_request(encode_fastscan(found[sub], 0, sub, (sub + 1) & 3)))
    assert LssAddress(*found) == ADDR
    assert m.state is LssState.CONFIGURATION


def test_fastscan_configured_slave_silent() -> None:
    """CiA 305: Fastscan addresses non-configured slaves only."""
    m = LssSlaveMachine(ADDR, 3)
    assert m.on_request(encode_fastscan(0, 0x80, 0, 0)) == []


def test_new_node_id_adopted_on_switch_to_waiting() -> None:
    """CiA 305: a non-configured slave that got a node-ID resets communication with it when the
    master switches back to waiting."""
    m = configured_machine(None)
    m.on_request(frame("11 0C 00 00 00 00 00 00"))
    assert m.on_request(frame("04 00 00 00 00 00 00 00")) == [AdoptNodeId(12)]
    configured = configured_machine(5)
    configured.on_request(frame("11 0C 00 00 00 00 00 00"))
    assert configured.on_request(frame("04 00 00 00 00 00 00 00")) == []


@settings(max_examples=400, deadline=None)
@given(st.lists(st.one_of(
    st.binary(min_size=0, max_size=8),
    st.builds(lambda cs, rest: bytes((cs,)) + rest,
              st.sampled_from([0x04, 0x11, 0x13, 0x15, 0x17, 0x40, 0x41, 0x42, 0x43, 0x46, 0x47, 0x48,
                               0x49, 0x4A, 0x4B, 0x4C, 0x51, 0x5A, 0x5B, 0x5C, 0x5D, 0x5E]),
              st.binary(min_size=7, max_size=7))), max_size=40), st.booleans())
def test_random_frames_only_valid_answers(frames: list[bytes], configured: bool) -> None:
    """Any sequence of frames on 0x7E5 yields only well-formed LSS answers (8 bytes, a response
    cs that fits the request) or silence; never an exception."""
    m = LssSlaveMachine(ADDR, 5 if configured else None, 0, store=lambda nid, bt: 0)
    answers_for = {0x43: {0x44}, 0x11: {0x11}, 0x13: {0x13}, 0x17: {0x17}, 0x5A: {0x5A}, 0x5B: {0x5B},
                   0x5C: {0x5C}, 0x5D: {0x5D}, 0x5E: {0x5E}, 0x4B: {0x4F}, 0x4C: {0x50}, 0x51: {0x4F}}
    for data in frames:
        for action in m.on_request(data):
            if isinstance(action, Reply):
                assert len(action.data) == 8
                assert action.data[0] in answers_for[data[0]]
            elif isinstance(action, AdoptNodeId):
                assert 1 <= action.node_id <= 127
            else:
                assert isinstance(action, ActivateBitTiming)
                assert data[0] == 0x15
