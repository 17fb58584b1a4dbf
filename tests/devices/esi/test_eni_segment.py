"""A segment from an ENI, built in the rig (simulated clock, the in-process master) and refused on the command
line: ``gatewaylab run --eni`` with a bad file exits 2 with one line naming the file, the element or line and
what is wrong (issue 'Bad files'); a slave without ESI is no error: it is built from the ENI, said once."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig

DATA = Path(__file__).with_name("data")
ENI = DATA / "GL-test-line.eni.xml"


def _rig(tmp_path: Path, eni: Path, esi: list[str] | None = None, devices: str = "") -> Rig:
    text = f'clock = "simulated"\n{devices}\n[ethercat]\ninterface = "gl-none"\neni = "{eni}"\n'
    if esi is not None:
        text += "esi = [" + ", ".join(f'"{e}"' for e in esi) + "]\n"
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return Rig.from_file(path)


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", "run", *args], capture_output=True, text=True,
                          timeout=120, cwd=cwd, check=False)


def test_eni_order_esi_matches_and_the_rig_device(tmp_path: Path) -> None:
    """Every <Slave> in ENI order: ESI-backed by identity (exact, else the highest lower revision, the slave
    then showing the ENI's revision in its SII and 0x1018:03), the rig's ECAN-Lite by vendor id and product
    code, the others from the ENI alone; paths relative to the rig file's folder."""
    (tmp_path / "esi").mkdir()
    for f in DATA.glob("GL-test-EL*.xml"):
        (tmp_path / "esi" / f.name).write_bytes(f.read_bytes())
    (tmp_path / "line.xml").write_bytes(ENI.read_bytes())
    with _rig(tmp_path, Path("line.xml"), ["esi"], '[[device]]\nkind = "ecanlite"\nname = "ecan1"\n') as rig:
        info = rig.ready_info()
        rows = info["eni"]["slaves"]
        assert [r["match"] for r in rows][:5] == ["ENI only", "exact", "device", "exact",
                                                  "revision 0x00140000, the highest below the ENI's 0x00150000"]
        assert [s["name"] for s in info["ethercat"]["slaves"]][:3] == ["Term_1_EK1100", "Term_2_EL1008", "ecan1"]
        seg = rig.participants[-1].segment
        lower = seg.slaves[4]
        assert lower.desc.revision == 0x00150000 and lower.od.values[(0x1018, 3)] == 0x00150000


def test_initcmds_of_eni_only_slaves_are_accepted(tmp_path: Path) -> None:
    """The ENI-only EL4132 and EL5101 take their CoE InitCmds (PDO assignment, a PDO mapping the ENI marks
    fixed but writes, settings objects the generic dictionary lacks) in PREOP, then reach OP with the
    in-process master mapping what the downloads assigned."""
    with _rig(tmp_path, ENI, [str(DATA)], '[[device]]\nkind = "ecanlite"\nname = "ecan1"\n') as rig:
        seg = rig.participants[-1]
        eni = seg.eni
        assert eni is not None
        master = Master(rig.clock, seg.segment)
        master.scan()
        master.set_state(AlState.PREOP)
        for s in eni.eni.slaves:
            for c in s.coe_cmds:
                master.sdo_download(s.position, c.index, c.subindex, c.data)
        master.config_map()
        master.set_state(AlState.SAFEOP)
        master.set_state(AlState.OP)
        assert master.exchange_process_data() == master.expected_wkc    # its frames: every slave took part
        assert eni.eni.cyclic_wkc == 16      # the ENI's two frames (outputs, inputs): 2 x 4 + 8
        assert master.sdo_upload8(5, 0x1C12, 0) == 2 and master.sdo_upload8(6, 0x8000, 0x01) == 0
        assert master.sdo_upload16(5, 0x8000, 0x11) == 100


def test_an_inputs_only_terminal_has_its_inputs_on_sm0(tmp_path: Path) -> None:
    """ETG.2000: SyncManagers are numbered in the ESI's ``<Sm>`` order; an EL1008 (no mailbox, one
    ``<Sm>Inputs</Sm>``) has its inputs on SM0, its SII lists that one SyncManager, and the ENI's register
    InitCmds programming SM0 and FMMU0 as inputs (TwinCAT's layout) take it to SAFEOP and OP (before, its
    inputs were SM1 and SAFEOP was refused with AL status 0x0017, invalid SyncManager configuration)."""
    with _rig(tmp_path, ENI, [str(DATA)], '[[device]]\nkind = "ecanlite"\nname = "ecan1"\n') as rig:
        seg = rig.participants[-1]
        assert seg.eni is not None
        el1008 = seg.segment.slaves[1]
        assert (el1008.sm_outputs, el1008.sm_inputs) == (1, 0)
        master = Master(rig.clock, seg.segment)
        infos = master.scan()
        assert [sm[4] for sm in infos[1].sii.sync_managers] == [4]      # one SyncManager: inputs
        master.set_state(AlState.PREOP)
        for s in seg.eni.eni.slaves:
            for c in s.coe_cmds:
                master.sdo_download(s.position, c.index, c.subindex, c.data)
        master.config_map()
        for c in seg.eni.eni.slaves[1].init_cmds:
            if "PS" in c.transitions and c.ado in (0x0800, 0x0600):          # set sm 0, set fmmu 0 (inputs)
                master.fpwr(0x1002, c.ado, c.data)
        master.set_state(AlState.SAFEOP)
        master.set_state(AlState.OP)
        assert master.al_status(1) == (AlState.OP, 0)


def test_an_eni_only_el2008_keeps_its_outputs_on_the_digital_output_register(tmp_path: Path) -> None:
    """No ESI at all: the EL2008 (Term 11) is built from the ENI alone, with its outputs SyncManager where the
    ENI's ``ProcessData/Sm0`` puts it (StartAddress 3840 = 0x0F00, the ESC's Digital I/O Output Data register,
    ET1100 data sheet II); its SII says so, a master mapping from the SII programs SM0 there, and the whole
    segment reaches OP with every slave in the working counter."""
    with _rig(tmp_path, ENI, None, '[[device]]\nkind = "ecanlite"\nname = "ecan1"\n') as rig:
        seg = rig.participants[-1]
        assert seg.eni is not None
        assert rig.ready_info()["eni"]["slaves"][10]["match"] == "ENI only"
        master = Master(rig.clock, seg.segment)
        infos = master.scan()
        assert infos[10].sii.sync_managers[0][:3] == (0x0F00, 1, 0x44)
        master.set_state(AlState.PREOP)
        for s in seg.eni.eni.slaves:
            for c in s.coe_cmds:
                master.sdo_download(s.position, c.index, c.subindex, c.data)
        master.config_map()
        master.set_state(AlState.SAFEOP)
        master.set_state(AlState.OP)
        assert master.exchange_process_data() == master.expected_wkc
        el2008 = seg.segment.slaves[10]
        assert el2008.esc.sm_config(0).start == 0x0F00 and el2008.esc.sm_active(0)
        assert master.al_status(10) == (AlState.OP, 0)


def test_ethercat_states_lists_the_eni_slaves_with_their_origin(tmp_path: Path) -> None:
    """The control request ``ethercat-states`` (docs/faults.md) shows every slave of the segment: the rig's
    own devices and the slaves the ENI built, each of those with the file (or 'ENI only') it came from."""
    from gatewaylab.rig.faults import Faults

    with _rig(tmp_path, ENI, [str(DATA)], '[[device]]\nkind = "ecanlite"\nname = "ecan1"\n') as rig:
        states = Faults(rig).ethercat_states()["devices"]
    assert len(states) == 12 and states["ecan1"]["state"] == "INIT"
    assert states["Term_1_EK1100"] == {"state": "INIT", "error": False, "code": 0, "from": "ENI only"}
    assert states["Term_2_EL1008"]["from"].endswith("GL-test-EL1xxx-EL2xxx.xml")


def test_a_missing_esi_falls_back_and_is_said_once(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Two EL3102 (and two EL1008) with no ESI given: both from the ENI alone, one warning per identity."""
    with caplog.at_level(logging.WARNING), _rig(tmp_path, ENI, None,
                                                '[[device]]\nkind = "ecanlite"\nname = "ecan1"\n') as rig:
        rows = rig.ready_info()["eni"]["slaves"]
    assert sum(r["match"] == "ENI only" for r in rows) == 11
    said = [r.getMessage() for r in caplog.records if "product 0xC1E3052 revision 0x140000" in r.getMessage()]
    assert len(said) == 1 and "built from the ENI alone" in said[0]


def test_esi_without_eni_and_a_rig_device_the_eni_lacks(tmp_path: Path) -> None:
    """``esi`` alone names nothing to build; a rig EtherCAT device the ENI does not list is refused (an ENI
    describes the whole segment)."""
    with pytest.raises(ConfigError, match="give eni"):
        Rig(parse_rig({"clock": "simulated", "ethercat": {"interface": "x", "esi": ["a"]}}))
    with pytest.raises(ConfigError, match=r"the rig's EtherCAT devices io \(vendor .*match no <Slave>"):
        _rig(tmp_path, ENI, [str(DATA)], '[[device]]\nkind = "ecanlite"\nname = "ecan1"\n'
                                         '[[device]]\nkind = "ethercat_io"\nname = "io"\n')


@pytest.mark.parametrize(("case", "message"), [
    ("malformed", r"bad\.xml: line 6 column \d+: malformed XML \(not well-formed"),
    ("sm", r"bad\.xml: line \d+: Slave #6 \(Term 6 \(EL4132\)\) ProcessData/Sm2: its PDOs map 32 bits, more "
           r"than the SyncManager's Length 2 bytes"),
    ("no-eni", r"--eni nowhere\.xml: no such file"),
    ("no-esi", r"--esi nowhere: no such ESI file or folder"),
    ("rig-key", r"nowhere\.xml: cannot read it \(No such file or directory\)"),
    ("bad-esi", r"broken\.xml: line 3 column \d+: malformed XML"),
])
def test_bad_files_exit_2_with_one_line(tmp_path: Path, case: str, message: str) -> None:
    """``gatewaylab run`` refuses each bad input before it starts anything: exit 2, one line on stderr."""
    text = ENI.read_text()
    args: list[str] = ["--eni", "bad.xml", "--interface", "gl-none"]
    if case == "malformed":
        lines = text.splitlines()
        lines[4] = lines[4].replace("<Master>", "<Master")
        (tmp_path / "bad.xml").write_text("\n".join(lines))
    elif case == "sm":
        marker = ("<Type>Outputs</Type>\n          <StartAddress>4352</StartAddress>\n"
                  "          <ControlByte>36</ControlByte>")
        assert marker in text
        (tmp_path / "bad.xml").write_text(text.replace(marker, marker + "\n          <Length>2</Length>"))
    elif case == "no-eni":
        args = ["--eni", "nowhere.xml"]
    elif case == "no-esi":
        (tmp_path / "bad.xml").write_text(text)
        args += ["--esi", "nowhere"]
    elif case == "rig-key":
        (tmp_path / "rig.toml").write_text('[ethercat]\ninterface = "gl-none"\neni = "nowhere.xml"\n')
        args = ["rig.toml"]
    else:
        (tmp_path / "bad.xml").write_text(text)
        (tmp_path / "esi").mkdir()
        (tmp_path / "esi" / "broken.xml").write_text("<?xml version='1.0'?>\n<EtherCATInfo><Vendor>\n")
        args += ["--esi", "esi"]
    done = _run(*args, cwd=tmp_path)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("gatewaylab: ")
    assert __import__("re").search(message, lines[0]), lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        p.name for p in tmp_path.iterdir() if not p.name.startswith("gatewaylab-"))   # nothing left behind


def test_slave_names_from_the_file_follow_the_name_rule() -> None:
    """An ENI's ``Info/Name`` is the file's text: the slave's rig name keeps only what the name rule allows
    (docs/rig.md "Names": a name may become a file name in the rig's folder), unique in the rig."""
    from gatewaylab.devices.esi.eni_segment import slave_name
    from gatewaylab.plugin.participant import name_problem

    taken: set[str] = {"ecan1"}
    names = [slave_name(text, taken) for text in ("Term 2 (EL2008)", "../../etc/passwd", "Term 2 (EL2008)",
                                                  "x" * 80, "", ".hidden", "ecan1", "a/b\\c\0d")]
    assert names[:3] == ["Term_2_EL2008", "etc_passwd", "Term_2_EL2008-2"]
    assert names[6] == "ecan1-2"
    assert all(name_problem(n) is None for n in names) and len(set(names)) == len(names)


_SLAVE = """<EtherCATConfig><Config><Slave>
<Info><Name>X</Name><VendorId>2</VendorId><ProductCode>{p}</ProductCode></Info>
<ProcessData><Send><BitLength>{sb}</BitLength></Send><Recv><BitLength>{rb}</BitLength></Recv>
<Sm2><Type>Outputs</Type><StartAddress>{o}</StartAddress><ControlByte>{oc}</ControlByte><Pdo>#x1600</Pdo></Sm2>
<Sm3><Type>Inputs</Type><StartAddress>{i}</StartAddress><Pdo>#x1a00</Pdo></Sm3>
<RxPdo Sm="2"><Index>#x1600</Index>
  <Entry><Index>#x7000</Index><SubIndex>1</SubIndex><BitLen>{eb}</BitLen></Entry></RxPdo>
<TxPdo Sm="3"><Index>#x1a00</Index>
  <Entry><Index>#x6000</Index><SubIndex>{es}</SubIndex><BitLen>8</BitLen></Entry></TxPdo>
</ProcessData>
<Mailbox><Send><Start>{ms}</Start><Length>{ml}</Length></Send><Recv><Start>{mr}</Start><Length>128</Length></Recv>
<CoE><InitCmds><InitCmd><Transition>PS</Transition><Index>{ci}</Index><SubIndex>{cs}</SubIndex><Data>{cd}</Data>
</InitCmd></InitCmds></CoE></Mailbox>
</Slave></Config></EtherCATConfig>"""


_NUMBERS = st.one_of(st.integers(0, 0x40), st.integers(0, 0x1FFFF), st.sampled_from([0x1000, 0x1080, 0x1100, 0x1400,
                                                                                      0xFFFF, 128, 16, 8]))


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.fixed_dictionaries({k: _NUMBERS for k in ("p", "sb", "rb", "o", "oc", "i", "eb", "es", "ms",
                                                                   "ml", "mr", "ci", "cs")},
                             optional={"cd": st.binary(max_size=12).map(bytes.hex)}))
def test_odd_numbers_build_a_slave_or_one_error(values: dict[str, object]) -> None:
    """Any numbers in an ENI slave's fields: a slave from the ENI alone, or one ConfigError line (the file's
    problem), never another exception."""
    from gatewaylab.common.clock import SimulatedClock
    from gatewaylab.devices.esi.eni_segment import EsiCatalogue, build_eni_slave
    from gatewaylab.ethercat.eni import parse_eni_xml

    text = _SLAVE.format(**{"cd": "00", **values})
    try:
        eni = parse_eni_xml(text, "odd.xml")
        build_eni_slave(SimulatedClock(), eni.slaves[0], "x", EsiCatalogue([]), "odd.xml")
    except ConfigError as exc:
        assert "\n" not in str(exc)
