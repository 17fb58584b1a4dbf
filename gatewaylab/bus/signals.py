"""Signal decoding beyond CANopen: a DBC / KCD / ARXML / SYM database through ``cantools`` (``--db FILE``).

:class:`SignalDecoder` turns a frame whose id the database knows into its message name and signal
values (scaled, with units and value names), what ``cantools decode`` and ``cantools monitor``
show; the bus monitor (``gatewaylab monitor``, the ``--web`` page) and ``gatewaylab plot`` use it.
Loading the file is the only I/O; decoding is pure.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import ConfigError

__all__ = ["DB_SUFFIXES", "DecodedMessage", "SignalDecoder", "load_database"]


#: The database formats cantools reads, by suffix.
DB_SUFFIXES = (".dbc", ".kcd", ".arxml", ".sym", ".xml")


@dataclass(frozen=True, slots=True)
class DecodedMessage:
    """One frame decoded by the database: the message's name and its signals (name -> value, unit);
    or, when the frame does not fit the message (too short, a value outside the layout), no signals
    and ``error`` saying why (cantools' reason)."""

    name: str
    signals: tuple[tuple[str, Any, str], ...]
    error: str = ""

    def text(self) -> str:
        """``EngineData: EngineSpeed=2000 rpm, Temperature=-56 degC`` (cantools decode's content);
        ``EngineData: not decodable (REASON)`` for a frame that does not fit its message."""
        if self.error:
            return f"{self.name}: not decodable ({self.error})"
        parts = []
        for name, value, unit in self.signals:
            shown = f"{value:g}" if isinstance(value, float) else str(value)
            parts.append(f"{name}={shown}" + (f" {unit}" if unit else ""))
        return f"{self.name}: " + ", ".join(parts)

    def numbers(self) -> dict[str, float]:
        """The signals with a numeric value (what ``gatewaylab plot`` draws)."""
        return {name: float(value) for name, value, _ in self.signals
                if isinstance(value, (int, float)) and not isinstance(value, bool)}


class SignalDecoder:
    """A loaded database: ``decode(frame)`` gives the message or None (an id it does not define)."""

    def __init__(self, database: Any, source: str = "") -> None:
        self.database = database
        self.source = source
        self._by_id: dict[tuple[int, bool], Any] = {
            (m.frame_id, bool(m.is_extended_frame)): m for m in database.messages}

    def __len__(self) -> int:
        return len(self._by_id)

    def knows(self, frame: CanFrame) -> bool:
        """True when the database describes this frame's identifier."""
        return (frame.can_id, frame.extended) in self._by_id

    def decode(self, frame: CanFrame) -> DecodedMessage | None:
        """The frame's signals by name (None: an unknown identifier or a remote frame)."""
        message = self._by_id.get((frame.can_id, frame.extended))
        if message is None or frame.rtr:
            return None
        try:
            values = message.decode(frame.data, decode_choices=True, scaling=True)
        except Exception as exc:  # cantools raises its own errors and struct/bitstruct ones on short frames
            return DecodedMessage(message.name, (), error=" ".join(str(exc).split()) or type(exc).__name__)
        units = {s.name: s.unit or "" for s in message.signals}
        return DecodedMessage(message.name, tuple(
            (name, value if isinstance(value, (int, float)) else str(value), units.get(name, ""))
            for name, value in values.items()))


def load_database(path: str | Path) -> SignalDecoder:
    """Read a signal database; a missing or malformed file is a ConfigError naming the file (and
    the line cantools reports)."""
    import cantools

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such signal database (--db wants a .dbc, .kcd, .arxml or .sym file)")
    try:
        database = cantools.database.load_file(str(path), strict=False)
    except (cantools.database.errors.Error, ValueError, KeyError, OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not a signal database cantools reads: {' '.join(str(exc).split())}") from None
    if not hasattr(database, "messages"):
        raise ConfigError(f"{path}: a diagnostics database, not a signal database (no messages)")
    return SignalDecoder(database, str(path))
