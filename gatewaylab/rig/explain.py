"""One-line explanations of CANopen frames (CiA 301 predefined connection set, CiA 305 LSS).

For the demo, for students reading a trace, and for anyone wondering what a candump line means.
"""

from __future__ import annotations

import struct

from ..bus.frame import CanFrame

_NMT_COMMANDS = {1: "start (-> Operational)", 2: "stop (-> Stopped)", 0x80: "enter Pre-operational",
                 0x81: "reset node", 0x82: "reset communication"}
_NMT_STATES = {0: "boot-up", 4: "Stopped", 5: "Operational", 0x7F: "Pre-operational"}
_LSS_MASTER = {0x04: "switch state global", 0x11: "configure node id", 0x13: "configure bit timing",
               0x15: "activate bit timing", 0x17: "store configuration", 0x40: "switch state selective: vendor",
               0x41: "switch state selective: product", 0x42: "switch state selective: revision",
               0x43: "switch state selective: serial", 0x46: "identify remote slave: vendor",
               0x47: "identify remote slave: product", 0x48: "identify: revision low",
               0x49: "identify: revision high", 0x4A: "identify: serial low", 0x4B: "identify: serial high",
               0x4C: "identify non-configured remote slave", 0x51: "Fastscan", 0x5A: "inquire vendor id",
               0x5B: "inquire product code", 0x5C: "inquire revision", 0x5D: "inquire serial number",
               0x5E: "inquire node id"}
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")


def _sdo(frame: CanFrame, request: bool) -> str:
    d = frame.data
    if len(d) < 1:
        return "SDO (empty)"
    cs = d[0] >> 5
    where = f" 0x{_U16.unpack_from(d, 1)[0]:04X}:{d[3]:02X}" if len(d) >= 4 else ""
    if cs == 4:
        return f"SDO abort{where} code 0x{_U32.unpack_from(d, 4)[0]:08X}" if len(d) == 8 else "SDO abort"
    if request:
        names = {1: "initiate download", 2: "initiate upload", 0: "download segment", 3: "upload segment",
                 5: "block upload", 6: "block download"}
        name = names.get(cs, f"cs {cs}")
        if cs == 1 and d[0] & 0x02:
            n = 4 - ((d[0] >> 2) & 3) if d[0] & 0x01 else 4
            return f"SDO {name}{where} expedited, value {d[4:4 + n].hex(' ')}"
        return f"SDO {name}{where if cs in (1, 2, 5, 6) else ''}"
    names = {2: "upload response", 3: "download response", 0: "upload segment", 1: "download segment ack",
             5: "block download", 6: "block upload"}
    name = names.get(cs, f"cs {cs}")
    if cs == 2 and d[0] & 0x02:
        n = 4 - ((d[0] >> 2) & 3) if d[0] & 0x01 else 4
        return f"SDO {name}{where} expedited, value {d[4:4 + n].hex(' ')}"
    return f"SDO {name}{where if cs in (2, 3) else ''}"


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
        return f"NMT {_NMT_COMMANDS.get(d[0], f'command 0x{d[0]:02X}')} to {target}"
    if cid == 0x080:
        return "SYNC" + (f" (counter {d[0]})" if d else "")
    if 0x081 <= cid <= 0x0FF:
        code = _U16.unpack_from(d, 0)[0] if len(d) >= 2 else 0
        return f"EMCY from node {cid - 0x80}: error code 0x{code:04X}" + (
            f", error register 0x{d[2]:02X}" if len(d) >= 3 else "")
    if cid == 0x100:
        return "TIME stamp"
    for base, name in ((0x180, "TPDO1"), (0x200, "RPDO1"), (0x280, "TPDO2"), (0x300, "RPDO2"),
                       (0x380, "TPDO3"), (0x400, "RPDO3"), (0x480, "TPDO4"), (0x500, "RPDO4")):
        if base < cid <= base + 0x7F:
            direction = "from" if name.startswith("T") else "to"
            return f"{name} {direction} node {cid - base}: {d.hex(' ')}"
    if 0x581 <= cid <= 0x5FF:
        return f"{_sdo(frame, request=False)} from node {cid - 0x580}"
    if 0x601 <= cid <= 0x67F:
        return f"{_sdo(frame, request=True)} to node {cid - 0x600}"
    if 0x701 <= cid <= 0x77F and len(d) == 1:
        state = _NMT_STATES.get(d[0] & 0x7F, f"state 0x{d[0]:02X}")
        return f"{'boot-up' if d[0] == 0 else 'heartbeat'} of node {cid - 0x700}" + (
            "" if d[0] == 0 else f": {state}")
    if cid == 0x7E5 and d:
        return f"LSS master: {_LSS_MASTER.get(d[0], f'command 0x{d[0]:02X}')}"
    if cid == 0x7E4 and d:
        if d[0] == 0x4F:
            return "LSS slave: identify remote slave / Fastscan answer (a slave matches)"
        if d[0] == 0x50:
            return "LSS slave: identify non-configured slave answer"
        if 0x5A <= d[0] <= 0x5E and len(d) >= 5:
            return f"LSS slave: {_LSS_MASTER[d[0]][8:]} = 0x{_U32.unpack_from(d, 1)[0]:X}"
        if d[0] in (0x11, 0x13, 0x17) and len(d) >= 2:
            return f"LSS slave: {_LSS_MASTER[d[0]]} answer, error code {d[1]}"
        if d[0] == 0x44:
            return "LSS slave: switch state selective answer (now in configuration state)"
        return f"LSS slave answer 0x{d[0]:02X}"
    return f"COB-ID 0x{cid:03X}: {d.hex(' ')}"
