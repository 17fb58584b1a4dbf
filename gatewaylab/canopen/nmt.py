"""NMT (CiA 301 7.2.8.3; IDX guide 3.3.3.5, tables 3-11 and 3-12): states, codecs, slave table, master.

The slave side is a transition table used by :class:`~gatewaylab.canopen.node.Node`; the master
side (:class:`NmtMaster`) is sans-I/O: it builds frames for a ``send`` callable and is fed received
frames with ``on_frame``, keeping the last state each node reported by heartbeat, guarding or
boot-up.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum, IntEnum

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import LocalError

__all__ = [
    "HEARTBEAT_BASE",
    "NMT_COB_ID",
    "NMT_TRANSITIONS",
    "NmtCommand",
    "NmtMaster",
    "NmtMessage",
    "NmtState",
    "decode_error_control",
    "decode_nmt",
    "encode_guard_response",
    "encode_heartbeat",
    "encode_nmt",
]


NMT_COB_ID = 0x000
HEARTBEAT_BASE = 0x700


class NmtState(Enum):
    """NMT slave states with the code that heartbeat and guarding carry (CiA 301 table 47)."""

    INITIALISING = 0x00   # only seen as the boot-up message
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F

    @property
    def label(self) -> str:
        """The state as CiA 301 writes it ("Pre-operational")."""
        return self.name.replace("_", "-").capitalize()


class NmtCommand(IntEnum):
    """NMT command specifiers (IDX guide table 3-12)."""

    START_REMOTE_NODE = 0x01
    STOP_REMOTE_NODE = 0x02
    ENTER_PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82

    @property
    def label(self) -> str:
        """What the command does, for traces ("start (-> Operational)", "reset node")."""
        if self is NmtCommand.START_REMOTE_NODE:
            return f"start (-> {NmtState.OPERATIONAL.label})"
        if self is NmtCommand.STOP_REMOTE_NODE:
            return f"stop (-> {NmtState.STOPPED.label})"
        if self is NmtCommand.ENTER_PRE_OPERATIONAL:
            return f"enter {NmtState.PRE_OPERATIONAL.label}"
        return self.name.replace("_", " ").lower()


#: Slave transitions of IDX guide table 3-11 / CiA 301 figure 48 that only change the state.
#: Reset node / reset communication are actions (transitions 10..14) handled by the node.
NMT_TRANSITIONS: dict[tuple[NmtState, NmtCommand], NmtState] = {
    (NmtState.PRE_OPERATIONAL, NmtCommand.START_REMOTE_NODE): NmtState.OPERATIONAL,      # 3
    (NmtState.PRE_OPERATIONAL, NmtCommand.STOP_REMOTE_NODE): NmtState.STOPPED,          # 5
    (NmtState.PRE_OPERATIONAL, NmtCommand.ENTER_PRE_OPERATIONAL): NmtState.PRE_OPERATIONAL,
    (NmtState.OPERATIONAL, NmtCommand.ENTER_PRE_OPERATIONAL): NmtState.PRE_OPERATIONAL,  # 4
    (NmtState.OPERATIONAL, NmtCommand.STOP_REMOTE_NODE): NmtState.STOPPED,               # 8
    (NmtState.OPERATIONAL, NmtCommand.START_REMOTE_NODE): NmtState.OPERATIONAL,
    (NmtState.STOPPED, NmtCommand.START_REMOTE_NODE): NmtState.OPERATIONAL,              # 6
    (NmtState.STOPPED, NmtCommand.ENTER_PRE_OPERATIONAL): NmtState.PRE_OPERATIONAL,      # 7
    (NmtState.STOPPED, NmtCommand.STOP_REMOTE_NODE): NmtState.STOPPED,
}

_STATE_BY_CODE = {s.value: s for s in NmtState}


@dataclass(frozen=True, slots=True)
class NmtMessage:
    """A decoded NMT module-control message; ``node_id`` 0 addresses every node."""

    command: NmtCommand
    node_id: int


def encode_nmt(command: NmtCommand, node_id: int = 0) -> CanFrame:
    """The 2-byte NMT frame on COB-ID 0 (IDX guide figure 3-23)."""
    if not 0 <= node_id <= 127:
        raise LocalError(f"NMT node-id {node_id} out of 0..127")
    return CanFrame(NMT_COB_ID, bytes((int(command), node_id)))


def decode_nmt(frame: CanFrame) -> NmtMessage | None:
    """The NMT message in ``frame``, or None when it is not a valid one (then it is ignored)."""
    if frame.can_id != NMT_COB_ID or frame.rtr or frame.extended or len(frame.data) != 2:
        return None
    try:
        command = NmtCommand(frame.data[0])
    except ValueError:
        return None
    node_id = frame.data[1]
    return NmtMessage(command, node_id) if node_id <= 127 else None


def encode_heartbeat(node_id: int, state: NmtState) -> CanFrame:
    """Heartbeat (and with INITIALISING the boot-up message) on 0x700 + node-id."""
    return CanFrame(HEARTBEAT_BASE + node_id, bytes((state.value,)))


def encode_guard_response(node_id: int, state: NmtState, toggle: bool) -> CanFrame:
    """Node-guarding answer: bit 7 toggles, bits 6..0 the state (CiA 301 7.2.8.3.2.1)."""
    return CanFrame(HEARTBEAT_BASE + node_id, bytes(((0x80 if toggle else 0) | state.value,)))


def decode_error_control(frame: CanFrame) -> tuple[int, NmtState, bool] | None:
    """(node-id, state, toggle) from a heartbeat/boot-up/guarding frame, or None."""
    node_id = frame.can_id - HEARTBEAT_BASE
    if not 1 <= node_id <= 127 or frame.rtr or frame.extended or len(frame.data) != 1:
        return None
    state = _STATE_BY_CODE.get(frame.data[0] & 0x7F)
    if state is None:
        return None
    return node_id, state, bool(frame.data[0] & 0x80)


class NmtMaster:
    """Sans-I/O NMT master: module control, heartbeat consumer table and node guarding."""

    def __init__(self, clock: Clock, send: Callable[[CanFrame], None]) -> None:
        self.clock = clock
        self._send = send
        #: Last state each node reported, and when.
        self.states: dict[int, NmtState] = {}
        self.last_seen: dict[int, float] = {}
        self._listeners: list[Callable[[int, NmtState], None]] = []
        self._timeout_listeners: list[Callable[[int], None]] = []
        self._monitors: dict[int, tuple[float, TimerHandle | None]] = {}
        self._guard_toggle: dict[int, bool] = {}
        self._guard_pending: set[int] = set()
        #: Guarding answers whose toggle bit did not alternate.
        self.guard_errors = 0

    def send_command(self, command: NmtCommand, node_id: int = 0) -> None:
        """Send an NMT command to one node (1..127) or to all (0)."""
        self._send(encode_nmt(command, node_id))

    def start(self, node_id: int = 0) -> None:
        """NMT start remote node (0 = all nodes)."""
        self.send_command(NmtCommand.START_REMOTE_NODE, node_id)

    def stop(self, node_id: int = 0) -> None:
        """NMT stop remote node (0 = all nodes)."""
        self.send_command(NmtCommand.STOP_REMOTE_NODE, node_id)

    def enter_pre_operational(self, node_id: int = 0) -> None:
        """NMT enter pre-operational (0 = all nodes)."""
        self.send_command(NmtCommand.ENTER_PRE_OPERATIONAL, node_id)

    def reset_node(self, node_id: int = 0) -> None:
        """NMT reset node (0 = all nodes)."""
        self.send_command(NmtCommand.RESET_NODE, node_id)

    def reset_communication(self, node_id: int = 0) -> None:
        """NMT reset communication (0 = all nodes)."""
        self.send_command(NmtCommand.RESET_COMMUNICATION, node_id)

    def guard(self, node_id: int) -> None:
        """Send a node-guarding remote request to ``node_id``."""
        self._guard_pending.add(node_id)
        self._send(CanFrame(HEARTBEAT_BASE + node_id, b"", rtr=True, dlc=1))

    def add_state_listener(self, callback: Callable[[int, NmtState], None]) -> None:
        """``callback(node_id, state)`` on every boot-up, heartbeat or guarding answer."""
        self._listeners.append(callback)

    def add_timeout_listener(self, callback: Callable[[int], None]) -> None:
        """``callback(node_id)`` when a monitored node's heartbeat stays away too long."""
        self._timeout_listeners.append(callback)

    def monitor(self, node_id: int, timeout: float) -> None:
        """Consume ``node_id``'s heartbeat: report a timeout when none comes within ``timeout`` s."""
        self.unmonitor(node_id)
        self._monitors[node_id] = (timeout, self.clock.call_later(timeout, self._timed_out, node_id))

    def unmonitor(self, node_id: int) -> None:
        """Stop watching the heartbeat of ``node_id``."""
        entry = self._monitors.pop(node_id, None)
        if entry is not None and entry[1] is not None:
            entry[1].cancel()

    def _timed_out(self, node_id: int) -> None:
        timeout, _ = self._monitors.get(node_id, (0.0, None))
        self._monitors[node_id] = (timeout, None)
        for cb in list(self._timeout_listeners):
            cb(node_id)

    def on_frame(self, frame: CanFrame, t: float) -> None:
        """A frame from the bus: heartbeats and boot-ups of the monitored nodes."""
        decoded = decode_error_control(frame)
        if decoded is None:
            return
        node_id, state, toggle = decoded
        if state is NmtState.INITIALISING:
            self._guard_toggle.pop(node_id, None)
        elif node_id in self._guard_pending:
            self._guard_pending.discard(node_id)
            if toggle != self._guard_toggle.get(node_id, False):
                self.guard_errors += 1
            self._guard_toggle[node_id] = not toggle
        self.states[node_id] = state
        self.last_seen[node_id] = t
        mon = self._monitors.get(node_id)
        if mon is not None:
            if mon[1] is not None:
                mon[1].cancel()
            self._monitors[node_id] = (mon[0], self.clock.call_later(mon[0], self._timed_out, node_id))
        for cb in list(self._listeners):
            cb(node_id, state)
