"""Error frames as SocketCAN reports them (linux/can/error.h), and their candump ``-e`` text.

The virtual bus knows why an error frame was sent (:class:`~.bus.ErrorKind`) and every
controller's state (:class:`~.bus.ErrorState`); a python-can client of the ``gatewaylab``
interface gets both as ``is_error_frame`` messages laid out as the Linux kernel lays them out, so
code written against ``interface="socketcan"`` reads them unchanged and ``gatewaylab dump -e``
prints them as ``candump -e`` does. Pure functions, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "CAN_ERR_ACK",
    "CAN_ERR_BUSERROR",
    "CAN_ERR_BUSOFF",
    "CAN_ERR_CNT",
    "CAN_ERR_CRTL",
    "CAN_ERR_CRTL_ACTIVE",
    "CAN_ERR_CRTL_RX_OVERFLOW",
    "CAN_ERR_CRTL_RX_PASSIVE",
    "CAN_ERR_CRTL_RX_WARNING",
    "CAN_ERR_CRTL_TX_PASSIVE",
    "CAN_ERR_CRTL_TX_WARNING",
    "CAN_ERR_FLAG",
    "CAN_ERR_LOSTARB",
    "CAN_ERR_MASK",
    "CAN_ERR_PROT",
    "CAN_ERR_PROT_BIT",
    "CAN_ERR_PROT_FORM",
    "CAN_ERR_PROT_LOC_ACK",
    "CAN_ERR_PROT_LOC_CRC_SEQ",
    "CAN_ERR_PROT_STUFF",
    "CAN_ERR_PROT_TX",
    "CAN_ERR_RESTARTED",
    "CAN_ERR_TRX",
    "CAN_ERR_TX_TIMEOUT",
    "KIND_LAYOUT",
    "ErrorFrame",
    "bus_error",
    "describe",
    "state_change",
    "summary",
]


#: can_id flag of an error frame (struct can_frame.can_id) and the mask of its class bits.
CAN_ERR_FLAG = 0x20000000
CAN_ERR_MASK = 0x1FFFFFFF

# error classes (can_id bits)
CAN_ERR_TX_TIMEOUT = 0x001
CAN_ERR_LOSTARB = 0x002
CAN_ERR_CRTL = 0x004
CAN_ERR_PROT = 0x008
CAN_ERR_TRX = 0x010
CAN_ERR_ACK = 0x020
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100
CAN_ERR_CNT = 0x200

# data[1]: controller problems
CAN_ERR_CRTL_RX_OVERFLOW = 0x01
CAN_ERR_CRTL_RX_WARNING = 0x04
CAN_ERR_CRTL_TX_WARNING = 0x08
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40

# data[2]: protocol violation types
CAN_ERR_PROT_BIT = 0x01
CAN_ERR_PROT_FORM = 0x02
CAN_ERR_PROT_STUFF = 0x04
CAN_ERR_PROT_TX = 0x80

# data[3]: protocol violation locations
CAN_ERR_PROT_LOC_CRC_SEQ = 0x08
CAN_ERR_PROT_LOC_ACK = 0x19

#: The virtual bus's error kinds (ErrorKind values) -> (class bits, data[2] type, data[3] location).
KIND_LAYOUT: dict[str, tuple[int, int, int]] = {
    "ack": (CAN_ERR_ACK, 0, CAN_ERR_PROT_LOC_ACK),
    "crc": (CAN_ERR_PROT | CAN_ERR_BUSERROR, 0, CAN_ERR_PROT_LOC_CRC_SEQ),
    "bit": (CAN_ERR_PROT | CAN_ERR_BUSERROR, CAN_ERR_PROT_BIT, 0),
    "form": (CAN_ERR_PROT | CAN_ERR_BUSERROR, CAN_ERR_PROT_FORM, 0),
    "stuff": (CAN_ERR_PROT | CAN_ERR_BUSERROR, CAN_ERR_PROT_STUFF, 0),
}

# the names can-utils' lib.c prints (snprintf_can_error_frame), bit i of each field
_CLASSES = ("tx-timeout", "lost-arbitration", "controller-problem", "protocol-violation", "transceiver-status",
            "no-acknowledgement-on-tx", "bus-off", "bus-error", "restarted-after-bus-off", "error-counter-tx-rx")
_CONTROLLER = ("rx-overflow", "tx-overflow", "rx-error-warning", "tx-error-warning", "rx-error-passive",
               "tx-error-passive", "back-to-error-active")
_PROT_TYPES = ("single-bit-error", "frame-format-error", "bit-stuffing-error", "tx-dominant-bit-error",
               "tx-recessive-bit-error", "bus-overload", "active-error", "error-on-tx")
_PROT_LOCATIONS = (
    "unspecified", "unspecified", "id.28-to-id.21", "start-of-frame", "bit-srtr", "bit-ide", "id.20-to-id.18",
    "id.17-to-id.13", "crc-sequence", "reserved-bit-0", "data-field", "data-length-code", "bit-rtr",
    "reserved-bit-1", "id.4-to-id.0", "id.12-to-id.5", "unspecified", "active-error-flag", "intermission",
    "tolerate-dominant-bits", "unspecified", "unspecified", "passive-error-flag", "error-delimiter",
    "crc-delimiter", "acknowledge-slot", "end-of-frame", "acknowledge-delimiter", "overload-flag", "unspecified",
    "unspecified", "unspecified")


@dataclass(frozen=True, slots=True)
class ErrorFrame:
    """A SocketCAN error frame: ``can_id`` holds the class bits (without CAN_ERR_FLAG), ``data`` 8 bytes."""

    can_id: int
    data: bytes = bytes(8)

    @property
    def tec(self) -> int:
        """The transmit error counter the frame reports (data byte 6)."""
        return self.data[6]

    @property
    def rec(self) -> int:
        """The receive error counter the frame reports (data byte 7)."""
        return self.data[7]


def _counters(tec: int, rec: int) -> tuple[int, int]:
    return min(tec, 255), min(rec, 255)


def bus_error(kind: str, transmitter: bool, tec: int, rec: int) -> ErrorFrame:
    """The error frame of one bus error of ``kind`` (an ErrorKind value) as the controller saw it."""
    classes, ptype, location = KIND_LAYOUT.get(kind, (CAN_ERR_PROT | CAN_ERR_BUSERROR, 0, 0))
    if transmitter and classes & CAN_ERR_PROT:
        ptype |= CAN_ERR_PROT_TX
    t, r = _counters(tec, rec)
    return ErrorFrame(classes | CAN_ERR_CNT, bytes((0, 0, ptype, location, 0, 0, t, r)))


def state_change(old: str, new: str, tec: int, rec: int) -> ErrorFrame:
    """The error frame of a controller state change (ErrorState values: error-active, error-passive,
    bus-off), as a Linux CAN driver reports it: bus-off, restarted, or a controller problem."""
    t, r = _counters(tec, rec)
    if new == "bus-off":
        return ErrorFrame(CAN_ERR_BUSOFF | CAN_ERR_CNT, bytes((0, 0, 0, 0, 0, 0, t, r)))
    if new == "error-passive":
        problem = (CAN_ERR_CRTL_TX_PASSIVE if tec > 127 else 0) | (CAN_ERR_CRTL_RX_PASSIVE if rec > 127 else 0)
        return ErrorFrame(CAN_ERR_CRTL | CAN_ERR_CNT, bytes((0, problem or CAN_ERR_CRTL_RX_PASSIVE, 0, 0, 0, 0, t, r)))
    restarted = CAN_ERR_RESTARTED if old == "bus-off" else 0
    return ErrorFrame(CAN_ERR_CRTL | restarted | CAN_ERR_CNT, bytes((0, CAN_ERR_CRTL_ACTIVE, 0, 0, 0, 0, t, r)))


def _bits(value: int, names: tuple[str, ...]) -> str:
    return ",".join(name for i, name in enumerate(names) if value & (1 << i))


def describe(frame: ErrorFrame, sep: str = "\n\t") -> str:
    """What ``candump -e`` prints under an error frame (can-utils lib.c snprintf_can_error_frame)."""
    cls = frame.can_id & CAN_ERR_MASK
    d = frame.data.ljust(8, b"\0")
    parts = []
    for i, name in enumerate(_CLASSES):
        mask = 1 << i
        if not cls & mask:
            continue
        text = name
        if mask == CAN_ERR_LOSTARB:
            text += f"{{at bit {d[0]}}}"
        elif mask == CAN_ERR_CRTL:
            text += "{" + _bits(d[1], _CONTROLLER) + "}"
        elif mask == CAN_ERR_PROT:
            where = _PROT_LOCATIONS[d[3]] if 0 < d[3] < len(_PROT_LOCATIONS) else ""
            text += "{{" + _bits(d[2], _PROT_TYPES) + "}{" + where + "}}"
        elif mask == CAN_ERR_CNT:
            text += f"{{{{{d[6]}}}{{{d[7]}}}}}"
        parts.append(text)
    out = sep.join(parts)
    if not cls & CAN_ERR_CNT and (d[6] or d[7]):
        out += f"{sep}error-counter-tx-rx{{{{{d[6]}}}{{{d[7]}}}}}"
    return out


def summary(frame: ErrorFrame) -> str:
    """One line for a decoded log: the error's kind in words and the counters."""
    cls = frame.can_id & CAN_ERR_MASK
    d = frame.data.ljust(8, b"\0")
    if cls & CAN_ERR_BUSOFF:
        what = "controller bus-off"
    elif cls & CAN_ERR_RESTARTED:
        what = "controller restarted after bus-off: error-active"
    elif cls & CAN_ERR_CRTL:
        what = "controller " + (_bits(d[1], _CONTROLLER) or "problem")
    elif cls & CAN_ERR_ACK:
        what = "error frame: no acknowledgement (ACK error)"
    elif cls & CAN_ERR_PROT:
        kind = _bits(d[2] & ~CAN_ERR_PROT_TX, _PROT_TYPES)
        if not kind and d[3] == CAN_ERR_PROT_LOC_CRC_SEQ:
            kind = "crc-error"
        what = f"error frame: {kind or 'protocol violation'}" + (" (as transmitter)" if d[2] & CAN_ERR_PROT_TX
                                                                  else "")
    else:
        what = "error frame: " + (describe(frame, ", ") or "unspecified")
    return f"{what}, TEC {d[6]} REC {d[7]}"
