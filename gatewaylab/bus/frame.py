"""CAN / CAN FD frames as frozen values, validated once at construction."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

from gatewaylab.common.errors import FrameError

if TYPE_CHECKING:
    import can

__all__ = ["FD_DLC_TO_LEN", "FD_LEN_TO_DLC", "MAX_EXT_ID", "MAX_STD_ID", "CanFrame", "len_to_dlc"]


#: CAN FD DLC -> payload length (ISO 11898-1:2015); DLC 0..8 mean 0..8 bytes.
#: (Final: compiled, mypyc reads a Final module constant natively instead of from the module's dict.)
FD_DLC_TO_LEN: Final[tuple[int, ...]] = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
FD_LEN_TO_DLC: Final[dict[int, int]] = {n: i for i, n in enumerate(FD_DLC_TO_LEN)}
MAX_STD_ID: Final = 0x7FF
MAX_EXT_ID: Final = 0x1FFFFFFF


def len_to_dlc(length: int) -> int:
    """DLC for an exact payload length; raises when no DLC encodes it."""
    try:
        return FD_LEN_TO_DLC[length]
    except KeyError:
        raise FrameError(f"no CAN FD DLC encodes a payload of {length} bytes") from None


@dataclass(frozen=True, slots=True)
class CanFrame:
    """One CAN (FD) frame as it appears on the bus.

    ``dlc`` is kept for classic remote frames, whose DLC is not the payload length. For every
    other frame it follows from ``data``.
    """

    can_id: int
    data: bytes = b""
    extended: bool = False
    rtr: bool = False
    fd: bool = False
    brs: bool = False
    esi: bool = False
    dlc: int = -1

    def __init__(self, can_id: int, data: bytes = b"", extended: bool = False, rtr: bool = False,
                 fd: bool = False, brs: bool = False, esi: bool = False, dlc: int = -1) -> None:
        # Written out (dataclass keeps an explicit __init__): a data frame whose DLC follows from its
        # length is checked and built in one step, everything else (remote frames, an explicit dlc,
        # data that is not bytes, any error) takes the full validation of __post_init__. Fields are
        # stored with object.__setattr__(self, "name", ...), written out: compiled (mypyc), each is a
        # direct store into the native object (docs/performance.md, "Rules that keep a module compilable").
        object.__setattr__(self, "can_id", can_id)
        object.__setattr__(self, "data", data)
        object.__setattr__(self, "extended", extended)
        object.__setattr__(self, "rtr", rtr)
        object.__setattr__(self, "fd", fd)
        object.__setattr__(self, "brs", brs)
        object.__setattr__(self, "esi", esi)
        # (no type(can_id) check: compiled, can_id is a machine int and the check would box it; pure, a
        # non-int either compares like one or raises TypeError on both paths)
        if type(data) is bytes and dlc == -1 and not rtr and 0 <= can_id <= (MAX_EXT_ID if extended else MAX_STD_ID):
            # A data frame whose length says its DLC (what decoders build by the thousand): checked here.
            n = len(data)
            if n <= 8:
                if not (brs or esi) or fd:
                    object.__setattr__(self, "dlc", n)
                    return
            elif fd and (fd_dlc := FD_LEN_TO_DLC.get(n, -1)) >= 0:
                object.__setattr__(self, "dlc", fd_dlc)
                return
        object.__setattr__(self, "dlc", dlc)
        self.__post_init__()

    def __post_init__(self) -> None:
        can_id, data = self.can_id, self.data
        if type(data) is not bytes:
            if not isinstance(data, (bytes, bytearray, memoryview, list, tuple)):
                raise FrameError(f"frame data must be bytes, got {type(data).__name__}")
            try:
                object.__setattr__(self, "data", bytes(data))
            except (ValueError, TypeError) as exc:
                raise FrameError(f"bad frame data: {exc}") from None
            data = self.data
        if can_id < 0 or can_id > (MAX_EXT_ID if self.extended else MAX_STD_ID):
            raise FrameError(
                f"id 0x{can_id:X} out of range for a {'29' if self.extended else '11'}-bit frame")
        n = len(data)
        if self.fd:
            if self.rtr:
                raise FrameError("CAN FD has no remote frames")
            dlc = FD_LEN_TO_DLC.get(n)
            if dlc is None:
                raise FrameError(f"a CAN FD payload of {n} bytes matches no DLC (use 0-8,12,16,20,24,32,48,64)")
            if self.dlc not in (-1, dlc):
                raise FrameError(f"DLC {self.dlc} does not match a {n}-byte CAN FD payload")
        else:
            if self.brs or self.esi:
                raise FrameError("BRS and ESI exist only on CAN FD frames")
            if self.rtr:
                if n:
                    raise FrameError("a remote frame carries no data")
                dlc = 0 if self.dlc == -1 else self.dlc
                if not 0 <= dlc <= 8:
                    raise FrameError(f"remote frame DLC {dlc} out of 0..8")
            else:
                if n > 8:
                    raise FrameError(f"classic CAN carries at most 8 bytes, got {n} (DLC > 8)")
                dlc = n
                if self.dlc not in (-1, dlc):
                    raise FrameError(f"DLC {self.dlc} does not match {n} data bytes")
        object.__setattr__(self, "dlc", dlc)

    def __reduce__(self) -> tuple[type[CanFrame], tuple[int, bytes, bool, bool, bool, bool, bool, int]]:
        """Pickle by the constructor's arguments: a compiled (mypyc) CanFrame has no argument-free ``__new__``."""
        return (CanFrame, (self.can_id, self.data, self.extended, self.rtr, self.fd, self.brs, self.esi,
                           self.dlc if self.rtr else -1))

    @property
    def length(self) -> int:
        """Bytes on the wire in the data field (0 for remote frames)."""
        return len(self.data)

    def __str__(self) -> str:
        ident = f"{self.can_id:08X}" if self.extended else f"{self.can_id:03X}"
        if self.rtr:
            return f"{ident}#R{self.dlc}"
        sep = "##" + format((self.brs and 1) | (self.esi and 2), "X") if self.fd else "#"
        return f"{ident}{sep}{self.data.hex().upper()}"

    # -- python-can interop -------------------------------------------------------------------
    def to_message(self, timestamp: float = 0.0, channel: str | int | None = None) -> can.Message:
        """The frame as a python-can ``Message`` (for adapters, traces and bridges); ``channel`` is what the
        user gave python-can (a name or a number: a compiled frame checks the annotation)."""
        import can

        return can.Message(
            timestamp=timestamp, arbitration_id=self.can_id, is_extended_id=self.extended,
            is_remote_frame=self.rtr, is_fd=self.fd, bitrate_switch=self.brs,
            error_state_indicator=self.esi, dlc=self.dlc if self.rtr else len(self.data),
            data=self.data, channel=channel, check=False)

    @classmethod
    def from_message(cls, msg: can.Message) -> CanFrame:
        """A python-can ``Message`` as a frame; error frames are refused (use fault injection)."""
        if msg.is_error_frame:
            raise FrameError("error frames cannot be sent; use the fault-injection API")
        data = bytes(msg.data) if msg.data is not None else b""
        if not (msg.is_remote_frame or msg.is_extended_id or msg.is_fd or msg.bitrate_switch
                or msg.error_state_indicator):
            return cls(msg.arbitration_id, data)     # the common classic base data frame
        if msg.is_remote_frame:
            return cls(msg.arbitration_id, b"", msg.is_extended_id, True, msg.is_fd,
                       msg.bitrate_switch, msg.error_state_indicator, msg.dlc)
        return cls(msg.arbitration_id, data, msg.is_extended_id, False, msg.is_fd,
                   msg.bitrate_switch, msg.error_state_indicator)

