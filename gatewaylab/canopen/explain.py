"""One-line explanations of CANopen frames (CiA 301 predefined connection set, CiA 305 LSS).

For the demo, for students reading a trace, and for anyone wondering what a candump line means.
Every code is decoded with the protocol modules' own enums (:class:`~.nmt.NmtCommand`,
:class:`~.nmt.NmtState`, :class:`~.lss.Cs`, the SDO command specifiers and
:class:`~gatewaylab.od.SdoAbortCode`), so the explanation cannot disagree with the emulator.
"""

from __future__ import annotations

import datetime
import struct

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.emcy import error_code_name
from gatewaylab.canopen.lss import Cs
from gatewaylab.canopen.nmt import NmtCommand, NmtState
from gatewaylab.od.aborts import abort_text
from gatewaylab.od.sdo import ClientCommand, ServerCommand

__all__ = ["explain", "time_of_day"]


_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_TIME = struct.Struct("<IH")
_EPOCH_1984 = datetime.datetime(1984, 1, 1, tzinfo=datetime.UTC)
#: Predefined connection set: PDO COB-ID bases (CiA 301 table 72).
_PDO_BASES = ((0x180, "TPDO1"), (0x200, "RPDO1"), (0x280, "TPDO2"), (0x300, "RPDO2"),
              (0x380, "TPDO3"), (0x400, "RPDO3"), (0x480, "TPDO4"), (0x500, "RPDO4"))


def time_of_day(data: bytes) -> datetime.datetime:
    """The TIME_OF_DAY of a 6-byte TIME frame: ms after midnight (28 bits), days since 1984-01-01."""
    ms, days = _TIME.unpack(data)
    return _EPOCH_1984 + datetime.timedelta(days=days, milliseconds=ms & 0x0FFFFFFF)


def _words(name: str) -> str:
    return name.replace("_", " ").lower()


def _nmt_command(code: int) -> str:
    try:
        return NmtCommand(code).label
    except ValueError:
        return f"command 0x{code:02X}"


def _nmt_state(code: int) -> str:
    try:
        return NmtState(code).label
    except ValueError:
        return f"state 0x{code:02X}"


def _lss(code: int) -> str:
    try:
        return _words(Cs(code).name)
    except ValueError:
        return f"command 0x{code:02X}"


def _sdo(frame: CanFrame, request: bool) -> tuple[str, str]:
    """(what, trailing detail) of an SDO request or response."""
    d = frame.data
    if len(d) < 1:
        return "SDO (empty)", ""
    cs = d[0] >> 5
    where = f" 0x{_U16.unpack_from(d, 1)[0]:04X}:{d[3]:02X}" if len(d) >= 4 else ""
    if cs == ClientCommand.ABORT:
        if len(d) != 8:
            return "SDO abort", ""
        code = _U32.unpack_from(d, 4)[0]
        return f"SDO abort{where} code 0x{code:08X}", f": {abort_text(code)}"
    if request:
        try:
            ccs = ClientCommand(cs)
        except ValueError:
            return f"SDO cs {cs}", ""
        name = _words(ccs.name)
        if ccs is ClientCommand.INITIATE_DOWNLOAD and d[0] & 0x02:
            n = 4 - ((d[0] >> 2) & 3) if d[0] & 0x01 else 4
            return f"SDO {name}{where} expedited, value {d[4:4 + n].hex(' ')}", ""
        with_where = ccs in (ClientCommand.INITIATE_DOWNLOAD, ClientCommand.INITIATE_UPLOAD,
                             ClientCommand.BLOCK_UPLOAD, ClientCommand.BLOCK_DOWNLOAD)
        return f"SDO {name}{where if with_where else ''}", ""
    try:
        scs = ServerCommand(cs)
    except ValueError:
        return f"SDO cs {cs}", ""
    name = _words(scs.name) + " response"
    if scs is ServerCommand.INITIATE_UPLOAD and d[0] & 0x02:
        n = 4 - ((d[0] >> 2) & 3) if d[0] & 0x01 else 4
        return f"SDO {name}{where} expedited, value {d[4:4 + n].hex(' ')}", ""
    with_where = scs in (ServerCommand.INITIATE_UPLOAD, ServerCommand.INITIATE_DOWNLOAD)
    return f"SDO {name}{where if with_where else ''}", ""


def explain(frame: CanFrame) -> str:
    """What a CANopen device would make of this frame."""
    if frame.extended:
        return "29-bit frame (not part of the CANopen predefined connection set)"
    cid = frame.can_id
    d = frame.data
    if frame.rtr:
        return f"remote request for COB-ID 0x{cid:03X}" + (" (node guarding)" if 0x701 <= cid <= 0x77F else "")
    if cid == 0x000 and len(d) == 2:
        target = "all nodes" if d[1] == 0 else f"node {d[1]}"
        return f"NMT {_nmt_command(d[0])} to {target}"
    if cid == 0x080 and len(d) <= 1:
        return "SYNC" + (f" (counter {d[0]})" if d else "")
    if 0x081 <= cid <= 0x0FF and len(d) == 8:
        code = _U16.unpack_from(d, 0)[0]
        return f"EMCY from node {cid - 0x80}: error code 0x{code:04X} ({error_code_name(code)}), " \
               f"error register 0x{d[2]:02X}"
    if cid == 0x100 and len(d) == 6:
        return f"TIME stamp {time_of_day(d).isoformat(timespec='milliseconds')}"
    for base, name in _PDO_BASES:
        if base < cid <= base + 0x7F:
            direction = "from" if name.startswith("T") else "to"
            return f"{name} {direction} node {cid - base}: {d.hex(' ')}"
    if 0x581 <= cid <= 0x5FF and len(d) == 8:
        what, detail = _sdo(frame, request=False)
        return f"{what} from node {cid - 0x580}{detail}"
    if 0x601 <= cid <= 0x67F and len(d) == 8:
        what, detail = _sdo(frame, request=True)
        return f"{what} to node {cid - 0x600}{detail}"
    if 0x701 <= cid <= 0x77F and len(d) == 1:
        return f"{'boot-up' if d[0] == 0 else 'heartbeat'} of node {cid - 0x700}" + (
            "" if d[0] == 0 else f": {_nmt_state(d[0] & 0x7F)}")
    if cid == 0x7E5 and len(d) == 8:
        return f"LSS master: {_lss(d[0])}"
    if cid == 0x7E4 and len(d) == 8:
        cs = d[0]
        if cs == Cs.IDENTIFY_SLAVE:
            return "LSS slave: identify remote slave / Fastscan answer (a slave matches)"
        if cs == Cs.IDENTIFY_NON_CONFIGURED_SLAVE:
            return "LSS slave: identify non-configured slave answer"
        if Cs.INQUIRE_VENDOR <= cs <= Cs.INQUIRE_NODE_ID and len(d) >= 5:
            return f"LSS slave: {_lss(cs)[8:]} = 0x{_U32.unpack_from(d, 1)[0]:X}"
        if cs in (Cs.CONFIGURE_NODE_ID, Cs.CONFIGURE_BIT_TIMING, Cs.STORE_CONFIGURATION) and len(d) >= 2:
            return f"LSS slave: {_lss(cs)} answer, error code {d[1]}"
        if cs == Cs.SWITCH_SELECTIVE_RESPONSE:
            return "LSS slave: switch state selective answer (now in configuration state)"
        return f"LSS slave answer 0x{cs:02X}"
    return f"COB-ID 0x{cid:03X}: {d.hex(' ')}"
