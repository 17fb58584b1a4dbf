"""``gatewaylab ec`` verbs on the slave itself: ``slaves``, ``states``, ``sii-read``, ``reg-read``, ``reg-write``."""

from __future__ import annotations

import argparse
from typing import IO

from gatewaylab.cli.ec_args import (
    STATES,
    TYPES,
    CoeType,
    EcUsage,
    bytes_out,
    format_value,
    one_slave,
    parse_number,
    parse_value,
    selected_slaves,
    state_name,
)
from gatewaylab.ethercat.esc import AlState
from gatewaylab.hosts.ethercat.backend import MasterBackend
from gatewaylab.hosts.ethercat.shared import al_status_name
from gatewaylab.hosts.ethercat.states import state_path


def cmd_slaves(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat slaves``: ``POS  ALIAS:RELPOS  STATE  FLAG  NAME``, one line per slave."""
    ident = {s.position: s for s in backend.slaves()}
    positions = selected_slaves(backend, args)
    rows = []
    for pos in positions:
        status, code = backend.al_status(pos)
        rows.append((pos, state_name(status), "E" if status & 0x10 else "+", code))
    if args.verbose:
        for pos, state, flag, code in rows:
            s = ident[pos]
            print(f"=== Master 0, Slave {pos} ===", file=out)
            print(f"State: {state}\nFlag: {flag}\nAL status code: {al_status_name(code)}", file=out)
            print("Identity:", file=out)
            print(f"  Vendor Id:       0x{s.vendor_id:08x}\n  Product code:    0x{s.product_code:08x}\n"
                  f"  Revision number: 0x{s.revision:08x}\n  Serial number:   0x{s.serial:08x}", file=out)
            print(f"Station address: 0x{s.station:04x}\nName: {s.name}", file=out)
        return
    wpos = max(len(str(p)) for p, *_ in rows)
    wrel = max(len(f"0:{p}") for p, *_ in rows)
    wstate = max(len(st) for _p, st, *_ in rows)
    for pos, state, flag, _code in rows:
        print(f"{pos:>{wpos}}  {f'0:{pos}':<{wrel}}  {state:<{wstate}}  {flag}  {ident[pos].name}", file=out)


def cmd_states(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat states STATE`` requests a state; without STATE the states are listed
    (position, state, error flag, AL status code by name)."""
    positions = selected_slaves(backend, args)
    if args.state is not None:
        target = STATES[args.state.upper()]
        if target in (AlState.SAFEOP, AlState.OP):
            backend.config_map()     # a one-shot command maps first, as IgH's master does on activation
        for pos in positions:
            for step in state_path(backend.state(pos)[0], target):
                backend.request_state(step, pos)
    for pos in positions:
        status, code = backend.al_status(pos)
        state = state_name(status)
        print(f"{pos}  {state:<6}  {'E' if status & 0x10 else '+'}  {al_status_name(code)}", file=out)


def cmd_sii_read(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``ethercat sii_read``: the SII bytes to stdout (binary), ``--hex`` as an offset/hex listing."""
    img = backend.sii_read(one_slave(backend, args))
    bytes_out(img, args.hex, out)


def cmd_reg_read(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``reg_read ADDRESS [SIZE]``: the bytes in hex, 16 a line; with ``--type`` the value."""
    pos = one_slave(backend, args)
    address = parse_number(args.address, "address", 0xFFFF)
    ctype = TYPES[args.type] if args.type else None
    size = parse_number(args.size, "size", 0x10000) if args.size is not None else (
        _type_size(ctype) if ctype is not None else 1)
    if address + size > 0x10000:
        raise EcUsage(f"registers 0x{address:04X}+{size} go past the ESC's 64 KiB (0x0000..0xFFFF)")
    data = backend.reg_read(pos, address, size)
    if ctype is not None:
        print(format_value(ctype, data), file=out)
        return
    for k in range(0, len(data), 16):
        print(" ".join(f"0x{b:02x}" for b in data[k:k + 16]), file=out)


def cmd_reg_write(backend: MasterBackend, args: argparse.Namespace, out: IO[str]) -> None:
    """IgH ``reg_write ADDRESS DATA``: DATA by ``--type``, else hex bytes (``0x0a 0x00`` or ``0a00``)."""
    pos = one_slave(backend, args)
    address = parse_number(args.address, "address", 0xFFFF)
    data = _register_bytes(args)
    if address + len(data) > 0x10000:
        raise EcUsage(f"registers 0x{address:04X}+{len(data)} go past the ESC's 64 KiB (0x0000..0xFFFF)")
    backend.reg_write(pos, address, data)


def _register_bytes(args: argparse.Namespace) -> bytes:
    if args.type:
        return parse_value(TYPES[args.type], args.data)
    text = args.data.replace("0x", "").replace(" ", "").replace(",", "")
    try:
        data = bytes.fromhex(text)
    except ValueError:
        raise EcUsage(f"register data {args.data!r}: hex bytes (0a00 or '0x0a 0x00'), or give --type") from None
    if not data:
        raise EcUsage("register data is empty")
    return data


def _type_size(ctype: CoeType) -> int:
    if not ctype.size:
        raise EcUsage(f"reg-read --type {ctype.name} (variable length) needs SIZE")
    return ctype.size
