"""Capabilities as declared Protocols (issue 22: 'faults reach devices through declared capability Protocols,
not getattr'): every built-in device satisfies the ones its faults need by its own members, and a plugin
device that offers only a Protocol's members gets the fault."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from gatewaylab.bus.bus import Controller, ErrorState, VirtualBus
from gatewaylab.plugin.capabilities import (
    CanChannels,
    CanopenDrive,
    EthercatDevice,
    HasDrive,
    HasNode,
    HasSegment,
    UsbPluggable,
    can_channels,
    drive_of,
    ethercat_devices,
    node_of,
    segment_of,
)
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
        assert isinstance(axis2, CanopenDrive) and isinstance(axis2, HasNode) and drive_of(axis2) is axis2
        assert isinstance(idx1, HasNode) and isinstance(idx1, HasDrive) and isinstance(idx1, UsbPluggable)
        assert node_of(idx1) is idx1.node and drive_of(idx1) is idx1.drive
        assert drive_of(by_name["ax1"]) is not None and node_of(by_name["ax1"]) is None
        assert isinstance(ecan1, CanChannels) and sorted(can_channels(ecan1)) == ["mcan0", "mcan1"]
        assert isinstance(esd1, CanChannels) and not isinstance(esd1, UsbPluggable)
        assert [d.name for d in ethercat_devices(rig.participants)] == ["ecan1", "esd1", "io1", "ax1"]
        assert all(isinstance(d, EthercatDevice) for d in ethercat_devices(rig.participants))
        segment = segment_of(rig.participants)
        assert isinstance(by_name["ethercat"], HasSegment) and segment is not None
        assert [s.name for s in segment.slaves] == ["ecan1", "esd1", "io1", "ax1"]
        assert can_channels(by_name["io1"]) == {} and drive_of(ecan1) is None


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
        assert isinstance(plugin, CanChannels) and not isinstance(plugin, HasNode)
        answer = rig.faults.bus_off("gadget", channel="right")
        assert answer["channel"] == "right"
        assert plugin._channels["right"].state is ErrorState.BUS_OFF
        assert plugin._channels["left"].state is ErrorState.ERROR_ACTIVE
