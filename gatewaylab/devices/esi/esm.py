"""The ESI's AL state machine timeouts (ETG.2000 ``<Info><StateMachine><Timeout>``) on an emulated slave.

The timeouts are the times a master waits for a transition; a slave stack that cannot finish a transition
gives it up before the master does. Beckhoff's slave stack (SSC ``ecatslv.c``, ``AL_ControlInd`` /
``AL_ControlRes``) keeps a pending transition's AL status at the present state and, when its ESM timeout runs
out, refuses it with the error flag: the timeout is PreopTimeout for INIT->PREOP and INIT->BOOT,
SafeopOpTimeout for PREOP->SAFEOP and SAFEOP->OP, less 10 % "to react before the master runs into a
timeout"; the code is 0x0001 (unspecified) for the first three, 0x001B (SM watchdog) for SAFEOP->OP without
DC synchronisation, 0x0032 (DC PLL sync error) with it once outputs have arrived.

An emulated slave finishes every transition at once unless the rig says the application is slow
(``transition_ms``): then the transition is pending for that long, and refused as above when that is longer
than the ESI allows. Downward transitions are always done at once (BackToInitTimeout and
BackToSafeopTimeout are therefore always met).
"""

from __future__ import annotations

from collections.abc import Mapping

from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.errors import AlStatusCode
from gatewaylab.ethercat.esc_al import AL_PENDING
from gatewaylab.ethercat.esc_registers import AlState
from gatewaylab.ethercat.slave import Slave

__all__ = ["DC_PLL_SYNC_ERROR", "ESM_DEFAULTS_MS", "SLOW_TRANSITIONS", "EsmTimer", "parse_transition_ms"]

#: ETG.1000.6 AL status code 0x0032 "PLL Error" (SSC's ALSTATUSCODE_DCPLLSYNCERROR)
DC_PLL_SYNC_ERROR = 0x0032
#: when the ESI gives none: the SSC's own defaults (PREOPTIMEOUT, SAFEOP2OPTIMEOUT, BACKTOINITTIMEOUT,
#: BACKTOSAFEOPTIMEOUT), which its tool also writes into the ESIs it generates
ESM_DEFAULTS_MS = {"PreopTimeout": 2000, "SafeopOpTimeout": 9000, "BackToInitTimeout": 5000,
                   "BackToSafeopTimeout": 200}
#: the transitions ``transition_ms`` may slow down, and the ESI timeout that bounds each
SLOW_TRANSITIONS: dict[str, tuple[AlState, AlState, str]] = {
    "INIT_PREOP": (AlState.INIT, AlState.PREOP, "PreopTimeout"),
    "INIT_BOOT": (AlState.INIT, AlState.BOOT, "PreopTimeout"),
    "PREOP_SAFEOP": (AlState.PREOP, AlState.SAFEOP, "SafeopOpTimeout"),
    "SAFEOP_OP": (AlState.SAFEOP, AlState.OP, "SafeopOpTimeout"),
}


def parse_transition_ms(table: Mapping[str, object], where: str) -> dict[tuple[AlState, AlState], float]:
    """``transition_ms = { PREOP_SAFEOP = 150, ... }``: the application's time per transition, in seconds."""
    out: dict[tuple[AlState, AlState], float] = {}
    for key, value in table.items():
        if key not in SLOW_TRANSITIONS:
            raise ConfigError(f"{where}: transition_ms: {key!r} is not one of {', '.join(SLOW_TRANSITIONS)}")
        if isinstance(value, bool) or not isinstance(value, int | float) or value < 0:
            raise ConfigError(f"{where}: transition_ms.{key}: {value!r} is not a number of milliseconds >= 0")
        old, new, _ = SLOW_TRANSITIONS[key]
        out[(old, new)] = float(value) / 1000.0
    return out


class EsmTimer:
    """One slave's pending transition: completed after the application's time, or refused when the ESI's
    timeout (less 10 %) runs out first."""

    def __init__(self, timeouts_ms: Mapping[str, int], delays: Mapping[tuple[AlState, AlState], float]) -> None:
        self.timeouts_ms = {**ESM_DEFAULTS_MS, **timeouts_ms}
        self.delays = dict(delays)
        self.pending: tuple[AlState, AlState] | None = None
        self._timer: TimerHandle | None = None
        #: (transition, AL status code) of each transition given up, in order
        self.refused: list[tuple[tuple[AlState, AlState], int]] = []

    def limit(self, old: AlState, new: AlState) -> float:
        """The slave's own limit for an upward transition, in seconds (the ESI timeout less 10 %)."""
        name = next(n for o, w, n in SLOW_TRANSITIONS.values() if (o, w) == (old, new))
        ms = self.timeouts_ms[name]
        return (ms - ms // 10) / 1000.0

    def cancel(self) -> None:
        """Forget a pending transition (the master asked for another state)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self.pending = None

    def on_transition(self, clock: Clock, slave: Slave, old: AlState, new: AlState) -> int:
        """0 to do the transition now, else :data:`AL_PENDING` (a timer completes or refuses it)."""
        key = (old, new)
        if self.pending == key:
            return AL_PENDING           # the master repeated its request: still in work
        self.cancel()
        delay = self.delays.get(key, 0.0)
        if delay <= 0.0:
            return 0
        limit = self.limit(old, new)
        self.pending = key
        if delay <= limit:
            self._timer = clock.call_later(delay, self._complete, slave, new)
        else:
            self._timer = clock.call_later(limit, self._give_up, slave, key)
        return AL_PENDING

    def _complete(self, slave: Slave, new: AlState) -> None:
        self._timer = None
        self.pending = None
        slave.esc.al.complete(new)

    def _give_up(self, slave: Slave, key: tuple[AlState, AlState]) -> None:
        self._timer = None
        self.pending = None
        code = int(AlStatusCode.UNSPECIFIED)
        if key == (AlState.SAFEOP, AlState.OP):
            dc = slave.esc.sync0_active
            code = DC_PLL_SYNC_ERROR if dc and slave.outputs_valid else int(AlStatusCode.SM_WATCHDOG)
        self.refused.append((key, code))
        slave.esc.al.refuse(code)
