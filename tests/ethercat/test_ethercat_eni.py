"""The ENI reader (gatewaylab/ethercat/eni.py): golden vectors from the elements ETG.2100 defines and the QEC
master manual A.7 lists (Info VendorId/ProductCode, Mailbox Send/Recv Start, CoE InitCmd Index/SubIndex/Data/
Timeout/CompleteAccess, ProcessData Send/Recv BitLength, Sm StartAddress/ControlByte/Enable, DC), the same
document in its equivalent spellings, trailing garbage, and a property: random or truncated XML gives an
:class:`EniError` line naming the file, never another exception."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.ethercat.eni import EniError, parse_eni_xml

ENI = Path(__file__).resolve().parent.parent / "devices" / "esi" / "data" / "GL-test-line.eni.xml"

#: One slave as A.7 lists the elements a master reads, TwinCAT's number spellings mixed in.
GOLDEN = """<?xml version="1.0" encoding="utf-8"?>
<EtherCATConfig Version="1.3">
  <Config>
    <Master><Info><Name>QEC</Name></Info></Master>
    <Slave>
      <Info>
        <Name>Drive 1</Name>
        <PhysAddr>4097</PhysAddr>
        <AutoIncAddr>0</AutoIncAddr>
        <VendorId>#x00000539</VendorId>
        <ProductCode>0x02200001</ProductCode>
        <RevisionNo>2</RevisionNo>
        <SerialNo>77</SerialNo>
      </Info>
      <ProcessData>
        <Send><BitStart>0</BitStart><BitLength>48</BitLength></Send>
        <Recv><BitStart>48</BitStart><BitLength>32</BitLength></Recv>
        <Sm2><Type>Outputs</Type><StartAddress>#x1100</StartAddress><ControlByte>100</ControlByte>
          <Enable>true</Enable><Pdo>#x1600</Pdo></Sm2>
        <Sm3><Type>Inputs</Type><StartAddress>5120</StartAddress><ControlByte>32</ControlByte>
          <Enable>1</Enable><Pdo>6656</Pdo></Sm3>
        <RxPdo Fixed="false" Sm="2"><Index>#x1600</Index><Name>Outputs</Name>
          <Entry><Index>#x6040</Index><SubIndex>0</SubIndex><BitLen>16</BitLen><Name>Controlword</Name>
            <DataType>UINT</DataType></Entry>
          <Entry><Index>#x607a</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><Name>Target position</Name>
            <DataType>DINT</DataType></Entry></RxPdo>
        <TxPdo Fixed="true" Sm="3"><Index>#x1a00</Index><Name>Inputs</Name>
          <Entry><Index>#x6041</Index><SubIndex>0</SubIndex><BitLen>16</BitLen><Name>Statusword</Name></Entry>
          <Entry><Index>0</Index><BitLen>16</BitLen></Entry></TxPdo>
      </ProcessData>
      <Mailbox DataLinkLayer="true">
        <Send><Start>4096</Start><Length>128</Length></Send>
        <Recv><Start>#x1080</Start><Length>128</Length></Recv>
        <Protocol>CoE</Protocol>
        <CoE><InitCmds>
          <InitCmd Fixed="true" CompleteAccess="true"><Transition>PS</Transition><Comment>assign</Comment>
            <Timeout>1000</Timeout><Ccs>1</Ccs><Index>7186</Index><SubIndex>0</SubIndex><Data>01000016</Data>
          </InitCmd>
          <InitCmd><Transition>PS</Transition><Timeout>0</Timeout><Ccs>1</Ccs><Index>#x6060</Index>
            <SubIndex>0</SubIndex><Data>08</Data></InitCmd>
        </InitCmds></CoE>
      </Mailbox>
      <InitCmds>
        <InitCmd><Transition>IP</Transition><Comment>set sm 0</Comment><Cmd>5</Cmd><Adp>4097</Adp><Ado>2048</Ado>
          <Data>0010800026000100</Data><Cnt>1</Cnt></InitCmd>
        <InitCmd><Transition>PS</Transition><Transition>IS</Transition><Comment>check state</Comment><Cmd>4</Cmd>
          <Adp>4097</Adp><Ado>304</Ado><DataLength>2</DataLength><Cnt>1</Cnt>
          <Validate><Data>0400</Data><DataMask>1f00</DataMask><Timeout>5000</Timeout></Validate></InitCmd>
      </InitCmds>
      <DC><CycleTime0>1000000</CycleTime0><ShiftTime>0</ShiftTime></DC>
    </Slave>
    <Cyclic><CycleTime>1000</CycleTime><Frame><Cmd><State>OP</State><Cmd>12</Cmd><Addr>0</Addr>
      <DataLength>10</DataLength><Cnt>3</Cnt></Cmd></Frame></Cyclic>
    <ProcessImage><Inputs><ByteSize>4</ByteSize></Inputs><Outputs><ByteSize>6</ByteSize></Outputs></ProcessImage>
  </Config>
</EtherCATConfig>
"""


def test_golden_slave_identity_mailbox_and_process_data() -> None:
    """A.7 Info, Mailbox, ProcessData and Sm elements as the QEC master reads them; decimal, ``0x`` and ``#x``
    numbers alike (TwinCAT writes both)."""
    eni = parse_eni_xml(GOLDEN, "golden.xml")
    (s,) = eni.slaves
    assert (s.name, s.vendor_id, s.product_code, s.revision, s.serial) == ("Drive 1", 0x539, 0x02200001, 2, 77)
    assert (s.phys_addr, s.auto_inc_addr) == (4097, 0)
    assert (s.mailbox_out, s.mailbox_in, s.protocols) == ((0x1000, 128), (0x1080, 128), ("CoE",))
    assert (s.send_bits, s.recv_bits) == (48, 32)
    assert [(m.number, m.kind, m.start, m.control, m.enable, m.pdos) for m in s.sms] == [
        (2, "Outputs", 0x1100, 0x64, True, (0x1600,)), (3, "Inputs", 0x1400, 0x20, True, (0x1A00,))]
    assert [e.mapping for e in s.rx_pdos[0].entries] == [0x60400010, 0x607A0020]
    assert [e.mapping for e in s.tx_pdos[0].entries] == [0x60410010, 0x00000010]
    assert (s.rx_pdos[0].fixed, s.tx_pdos[0].fixed) == (False, True)
    assert (s.rx_assign, s.tx_assign, s.dc) == ((0x1600,), (0x1A00,), True)
    assert (eni.master, eni.cyclic_wkc, eni.cycle_time_us, eni.inputs_bytes, eni.outputs_bytes) == (
        "QEC", 3, 1000, 4, 6)


def test_golden_init_cmds() -> None:
    """A.7 'InitCmds : InitCmd : Index/SubIndex/Data/Timeout' and the CompleteAccess attribute; ETG.2100
    register InitCmds with their transitions, command, address, data or length, Cnt and Validate."""
    (s,) = parse_eni_xml(GOLDEN, "golden.xml").slaves
    ca, mode = s.coe_cmds
    assert (ca.index, ca.subindex, ca.data, ca.complete_access, ca.transitions, ca.timeout_ms, ca.comment) == (
        0x1C12, 0, bytes.fromhex("01000016"), True, ("PS",), 1000, "assign")
    assert (mode.index, mode.data, mode.complete_access) == (0x6060, b"\x08", False)
    write, check = s.init_cmds
    assert (write.cmd, write.adp, write.ado, write.data, write.cnt, write.is_read) == (
        5, 4097, 0x0800, bytes.fromhex("0010800026000100"), 1, False)
    assert (check.transitions, check.cmd, check.data, check.validate, check.validate_mask, check.timeout_ms,
            check.is_read) == (("PS", "IS"), 4, b"\0\0", b"\x04\x00", b"\x1f\x00", 5000, True)


@pytest.mark.parametrize("variant", ["crlf", "bom", "namespace", "spaces"])
def test_equivalent_spellings_read_the_same(variant: str) -> None:
    """The same document with CRLF line ends, a UTF-8 byte order mark, a namespace prefix on every element, or
    blanks around every number is the same ENI."""
    text = GOLDEN
    if variant == "crlf":
        data = text.replace("\n", "\r\n").encode()
    elif variant == "bom":
        data = b"\xef\xbb\xbf" + text.encode()
    elif variant == "namespace":
        body = text.split("?>", 1)[1].replace("<", "<e:").replace("<e:/", "</e:").replace(
            '<e:EtherCATConfig Version="1.3">', '<e:EtherCATConfig xmlns:e="urn:x" Version="1.3">')
        data = body.encode()
    else:
        data = text.replace("<Index>", "<Index> ").replace("</Index>", " </Index>").encode()
    assert parse_eni_xml(data, "v.xml") == parse_eni_xml(GOLDEN, "v.xml")


def test_trailing_garbage_is_one_line_naming_file_and_line() -> None:
    """Anything after the root element is malformed XML: the file and the line, nothing read."""
    line = GOLDEN.count("\n") + 1
    with pytest.raises(EniError, match=rf"^g\.xml: line {line} column \d+: malformed XML \(junk after document"):
        parse_eni_xml(GOLDEN + "<Slave/>\n", "g.xml")


@pytest.mark.parametrize(("edit", "match"), [
    (("<VendorId>#x00000539</VendorId>", ""), r"line 6: Slave #1 \(Drive 1\) Info/VendorId: missing"),
    (("<RevisionNo>2</RevisionNo>", "<RevisionNo>two</RevisionNo>"), r"RevisionNo: 'two' is not a number"),
    (("<Data>08</Data>", "<Data>0g</Data>"), r"InitCmd #2 0x6060:00/Data: '0g' is not hex bytes"),
    (("<Cmd>5</Cmd>", "<Cmd>15</Cmd>"), r"InitCmds/InitCmd #1/Cmd: 15 is not an EtherCAT command"),
    (("<Start>4096</Start>", "<Start>256</Start>"), r"Mailbox/Send: a mailbox at 0x0100"),
    (("<DataLength>2</DataLength>", "<DataLength>99999999999</DataLength>"),
     r"InitCmd #2/DataLength: 99999999999 is out of range \(0..1486\)"),
    (("<ProductCode>0x02200001</ProductCode>", "<ProductCode>0x1FFFFFFFF</ProductCode>"),
     r"Info/ProductCode: 8589934591 is out of range"),
    (("<Index>#x1600</Index>", "<Index>-1</Index>"), r"RxPdo/Index: -1 is out of range"),
    (("<EtherCATConfig", "<EtherCATInfo"), None),
])
def test_bad_elements_name_file_line_and_element(edit: tuple[str, str], match: str | None) -> None:
    """Each unusable element: one line with the file, the line of its slave, the element path and the problem."""
    text = GOLDEN.replace(*edit)
    if match is None:
        text = text.replace("</EtherCATConfig>", "</EtherCATInfo>")
        match = r"<EtherCATInfo>: the root element must be <EtherCATConfig>"
    pattern = match if match.startswith("line") else rf"(line \d+: )?.*{match}"
    with pytest.raises(EniError, match=r"^b\.xml: " + pattern):
        parse_eni_xml(text, "b.xml")


def test_pdo_mapping_exceeding_its_sync_manager() -> None:
    """A PDO mapping larger than its SyncManager's Length (or than the process data's BitLength) cannot run."""
    text = GOLDEN.replace("<Enable>true</Enable><Pdo>#x1600</Pdo>", "<Enable>true</Enable><Length>4</Length>"
                                                                    "<Pdo>#x1600</Pdo>")
    with pytest.raises(EniError, match=r"ProcessData/Sm2: its PDOs map 48 bits, more than the SyncManager's Length 4"):
        parse_eni_xml(text, "b.xml")
    text = GOLDEN.replace("<BitLength>48</BitLength>", "<BitLength>40</BitLength>")
    with pytest.raises(EniError, match=r"Send/BitLength: the assigned PDOs map 48 bits, more than the 40 bits"):
        parse_eni_xml(text, "b.xml")


def test_the_test_eni_reads_whole() -> None:
    """The 12-slave TwinCAT-layout test ENI: every slave, its InitCmds and the cyclic working counter."""
    eni = parse_eni_xml(ENI.read_bytes(), ENI.name)
    assert len(eni.slaves) == 12 and eni.cyclic_wkc == 16
    assert [s.phys_addr for s in eni.slaves] == [0x1001 + i for i in range(12)]
    assert all(s.init_cmds for s in eni.slaves)


TEXT = ENI.read_bytes()


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(st.binary(max_size=400), st.integers(0, len(TEXT)).map(lambda n: TEXT[:n]),
                 st.tuples(st.integers(0, len(TEXT) - 1), st.binary(min_size=1, max_size=8)).map(
                     lambda t: TEXT[:t[0]] + t[1] + TEXT[t[0] + len(t[1]):])))
def test_random_and_truncated_xml_never_crashes(data: bytes) -> None:
    """Random bytes, every truncation and random overwrites of the test ENI: an ENI or one EniError line
    naming the file (DEVELOPERS.md: only spec errors come out of a parser)."""
    try:
        parse_eni_xml(data, "fuzz.xml")
    except EniError as exc:
        text = str(exc)
        assert text.startswith("fuzz.xml: ") and "\n" not in text
