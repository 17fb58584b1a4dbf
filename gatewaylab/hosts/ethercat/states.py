"""AL state walks over any :class:`~gatewaylab.hosts.ethercat.backend.MasterBackend`: the legal ESM
steps between two states and a walk along them, for host libraries and the ``gatewaylab ec`` verbs."""

from __future__ import annotations

from gatewaylab.ethercat.esc import AlState
from gatewaylab.hosts.ethercat.backend import MasterBackend

__all__ = ["state_path", "walk_to"]


_ORDER = (AlState.INIT, AlState.PREOP, AlState.SAFEOP, AlState.OP)


def state_path(current: AlState, target: AlState) -> list[AlState]:
    """The legal ESM steps from ``current`` to ``target`` (ETG.1000.6 table 'state transitions'):
    upwards one state at a time, downwards directly, BOOT only from and to INIT; as IgH's master walks."""
    if target == current:
        return [target]
    if target == AlState.BOOT or current == AlState.BOOT:
        return ([AlState.INIT] if current != AlState.INIT else []) + ([target] if target != AlState.INIT else [])
    if _ORDER.index(target) < _ORDER.index(current):
        return [target]
    return list(_ORDER[_ORDER.index(current) + 1:_ORDER.index(target) + 1])


def walk_to(backend: MasterBackend, position: int, target: AlState, timeout: float = 5.0) -> None:
    """Request each step of :func:`state_path` from the slave's state to ``target``; nothing when it is
    there already (e.g. PREOP for configuration: from BOOT through INIT, from SAFEOP/OP directly)."""
    current, _code = backend.state(position)
    if current == target:
        return
    for step in state_path(current, target):
        backend.request_state(step, position, timeout)
