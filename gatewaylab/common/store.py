"""Non-volatile memory for devices: a small key-value store object, file-backed by default.

Protocol code (CANopen store/restore 0x1010/0x1011, LSS 'store configuration') keeps what a real
device writes to its flash in a :class:`ParameterStore` it is given, instead of opening files
itself: :class:`JsonFileStore` survives a restart of the emulator, :class:`MemoryStore` lives
as long as the process (tests, throw-away rigs).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Protocol

from gatewaylab.common.errors import ConfigError

__all__ = ["JsonFileStore", "MemoryStore", "ParameterStore", "StoreError"]


class StoreError(ConfigError, ValueError):
    """A store file that holds something else than what a device stored (its callers also catch ValueError)."""


class ParameterStore(Protocol):
    """Where a device keeps its non-volatile data (one JSON-compatible dict)."""

    def load(self) -> dict[str, Any] | None:
        """The stored dict, None when nothing was stored; OSError/ValueError when unreadable."""

    def save(self, data: dict[str, Any]) -> None:
        """Replace the stored dict; OSError when the medium fails."""


class MemoryStore:
    """A store that lives as long as the object (no file)."""

    def __init__(self, data: dict[str, Any] | None = None) -> None:
        self.data = json.loads(json.dumps(data)) if data is not None else None

    def load(self) -> dict[str, Any] | None:
        """A copy of what was saved."""
        return json.loads(json.dumps(self.data)) if self.data is not None else None

    def save(self, data: dict[str, Any]) -> None:
        """Keep a copy (so later changes of ``data`` are not stored by accident)."""
        self.data = json.loads(json.dumps(data))


class JsonFileStore:
    """A store in one JSON file, replaced atomically on every save."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)

    def load(self) -> dict[str, Any] | None:
        """The file's dict, None when the file does not exist."""
        if not self.path.exists():
            return None
        raw = json.loads(self.path.read_text())
        if not isinstance(raw, dict):
            raise StoreError(f"{self.path}: not a JSON object")
        return raw

    def save(self, data: dict[str, Any]) -> None:
        """Write a temporary file next to the target and rename it over the target."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(self.path.suffix + ".tmp")
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True))
        os.replace(tmp, self.path)

    def __repr__(self) -> str:
        return f"JsonFileStore({str(self.path)!r})"
