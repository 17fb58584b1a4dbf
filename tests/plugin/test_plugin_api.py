"""The device plugin API of issue 22: capabilities as declared Protocols ('faults reach devices through declared
capability Protocols, not getattr': every built-in device satisfies the ones its faults need by its own members,
and a plugin device that offers only a Protocol's members gets the fault), and the Participant base
('validate-once and symmetric attach/detach')."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from gatewaylab.bus import Controller, ErrorState, VirtualBus
from gatewaylab.plugin import CheckedSection, DeviceKind, Key, ParticipantBase, RigContext
from gatewaylab.plugin import capabilities as cap
from gatewaylab.rig import kinds
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig

EVERY_KIND: dict[str, Any] = {
    "clock": "simulated", "bus": [{"name": "can0"}, {"name": "can1"}],
    "drive": [{"bus": "can0", "node_id": 2, "serial": 0x1002, "name": "axis2"}],
    "device": [{"kind": "maxon_idx", "name": "idx1", "bus": "can0", "node_id": 5, "serial": 0x5005,
                "usb": {"pty": False}},
               {"kind": "ecanlite", "name": "ecan1", "channels": ["can0", "can1"]},
               {"kind": "esd_can_ethercat", "name": "esd1", "bus": "can1"},
               {"kind": "ethercat_io", "name": "io1"},
               {"kind": "ethercat_drive", "name": "ax1"}],
    "ethercat": {"interface": "gl-none"}}


def test_every_device_declares_what_its_faults_need() -> None:
    """docs/faults.md 'Devices and faults': the drive is a CanopenDrive with a node, the IDX has a node, a
    drive and a USB port, the gateways list CAN channels and join the segment, the [ethercat] section owns it."""
    with Rig(parse_rig(EVERY_KIND)) as rig:
        rig.start()
        by_name = {p.name: p for p in rig.participants}
        axis2, idx1, ecan1, esd1 = by_name["axis2"], by_name["idx1"], by_name["ecan1"], by_name["esd1"]
        assert isinstance(axis2, cap.CanopenDrive) and isinstance(axis2, cap.HasNode) and cap.drive_of(axis2) is axis2
        assert isinstance(idx1, cap.HasNode) and isinstance(idx1, cap.HasDrive) and isinstance(idx1, cap.UsbPluggable)
        assert cap.node_of(idx1) is idx1.node and cap.drive_of(idx1) is idx1.drive
        assert cap.drive_of(by_name["ax1"]) is not None and cap.node_of(by_name["ax1"]) is None
        assert isinstance(ecan1, cap.CanChannels) and sorted(cap.can_channels(ecan1)) == ["mcan0", "mcan1"]
        assert isinstance(esd1, cap.CanChannels) and not isinstance(esd1, cap.UsbPluggable)
        assert [d.name for d in cap.ethercat_devices(rig.participants)] == ["ecan1", "esd1", "io1", "ax1"]
        assert all(isinstance(d, cap.EthercatDevice) for d in cap.ethercat_devices(rig.participants))
        segment = cap.segment_of(rig.participants)
        assert isinstance(by_name["ethercat"], cap.HasSegment) and segment is not None
        assert [s.name for s in segment.slaves] == ["ecan1", "esd1", "io1", "ax1"]
        assert cap.can_channels(by_name["io1"]) == {} and cap.drive_of(ecan1) is None


class _TwoChannelPlugin:
    """A plugin device outside gatewaylab: it offers CanChannels by the method alone (no base class)."""

    def __init__(self, name: str, a: Controller, b: Controller) -> None:
        self.name = name
        self._channels = {"left": a, "right": b}

    def can_channels(self) -> Mapping[str, Controller]:
        return self._channels

    def start(self) -> None:
        """Nothing to open."""

    def stop(self) -> None:
        """Nothing to release."""

    def ready_info(self) -> dict[str, Any]:
        return {}


def test_a_plugin_with_only_the_protocol_members_gets_controller_faults() -> None:
    """Issue 22: capabilities are Protocols, so a plugin needs nothing from gatewaylab's fault module to be
    faulted: bus-off on its channel 'right' (CAN 2.0 §8 rule 9), the other channel left alone."""
    with Rig(parse_rig({"clock": "simulated", "bus": [{"name": "can0"}]})) as rig:
        bus: VirtualBus = rig.buses["can0"]
        plugin = _TwoChannelPlugin("gadget", bus.attach("gadget.l"), bus.attach("gadget.r"))
        rig.participants.append(plugin)
        assert isinstance(plugin, cap.CanChannels) and not isinstance(plugin, cap.HasNode)
        answer = rig.faults.bus_off("gadget", channel="right")
        assert answer["channel"] == "right"
        assert plugin._channels["right"].state is ErrorState.BUS_OFF
        assert plugin._channels["left"].state is ErrorState.ERROR_ACTIVE


class _Probe(ParticipantBase):
    """A plugin participant on the base: it attaches in start(), so it can start again after stop()."""

    def __init__(self, rig: RigContext, cfg: dict[str, Any]) -> None:
        self.cfg = PROBE.validate(cfg, "[[device]] probe", list(rig.buses))
        super().__init__(rig, self.cfg["name"])

    def start(self) -> None:
        self.attach(self.cfg["bus"], f"{self.name}.a")
        self.attach(self.cfg["bus"], f"{self.name}.b", listen_only=True)


PROBE = DeviceKind("probe", _Probe, {"name": Key(str, "probe"), "bus": Key(str, required=True, bus=True)})


def test_participant_base_checks_once_and_detaches_what_it_attached() -> None:
    """Issue 22 'Participant base with validate-once and symmetric attach/detach': a section the kind checked
    passes its validate() unchanged (the same object), a raw one is checked; stop() detaches every controller
    start() attached, and a second start attaches them again."""
    raw = {"bus": "can0"}
    checked = PROBE.validate(raw, "[[device]] probe", ["can0"])
    assert isinstance(checked, CheckedSection) and checked == {"name": "probe", "bus": "can0"}
    assert PROBE.validate(checked, "elsewhere", ["can0"]) is checked
    with Rig(parse_rig({"clock": "simulated", "bus": [{"name": "can0"}]})) as rig:
        bus = rig.buses["can0"]
        probe = _Probe(rig, checked)
        assert probe.cfg is checked
        for _ in range(2):
            probe.start()
            assert [c.name for c in bus.controllers] == ["probe.a", "probe.b"]
            probe.stop()
            assert bus.controllers == [] and probe.controllers == []
        probe.stop()   # idempotent


def test_the_rig_plan_checks_each_section_once_for_its_device() -> None:
    """Validate once: the rig's plan checks every section before anything is built (a CheckedSection of its
    kind), and the device's own validate() call in its constructor returns that section without checking it
    again; the tunnel and bridge participants detach what they attached when the rig closes."""
    cfg = {"clock": "simulated", "bus": [{"name": "can0"}],
           "device": [{"kind": "ethercat_io", "name": "io1"}],
           "tunnel": [{"bus": "can0", "local": "127.0.0.1:0", "remote": "127.0.0.1:20000"}]}
    config = parse_rig(cfg)
    sections = kinds.plan(config)
    assert [s.kind.kind for s in sections] == ["tunnel", "ethercat_io"]
    for section in sections:
        assert isinstance(section.cfg, CheckedSection) and section.cfg.kind == section.kind.kind
        assert section.kind.validate(section.cfg, "elsewhere", ["can0"]) is section.cfg
    with Rig(config) as rig:
        tunnel = next(p for p in rig.participants if isinstance(p, ParticipantBase))
        assert tunnel.controllers and tunnel.controllers[0] in rig.buses["can0"].controllers
    assert rig.buses["can0"].controllers == [] and tunnel.controllers == []
