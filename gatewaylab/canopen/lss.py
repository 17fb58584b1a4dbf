"""CiA 305 Layer Setting Services: the slave state machine, its Node plug-in, and a master.

The IDX guide chapter 3.5 (table 3-14) lists the services; their frames follow CiA 305 V3.0:
every LSS frame is 8 bytes, the master sends on COB-ID 0x7E5, slaves answer on 0x7E4, byte 0 is
the command specifier (cs), numbers are little-endian, unused bytes are 0.

Three layers, so that the protocol stays sans-I/O:

* :class:`LssSlaveMachine` -- pure: ``on_request(data) -> list[LssAction]`` (replies and what the
  device must do: adopt a node-ID, switch the bit rate).
* :class:`LssSlave` -- binds a machine to a :class:`~gatewaylab.canopen.node.Node` through
  ``node.add_frame_listener`` / ``node.send``, applies actions on the node's controller and clock.
* :class:`LssMaster` -- sans-I/O master: ``LssMaster(clock, send)``, fed with ``on_frame``; every
  service takes a callback. Multi-step services (selective switch, identify, Fastscan) run as
  generators that yield one request at a time.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable, Generator
from dataclasses import dataclass
from enum import Enum, IntEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import LocalError, RemoteError, TimeoutError_
from gatewaylab.common.store import JsonFileStore, ParameterStore

if TYPE_CHECKING:
    from gatewaylab.canopen.node import Node

#: COB-ID of LSS master requests (IDX guide 3.5).
LSS_MASTER_COB_ID = 0x7E5
#: COB-ID of LSS slave responses (IDX guide 3.5).
LSS_SLAVE_COB_ID = 0x7E4
#: Node-ID value of a non-configured device (IDX guide 3.5).
UNCONFIGURED = 0xFF

#: CiA 305 standard bit timing table (table selector 0): index -> bit rate; None = reserved.
#: Index 9 (automatic bit rate detection) is not supported by the emulated controller.
BIT_TIMING_TABLE: tuple[int | None, ...] = (
    1_000_000, 800_000, 500_000, 250_000, 125_000, None, 50_000, 20_000, 10_000)

_CS_U32 = struct.Struct("<BI3x")      # cs + 32-bit value (identity, fastscan IDNumber part)
_FASTSCAN = struct.Struct("<BIBBB")    # cs, IDNumber, BitChecked, LSSSub, LSSNext
_ACTIVATE = struct.Struct("<BH5x")     # cs, switch delay (ms)
_CS_B_B = struct.Struct("<BBB5x")      # cs + two bytes (error code + specific, selector + index)


class Cs(IntEnum):
    """LSS command specifiers (IDX guide table 3-14, CiA 305 V3.0)."""

    SWITCH_STATE_GLOBAL = 0x04
    CONFIGURE_NODE_ID = 0x11
    CONFIGURE_BIT_TIMING = 0x13
    ACTIVATE_BIT_TIMING = 0x15
    STORE_CONFIGURATION = 0x17
    SWITCH_SELECTIVE_VENDOR = 0x40
    SWITCH_SELECTIVE_PRODUCT = 0x41
    SWITCH_SELECTIVE_REVISION = 0x42
    SWITCH_SELECTIVE_SERIAL = 0x43
    SWITCH_SELECTIVE_RESPONSE = 0x44
    IDENTIFY_VENDOR = 0x46
    IDENTIFY_PRODUCT = 0x47
    IDENTIFY_REVISION_LOW = 0x48
    IDENTIFY_REVISION_HIGH = 0x49
    IDENTIFY_SERIAL_LOW = 0x4A
    IDENTIFY_SERIAL_HIGH = 0x4B
    IDENTIFY_NON_CONFIGURED = 0x4C
    IDENTIFY_SLAVE = 0x4F
    IDENTIFY_NON_CONFIGURED_SLAVE = 0x50
    FASTSCAN = 0x51
    INQUIRE_VENDOR = 0x5A
    INQUIRE_PRODUCT = 0x5B
    INQUIRE_REVISION = 0x5C
    INQUIRE_SERIAL = 0x5D
    INQUIRE_NODE_ID = 0x5E


class LssState(Enum):
    """LSS slave states (CiA 305; IDX guide 3.5.1)."""

    WAITING = 0
    CONFIGURATION = 1


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

FASTSCAN_CONFIRM = 0x80  # BitChecked value that restarts a Fastscan (CiA 305 clause 8.3.5)


@dataclass(frozen=True, slots=True)
class LssAddress:
    """The 128-bit LSS address = identity object 0x1018 sub 1..4 (IDX guide 3.5)."""

    vendor_id: int
    product_code: int
    revision: int
    serial: int

    def part(self, sub: int) -> int:
        """The 32-bit part ``sub`` (1 vendor, 2 product, 3 revision, 4 serial) of the address."""
        return (self.vendor_id, self.product_code, self.revision, self.serial)[sub]


# -- codecs -----------------------------------------------------------------------------------
def encode_switch_global(mode: LssState) -> bytes:
    """Switch state global request (CiA 305): 1 = configuration, 0 = waiting."""
    return _CS_B_B.pack(Cs.SWITCH_STATE_GLOBAL, mode.value, 0)


def encode_u32(cs: int, value: int) -> bytes:
    """A request or response carrying one 32-bit number (selective, identify, inquire)."""
    return _CS_U32.pack(cs, value & 0xFFFFFFFF)


def encode_cs(cs: int) -> bytes:
    """A request with only a command specifier (inquire services, store, ...)."""
    return bytes((cs,)) + bytes(7)


def encode_configure_node_id(node_id: int) -> bytes:
    """Configure node-ID request (CiA 305; 0xFF = unconfigured)."""
    return _CS_B_B.pack(Cs.CONFIGURE_NODE_ID, node_id & 0xFF, 0)


def encode_configure_bit_timing(index: int, selector: int = 0) -> bytes:
    """Configure bit timing request: table selector 0, table index."""
    return _CS_B_B.pack(Cs.CONFIGURE_BIT_TIMING, selector & 0xFF, index & 0xFF)


def encode_activate_bit_timing(delay_ms: int) -> bytes:
    """Activate bit timing request with the switch delay in ms."""
    return _ACTIVATE.pack(Cs.ACTIVATE_BIT_TIMING, delay_ms & 0xFFFF)


def encode_result(cs: int, error: int, specific: int = 0) -> bytes:
    """Configure node-ID / bit timing / store responses: cs, error code, specific error."""
    return _CS_B_B.pack(cs, error, specific)


def encode_fastscan(id_number: int, bit_checked: int, lss_sub: int, lss_next: int) -> bytes:
    """One Fastscan request: id bits, bit checked, LSS sub, LSS next (CiA 305)."""
    return _FASTSCAN.pack(Cs.FASTSCAN, id_number & 0xFFFFFFFF, bit_checked, lss_sub, lss_next)


# -- slave ------------------------------------------------------------------------------------
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
        value = _CS_U32.unpack(data)[1]
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
        delay_ms = _ACTIVATE.unpack(data)[1]
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
        return [Reply(_CS_B_B.pack(cs, self.active_node_id, 0))]

    def _identify_remote(self, cs: int, data: bytes) -> list[LssAction]:
        step = cs - Cs.IDENTIFY_VENDOR
        value = _CS_U32.unpack(data)[1]
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
        _, id_number, bit_checked, lss_sub, lss_next = _FASTSCAN.unpack(data)
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


def bit_timing_index(bitrate: int) -> int:
    """CiA 305 table index of a bit rate; raises LocalError for rates outside the table."""
    try:
        return BIT_TIMING_TABLE.index(bitrate)
    except ValueError:
        raise LocalError(f"bit rate {bitrate} is not in the CiA 305 bit timing table") from None


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


# -- master -----------------------------------------------------------------------------------
class LssError(RemoteError):
    """An LSS slave answered with an error code (``.code``), or nobody answered."""


class LssTimeout(LssError, TimeoutError_):
    """No LSS slave answered in time."""


@dataclass(frozen=True, slots=True)
class _Request:
    data: bytes
    expect: int | None      # response cs, or None when no response exists
    collect: bool = False   # wait the whole timeout and count every response


_Proc = Generator[_Request, "bytes | int | None", Any]
ResultCallback = Callable[[Any], None]


class LssMaster:
    """A sans-I/O CiA 305 LSS master: ``send`` gets the frames, feed answers to ``on_frame``.

    Services queue; one runs at a time. Each callback receives the result or an
    :class:`LssError` / :class:`LssTimeout`. After a response arrives the master waits ``settle``
    seconds before the next request so that identical answers of other slaves to the same
    request are not taken for the answer to the next one.
    """

    def __init__(self, clock: Clock, send: Callable[[CanFrame], None], timeout: float = 0.1,
                 settle: float = 0.002) -> None:
        self.clock = clock
        self._send = send
        self.timeout = timeout
        self.settle = settle
        self._queue: deque[tuple[_Proc, ResultCallback | None]] = deque()
        self._proc: _Proc | None = None
        self._callback: ResultCallback | None = None
        self._request: _Request | None = None
        self._timer: TimerHandle | None = None
        self._count = 0
        self._answered = False
        self.unexpected = 0

    # -- services -------------------------------------------------------------------------
    def switch_state_global(self, state: LssState, callback: ResultCallback | None = None) -> None:
        """Switch state global: every slave to ``state`` (configuration or waiting)."""
        self._submit(self._single(encode_switch_global(state), None), callback)

    def switch_state_selective(self, address: LssAddress, callback: ResultCallback | None = None) -> None:
        """Result: True when a slave answered (it is now in configuration state)."""
        self._submit(self._selective(address), callback)

    def configure_node_id(self, node_id: int, callback: ResultCallback | None = None) -> None:
        """Give the selected slave a node-ID (0xFF = unconfigured)."""
        self._submit(self._configure(encode_configure_node_id(node_id)), callback)

    def configure_bit_timing(self, index: int, callback: ResultCallback | None = None) -> None:
        """Select a CiA 305 bit timing table index in the selected slave."""
        self._submit(self._configure(encode_configure_bit_timing(index)), callback)

    def activate_bit_timing(self, delay_ms: int, callback: ResultCallback | None = None) -> None:
        """Switch all slaves to the configured bit timing after ``delay_ms``."""
        self._submit(self._single(encode_activate_bit_timing(delay_ms), None), callback)

    def store_configuration(self, callback: ResultCallback | None = None) -> None:
        """Ask the selected slave to store node-ID and bit timing."""
        self._submit(self._configure(encode_cs(Cs.STORE_CONFIGURATION)), callback)

    def inquire(self, cs: Cs, callback: ResultCallback | None = None) -> None:
        """Inquire vendor/product/revision/serial (u32) or node-ID (u8) of the configured slave."""
        if not Cs.INQUIRE_VENDOR <= cs <= Cs.INQUIRE_NODE_ID:
            raise LocalError(f"not an inquire service: {cs!r}")
        self._submit(self._inquire(cs), callback)

    def identify_remote_slave(self, vendor_id: int, product_code: int, revision_low: int,
                              revision_high: int, serial_low: int, serial_high: int,
                              callback: ResultCallback | None = None) -> None:
        """Result: how many slaves answered within the timeout."""
        self._submit(self._identify((vendor_id, product_code, revision_low, revision_high,
                                     serial_low, serial_high)), callback)

    def identify_non_configured(self, callback: ResultCallback | None = None) -> None:
        """Result: how many non-configured slaves answered within the timeout."""
        req = _Request(encode_cs(Cs.IDENTIFY_NON_CONFIGURED), Cs.IDENTIFY_NON_CONFIGURED_SLAVE, True)
        self._submit(self._collect(req), callback)

    def fast_scan(self, callback: ResultCallback | None = None) -> None:
        """CiA 305 Fastscan. Result: the LssAddress of one non-configured slave (now in
        configuration state), or None when no non-configured slave answered."""
        self._submit(self._fastscan(), callback)

    # -- procedures -----------------------------------------------------------------------
    @staticmethod
    def _single(data: bytes, expect: int | None) -> _Proc:
        answer = yield _Request(data, expect)
        return answer

    @staticmethod
    def _collect(req: _Request) -> _Proc:
        count = yield req
        return count

    @staticmethod
    def _selective(address: LssAddress) -> _Proc:
        for sub in range(3):
            yield _Request(encode_u32(Cs.SWITCH_SELECTIVE_VENDOR + sub, address.part(sub)), None)
        answer = yield _Request(encode_u32(Cs.SWITCH_SELECTIVE_SERIAL, address.serial),
                                Cs.SWITCH_SELECTIVE_RESPONSE)
        return answer is not None

    @staticmethod
    def _configure(data: bytes) -> _Proc:
        answer = yield _Request(data, data[0])
        if not isinstance(answer, bytes):
            raise LssTimeout(f"no answer to LSS cs 0x{data[0]:02X}")
        if answer[1]:
            raise LssError(f"LSS cs 0x{data[0]:02X} refused with error {answer[1]} "
                           f"(specific {answer[2]})", answer[1])
        return None

    @staticmethod
    def _inquire(cs: int) -> _Proc:
        answer = yield _Request(encode_cs(cs), cs)
        if not isinstance(answer, bytes):
            raise LssTimeout(f"no answer to LSS inquire cs 0x{cs:02X}")
        if cs == Cs.INQUIRE_NODE_ID:
            return answer[1]
        return int(_CS_U32.unpack(answer)[1])

    @staticmethod
    def _identify(values: tuple[int, ...]) -> _Proc:
        for step, value in enumerate(values[:5]):
            yield _Request(encode_u32(Cs.IDENTIFY_VENDOR + step, value), None)
        count = yield _Request(encode_u32(Cs.IDENTIFY_SERIAL_HIGH, values[5]), Cs.IDENTIFY_SLAVE, True)
        return count

    @staticmethod
    def _fastscan() -> _Proc:
        answer = yield _Request(encode_fastscan(0, FASTSCAN_CONFIRM, 0, 0), Cs.IDENTIFY_SLAVE)
        if answer is None:
            return None
        ids = [0, 0, 0, 0]
        for sub in range(4):
            for bit in range(31, -1, -1):
                answer = yield _Request(encode_fastscan(ids[sub], bit, sub, sub), Cs.IDENTIFY_SLAVE)
                if answer is None:
                    ids[sub] |= 1 << bit
            answer = yield _Request(encode_fastscan(ids[sub], 0, sub, (sub + 1) & 3), Cs.IDENTIFY_SLAVE)
            if answer is None:
                return None
        return LssAddress(*ids)

    # -- engine ---------------------------------------------------------------------------
    @property
    def busy(self) -> bool:
        """True while a request waits for its answer."""
        return self._proc is not None or bool(self._queue)

    def _submit(self, proc: _Proc, callback: ResultCallback | None) -> None:
        self._queue.append((proc, callback))
        if self._proc is None:
            self._next_proc()

    def _next_proc(self) -> None:
        while self._proc is None and self._queue:
            self._proc, self._callback = self._queue.popleft()
            self._step(None, first=True)

    def _step(self, value: bytes | int | None, first: bool = False) -> None:
        proc = self._proc
        assert proc is not None
        self._request = None
        try:
            req = next(proc) if first else proc.send(value)
        except StopIteration as stop:
            self._finish(stop.value)
            return
        except LssError as exc:
            self._finish(exc)
            return
        self._request = req
        self._count = 0
        self._answered = False
        self._send(CanFrame(LSS_MASTER_COB_ID, req.data))
        if req.expect is None:
            # unconfirmed service: continue once the request is queued
            self._timer = self.clock.call_soon(self._advance, None)
        else:
            self._timer = self.clock.call_later(self.timeout, self._expired)

    def _advance(self, value: bytes | int | None) -> None:
        self._timer = None
        if self._proc is not None:
            self._step(value)

    def _expired(self) -> None:
        self._timer = None
        req = self._request
        if req is not None and req.collect:
            self._step(self._count)
        else:
            self._step(None)

    def _finish(self, result: Any) -> None:
        callback = self._callback
        self._proc = self._callback = None
        self._request = None
        if callback is not None:
            callback(result)
        self._next_proc()

    def on_frame(self, frame: CanFrame, t: float) -> None:
        """Feed every received frame; only 0x7E4 responses are used."""
        if frame.can_id != LSS_SLAVE_COB_ID or frame.rtr or frame.extended or len(frame.data) != 8:
            return
        req = self._request
        if req is None or req.expect is None or frame.data[0] != req.expect:
            self.unexpected += 1
            return
        if req.collect:
            self._count += 1
            return
        if self._answered:
            self.unexpected += 1   # a second slave's copy of an answer already taken
            return
        self._answered = True
        if self._timer is not None:
            self._timer.cancel()
        self._timer = self.clock.call_later(self.settle, self._advance, frame.data)

    def stop(self) -> None:
        """Forget pending requests without callbacks (the owner shuts down)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._queue.clear()
        self._proc = self._callback = None
        self._request = None
