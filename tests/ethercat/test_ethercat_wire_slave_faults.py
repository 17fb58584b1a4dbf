"""One slave's faults as pysoem (SOEM) sees them over a veth pair, injected into a running ``gatewaylab run``
from another process with ``gatewaylab fault READY-FILE ...`` (and once through the pytest plugin's
``RigHandle.fault``); the master recovers in the same session, the rig is never restarted.

What each master call must show (ETG.1000.6 and SOEM's own handling): a refused transition leaves the
slave in its state with the error flag (``state`` 0x12 for PREOP + error) and the AL status code that
``ecx_readstate`` reads; a drop to SAFEOP by the slave lowers the working counter and reads 0x001B; an SDO
abort raises ``SdoError`` with its code; a silent SDO is a timeout (``WkcError``) and the next read works;
an FoE error ends ``foe_write`` with SOEM's FoE error result (-5, -10 for 0x8001 file not found); a lost
mailbox reply is repeated (SM1 repeat request) and the SDO completes; an emergency reaches the emergency
callback; a wrong product code in the SII is what ``config_init`` reads.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from wire_kit import JsonMaster, net_capable, run_fault, veth_namespace

from gatewaylab.cli.fault import send_request
from gatewaylab.rig.process import RigProcess

DRIVER = Path(__file__).with_name("ethercat_slave_faults_driver.py")
PRODUCT = 0x00010001
VENDOR = 0x47574C42
RIG = """
[[device]]
kind = "ethercat_io"
name = "io-a"
[[device]]
kind = "ethercat_io"
name = "io-b"
serial = 7
[ethercat]
interface = "{iface}"
"""
PREOP, SAFEOP, OP, ERROR = 0x02, 0x04, 0x08, 0x10


class Line:
    """The rig (``gatewaylab run`` child) and the namespace of the master's end."""

    def __init__(self, rig: RigProcess, namespace: str, iface: str) -> None:
        self.rig, self.namespace, self.iface = rig, namespace, iface

    def fault(self, *args: str) -> dict[str, Any]:
        """``gatewaylab fault READY-FILE --json ARGS`` as a user runs it; its answer."""
        return run_fault(self.rig.ready_file, *args)

    def board(self) -> list[str]:
        states = send_request(str(self.rig.ready_file), {"fault": "ethercat-states"})
        return [f["fault"] for f in states["faults"]]


class Master(JsonMaster):
    """The pysoem driver process; one command, one answer."""

    def __init__(self, line: Line) -> None:
        super().__init__(line.namespace, DRIVER, line.iface)


@pytest.fixture(scope="module")
def line(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Line]:
    reason = net_capable("pysoem")
    if reason is not None:
        pytest.skip(reason)
    workdir = tmp_path_factory.mktemp("slave-faults")
    with veth_namespace("gl-sf-", "glsf") as (ns, emu, mst):
        path = workdir / "rig.toml"
        path.write_text(RIG.format(iface=emu))
        with RigProcess(path, workdir=workdir, timeout=60) as rig:
            yield Line(rig, ns, mst)
            assert rig.proc.poll() is None, rig.log_text()[-2000:]


@pytest.fixture
def master(line: Line) -> Iterator[Master]:
    m = Master(line)
    try:
        assert m.do("init")["count"] == 2
        yield m
    finally:
        m.close()
        send_request(str(line.rig.ready_file), {"fault": "ec-clear"})


def _op(master: Master) -> int:
    up = master.do("to_op")
    assert up["op"] == OP, up
    return int(up["expected_wkc"])


def _wkcs(master: Master, n: int = 20) -> list[int]:
    """The working counters of n cycles; lost cycles (<= 0) are counted and printed, not judged."""
    wkc: list[int] = master.do("cycles", n=n)["wkc"]
    lost = sum(1 for w in wkc if w <= 0)
    if lost:
        print(f"{lost} of {n} cycles lost (no reply)")
    return [w for w in wkc if w > 0]


def test_al_error_refuses_safeop_then_ack_and_retry(line: Line, master: Master) -> None:
    """ec-al-error io-b 0x001D --on PS: SOEM's request of SAFEOP leaves io-b in PREOP + error with AL status
    code 0x001D (ecx_readstate); the master acknowledges (PREOP + ACK) and SAFEOP then succeeds."""
    assert line.fault("ec-al-error", "io-b", "0x001D", "--on", "PS")["on"] == "PREOP-SAFEOP"
    states = master.do("map")["states"]               # SOEM's config_map requests SAFEOP of every slave
    assert states[0] == {"state": SAFEOP, "al_status": 0}, states
    assert states[1] == {"state": PREOP | ERROR, "al_status": 0x001D}, states
    assert line.board() == []
    master.do("state", slave=1, state=PREOP, ack=True)
    assert master.do("read_state")["states"][1]["state"] == PREOP
    assert master.do("state", slave=1, state=SAFEOP)["states"][1] == {"state": SAFEOP, "al_status": 0}


def test_drop_state_lowers_the_working_counter_and_the_master_recovers(line: Line, master: Master) -> None:
    expected = _op(master)
    assert set(_wkcs(master)) == {expected}
    answer = line.fault("ec-drop-state", "io-a", "SAFEOP")
    assert answer["code"] == 0x001B
    low = _wkcs(master)
    assert low and all(w < expected for w in low)
    assert master.do("read_state")["states"][0] == {"state": SAFEOP | ERROR, "al_status": 0x001B}
    master.do("state", slave=0, state=SAFEOP, ack=True)
    assert master.do("state", slave=0, state=OP)["states"][0]["state"] == OP
    assert set(_wkcs(master)) == {expected}


def test_sdo_abort_raises_sdo_error_with_the_code(line: Line, master: Master) -> None:
    line.fault("ec-sdo-abort", "io-a", "0x06090011", "--index", "0x1018")
    assert master.do("sdo_read", slave=0, index=0x1008, sub=0).get("data")
    aborted = master.do("sdo_read", slave=0, index=0x1018, sub=1)
    assert aborted["error"] == "SdoError" and aborted["abort_code"] == 0x06090011, aborted
    assert master.do("sdo_read", slave=0, index=0x1018, sub=1)["data"] == VENDOR.to_bytes(4, "little").hex()


def test_sdo_silent_times_out_then_the_next_works(line: Line, master: Master) -> None:
    line.fault("ec-sdo-silent", "io-b")
    silent = master.do("sdo_read", slave=1, index=0x1018, sub=2, timeout_us=1_000_000)
    assert silent["error"] == "WkcError", silent
    assert line.board() == []
    assert master.do("sdo_read", slave=1, index=0x1018, sub=2)["data"] == PRODUCT.to_bytes(4, "little").hex()


def test_foe_error_at_packet_two(line: Line, master: Master) -> None:
    """SOEM ends the write with its FoE error result: -10 (EC_ERR_TYPE_FOE_FILE_NOTFOUND) for FoE error
    0x8001, -5 (EC_ERR_TYPE_FOE_ERROR) for any other; written again, it completes."""
    line.fault("ec-foe-error", "io-a", "0x8001", "--packet", "2")
    assert master.do("foe_write", slave=0, name="fw.bin", size=400)["result"] == -10
    line.fault("ec-foe-error", "io-a", "0x8008", "--packet", "2")
    assert master.do("foe_write", slave=0, name="fw.bin", size=400)["result"] == -5
    assert master.do("foe_write", slave=0, name="fw.bin", size=400)["result"] > 0


def test_mailbox_lose_the_sdo_still_completes(line: Line, master: Master) -> None:
    """The reply is read by SOEM with working counter 0; SOEM toggles the SM1 repeat request and reads it
    again: the SDO read returns the value, and the fault was used (off the board)."""
    line.fault("ec-mailbox-lose", "io-a")
    assert master.do("sdo_read", slave=0, index=0x1018, sub=1)["data"] == VENDOR.to_bytes(4, "little").hex()
    assert line.board() == []


def test_emcy_reaches_the_emergency_callback(line: Line, master: Master) -> None:
    line.fault("ec-emcy", "io-b", "0x8110", "--register", "0x11", "--data", "0102030405")
    out = master.do("emcy", slave=1)
    assert out["data"] == VENDOR.to_bytes(4, "little").hex()
    assert out["emergencies"] == [{"error_code": 0x8110, "error_reg": 0x11, "b1": 1, "w1": 0x0302, "w2": 0x0504}]


def test_eeprom_wrong_product_is_what_config_init_reads(line: Line, master: Master) -> None:
    line.fault("ec-eeprom", "io-b", "product=0x00BADBAD")
    ids = [s["id"] for s in master.do("config_init")["slaves"]]
    assert ids == [PRODUCT, 0x00BADBAD]
    line.fault("ec-clear", "io-b")
    assert [s["id"] for s in master.do("config_init")["slaves"]] == [PRODUCT, PRODUCT]
    # a bad SII checksum: SOEM clears the error bits (NOP) before each EEPROM read and does not check the
    # checksum itself, so it still reads the identity
    line.fault("ec-eeprom", "io-b", "checksum")
    assert [s["id"] for s in master.do("config_init")["slaves"]] == [PRODUCT, PRODUCT]


def test_drop_state_init_is_a_power_glitch_the_master_reconfigures(line: Line, master: Master) -> None:
    """ec-drop-state io-b INIT: io-b powers on (station address lost): SOEM's working counter drops and its
    state read shows io-b gone from OP; config_init and the bring-up again take both back to OP with the
    full working counter."""
    expected = _op(master)
    answer = line.fault("ec-drop-state", "io-b", "INIT")
    assert answer["reset"] is True and answer["from"] == "OP"
    low = _wkcs(master)
    assert low and all(w < expected for w in low)
    assert master.do("read_state")["states"][1]["state"] != OP
    assert master.do("config_init")["count"] == 2
    assert _op(master) == expected
    assert set(_wkcs(master)) == {expected}


def test_sdo_abort_at_the_second_segment(line: Line, master: Master) -> None:
    """--segment 2 on a 400-byte segmented download to 0x8000:01: SdoError with the code, the old value kept;
    the same write then completes, and an upload aborted at its second segment raises too."""
    before = master.do("sdo_read", slave=0, index=0x8000, sub=1, size=1024)["data"]
    text = (bytes(range(32, 112)) * 5).hex()
    line.fault("ec-sdo-abort", "io-a", "0x08000020", "--index", "0x8000", "--segment", "2")
    aborted = master.do("sdo_write", slave=0, index=0x8000, sub=1, data=text)
    assert aborted["error"] == "SdoError" and aborted["abort_code"] == 0x08000020, aborted
    assert master.do("sdo_read", slave=0, index=0x8000, sub=1, size=1024)["data"] == before
    assert master.do("sdo_write", slave=0, index=0x8000, sub=1, data=text) == {"done": True}
    line.fault("ec-sdo-abort", "io-a", "0x08000021", "--segment", "2")
    aborted = master.do("sdo_read", slave=0, index=0x8000, sub=1, size=1024)
    assert aborted["error"] == "SdoError" and aborted["abort_code"] == 0x08000021, aborted
    assert master.do("sdo_read", slave=0, index=0x8000, sub=1, size=1024)["data"] == text


def test_eeprom_busy_and_stuck_reads(line: Line, master: Master) -> None:
    """busy: SOEM's EEPROM read gives up after its 20 ms timeout (zeros) while 0x0502 shows busy; ended, the
    read returns the product code. stuck: the same; cleared, the read fails once (acknowledge error) and
    SOEM's next read, clearing the error bits first, returns the product code."""
    product = PRODUCT.to_bytes(4, "little").hex()
    line.fault("ec-eeprom", "io-a", "busy", "--seconds", "60")
    assert master.do("eeprom_read", slave=0, word=0x0A)["data"] == "00000000"
    line.fault("ec-clear", "io-a")
    assert master.do("eeprom_read", slave=0, word=0x0A)["data"] == product
    line.fault("ec-eeprom", "io-a", "stuck")
    assert master.do("eeprom_read", slave=0, word=0x0A)["data"] == "00000000"
    assert line.board() == ["ec-eeprom"]
    line.fault("ec-clear", "io-a")
    assert master.do("eeprom_read", slave=0, word=0x0A)["data"] == product


def test_plugin_fault_through_a_running_rig(gatewaylab_rig: Any, tmp_path: Path) -> None:
    """Through the pytest plugin: ``gatewaylab_rig(...)`` runs ``gatewaylab run`` as a child on a veth pair,
    ``RigHandle.fault("ec-sdo-abort", ...)`` arms the fault through its control endpoint, and pysoem's next
    SDO read raises ``SdoError`` with that code."""
    reason = net_capable("pysoem")
    if reason is not None:
        pytest.skip(reason)
    with veth_namespace("gl-sfp-", "glsp") as (ns, emu, mst):
        rig = tmp_path / "rig.toml"
        rig.write_text(RIG.format(iface=emu))
        handle = gatewaylab_rig(rig, clock="realtime")
        master = Master(Line(handle.process, ns, mst))
        try:
            assert master.do("init")["count"] == 2
            answer = handle.fault("ec-sdo-abort", device="io-b", code=0x06010002, index=0x1018)
            assert answer["fault"] == "ec-sdo-abort" and answer["id"]
            aborted = master.do("sdo_read", slave=1, index=0x1018, sub=1)
            assert aborted["error"] == "SdoError" and aborted["abort_code"] == 0x06010002, aborted
            assert master.do("sdo_read", slave=1, index=0x1018, sub=1)["data"] == VENDOR.to_bytes(4, "little").hex()
        finally:
            master.close()
            handle.stop()
