"""``gatewaylab ec`` CoE verbs: ``upload``, ``download`` and ``sdos`` (SDO information)."""

from __future__ import annotations

import argparse
from typing import IO

from gatewaylab.cli.ec_args import (
    TYPE_BY_CODE,
    TYPES,
    EcUsage,
    access_text,
    format_value,
    one_slave,
    parse_number,
    parse_value,
    selected_slaves,
    slave_header,
    type_name,
)
from gatewaylab.common.errors import GatewaylabError
from gatewaylab.hosts.ethercat.backend import EntryInfo, MasterBackend
from gatewaylab.od.aborts import SdoAbort

__all__ = ["cmd_download", "cmd_sdos", "cmd_upload"]


def _entry(backend: MasterBackend, pos: int, index: int, sub: int) -> EntryInfo | None:
    try:
        info = backend.object_info(pos, index)
    except SdoAbort:
        raise
    except GatewaylabError:
        return None            # no SDO information: the caller needs --type
    for e in info.entries:
        if e.subindex == sub:
            return e
    raise SdoAbort(0x06090011, f"0x{index:04X}:{sub:02X}")


def cmd_upload(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat upload [-t TYPE] INDEX SUBINDEX``: prints the value (integers ``0x.. dec``)."""
    pos = one_slave(backend, args)
    index = parse_number(args.index, "index", 0xFFFF)
    sub = parse_number(args.subindex, "subindex", 0xFF)
    ctype = TYPES[args.type] if args.type else None
    data = backend.sdo_upload(pos, index, sub)
    if ctype is None:
        entry = _entry(backend, pos, index, sub)
        ctype = TYPE_BY_CODE.get(entry.data_type) if entry is not None else None
    print(format_value(ctype, data), file=out)


def cmd_download(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat download [-t TYPE] INDEX SUBINDEX VALUE``."""
    pos = one_slave(backend, args)
    index = parse_number(args.index, "index", 0xFFFF)
    sub = parse_number(args.subindex, "subindex", 0xFF)
    if args.type:
        ctype = TYPES[args.type]
    else:
        entry = _entry(backend, pos, index, sub)
        found = TYPE_BY_CODE.get(entry.data_type) if entry is not None else None
        if found is None:
            raise EcUsage(f"no data type known for 0x{index:04X}:{sub:02X}: give --type")
        ctype = found
    backend.sdo_download(pos, index, sub, parse_value(ctype, args.value))


def cmd_sdos(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat sdos``: every object by SDO Information, then its entries (``-q``: objects only)."""
    positions = selected_slaves(backend, args)
    for pos in positions:
        slave_header(pos, len(positions) > 1, out)
        for obj in backend.object_dictionary(pos):
            print(f'SDO 0x{obj.index:04x}, "{obj.name}"', file=out)
            if args.quiet:
                continue
            for e in obj.entries:
                print(f"  0x{obj.index:04x}:{e.subindex:02x}, {access_text(e.access)}, {type_name(e.data_type)}, "
                      f'{e.bit_length} bit, "{e.name}"', file=out)
