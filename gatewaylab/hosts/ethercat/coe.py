"""CoE of the in-process master (SOEM's ethercatcoe): SDO upload/download, SDO information, emergencies.

Everything goes through the mailbox (:class:`~gatewaylab.hosts.ethercat.mailbox.Mailboxes`); the
SDO segment state machines are the shared client codec of :mod:`gatewaylab.od.sdo`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from gatewaylab.ethercat.coe import SDO, CoeService, InfoOpcode, coe_header
from gatewaylab.ethercat.errors import FrameFormatError, SdoAbort
from gatewaylab.ethercat.mailbox import MailboxMessage, MailboxType
from gatewaylab.hosts.ethercat.base import U8, U16, U32, U64
from gatewaylab.hosts.ethercat.config import Configuration
from gatewaylab.hosts.ethercat.mailbox import Mailboxes
from gatewaylab.od import sdo as sdo_codec


@dataclass(frozen=True, slots=True)
class ObjectDescription:
    """One SDO information OD description: lets a master browse a dictionary it has no ESI for."""

    index: int
    data_type: int
    max_subindex: int
    object_code: int
    name: str


@dataclass(frozen=True, slots=True)
class EntryDescription:
    """One SDO information entry description: type, bit length and access of a subindex."""

    index: int
    subindex: int
    data_type: int
    bit_length: int
    access: int
    name: str


def _is_sdo(m: MailboxMessage) -> bool:
    """A CoE SDO request/response (not an emergency or SDO information reply)."""
    return len(m.data) >= 2 and (m.data[1] >> 4) in (CoeService.SDO_REQUEST, CoeService.SDO_RESPONSE)


def _is_info(m: MailboxMessage) -> bool:
    """A CoE SDO information reply."""
    return len(m.data) >= 6 and (m.data[1] >> 4) == CoeService.SDO_INFO


def _is_emergency(m: MailboxMessage) -> bool:
    """A CoE emergency (ETG.1000.6)."""
    return m.type == MailboxType.COE and len(m.data) >= 10 and m.data[1] >> 4 == CoeService.EMERGENCY


class Coe:
    """The CoE client of one master: SDO transfers, dictionary browsing and emergencies by slave position."""

    def __init__(self, mailbox: Mailboxes, config: Configuration) -> None:
        self.mailbox = mailbox
        self.config = config

    # ------------------------------------------------------------------ SDO
    def _sdo(self, position: int, req: bytes) -> bytes:
        """One SDO request and its response body, raising SdoAbort on an abort."""
        msg = self.mailbox.exchange(position, MailboxType.COE, coe_header(CoeService.SDO_REQUEST) + req, _is_sdo)
        body = msg.data[2:]
        if len(body) < SDO.size:
            raise FrameFormatError("SDO response too short")
        cmd, index, sub, word = SDO.unpack_from(body, 0)
        if cmd == 0x80:
            raise SdoAbort(word, f"SDO 0x{index:04X}:{sub} aborted")
        return body

    def sdo_upload(self, position: int, index: int, subindex: int = 0, complete: bool = False) -> bytes:
        """Read an object by CoE SDO (expedited, normal or segmented, as the slave answers)."""
        ca = 0x10 if complete else 0
        body = self._sdo(position, SDO.pack(sdo_codec.CS_UPLOAD_REQUEST | ca, index, subindex, 0))
        cmd, _i, _s, word = SDO.unpack_from(body, 0)
        if cmd & 0x02:                                  # expedited: the data is in the initiate
            return body[4:4 + (sdo_codec.expedited_size(cmd) or 4)]
        up = sdo_codec.ClientSegmentedUpload(word, bytearray(body[8:8 + word]))
        while not up.done:
            up.response(self._sdo(position, up.request()))
        return up.data[:word]

    def sdo_download(self, position: int, index: int, subindex: int, data: bytes,
                     complete: bool = False) -> None:
        """Write an object by CoE SDO: expedited up to 4 bytes, else normal, segmented when it does not fit."""
        ca = 0x10 if complete else 0
        if len(data) <= 4:
            request = sdo_codec.expedited_download_request(index, subindex, data)
            self._sdo(position, bytes((request[0] | ca,)) + request[1:])
            return
        s = self.config.slave(position)
        max_first = s.mailbox_out[1] - 16
        first = data[:max_first]
        self._sdo(position, SDO.pack(0x21 | ca, index, subindex, len(data)) + first)
        down = sdo_codec.ClientSegmentedDownload(data[len(first):], s.mailbox_out[1] - 9)
        while not down.done:
            down.response(self._sdo(position, down.next_segment()))

    def typed_upload(self, position: int, index: int, sub: int, st: struct.Struct) -> int:
        """Read an object as an unsigned int of the struct's size, raising FrameFormatError on another size."""
        raw = self.sdo_upload(position, index, sub)
        if len(raw) != st.size:
            raise FrameFormatError(f"0x{index:04X}:{sub} has {len(raw)} bytes, not {st.size}")
        return int(st.unpack(raw)[0])

    def sdo_upload8(self, position: int, index: int, sub: int = 0) -> int:
        """Read an 8-bit object as an int (QEC sdo_upload8), checking its size."""
        return self.typed_upload(position, index, sub, U8)

    def sdo_upload16(self, position: int, index: int, sub: int = 0) -> int:
        """Read a 16-bit object as an int (QEC sdo_upload16), checking its size."""
        return self.typed_upload(position, index, sub, U16)

    def sdo_upload32(self, position: int, index: int, sub: int = 0) -> int:
        """Read a 32-bit object as an int (QEC sdo_upload32), checking its size."""
        return self.typed_upload(position, index, sub, U32)

    def sdo_upload64(self, position: int, index: int, sub: int = 0) -> int:
        """Read a 64-bit object as an int, checking its size."""
        return self.typed_upload(position, index, sub, U64)

    # ------------------------------------------------------------------ SDO information, emergency
    def _info(self, position: int, opcode: int, data: bytes) -> list[bytes]:
        """The fragments of one SDO information reply, raising SdoAbort on its error opcode."""
        frags: list[bytes] = []
        msg = self.mailbox.exchange(position, MailboxType.COE,
                                    coe_header(CoeService.SDO_INFO) + bytes([opcode, 0, 0, 0]) + data, _is_info)
        while True:
            op, frags_left = msg.data[2] & 0x7F, U16.unpack_from(msg.data, 4)[0]
            if op == InfoOpcode.ERROR:
                raise SdoAbort(U32.unpack_from(msg.data, 6)[0], "SDO information error")
            frags.append(msg.data[6:])
            if not frags_left:
                return frags
            msg = self.mailbox.receive(position, _is_info)

    def od_list(self, position: int, list_type: int = 1) -> list[int]:
        """The indexes of a slave's dictionary by SDO information (list type 1: all), to browse it without an ESI."""
        data = b"".join(self._info(position, InfoOpcode.OD_LIST_REQ, U16.pack(list_type)))
        return [U16.unpack_from(data, i)[0] for i in range(2, len(data) - 1, 2)]

    def object_description(self, position: int, index: int) -> ObjectDescription:
        """Name, type and size of one object by SDO information, to browse a dictionary without an ESI."""
        data = b"".join(self._info(position, InfoOpcode.OD_REQ, U16.pack(index)))
        idx, dtype, max_sub, code = struct.unpack_from("<HHBB", data, 0)
        return ObjectDescription(idx, dtype, max_sub, code, data[6:].decode("latin-1"))

    def entry_description(self, position: int, index: int, subindex: int) -> EntryDescription:
        """Type, bit length, access and name of one subindex by SDO information."""
        data = b"".join(self._info(position, InfoOpcode.ED_REQ, struct.pack("<HBB", index, subindex, 0)))
        idx, sub, _vi, dtype, bits, access = struct.unpack_from("<HBBHHH", data, 0)
        return EntryDescription(idx, sub, dtype, bits, access, data[10:].decode("latin-1"))

    def receive_emergency(self, position: int) -> tuple[int, int, bytes]:
        """The next CoE emergency (ETG.1000.6) the slave sent: (error code, error register, 5 data
        bytes); other mailbox messages read meanwhile are dropped. TimeoutError_ without one."""
        data = self.mailbox.receive(position, _is_emergency).data
        code, register = struct.unpack_from("<HB", data, 2)
        return code, register, bytes(data[5:10])
