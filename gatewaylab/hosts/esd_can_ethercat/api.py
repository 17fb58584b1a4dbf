"""The esd queue API as a contract: what code written against the esd CAN-EtherCAT
host library calls, and the value types it gets back.

:class:`EsdQueueApi` names the user-facing calls of :class:`~.gateway.EsdHost` (which satisfies it
as it is) so that a second implementation, ``gatewaylab.migrate.esdqueue.EsdQueueOnEcanLite`` (the
same queues over an ECAN-Lite MCAN channel), can be checked against it by mypy and at run time
(``isinstance(host, EsdQueueApi)``). Application code that types its gateway as ``EsdQueueApi``
runs unchanged on either gateway; the remaining differences are listed in
``docs/migration-esd-to-ecanlite.md`` ('The esd queue API on the ECAN-Lite').

Value types: :class:`~.config.EsdConfig` / :class:`~.config.BitRate` / :class:`~.config.FilterArea`
in, :class:`~.config.QueueLayout`, transaction numbers (``int``, 1..FFFFh), :class:`~.handshake.RxFrame`,
:class:`~..codec.CanStatus` and the 0x2010 statistics by the manual's names (5.1.4.2) out. A
statistic an implementation has no source for is ``None`` (the esd gateway has a value for every one).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, Protocol, runtime_checkable

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import Clock
from gatewaylab.devices.esd_can_ethercat.codec import CanStatus
from gatewaylab.hosts.esd_can_ethercat.config import BitRate, EsdConfig, FilterArea, QueueLayout
from gatewaylab.hosts.esd_can_ethercat.handshake import RxFrame

__all__ = ["EsdQueueApi"]


@runtime_checkable
class EsdQueueApi(Protocol):
    """The esd host library's user-facing API (manual 5.1.4.2, 5.1.5; note 'esd-mdp5000-queues').

    Lifecycle: :meth:`configure` (PREOP, with readback) -> :meth:`start` (map, SAFEOP, OP) ->
    :meth:`cycle` every process-data cycle (or let the blocking calls run the cycles) -> :meth:`stop`.
    Sending: :meth:`queue` / :meth:`send` hand out transaction numbers in order; :meth:`accepted`
    (the gateway took the batch), :meth:`completed` (done on the bus; the completed ones are always
    a prefix of the queued ones), :meth:`wait_sent`. Receiving: :meth:`receive` returns
    :class:`RxFrame` values oldest first, each Rx batch acknowledged once read.
    """

    # ---------------------------------------------------------------- state an application reads
    @property
    def clock(self) -> Clock:
        """The backend's clock (simulated or real time); every wait goes through it."""
        ...

    @property
    def cycle_time(self) -> float:
        """Seconds between two cycles the blocking calls run."""
        ...

    @property
    def config(self) -> EsdConfig | None:
        """The configuration written by :meth:`configure` (None before)."""
        ...

    @property
    def layout(self) -> QueueLayout | None:
        """The queue layout :meth:`configure` returned (None before)."""
        ...

    @property
    def wkc_errors(self) -> int:
        """Cycles whose working counter was wrong (their inputs were not used)."""
        ...

    # ---------------------------------------------------------------- lifecycle
    def to_preop(self, timeout: float = ...) -> None:
        """The gateway in PREOP; the queues stop until started again."""
        ...

    def configure(self, config: EsdConfig | None = None, /, **changes: Any) -> QueueLayout:
        """Write the bit rate, queue sizes, 29-bit flag, filter areas and status PDO in PREOP."""
        ...

    def set_bitrate(self, bitrate: BitRate) -> None:
        """Change the bit rate (any state)."""
        ...

    def start(self, timeout: float = ...) -> None:
        """Map, SAFEOP, OP and start the queues."""
        ...

    def stop(self, timeout: float = ...) -> None:
        """Back to PREOP; queued frames stay unsent."""
        ...

    def cycle(self) -> bool:
        """One process-data cycle; False when the working counter was wrong."""
        ...

    def recover(self, timeout: float = ...) -> bool:
        """Back to OP after a fall to SAFEOP; True when it had to."""
        ...

    # ---------------------------------------------------------------- Tx
    def queue(self, frames: Iterable[CanFrame]) -> list[int]:
        """Queue frames in order without waiting; their transaction numbers (TxQueueFull: none queued)."""
        ...

    def send(self, frames: Iterable[CanFrame], timeout: float = ...) -> list[int]:
        """Queue and wait until the gateway accepted every batch; their transaction numbers."""
        ...

    def accepted(self, tn: int) -> bool:
        """The gateway took the frame of transaction ``tn``."""
        ...

    def completed(self, tn: int) -> bool:
        """The gateway is done with transaction ``tn`` and every one before it."""
        ...

    def wait_sent(self, tn: int, timeout: float = ...) -> None:
        """Wait until :meth:`completed` (MasterTimeout when not in time)."""
        ...

    # ---------------------------------------------------------------- Rx
    def receive(self, timeout: float = ..., limit: int | None = ...) -> list[RxFrame]:
        """The frames received so far, oldest first; with a timeout, waits for at least one."""
        ...

    # ---------------------------------------------------------------- status, statistics, readback
    def status(self) -> CanStatus:
        """The CAN status now (0xF108 on the esd)."""
        ...

    def pdo_status(self) -> CanStatus | None:
        """The CAN status the last cycle's process data brought (None without the status PDO)."""
        ...

    def statistics(self) -> Mapping[str, int | None]:
        """0x2010 by the manual's names (5.1.4.2); None where there is no source."""
        ...

    def reset_statistics(self) -> None:
        """Zero the statistics (0x2010:01 on the esd)."""
        ...

    def read_filters(self) -> tuple[FilterArea, ...]:
        """The identifier areas the gateway holds."""
        ...

    def read_bitrate(self) -> tuple[int, int]:
        """(0xF800:02 'Baud rate', 0xF800:05 'API-baud rate') as the gateway holds them."""
        ...
