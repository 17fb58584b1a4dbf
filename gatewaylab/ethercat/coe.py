"""CANopen over EtherCAT: SDO server with segmented and complete access, SDO Information, EMCY.

The SDO transfer logic (command specifiers, segment codec, segmented state machines) is the
CANopen one from :mod:`gatewaylab.od.sdo`; this module adds the mailbox framing (CoE header,
longer segments, data in the initiate upload response) and the EtherCAT access rules
(:class:`CoeAccess`). Codec constants are shared with the in-process master's client
(``master.py``). Abort replies go out as CoE service 2 (SDO request) with command 0x80, which is
what SOEM decodes as an abort (docs/decisions.md); QEC appendix A.5
lists the codes.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Callable

from gatewaylab.ethercat.errors import FrameFormatError
from gatewaylab.od import Entry, ObjectCode, ObjectDictionary, SdoAbort, SdoAbortCode, check_length, type_size
from gatewaylab.od import sdo as codec
from gatewaylab.od.sdo import ClientCommand, SegmentedDownload, SegmentedUpload

__all__ = [
    "COE_HEADER",
    "EMCY",
    "SDO",
    "SDO_INFO_HEADER",
    "CoeAccess",
    "CoeAccessBits",
    "CoeServer",
    "CoeService",
    "InfoOpcode",
    "abort_message",
    "access_word",
    "coe_header",
    "emergency_message",
]


COE_HEADER = struct.Struct("<H")
SDO = codec.SDO_HEADER_U32  # command, index, subindex, data/size
SDO_INFO_HEADER = struct.Struct("<BBH")  # opcode, reserved, fragments left
EMCY = struct.Struct("<HB5s")

#: EtherCAT AL states as the CoE access rules see them (ETG.1000.6 object access word).
_PREOP, _SAFEOP, _OP = 0x02, 0x04, 0x08


class CoeService(enum.IntEnum):
    """CoE header service numbers (ETG.1000.6)."""

    EMERGENCY = 1
    SDO_REQUEST = 2
    SDO_RESPONSE = 3
    TXPDO = 4
    RXPDO = 5
    SDO_INFO = 8


class InfoOpcode(enum.IntEnum):
    """SDO Information opcodes (ETG.1000.6)."""

    OD_LIST_REQ = 1
    OD_LIST_RESP = 2
    OD_REQ = 3
    OD_RESP = 4
    ED_REQ = 5
    ED_RESP = 6
    ERROR = 7


class CoeAccessBits(enum.IntFlag):
    """ETG.1000.6 object access word of an SDO Information entry description."""

    READ_PREOP = 0x0001
    READ_SAFEOP = 0x0002
    READ_OP = 0x0004
    WRITE_PREOP = 0x0008
    WRITE_SAFEOP = 0x0010
    WRITE_OP = 0x0020
    RXPDO = 0x0040
    TXPDO = 0x0080


def access_word(entry: Entry) -> int:
    """The ETG access word of a dictionary row (readable in every state; preop-only writes in PREOP)."""
    word = 0
    if entry.access.readable:
        word |= CoeAccessBits.READ_PREOP | CoeAccessBits.READ_SAFEOP | CoeAccessBits.READ_OP
    if entry.access.writable:
        word |= CoeAccessBits.WRITE_PREOP if entry.preop_only else (
            CoeAccessBits.WRITE_PREOP | CoeAccessBits.WRITE_SAFEOP | CoeAccessBits.WRITE_OP)
    if entry.rx_pdo:
        word |= CoeAccessBits.RXPDO
    if entry.tx_pdo:
        word |= CoeAccessBits.TXPDO
    return int(word)


class CoeAccess:
    """CoE access rules: preop-only entries are written in PREOP only (0x08000022), lengths must
    match (0x06070012 / 0x06070013), subindex 0 of an array/record not above the last entry."""

    __slots__ = ("od", "state")

    def __init__(self, od: ObjectDictionary, state: Callable[[], int]) -> None:
        self.od = od
        self.state = state

    def check_read(self, entry: Entry) -> None:
        """Write-only entries answer 0x06010001."""
        if not entry.access.readable:
            raise SdoAbort(SdoAbortCode.WRITE_ONLY, f"0x{entry.index:04X}:{entry.subindex}")

    def check_write(self, entry: Entry, data: bytes) -> None:
        """Access right in the present EtherCAT state, then length and subindex 0 rules."""
        if not entry.access.writable:
            raise SdoAbort(SdoAbortCode.READ_ONLY, f"0x{entry.index:04X}:{entry.subindex}")
        if entry.preop_only and self.state() & 0x0F in (_SAFEOP, _OP):
            raise SdoAbort(SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE, "writable in PREOP only")
        size = entry.size
        if size is not None and len(data) != size:
            raise SdoAbort(SdoAbortCode.LENGTH_TOO_HIGH if len(data) > size else SdoAbortCode.LENGTH_TOO_LOW)
        if entry.subindex == 0 and data:
            obj = self.od.objects[entry.index]
            if obj.object_code is not ObjectCode.VAR and data[0] > obj.max_subindex:
                raise SdoAbort(SdoAbortCode.VALUE_TOO_HIGH, "more entries than exist")


def coe_header(service: int, number: int = 0) -> bytes:
    """The 2-byte CoE header."""
    return COE_HEADER.pack((number & 0x1FF) | (service << 12))


def abort_message(index: int, subindex: int, code: int) -> bytes:
    """A CoE SDO abort (service 2, command 0x80)."""
    return coe_header(CoeService.SDO_REQUEST) + codec.abort(index, subindex, code)


def emergency_message(error_code: int, error_register: int, data: bytes = b"") -> bytes:
    """A CoE emergency message."""
    return coe_header(CoeService.EMERGENCY) + EMCY.pack(error_code, error_register, data[:5].ljust(5, b"\0"))


_RESPONSE = coe_header(CoeService.SDO_RESPONSE)


class CoeServer:
    """One slave's SDO server; ``state()`` gives the AL state for the per-state access rights."""

    def __init__(self, od: ObjectDictionary, mailbox_size: int, state: Callable[[], int]) -> None:
        self.od = od
        self.state = state
        self.access = CoeAccess(od, state)
        self.max_first = mailbox_size - 6 - 10  # data in an initiate response
        self.max_segment = mailbox_size - 6 - 3  # data in a segment
        self.max_info = mailbox_size - 6 - 2 - 4  # data in an SDO information fragment
        self._download: SegmentedDownload | None = None
        self._download_complete = False
        self._upload: SegmentedUpload | None = None
        self.aborts_sent = 0

    def handle(self, data: bytes) -> list[bytes]:
        """One CoE mailbox message in, the replies out."""
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
            handler = _SDO_DISPATCH.get(ccs)
            if handler is None:
                raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN)
            return handler(self, cmd, index, sub, word, req)
        except SdoAbort as exc:
            t = self._download or self._upload
            if ccs in (ClientCommand.DOWNLOAD_SEGMENT, ClientCommand.UPLOAD_SEGMENT) and t is not None:
                index, sub = t.index, t.subindex
            self._download = self._upload = None
            self.aborts_sent += 1
            return abort_message(index, sub, exc.code if exc.code is not None else SdoAbortCode.GENERAL_ERROR)

    def cancel(self) -> None:
        """Forget a segmented transfer in progress (it was aborted)."""
        self._download = self._upload = None

    def _abort_request(self, cmd: int, index: int, sub: int, word: int, req: bytes) -> None:
        self._download = self._upload = None

    def _store(self, index: int, sub: int, complete: bool, data: bytes) -> None:
        if complete:
            self.write_complete(index, sub, data)
        else:
            self.od.write(index, sub, data, self.access)

    def _download_initiate(self, cmd: int, index: int, sub: int, word: int, req: bytes) -> bytes:
        complete = bool(cmd & 0x10)
        self._download = self._upload = None
        if complete and sub > 1:
            raise SdoAbort(SdoAbortCode.UNSUPPORTED_ACCESS, "complete access starts at subindex 0 or 1")
        if cmd & 0x02:  # expedited
            n = (cmd >> 2) & 3 if cmd & 0x01 else 0
            self._store(index, sub, complete, bytes(req[4:8 - n]))
        else:
            size = word
            payload = req[8:]
            if len(payload) >= size:
                self._store(index, sub, complete, bytes(payload[:size]))
            else:
                self.od.object(index)  # fail early on an unknown object
                if not complete:
                    entry = self.od.entry(index, sub)
                    if entry.size is None:  # a string longer than it holds: 0x06070012 before its data
                        self.access.check_write(entry, b"")
                        check_length(entry, size)
                self._download = SegmentedDownload(index, sub, size, size, SdoAbortCode.LENGTH_TOO_HIGH,
                                                   buf=bytearray(payload[:size]))
                self._download_complete = complete
        return _RESPONSE + SDO.pack(0x60 | (cmd & 0x10), index, sub, 0)

    def _download_segment(self, cmd: int, index: int, sub: int, word: int, req: bytes) -> bytes:
        t = self._download
        if t is None:
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN, "segment without initiate")
        toggle, last = t.segment(req)
        if last:
            self._download = None
            codec.check_size(len(t.buf), t.size)
            self._store(t.index, t.subindex, self._download_complete, bytes(t.buf))
        return _RESPONSE + SDO.pack(0x20 | (toggle << 4), t.index, t.subindex, 0)

    def _upload_initiate(self, cmd: int, index: int, sub: int, word: int, req: bytes) -> bytes:
        complete = bool(cmd & 0x10)
        self._download = self._upload = None
        if complete:
            if sub > 1:
                raise SdoAbort(SdoAbortCode.UNSUPPORTED_ACCESS, "complete access starts at subindex 0 or 1")
            value = self.read_complete(index, sub)
        else:
            value = self.od.read(index, sub, self.access)
        if len(value) <= 4 and not complete and value:
            return _RESPONSE + codec.expedited_upload_response(index, sub, value)
        first = value[:self.max_first]
        if len(value) > len(first):
            self._upload = SegmentedUpload(index, sub, value[len(first):], self.max_segment)
        return _RESPONSE + SDO.pack(codec.CS_UPLOAD_SEGMENTED_RESPONSE, index, sub, len(value)) + first

    def _upload_segment(self, cmd: int, index: int, sub: int, word: int, req: bytes) -> bytes:
        t = self._upload
        if t is None:
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN, "segment without initiate")
        reply, last = t.segment(cmd)
        if last:
            self._upload = None
        return _RESPONSE + reply

    # -- complete access ----------------------------------------------------------------------
    def read_complete(self, index: int, first_sub: int) -> bytes:
        """Complete access upload: subindex 0 is padded to 16 bits (ETG.1000.6 complete access)."""
        od = self.od
        obj = od.object(index)
        if obj.object_code is ObjectCode.VAR:
            raise SdoAbort(SdoAbortCode.UNSUPPORTED_ACCESS, "complete access to a VAR")
        n = int(od.values[(index, 0)])
        parts: list[bytes] = []
        if first_sub == 0:
            parts.append(od.read(index, 0, self.access) + b"\x00")
        for sub in range(1, n + 1):
            if sub in obj.entries:
                parts.append(od.read(index, sub, self.access))
        return b"".join(parts)

    def write_complete(self, index: int, first_sub: int, data: bytes) -> None:
        """Complete access download: subindex 0 = 0, the entries, then subindex 0 = n."""
        od = self.od
        obj = od.object(index)
        if obj.object_code is ObjectCode.VAR:
            raise SdoAbort(SdoAbortCode.UNSUPPORTED_ACCESS, "complete access to a VAR")
        pos = 0
        n = obj.max_subindex
        if first_sub == 0:
            if len(data) < 2:
                raise SdoAbort(SdoAbortCode.LENGTH_TOO_LOW)
            n = data[0]
            pos = 2
        writes: list[tuple[int, bytes]] = []
        for sub in range(1, n + 1):
            entry = od.entry(index, sub)
            size = type_size(entry.data_type) or len(od.get_bytes(index, sub))
            if pos + size > len(data):
                raise SdoAbort(SdoAbortCode.LENGTH_TOO_LOW)
            writes.append((sub, data[pos:pos + size]))
            pos += size
        if pos != len(data):
            raise SdoAbort(SdoAbortCode.LENGTH_TOO_HIGH)
        if first_sub == 0:
            od.write(index, 0, b"\x00", self.access)
        for sub, raw in writes:
            od.write(index, sub, raw, self.access)
        if first_sub == 0:
            od.write(index, 0, bytes([n]), self.access)

    # -- SDO Information ----------------------------------------------------------------------
    def _info(self, req: bytes) -> list[bytes]:
        """One SDO information request, its answer in as many fragments as the mailbox needs, or
        an SDO information error (ETG.1000.6 5.6.3): every request gets one of the two."""
        opcode = req[0] & 0x7F
        body = req[4:]
        try:
            if opcode == InfoOpcode.OD_LIST_REQ and len(body) >= 2:
                return self._od_list(int.from_bytes(body[:2], "little"))
            if opcode == InfoOpcode.OD_REQ and len(body) >= 2:
                return self._fragments(InfoOpcode.OD_RESP, self._od_desc(int.from_bytes(body[:2], "little")))
            if opcode == InfoOpcode.ED_REQ and len(body) >= 4:
                index = int.from_bytes(body[:2], "little")
                return self._fragments(InfoOpcode.ED_RESP, self._entry_desc(index, body[2], body[3]))
            raise SdoAbort(SdoAbortCode.COMMAND_SPECIFIER_UNKNOWN, "SDO information service")
        except SdoAbort as exc:
            self.aborts_sent += 1
            code = exc.code if exc.code is not None else SdoAbortCode.GENERAL_ERROR
            return [self._info_reply(InfoOpcode.ERROR, code.to_bytes(4, "little"))]

    @staticmethod
    def _info_reply(opcode: int, data: bytes, fragments_left: int = 0, incomplete: bool = False) -> bytes:
        return coe_header(CoeService.SDO_INFO) + SDO_INFO_HEADER.pack(
            opcode | (0x80 if incomplete else 0), 0, fragments_left) + data

    def _fragments(self, opcode: int, payload: bytes, step: int = 0) -> list[bytes]:
        """An SDO information answer cut to the mailbox: every fragment but the last has the
        Incomplete flag, each counts the fragments left (ETG.1000.6 5.6.3.2)."""
        step = step or self.max_info
        chunks = [payload[i:i + step] for i in range(0, len(payload), step)] or [b""]
        if len(chunks) > 0xFFFF:
            raise SdoAbort(SdoAbortCode.OBJECT_TOO_LONG, "more fragments than the header counts")
        return [self._info_reply(opcode, c, len(chunks) - 1 - i, i < len(chunks) - 1)
                for i, c in enumerate(chunks)]

    def _od_list(self, list_type: int) -> list[bytes]:
        objs = list(self.od)

        rx = [o.index for o in objs if any(e.rx_pdo for e in o.entries.values())]
        tx = [o.index for o in objs if any(e.tx_pdo for e in o.entries.values())]
        lists = {1: [o.index for o in objs], 2: rx, 3: tx, 4: [], 5: []}
        if list_type == 0:
            payload = struct.pack("<H5H", 0, *(len(lists[i]) for i in range(1, 6)))
        elif list_type in lists:
            payload = struct.pack("<H", list_type) + b"".join(struct.pack("<H", i) for i in lists[list_type])
        else:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "unknown list type")
        return self._fragments(InfoOpcode.OD_LIST_RESP, payload, self.max_info - self.max_info % 2)

    def _od_desc(self, index: int) -> bytes:
        obj = self.od.object(index)
        if obj.object_code is ObjectCode.VAR:
            dtype = int(obj.entries[0].data_type)
        elif obj.object_code is ObjectCode.ARRAY and 1 in obj.entries:
            dtype = int(obj.entries[1].data_type)
        else:
            dtype = 0x002A  # RECORD: no single data type
        return struct.pack("<HHBB", index, dtype, obj.max_subindex, int(obj.object_code)) + _name(obj.name)

    def _entry_desc(self, index: int, sub: int, value_info: int) -> bytes:
        """Entry description: BitLength is UNSIGNED16 (ETG.1000.6 5.6.3.6), so an object of more than
        65,535 bits (a string of 8,192 bytes or more) cannot be described: SDO information error
        0x06040047 (general internal incompatibility), never a truncated or wrapped length."""
        e = self.od.entry(index, sub)
        bits = self.od.bit_length(index, sub)
        if bits > 0xFFFF:
            raise SdoAbort(SdoAbortCode.GENERAL_INTERNAL_INCOMPATIBILITY,
                           f"0x{index:04X}:{sub:02X}: {bits} bits do not fit the 16-bit BitLength")
        return struct.pack("<HBBHHH", index, sub, 0, int(e.data_type), bits, access_word(e)) + _name(e.name)


def _name(text: str) -> bytes:
    """A name as SDO information carries it (VISIBLE_STRING: one byte per character)."""
    return text.encode("latin-1", "replace")


_SdoHandler = Callable[[CoeServer, int, int, int, int, bytes], "bytes | None"]
#: Client command specifier -> handler (CiA 301 7.2.4.3; CoE has no block transfers).
_SDO_DISPATCH: dict[int, _SdoHandler] = {
    ClientCommand.INITIATE_DOWNLOAD: CoeServer._download_initiate,
    ClientCommand.DOWNLOAD_SEGMENT: CoeServer._download_segment,
    ClientCommand.INITIATE_UPLOAD: CoeServer._upload_initiate,
    ClientCommand.UPLOAD_SEGMENT: CoeServer._upload_segment,
    ClientCommand.ABORT: CoeServer._abort_request,
}
