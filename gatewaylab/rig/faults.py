"""Fault injection into a rig: ``rig.faults`` (Python) and the request table of the control endpoint.

Every fault is one method of :class:`Faults` that takes names (buses, devices) and numbers,
changes the rig under ``clock.lock`` and returns a JSON-ready dict saying what it did. The control
endpoint (``control.py``) and ``gatewaylab fault`` only translate requests into these calls
(:meth:`Faults.request`), so the three faces cannot drift apart. See docs/faults.md.

How a device takes part: by the capability Protocols of :mod:`gatewaylab.plugin.capabilities` (structural,
so a plugin device only needs the members, nothing from here):

* CAN channels: :class:`~gatewaylab.plugin.capabilities.CanChannels` (an EtherCAT gateway lists its
  channels, e.g. ``{"mcan0": ..., "mcan1": ...}``); a drive or an IDX is found through its CANopen
  node (:class:`~gatewaylab.plugin.capabilities.HasNode`: one channel, ``"can"``).
* power cycle and drive faults: a :class:`~gatewaylab.plugin.capabilities.CanopenDrive` (the drive itself) or a
  :class:`~gatewaylab.plugin.capabilities.HasDrive` (the maxon IDX).
* EtherCAT: an :class:`~gatewaylab.plugin.capabilities.EthercatDevice` in the rig's ``[ethercat]`` segment
  (:class:`~gatewaylab.plugin.capabilities.HasSegment`).
* USB: a :class:`~gatewaylab.plugin.capabilities.UsbPluggable` (the maxon IDX).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from gatewaylab.bus.controller import Controller
from gatewaylab.canopen.emcy import ERR_CURRENT, ERR_PROFILE
from gatewaylab.ethercat.esc import AlState
from gatewaylab.plugin.capabilities import (
    CanopenDrive,
    UsbPluggable,
    can_channels,
    drive_of,
    node_of,
)
from gatewaylab.rig.faults_core import FaultRefused, FaultsCore, check_seconds
from gatewaylab.rig.faults_ec_dc import EC_DC_REQUESTS, EcDcFaults
from gatewaylab.rig.faults_ec_frames import EC_FRAMES_REQUESTS, EcFramesFaults
from gatewaylab.rig.faults_ec_ring import EC_RING_REQUESTS, EcRingFaults
from gatewaylab.rig.faults_ec_slave import EC_SLAVE_REQUESTS, EcSlaveFaults
from gatewaylab.rig.segment import SegmentParticipant

if TYPE_CHECKING:
    from gatewaylab.rig.runtime import Rig

__all__ = ["DRIVE_FAULTS", "REQUESTS", "Faults", "check_request"]


#: CiA 402 drive faults: name -> (EMCY / 0x603F error code, error register bits).
DRIVE_FAULTS: dict[str, tuple[int, int]] = {
    "following-error": (0x8611, ERR_PROFILE),    # maxon / CiA 402 'following error'
    "over-current": (0x2310, ERR_CURRENT),       # CiA 301 table 21 'continuous over-current'
}


class Faults(EcFramesFaults, EcSlaveFaults, EcDcFaults, EcRingFaults, FaultsCore):
    """The faults of one rig (``rig.faults``); each call returns what it did as a dict. The EtherCAT
    families come from their own modules (``faults_ec_*.py``, each a :class:`FaultsCore` mixin)."""

    def __init__(self, rig: Rig) -> None:
        super().__init__(rig)
        self._powered_off: dict[str, CanopenDrive] = {}

    # -- lookup ---------------------------------------------------------------------------------
    def _node_device(self, node_id: int, bus: str) -> Any:
        """The participant whose CANopen node has ``node_id`` on ``bus``."""
        b = self.bus(bus)
        for p in self.rig.participants:
            node = node_of(p)
            if node is not None and node.bus is b and node.node_id == node_id:
                return p
        raise FaultRefused(f"no node {node_id} on bus {bus!r}")

    def _target(self, device: str | int, bus: str | None) -> Any:
        """A device by name, or by CANopen node-ID (an int) on ``bus``."""
        if isinstance(device, int):
            if bus is None:
                raise FaultRefused(f"node {device}: which bus? (give bus=...)")
            return self._node_device(device, bus)
        return self.device(device)

    def _controller(self, device: str | int, bus: str | None, channel: str | None) -> tuple[Any, str, Controller]:
        p = self._target(device, bus)
        channels = can_channels(p)
        if not channels:
            raise FaultRefused(f"{p.name} has no CAN controller")
        if channel is None:
            if len(channels) > 1:
                raise FaultRefused(f"{p.name} has CAN channels {', '.join(channels)}: say which (channel=...)")
            channel = next(iter(channels))
        ctrl = channels.get(channel)
        if ctrl is None:
            raise FaultRefused(f"{p.name} has no CAN channel {channel!r} (channels: {', '.join(channels)})")
        return p, channel, ctrl

    def _drive(self, device: str | int, bus: str | None) -> tuple[Any, CanopenDrive]:
        p = self._target(device, bus)
        drive = drive_of(p)
        if drive is None:
            raise FaultRefused(f"{p.name} is not a drive")
        return p, drive

    def _usb(self, device: str) -> UsbPluggable:
        p = self.device(device)
        if not isinstance(p, UsbPluggable):
            raise FaultRefused(f"{device} has no USB port")
        return p

    # -- bus faults -------------------------------------------------------------------------------
    def bus_errors(self, bus: str, duration: float, every: int = 1) -> dict[str, Any]:
        """Error frames on ``bus`` for ``duration`` s: one frame in ``every`` ends in a CRC error."""
        b = self.bus(bus)
        _positive("duration", duration)
        if every < 1:
            raise FaultRefused(f"every must be >= 1, got {every}")
        return self.run(lambda: b.error_frames(duration, every), {
            "fault": "bus-errors", "bus": bus, "duration": duration, "every": every})

    def stuck_dominant(self, bus: str, duration: float) -> dict[str, Any]:
        """Hold ``bus`` dominant for ``duration`` s: transmitters go bus-off, nothing completes."""
        b = self.bus(bus)
        _positive("duration", duration)
        return self.run(lambda: b.stuck_dominant(duration), {
            "fault": "stuck-dominant", "bus": bus, "duration": duration})

    def drop(self, bus: str, can_id: int, count: int = 1) -> dict[str, Any]:
        """The next ``count`` frames of ``can_id`` on ``bus`` vanish (the sender sees success)."""
        b = self.bus(bus)
        _can_id(can_id)
        _count(count)
        return self.run(lambda: b.drop_next(count, can_id), {
            "fault": "drop", "bus": bus, "can_id": can_id, "count": count})

    def corrupt(self, bus: str, can_id: int, count: int = 1) -> dict[str, Any]:
        """The next ``count`` frames of ``can_id`` on ``bus`` end in a CRC error (retransmitted)."""
        b = self.bus(bus)
        _can_id(can_id)
        _count(count)
        return self.run(lambda: b.corrupt_next(count, can_id), {
            "fault": "corrupt", "bus": bus, "can_id": can_id, "count": count})

    # -- controller faults ------------------------------------------------------------------------
    def error_passive(self, device: str | int, bus: str | None = None, channel: str | None = None) -> dict[str, Any]:
        """A device's CAN controller to error-passive (TEC 128)."""
        def act() -> dict[str, Any]:
            p, ch, ctrl = self._controller(device, bus, channel)
            if ctrl.bus_off:
                raise FaultRefused(f"{p.name} {ch}: the controller is bus-off")
            ctrl.bus.force_error_passive(ctrl)
            return {"fault": "error-passive", "device": p.name, "channel": ch, "tec": ctrl.tec,
                    "state": ctrl.state.value}
        return self.locked(act)

    def bus_off(self, device: str | int, bus: str | None = None, channel: str | None = None) -> dict[str, Any]:
        """A device's CAN controller to bus-off (it recovers after 128 x 11 recessive bits)."""
        def act() -> dict[str, Any]:
            p, ch, ctrl = self._controller(device, bus, channel)
            ctrl.bus.force_bus_off(ctrl)
            return {"fault": "bus-off", "device": p.name, "channel": ch, "state": ctrl.state.value}
        return self.locked(act)

    def can_unplug(self, device: str | int, bus: str | None = None, channel: str | None = None) -> dict[str, Any]:
        """Pull a device's CAN connector: its controller neither sends nor receives."""
        def act() -> dict[str, Any]:
            p, ch, ctrl = self._controller(device, bus, channel)
            ctrl.bus.disconnect(ctrl)
            return {"fault": "can-unplug", "device": p.name, "channel": ch, "bus": ctrl.bus.name}
        return self.locked(act)

    def can_replug(self, device: str | int, bus: str | None = None, channel: str | None = None) -> dict[str, Any]:
        """Plug a device's CAN connector back in (frames it queued meanwhile go out)."""
        def act() -> dict[str, Any]:
            p, ch, ctrl = self._controller(device, bus, channel)
            ctrl.bus.reconnect(ctrl)
            return {"fault": "can-replug", "device": p.name, "channel": ch, "bus": ctrl.bus.name}
        return self.locked(act)

    # -- node faults --------------------------------------------------------------------------------
    def power_cycle(self, device: str | int, bus: str | None = None, off: float = 1.0) -> dict[str, Any]:
        """Switch a drive off for ``off`` s and on again: it leaves the bus, then boots (boot-up
        message, dictionary at its power-on values plus what was stored with 0x1010)."""
        if not (off >= 0 and math.isfinite(off)):
            raise FaultRefused(f"off must be a finite number of seconds >= 0, got {off}")

        def act() -> dict[str, Any]:
            p, drive = self._drive(device, bus)
            if p.name in self._powered_off:
                raise FaultRefused(f"{p.name} is already switched off")
            drive.stop()
            self._powered_off[p.name] = drive

            def power_on() -> None:
                if self._powered_off.pop(p.name, None) is drive:
                    drive.start()
            if off == 0:
                power_on()
            else:
                self.later(off, power_on)
            return {"fault": "power-cycle", "device": p.name, "off": off}
        return self.locked(act)

    def drive_fault(self, device: str | int, kind: str = "following-error", bus: str | None = None,
                    code: int | None = None) -> dict[str, Any]:
        """A CiA 402 drive fault: EMCY with the error code, 0x603F, Fault state (fault reset clears it)."""
        if kind not in DRIVE_FAULTS:
            raise FaultRefused(f"drive fault {kind!r}: one of {', '.join(DRIVE_FAULTS)}")
        error_code, register = DRIVE_FAULTS[kind]
        if code is not None:
            if not 0x1000 <= code <= 0xFFFF:
                raise FaultRefused(f"error code 0x{code:04X} is not a CiA 301 EMCY error code (0x1000..0xFFFF)")
            error_code = code

        def act() -> dict[str, Any]:
            p, drive = self._drive(device, bus)
            if not drive.running:
                raise FaultRefused(f"{p.name} is switched off")
            drive.fault(error_code, register)
            return {"fault": "drive-fault", "device": p.name, "kind": kind, "error_code": error_code,
                    "state": drive.state.name}
        return self.locked(act)

    # -- EtherCAT ------------------------------------------------------------------------------------
    def ethercat_unplug(self, device: str) -> dict[str, Any]:
        """Pull an EtherCAT device out of its segment: it and the devices behind it stop answering."""
        def act() -> dict[str, Any]:
            segment, position = self.ethercat_position(device)
            segment.unplug(position)
            reached = {id(s) for s in segment.reached} | {id(s) for s in segment.reached_secondary}
            return {"fault": "ethercat-unplug", "device": device, "position": position,
                    "unreachable": [s.name for s in segment.slaves if id(s) not in reached]}
        return self.locked(act)

    def ethercat_replug(self, device: str) -> dict[str, Any]:
        """Plug an EtherCAT device back in: it powers on in INIT."""
        def act() -> dict[str, Any]:
            segment, position = self.ethercat_position(device)
            segment.replug(position)
            return {"fault": "ethercat-replug", "device": device, "position": position,
                    "al_status": segment.slaves[position].esc.al_status}
        return self.locked(act)

    def ec_clear(self, device: str | None = None) -> dict[str, Any]:
        """End every active EtherCAT fault (of ``device`` only, when given); each is undone."""
        def act() -> dict[str, Any]:
            if device is not None:
                self.device(device)
            ended = self.board.end_all(device)
            return {"fault": "ec-clear", "device": device, "ended": [e.as_json() for e in ended]}
        return self.locked(act)

    # -- USB -----------------------------------------------------------------------------------------
    def usb_unplug(self, device: str) -> dict[str, Any]:
        """Pull a device's USB cable: its host connections drop, new ones are refused."""
        def act() -> dict[str, Any]:
            p = self._usb(device)
            p.usb_unplug()
            return {"fault": "usb-unplug", "device": device}
        return self.locked(act)

    def usb_replug(self, device: str) -> dict[str, Any]:
        """Plug the USB cable back in; the answer gives the port's endpoints (a pty gets a new path)."""
        def act() -> dict[str, Any]:
            p = self._usb(device)
            p.usb_replug()
            return {"fault": "usb-replug", "device": device, **p.ready_info()}
        return self.locked(act)

    # -- status (not a fault: what `gatewaylab monitor` shows of the EtherCAT side) -------------------
    def ethercat_states(self) -> dict[str, Any]:
        """AL state and AL status code of every EtherCAT device of the rig (ETG.1000.6 AL status)."""
        def act() -> dict[str, Any]:
            states: dict[str, Any] = {}
            for p in self.ethercat_devices():
                esc = p.slave.esc
                status = esc.al_status
                try:
                    state = AlState(status & 0x0F).name
                except ValueError:
                    state = f"0x{status & 0x0F:X}"
                states[p.name] = {"state": state, "error": bool(status & 0x10), "code": esc.al_status_code}
            out: dict[str, Any] = {"fault": "ethercat-states", "devices": states,
                                   "faults": [e.as_json() for e in self.board.entries()]}
            for q in self.rig.participants:       # the [ethercat] wire's counters while it runs
                if isinstance(q, SegmentParticipant) and (wire := q.wire_stats()) is not None:
                    out["wire"] = wire
                if isinstance(q, SegmentParticipant) and q.eni is not None:     # the slaves an ENI built
                    states.update(q.eni.states())
            if self.rig.scenario is not None:       # the steps of a [[scenario]], those fired so far
                out["scenario"] = self.rig.scenario.as_json()
            return out
        return self.locked(act)

    def can_states(self) -> dict[str, Any]:
        """Every CAN controller of the rig's devices by bus: fault-confinement state, error counters and
        whether it is plugged in (what `gatewaylab monitor` and the --web page show of other nodes)."""
        def act() -> dict[str, Any]:
            buses: dict[str, Any] = {}
            for p, channels in self.can_sides():
                for ch, ctrl in channels.items():
                    name = p.name if ch == "can" else f"{p.name}.{ch}"
                    stats = ctrl.stats
                    buses.setdefault(ctrl.bus.name, {})[name] = {
                        "state": ctrl.state.value, "tec": ctrl.tec, "rec": ctrl.rec, "connected": ctrl.connected,
                        "bus_offs": stats.bus_offs, "error_frames": stats.error_frames}
            return {"fault": "can-states", "buses": buses}
        return self.locked(act)

    # -- the request table (control endpoint, CLI) -------------------------------------------------
    def request(self, req: Mapping[str, Any]) -> dict[str, Any]:
        """Run one control request ``{"fault": NAME, ...arguments}`` (docs/faults.md)."""
        method, kwargs = check_request(req)
        result: dict[str, Any] = getattr(self, method)(**kwargs)
        return result


def check_request(req: Mapping[str, Any]) -> tuple[str, dict[str, Any]]:
    """Check a control request against :data:`REQUESTS` without running it (a scenario checks its steps
    when it loads): the :class:`Faults` method and its keyword arguments, else :class:`FaultRefused`."""
    name = req.get("fault")
    spec = REQUESTS.get(name) if isinstance(name, str) else None
    if spec is None:
        raise FaultRefused(f"unknown fault {name!r} (faults: {', '.join(REQUESTS)})")
    method, params = spec
    kwargs: dict[str, Any] = {}
    for key, value in req.items():
        if key == "fault":
            continue
        if key not in params:
            raise FaultRefused(f"{name}: unknown argument {key!r} (arguments: {', '.join(params)})")
        want, _required = params[key]
        if not _accepts(want, value):
            raise FaultRefused(f"{name}: {key} must be {want}, got {value!r}")
        kwargs[_PY_NAMES.get(key, key)] = value
    if "node" in params:
        if "node" in req and "device" in req:
            raise FaultRefused(f"{name}: give device or node, not both")
        if "node" not in req and "device" not in req:
            raise FaultRefused(f"{name}: missing device (a name) or node (a node-ID, with bus)")
    missing = [k for k, (_, required) in params.items() if required and k not in req]
    if missing:
        raise FaultRefused(f"{name}: missing {', '.join(missing)}")
    return method, kwargs


def _positive(what: str, value: float) -> None:
    check_seconds(what, value)


def _can_id(can_id: int) -> None:
    if not 0 <= can_id <= 0x1FFFFFFF:
        raise FaultRefused(f"CAN id 0x{can_id:X} is out of range")


def _count(count: int) -> None:
    if count < 1:
        raise FaultRefused(f"count must be >= 1, got {count}")


def _accepts(want: str, value: object) -> bool:
    if want == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    if want == "number":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if want == "string":
        return isinstance(value, str)
    if want == "bool":
        return isinstance(value, bool)
    return (isinstance(value, int) and not isinstance(value, bool)) or isinstance(value, str)  # "device"


#: request argument names that differ from the Python ones
_PY_NAMES = {"node": "device"}

_R, _O = True, False
_CONTROLLER = {"device": ("device", _O), "node": ("int", _O), "bus": ("string", _O), "channel": ("string", _O)}

#: fault name -> (Faults method, {argument: (JSON type, required)})
REQUESTS: dict[str, tuple[str, dict[str, tuple[str, bool]]]] = {
    "bus-errors": ("bus_errors", {"bus": ("string", _R), "duration": ("number", _R), "every": ("int", _O)}),
    "stuck-dominant": ("stuck_dominant", {"bus": ("string", _R), "duration": ("number", _R)}),
    "drop": ("drop", {"bus": ("string", _R), "can_id": ("int", _R), "count": ("int", _O)}),
    "corrupt": ("corrupt", {"bus": ("string", _R), "can_id": ("int", _R), "count": ("int", _O)}),
    "error-passive": ("error_passive", _CONTROLLER),
    "bus-off": ("bus_off", _CONTROLLER),
    "can-unplug": ("can_unplug", _CONTROLLER),
    "can-replug": ("can_replug", _CONTROLLER),
    "power-cycle": ("power_cycle", {"device": ("device", _O), "node": ("int", _O), "bus": ("string", _O),
                                    "off": ("number", _O)}),
    "drive-fault": ("drive_fault", {"device": ("device", _O), "node": ("int", _O), "bus": ("string", _O),
                                    "kind": ("string", _O), "code": ("int", _O)}),
    "ethercat-unplug": ("ethercat_unplug", {"device": ("string", _R)}),
    "ethercat-replug": ("ethercat_replug", {"device": ("string", _R)}),
    "usb-unplug": ("usb_unplug", {"device": ("string", _R)}),
    "usb-replug": ("usb_replug", {"device": ("string", _R)}),
    "ec-clear": ("ec_clear", {"device": ("string", _O)}),
    "ethercat-states": ("ethercat_states", {}),
    "can-states": ("can_states", {}),
}
REQUESTS.update(EC_DC_REQUESTS)
REQUESTS.update(EC_FRAMES_REQUESTS)
REQUESTS.update(EC_SLAVE_REQUESTS)
REQUESTS.update(EC_RING_REQUESTS)
