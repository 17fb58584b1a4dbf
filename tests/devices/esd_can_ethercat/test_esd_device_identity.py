"""The esd CAN-EtherCAT's EtherCAT face on the in-process master: identity, standard objects, the
object list as SDO Information gives it, default process image sizes, mappings (manual 5.1.2-5.1.3, 4.2)."""

from __future__ import annotations

from typing import Any

import pytest

from gatewaylab.devices.esd_can_ethercat.objects import esd_description
from gatewaylab.ethercat.errors import AlStatusCode, AlStatusError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.esi import export_esi
from gatewaylab.ethercat.sii import build_sii, parse_sii
from gatewaylab.od import DataType


def test_identity_and_standard_objects_to_the_value(kit: Any) -> None:
    """5.1.3.1-5.1.3.6: device type 0x13881389, name "MEESC", version strings, identity (vendor 0x17,
    product 2, revision = the SII's, serial), 0x1C00 types 1-4."""
    m = kit.master
    kit.preop()
    assert m.sdo_upload32(0, 0x1000) == 0x13881389
    assert m.sdo_upload_str(0, 0x1008) == "MEESC"
    assert m.sdo_upload_str(0, 0x1009) == "1.2"
    assert m.sdo_upload_str(0, 0x100A) == "2.3"
    assert m.sdo_upload8(0, 0x1018, 0) == 4
    assert [m.sdo_upload32(0, 0x1018, i) for i in (1, 2, 4)] == [0x17, 2, 0x1234]
    assert m.sdo_upload32(0, 0x1018, 3) == m.slaves[0].revision == parse_sii(kit.gw.slave.sii).revision
    assert m.slaves[0].vendor_id == 0x17 and m.slaves[0].product_code == 2
    assert [m.sdo_upload8(0, 0x1C00, i) for i in range(5)] == [4, 1, 2, 3, 4]
    assert [m.sdo_upload16(0, 0xF000, i) for i in (1, 2)] == [16, 1]
    assert m.sdo_upload32(0, 0xF000, 3) == 1


def test_sdo_information_lists_every_object_of_5_1_2(kit: Any) -> None:
    """5.1.2: the objects the gateway supports, recreated online by SDO Information (4.2 Figure 7)."""
    kit.preop()
    listed = set(kit.master.od_list(0))
    for index in (0x1000, 0x1008, 0x1009, 0x100A, 0x1018, 0x1600, 0x1A00, 0x1A85, 0x1C00, 0x1C12, 0x1C13,
                  0x2000, 0x2010, 0x6000, 0x6001, 0x7000, 0x7001, 0x8000, 0x8001, 0xF000, 0xF108, 0xF800):
        assert index in listed, hex(index)
    desc = kit.master.object_description(0, 0x1600)
    assert desc.name == "CAN RxPDO-Map" and desc.max_subindex == 19
    entry = kit.master.entry_description(0, 0x6000, 5)
    assert entry.data_type == DataType.OCTET_STRING and entry.bit_length == 80 and entry.name == "Rx Message 1"
    entry = kit.master.entry_description(0, 0x7000, 4)
    assert entry.bit_length == 96 and entry.name == "Tx Message 1"


def test_default_mapping_and_sizes_198_out_168_in(kit: Any) -> None:
    """4.2 / 4.3 Figure 15: 0x1600 has 19 entries (0x7000:01-03 of 16 bits, 16 Tx messages of 96 bits),
    0x1A00 20 (0x6000:01-04, 16 Rx messages of 80 bits): outputs 198 B, inputs 168 B."""
    m = kit.master
    kit.preop()
    assert m.sdo_upload8(0, 0x1600, 0) == 19
    assert [m.sdo_upload32(0, 0x1600, i) for i in (1, 2, 3, 4, 19)] == [
        0x70000110, 0x70000210, 0x70000310, 0x70000460, 0x70001360]
    assert m.sdo_upload8(0, 0x1A00, 0) == 20
    assert [m.sdo_upload32(0, 0x1A00, i) for i in (1, 4, 5, 20)] == [0x60000110, 0x60000410, 0x60000550,
                                                                      0x60001450]
    assert (m.sdo_upload8(0, 0x1C12, 0), m.sdo_upload16(0, 0x1C12, 1)) == (1, 0x1600)
    assert (m.sdo_upload8(0, 0x1C13, 0), m.sdo_upload16(0, 0x1C13, 1)) == (1, 0x1A00)
    kit.op()
    assert (kit.out_size, kit.in_size) == (198, 168)
    assert kit.master.slaves[0].output_bytes == 198


def test_can_status_pdo_1a85_has_the_paddings_of_5_1_3_9(kit: Any) -> None:
    """5.1.3.9: 14 entries, F108:01/02/03, 1-bit padding, :05/:06, 10-bit padding, :11-:14, 12-bit
    padding, :21/:22 (bytes): 48 bits."""
    m = kit.master
    kit.preop()
    assert m.sdo_upload8(0, 0x1A85, 0) == 14
    values = [m.sdo_upload32(0, 0x1A85, i) for i in range(1, 15)]
    assert values == [0xF1080101, 0xF1080201, 0xF1080301, 0x00000001, 0xF1080501, 0xF1080601, 0x0000000A,
                      0xF1081101, 0xF1081201, 0xF1081301, 0xF1081401, 0x0000000C, 0xF1082108, 0xF1082208]
    assert sum(v & 0xFF for v in values) == 48


def test_configuration_objects_and_their_defaults(kit: Any) -> None:
    """5.1.5.5 (0x8000: 36 sub-indexes, queues 16, local queues 1000), 5.1.5.6 (0x8001 empty),
    5.1.5.9 (0xF800:02 = FFh, :05 = 7FFFFFFFh, subindex 0 reads 24 as Figure 13 shows), 5.1.4.1 (0x2000)."""
    m = kit.master
    kit.preop()
    assert m.sdo_upload8(0, 0x8000, 0) == 0x24
    assert [m.sdo_upload8(0, 0x8000, s) for s in (0x21, 0x22)] == [16, 16]
    assert [m.sdo_upload16(0, 0x8000, s) for s in (0x01, 0x20, 0x23, 0x24)] == [0, 0, 1000, 1000]
    assert m.sdo_upload8(0, 0x8001, 0) == 0
    assert m.sdo_upload8(0, 0xF800, 0) == 24
    assert m.sdo_upload8(0, 0xF800, 2) == 0xFF
    assert m.sdo_upload32(0, 0xF800, 5) == 0x7FFFFFFF
    assert [m.sdo_upload8(0, 0x2000, s) for s in (0, 1, 2)] == [2, 0, 0]
    assert m.sdo_upload8(0, 0x2010, 0) == 33
    assert m.sdo_upload8(0, 0xF108, 0) == 0x22


def test_bootstrap_mailbox_has_the_standard_layout_in_the_sii() -> None:
    """Issue 11 'BOOT state with a bootstrap mailbox': the same SM0/SM1 areas (0x1000/0x1080, 128 B,
    Figure 14) so a master that does not reconfigure them still talks FoE."""
    info = parse_sii(build_sii(esd_description()))
    assert info.bootstrap_mailbox == (0x1000, 128, 0x1080, 128)
    assert info.mailbox_out == (0x1000, 128) and info.mailbox_in == (0x1080, 128)
    assert info.vendor_id == 0x17 and info.product_code == 2 and info.revision == 1


@pytest.mark.parametrize("text", ["#x00000017", "#x00000002", "CAN RxPDO-Map", "CAN TxPDO-Map",
                                  "CAN Status PDO", "#x1A85", "MEESC"])
def test_esi_carries_identity_and_pdos(kit: Any, text: str) -> None:
    """4.2 'ESD CAN-EtherCAT.xml': the ESI names vendor, product, the PDOs and the dictionary."""
    esi = export_esi(kit.gw.slave.desc, kit.gw.slave.od)
    assert text in esi


def _assign(kit: Any, index: int, pdos: list[int]) -> None:
    m = kit.master
    m.sdo_download8(0, index, 0, 0)
    for i, pdo in enumerate(pdos):
        m.sdo_download16(0, index, i + 1, pdo)
    m.sdo_download8(0, index, 0, len(pdos))


@pytest.mark.parametrize(("rx", "tx", "code"), [
    ([], [0x1A00], AlStatusCode.INVALID_OUTPUT_MAPPING),
    ([0x1600], [], AlStatusCode.INVALID_INPUT_MAPPING),
    ([0x1600], [0x1A85, 0x1A00], AlStatusCode.INVALID_INPUT_MAPPING),
    ([0x1600], [0x1A85], AlStatusCode.INVALID_INPUT_MAPPING),
])
def test_pdo_assignment_without_the_queues_is_refused_at_safeop(kit: Any, rx: list[int], tx: list[int],
                                                                  code: int) -> None:
    """5.1.3.10 / 5.1.3.11: 0x1C12 assigns the CAN RxPDO 0x1600, 0x1C13 the CAN TxPDO 0x1A00 (4.2 'the
    PDOs 0x1600 and 0x1a00 should be mapped'; 0x1A85 is optional, after them): without the queues the
    gateway cannot run its handshake and refuses PREOP -> SAFEOP with the AL status code of the
    missing direction; it stays in PREOP."""
    kit.preop()
    _assign(kit, 0x1C12, rx)
    _assign(kit, 0x1C13, tx)
    kit.master.config_map()                         # the SyncManagers as the assignment asks for
    with pytest.raises(AlStatusError) as err:
        kit.master.request_state(0, AlState.SAFEOP)
    assert err.value.code == code
    assert kit.gw.slave.state == AlState.PREOP


def test_status_pdo_after_the_queues_reaches_op(kit: Any) -> None:
    """5.1.3.11 + 4.2 '(The optional PDO 0x1a85 contains CAN Status information)': 0x1C13 = 0x1A00,
    0x1A85 is accepted; inputs 168 + 6 bytes."""
    kit.preop()
    _assign(kit, 0x1C13, [0x1A00, 0x1A85])
    kit.op()
    assert kit.gw.slave.state == AlState.OP and kit.in_size == 168 + 6
