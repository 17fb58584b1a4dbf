"""ec-port-open, ec-ring-break / ec-ring-heal and ec-hot-unplug / ec-hot-plug through the pytest plugin's
``RigHandle.fault`` on a simulated-clock rig (docs/faults.md, EtherCAT table), with the in-process master.

ET1100 data sheet, register 0x0110 (DL status): bit 4+p physical link on port p, bit 8+2p loop closed, bit 9+2p
communication; an open port closes and loops frames back, so a line loses the slaves behind it (ETG.1000.4: the
working counter counts the slaves that executed the datagram). Hot-connect groups (ETG.1000 / Beckhoff
hot-connect): the group hangs off a junction port, so the slaves after it stay in the line.
"""

from __future__ import annotations

import argparse
import struct
from typing import Any

import pytest

from gatewaylab.cli.fault import add_subcommand, build_request
from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.datagram import Command, Datagram, Frame, decode_frame, encode_frame
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.faults_core import FaultRefused
from gatewaylab.rig.runtime import Rig
from gatewaylab.rig.segment import hot_connect_groups


def _rig(**ethercat: Any) -> dict[str, Any]:
    devices = [{"kind": "ethercat_io", "name": f"io-{c}", "serial": 10 + i} for i, c in enumerate("abcd")]
    return {"device": devices, "ethercat": {"interface": "gl-none", **ethercat}}


def _segment(handle: Any) -> Segment:
    segment: Segment = next(p for p in handle.rig.participants if p.name == "ethercat").segment
    return segment


def _dl(segment: Segment, position: int) -> int:
    value: int = struct.unpack_from("<H", segment.slaves[position].esc.mem, 0x0110)[0]
    return value


def test_port_open_hides_the_slaves_behind_it_until_its_time_is_up(gatewaylab_rig: Any) -> None:
    """ec-port-open io-b 1 --seconds 0.05 while the master cycles at 1 kHz: the LRW working counter drops by what
    io-c and io-d contributed, io-b's DL status shows port 1 without link and closed (0x0400), ethercat-states lists
    the fault; after 0.05 s the port has its link again and the full working counter is back without a restart."""
    handle = gatewaylab_rig(_rig(), clock="simulated")
    segment = _segment(handle)
    master = Master(handle.clock, segment)
    master.bring_up()
    master.start_cyclic(0.001)     # outputs keep coming: the SM watchdogs of the slaves reached stay quiet
    full = master.exchange_process_data()
    assert full == master.expected_wkc
    per_slave = full // 4
    answer = handle.fault("ec-port-open", device="io-b", port=1, seconds=0.05)
    assert answer["primary"] == ["io-a", "io-b"] and answer["primary_returns_on"] == "primary"
    assert _dl(segment, 1) & 0x0F30 == 0x0610 and _dl(segment, 2) & 0x0F30 == 0x0920
    assert master.exchange_process_data() == full - 2 * per_slave
    states = handle.fault("ethercat-states")
    assert [(f["fault"], f["target"], f["port"]) for f in states["faults"]] == [("ec-port-open", "io-b", 1)]
    handle.clock.run_until(handle.clock.now() + 0.06)
    assert _dl(segment, 1) & 0x0F30 == 0x0A30 and _dl(segment, 2) & 0x0F30 == 0x0A30
    assert master.exchange_process_data() == full
    assert handle.fault("ethercat-states")["faults"] == []
    master.stop_cyclic()


def test_ring_faults_need_a_ring_and_split_the_slaves_between_the_ports(gatewaylab_rig: Any) -> None:
    """A line refuses ec-ring-break; a redundant rig broken after io-b answers io-a..io-b through the primary
    interface and io-c..io-d through the secondary one; ec-ring-heal closes the ring (the primary frame passes
    every slave and returns on the secondary interface); port 2 has no cable to open."""
    line = gatewaylab_rig(_rig(), clock="simulated")
    with pytest.raises(FaultRefused, match="line, not a ring"):
        line.fault("ec-ring-break", after_device="io-b")
    with pytest.raises(FaultRefused, match="no cable"):
        line.fault("ec-port-open", device="io-b", port=2)
    ring = gatewaylab_rig(_rig(redundant="gl-none2"), clock="simulated")
    segment = _segment(ring)
    assert _dl(segment, 3) & 0x0F30 == 0x0A30       # the last slave's port 1 is cabled to the secondary interface
    answer = ring.fault("ec-ring-break", after_device="io-b")
    assert (answer["primary"], answer["secondary"]) == (["io-a", "io-b"], ["io-c", "io-d"])
    with pytest.raises(FaultRefused, match="already"):
        ring.fault("ec-ring-break", after_device="io-b")
    healed = ring.fault("ec-ring-heal")
    assert healed["healed"] == ["io-b"] and healed["primary_returns_on"] == "secondary"
    assert healed["primary"] == ["io-a", "io-b", "io-c", "io-d"] and healed["secondary"] == []


def test_hot_connect_group_unplugged_by_its_head(gatewaylab_rig: Any) -> None:
    """hot_connect = "io-b, io-d": io-b heads io-b + io-c. Unplugged, io-d answers right after io-a (positions one
    group shorter) and the BRD a master counts slaves with counts 2; plugged back, the group is there again in INIT
    (power-on: no station address) and a master re-initialising the line brings all 4 to OP."""
    handle = gatewaylab_rig(_rig(hot_connect="io-b, io-d"), clock="simulated")
    segment = _segment(handle)
    master = Master(handle.clock, segment)
    master.bring_up()
    answer = handle.fault("ec-hot-unplug", head="io-b")
    assert answer["group"] == ["io-b", "io-c"] and answer["primary"] == ["io-a", "io-d"]
    frame = bytearray(encode_frame(Frame((Datagram.physical(Command.BRD, 1, 0, 0x0000, b"\0\0"),))))
    assert segment.process(frame) and decode_frame(frame).datagrams[0].wkc == 2      # a master's slave count
    with pytest.raises(FaultRefused, match="heads no hot-connect group"):
        handle.fault("ec-hot-unplug", head="io-c")
    handle.fault("ec-hot-plug", head="io-b")
    assert [(s.esc.al_status & 0x0F, s.esc.station_address) for s in segment.slaves[1:3]] == [(1, 0), (1, 0)]
    again = Master(handle.clock, segment)
    again.bring_up()
    assert again.exchange_process_data() == again.expected_wkc


def test_the_command_line_builds_the_control_requests() -> None:
    """docs/faults.md: ``gatewaylab fault READY ec-port-open DEVICE PORT [--seconds S]``, ``ec-ring-break
    AFTER-DEVICE``, ``ec-ring-heal``, ``ec-hot-unplug HEAD``, ``ec-hot-plug HEAD`` become the control requests of
    the same names; a port outside 0..3 is a command-line error (exit 2)."""
    parser = argparse.ArgumentParser()
    add_subcommand(parser.add_subparsers())
    def request(*argv: str) -> dict[str, Any]:
        return build_request(parser.parse_args(["fault", "ready.json", *argv]))
    assert request("ec-port-open", "io-b", "1", "--seconds", "2.5") == {
        "fault": "ec-port-open", "device": "io-b", "port": 1, "seconds": 2.5}
    assert request("ec-port-open", "io-b", "0") == {"fault": "ec-port-open", "device": "io-b", "port": 0}
    assert request("ec-ring-break", "io-a") == {"fault": "ec-ring-break", "after_device": "io-a"}
    assert request("ec-ring-heal") == {"fault": "ec-ring-heal"}
    assert request("ec-hot-unplug", "io-b") == {"fault": "ec-hot-unplug", "head": "io-b"}
    assert request("ec-hot-plug", "io-b") == {"fault": "ec-hot-plug", "head": "io-b"}
    with pytest.raises(SystemExit) as exit_:
        request("ec-port-open", "io-b", "4")
    assert exit_.value.code == 2


def test_unplugging_a_device_of_a_ring_leaves_the_devices_after_it_to_the_secondary_interface(
        gatewaylab_rig: Any) -> None:
    """ethercat-unplug io-b on a redundant rig: io-b's cables are gone on both sides, so io-a answers through the
    primary interface and io-c, io-d through the secondary one (ETG.1000.4 cable redundancy); only io-b is
    unreachable. On a line the same request cuts off io-b and everything behind it."""
    ring = gatewaylab_rig(_rig(redundant="gl-none2"), clock="simulated")
    assert ring.fault("ethercat-unplug", device="io-b")["unreachable"] == ["io-b"]
    segment = _segment(ring)
    assert [s.name for s in segment.reached_secondary] == ["io-c", "io-d"]
    line = gatewaylab_rig(_rig(), clock="simulated")
    assert line.fault("ethercat-unplug", device="io-b")["unreachable"] == ["io-b", "io-c", "io-d"]


def test_a_hot_connect_head_must_be_a_device_of_the_segment(tmp_path: Any) -> None:
    """docs/rig.md `[ethercat] hot_connect`: a head that is no EtherCAT device of the rig is a configuration error
    naming the key and the devices there are, before anything runs."""
    with pytest.raises(ConfigError, match=r"hot_connect: 'io-x' is not an EtherCAT device of this rig \(devices: "
                                          r"io-a, io-b, io-c, io-d\)"):
        Rig(parse_rig({"clock": "simulated", **_rig(hot_connect="io-b, io-x")}, "rig.toml"))


def test_hot_connect_groups_follow_the_line_order_of_their_heads() -> None:
    """docs/rig.md `hot_connect`: a head and the devices after it up to the next head form a group, whatever order
    the heads are written in; devices before the first head belong to no group."""
    names = ["io-a", "io-b", "io-c", "io-d", "io-e"]
    assert hot_connect_groups("io-d, io-b", names) == {"io-b": [1, 2], "io-d": [3, 4]}
    assert hot_connect_groups(" io-e ,", names) == {"io-e": [4]}
    assert hot_connect_groups(None, names) == {}


def test_a_scenario_breaks_and_heals_the_ring(tmp_path: Any) -> None:
    """docs/faults.md "Scenarios": any verb as a step -- a redundant rig's ring broken after io-b 2 ms after the
    start and, by the step's ``end_after``, mended 3 ms later (ending the step undoes its fault, as ec-clear)."""
    path = tmp_path / "rig.toml"
    path.write_text('clock = "simulated"\n' + "".join(
        f'[[device]]\nkind = "ethercat_io"\nname = "io-{c}"\nserial = {10 + i}\n' for i, c in enumerate("abcd"))
        + '[ethercat]\ninterface = "gl-none"\nredundant = "gl-none2"\n'
        + '[[scenario]]\nat = 0.002\nfault = "ec-ring-break"\nafter_device = "io-b"\nend_after = 0.003\n')
    with Rig.from_file(path) as rig:
        rig.start()
        segment = next(p for p in rig.participants if p.name == "ethercat").segment  # type: ignore[attr-defined]
        rig.clock.advance(0.003)
        assert [s.name for s in segment.reached_secondary] == ["io-c", "io-d"] and segment.cuts == {2: 1}
        rig.clock.advance(0.005)
        assert segment.reached_secondary == [] and segment.cuts == {}
        fired = rig.faults.ethercat_states()["scenario"]["fired"]
    assert [(r["fault"], r["answer"]["secondary"]) for r in fired] == [("ec-ring-break", ["io-c", "io-d"])]
