"""EMCY producer (CiA 301 7.2.7; IDX guide 3.3.3.4) with error register 0x1001 and history 0x1003.

An error is signalled once per error event: raising a code that is already active sends
nothing; when an error goes away the 'error reset / no error' message (code 0x0000) carries the
remaining error register. Messages obey the inhibit time 0x1015 (multiples of 100 us) and are
not sent in NMT Stopped (they are still recorded in 0x1003).
"""

from __future__ import annotations

import struct
from collections import deque
from typing import TYPE_CHECKING, Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.common.clock import TimerHandle
from gatewaylab.od import Entry
from gatewaylab.od.aborts import SdoAbort, SdoAbortCode

if TYPE_CHECKING:
    from gatewaylab.canopen.node import Node

__all__ = [
    "EMCY_CAN_OVERRUN",
    "EMCY_FRAME",
    "EMCY_LIFE_GUARD_HEARTBEAT",
    "EMCY_NO_ERROR",
    "EMCY_PDO_LENGTH",
    "EMCY_PDO_LENGTH_EXCEEDED",
    "EMCY_UNEXPECTED_SYNC_LENGTH",
    "ERROR_CODE_NAMES",
    "ERR_COMMUNICATION",
    "ERR_CURRENT",
    "ERR_GENERIC",
    "ERR_MANUFACTURER",
    "ERR_PROFILE",
    "ERR_TEMPERATURE",
    "ERR_VOLTAGE",
    "Emcy",
    "encode_emcy",
    "error_code_name",
]


EMCY_FRAME = struct.Struct("<HB5s")

# Error register bits (CiA 301 table 48)
ERR_GENERIC = 0x01
ERR_CURRENT = 0x02
ERR_VOLTAGE = 0x04
ERR_TEMPERATURE = 0x08
ERR_COMMUNICATION = 0x10
ERR_PROFILE = 0x20
ERR_MANUFACTURER = 0x80

# Emergency error codes used by the stack (CiA 301 table 21)
EMCY_NO_ERROR = 0x0000
EMCY_CAN_OVERRUN = 0x8110
EMCY_LIFE_GUARD_HEARTBEAT = 0x8130
EMCY_PDO_LENGTH = 0x8210
EMCY_PDO_LENGTH_EXCEEDED = 0x8220
EMCY_UNEXPECTED_SYNC_LENGTH = 0x8240


#: Names of emergency error codes: CiA 301 table 21 and the CiA 402 drive codes a drive sends (0x603F),
#: exact codes first; :func:`error_code_name` falls back to the class (high byte, then high nibble).
ERROR_CODE_NAMES: dict[int, str] = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x2310: "continuous over-current",
    0x2320: "short circuit at outputs",
    0x3210: "DC link over-voltage",
    0x3220: "DC link under-voltage",
    0x4210: "excess temperature device",
    0x4310: "excess temperature drive",
    0x5441: "enable input off",
    0x6010: "software reset (watchdog)",
    0x7121: "motor blocked",
    0x7320: "position sensor error",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8150: "CAN-ID collision",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8230: "DAM MPDO not processed, destination object not available",
    0x8240: "unexpected SYNC data length",
    0x8250: "RPDO timeout",
    0x8611: "following error",
    0x8612: "reference limit",
    0x9000: "external error",
    0xF000: "additional functions",
    0xFF00: "device specific",
}
_ERROR_CLASSES: dict[int, str] = {
    0x10: "generic error", 0x20: "current", 0x21: "current, device input side", 0x22: "current inside the device",
    0x23: "current, device output side", 0x30: "voltage", 0x31: "mains voltage", 0x32: "voltage inside the device",
    0x33: "output voltage", 0x40: "temperature", 0x41: "ambient temperature", 0x42: "device temperature",
    0x50: "device hardware", 0x60: "device software", 0x61: "internal software", 0x62: "user software",
    0x63: "data set", 0x70: "additional modules", 0x80: "monitoring", 0x81: "communication",
    0x82: "protocol error", 0x84: "velocity speed controller", 0x85: "position controller",
    0x86: "positioning controller", 0x90: "external error", 0xF0: "additional functions", 0xFF: "device specific",
}


def error_code_name(code: int) -> str:
    """What an emergency error code means (CiA 301 table 21, CiA 402 drive codes): the exact name when
    known, else its class ("monitoring (class 0x8Fxx)")."""
    name = ERROR_CODE_NAMES.get(code)
    if name is not None:
        return name
    cls = _ERROR_CLASSES.get(code >> 8) or _ERROR_CLASSES.get((code >> 12) << 4)
    return f"{cls or 'unknown'} (class 0x{code >> 8:02X}xx)"


def encode_emcy(cob_id: int, code: int, register: int, info: bytes = b"") -> CanFrame:
    """EMCY frame: error code (u16), error register (u8), 5 manufacturer-specific bytes."""
    return CanFrame(cob_id, EMCY_FRAME.pack(code, register, info[:5].ljust(5, b"\x00")))


class Emcy:
    """The EMCY producer of a :class:`Node`."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.cob_id = 0
        self.inhibit = 0.0
        #: Active errors: code -> error register bits it sets.
        self.active: dict[int, int] = {}
        self._queue: deque[CanFrame] = deque()
        self._last_tx = -1e9
        self._timer: TimerHandle | None = None
        node.add_validator(0x1003, self._validate_history)
        node.add_validator(0x1014, self._validate_cob_id)
        node.add_reaction(0x1014, lambda e, v: self.configure())
        node.add_reaction(0x1015, lambda e, v: self.configure())

    def configure(self) -> None:
        """Take the COB-ID and inhibit time from 0x1014/0x1015."""
        od = self.node.od
        cob = od.get(0x1014, 0)
        self.cob_id = 0 if cob & 0x80000000 else cob & 0x7FF
        self.inhibit = od.get(0x1015, 0) * 100e-6

    def halt(self) -> None:
        """Cancel the inhibit timer (reset, stop)."""
        self._queue.clear()
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    @staticmethod
    def _validate_history(entry: Entry, value: Any) -> None:
        if entry.subindex == 0 and value != 0:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "0x1003:00 accepts only 0 (clear the history)")

    def _validate_cob_id(self, entry: Entry, value: Any) -> None:
        if value & 0x20000000 or ((value & 0x7FF) == 0 and not value & 0x80000000):
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, "EMCY COB-ID: 11-bit, not 0")

    @property
    def register(self) -> int:
        """The error register 0x1001 as the active errors define it."""
        reg = 0
        for bits in self.active.values():
            reg |= bits
        return reg | ERR_GENERIC if self.active else 0

    def raise_error(self, code: int, register_bits: int = ERR_GENERIC, info: bytes = b"") -> None:
        """Signal error ``code``: 0x1001, 0x1003 and one EMCY message (once per error event)."""
        if code in self.active:
            return
        self.active[code] = register_bits
        node = self.node
        od = node.od
        od.values[(0x1001, 0)] = self.register
        # 0x1003: newest at sub-index 1, older ones shift up, sub 0 counts them.
        count = od.values[(0x1003, 0)]
        highest = max(s for s in od.objects[0x1003].entries)
        extra = int.from_bytes(info[:2].ljust(2, b"\x00"), "little")
        for sub in range(min(count + 1, highest), 1, -1):
            od.values[(0x1003, sub)] = od.values[(0x1003, sub - 1)]
        od.values[(0x1003, 1)] = (extra << 16) | code
        od.values[(0x1003, 0)] = min(count + 1, highest)
        self._emit(code, info)

    def clear_error(self, code: int) -> None:
        """The error ``code`` went away: error register updated, 'error reset' message sent."""
        if self.active.pop(code, None) is None:
            return
        self.node.od.values[(0x1001, 0)] = self.register
        self._emit(EMCY_NO_ERROR, b"")

    def clear_all(self, send: bool = True) -> None:
        """Forget every active error (error register 0x1001 = 0); optionally send 'no error'."""
        had = bool(self.active)
        self.active.clear()
        self.node.od.values[(0x1001, 0)] = 0
        if had and send:
            self._emit(EMCY_NO_ERROR, b"")

    def _emit(self, code: int, info: bytes) -> None:
        node = self.node
        if (not self.cob_id or node.nmt_state is NmtState.STOPPED
                or node.nmt_state is NmtState.INITIALISING or not node.running):
            node.count("emcy_not_sent")
            return
        self._queue.append(encode_emcy(self.cob_id, code, self.register, info))
        if self._timer is None:
            self._pump()

    def _pump(self) -> None:
        self._timer = None
        now = self.node.clock.now()
        while self._queue:
            due = self._last_tx + self.inhibit
            if self.inhibit and now < due:
                self._timer = self.node.clock.call_at(due, self._pump)
                return
            self.node.send(self._queue.popleft())
            self._last_tx = now
