"""A CANopen device from its EDS or DCF alone: CiA 301 behaviour from the dictionary, no device code.

The node is the project's :class:`~gatewaylab.canopen.node.Node` (boot-up, NMT, heartbeat producer
0x1017 and consumer 0x1016, SYNC consumer/producer 0x1005/0x1006/0x1019, TPDOs by transmission type
with inhibit time and event timer, RPDOs into the dictionary, EMCY, SDO expedited/segmented/block,
store/restore 0x1010/0x1011, access and value ranges with their aborts) on a dictionary read from the
file: a DCF's ParameterValues are the power-on values. An LSS slave (CiA 305) answers when the file
says ``LSS_Supported=1``, with the identity of 0x1018. Entries move by themselves only through the
behaviour rules (:mod:`gatewaylab.plugin.behaviour`).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from gatewaylab.canopen.lss import LssAddress, LssConfigStore, LssSlave
from gatewaylab.canopen.node import Node
from gatewaylab.common.clock import PeriodicTimer
from gatewaylab.common.errors import ConfigError
from gatewaylab.od import ObjectDictionary
from gatewaylab.plugin.behaviour import Behaviour
from gatewaylab.plugin.participant import ParticipantBase, RigContext

__all__ = ["CanopenNodeDevice"]

log = logging.getLogger(__name__)


class CanopenNodeDevice(ParticipantBase):
    """One CANopen node built from a description file, on one bus of the rig."""

    def __init__(self, rig: RigContext, name: str, bus: str, node_id: int | None, od: ObjectDictionary, *,
                 source: Path, serial: int | None = None, lss: bool = False, store_path: Path | None = None,
                 behaviour: Behaviour | None = None, behaviour_period: float = 0.01) -> None:
        super().__init__(rig, name)
        self.source = source
        self.bus_name = bus
        if serial is not None and (0x1018, 4) in od.entries:
            od.put(0x1018, 4, serial)
        lss_store = LssConfigStore(store_path.with_name(store_path.name + ".lss.json")) if lss and store_path else None
        stored = lss_store.load() if lss_store is not None else None
        if stored is not None:
            node_id = None if stored[0] == 0xFF else stored[0]
        if node_id is None and not lss:
            raise ConfigError(f"{name}: no node_id in the rig file and none in {source.name} ([DeviceComissioning] "
                              "NodeID), and the device has no LSS to be given one (LSS_Supported=0)")
        self._node = Node(rig.clock, rig.bus(bus), node_id, od, name=name, store_path=store_path)
        self._lss: LssSlave | None = None
        if lss:
            identity = [od.get(0x1018, sub) if (0x1018, sub) in od.entries else 0 for sub in range(1, 5)]
            self._lss = LssSlave(self._node, LssAddress(*identity), store=lss_store)
        self.behaviour = behaviour
        self.behaviour_period = behaviour_period
        self._timer: PeriodicTimer | None = None
        #: what the ready file lists for this node (its EDS, for monitors and `gatewaylab sdo --eds`)
        self.ready_extra: dict[str, Any] = {}

    @property
    def node(self) -> Node:
        """The device's CANopen node (:class:`~gatewaylab.plugin.capabilities.HasNode`)."""
        return self._node

    @property
    def lss(self) -> LssSlave | None:
        """The LSS slave, when the description file says LSS_Supported=1."""
        return self._lss

    @property
    def running(self) -> bool:
        """Switched on: the node runs (fault injection's power cycle)."""
        return self._node.running

    def start(self) -> None:
        """Power on: boot-up (the node sends its boot-up message and enters Pre-operational), rules tick."""
        self._node.start()
        if self.behaviour is not None and self._timer is None:
            self._timer = self.rig.clock.call_every(self.behaviour_period, self._tick)

    def _tick(self) -> None:
        behaviour = self.behaviour
        if behaviour is None or not self._node.running:
            return
        errors = behaviour.hook_errors
        behaviour.apply(self.rig.clock.now())
        if behaviour.hook_errors and not errors:
            log.warning("%s: the behaviour hook raised %r (counted; the device carries on)", self.name,
                        behaviour.last_hook_error)

    def ready_info(self) -> dict[str, Any]:
        """The node in the ready file's ``canopen`` list (name, node-ID, EDS)."""
        return dict(self.ready_extra)

    def stop(self) -> None:
        """Power off: stop the rules, the LSS timers and the node."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._lss is not None:
            self._lss.stop()
        self._node.stop()
