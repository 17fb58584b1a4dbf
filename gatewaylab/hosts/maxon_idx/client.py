"""A host-side client for the maxon USB command protocol, as a maxon user would expect it.

``IdxClient`` speaks the IDX guide's commands (chapter 2) over any :class:`~.link.Link`:
read/write objects of any node (the IDX forwards other nodes to CAN, chapter 5), typed helpers,
segmented transfers of any size, NMT, and LSS (CiA 305 through SendLSS/ReadLSS, including fastscan).
Every failure raises :class:`IdxError` carrying the error code and its table 6-20 name.
"""

from __future__ import annotations

import struct
import time
from typing import Any

from gatewaylab.canopen.lss import Cs, LssAddress
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.common.errors import GatewaylabError, LocalError, RemoteError
from gatewaylab.devices.maxon_idx import commands as cmd
from gatewaylab.devices.maxon_idx.codec import DecoderEvent, FrameDecoder, FrameReceived, encode_frame
from gatewaylab.devices.maxon_idx.errors import SdoAbortCode, error_cause, error_name
from gatewaylab.hosts.maxon_idx.link import Link, open_link

__all__ = [
    "LSS_CONFIGURE_NODE_ID",
    "LSS_FASTSCAN",
    "LSS_IDENTIFY_NON_CONFIGURED",
    "LSS_IDENTIFY_REMOTE",
    "LSS_IDENTIFY_RESPONSE",
    "LSS_INQUIRE",
    "LSS_NON_CONFIGURED_RESPONSE",
    "LSS_STORE",
    "LSS_SWITCH_GLOBAL",
    "LSS_SWITCH_SELECTIVE",
    "LSS_SWITCH_SELECTIVE_RESPONSE",
    "IdxClient",
    "IdxError",
    "IdxTimeout",
    "IdxValueError",
]


_TYPES: dict[str, struct.Struct] = {
    "u8": struct.Struct("<B"), "u16": struct.Struct("<H"), "u32": struct.Struct("<I"),
    "i8": struct.Struct("<b"), "i16": struct.Struct("<h"), "i32": struct.Struct("<i"),
}

# CiA 305 LSS command specifiers (IDX guide 3.5.2 and CiA 305 fastscan), named as the client uses them.
LSS_SWITCH_GLOBAL = Cs.SWITCH_STATE_GLOBAL
LSS_CONFIGURE_NODE_ID = Cs.CONFIGURE_NODE_ID
LSS_STORE = Cs.STORE_CONFIGURATION
LSS_SWITCH_SELECTIVE = (Cs.SWITCH_SELECTIVE_VENDOR, Cs.SWITCH_SELECTIVE_PRODUCT, Cs.SWITCH_SELECTIVE_REVISION,
                        Cs.SWITCH_SELECTIVE_SERIAL)
LSS_SWITCH_SELECTIVE_RESPONSE = Cs.SWITCH_SELECTIVE_RESPONSE
LSS_IDENTIFY_REMOTE = Cs.IDENTIFY_VENDOR
LSS_IDENTIFY_NON_CONFIGURED = Cs.IDENTIFY_NON_CONFIGURED
LSS_IDENTIFY_RESPONSE = Cs.IDENTIFY_SLAVE
LSS_NON_CONFIGURED_RESPONSE = Cs.IDENTIFY_NON_CONFIGURED_SLAVE
LSS_FASTSCAN = Cs.FASTSCAN
LSS_INQUIRE = {"vendor": Cs.INQUIRE_VENDOR, "product": Cs.INQUIRE_PRODUCT, "revision": Cs.INQUIRE_REVISION,
               "serial": Cs.INQUIRE_SERIAL, "node_id": Cs.INQUIRE_NODE_ID}


class IdxError(RemoteError):
    """The IDX answered with a non-zero error code (or did not answer at all).

    ``code`` is the error DWORD, ``name`` and ``cause`` its table 6-20 Name and Cause columns,
    ``request`` what was asked (e.g. "read node 2 0x6041:00").
    """

    def __init__(self, code: int, request: str = "", detail: str = "") -> None:
        self.code: int = code
        self.name = error_name(code)
        self.cause = error_cause(code)
        self.request = request
        text = f'0x{code:08X} "{self.name}"' + (f" ({self.cause})" if self.cause else "")
        if detail:
            text = f"{detail}; {text}"
        super().__init__(f"{request}: {text}" if request else text, code)


class IdxValueError(LocalError, ValueError):
    """A value that does not fit where the caller put it: a typed read narrower than the object's
    value, or more than 4 bytes for WriteObject (a ValueError too, for callers that catch that)."""


class IdxTimeout(IdxError):
    """No reply frame within the client's timeout (reported as the SDO timeout code): the port
    is not an IDX, or the IDX is busy with someone else's request."""

    def __init__(self, request: str = "", timeout: float | None = None, detail: str = "") -> None:
        within = f" within {timeout:g} s" if timeout is not None else ""
        super().__init__(SdoAbortCode.SDO_PROTOCOL_TIMED_OUT, request, detail or f"no reply frame from the IDX{within}")


class IdxClient:
    """One host's connection to one IDX; ``node_id`` 0 addresses the IDX itself.

    ``timeout`` bounds each reply; keep it above the IDX's gateway SDO timeout (0.5 s) or a
    silent node shows up as a client timeout. The protocol has no sequence numbers, so after a
    client timeout the IDX may still answer the abandoned request: the next request first waits
    up to ``late_reply_wait`` seconds for that late reply and drops it, so that it is never taken
    for the next request's answer (guide 2.2.8 D: wait for "the receive frame or a timeout").
    """

    def __init__(self, link: Link | str, timeout: float = 1.0, late_reply_wait: float = 1.0) -> None:
        self.link: Link = open_link(link) if isinstance(link, str) else link
        self.timeout = timeout
        self.late_reply_wait = late_reply_wait
        self.late_replies_dropped = 0
        self._frames: list[Any] = []
        self._stale = False
        self._decoder = FrameDecoder(RealTimeClock(), self._on_event, timeout=None)

    def __enter__(self) -> IdxClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the link (leaving the ``with`` block does the same)."""
        self.link.close()

    def _on_event(self, event: DecoderEvent) -> None:
        if isinstance(event, FrameReceived):
            self._frames.append(event.frame)

    # -- one transaction ------------------------------------------------------------------------------
    def transact(self, request: cmd.Request, timeout: float | None = None, what: str = "") -> cmd.Reply:
        """Send ``request``, wait for its reply frame (guide 2.2.8 D: one request at a time)."""
        if self._stale:                  # an earlier request timed out: its reply may still come
            self._drop_late_reply()
        self._frames.clear()
        self._decoder.reset()
        self.link.write(encode_frame(request.to_frame()))
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while not self._frames:
            left = deadline - time.monotonic()
            if left <= 0:
                self._stale = True
                waited = self.timeout if timeout is None else timeout
                raise IdxTimeout(what or type(request).__name__, detail=(
                    f"no reply frame from the IDX to {type(request).__name__} within {waited:g} s"))
            self._decoder.feed(self.link.read(512, left))
        try:
            return cmd.decode_reply(request.opcode, self._frames[0])
        except GatewaylabError as exc:
            raise IdxError(exc.code or SdoAbortCode.GENERAL_ERROR, type(request).__name__) from exc

    def _drop_late_reply(self) -> None:
        """Wait up to ``late_reply_wait`` for the reply owed to a timed-out request and drop it."""
        self._stale = False
        self._frames.clear()
        self._decoder.reset()
        deadline = time.monotonic() + self.late_reply_wait
        while not self._frames:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            self._decoder.feed(self.link.read(512, left))
        self.late_replies_dropped += len(self._frames)
        self.link.reset_input()

    def _ok(self, request: cmd.Request, what: str, timeout: float | None = None) -> Any:
        reply = self.transact(request, timeout, what)
        if reply.error:
            raise IdxError(reply.error, what)
        return reply

    # -- objects ------------------------------------------------------------------------------------
    def read_object(self, node_id: int, index: int, subindex: int) -> bytes:
        """ReadObject (2.1.1.1): the 4 data bytes (objects shorter than 4 bytes are zero-padded)."""
        reply: cmd.ReadObjectReply = self._ok(cmd.ReadObject(node_id, index, subindex),
                                          f"read node {node_id} 0x{index:04X}:{subindex:02X}")
        return reply.data

    def write_object(self, node_id: int, index: int, subindex: int, data: bytes) -> None:
        """WriteObject (2.1.2.1) of up to 4 bytes."""
        if len(data) > 4:
            raise IdxValueError("WriteObject carries at most 4 bytes; use write_segmented")
        self._ok(cmd.WriteObject(node_id, index, subindex, data.ljust(4, b"\x00")),
                 f"write node {node_id} 0x{index:04X}:{subindex:02X}")

    def read(self, node_id: int, index: int, subindex: int, type_: str = "u32") -> int:
        """Typed read: ``type_`` is one of u8 u16 u32 i8 i16 i32.

        ReadObject always carries 4 bytes, shorter objects zero-padded (2.1.1.1); bytes beyond the
        type's width that are neither that padding nor the sign extension of a negative value
        mean the object does not fit ``type_``: :class:`IdxValueError`, never a silent truncation.
        """
        s = _TYPES[type_]
        data = self.read_object(node_id, index, subindex)
        value = int(s.unpack_from(data)[0])
        rest = data[s.size:]
        if any(rest) and not (value < 0 and rest == b"\xff" * len(rest)):
            whole = int.from_bytes(data, "little")
            raise IdxValueError(f"read node {node_id} 0x{index:04X}:{subindex:02X}: the value 0x{whole:08X} "
                                f"does not fit {type_}; read it as u32 or i32")
        return value

    def write(self, node_id: int, index: int, subindex: int, value: int, type_: str = "u32") -> None:
        """Typed write: pack ``value`` as ``type_`` (u8 u16 u32 i8 i16 i32) and send it by WriteObject (2.1.2.1)."""
        self.write_object(node_id, index, subindex, _TYPES[type_].pack(value))

    def read_segmented(self, node_id: int, index: int, subindex: int) -> bytes:
        """InitiateSegmentedRead + SegmentRead (2.1.1.2/2.1.1.3) until the last-segment bit."""
        what = f"segmented read node {node_id} 0x{index:04X}:{subindex:02X}"
        first: cmd.InitiateSegmentedReadReply = self._ok(cmd.InitiateSegmentedRead(node_id, index, subindex), what)
        data = bytearray(first.data)
        toggle = False
        while len(data) < first.total_length:
            seg: cmd.SegmentReadReply = self._ok(cmd.SegmentRead(toggle), what)
            if seg.toggle != toggle:
                raise IdxError(SdoAbortCode.TOGGLE_BIT_NOT_ALTERNATED, what, "the reply's toggle bit did not alternate")
            data += seg.data
            toggle = not toggle
            if seg.last:
                break
            if not seg.data:        # would loop for ever on a device that sends nothing more
                raise IdxError(SdoAbortCode.GENERAL_ERROR, what, "empty segment without the last-segment bit")
        if len(data) != first.total_length:
            raise IdxError(SdoAbortCode.LENGTH_MISMATCH, what,
                           f"{len(data)} bytes received, {first.total_length} announced")
        return bytes(data)

    def read_string(self, node_id: int, index: int, subindex: int) -> str:
        """A string object (e.g. 0x1008 device name) by segmented read, trailing NULs stripped, decoded as Latin-1."""
        return self.read_segmented(node_id, index, subindex).rstrip(b"\x00").decode("latin-1")

    def write_segmented(self, node_id: int, index: int, subindex: int, data: bytes,
                        segment: int = cmd.MAX_SEGMENT) -> None:
        """InitiateSegmentedWrite + SegmentWrite (2.1.2.2/2.1.2.3); the IDX's own objects only."""
        what = f"segmented write node {node_id} 0x{index:04X}:{subindex:02X}"
        self._ok(cmd.InitiateSegmentedWrite(node_id, index, subindex, len(data)), what)
        toggle = False
        offset = 0
        while True:
            chunk = data[offset:offset + segment]
            offset += len(chunk)
            last = offset >= len(data)
            reply: cmd.SegmentWriteReply = self._ok(cmd.SegmentWrite(toggle, last, chunk), what)
            if reply.length_written != len(chunk):
                raise IdxError(SdoAbortCode.LENGTH_MISMATCH, what)
            toggle = not toggle
            if last:
                return

    # -- NMT ----------------------------------------------------------------------------------------
    def nmt(self, node_id: int, command: cmd.NmtCommand | int) -> None:
        """SendNMTService (2.1.2.4); node 0 addresses every node."""
        self._ok(cmd.SendNmtService(node_id, int(command)), f"NMT {int(command)} to node {node_id}")

    # -- LSS ----------------------------------------------------------------------------------------
    def send_lss(self, data: bytes) -> None:
        """SendLSS (2.1.3.1): put an LSS master message, padded to 8 bytes, on the bus; answers come by ReadLSS."""
        self._ok(cmd.SendLss(data.ljust(8, b"\x00")), "SendLSS")

    def read_lss(self, timeout_ms: int = 50) -> bytes | None:
        """ReadLSS (2.1.3.2): the next LSS slave message, or None when none came in time."""
        reply = self.transact(cmd.ReadLss(timeout_ms), self.timeout + timeout_ms / 1000)
        assert isinstance(reply, cmd.ReadLssReply)
        if reply.error == SdoAbortCode.SDO_PROTOCOL_TIMED_OUT:
            return None
        if reply.error:
            raise IdxError(reply.error, "ReadLSS")
        return reply.data

    def lss_request(self, data: bytes, timeout_ms: int = 50, expect: int | None = None) -> bytes | None:
        """SendLSS then ReadLSS: the slave's answer (with command specifier ``expect``) or None."""
        self.send_lss(data)
        while True:
            answer = self.read_lss(timeout_ms)
            if answer is None or expect is None or answer[0] == expect:
                return answer

    def switch_state_global(self, configuration: bool) -> None:
        """3.5.2.1: all slaves to LSS configuration (True) or waiting (False); no answer."""
        self.send_lss(bytes([LSS_SWITCH_GLOBAL, 1 if configuration else 0]))

    def switch_state_selective(self, address: LssAddress, timeout_ms: int = 50) -> bool:
        """3.5.2.2: the slave with this LSS address enters configuration state (answers 0x44)."""
        for cs, value in zip(LSS_SWITCH_SELECTIVE, (address.part(sub) for sub in range(4))):
            if cs != LSS_SWITCH_SELECTIVE[-1]:
                self.send_lss(bytes([cs]) + value.to_bytes(4, "little"))
        cs, value = LSS_SWITCH_SELECTIVE[-1], address.serial
        return self.lss_request(bytes([cs]) + value.to_bytes(4, "little"), timeout_ms,
                                LSS_SWITCH_SELECTIVE_RESPONSE) is not None

    def configure_node_id(self, node_id: int, timeout_ms: int = 50) -> None:
        """3.5.2.3: error code 0 = success, 1 = node id out of range."""
        answer = self.lss_request(bytes([LSS_CONFIGURE_NODE_ID, node_id]), timeout_ms, LSS_CONFIGURE_NODE_ID)
        if answer is None:
            raise IdxTimeout("LSS configure node id", detail="no LSS slave answered")
        if answer[1]:
            raise IdxError(SdoAbortCode.VALUE_RANGE_EXCEEDED, f"LSS configure node id {node_id}: error {answer[1]}")

    def store_configuration(self, timeout_ms: int = 50) -> None:
        """3.5.2.6: error 0 ok, 1 not supported, 2 storage media access error."""
        answer = self.lss_request(bytes([LSS_STORE]), timeout_ms, LSS_STORE)
        if answer is None:
            raise IdxTimeout("LSS store configuration", detail="no LSS slave answered")
        if answer[1]:
            raise IdxError(SdoAbortCode.DATA_CANNOT_BE_STORED, f"LSS store configuration: error {answer[1]}")

    def inquire(self, what: str, timeout_ms: int = 50) -> int | None:
        """3.5.2.7-3.5.2.11: vendor, product, revision, serial or node_id of the slave in configuration."""
        cs = LSS_INQUIRE[what]
        answer = self.lss_request(bytes([cs]), timeout_ms, cs)
        if answer is None:
            return None
        return answer[1] if what == "node_id" else int.from_bytes(answer[1:5], "little")

    def identify_non_configured(self, timeout_ms: int = 50) -> bool:
        """3.5.2.13: True when some slave without a node id (0xFF) answered 0x50."""
        return self.lss_request(bytes([LSS_IDENTIFY_NON_CONFIGURED]), timeout_ms,
                                LSS_NON_CONFIGURED_RESPONSE) is not None

    def identify_remote(self, vendor: int, product: int, revision: tuple[int, int], serial: tuple[int, int],
                        timeout_ms: int = 50) -> bool:
        """3.5.2.12: True when a slave inside the address range answered 0x4F."""
        for cs, value in zip(range(LSS_IDENTIFY_REMOTE, LSS_IDENTIFY_REMOTE + 5),
                             (vendor, product, revision[0], revision[1], serial[0])):
            self.send_lss(bytes([cs]) + value.to_bytes(4, "little"))
        return self.lss_request(bytes([LSS_IDENTIFY_REMOTE + 5]) + serial[1].to_bytes(4, "little"),
                                timeout_ms, LSS_IDENTIFY_RESPONSE) is not None

    def _fastscan_step(self, id_number: int, bit: int, sub: int, next_: int, timeout_ms: int) -> bool:
        data = bytes([LSS_FASTSCAN]) + id_number.to_bytes(4, "little") + bytes([bit, sub, next_])
        return self.lss_request(data, timeout_ms, LSS_IDENTIFY_RESPONSE) is not None

    def fastscan(self, timeout_ms: int = 20) -> LssAddress | None:
        """CiA 305 fastscan through SendLSS/ReadLSS: finds one unconfigured slave bit by bit and
        leaves it in LSS configuration state; None when no unconfigured slave answers."""
        if not self._fastscan_step(0, 0x80, 0, 0, timeout_ms):
            return None
        ids = [0, 0, 0, 0]
        for sub in range(4):
            for bit in range(31, -1, -1):
                if not self._fastscan_step(ids[sub], bit, sub, sub, timeout_ms):
                    ids[sub] |= 1 << bit
            if not self._fastscan_step(ids[sub], 0, sub, (sub + 1) & 3, timeout_ms):
                return None
        return LssAddress(*ids)
