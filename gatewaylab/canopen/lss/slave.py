"""The CiA 305 LSS slave: a pure state machine (:class:`LssSlaveMachine`) and its Node plug-in (:class:`LssSlave`).

``LssSlaveMachine.on_request(data) -> list[LssAction]`` answers one 0x7E5 request with replies and
what the device must do (adopt a node-ID, switch the bit rate); :class:`LssSlave` binds a machine to
a :class:`~gatewaylab.canopen.node.Node` through ``node.add_frame_listener`` / ``node.send`` and
carries the actions out on the node's controller and clock (IDX guide 3.5, CiA 305 V3.0).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.lss.frames import (
    ACTIVATE_FRAME,
    BIT_TIMING_TABLE,
    FASTSCAN_CONFIRM,
    FASTSCAN_FRAME,
    LSS_MASTER_COB_ID,
    LSS_SLAVE_COB_ID,
    TWO_BYTE_FRAME,
    U32_FRAME,
    UNCONFIGURED,
    Cs,
    LssAddress,
    LssState,
    bit_timing_index,
    encode_cs,
    encode_result,
    encode_u32,
)
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.store import JsonFileStore, ParameterStore

if TYPE_CHECKING:
    from gatewaylab.canopen.node import Node

__all__ = [
    "ALLOWED",
    "ActivateBitTiming",
    "AdoptNodeId",
    "LssAction",
    "LssConfigStore",
    "LssSlave",
    "LssSlaveMachine",
    "LssSlaveStats",
    "Reply",
    "StoreFunction",
]


#: Which state accepts which service (IDX guide table 3-14); commands absent here are ignored.
ALLOWED: dict[int, frozenset[LssState]] = {
    Cs.SWITCH_STATE_GLOBAL: frozenset({LssState.WAITING, LssState.CONFIGURATION}),
    **{cs: frozenset({LssState.WAITING}) for cs in range(0x40, 0x44)},
    **{cs: frozenset({LssState.CONFIGURATION})
       for cs in (0x11, 0x13, 0x15, 0x17, 0x5A, 0x5B, 0x5C, 0x5D, 0x5E)},
    **{cs: frozenset({LssState.WAITING, LssState.CONFIGURATION}) for cs in range(0x46, 0x4D)},
    # Fastscan (CiA 305 V3.0 clause 8.3.5) is served in LSS waiting state only.
    Cs.FASTSCAN: frozenset({LssState.WAITING}),
}


@dataclass(frozen=True, slots=True)
class Reply:
    """Send this 8-byte LSS response on 0x7E4."""

    data: bytes


@dataclass(frozen=True, slots=True)
class AdoptNodeId:
    """Switch to waiting with a new pending node-ID on an unconfigured device: reset communication."""

    node_id: int


@dataclass(frozen=True, slots=True)
class ActivateBitTiming:
    """Stop sending now, switch to ``bitrate`` after ``delay`` s, send again after another ``delay``."""

    bitrate: int
    delay: float


LssAction = Reply | AdoptNodeId | ActivateBitTiming
#: ``store(node_id, bit_timing_index) -> CiA 305 error code`` (0 ok, 1 not supported, 2 media error).
StoreFunction = Callable[[int, int], int]


@dataclass(slots=True)
class LssSlaveStats:
    """Counters of an LSS slave (requests served, ignored)."""
    requests: int = 0
    ignored: int = 0      # not allowed in the current state, or not addressed to us
    malformed: int = 0    # not 8 bytes, unknown cs, bad parameters


class LssSlaveMachine:
    """The CiA 305 LSS slave as a pure state machine: request bytes in, actions out."""

    def __init__(self, address: LssAddress, node_id: int | None, bit_timing_index: int = 0,
                 store: StoreFunction | None = None) -> None:
        self.address = address
        self.state = LssState.WAITING
        self.active_node_id = UNCONFIGURED if node_id is None else node_id
        self.pending_node_id = self.active_node_id
        self.active_bit_timing = bit_timing_index
        self.pending_bit_timing = bit_timing_index
        self.store = store
        self.stats = LssSlaveStats()
        self._selective: dict[int, int] = {}
        self._identify: dict[int, int] = {}
        self._fastscan_pos = 0

    @property
    def configured(self) -> bool:
        """True once the slave has an active node-ID (not 0xFF)."""
        return self.active_node_id != UNCONFIGURED

    def node_reset(self, node_id: int | None) -> None:
        """The node went through reset communication with ``node_id`` active (pending adopted)."""
        self.active_node_id = UNCONFIGURED if node_id is None else node_id
        self.pending_node_id = self.active_node_id

    def on_request(self, data: bytes) -> list[LssAction]:
        """Handle one frame received on 0x7E5; returns the actions to carry out."""
        self.stats.requests += 1
        if len(data) != 8:
            self.stats.malformed += 1
            return []
        cs = data[0]
        allowed = ALLOWED.get(cs)
        if allowed is None:
            self.stats.malformed += 1
            return []
        if self.state not in allowed:
            self.stats.ignored += 1
            return []
        handler: Callable[[int, bytes], list[LssAction]] = getattr(self, _HANDLERS[cs])
        return handler(cs, data)

    # -- services -------------------------------------------------------------------------
    def _switch_global(self, cs: int, data: bytes) -> list[LssAction]:
        mode = data[1]
        if mode > 1:
            self.stats.malformed += 1
            return []
        self._selective.clear()
        if mode == 1:
            self.state = LssState.CONFIGURATION
            return []
        self.state = LssState.WAITING
        self._fastscan_pos = 0
        # CiA 305: leaving configuration with a new pending node-ID on a non-configured device
        # makes the device reset communication with that node-ID.
        if self.active_node_id == UNCONFIGURED and self.pending_node_id != UNCONFIGURED:
            return [AdoptNodeId(self.pending_node_id)]
        return []

    def _switch_selective(self, cs: int, data: bytes) -> list[LssAction]:
        sub = cs - Cs.SWITCH_SELECTIVE_VENDOR
        value = U32_FRAME.unpack(data)[1]
        if sub == 0:
            self._selective.clear()
        elif sub - 1 not in self._selective:
            self._selective.clear()
            return []
        self._selective[sub] = value
        if sub < 3:
            return []
        match = all(self._selective[i] == self.address.part(i) for i in range(4))
        self._selective.clear()
        if not match:
            return []
        self.state = LssState.CONFIGURATION
        return [Reply(encode_cs(Cs.SWITCH_SELECTIVE_RESPONSE))]

    def _configure_node_id(self, cs: int, data: bytes) -> list[LssAction]:
        node_id = data[1]
        if 1 <= node_id <= 127 or node_id == UNCONFIGURED:
            self.pending_node_id = node_id
            return [Reply(encode_result(cs, 0))]
        return [Reply(encode_result(cs, 1))]

    def _configure_bit_timing(self, cs: int, data: bytes) -> list[LssAction]:
        selector, index = data[1], data[2]
        if selector != 0 or index >= len(BIT_TIMING_TABLE) or BIT_TIMING_TABLE[index] is None:
            return [Reply(encode_result(cs, 1))]
        self.pending_bit_timing = index
        return [Reply(encode_result(cs, 0))]

    def _activate_bit_timing(self, cs: int, data: bytes) -> list[LssAction]:
        delay_ms = ACTIVATE_FRAME.unpack(data)[1]
        self.active_bit_timing = self.pending_bit_timing
        bitrate = BIT_TIMING_TABLE[self.active_bit_timing]
        assert bitrate is not None
        return [ActivateBitTiming(bitrate, delay_ms / 1000.0)]

    def _store(self, cs: int, data: bytes) -> list[LssAction]:
        if self.store is None:
            return [Reply(encode_result(cs, 1))]
        code = self.store(self.pending_node_id, self.pending_bit_timing)
        return [Reply(encode_result(cs, code))]

    def _inquire(self, cs: int, data: bytes) -> list[LssAction]:
        return [Reply(encode_u32(cs, self.address.part(cs - Cs.INQUIRE_VENDOR)))]

    def _inquire_node_id(self, cs: int, data: bytes) -> list[LssAction]:
        return [Reply(TWO_BYTE_FRAME.pack(cs, self.active_node_id, 0))]

    def _identify_remote(self, cs: int, data: bytes) -> list[LssAction]:
        step = cs - Cs.IDENTIFY_VENDOR
        value = U32_FRAME.unpack(data)[1]
        if step == 0:
            self._identify.clear()
        elif step - 1 not in self._identify:
            self._identify.clear()
            return []
        self._identify[step] = value
        if step < 5:
            return []
        ident, a = self._identify, self.address
        self._identify = {}
        if (ident[0] == a.vendor_id and ident[1] == a.product_code
                and ident[2] <= a.revision <= ident[3] and ident[4] <= a.serial <= ident[5]):
            return [Reply(encode_cs(Cs.IDENTIFY_SLAVE))]
        return []

    def _identify_non_configured(self, cs: int, data: bytes) -> list[LssAction]:
        if self.active_node_id == UNCONFIGURED and self.pending_node_id == UNCONFIGURED:
            return [Reply(encode_cs(Cs.IDENTIFY_NON_CONFIGURED_SLAVE))]
        return []

    def _fastscan(self, cs: int, data: bytes) -> list[LssAction]:
        # CiA 305 V3.0 clause 8.3.5: only non-configured slaves take part.
        if self.active_node_id != UNCONFIGURED or self.pending_node_id != UNCONFIGURED:
            return []
        _, id_number, bit_checked, lss_sub, lss_next = FASTSCAN_FRAME.unpack(data)
        if (bit_checked > 31 and bit_checked != FASTSCAN_CONFIRM) or lss_sub > 3 or lss_next > 3:
            self.stats.malformed += 1
            return []
        if bit_checked == FASTSCAN_CONFIRM:
            self._fastscan_pos = 0
            return [Reply(encode_cs(Cs.IDENTIFY_SLAVE))]
        if lss_sub != self._fastscan_pos:
            return []
        mask = (0xFFFFFFFF << bit_checked) & 0xFFFFFFFF
        if (self.address.part(lss_sub) ^ id_number) & mask:
            return []
        self._fastscan_pos = lss_next
        if bit_checked == 0 and lss_next < lss_sub:
            self.state = LssState.CONFIGURATION
        return [Reply(encode_cs(Cs.IDENTIFY_SLAVE))]


#: cs -> LssSlaveMachine method serving it.
_HANDLERS: dict[int, str] = {
    Cs.SWITCH_STATE_GLOBAL: "_switch_global",
    **{cs: "_switch_selective" for cs in range(0x40, 0x44)},
    Cs.CONFIGURE_NODE_ID: "_configure_node_id",
    Cs.CONFIGURE_BIT_TIMING: "_configure_bit_timing",
    Cs.ACTIVATE_BIT_TIMING: "_activate_bit_timing",
    Cs.STORE_CONFIGURATION: "_store",
    **{cs: "_inquire" for cs in range(0x5A, 0x5E)},
    Cs.INQUIRE_NODE_ID: "_inquire_node_id",
    **{cs: "_identify_remote" for cs in range(0x46, 0x4C)},
    Cs.IDENTIFY_NON_CONFIGURED: "_identify_non_configured",
    Cs.FASTSCAN: "_fastscan",
}


class LssConfigStore:
    """The LSS 'non-volatile memory': node-ID and bit timing index in a :class:`ParameterStore`
    (a JSON file when given a path)."""

    def __init__(self, store: ParameterStore | Path) -> None:
        self.store: ParameterStore = JsonFileStore(store) if isinstance(store, Path) else store

    def load(self) -> tuple[int, int] | None:
        """(node_id, bit_timing_index) stored earlier, or None."""
        try:
            raw = self.store.load()
            if raw is None:
                return None
            return int(raw["node_id"]), int(raw["bit_timing"])
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def save(self, node_id: int, bit_timing: int) -> int:
        """Store; returns the CiA 305 error code (0 ok, 2 storage media access error)."""
        try:
            self.store.save({"node_id": node_id, "bit_timing": bit_timing})
        except OSError:
            return 2
        return 0


class LssSlave:
    """An LSS slave plugged into a :class:`Node` (frames via ``add_frame_listener`` / ``send``).

    The IDX guide 3.5 makes LSS "only accessible in NMT slave state Stopped"; a device without a
    node-ID takes no part in NMT and serves LSS at once (CiA 305). ``nmt_gate=False`` lifts the
    Stopped condition for devices that follow plain CiA 305.
    """

    def __init__(self, node: Node, address: LssAddress, *, store: LssConfigStore | None = None,
                 nmt_gate: bool = True) -> None:
        self.node = node
        self.clock: Clock = node.clock
        self.config_store = store
        self.nmt_gate = nmt_gate
        rate = node.controller.bitrate
        index = bit_timing_index(rate) if rate in BIT_TIMING_TABLE else 0
        self.machine = LssSlaveMachine(address, node.node_id, index,
                                       store.save if store is not None else None)
        self._timers: list[TimerHandle] = []
        node.add_frame_listener(self._on_frame, can_id=LSS_MASTER_COB_ID)
        node.on_reset(self._on_node_reset)

    @property
    def state(self) -> LssState:
        """The CiA 305 state (waiting / configuration)."""
        return self.machine.state

    def _serving(self) -> bool:
        if not self.nmt_gate or self.node.node_id is None:
            return True
        return self.node.nmt_state is NmtState.STOPPED

    def _on_frame(self, frame: CanFrame, t: float) -> None:
        if frame.can_id != LSS_MASTER_COB_ID or frame.extended or frame.rtr or frame.fd:
            return
        machine = self.machine
        # keep the machine's idea of the node-ID in step with NMT resets done elsewhere
        active = UNCONFIGURED if self.node.node_id is None else self.node.node_id
        if active != machine.active_node_id:
            machine.node_reset(self.node.node_id)
        if not self._serving():
            machine.stats.ignored += 1
            return
        for action in machine.on_request(frame.data):
            if isinstance(action, Reply):
                self.node.send(CanFrame(LSS_SLAVE_COB_ID, action.data))
            elif isinstance(action, AdoptNodeId):
                self.apply_node_id(action.node_id)
            else:
                self._activate_bit_timing(action)

    def apply_node_id(self, node_id: int) -> None:
        """Make ``node_id`` active through the node's reset-communication path (CiA 305)."""
        new = None if node_id == UNCONFIGURED else node_id
        self.node.node_id = new
        self.node.reset_communication()
        self.machine.node_reset(new)

    def _on_node_reset(self, reset_node: bool) -> None:
        self.on_reset_communication()

    def on_reset_communication(self) -> None:
        """NMT reset communication/node runs: the pending node-ID becomes active (CiA 305)."""
        pending = self.machine.pending_node_id
        if pending != self.machine.active_node_id:
            self.node.node_id = None if pending == UNCONFIGURED else pending
            self.machine.node_reset(self.node.node_id)

    def _activate_bit_timing(self, action: ActivateBitTiming) -> None:
        ctrl = self.node.controller
        bus = ctrl.bus
        # stop communication on the old bit rate at once (CiA 305 switch delay, IDX fig. 3-30)
        bus.disconnect(ctrl)
        ctrl.flush_tx()
        for timer in self._timers:
            timer.cancel()

        def switch() -> None:
            ctrl.bitrate = action.bitrate

        def resume() -> None:
            bus.reconnect(ctrl)

        self._timers = [self.clock.call_later(action.delay, switch),
                        self.clock.call_later(2 * action.delay, resume)]

    def stop(self) -> None:
        """Cancel the pending bit-timing switch timers (the node stops)."""
        for timer in self._timers:
            timer.cancel()
        self._timers = []
