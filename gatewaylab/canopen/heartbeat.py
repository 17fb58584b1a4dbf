"""Error control (CiA 301 7.2.8.3): heartbeat producer 0x1017, consumer 0x1016, node/life guarding.

* Producer: every 0x1017 ms the node sends its NMT state on 0x700 + node-id, in every state
  (Stopped included, IDX guide table 3-11).
* Consumer: each 0x1016 entry (node-id in bits 23..16, time in ms in bits 15..0) is monitored from
  the first heartbeat received; a missing heartbeat raises EMCY 0x8130 (communication error
  bit); the error is reset when the heartbeat comes back.
* Guarding: a remote frame on 0x700 + node-id is answered with the state and a toggle bit; when
  guard time 0x100C x life time factor 0x100D is not 0, a missing guard request after the first
  one is a life-guarding event (EMCY 0x8130).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.emcy import EMCY_LIFE_GUARD_HEARTBEAT, ERR_COMMUNICATION
from gatewaylab.canopen.nmt import HEARTBEAT_BASE, encode_guard_response, encode_heartbeat
from gatewaylab.common.clock import PeriodicTimer, TimerHandle
from gatewaylab.od import Entry
from gatewaylab.od.aborts import SdoAbort, SdoAbortCode

if TYPE_CHECKING:
    from gatewaylab.canopen.node import Node

__all__ = ["AddHandler", "Heartbeat"]


AddHandler = Callable[[int, Callable[[CanFrame, float], None]], None]


class Heartbeat:
    """Heartbeat producer/consumer and node guarding of a :class:`Node`."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self._producer: PeriodicTimer | None = None
        #: node-id -> consumer time in seconds (0x1016)
        self.consumed: dict[int, float] = {}
        self._consumer_timers: dict[int, TimerHandle] = {}
        #: Node-ids whose heartbeat timed out and has not come back yet.
        self.timed_out: set[int] = set()
        self.timeout_listeners: list[Callable[[int], None]] = []
        self._toggle = False
        self._life_timer: TimerHandle | None = None
        self.life_guarding_failed = False
        node.add_validator(0x1016, self._validate_consumer)
        node.add_reaction(0x1016, lambda e, v: self._reconfigure_consumers())
        node.add_reaction(0x1017, lambda e, v: self.start())
        node.add_reaction(0x100C, lambda e, v: self._restart_life())
        node.add_reaction(0x100D, lambda e, v: self._restart_life())

    # -- configuration -------------------------------------------------------------------------
    def configure(self) -> None:
        """Start anew from the dictionary: heartbeat consumer times (0x1016), guarding state cleared."""
        self._toggle = False
        self.life_guarding_failed = False
        self._read_consumers()

    def _read_consumers(self) -> None:
        od = self.node.od
        consumed: dict[int, float] = {}
        for sub in range(1, od.get(0x1016, 0) + 1):
            value = od.values.get((0x1016, sub), 0)
            nid, ms = (value >> 16) & 0xFF, value & 0xFFFF
            if 1 <= nid <= 127 and ms:
                consumed[nid] = ms / 1000.0
        self.consumed = consumed

    def _reconfigure_consumers(self) -> None:
        for handle in self._consumer_timers.values():
            handle.cancel()
        self._consumer_timers.clear()
        self.timed_out.clear()
        self._read_consumers()
        self.node.rebuild_dispatch()

    def _validate_consumer(self, entry: Entry, value: Any) -> None:
        """CiA 301 7.5.2.20: two entries for one node-id with a time != 0 are refused."""
        if entry.subindex == 0:
            return
        nid, ms = (value >> 16) & 0xFF, value & 0xFFFF
        if not ms or not nid:
            return
        od = self.node.od
        for sub in range(1, od.get(0x1016, 0) + 1):
            other = od.values.get((0x1016, sub), 0)
            if sub != entry.subindex and (other >> 16) & 0xFF == nid and other & 0xFFFF:
                raise SdoAbort(SdoAbortCode.GENERAL_PARAMETER_INCOMPATIBILITY, f"node {nid} already consumed")

    def register(self, add: AddHandler) -> None:
        """Add the COB-IDs this node consumes (heartbeats, guarding RTR) to the dispatch table."""
        node_id = self.node.node_id
        assert node_id is not None
        add(HEARTBEAT_BASE + node_id, self._on_guard_request)
        for nid in self.consumed:
            if nid != node_id:
                add(HEARTBEAT_BASE + nid, self._on_heartbeat)

    def halt(self) -> None:
        """Cancel the producer and consumer timers (reset, stop)."""
        if self._producer is not None:
            self._producer.cancel()
            self._producer = None
        for handle in self._consumer_timers.values():
            handle.cancel()
        self._consumer_timers.clear()
        self.timed_out.clear()
        if self._life_timer is not None:
            self._life_timer.cancel()
            self._life_timer = None

    # -- producer --------------------------------------------------------------------------------
    def start(self) -> None:
        """(Re)start the producer from 0x1017; the first heartbeat follows one period later."""
        if self._producer is not None:
            self._producer.cancel()
            self._producer = None
        node = self.node
        ms = node.od.get(0x1017, 0)
        if ms and node.running and node.node_id is not None:
            self._producer = node.clock.call_every(ms / 1000.0, self._beat)

    def _beat(self) -> None:
        node = self.node
        if node.node_id is not None:
            node.send(encode_heartbeat(node.node_id, node.nmt_state))

    # -- guarding --------------------------------------------------------------------------------
    def _on_guard_request(self, frame: CanFrame, t: float) -> None:
        if not frame.rtr:
            return
        node = self.node
        assert node.node_id is not None
        node.send(encode_guard_response(node.node_id, node.nmt_state, self._toggle))
        self._toggle = not self._toggle
        if self.life_guarding_failed:
            self.life_guarding_failed = False
            node.emcy.clear_error(EMCY_LIFE_GUARD_HEARTBEAT)
        self._restart_life(first=True)

    def _restart_life(self, first: bool = False) -> None:
        if self._life_timer is not None:
            self._life_timer.cancel()
            self._life_timer = None
        elif not first:
            return      # life guarding starts with the first guard request
        od = self.node.od
        lifetime = od.get(0x100C, 0) * od.get(0x100D, 0) / 1000.0
        if lifetime > 0:
            self._life_timer = self.node.clock.call_later(lifetime, self._life_guarding_event)

    def _life_guarding_event(self) -> None:
        self._life_timer = None
        self.life_guarding_failed = True
        self.node.emcy.raise_error(EMCY_LIFE_GUARD_HEARTBEAT, ERR_COMMUNICATION)

    # -- consumer --------------------------------------------------------------------------------
    def _on_heartbeat(self, frame: CanFrame, t: float) -> None:
        if frame.rtr or len(frame.data) != 1:
            return
        nid = frame.can_id - HEARTBEAT_BASE
        timeout = self.consumed.get(nid)
        if timeout is None:
            return
        old = self._consumer_timers.pop(nid, None)
        if old is not None:
            old.cancel()
        if nid in self.timed_out:
            self.timed_out.discard(nid)
            if not self.timed_out:
                self.node.emcy.clear_error(EMCY_LIFE_GUARD_HEARTBEAT)
        self._consumer_timers[nid] = self.node.clock.call_later(timeout, self._consumer_timeout, nid)

    def _consumer_timeout(self, nid: int) -> None:
        self._consumer_timers.pop(nid, None)
        self.timed_out.add(nid)
        self.node.emcy.raise_error(EMCY_LIFE_GUARD_HEARTBEAT, ERR_COMMUNICATION, bytes((nid,)))
        for cb in list(self.timeout_listeners):
            cb(nid)
