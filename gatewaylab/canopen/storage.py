"""Store / restore parameters (CiA 301 7.5.2.13-14): 0x1010 'save' and 0x1011 'load'.

Writing the signature "save" (0x65766173) to 0x1010 sub 1 (all), 2 (communication 0x1000-0x1FFF)
or 3 (application 0x6000-0x9FFF) records the present values of the writable entries of that area;
"load" (0x64616F6C) to 0x1011 forgets them, so the defaults come back with the next reset. A
wrong signature is refused with 0x08000020. The records (hex of the wire form per entry) go to
the :class:`~gatewaylab.common.store.ParameterStore` the node is given: a JSON file
(:class:`~gatewaylab.common.store.JsonFileStore`, survives a restart of the emulator) or memory
(survives node resets only). This module never opens a file itself.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from gatewaylab.canopen.communication import LOAD_SIGNATURE, SAVE_SIGNATURE
from gatewaylab.common.errors import ConfigError
from gatewaylab.common.store import MemoryStore, ParameterStore
from gatewaylab.od import Entry, SdoAbort, SdoAbortCode, decode, encode

if TYPE_CHECKING:
    from gatewaylab.canopen.node import Node

__all__ = ["AREAS", "NOT_STORED", "Storage"]


#: 0x1010/0x1011 sub-index -> index ranges it covers.
AREAS: dict[int, tuple[range, ...]] = {
    1: (range(0x1000, 0x10000),),
    2: (range(0x1000, 0x2000),),
    3: (range(0x6000, 0xA000),),
}
#: Never stored: the command objects themselves and the error history.
NOT_STORED = frozenset({0x1003, 0x1010, 0x1011})


class Storage:
    """Non-volatile parameter memory of a :class:`Node`."""

    def __init__(self, node: Node, store: ParameterStore | None = None) -> None:
        self.node = node
        self.store: ParameterStore = store if store is not None else MemoryStore()
        #: "IIIISS" (hex index+subindex) -> hex of the stored wire value
        self.stored: dict[str, str] = {}
        try:
            raw = self.store.load()
            if raw is not None:
                self.stored = {str(k): str(v) for k, v in raw.get("values", {}).items()}
        except (OSError, ValueError, AttributeError) as exc:
            raise ConfigError(f"cannot read stored parameters {self.store!r}: {exc}") from exc
        node.add_command(0x1010, self._save)
        node.add_command(0x1011, self._load)

    @staticmethod
    def _in(index: int, areas: tuple[range, ...]) -> bool:
        return any(index in r for r in areas)

    def _save(self, entry: Entry, value: Any) -> None:
        if value != SAVE_SIGNATURE:
            raise SdoAbort(SdoAbortCode.DATA_CANNOT_BE_STORED, "0x1010 expects the signature 'save'")
        areas = AREAS.get(entry.subindex)
        if areas is None:
            raise SdoAbort(SdoAbortCode.DATA_CANNOT_BE_STORED)
        od = self.node.od
        for key, e in od.entries.items():
            if e.access.writable and key[0] not in NOT_STORED and self._in(key[0], areas):
                self.stored[f"{key[0]:04X}{key[1]:02X}"] = encode(e, od.values[key]).hex()
        self._persist()

    def _load(self, entry: Entry, value: Any) -> None:
        if value != LOAD_SIGNATURE:
            raise SdoAbort(SdoAbortCode.DATA_CANNOT_BE_STORED, "0x1011 expects the signature 'load'")
        areas = AREAS.get(entry.subindex)
        if areas is None:
            raise SdoAbort(SdoAbortCode.DATA_CANNOT_BE_STORED)
        self.stored = {k: v for k, v in self.stored.items() if not self._in(int(k[:4], 16), areas)}
        self._persist()

    def _persist(self) -> None:
        try:
            self.store.save({"format": "gatewaylab-canopen-store/1", "values": self.stored})
        except OSError as exc:
            raise SdoAbort(SdoAbortCode.DATA_CANNOT_BE_STORED, f"{self.store!r}: {exc}") from exc

    def apply(self, area: range) -> None:
        """Load the stored values of ``area`` into the dictionary (at power-on and resets)."""
        od = self.node.od
        for k, hexval in self.stored.items():
            key = (int(k[:4], 16), int(k[4:], 16))
            if key[0] not in area:
                continue
            entry = od.entries.get(key)
            if entry is None or not entry.access.writable:
                continue
            try:
                od.values[key] = decode(entry, bytes.fromhex(hexval))
            except (SdoAbort, ValueError):
                self.node.count("store_errors")
