"""ECAN-Lite host library, CiA 402 layer (issue 12, manual 15.5.4 / 15.6) in process on a simulated
clock: an SDO probe of a drive through the gateway (15.4 ``igh_canopen_sdo_probe``), single-axis and
10-axis CSP on four channels reaching their targets, motion at a reduced rate (15.6 --motion-div),
and targets scheduled after SYNC0 (15.5.4 step 6)."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from ecanlite_host_kit import classic_port, host_rig

from gatewaylab.common.errors import LocalError
from gatewaylab.hosts.ecanlite.adapter import AdapterConfig, EcanAdapter, SlaveConfig
from gatewaylab.hosts.ecanlite.cia402 import Axis, Cia402, parse_axes
from gatewaylab.hosts.ecanlite.demo import rig_axes
from gatewaylab.hosts.ecanlite.port import ChannelConfig, McanPort, PortConfig
from gatewaylab.od import SdoAbort

TEN = ((1, 2, 3), (4, 5, 6), (7, 8), (9, 10))


def test_sdo_probe_through_the_gateway(tmp_path: Path) -> None:
    """15.4 SDO probe: 0x1000:00 of node 1 behind CAN0 is the CiA 402 servo device type; 0x1018:04
    the rig's serial; a missing object aborts with the drive's code 0x06020000 (CiA 301)."""
    with host_rig(tmp_path, ((1,),)) as h:
        _adapter, port = classic_port(h.backend, channels=(0,))
        cia = Cia402(port, [Axis(0, 0, 1)])
        axis = cia.axes[0].axis
        device_type, serial = cia.sdo_transfer([(axis, 0x1000, 0, None), (axis, 0x1018, 4, None)], 2.0)
        assert struct.unpack("<I", device_type)[0] == 0x00020192
        assert struct.unpack("<I", serial)[0] == 0x10001   # rig_toml: 0x10000 * (slave + 1) + 0x100 * ch + node
        with pytest.raises(SdoAbort) as exc:
            cia.sdo_transfer([(axis, 0x2FFF, 0, None)], 2.0)
        assert exc.value.code == 0x06020000


def test_single_axis_csp_reaches_target(tmp_path: Path) -> None:
    """15.5.4 steps 4-5 / 15.6 single-axis demo: NMT, CSP mapping by SDO, actual position, enable,
    then 500 cycles of +20 increments: the axis ends at start + 10000 within the position window."""
    with host_rig(tmp_path, ((1,),)) as h:
        adapter, port = classic_port(h.backend, channels=(0,))
        cia = Cia402(port, [Axis(0, 0, 1, 20)])
        cia.startup()
        (before,) = cia.results()
        assert before.enabled and before.statusword & 0x6F == 0x27
        cia.run(500)
        assert cia.settle(1.0)
        (r,) = cia.results()
        assert r.target == r.start + 10_000 and r.reached()
        assert r.tpdos >= 500 and r.heartbeats >= 1 and r.emcys == 0
        assert adapter.wkc_errors == 0 and port.parse_errors == 0


def test_ten_axes_on_four_channels(tmp_path: Path) -> None:
    """15.6 10-axis demo: ten drives on CAN0..CAN3 of one ECAN-Lite (N = 3, 1 ms), steps of both signs,
    every axis at its own target after the move, no WKC or PDO parse error."""
    with host_rig(tmp_path, TEN) as h:
        positions, axes = rig_axes(h.rig)
        assert positions == [0] and len(axes) == 10
        axes = [Axis(a.slave, a.channel, a.node_id, 5 * a.node_id * (-1) ** a.node_id) for a in axes]
        adapter, port = classic_port(h.backend)
        cia = Cia402(port, axes)
        cia.startup()
        cia.run(400)
        assert cia.settle(1.0)
        for r, a in zip(cia.results(), axes, strict=True):
            assert (r.node_id, r.channel) == (a.node_id, a.channel)
            assert r.target - r.start == 400 * a.step and r.reached()
        assert adapter.wkc_errors == 0 and port.parse_errors == 0 and port.lost_images == 0


def test_motion_div_sends_targets_every_other_cycle(tmp_path: Path) -> None:
    """15.6 --motion-div 2: the CAN target frame period is twice the EtherCAT cycle, so 400 cycles
    move 200 steps."""
    with host_rig(tmp_path, ((1,),)) as h:
        _adapter, port = classic_port(h.backend, channels=(0,))
        cia = Cia402(port, [Axis(0, 0, 1, 10)], motion_div=2)
        cia.startup()
        cia.run(400)
        assert cia.settle(1.0)
        (r,) = cia.results()
        assert r.target - r.start == 2000 and r.reached()


def test_scheduled_targets_after_sync0(tmp_path: Path) -> None:
    """15.5.4 step 6 / 8.4: with DC SYNC0, RPDO targets and SYNC scheduled independently after SYNC0
    move the axis as the direct sending does, without a scheduling error (LastPDOError 0)."""
    with host_rig(tmp_path, ((1,),)) as h:
        _adapter, port = classic_port(h.backend, channels=(0,), dc_sync0=True)
        cia = Cia402(port, [Axis(0, 0, 1, 20)])
        cia.set_scheduled_tx(100_000, 400_000)
        cia.startup()
        cia.run(300)
        assert cia.settle(1.0)
        (r,) = cia.results()
        assert r.target - r.start == 6000 and r.reached()
        assert h.backend.sdo_upload(0, 0x8011, 14) == b"\0\0"


def test_axis_table_parsing() -> None:
    """15.5.4 step 2: slave, MCAN channel, node id and step per axis; a wrong row is refused."""
    assert parse_axes("0:0:1,0:3:12:-5", 7) == [Axis(0, 0, 1, 7), Axis(0, 3, 12, -5)]
    for bad in ("0:0", "0:4:1", "0:0:128", "a:b:c", ""):
        with pytest.raises(LocalError):
            parse_axes(bad)


def test_two_slaves_with_their_own_pdo_size(tmp_path: Path) -> None:
    """15.5.2 step 3: ``ecan_igh_config_set_slave_pdo_multiplier``: slave 0 with N = 3 and slave 1 with
    N = 2 on one line (SM lengths 384 / 256 B), an axis behind each channel of both, all at target."""
    with host_rig(tmp_path, ((1,), (2,)), slaves=2) as h:
        positions, axes = rig_axes(h.rig, 10)
        assert positions == [0, 1] and len(axes) == 4
        adapter = EcanAdapter(h.backend, AdapterConfig((SlaveConfig(0, 3), SlaveConfig(1, 2))))
        port = McanPort(adapter, PortConfig({0: ChannelConfig.classic(), 1: ChannelConfig.classic()}))
        adapter.start()
        assert [len(adapter.rxpdo(k)) for k in (0, 1)] == [384, 256]
        assert [len(adapter.txpdo(k)) for k in (0, 1)] == [384, 256]
        cia = Cia402(port, axes)
        cia.startup()
        cia.run(200)
        assert cia.settle(1.0)
        assert [(r.slave, r.channel, r.node_id, r.target - r.start) for r in cia.results()] == [
            (0, 0, 1, 2000), (0, 1, 2, 2000), (1, 0, 1, 2000), (1, 1, 2, 2000)]
        assert all(r.reached() for r in cia.results())
        assert adapter.wkc_errors == 0 and port.parse_errors == 0
