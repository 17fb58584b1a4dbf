"""ESI (EtherCAT Slave Information, ETG.2000) XML export from a device description + dictionary.

The same description feeds the SII image, so what a configuration tool imports matches what the
slave reports online: identity, SyncManagers, FMMUs, PDOs, mailbox protocols, DC modes, the CoE
dictionary (data types with sub-items for records/arrays) and the EEPROM configuration data.
"""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET

from gatewaylab.ethercat.description import DeviceDescription, Pdo, build_od
from gatewaylab.ethercat.sii import build_sii
from gatewaylab.od import ObjectDictionary
from gatewaylab.od.esi import esi_dictionary, esi_type_name

__all__ = ["export_esi"]


def _hex(value: int, digits: int = 8) -> str:
    return f"#x{value:0{digits}X}"


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrs: str) -> ET.Element:
    el = ET.SubElement(parent, tag, attrs)
    if text is not None:
        el.text = text
    return el


def _pdo(parent: ET.Element, tag: str, pdo: Pdo, sm: int | None) -> None:
    """A PDO; ``Sm`` only on the PDOs assigned by default (the others are optional)."""
    attrs = {"Fixed": "1" if pdo.fixed else "0", "Mandatory": "0" if sm is None else "1"}
    if sm is not None:
        attrs["Sm"] = str(sm)
    el = _sub(parent, tag, **attrs)
    _sub(el, "Index", _hex(pdo.index, 4))
    _sub(el, "Name", pdo.name)
    for other in pdo.exclude:
        _sub(el, "Exclude", _hex(other, 4))
    for e in pdo.entries:
        entry = _sub(el, "Entry")
        _sub(entry, "Index", _hex(e.index, 4))
        if e.index:
            _sub(entry, "SubIndex", str(e.subindex))
        _sub(entry, "BitLen", str(e.bit_length))
        if e.index:
            _sub(entry, "Name", e.name)
            # a string entry names its length, as the dictionary part does (ETG.2000: STRING(n))
            _sub(entry, "DataType", esi_type_name(e.data_type, e.bit_length // 8))


def export_esi(desc: DeviceDescription, od: ObjectDictionary | None = None) -> str:
    """ESI XML text for one device type."""
    if od is None:
        od = build_od(desc)
    root = ET.Element("EtherCATInfo", {"xmlns:xsi": "http://www.w3.org/2001/XMLSchema-instance",
                                       "xsi:noNamespaceSchemaLocation": "EtherCATInfo.xsd", "Version": "1.6"})
    vendor = _sub(root, "Vendor")
    _sub(vendor, "Id", _hex(desc.vendor_id))
    _sub(vendor, "Name", desc.vendor_name)
    descriptions = _sub(root, "Descriptions")
    group = _sub(_sub(descriptions, "Groups"), "Group")
    _sub(group, "Type", desc.group)
    _sub(group, "Name", desc.group, LcId="1033")
    device = _sub(_sub(descriptions, "Devices"), "Device", Physics="YY")
    _sub(device, "Type", desc.order_code or desc.name, ProductCode=_hex(desc.product_code),
         RevisionNo=_hex(desc.revision))
    _sub(device, "Name", desc.name, LcId="1033")
    _sub(device, "GroupType", desc.group)
    if desc.coe:
        profile = _sub(device, "Profile")
        _sub(profile, "ProfileNo", str(desc.device_type & 0xFFFF))
        _sub(profile, "AddInfo", str(desc.device_type >> 16))
        esi_dictionary(profile, od)
    has_mbx = desc.has_mailbox
    _sub(device, "Fmmu", "Outputs")
    _sub(device, "Fmmu", "Inputs")
    if has_mbx:
        _sub(device, "Fmmu", "MBoxState")
        for (start, size), ctrl, name in ((desc.mailbox_out, DeviceDescription.SM0_CONTROL, "MBoxOut"),
                                          (desc.mailbox_in, DeviceDescription.SM1_CONTROL, "MBoxIn")):
            _sub(device, "Sm", name, MinSize="34", MaxSize=str(size), DefaultSize=str(size),
                 StartAddress=_hex(start, 4), ControlByte=_hex(ctrl, 2), Enable="1")
    if not desc.inputs_first or has_mbx:
        _sub(device, "Sm", "Outputs", DefaultSize=str(desc.outputs_sii_size),
             StartAddress=_hex(desc.outputs_start, 4), ControlByte=_hex(desc.outputs_control, 2),
             Enable="1" if desc.outputs_sii_size else "0")
    _sub(device, "Sm", "Inputs", DefaultSize=str(desc.inputs_sii_size), StartAddress=_hex(desc.inputs_start, 4),
         ControlByte=_hex(desc.inputs_control, 2), Enable="1" if desc.inputs_sii_size else "0")
    sm_out, sm_in = desc.sm_numbers
    for pdo in desc.rx_pdos:
        _pdo(device, "RxPdo", pdo, sm_out if pdo in desc.assigned_rx_pdos else None)
    for pdo in desc.tx_pdos:
        _pdo(device, "TxPdo", pdo, sm_in if pdo in desc.assigned_tx_pdos else None)
    if has_mbx:
        mailbox = _sub(device, "Mailbox", DataLinkLayer="1")
        for bit, tag in ((0x01, "AoE"), (0x02, "EoE")):
            if desc.other_protocols & bit:
                _sub(mailbox, tag)
        if desc.coe:
            details = 0x2F if desc.coe_details is None else desc.coe_details
            flags = {name: "1" for bit, name in ((0x02, "SdoInfo"), (0x04, "PdoAssign"), (0x08, "PdoConfig"),
                                                 (0x10, "PdoUpload"), (0x20, "CompleteAccess")) if details & bit}
            _sub(mailbox, "CoE", **flags)
        if desc.foe:
            _sub(mailbox, "FoE")
        for bit, tag in ((0x10, "SoE"), (0x20, "VoE")):
            if desc.other_protocols & bit:
                _sub(mailbox, tag)
    if desc.dc:
        dc = _sub(device, "Dc")
        for name, text, assign in desc.dc_op_modes:
            mode = _sub(dc, "OpMode")
            _sub(mode, "Name", name)
            _sub(mode, "Desc", text)
            _sub(mode, "AssignActivate", _hex(assign, 4))
            if assign:
                _sub(mode, "CycleTimeSync0", "0", Factor="1")
                _sub(mode, "ShiftTimeSync0", "0")
    eeprom = _sub(device, "Eeprom")
    sii = build_sii(desc)
    _sub(eeprom, "ByteSize", str(len(sii)))
    _sub(eeprom, "ConfigData", sii[:14].hex().upper())
    if desc.bootstrap:
        _sub(eeprom, "BootStrap", struct.pack("<4H", *desc.bootstrap_mailbox).hex().upper())
    for kind, data in desc.sii_categories:
        category = _sub(eeprom, "Category")
        _sub(category, "CatNo", str(kind))
        _sub(category, "Data", data.hex().upper())
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
