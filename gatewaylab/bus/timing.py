"""How long a frame occupies the bus: a documented bit-count model (docs/bus.md).

Classic CAN uses the worst-case bit-stuffing model of Davis, Burns, Bril and Lukkien,
"Controller Area Network (CAN) schedulability analysis: refuted, revisited and revised"
(Real-Time Systems 35, 2007), the model used throughout CAN timing analysis:

    bits = g + 8n + 13 + floor((g + 8n - 1) / 4)

with ``g = 34`` control bits exposed to stuffing for an 11-bit frame (SOF, 11 id, RTR, IDE, r0,
4 DLC, 15 CRC) and ``g = 54`` for a 29-bit frame (SOF, 11 id, SRR, IDE, 18 id, RTR, r1, r0, 4 DLC,
15 CRC); 13 = CRC delimiter, ACK slot, ACK delimiter, 7 EOF and 3 intermission bits, which are
never stuffed. A remote frame has ``n = 0``.

CAN FD (ISO 11898-1:2015) is split into the part sent at the nominal bit rate and the part sent
at the data bit rate (when BRS is set; otherwise everything uses the nominal rate):

* nominal: SOF, id, RRS, IDE, FDF, res, BRS (11-bit: 17 bits; 29-bit: SOF, 11 id, SRR, IDE,
  18 id, RRS, FDF, res, BRS = 36 bits) plus worst-case dynamic stuff bits ``floor((a - 1) / 4)``;
  and after the switch back: CRC delimiter, ACK, ACK delimiter, 7 EOF, 3 intermission = 13 bits.
* data: ESI, 4 DLC, 8n data bits with worst-case dynamic stuffing ``floor((5 + 8n) / 4)``,
  then the 4-bit stuff count and the CRC (17 bits up to 16 data bytes, 21 above) with one fixed
  stuff bit before the stuff count and after every 4 bits: 6 (CRC-17) or 7 (CRC-21) fixed bits.
"""

from __future__ import annotations

from functools import lru_cache

from gatewaylab.bus.frame import CanFrame

__all__ = [
    "BUS_OFF_RECOVERY_BITS",
    "ERROR_FRAME_BITS",
    "SUSPEND_TRANSMISSION_BITS",
    "arbitration_key",
    "classic_bits",
    "classic_durations",
    "error_duration",
    "fd_bits",
    "frame_bits_until_ack",
    "frame_duration",
]


#: Bits of the error frame sent after an error is detected: 6-bit error flag, up to 6 more from
#: other nodes' flags (counted as 6), 8-bit delimiter and 3 intermission bits.
ERROR_FRAME_BITS = 6 + 6 + 8 + 3
#: Extra recessive bits an error-passive transmitter waits before it may retransmit.
SUSPEND_TRANSMISSION_BITS = 8
#: Bus-off recovery: 128 occurrences of 11 consecutive recessive bits (ISO 11898-1 fault confinement).
BUS_OFF_RECOVERY_BITS = 128 * 11


def classic_bits(extended: bool, n: int) -> int:
    """Worst-case bit count of a classic frame with ``n`` data bytes, stuffing included."""
    g = 54 if extended else 34
    return g + 8 * n + 13 + (g + 8 * n - 1) // 4


def fd_bits(extended: bool, n: int) -> tuple[int, int]:
    """(nominal-rate bits, data-phase bits) of a CAN FD frame with ``n`` data bytes."""
    arb = 36 if extended else 17
    nominal = arb + (arb - 1) // 4 + 13
    dyn = 1 + 4 + 8 * n
    crc = 17 if n <= 16 else 21
    fixed = 6 if n <= 16 else 7
    data = dyn + dyn // 4 + 4 + crc + fixed
    return nominal, data


@lru_cache(maxsize=4096)
def _duration(extended: bool, fd: bool, brs: bool, n: int, bitrate: int, data_bitrate: int) -> float:
    if not fd:
        return classic_bits(extended, n) / bitrate
    nominal, data = fd_bits(extended, n)
    if brs:
        return nominal / bitrate + data / data_bitrate
    return (nominal + data) / bitrate


def frame_duration(frame: CanFrame, bitrate: int, data_bitrate: int | None = None) -> float:
    """Seconds the frame occupies the bus, from SOF to the end of the intermission."""
    n = 0 if frame.rtr else len(frame.data)
    return _duration(frame.extended, frame.fd, frame.brs, n, bitrate, data_bitrate or bitrate)


def classic_durations(bitrate: int) -> tuple[float, ...]:
    """Seconds of classic base frames with 0..8 data bytes (index = bytes; remote frames: 0)."""
    return tuple(classic_bits(False, n) / bitrate for n in range(9))


def frame_bits_until_ack(frame: CanFrame) -> int:
    """Nominal-rate bit times until the ACK slot, where an ACK error is detected."""
    n = 0 if frame.rtr else len(frame.data)
    if not frame.fd:
        return classic_bits(frame.extended, n) - 12
    nominal, data = fd_bits(frame.extended, n)
    return nominal - 12 + data


def error_duration(frame: CanFrame, passive: bool, bitrate: int, data_bitrate: int | None = None) -> float:
    """Seconds a transmission that ends in an error (ACK or CRC) occupies the bus: the frame up
    to its ACK slot, the error frame, and for an error-passive sender the suspend transmission."""
    if frame.fd and frame.brs and data_bitrate:
        until_ack = frame_duration(frame, bitrate, data_bitrate) - 12 / bitrate
    else:
        until_ack = frame_bits_until_ack(frame) / bitrate
    return until_ack + (ERROR_FRAME_BITS + (SUSPEND_TRANSMISSION_BITS if passive else 0)) / bitrate


def arbitration_key(frame: CanFrame) -> int:
    """Integer that orders frames as bitwise arbitration does (smaller wins).

    The arbitration field is compared bit by bit, dominant (0) winning: 11-bit id, then for a
    base frame RTR and IDE (0), for an extended frame SRR (1), IDE (1), 18 id bits and RTR. So a
    base frame beats an extended frame with the same base id, and a data frame beats a remote
    frame with the same id. CAN FD frames send RRS (always dominant) in the RTR position.
    """
    if frame.extended:
        cid = frame.can_id
        return ((cid >> 18) << 21) | (3 << 19) | ((cid & 0x3FFFF) << 1) | frame.rtr
    return (frame.can_id << 21) | (frame.rtr << 20)
