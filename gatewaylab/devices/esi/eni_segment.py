"""A segment from an ENI: every ``<Slave>`` built from its ESI when one matches, else from the ENI alone.

Matching (docs/bring-your-own-network.md): the ESI device with the ENI slave's vendor id, product code
and revision; else the same product's highest lower revision (the slave then shows the ENI's revision,
said once in the log); else an ENI-only slave: the ENI's identity, mailbox SyncManagers and protocols,
process data SyncManagers and PDOs, and a generic dictionary (the standard objects, one object per mapped
entry, one per object the ENI's CoE InitCmds write), as acontis EC-Simulator builds a slave without EXI.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from gatewaylab.common.clock import Clock
from gatewaylab.devices.esi.device import EsiApplication, esi_description
from gatewaylab.devices.esi.files import EsiFiles
from gatewaylab.devices.esi.reader import EsiDevice, EsiError, apply_dictionary, identity_overrides
from gatewaylab.ethercat.description import DeviceDescription
from gatewaylab.ethercat.eni import CoeInitCmd, EniError, EniSlave
from gatewaylab.ethercat.errors import EtherCATConfigError
from gatewaylab.ethercat.esc_registers import RAM_START, SmConfig
from gatewaylab.ethercat.slave import Slave
from gatewaylab.od import Access, DataType, ObjectCode, ObjectDictionary
from gatewaylab.plugin.participant import NAME_MAX, name_problem

__all__ = ["ENI_ONLY", "EsiCatalogue", "Origin", "build_eni_slave", "eni_only_device", "slave_name"]

#: ``Origin.match`` of a slave built from the ENI alone.
ENI_ONLY = "ENI only"


@dataclass(frozen=True, slots=True)
class Origin:
    """Where one slave of the segment came from (the start-up line and the ready file)."""

    position: int
    name: str
    match: str                   # "exact", "lower revision 0x...", ENI_ONLY, "device"
    file: str | None             # the ESI file; None for ENI-only slaves and rig devices
    type_name: str = ""

    def line(self) -> str:
        """The start-up line for this slave."""
        where = f"{self.file} {self.type_name} ({self.match})" if self.file else self.match
        return f"slave {self.position} {self.name}: {where}"


def slave_name(text: str, taken: set[str]) -> str:
    """A rig-wide name from an ENI ``Info/Name`` (``Term 2 (EL2008)`` -> ``Term_2_EL2008``), unique in ``taken``
    and within the name rule every rig name follows (a name may become a file name in the rig's folder): the
    file's text never reaches a path as it is."""
    base = (re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_.-") or "slave")[:NAME_MAX - 4].rstrip("_.-") or "slave"
    name, n = base, 1
    while name in taken:
        n += 1
        name = f"{base}-{n}"
    if name_problem(name) is not None:      # cannot happen by the rules above; a plain name if it ever did
        name = f"slave{len(taken)}"
    taken.add(name)
    return name


class EsiCatalogue:
    """The ESI files given (files, or folders searched for ``*.xml``), indexed by device identity; ``cache``
    the rig build's parsed files (each file read and parsed once however many slaves use it)."""

    def __init__(self, paths: Sequence[Path], cache: EsiFiles | None = None) -> None:
        self.cache = cache if cache is not None else EsiFiles()
        self.files: list[Path] = []
        for path in paths:
            if path.is_dir():
                self.files.extend(sorted(p for p in path.rglob("*") if p.suffix.lower() == ".xml" and p.is_file()))
            elif path.is_file():
                self.files.append(path)
            else:
                raise EsiError(f"{path}: no such ESI file or folder")
        #: (vendor, product) -> [(revision, file, type name)]
        self.index: dict[tuple[int, int], list[tuple[int, Path, str]]] = {}
        for path in self.files:
            self._scan(path)

    def _scan(self, path: Path) -> None:
        _key, root = self.cache.root(path, str(path))
        if root.tag != "EtherCATInfo":
            return                  # another XML file in the folder (an ENI, a project file): not an ESI
        vendor = next(root.iter("Vendor"), None)
        vid = vendor.find("Id") if vendor is not None else None
        try:
            vendor_id = _number(vid.text if vid is not None else None)
            for dev in root.iter("Device"):
                t = dev.find("Type")
                if t is None:
                    continue
                key = (vendor_id, _number(t.get("ProductCode")))
                self.index.setdefault(key, []).append((_number(t.get("RevisionNo", "0")), path,
                                                       (t.text or "").strip()))
        except ValueError as exc:
            raise EsiError(f"{path}: Vendor/Id or Device/Type: {exc}") from None

    def match(self, vendor: int, product: int, revision: int) -> tuple[EsiDevice, str] | None:
        """The ESI device for this identity and how it matched, or None (no ESI: an ENI-only slave)."""
        rows = self.index.get((vendor, product), [])
        exact = [row for row in rows if row[0] == revision]
        lower = sorted((row for row in rows if row[0] < revision), key=lambda row: row[0])
        if exact:
            row, how = exact[0], "exact"
        elif lower:
            row, how = lower[-1], f"revision 0x{lower[-1][0]:08X}, the highest below the ENI's 0x{revision:08X}"
        else:
            return None
        rev, path, type_name = row
        return self.cache.device(path, str(path), type_name or None, product, rev), how


def _number(text: str | None) -> int:
    """Decimal, ``0x`` or ``#x`` (ValueError from int() for anything else, a missing number included)."""
    t = (text or "").strip().lower()
    return int(t[2:], 16) if t.startswith("#x") else int(t, 0) if t.startswith("0x") else int(t)


def eni_only_device(s: EniSlave, source: str) -> EsiDevice:
    """An ESI-like device from what the ENI holds about a slave."""
    outputs = next((sm for sm in s.sms if sm.kind == "Outputs"), None)
    inputs = next((sm for sm in s.sms if sm.kind == "Inputs"), None)
    notes: list[str] = []
    starts = {}
    for label, sm, default in (("Outputs", outputs, 0x1100), ("Inputs", inputs, 0x1400)):
        # where the ENI puts it, an EL2008's outputs on the ESC's Digital I/O Output Data register 0x0F00 included
        starts[label] = sm.start if sm is not None else default
        if sm is not None and sm.start < RAM_START and not SmConfig(
                sm.number, sm.start, max(sm.length or 1, 1), sm.control, 1).on_output_register:
            notes.append(f"Sm {label} at 0x{sm.start:04X} lies on the ESC registers: the ESC refuses it "
                         f"(AL status 0x0017 at PREOP -> SAFEOP)")
    protocols = set(s.protocols)
    other = sum(bit for tag, bit in (("AoE", 0x01), ("EoE", 0x02), ("SoE", 0x10), ("VoE", 0x20)) if tag in protocols)
    has_mailbox = s.mailbox_out is not None and s.mailbox_in is not None
    coe = has_mailbox and ("CoE" in protocols or bool(s.coe_cmds))
    written = {c.index for c in s.coe_cmds if 0x1600 <= c.index < 0x1C00}
    rx = tuple(replace(p, fixed=p.fixed and p.index not in written) for p in s.rx_pdos)
    tx = tuple(replace(p, fixed=p.fixed and p.index not in written) for p in s.tx_pdos)
    mailbox_out = s.mailbox_out if has_mailbox and s.mailbox_out is not None else (0x1000, 128)
    mailbox_in = s.mailbox_in if has_mailbox and s.mailbox_in is not None else (0x1080, 128)
    out_bits = sum(p.bit_length for p in rx if p.index in s.rx_assign)
    in_bits = sum(p.bit_length for p in tx if p.index in s.tx_assign)
    for label, sm, bits in (("Outputs", outputs, out_bits), ("Inputs", inputs, in_bits)):
        size = max((bits + 7) // 8, (sm.length or 0) if sm is not None else 0)
        if starts[label] + 3 * size > 0x10000:
            raise EniError(f"{source}: line {s.line}: Slave #{s.position + 1} ({s.name}) ProcessData: the {label} "
                           f"SyncManager at 0x{starts[label]:04X} with {size} bytes does not fit the ESC's 64 KB")
    try:
        desc = DeviceDescription(
            name=s.name, vendor_id=s.vendor_id, product_code=s.product_code, revision=s.revision, serial=s.serial,
            vendor_name="ENI", group="ENI", order_code=s.name, outputs_start=starts["Outputs"],
            inputs_start=starts["Inputs"], outputs_control=outputs.control if outputs else 0x64,
            inputs_control=inputs.control if inputs else 0x20,
            outputs_sm_size=max((out_bits + 7) // 8, (outputs.length or 0) if outputs else 0),
            inputs_sm_size=max((in_bits + 7) // 8, (inputs.length or 0) if inputs else 0),
            rx_pdos=rx, tx_pdos=tx, rx_assign=s.rx_assign, tx_assign=s.tx_assign, coe=coe,
            foe=has_mailbox and "FoE" in protocols, other_protocols=other if has_mailbox else 0, dc=s.dc,
            inputs_first=not has_mailbox and outputs is None and inputs is not None and inputs.number == 0,
            mailbox_out=mailbox_out, mailbox_in=mailbox_in)
    except EtherCATConfigError as exc:
        raise EniError(f"{source}: line {s.line}: Slave #{s.position + 1} ({s.name}): {exc}") from None
    return EsiDevice(ENI_ONLY, s.name, desc, None, None, tuple(sorted(protocols)), {},
                     outputs.length if outputs else None, inputs.length if inputs else None, tuple(notes))


_SIZES = {1: DataType.UNSIGNED8, 2: DataType.UNSIGNED16, 4: DataType.UNSIGNED32, 8: DataType.UNSIGNED64}


def _accept_init_cmds(od: ObjectDictionary, cmds: Sequence[CoeInitCmd]) -> None:
    """An object for every entry the ENI's CoE InitCmds write that the generic dictionary lacks (the type
    by the data's size), so each download succeeds as on the device the ENI was made for."""
    for c in cmds:
        if c.ccs != 1 or c.complete_access or (c.index, c.subindex) in od.entries:
            continue
        dtype = _SIZES.get(len(c.data), DataType.OCTET_STRING)
        size = None if dtype is not DataType.OCTET_STRING else len(c.data)
        if c.subindex == 0 and c.index not in od.objects:
            od.add_variable(c.index, f"Object 0x{c.index:04X}", dtype, Access.RW, pdo_mappable=False,
                            max_length=size)
            continue
        if c.index not in od.objects:
            od.add_record(c.index, f"Object 0x{c.index:04X}")
        elif od.objects[c.index].object_code is ObjectCode.VAR:
            continue            # a VAR: its subindexes cannot be added
        od.add_sub(c.index, c.subindex, f"SubIndex {c.subindex:03d}", dtype, Access.RW, sub0_name="SubIndex 000",
                   max_length=size)


def build_eni_slave(clock: Clock, s: EniSlave, name: str, catalogue: EsiCatalogue,
                    source: str) -> tuple[Slave, Origin]:
    """The slave for ENI slave ``s``: from its ESI when the catalogue has one, else from the ENI alone."""
    found = catalogue.match(s.vendor_id, s.product_code, s.revision)
    if found is not None:
        device, how = found
        desc = esi_description(device, s.serial or None)
        overlay = identity_overrides(s.serial or None)
        revision = s.revision if desc.revision != s.revision else None

        def own(od: ObjectDictionary) -> None:
            """What this slave shows differently from its ESI: the serial, the ENI's revision."""
            overlay(od)
            if revision is not None and (0x1018, 3) in od.entries:
                od.values[(0x1018, 3)] = revision
                od.replace_entry(replace(od.entries[(0x1018, 3)], default=revision))

        if revision is not None:     # the lower revision's device, showing the ENI's identity
            esi_extend = desc.extend_od

            def revised(od: ObjectDictionary) -> None:
                if esi_extend is not None:
                    esi_extend(od)
                own(od)

            desc = replace(desc, revision=revision, sii_image=None, extend_od=revised)
        od = catalogue.cache.dictionary(device, desc, own)
        slave = Slave(clock, desc, EsiApplication(device), name=name, od=od)
        return slave, Origin(s.position, name, how, device.source, device.type_name)
    device = eni_only_device(s, source)
    overlay = identity_overrides(s.serial or None)

    def extend(od: ObjectDictionary) -> None:
        apply_dictionary(od, device)
        _accept_init_cmds(od, s.coe_cmds)
        overlay(od)

    desc = replace(device.desc, extend_od=extend)
    return Slave(clock, desc, EsiApplication(device), name=name), Origin(s.position, name, ENI_ONLY, None)
