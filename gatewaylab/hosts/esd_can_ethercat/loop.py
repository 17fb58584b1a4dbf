"""What every implementation of the esd queue API does around its process-data cycle.

The blocking calls (``send``, ``wait_sent``, ``receive`` with a timeout) run cycles themselves
unless another thread does (``external_cycle``), count wrong working counters, and bring a slave
that fell to SAFEOP (SM watchdog after a stalled master) back to OP. :class:`EsdHost` (counter
handshake) and :class:`~gatewaylab.migrate.esdqueue.EsdQueueOnEcanLite` (MCAN Port) subclass it
and supply :meth:`HostLoop.cycle`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.esc import AlState
from gatewaylab.hosts.ethercat.backend import MasterBackend, MasterTimeout

__all__ = ["DEFAULT_TIMEOUT", "STATE_CHECK_PERIOD", "WKC_RECOVER", "HostLoop"]

#: Seconds a blocking call waits by default.
DEFAULT_TIMEOUT = 5.0
#: Waiting calls look at the AL state after this many bad cycles, and every STATE_CHECK_PERIOD s.
WKC_RECOVER = 10
STATE_CHECK_PERIOD = 0.05


class HostLoop:
    """Cycling, waiting and SAFEOP recovery of one gateway at ``position`` on ``backend``."""

    def __init__(self, backend: MasterBackend, position: int, cycle_time: float, external_cycle: bool) -> None:
        self.backend = backend
        self.position = position
        self.clock: Clock = backend.clock
        self.cycle_time = cycle_time
        #: True when another thread calls :meth:`cycle` every ``cycle_time``: the blocking calls then only wait.
        self.external_cycle = external_cycle
        #: Cycles whose working counter was not the expected one (their inputs were not used).
        self.wkc_errors = 0
        self.cycles = 0
        #: Times :meth:`recover` brought the slave back to OP.
        self.recoveries = 0
        #: AL state reads of the waiting calls that got no answer (tried again later).
        self.lost_state_reads = 0
        self._bad_cycles = 0
        self._state_checked_at = self.clock.now()
        self._lock = threading.RLock()

    def cycle(self) -> bool:
        """One process-data cycle; False when the working counter was wrong."""
        raise NotImplementedError

    def recover(self, timeout: float = DEFAULT_TIMEOUT) -> bool:
        """Back to OP when the slave fell to SAFEOP (the SM watchdog after a stalled master); the
        gateway keeps its state there, so the queues carry on. True when it had to; ConfigError when
        the slave is in INIT/PREOP/BOOT (it lost its mapping: configure() and start() again)."""
        state, code = self.backend.state(self.position)
        if state == AlState.OP:
            return False
        if state != AlState.SAFEOP:
            raise ConfigError(f"slave {self.position} is in {state.name} (AL status code 0x{code:04X}): "
                              "configure() and start() again")
        self.backend.request_state(AlState.OP, self.position, timeout)
        self.recoveries += 1
        self._bad_cycles = 0
        return True

    def _wait_for(self, what: str, done: Callable[[], bool], timeout: float) -> None:
        deadline = self.clock.now() + timeout
        while True:
            with self._lock:
                if done():
                    return
            if self.clock.now() >= deadline:
                state, code = self.backend.state(self.position)
                raise MasterTimeout(f"{what}: not within {timeout:g} s (slave {self.position} in {state.name}, "
                                    f"AL status code 0x{code:04X}, {self.wkc_errors} working counter errors)")
            if not self.external_cycle:
                self.cycle()
                now = self.clock.now()
                if self._bad_cycles >= WKC_RECOVER or now - self._state_checked_at >= STATE_CHECK_PERIOD:
                    self._state_checked_at = now
                    try:
                        self.recover()
                    except MasterTimeout:
                        self.lost_state_reads += 1    # a lost register read: looked at again later
            self.clock.wait(self.cycle_time)
