"""CANopen over EtherCAT: SDO server with segmented and complete access, SDO Information, EMCY.

Codec constants are shared with the in-process master's client (``master.py``). Abort replies go
out as CoE service 2 (SDO request) with command 0x80, which is what SOEM decodes as an abort
(see shared notes 'soem-interop', pitfall 1); QEC appendix A.5 lists the codes.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Callable
from dataclasses import dataclass

from .errors import FrameFormatError, SdoAbortCode, SdoAbortError
from .od import Access, ObjectCode, ObjectDictionary

COE_HEADER = struct.Struct("<H")
SDO = struct.Struct("<BHBI")  # command, index, subindex, data/size
SDO_INFO_HEADER = struct.Struct("<BBH")  # opcode, reserved, fragments left
EMCY = struct.Struct("<HB5s")


class CoeService(enum.IntEnum):
    EMERGENCY = 1
    SDO_REQUEST = 2
    SDO_RESPONSE = 3
    TXPDO = 4
    RXPDO = 5
    SDO_INFO = 8


class InfoOpcode(enum.IntEnum):
    OD_LIST_REQ = 1
    OD_LIST_RESP = 2
    OD_REQ = 3
    OD_RESP = 4
    ED_REQ = 5
    ED_RESP = 6
    ERROR = 7


def coe_header(service: int, number: int = 0) -> bytes:
    return COE_HEADER.pack((number & 0x1FF) | (service << 12))


def abort_message(index: int, subindex: int, code: int) -> bytes:
    return coe_header(CoeService.SDO_REQUEST) + SDO.pack(0x80, index, subindex, code)


def emergency_message(error_code: int, error_register: int, data: bytes = b"") -> bytes:
    return coe_header(CoeService.EMERGENCY) + EMCY.pack(error_code, error_register, data[:5].ljust(5, b"\0"))


@dataclass(slots=True)
class _Transfer:
    index: int
    subindex: int
    complete: bool
    toggle: int
    data: bytearray
    size: int


class CoeServer:
    """One slave's SDO server; ``state()`` gives the AL state for the per-state access rights."""

    def __init__(self, od: ObjectDictionary, mailbox_size: int, state: Callable[[], int]) -> None:
        self.od = od
        self.state = state
        self.max_first = mailbox_size - 6 - 10  # data in an initiate response
        self.max_segment = mailbox_size - 6 - 3  # data in a segment
        self.max_info = mailbox_size - 6 - 2 - 4  # data in an SDO information fragment
        self._download: _Transfer | None = None
        self._upload: _Transfer | None = None
        self.aborts_sent = 0

    def handle(self, data: bytes) -> list[bytes]:
        if len(data) < 2:
            raise FrameFormatError("CoE header missing")
        service = COE_HEADER.unpack_from(data, 0)[0] >> 12
        if service == CoeService.SDO_REQUEST:
            if len(data) < 2 + SDO.size:
                raise FrameFormatError("SDO request shorter than 8 bytes")
            reply = self._sdo(data[2:])
            return [reply] if reply is not None else []
        if service == CoeService.SDO_INFO:
            if len(data) < 6:
                raise FrameFormatError("SDO information header missing")
            return self._info(data[2:])
        raise FrameFormatError(f"CoE service {service} not served")

    # -- SDO ----------------------------------------------------------------------------------
    def _sdo(self, req: bytes) -> bytes | None:
        cmd, index, sub, word = SDO.unpack_from(req, 0)
        ccs = cmd >> 5
        try:
            if ccs == 1:
                return self._download_initiate(cmd, index, sub, word, req)
            if ccs == 0:
                return self._download_segment(cmd, req)
            if ccs == 2:
                return self._upload_initiate(cmd, index, sub)
            if ccs == 3:
                return self._upload_segment(cmd)
            if ccs == 4:
                self._download = self._upload = None
                return None
            raise SdoAbortError("unknown command specifier", SdoAbortCode.COMMAND_SPECIFIER)
        except SdoAbortError as exc:
            t = self._download or self._upload
            if ccs in (0, 3) and t is not None:
                index, sub = t.index, t.subindex
            self._download = self._upload = None
            self.aborts_sent += 1
            return abort_message(index, sub, exc.code if exc.code is not None else SdoAbortCode.GENERAL)

    def _store(self, t: _Transfer) -> None:
        state = self.state()
        if t.complete:
            self.od.write_complete(t.index, t.subindex, bytes(t.data), state)
        else:
            self.od.write(t.index, t.subindex, bytes(t.data), state)

    def _download_initiate(self, cmd: int, index: int, sub: int, word: int, req: bytes) -> bytes:
        complete = bool(cmd & 0x10)
        self._download = self._upload = None
        if complete and sub > 1:
            raise SdoAbortError("complete access starts at sub 0 or 1", SdoAbortCode.UNSUPPORTED_ACCESS)
        if cmd & 0x02:  # expedited
            n = (cmd >> 2) & 3 if cmd & 0x01 else 0
            self._store(_Transfer(index, sub, complete, 0, bytearray(req[4:8 - n]), 4 - n))
        else:
            size = word
            payload = req[8:]
            t = _Transfer(index, sub, complete, 0, bytearray(payload[:size]), size)
            if len(payload) >= size:
                self._store(t)
            else:
                self.od.object(index)  # fail early on an unknown object
                self._download = t
        return coe_header(CoeService.SDO_RESPONSE) + SDO.pack(0x60 | (cmd & 0x10), index, sub, 0)

    def _download_segment(self, cmd: int, req: bytes) -> bytes:
        t = self._download
        if t is None:
            raise SdoAbortError("segment without initiate", SdoAbortCode.COMMAND_SPECIFIER)
        toggle = cmd & 0x10
        if toggle != t.toggle:
            raise SdoAbortError("toggle bit", SdoAbortCode.TOGGLE_BIT)
        seg = req[1:]
        if len(req) <= 8:
            seg = req[1:8 - ((cmd >> 1) & 7)]
        t.data.extend(seg)
        t.toggle ^= 0x10
        if len(t.data) > t.size:
            raise SdoAbortError("more data than announced", SdoAbortCode.LENGTH_TOO_HIGH)
        if cmd & 0x01:
            self._download = None
            if len(t.data) != t.size:
                raise SdoAbortError("less data than announced", SdoAbortCode.LENGTH_TOO_LOW)
            self._store(t)
        return coe_header(CoeService.SDO_RESPONSE) + SDO.pack(0x20 | toggle, t.index, t.subindex, 0)

    def _upload_initiate(self, cmd: int, index: int, sub: int) -> bytes:
        complete = bool(cmd & 0x10)
        self._download = self._upload = None
        state = self.state()
        if complete:
            if sub > 1:
                raise SdoAbortError("complete access starts at sub 0 or 1", SdoAbortCode.UNSUPPORTED_ACCESS)
            value = self.od.read_complete(index, sub, state)
        else:
            value = self.od.read(index, sub, state)
        if len(value) <= 4 and not complete and value:
            n = 4 - len(value)
            return coe_header(CoeService.SDO_RESPONSE) + SDO.pack(
                0x43 | (n << 2), index, sub, int.from_bytes(value.ljust(4, b"\0"), "little"))
        first = value[:self.max_first]
        if len(value) > len(first):
            self._upload = _Transfer(index, sub, complete, 0, bytearray(value[len(first):]), len(value))
        return coe_header(CoeService.SDO_RESPONSE) + SDO.pack(0x41, index, sub, len(value)) + first

    def _upload_segment(self, cmd: int) -> bytes:
        t = self._upload
        if t is None:
            raise SdoAbortError("segment without initiate", SdoAbortCode.COMMAND_SPECIFIER)
        toggle = cmd & 0x10
        if toggle != t.toggle:
            raise SdoAbortError("toggle bit", SdoAbortCode.TOGGLE_BIT)
        chunk = bytes(t.data[:self.max_segment])
        del t.data[:len(chunk)]
        t.toggle ^= 0x10
        last = 0 if t.data else 1
        if last:
            self._upload = None
        n = 7 - len(chunk) if len(chunk) < 7 else 0
        return coe_header(CoeService.SDO_RESPONSE) + bytes([toggle | (n << 1) | last]) + chunk.ljust(7, b"\0")

    # -- SDO Information ----------------------------------------------------------------------
    def _info(self, req: bytes) -> list[bytes]:
        opcode = req[0] & 0x7F
        body = req[4:]
        try:
            if opcode == InfoOpcode.OD_LIST_REQ and len(body) >= 2:
                return self._od_list(int.from_bytes(body[:2], "little"))
            if opcode == InfoOpcode.OD_REQ and len(body) >= 2:
                return [self._info_reply(InfoOpcode.OD_RESP, self._od_desc(int.from_bytes(body[:2], "little")))]
            if opcode == InfoOpcode.ED_REQ and len(body) >= 4:
                index = int.from_bytes(body[:2], "little")
                return [self._info_reply(InfoOpcode.ED_RESP, self._entry_desc(index, body[2], body[3]))]
            raise SdoAbortError("SDO information service", SdoAbortCode.COMMAND_SPECIFIER)
        except SdoAbortError as exc:
            self.aborts_sent += 1
            code = exc.code if exc.code is not None else SdoAbortCode.GENERAL
            return [self._info_reply(InfoOpcode.ERROR, code.to_bytes(4, "little"))]

    @staticmethod
    def _info_reply(opcode: int, data: bytes, fragments_left: int = 0, incomplete: bool = False) -> bytes:
        return coe_header(CoeService.SDO_INFO) + SDO_INFO_HEADER.pack(
            opcode | (0x80 if incomplete else 0), 0, fragments_left) + data

    def _od_list(self, list_type: int) -> list[bytes]:
        objs = list(self.od)

        def mappable(flag: Access) -> list[int]:
            return [o.index for o in objs if any(e.access & flag for e in o.entries.values())]

        lists = {1: [o.index for o in objs], 2: mappable(Access.RXPDO), 3: mappable(Access.TXPDO), 4: [], 5: []}
        if list_type == 0:
            payload = struct.pack("<H5H", 0, *(len(lists[i]) for i in range(1, 6)))
        elif list_type in lists:
            payload = struct.pack("<H", list_type) + b"".join(struct.pack("<H", i) for i in lists[list_type])
        else:
            raise SdoAbortError("unknown list type", SdoAbortCode.VALUE_RANGE)
        step = self.max_info - self.max_info % 2
        chunks = [payload[i:i + step] for i in range(0, len(payload), step)] or [b""]
        return [self._info_reply(InfoOpcode.OD_LIST_RESP, c, len(chunks) - 1 - i, i < len(chunks) - 1)
                for i, c in enumerate(chunks)]

    def _od_desc(self, index: int) -> bytes:
        obj = self.od.object(index)
        if obj.code == ObjectCode.VAR:
            dtype = int(obj.entries[0].data_type)
        elif obj.code == ObjectCode.ARRAY and 1 in obj.entries:
            dtype = int(obj.entries[1].data_type)
        else:
            dtype = 0x002A  # RECORD: no single data type
        return struct.pack("<HHBB", index, dtype, obj.max_subindex, int(obj.code)) + obj.name.encode("latin-1")

    def _entry_desc(self, index: int, sub: int, value_info: int) -> bytes:
        e = self.od.entry(index, sub)
        return struct.pack("<HBBHHH", index, sub, 0, int(e.data_type), e.bits, int(e.access) & 0xFFFF) + \
            e.name.encode("latin-1")
