"""EtherCAT faults of distributed clocks: a slave's local clock drifts by N ppm, or jumps by an offset (the
mechanism: :mod:`gatewaylab.ethercat.esc_dc_clock`, the ESC's time control loop fed by drift compensation).

``ec-dc-drift`` stays on the fault board until ``ec-clear`` (the crystal is good again: 0 ppm; a drift fault on a
device that has one replaces it). ``ec-dc-jump`` happens once and is not on the board: a jump cannot be undone,
the slave's control loop slews it out at its limit rate, and a master that re-initialises DC (new offsets in
0x0920, as SOEM ``ec_configdc`` writes) removes it at once.
"""

from __future__ import annotations

import math
from typing import Any

from gatewaylab.ethercat.esc_dc_clock import LOOP_LIMIT_PPM
from gatewaylab.rig.faults_core import FaultRefused, FaultsCore

__all__ = ["EC_DC_REQUESTS", "MAX_DRIFT_PPM", "EcDcFaults"]

#: The largest drift a fault may give a clock (10 %: far beyond any crystal, well short of a stopped clock).
MAX_DRIFT_PPM = 100_000.0


class EcDcFaults(FaultsCore):
    """``ec-dc-drift`` and ``ec-dc-jump``."""

    def ec_dc_drift(self, device: str, ppm: float) -> dict[str, Any]:
        """From now on ``device``'s local clock runs ``ppm`` fast (negative: slow) until ``ec-clear``: within the
        control loop's limit a master's drift compensation keeps 0x092C small, beyond it 0x092C grows."""
        if not math.isfinite(ppm) or abs(ppm) > MAX_DRIFT_PPM:
            raise FaultRefused(f"ppm must be a finite number within +-{MAX_DRIFT_PPM:g}, got {ppm}")
        def act() -> dict[str, Any]:
            segment, position = self.ethercat_position(device)
            for e in self.board.entries():
                if e.fault == "ec-dc-drift" and e.target == device:
                    self.board.end(e.ident)
            local = segment.slaves[position].esc.clocks.local
            local.set_drift(float(ppm))
            def undo() -> None:
                local.set_drift(0.0)
            entry = self.activate("ec-dc-drift", device, {"ppm": ppm}, undo)
            return {"fault": "ec-dc-drift", "id": entry.ident, "device": device, "position": position, "ppm": ppm,
                    "loop_limit_ppm": LOOP_LIMIT_PPM}
        return self.locked(act)

    def ec_dc_jump(self, device: str, ns: int) -> dict[str, Any]:
        """``device``'s local time jumps by ``ns`` (once): its system time is off by that much until the control
        loop slews it out or the master re-initialises DC."""
        if abs(ns) >= 1 << 62:
            raise FaultRefused(f"ns must be within +-2**62, got {ns}")
        def act() -> dict[str, Any]:
            segment, position = self.ethercat_position(device)
            esc = segment.slaves[position].esc
            esc.clocks.local.jump(float(ns))
            return {"fault": "ec-dc-jump", "device": device, "position": position, "ns": ns,
                    "system_time": esc.system_time_ns()}
        return self.locked(act)


_R = True

#: fault name -> (method, {argument: (JSON type, required)}), the format of ``faults.REQUESTS``
EC_DC_REQUESTS: dict[str, tuple[str, dict[str, tuple[str, bool]]]] = {
    "ec-dc-drift": ("ec_dc_drift", {"device": ("string", _R), "ppm": ("number", _R)}),
    "ec-dc-jump": ("ec_dc_jump", {"device": ("string", _R), "ns": ("int", _R)}),
}
