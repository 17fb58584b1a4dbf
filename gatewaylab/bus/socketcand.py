"""The socketcand text protocol, sans-I/O: bytes in -> events out, frames in -> bytes out.

socketcand (linux-can/socketcand, doc/protocol.md and src/state_*.c) serves a CAN bus over one TCP
connection in ASCII elements ``< word word ... >``. This module is its server half as upstream
behaves, so python-can's ``interface="socketcand"`` and other socketcand clients reach a rig bus
unchanged:

* CAN FD is sent as ``< fdframe >`` only to a client that asked for it (``< rawmode fd >``, this
  server's extension, or an ``fdsend``/``sendfd`` of its own): python-can's client, like every client
  written for upstream's classic protocol, cannot parse it; it sends FD messages as ``send`` with a hex
  length over 8, taken here as an FD frame (docs/endpoints.md);
* framing (``receive_command``): bytes before a ``<`` are dropped, an element ends at the first
  ``>``; an unterminated element longer than upstream's buffer (MAXLEN) ends the connection;
* NO_BUS: greeted with ``< hi >``; ``< open BUS >`` -> ``< ok >`` and BCM mode, an unknown bus ->
  ``< error could not open bus >`` and the connection ends; ``< BUS B ... >`` / ``< BUS C ... >``
  (bit timing / control mode) -> ``< error configuring interface BUS >`` and the end (a rig bus's
  timing is its rig file's);
* BCM (the mode after open): ``send``, ``add``, ``update``, ``delete``, ``subscribe``,
  ``unsubscribe``, ``echo``; RAW (``< rawmode >``): every frame as ``< frame ... >``, ``send``,
  ``echo``; CAN FD: ``< fdframe ID FLAGS sec.usec DATA >`` out, ``< fdsend ID FLAGS LEN b ... >``
  (socketcand pull request 33) and ``< sendfd ID LEN b ... >`` (upstream branch rawmode-canfd) in;
* a mode switch answers ``< ok >``; a command the mode does not know answers
  ``< error unknown command >``; a malformed ``send``/``add``/... is only logged by upstream
  (nothing on the wire): here a :class:`SyntaxErrorEvent` the server logs and counts.

``filter``/``muxfilter`` (BCM content filters), ISO-TP mode and CONTROL-mode statistics are not
served: they answer ``< error unknown command >`` (docs/decisions.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from gatewaylab.bus.frame import FD_LEN_TO_DLC, MAX_EXT_ID, MAX_STD_ID, CanFrame

#: upstream's command buffer (socketcand.h MAXLEN = 2 * ISOTPLEN + 100): an element that does not
#: end within it ends the connection
MAX_ELEMENT = 2 * 4095 + 100

HI = b"< hi >"
OK = b"< ok >"
ECHO = b"< echo >"
UNKNOWN_COMMAND = b"< error unknown command >"
COULD_NOT_OPEN = b"< error could not open bus >"

#: linux/can/error.h classes (the id of a SocketCAN error frame, sent as ``< error CLASS t >``)
CAN_ERR_CRTL = 0x004
CAN_ERR_PROT = 0x008
CAN_ERR_ACK = 0x020
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100
#: linux/can.h canfd_frame.flags
CANFD_BRS = 0x01
CANFD_ESI = 0x02

_HEX = frozenset(b"0123456789abcdefABCDEF")
_DEC = frozenset(b"0123456789")


class Mode(Enum):
    """socketcand's states (socketcand.h STATE_*) that this server serves."""

    NO_BUS = "no-bus"
    BCM = "bcm"
    RAW = "raw"


_SWITCH = {b"rawmode": Mode.RAW, b"bcmmode": Mode.BCM}


@dataclass(frozen=True, slots=True)
class Reply:
    """Bytes to send to the client."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Close:
    """End the connection (after sending ``data``, if any): upstream's STATE_SHUTDOWN."""

    data: bytes
    reason: str


@dataclass(frozen=True, slots=True)
class Opened:
    """``< open BUS >`` accepted: attach to the bus (BCM mode: nothing is received yet)."""

    bus: str


@dataclass(frozen=True, slots=True)
class ModeChanged:
    """``< rawmode >`` / ``< bcmmode >``: the mode the connection is in from here on."""

    mode: Mode


@dataclass(frozen=True, slots=True)
class SendFrame:
    """``send`` / ``fdsend`` / ``sendfd``: put one frame on the bus."""

    frame: CanFrame


@dataclass(frozen=True, slots=True)
class AddJob:
    """BCM ``add``: send ``frame`` every ``interval`` seconds (0: once) until deleted."""

    frame: CanFrame
    interval: float


@dataclass(frozen=True, slots=True)
class UpdateJob:
    """BCM ``update``: new content for the job of ``frame``'s id, its timer untouched."""

    frame: CanFrame


@dataclass(frozen=True, slots=True)
class DeleteJob:
    """A client's ``< delete >``: stop a cyclic transmission job."""
    can_id: int
    extended: bool


@dataclass(frozen=True, slots=True)
class Subscribe:
    """BCM ``subscribe``: receive frames of one id, at most one per ``interval`` seconds (0: all)."""

    can_id: int
    extended: bool
    interval: float


@dataclass(frozen=True, slots=True)
class Unsubscribe:
    """A client's ``< unsubscribe >``: stop reporting an identifier."""
    can_id: int
    extended: bool


@dataclass(frozen=True, slots=True)
class SyntaxErrorEvent:
    """A known command with bad arguments: upstream logs it and answers nothing."""

    command: str
    message: str


Event = (Reply | Close | Opened | ModeChanged | SendFrame | AddJob | UpdateJob | DeleteJob | Subscribe
         | Unsubscribe | SyntaxErrorEvent)


class _Bad(Exception):
    """A malformed argument inside this module (becomes a SyntaxErrorEvent)."""


def _hex(token: bytes, what: str, limit: int) -> int:
    if not token or len(token) > 8 or not set(token) <= _HEX:
        raise _Bad(f"{what} {token.decode(errors='replace')!r} is not hex")
    value = int(token, 16)
    if value > limit:
        raise _Bad(f"{what} 0x{value:X} > 0x{limit:X}")
    return value


def _dec(token: bytes, what: str, limit: int) -> int:
    if not token or len(token) > 20 or not set(token) <= _DEC:
        raise _Bad(f"{what} {token.decode(errors='replace')!r} is not a decimal number")
    value = int(token)
    if value > limit:
        raise _Bad(f"{what} {value} > {limit}")
    return value


def _ident(token: bytes) -> tuple[int, bool]:
    """A CAN id as upstream reads it: hex, extended exactly when it has 8 digits."""
    extended = len(token) == 8
    return _hex(token, "can_id", MAX_EXT_ID if extended else MAX_STD_ID), extended


def _payload(tokens: list[bytes], length: int) -> bytes:
    if len(tokens) != length:
        raise _Bad(f"{length} data bytes announced, {len(tokens)} given")
    return bytes(_hex(t, "data byte", 0xFF) for t in tokens)


def _classic(args: list[bytes]) -> CanFrame:
    """``ID DLC b ...`` of send/update/add: classic, at most 8 bytes."""
    if len(args) < 2:
        raise _Bad("needs can_id and can_dlc")
    can_id, extended = _ident(args[0])
    length = _dec(args[1], "can_dlc", 8)
    return CanFrame(can_id, _payload(args[2:], length), extended)


def _send(args: list[bytes]) -> CanFrame:
    """``send ID LEN b ...``: classic up to 8 bytes; more is taken as a CAN FD frame (no bit rate
    switch), the form python-can's socketcand client writes an FD message in (LEN in hex). Upstream
    knows only classic frames here; an FD frame on a classic bus is refused by the bus."""
    if len(args) < 2 or len(args) - 2 <= 8:
        return _classic(args)
    length = len(args) - 2
    token = args[1]
    announced = {int(token)} if set(token) <= _DEC else set()
    if set(token) <= _HEX and len(token) <= 2:
        announced.add(int(token, 16))
    if length not in announced or length not in FD_LEN_TO_DLC:
        raise _Bad(f"can_dlc {token.decode(errors='replace')!r} with {length} data bytes: not a frame")
    can_id, extended = _ident(args[0])
    return CanFrame(can_id, _payload(args[2:], length), extended, fd=True)


def _interval(sec: bytes, usec: bytes) -> float:
    return _dec(sec, "seconds", 2**32) + _dec(usec, "microseconds", 2**32) / 1e6


class Session:
    """One socketcand connection's state: :meth:`feed` the client's bytes, get events back."""

    def __init__(self, buses: tuple[str, ...]) -> None:
        #: the bus names ``< open >`` accepts
        self.buses = buses
        self.mode = Mode.NO_BUS
        self.bus: str | None = None
        #: the client asked for CAN FD (``< rawmode fd >``, or it sent ``fdsend``/``sendfd``): only then
        #: are FD frames sent to it as ``< fdframe >``, which a classic client cannot parse
        self.fd = False
        self.closed = False
        self._buf = bytearray()
        #: commands answered or refused, for the server's statistics
        self.commands = 0
        self.syntax_errors = 0
        self.unknown = 0

    @staticmethod
    def greeting() -> bytes:
        """What the server sends first on a new connection (``< hi >``)."""
        return HI

    def feed(self, data: bytes) -> list[Event]:
        """The events of every complete element in ``data`` (and what came before it)."""
        events: list[Event] = []
        if self.closed:
            return events
        buf = self._buf
        buf += data
        while True:
            start = buf.find(b"<")
            if start < 0:            # upstream: no '<' at all, nothing to keep
                buf.clear()
                break
            if start:
                del buf[:start]
            stop = buf.find(b">", 1)
            if stop < 0:
                if len(buf) >= MAX_ELEMENT:
                    buf.clear()
                    self.closed = True
                    events.append(Close(b"", f"an element longer than {MAX_ELEMENT} bytes"))
                break
            element = bytes(buf[1:stop])
            del buf[:stop + 1]
            self._command(element.split(), events)
            if self.closed:
                buf.clear()
                break
        return events

    def _command(self, words: list[bytes], events: list[Event]) -> None:
        self.commands += 1
        if self.mode is Mode.NO_BUS:
            self._no_bus(words, events)
            return
        head = words[0] if words else b""
        if head in _SWITCH and len(words) == 1 and _SWITCH[head] is not self.mode:
            self.mode = _SWITCH[head]
            events.append(ModeChanged(self.mode))
            events.append(Reply(OK))
            return
        if words == [b"echo"]:
            events.append(Reply(ECHO))
            return
        if words == [b"rawmode", b"fd"]:
            self.fd = True
            if self.mode is not Mode.RAW:
                self.mode = Mode.RAW
                events.append(ModeChanged(self.mode))
            events.append(Reply(OK))
            return
        args = words[1:]
        try:
            if head == b"send":
                events.append(SendFrame(_send(args)))
            elif head in (b"fdsend", b"sendfd") and self.mode is Mode.RAW:
                self.fd = True
                events.append(SendFrame(self._fd(head, args)))
            elif self.mode is Mode.BCM and head in (b"add", b"subscribe"):
                if len(args) < 3:
                    raise _Bad("needs secs, usecs and can_id")
                interval = _interval(args[0], args[1])
                if head == b"add":
                    events.append(AddJob(_classic(args[2:]), interval))
                else:
                    if len(args) != 3:
                        raise _Bad("takes secs, usecs and can_id")
                    can_id, extended = _ident(args[2])
                    events.append(Subscribe(can_id, extended, interval))
            elif self.mode is Mode.BCM and head == b"update":
                events.append(UpdateJob(_classic(args)))
            elif self.mode is Mode.BCM and head in (b"delete", b"unsubscribe"):
                if len(args) != 1:
                    raise _Bad("takes one can_id")
                can_id, extended = _ident(args[0])
                events.append(DeleteJob(can_id, extended) if head == b"delete" else Unsubscribe(can_id, extended))
            else:
                self.unknown += 1
                events.append(Reply(UNKNOWN_COMMAND))
        except (_Bad, ValueError) as exc:   # ValueError: a frame CanFrame refuses
            self.syntax_errors += 1
            events.append(SyntaxErrorEvent(head.decode(errors="replace"), str(exc)))

    @staticmethod
    def _fd(head: bytes, args: list[bytes]) -> CanFrame:
        """``fdsend ID FLAGS LEN b ...`` (PR 33) or ``sendfd ID LEN b ...`` (branch rawmode-canfd)."""
        flags = 0
        if head == b"fdsend":
            if len(args) < 3:
                raise _Bad("needs can_id, flags and len")
            flags = _hex(args[1], "flags", 0xFF)
            args = [args[0], *args[2:]]
        if len(args) < 2:
            raise _Bad("needs can_id and len")
        can_id, extended = _ident(args[0])
        length = _dec(args[1], "len", 64)
        if length not in FD_LEN_TO_DLC:
            raise _Bad(f"len {length} is no CAN FD length")
        return CanFrame(can_id, _payload(args[2:], length), extended, fd=True,
                        brs=bool(flags & CANFD_BRS), esi=bool(flags & CANFD_ESI))

    def _no_bus(self, words: list[bytes], events: list[Event]) -> None:
        if len(words) == 2 and words[0] == b"open":
            name = words[1].decode(errors="replace")
            if name in self.buses:
                self.mode = Mode.BCM
                self.bus = name
                events.append(Opened(name))
                events.append(Reply(OK))
            else:
                self._close(events, COULD_NOT_OPEN, f"client asked for bus {name!r}")
            return
        if len(words) >= 2 and len(words[1]) == 1 and words[0] != b"open":
            name = words[0].decode(errors="replace")
            op = words[1].decode(errors="replace")
            if name not in self.buses:
                self._close(events, COULD_NOT_OPEN, f"client configured bus {name!r}")
            elif op in ("B", "C"):
                self._close(events, f"< error configuring interface {name} >".encode(),
                            f"bus {name}: bit timing and control modes are the rig file's")
            else:
                self._close(events, f"< configuration operation not supported {op} >".encode(),
                            f"configuration operation {op!r}")
            return
        self.unknown += 1
        events.append(Reply(UNKNOWN_COMMAND))

    def _close(self, events: list[Event], data: bytes, reason: str) -> None:
        self.closed = True
        events.append(Close(data, reason))


# -- server -> client ----------------------------------------------------------------------------
def _stamp(unix_time: float) -> str:
    sec, usec = divmod(round(unix_time * 1e6), 1_000_000)
    return f"{sec}.{usec:06d}"


def _id(frame: CanFrame) -> str:
    return f"{frame.can_id:08X}" if frame.extended else f"{frame.can_id:03X}"


def raw_frame(frame: CanFrame, unix_time: float) -> bytes:
    """RAW mode (state_raw.c): ``< frame ID sec.usec DATA >``, CAN FD as ``< fdframe ID FLAGS ... >``.

    Upstream does not forward remote frames (``/* TODO implement */``): the caller skips them.
    """
    if frame.fd:
        flags = (CANFD_BRS if frame.brs else 0) | (CANFD_ESI if frame.esi else 0)
        return f"< fdframe {_id(frame)} {flags:02X} {_stamp(unix_time)} {frame.data.hex().upper()} >".encode()
    return f"< frame {_id(frame)} {_stamp(unix_time)} {frame.data.hex().upper()} >".encode()


def bcm_frame(frame: CanFrame, unix_time: float) -> bytes:
    """BCM mode (state_bcm.c): every data byte as ``%02X `` then `` >``."""
    data = "".join(f"{b:02X} " for b in frame.data)
    return f"< frame {_id(frame)} {_stamp(unix_time)} {data} >".encode()


def error_frame(error_class: int, unix_time: float) -> bytes:
    """RAW mode error frame: ``< error CLASS sec.usec >`` (CLASS: linux/can/error.h bits)."""
    return f"< error {error_class:03X} {_stamp(unix_time)} >".encode()
