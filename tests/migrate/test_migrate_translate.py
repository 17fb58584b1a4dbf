"""Issue 13 part 1: esd startup writes -> ECAN-Lite startup writes (golden vectors)."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.esd_can_ethercat import bitrate as esd_rate
from gatewaylab.migrate.eni import EniError, InitCmd, format_writes, parse_eni, parse_writes
from gatewaylab.migrate.translate import read_esd, translate


def w(index: int, sub: int, value: int, size: int) -> InitCmd:
    return InitCmd(index, sub, value.to_bytes(size, "little"))


def area(first: int, last: int, ext: bool = False) -> int:
    """esd manual 5.1.5.6: bytes 0-3 first identifier, 4-7 last; bits 31 and 63 mark 29-bit."""
    flag = 0x80000000 if ext else 0
    return (first | flag) | ((last | flag) << 32)


def writes_of(cmds: list[InitCmd], index: int) -> dict[int, int]:
    """Last value written per subindex of ``index``."""
    return {c.subindex: c.value for c in cmds if c.index == index and not c.complete_access}


GOLDEN_ESD = [w(0xF800, 2, 4, 1), w(0x8000, 0x20, 1, 2), w(0x8000, 0x22, 32, 1), w(0x8000, 0x21, 20, 1),
              w(0x8001, 0, 2, 1), w(0x8001, 1, area(0x100, 0x100), 8), w(0x8001, 2, area(0x1000, 0x1FFFFFFF, True), 8),
              w(0x1C13, 0, 0, 1), w(0x1C13, 1, 0x1A00, 2), w(0x1C13, 2, 0x1A85, 2), w(0x1C13, 0, 2, 1)]
#: The expected ECAN-Lite writes (manual 5.4.1 assignment, 5.4.2 order, 13.4 channel config).
GOLDEN_ECAN = (
    [(0x1C12, 0, 0)] + [(0x1C12, i + 1, 0x1600 + i) for i in range(4)] + [(0x1C12, 0, 4)]
    + [(0x1C13, 0, 0)] + [(0x1C13, i + 1, 0x1A00 + i) for i in range(4)] + [(0x1C13, 0, 4)]
    + [(0x8010, 3, 4), (0x8010, 4, 1), (0x8010, 5, 0), (0x8010, 6, 0), (0x8010, 7, 1),
       (0x8011, 3, 4), (0x8011, 4, 1), (0x8011, 5, 0), (0x8011, 6, 0), (0x8011, 7, 0),
       (0x8010, 1, 1), (0x8011, 1, 1),
       (0x8001, 15, 0), (0x8001, 16, 0), (0x8001, 7, 0), (0x8001, 19, 125_000), (0x8001, 21, 850),
       (0x8001, 22, 850), (0x8001, 8, 0),
       (0x8001, 43, 0), (0x8001, 50, 0), (0x8001, 51, 1), (0x8001, 53, 0x100), (0x8001, 54, 0x100),
       (0x8001, 45, 2), (0x8001, 49, 1),
       (0x8001, 44, 0), (0x8001, 56, 0), (0x8001, 57, 1), (0x8001, 59, 0x1000), (0x8001, 60, 0x1FFFFFFF),
       (0x8001, 46, 2), (0x8001, 55, 1), (0x8001, 36, 2), (0x8001, 37, 2), (0x8001, 1, 1)])


def test_golden_translation() -> None:
    """5.4.1/5.4.2: assignment of the first N chunks, profiles, apply; 13.4 channel config, filters and
    apply. esd Table 6 index 4 = 125 kbit/s (5.1.5.9), 29-bit flag, Tx 32 / Rx 20, two areas."""
    tr = translate(GOLDEN_ESD)
    assert [(c.index, c.subindex, c.value) for c in tr.cmds] == GOLDEN_ECAN
    assert tr.multiplier == 4
    assert any("32 x 14 = 448 B" in a for a in tr.arithmetic)
    assert any("20 x 14 + 32 x 6" in a for a in tr.arithmetic)
    topics = [n.topic for n in tr.notes]
    assert "esd local queues" in topics and "0x1A85 status PDO" in topics


def test_number_4_in_both_tables() -> None:
    """esd 5.1.5.9: F800:02 uses Table 6 (4 = 125 kbit/s), F800:05 Table 9 (4 = 250 kbit/s)."""
    t6 = translate([w(0xF800, 2, 4, 1)])
    t9 = translate([w(0xF800, 5, 4, 4)])
    assert writes_of(t6.cmds, 0x8001)[19] == 125_000
    assert writes_of(t9.cmds, 0x8001)[19] == 250_000


def test_table6_index_wins_over_api_value() -> None:
    """5.1.5.9: a Table 6 index in :02 wins over :05; the ignored :05 is reported, not dropped."""
    tr = translate([w(0xF800, 5, 4, 4), w(0xF800, 2, 2, 1)])
    assert writes_of(tr.cmds, 0x8001)[19] == 500_000
    assert any(n.topic == "0xF800:05" for n in tr.notes)


@pytest.mark.parametrize(("api", "rate", "node_mode"), [
    (esd_rate.NTCAN_USER_BAUDRATE_NUM | 800_000, 800_000, 0),        # UBRN
    (esd_rate.NTCAN_USER_BAUDRATE | 0x000B0772, 500_000, 0),         # UBR: BRP 11, PROPAG 7, PHASE1 7, PHASE2 2
    (esd_rate.NTCAN_LISTEN_ONLY_MODE | 0x2, 500_000, 3),             # LOM + Table 9 index 2
    (esd_rate.NTCAN_LISTEN_ONLY_MODE | esd_rate.NTCAN_USER_BAUDRATE_NUM | 250_000, 250_000, 3),
])
def test_api_baud_modes(api: int, rate: int, node_mode: int) -> None:
    """5.1.5.9 Tables 7/8/10: UBRN numerical, UBR register, LOM -> 13.4 :19 rate, :08 node mode 3 (listen)."""
    tr = translate([w(0xF800, 5, api, 4)])
    ch = writes_of(tr.cmds, 0x8001)
    assert (ch[19], ch[8], ch[15], ch[7]) == (rate, node_mode, 0, 0)
    timing = esd_rate.from_api(api).timing              # the esd's own sample point (Figure 41)
    assert timing is not None
    assert ch[21] == ch[22] == round(timing.sample_point * 10)


def test_non_integer_table_rate_gets_manual_timing() -> None:
    """Table 9 index 1 = 666.6 kbit/s: no exact automatic MCAN solution (13.4), so the esd's bit
    (180 clocks of 120 MHz = 120 clocks of 80 MHz) is written as manual timing and reported."""
    tr = translate([w(0xF800, 5, 0x1, 4)])
    ch = writes_of(tr.cmds, 0x8001)
    assert ch[7] == 1
    assert ch[25] * (1 + ch[26] + ch[27]) == 120
    assert any(n.topic == "bit timing" for n in tr.notes)


def test_autobaud_and_no_baud_rate_are_reported() -> None:
    """5.1.5.9 NTCAN_AUTOBAUD / NTCAN_NO_BAUDRATE have no ECAN-Lite counterpart: reported with the
    closest setting (listen-only at the fallback rate / channel out of the mask)."""
    auto = translate([w(0xF800, 5, esd_rate.NTCAN_AUTOBAUD, 4)], fallback_rate=250_000)
    ch = writes_of(auto.cmds, 0x8001)
    assert (ch[19], ch[8]) == (250_000, 3)
    assert any(n.topic == "0xF800 autobaud" for n in auto.notes)
    none = translate([])
    assert not writes_of(none.cmds, 0x8001)
    assert writes_of(none.cmds, 0x8010)[4] == 0
    assert any(n.topic == "0xF800 no baud rate" for n in none.notes)


def test_queue_sizes_to_multiplier() -> None:
    """Chapter 12: frame area 128 x N - 24 must hold the esd's Tx queue (outputs) and Rx queue plus
    one TX_RESULT per Tx message (inputs). 11-bit T=148: 148 x 12 + 24 = 1800 B -> N = 15."""
    tr = translate([w(0xF800, 2, 2, 1), w(0x8000, 0x22, 148, 1)])
    assert tr.multiplier == 15
    assert writes_of(tr.cmds, 0x8010)[3] == writes_of(tr.cmds, 0x8011)[3] == 15
    default = translate([w(0xF800, 2, 2, 1)])            # 16 + 16: 16 x 12 + 16 x 6 + 24 = 312 -> 3
    assert default.multiplier == 3


def test_too_many_areas_are_merged_and_reported() -> None:
    """13.4: 64 standard filters at most (:41); 70 esd areas -> 64 ranges, the widened gaps reported."""
    areas = [w(0x8001, 0, 70, 1)] + [w(0x8001, i + 1, area(4 * i, 4 * i + 1), 8) for i in range(70)]
    tr = translate([w(0xF800, 2, 2, 1), *areas])
    ch = writes_of(tr.cmds, 0x8001)
    assert ch[49] == 64
    note = next(n for n in tr.notes if n.topic == "0x8001 11-bit areas")
    assert "70 areas" in note.reason and note.closest.count("..") == 6


def test_eleven_bit_mode_rejects_extended_frames() -> None:
    """esd 5.1.5.5: 11-bit queues cannot carry 29-bit frames; the ECAN-Lite rejects them (:37 = 2)."""
    tr = translate([w(0xF800, 2, 2, 1)])
    ch = writes_of(tr.cmds, 0x8001)
    assert (ch[36], ch[37]) == (0, 2)
    assert any(n.topic == "11-bit mode" for n in tr.notes)


def test_channel_option_and_complete_access() -> None:
    """--channel K: 0x8001 + K and mask bit K; --complete-access: 0x1C12/0x1C13 in one CA write
    (subindex 0 padded to 16 bits, ETG.1000.6)."""
    tr = translate([w(0xF800, 2, 2, 1)], channel=2, complete_access=True)
    assert writes_of(tr.cmds, 0x8003)[19] == 500_000
    assert not writes_of(tr.cmds, 0x8001)
    assert writes_of(tr.cmds, 0x8010)[4] == 0x04
    ca = [c for c in tr.cmds if c.complete_access]
    assert [(c.index, c.subindex) for c in ca] == [(0x1C12, 0), (0x1C13, 0)]
    assert ca[0].data == bytes((3, 0)) + struct.pack("<3H", 0x1600, 0x1601, 0x1602)


def test_complete_access_esd_input() -> None:
    """An esd ENI may write 0x8001 and 0x1C13 by complete access: read the same settings."""
    data = bytes((1, 0)) + struct.pack("<Q", area(0x200, 0x2FF))
    esd = read_esd([InitCmd(0x8001, 0, data, True),
                    InitCmd(0x1C13, 0, bytes((2, 0)) + struct.pack("<2H", 0x1A00, 0x1A85), True)])
    assert esd.areas == (area(0x200, 0x2FF),) and esd.status_pdo


def test_unknown_writes_are_reported() -> None:
    """Nothing dropped silently: an esd write the translator does not know is a note."""
    tr = translate([w(0xF800, 2, 2, 1), w(0x2000, 1, 1, 1)])
    assert any(n.topic == "0x2000:01" for n in tr.notes)


def test_startup_list_round_trip() -> None:
    """The plain startup-list format reads back what it writes."""
    tr = translate(GOLDEN_ESD, complete_access=True)
    assert parse_writes(format_writes(tr.cmds)) == [InitCmd(c.index, c.subindex, c.data, c.complete_access)
                                                    for c in tr.cmds]


@given(st.text(max_size=300))
def test_startup_list_parser_only_spec_errors(text: str) -> None:
    """Any text: a list of InitCmds or an EniError, never another exception."""
    try:
        parse_writes(text)
    except EniError:
        pass


@given(st.text(max_size=300))
def test_eni_parser_only_spec_errors(text: str) -> None:
    """Any text: slaves or an EniError."""
    try:
        parse_eni("<EtherCATConfig><Config><Slave><Info>" + text)
        parse_eni(text)
    except EniError:
        pass


TWINCAT_STYLE = """<?xml version="1.0"?>
<EtherCATConfig><Config><Master/><Slave>
 <Info><Name>Box 1 (CAN-EtherCAT)</Name><VendorId>#x00000017</VendorId><ProductCode>2</ProductCode>
  <RevisionNo>#x1</RevisionNo></Info>
 <ProcessData><Send><BitStart>0</BitStart><BitLength>1584</BitLength></Send>
  <Recv><BitLength>1344</BitLength></Recv>
  <Sm2><Type>Outputs</Type><StartAddress>#x1100</StartAddress><ControlByte>#x64</ControlByte><Enable>true</Enable></Sm2>
 </ProcessData>
 <Mailbox DataLinkLayer="true"><Send><Start>4096</Start><Length>256</Length></Send>
  <Recv><Start>4352</Start><Length>256</Length></Recv><Protocol>CoE</Protocol>
  <CoE><InitCmds>
   <InitCmd Fixed="true"><Transition>PS</Transition><Comment>baud</Comment><Timeout>0</Timeout><Ccs>1</Ccs>
    <Index>#xF800</Index><SubIndex>2</SubIndex><Data>04</Data></InitCmd>
   <InitCmd><Transition>PS</Transition><Ccs>2</Ccs><Index>0x1018</Index><SubIndex>1</SubIndex><Data>00</Data></InitCmd>
   <InitCmd CompleteAccess="true"><Transition>PS</Transition><Transition>SO</Transition><Index>7187</Index>
    <SubIndex>0</SubIndex><Data>0200 001A 851A</Data></InitCmd>
  </InitCmds></CoE></Mailbox>
 <DC><CycleTime0>1000000</CycleTime0><ShiftTime>250000</ShiftTime></DC>
</Slave></Config></EtherCATConfig>"""


def test_eni_reader_defensive() -> None:
    """QEC A.7 elements: identity, mailbox, InitCmds (decimal, 0x, #x numbers; Ccs 2 uploads skipped;
    CompleteAccess attribute), process data bit lengths and SMs, DC cycle/shift."""
    (s,) = parse_eni(TWINCAT_STYLE)
    assert (s.vendor_id, s.product_code, s.revision) == (0x17, 2, 1)
    assert (s.mailbox_out, s.mailbox_in) == ((0x1000, 256), (0x1100, 256))
    assert [(c.index, c.subindex, c.data, c.complete_access) for c in s.init_cmds] == [
        (0xF800, 2, b"\x04", False), (0x1C13, 0, bytes.fromhex("0200001A851A"), True)]
    assert (s.output_bits, s.input_bits, s.dc_cycle0, s.dc_shift) == (1584, 1344, 1_000_000, 250_000)
    assert s.sync_managers[0].start == 0x1100
    assert read_esd(s.init_cmds).status_pdo
    with pytest.raises(EniError):
        parse_eni(TWINCAT_STYLE.replace("<Index>#xF800</Index>", "<Index>F800h</Index>"))


@pytest.mark.parametrize("channel", [-1, 4])
def test_channel_out_of_range_is_a_config_error(channel: int) -> None:
    """Manual 13.4: the ECAN-Lite has MCAN channels 0..3 (0x8001..0x8004); another channel is the caller's
    mistake, raised as a ConfigError (issue 22: 'Every exception under GatewaylabError')."""
    with pytest.raises(ConfigError, match=f"channel {channel} is not 0..3"):
        translate(GOLDEN_ESD, channel)
