"""EtherCAT faults of frames, working counters and the master's link: ``ec-lose``, ``ec-corrupt``, ``ec-delay``,
``ec-duplicate``, ``ec-reorder``, ``ec-wkc``, ``ec-outputs-off``, ``ec-link-down`` (docs/faults.md "EtherCAT faults").

The mechanism is the segment's :class:`~gatewaylab.ethercat.line_faults.LineFaults` (sans-I/O, served by the
wire and by the in-process master); this module arms a :class:`~gatewaylab.ethercat.line_faults.LineFault`
per request and puts it on the board, which it leaves when its count is used up, its time is over or on
``ec-clear``. ``ec-outputs-off`` is a slave's own doing instead: its firmware deactivates the output
SyncManager from the PDI side (0x0807 bit 0), as on a local exit from OP.
"""

from __future__ import annotations

import math
from typing import Any

from gatewaylab.ethercat.errors import EtherCATConfigError
from gatewaylab.ethercat.line_faults import ANY_DATAGRAM, Kind, LineFault, LineFaults, Match, parse_command
from gatewaylab.ethercat.segment import Segment
from gatewaylab.rig.faults_core import FaultRefused, FaultsCore, check_count, check_seconds

__all__ = ["EC_FRAMES_REQUESTS", "EcFramesFaults", "parse_logical"]

#: the target the board shows for a fault of the whole line
LINE = "segment"
#: the longest delay ``ec-delay`` takes (a reply held a second is a lost frame to every master)
MAX_DELAY_US = 1_000_000.0


def parse_logical(value: str | tuple[int, int] | list[int]) -> tuple[int, int]:
    """A logical address range ``"START:END"`` (END included, numbers decimal or 0x-hex) or a pair."""
    try:
        if isinstance(value, str):
            start_text, end_text = value.split(":")
            start, end = int(start_text, 0), int(end_text, 0)
        else:
            start, end = int(value[0]), int(value[1])
    except (ValueError, IndexError, TypeError):
        raise FaultRefused(f"logical range {value!r}: START:END, e.g. 0x10000:0x1007F") from None
    if not 0 <= start <= end <= 0xFFFFFFFF:
        raise FaultRefused(f"logical range {value!r}: need 0 <= START <= END <= 0xFFFFFFFF")
    return start, end


def _commands(cmd: str | int | list[str | int] | None) -> frozenset[int] | None:
    if cmd is None:
        return None
    items: list[str | int] = (list(cmd.split(",")) if isinstance(cmd, str) else [cmd] if isinstance(cmd, int)
                              else list(cmd))
    try:
        return frozenset(parse_command(c) for c in items)
    except EtherCATConfigError as exc:
        raise FaultRefused(str(exc)) from None


def _match(cmd: str | int | list[str | int] | None = None, station: int | None = None,
           logical: str | tuple[int, int] | list[int] | None = None) -> Match:
    if station is not None and not 0 <= station <= 0xFFFF:
        raise FaultRefused(f"station address {station} is not 0..0xFFFF")
    return Match(_commands(cmd), station, None if logical is None else parse_logical(logical))


class EcFramesFaults(FaultsCore):
    """Frames lost, corrupted, delayed, duplicated, reordered; working counters offset; outputs not counted;
    the master's link down."""

    def _line(self, segment: Segment) -> LineFaults:
        """The segment's line faults (created with the first one armed)."""
        if segment.line_faults is None:
            segment.line_faults = LineFaults()
        return segment.line_faults

    def _arm(self, verb: str, kind: Kind, details: dict[str, Any], count: int | None = None,
             seconds: float | None = None, match: Match = ANY_DATAGRAM, **kw: Any) -> dict[str, Any]:
        """Arm one line fault and put it on the board (under ``clock.lock``); the answer."""
        def act() -> dict[str, Any]:
            line = self._line(self.segment())
            shown = {**details, **match.describe()}
            fault = LineFault(kind, match, count, details=shown, **kw)
            entry = self.activate(verb, LINE, shown, lambda: line.remove(fault), seconds)
            ident = entry.ident
            fault.on_end = lambda: self.finish(ident)
            line.add(fault)
            return {"fault": verb, "id": ident, **entry.as_json()}
        return self.locked(act)

    def ec_lose(self, count: int = 1, replies: bool = False, cmd: str | int | list[str | int] | None = None,
                station: int | None = None, logical: str | tuple[int, int] | list[int] | None = None) -> dict[str, Any]:
        """Lose the next ``count`` frames with a matching datagram: on their way to the segment (nothing
        processed), or with ``replies`` on their way back (processed, the master sees no reply)."""
        check_count("count", count)
        return self._arm("ec-lose", Kind.LOSE_REPLY if replies else Kind.LOSE, {"replies": replies}, count,
                         match=_match(cmd, station, logical))

    def ec_corrupt(self, count: int = 1) -> dict[str, Any]:
        """The next ``count`` replies come back with a bad FCS: processed by the slaves, discarded by the
        master's NIC (a lost frame to the master)."""
        check_count("count", count)
        return self._arm("ec-corrupt", Kind.CORRUPT, {}, count)

    def ec_delay(self, us: float, jitter: float = 0.0, seconds: float | None = None, seed: int = 1) -> dict[str, Any]:
        """Every reply leaves ``us`` microseconds (+ uniform jitter up to ``jitter`` us, from a generator seeded
        with ``seed``) late, for ``seconds`` (None: until ``ec-clear``)."""
        for what, value in (("us", us), ("jitter", jitter)):
            if not math.isfinite(value) or not 0 <= value <= MAX_DELAY_US:
                raise FaultRefused(f"{what} must be 0..{MAX_DELAY_US:g} microseconds, got {value}")
        if seconds is not None:
            check_seconds("seconds", seconds)
        return self._arm("ec-delay", Kind.DELAY, {"us": us, "jitter": jitter, "seed": seed}, seconds=seconds,
                         delay_s=us / 1e6, jitter_s=jitter / 1e6, seed=seed)

    def ec_duplicate(self, count: int = 1) -> dict[str, Any]:
        """The next ``count`` replies arrive twice (a switch in the path that floods a frame twice)."""
        check_count("count", count)
        return self._arm("ec-duplicate", Kind.DUPLICATE, {}, count)

    def ec_reorder(self, count: int = 1) -> dict[str, Any]:
        """The next ``count`` replies are each held back and arrive after the reply that follows them."""
        check_count("count", count)
        return self._arm("ec-reorder", Kind.REORDER, {}, count)

    def ec_wkc(self, offset: int, count: int = 1, cmd: str | int | list[str | int] | None = None,
               logical: str | tuple[int, int] | list[int] | None = None) -> dict[str, Any]:
        """Add ``offset`` (modulo 2^16) to the working counter of the next ``count`` matching datagrams."""
        check_count("count", count)
        if offset == 0 or not -0xFFFF <= offset <= 0xFFFF:
            raise FaultRefused(f"offset must be a non-zero number in -65535..65535, got {offset}")
        return self._arm("ec-wkc", Kind.WKC, {"offset": offset}, count, match=_match(cmd, None, logical),
                         offset=offset)

    def ec_link_down(self, seconds: float) -> dict[str, Any]:
        """The master's link is down for ``seconds``: no frame reaches the segment, none comes back."""
        check_seconds("seconds", seconds)
        return self._arm("ec-link-down", Kind.LINK_DOWN, {}, seconds=seconds)

    def ec_outputs_off(self, device: str, seconds: float | None = None) -> dict[str, Any]:
        """``device``'s firmware deactivates its output SyncManager (0x0807 bit 0, PDI side): the master's
        output writes are refused and stop counting in the working counter, for ``seconds`` (None: until
        ``ec-clear`` or the master takes the slave through a state change)."""
        if seconds is not None:
            check_seconds("seconds", seconds)

        def act() -> dict[str, Any]:
            segment, position = self.ethercat_position(device)
            memory = segment.slaves[position].esc.memory
            if not 0 <= memory.output_sm < memory.n_sm:
                raise FaultRefused(f"{device} has no output SyncManager")
            if not memory.stop_outputs():
                raise FaultRefused(f"{device}'s output SyncManager is deactivated already")
            sm = memory.output_sm
            entry = self.activate("ec-outputs-off", device, {"sm": sm}, memory.start_outputs, seconds)
            return {"fault": "ec-outputs-off", "id": entry.ident, **entry.as_json()}
        return self.locked(act)


_R, _O = True, False
_FILTERS: dict[str, tuple[str, bool]] = {"cmd": ("int|string", _O), "logical": ("string", _O)}

#: fault name -> (method, {argument: (JSON type, required)}), as ``REQUESTS`` in rig/faults.py
EC_FRAMES_REQUESTS: dict[str, tuple[str, dict[str, tuple[str, bool]]]] = {
    "ec-lose": ("ec_lose", {"count": ("int", _O), "replies": ("bool", _O), "station": ("int", _O), **_FILTERS}),
    "ec-corrupt": ("ec_corrupt", {"count": ("int", _O)}),
    "ec-delay": ("ec_delay", {"us": ("number", _R), "jitter": ("number", _O), "seconds": ("number", _O),
                              "seed": ("int", _O)}),
    "ec-duplicate": ("ec_duplicate", {"count": ("int", _O)}),
    "ec-reorder": ("ec_reorder", {"count": ("int", _O)}),
    "ec-wkc": ("ec_wkc", {"offset": ("int", _R), "count": ("int", _O), **_FILTERS}),
    "ec-link-down": ("ec_link_down", {"seconds": ("number", _R)}),
    "ec-outputs-off": ("ec_outputs_off", {"device": ("string", _R), "seconds": ("number", _O)}),
}
