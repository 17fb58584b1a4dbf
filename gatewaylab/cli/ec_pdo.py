"""``gatewaylab ec`` process data verbs: ``pdos``, ``cstruct``, ``xml``, ``domains``, ``data``, ``config``.

They share one view of a slave's SyncManagers with their assigned PDOs (:func:`sync_layout`) and of
the master's one domain (:func:`read_domain`)."""

from __future__ import annotations

import argparse
import struct
from dataclasses import dataclass
from typing import IO, Protocol, runtime_checkable

from gatewaylab.cli.ec_args import EcUsage, bytes_out, selected_slaves, slave_header, state_name
from gatewaylab.ethercat.esc import FMMU_REG, REG_FMMU
from gatewaylab.ethercat.sii import CATEGORY_HEADER, PDO_ENTRY, PDO_HEADER, Category, SmType
from gatewaylab.hosts.ethercat.backend import MasterBackend

__all__ = [
    "MAX_FMMUS",
    "Domain",
    "DomainFmmu",
    "LiveMaster",
    "SiiPdo",
    "SyncLayout",
    "cmd_config",
    "cmd_cstruct",
    "cmd_data",
    "cmd_domains",
    "cmd_pdos",
    "cmd_xml",
    "read_domain",
    "sii_pdos",
    "slave_fmmus",
    "sync_layout",
]


# ------------------------------------------------------------------------------- SII PDOs
@dataclass(frozen=True, slots=True)
class SiiPdo:
    """A PDO of the SII TxPDO/RxPDO categories: names for ``pdos``."""

    index: int
    sm: int
    name: str
    entries: tuple[tuple[int, int, int, str], ...]   # index, subindex, bit length, name


def sii_pdos(img: bytes, strings: tuple[str, ...]) -> dict[int, SiiPdo]:
    """The PDOs of the SII categories (ETG.2010 TxPDO 50 / RxPDO 51), by index."""

    def text(i: int) -> str:
        return strings[i - 1] if 0 < i <= len(strings) else ""

    out: dict[int, SiiPdo] = {}
    pos = 0x80
    while pos + CATEGORY_HEADER.size <= len(img):
        kind, words = CATEGORY_HEADER.unpack_from(img, pos)
        if kind == Category.END:
            break
        data = img[pos + 4:pos + 4 + 2 * words]
        if kind in (Category.TXPDO, Category.RXPDO):
            p = 0
            while p + PDO_HEADER.size <= len(data):
                index, n, sm, _dc, name_idx, _flags = PDO_HEADER.unpack_from(data, p)
                p += PDO_HEADER.size
                entries = []
                for _ in range(n):
                    if p + PDO_ENTRY.size > len(data):
                        break
                    e_index, e_sub, e_name, _dt, bits, _f = PDO_ENTRY.unpack_from(data, p)
                    p += PDO_ENTRY.size
                    entries.append((e_index, e_sub, bits, text(e_name)))
                out[index] = SiiPdo(index, sm, text(name_idx), tuple(entries))
        pos += 4 + 2 * words
    return out


@dataclass(frozen=True, slots=True)
class SyncLayout:
    """One SyncManager of a slave with its assigned PDOs: [(index, name, [(index, sub, bits, name)])]."""

    index: int
    start: int
    length: int
    control: int
    enable: int
    sm_type: int
    pdos: tuple[tuple[int, str, tuple[tuple[int, int, int, str], ...]], ...]

    @property
    def output(self) -> bool:
        """Master writes, slave reads: SM control register direction bits 2-3 = 01 (ETG.1000.4 SM)."""
        return self.control & 0x0C == 0x04

    @property
    def watchdog(self) -> bool:
        """The SM's watchdog trigger (control register bit 6)."""
        return bool(self.control & 0x40)


def sync_layout(backend: MasterBackend, pos: int) -> list[SyncLayout]:
    """SyncManagers (SII), their assigned PDOs (0x1C1x by SDO for CoE slaves) and each PDO's mapped
    entries (0x16xx/0x1Axx), names from the SII PDO categories: what ``pdos`` and ``cstruct`` show."""
    info = backend.sii_info(pos)
    named = sii_pdos(backend.sii_read(pos), info.strings)
    names = {(i, s): n for p in named.values() for i, s, _b, n in p.entries}
    out = []
    for sm_index, (start, length, ctrl, enable, sm_type) in enumerate(info.sync_managers):
        pdos: list[tuple[int, str, tuple[tuple[int, int, int, str], ...]]] = []
        if sm_type in (SmType.OUTPUTS, SmType.INPUTS):
            for pdo_index, entries in _assigned(backend, pos, sm_index, info.coe_details != 0, named):
                pdos.append((pdo_index, named[pdo_index].name if pdo_index in named else "",
                             tuple((i, s, b, names.get((i, s), "")) for i, s, b in entries)))
        out.append(SyncLayout(sm_index, start, length, ctrl, enable, sm_type, tuple(pdos)))
    return out


def cmd_pdos(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat pdos``: SyncManagers (SII), their assigned PDOs (0x1C1x by SDO for CoE slaves)
    and each PDO's mapped entries (0x16xx/0x1Axx), names from the SII PDO categories."""
    positions = selected_slaves(backend, args)
    for pos in positions:
        slave_header(pos, len(positions) > 1, out)
        for sm in sync_layout(backend, pos):
            print(f"SM{sm.index}: PhysAddr 0x{sm.start:04x}, DefaultSize {sm.length:4d}, ControlRegister "
                  f"0x{sm.control:02x}, Enable {sm.enable}", file=out)
            direction = "R" if sm.sm_type == SmType.OUTPUTS else "T"
            for pdo_index, name, entries in sm.pdos:
                print(f'  {direction}xPDO 0x{pdo_index:04x} "{name}"', file=out)
                for e_index, e_sub, bits, e_name in entries:
                    print(f'    PDO entry 0x{e_index:04x}:{e_sub:02x}, {bits:2d} bit, "{e_name}"', file=out)


def cmd_cstruct(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat cstruct``: the slave's PDO configuration as the C structures an IgH application
    hands to ``ecrt_slave_config_pdos()`` (ec_pdo_entry_info_t, ec_pdo_info_t, ec_sync_info_t)."""
    ident = {s.position: s for s in backend.slaves()}
    for pos in selected_slaves(backend, args):
        s = ident[pos]
        layout = sync_layout(backend, pos)
        print(f'/* Master 0, Slave {pos}, "{s.name}"\n * Vendor ID:       0x{s.vendor_id:08x}\n'
              f" * Product code:    0x{s.product_code:08x}\n * Revision number: 0x{s.revision:08x}\n */\n",
              file=out)
        entries = [e for sm in layout for _i, _n, es in sm.pdos for e in es]
        if entries:
            print(f"ec_pdo_entry_info_t slave_{pos}_pdo_entries[] = {{", file=out)
            for index, sub, bits, name in entries:
                print(f"    {{0x{index:04x}, {sub}, {bits}}}, /* {name} */", file=out)
            print("};\n", file=out)
        pdos = [p for sm in layout for p in sm.pdos]
        if pdos:
            print(f"ec_pdo_info_t slave_{pos}_pdos[] = {{", file=out)
            at = 0
            for index, name, es in pdos:
                where = f"slave_{pos}_pdo_entries + {at}" if es else "NULL"
                print(f"    {{0x{index:04x}, {len(es)}, {where}}}, /* {name} */", file=out)
                at += len(es)
            print("};\n", file=out)
        print(f"ec_sync_info_t slave_{pos}_syncs[] = {{", file=out)
        at = 0
        for sm in layout:
            direction = "EC_DIR_OUTPUT" if sm.output else "EC_DIR_INPUT"
            where = f"slave_{pos}_pdos + {at}" if sm.pdos else "NULL"
            watchdog = "EC_WD_ENABLE" if sm.watchdog else "EC_WD_DISABLE"
            print(f"    {{{sm.index}, {direction}, {len(sm.pdos)}, {where}, {watchdog}}},", file=out)
            at += len(sm.pdos)
        print("    {0xff}\n};\n", file=out)


def _assigned(backend: MasterBackend, pos: int, sm_index: int, coe: bool,
              named: dict[int, SiiPdo]) -> list[tuple[int, list[tuple[int, int, int]]]]:
    """(PDO index, [(index, subindex, bits)]) assigned to one SM: by SDO (0x1C10 + SM) on CoE
    slaves, from the SII categories otherwise."""
    if not coe:
        return [(p.index, [(i, s, b) for i, s, b, _n in p.entries]) for p in named.values() if p.sm == sm_index]
    assign = 0x1C10 + sm_index
    out = []
    for i in range(1, backend.sdo_upload(pos, assign, 0)[0] + 1):
        pdo = struct.unpack("<H", backend.sdo_upload(pos, assign, i)[:2])[0]
        entries = []
        for j in range(1, backend.sdo_upload(pos, pdo, 0)[0] + 1):
            word = struct.unpack("<I", backend.sdo_upload(pos, pdo, j)[:4])[0]
            entries.append((word >> 16, (word >> 8) & 0xFF, word & 0xFF))
        out.append((pdo, entries))
    return out


#: ESI data type names by bit length (ETG.2000 base types) for ``xml``'s PDO entries.
_ESI_TYPES = {1: "BOOL", 8: "UINT8", 16: "UINT16", 32: "UINT32", 64: "UINT64"}


def cmd_xml(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat xml``: an ESI (EtherCATInfo, ETG.2000) of each slave from what the line says:
    identity and name, SyncManagers, assigned PDOs and entries (data types by bit length)."""
    from xml.sax.saxutils import escape

    ident = {s.position: s for s in backend.slaves()}
    for pos in selected_slaves(backend, args):
        s = ident[pos]
        lines = ['<?xml version="1.0" ?>', "<EtherCATInfo>", f"  <!-- Slave {pos} -->", "  <Vendor>",
                 f"    <Id>{s.vendor_id}</Id>", "  </Vendor>", "  <Descriptions>", "    <Devices>", "      <Device>",
                 f'        <Type ProductCode="#x{s.product_code:08x}" RevisionNo="#x{s.revision:08x}">'
                 f"{escape(s.name)}</Type>", f"        <Name>{escape(s.name)}</Name>"]
        layout = sync_layout(backend, pos)
        for sm in layout:
            lines.append(f'        <Sm Enable="{sm.enable}" StartAddress="#x{sm.start:04x}" ControlByte='
                         f'"#x{sm.control:02x}" DefaultSize="{sm.length}" />')
        for sm in layout:
            kind = "RxPdo" if sm.sm_type == SmType.OUTPUTS else "TxPdo"
            for index, name, entries in sm.pdos:
                lines += [f'        <{kind} Sm="{sm.index}" Fixed="1" Mandatory="1">',
                          f"          <Index>#x{index:04x}</Index>", f"          <Name>{escape(name)}</Name>"]
                for e_index, e_sub, bits, e_name in entries:
                    lines += ["          <Entry>", f"            <Index>#x{e_index:04x}</Index>",
                              f"            <SubIndex>{e_sub}</SubIndex>", f"            <BitLen>{bits}</BitLen>",
                              f"            <Name>{escape(e_name)}</Name>"]
                    if e_index:
                        lines.append(f"            <DataType>{_ESI_TYPES.get(bits, f'BIT{bits}')}</DataType>")
                    lines.append("          </Entry>")
                lines.append(f"        </{kind}>")
        lines += ["      </Device>", "    </Devices>", "  </Descriptions>", "</EtherCATInfo>"]
        print("\n".join(lines), file=out)


# ------------------------------------------------------------------------------- domain, config
#: FMMUs an ESC may have (ETG.1000.4 registers 0x0600-0x06FF, 16 bytes each).
MAX_FMMUS = 16
#: FMMU type register: 1 = read (the slave's inputs), 2 = write (its outputs).
FMMU_READ, FMMU_WRITE = 1, 2


@runtime_checkable
class LiveMaster(Protocol):
    """The backend of a persistent master (ec_server): mapped or not, and its exchange counters."""

    @property
    def mapped(self) -> bool:
        """Whether the process data is mapped and cycling."""
        ...

    def counters(self) -> tuple[int, int | None, int | None]:
        """(exchanges, working counter of the last one, the one expected then) of the cycling master."""
        ...


@dataclass(frozen=True, slots=True)
class DomainFmmu:
    """One process-data FMMU as the slave's registers hold it (IgH ``domains -v`` lines)."""

    position: int
    sm: int
    output: bool
    logical: int
    size: int


@dataclass(frozen=True, slots=True)
class Domain:
    """The one process-data domain of the master: the mapped image (IgH ``ethercat domains``)."""

    base: int
    size: int
    fmmus: tuple[DomainFmmu, ...]
    working_counter: int | None
    expected: int | None
    exchanges: int
    wkc_errors: int
    data: bytes


def slave_fmmus(backend: MasterBackend, pos: int) -> list[DomainFmmu]:
    """The active read/write FMMUs of one slave (registers 0x0600..), each with the SyncManager whose
    physical start it maps (SyncManagers from the SII): what the master programmed, on either backend."""
    raw = backend.reg_read(pos, REG_FMMU, 16 * MAX_FMMUS)
    starts = {sm[0]: i for i, sm in enumerate(backend.sii_info(pos).sync_managers)}
    out = []
    for k in range(MAX_FMMUS):
        logical, length, _b0, _b1, phys, _pbit, ftype, active = FMMU_REG.unpack_from(raw, 16 * k)
        if active & 1 and length and ftype in (FMMU_READ, FMMU_WRITE) and phys in starts:
            out.append(DomainFmmu(pos, starts[phys], ftype == FMMU_WRITE, logical, length))
    return out


def read_domain(backend: MasterBackend) -> Domain:
    """The domain: mapped first if the master has not (one exchange then, as a one-shot command has no
    cycle), its FMMUs from the slaves' registers and the image put together from outputs and inputs."""
    live = backend if isinstance(backend, LiveMaster) else None
    wkc: int | None = None
    expected: int | None = None
    exchanges = 0
    if live is None or not live.mapped:
        backend.config_map()
        wkc, expected = backend.exchange()
        exchanges = 1
    if live is not None:
        exchanges, wkc, expected = live.counters()
    fmmus = sorted((f for pos in range(len(backend.slaves())) for f in slave_fmmus(backend, pos)),
                   key=lambda f: (f.logical, f.position))
    base = min((f.logical for f in fmmus), default=0)
    size = max((f.logical + f.size for f in fmmus), default=base) - base
    image = bytearray(size)
    for f in fmmus:
        part = bytes(backend.outputs(f.position)) if f.output else backend.inputs(f.position)
        at = f.logical - base
        image[at:at + f.size] = part[:f.size].ljust(f.size, b"\0")
    return Domain(base, size, tuple(fmmus), wkc, expected, exchanges, backend.wkc_errors, bytes(image))


def _check_domain(args: argparse.Namespace) -> None:
    if args.domain not in (None, 0):
        raise EcUsage(f"no domain {args.domain} (the master has one domain: 0, the mapped image)")


def cmd_domains(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat domains``: logical base address, size, working counter (last / expected), the
    exchanges so far; ``-v``: each FMMU (slave, SM, direction, logical address, size) with its data."""
    _check_domain(args)
    d = read_domain(backend)
    wkc = "-" if d.working_counter is None else str(d.working_counter)
    expected = "-" if d.expected is None else str(d.expected)
    print(f"Domain0: LogBaseAddr 0x{d.base:08x}, Size {d.size:3d}, WorkingCounter {wkc}/{expected}", file=out)
    print(f"  Exchanges {d.exchanges}, WorkingCounter mismatches {d.wkc_errors}", file=out)
    if not args.verbose:
        return
    for f in d.fmmus:
        print(f"  SlaveConfig 0:{f.position}, SM{f.sm} ({'Output' if f.output else 'Input':>6}), "
              f"LogAddr 0x{f.logical:08x}, Size {f.size}", file=out)
        data = d.data[f.logical - d.base:f.logical - d.base + f.size]
        for k in range(0, len(data), 16):
            print(f"    {data[k:k + 16].hex(' ')}", file=out)


def cmd_data(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat data``: the domain's process data, binary on stdout (``--hex``: a listing)."""
    _check_domain(args)
    bytes_out(read_domain(backend).data, args.hex, out)


def cmd_config(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat config``: one slave configuration per slave (alias:position, vendor/product,
    the attached slave and its state); ``-v``: the SyncManagers with the PDOs and entries assigned."""
    ident = {s.position: s for s in backend.slaves()}
    rows = []
    for pos in selected_slaves(backend, args):
        status, _code = backend.al_status(pos)
        rows.append((pos, state_name(status) + ("+ERROR" if status & 0x10 else "")))
    if not args.verbose:
        wpos = max(len(str(p)) for p, _ in rows)
        for pos, state in rows:
            s = ident[pos]
            print(f"0:{pos:<{wpos}}  0x{s.vendor_id:08x}/0x{s.product_code:08x}  {pos:>{wpos}}  {state}", file=out)
        return
    for pos, state in rows:
        s = ident[pos]
        print(f"Alias: 0\nPosition: {pos}\nVendor Id: 0x{s.vendor_id:08x}\nProduct code: 0x{s.product_code:08x}\n"
              f"Attached slave: {pos} ({state})\nWatchdog divider: (Default)\nWatchdog intervals: (Default)",
              file=out)
        for sm in sync_layout(backend, pos):
            if not sm.pdos:
                continue
            print(f"SM{sm.index}, Dir: {'Output' if sm.output else 'Input'}, "
                  f"Watchdog: {'Enable' if sm.watchdog else 'Disable'}", file=out)
            for pdo_index, _name, entries in sm.pdos:
                print(f"  PDO 0x{pdo_index:04x}", file=out)
                for e_index, e_sub, bits, _e_name in entries:
                    print(f"    PDO entry 0x{e_index:04x}:{e_sub:02x}, {bits:2d} bit", file=out)
        print("SDO configuration:\n  None.\nIDN configuration:\n  None.\nFeature flags:\n  None.\n", file=out)
