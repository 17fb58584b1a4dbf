"""``[[tunnel]] kind = "cannelloni"`` (issue 24, cannelloni tunnel): two rigs joined over UDP carry a
canopen client's SDO and PDO traffic with a drive on the other rig; garbage datagrams, datagrams from
another host and a far side that vanishes and comes back leave the rigs running
(mguentner/cannelloni udpthread.cpp: peer check, buffer timeout); and the issue's proof: two
`gatewaylab run` rigs in two network namespaces joined by a veth pair with no other address."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import socket
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import canopen
import pytest
from csp_loop_kit import csp_loop

from gatewaylab.bus import CanFrame, python_can_bus
from gatewaylab.common.errors import ConfigError
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.process import RigProcess, free_udp_ports
from gatewaylab.rig.runtime import Rig
from gatewaylab.rig.tunnel import CannelloniTunnel

DRIVE = {"bus": "can0", "node_id": 2, "serial": 0x1002, "name": "axis2"}


class Pair:
    """Rig A (a drive) and rig B (a canopen master) joined by a cannelloni tunnel on 127.0.0.1."""

    def __init__(self) -> None:
        self.port_a, self.port_b = free_udp_ports(2)
        self.a = self._rig(self.port_a, self.port_b, [DRIVE])
        self.b: tuple[Rig, threading.Thread] | None = None
        self.start_b()

    @staticmethod
    def _rig(local: int, remote: int, drives: list[dict[str, Any]]) -> tuple[Rig, threading.Thread]:
        config = parse_rig({"clock": "realtime", "bus": [{"name": "can0", "endpoint": "none"}], "drive": drives,
                            "tunnel": [{"kind": "cannelloni", "bus": "can0", "local": f"127.0.0.1:{local}",
                                        "remote": f"127.0.0.1:{remote}", "timeout_us": 500}]})
        rig = Rig(config)
        rig.start()
        return rig, rig.run_in_thread()

    def start_b(self) -> None:
        self.b = self._rig(self.port_b, self.port_a, [])

    def stop_b(self) -> None:
        assert self.b is not None
        rig, thread = self.b
        rig.request_stop()
        thread.join(10)
        rig.close()
        self.b = None

    def tunnel(self, rig: Rig) -> CannelloniTunnel:
        [t] = [p for p in rig.participants if isinstance(p, CannelloniTunnel)]
        return t

    def master(self) -> canopen.Network:
        assert self.b is not None
        network = canopen.Network(python_can_bus(self.b[0].bus("can0")))
        network.connect()
        return network

    def close(self) -> None:
        if self.b is not None:
            self.stop_b()
        rig, thread = self.a
        rig.request_stop()
        thread.join(10)
        rig.close()


@pytest.fixture
def pair() -> Iterator[Pair]:
    p = Pair()
    try:
        yield p
    finally:
        p.close()


def eds(rig: Rig) -> str:
    return str(rig.ready_info()["canopen"]["can0"]["axis2"]["eds"])


def sdo_and_pdo(network: canopen.Network, eds_file: str, cycles: int = 100) -> int:
    """CiA 301 SDO upload of 0x1008, then a SYNC loop with RPDO1/TPDO1 (type 1): TPDOs received."""
    node = network.add_node(2, eds_file)
    assert "gatewaylab" in node.sdo[0x1008].raw
    return csp_loop(network, node, cycles)[0]


def test_canopen_sdo_and_pdo_through_the_tunnel(pair: Pair) -> None:
    """A canopen master on rig B reads the drive on rig A (segmented SDO) and runs 100 SYNC cycles of
    RPDO1 out / TPDO1 back across the tunnel; sequence numbers show no lost datagram."""
    logging.getLogger("canopen").setLevel(logging.ERROR)
    network = pair.master()
    try:
        assert sdo_and_pdo(network, eds(pair.a[0])) >= 95
    finally:
        network.disconnect()
    a, b = pair.tunnel(pair.a[0]), pair.tunnel(pair.b[0])   # type: ignore[index]
    assert a.stats.received_frames > 100 and b.stats.received_frames > 100
    assert a.seq.missing == 0 and b.seq.missing == 0 and a.stats.bad_packets == 0


def test_garbage_and_foreign_datagrams_are_counted_and_dropped(pair: Pair) -> None:
    """A datagram that is no cannelloni DATA packet is dropped and counted (parseFrames() errors; an empty
    one is not parsed at all, udpthread.cpp run()); one from
    a host that is not the remote is refused (udpthread.cpp parsePacket(), check_peer); the tunnel works
    on."""
    tunnel = pair.tunnel(pair.a[0])
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as junk:
        junk.bind(("127.0.0.1", 0))
        for data in (b"", b"\x02", b"hello world", bytes.fromhex("0300000001"),
                     bytes.fromhex("0200000005 00000001 08")):
            junk.sendto(data, ("127.0.0.1", pair.port_a))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
        stranger.bind(("127.0.0.2", 0))
        stranger.sendto(bytes.fromhex("0200000001 00000123 00"), ("127.0.0.1", pair.port_a))
    network = pair.master()
    try:                                       # the datagrams above arrived before these SDO requests
        node = network.add_node(2, eds(pair.a[0]))
        assert "gatewaylab" in node.sdo[0x1008].raw
    finally:
        network.disconnect()
    assert tunnel.stats.bad_packets == 4 and tunnel.stats.foreign_packets == 1
    assert tunnel.stats.received_frames > 0 and pair.a[1].is_alive()


def test_the_far_side_vanishes_and_comes_back(pair: Pair) -> None:
    """Rig B stops (its port closes: ICMP port unreachable for rig A's datagrams): rig A runs on; a new
    rig B on the same port gets through again."""
    pair.stop_b()
    rig_a = pair.a[0]
    source = rig_a.buses["can0"].attach("source")
    last = threading.Event()
    rig_a.clock.call_soon_threadsafe(rig_a.buses["can0"].add_monitor,
                                     lambda frame, t: frame.can_id == 0x713 and last.set())
    for i in range(20):                           # frames for the tunnel while nobody listens
        rig_a.clock.call_soon_threadsafe(source.send, CanFrame(0x700 + i))
    assert last.wait(10) and pair.a[1].is_alive()
    pair.start_b()
    network = pair.master()
    try:
        node = network.add_node(2, eds(rig_a))
        assert "gatewaylab" in node.sdo[0x1008].raw
    finally:
        network.disconnect()


def test_tunnel_keys_are_checked() -> None:
    """One ConfigError line: the kind, HOST:PORT, per-id timeouts."""
    base = {"clock": "realtime", "bus": [{"name": "can0"}]}
    good = {"bus": "can0", "local": "127.0.0.1:0", "remote": "127.0.0.1:9"}
    with pytest.raises(ConfigError, match=r"\[\[tunnel\]\] #1.*kind = 'gre'"):
        parse_rig({**base, "tunnel": [{**good, "kind": "gre"}]})
    for bad, match in (({"remote": "127.0.0.1:0"}, "remote = '127.0.0.1:0' is not HOST:PORT"),
                       ({"local": "nohost"}, "local = 'nohost' is not HOST:PORT"),
                       ({"timeouts": {"x": 5}}, "timeouts: 'x' is not a CAN id")):
        config = parse_rig({**base, "tunnel": [{**good, **bad}]})
        with pytest.raises(ConfigError, match=match):
            Rig(config, endpoints=False)


# -- two namespaces, one veth pair --------------------------------------------------------------
def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


@contextlib.contextmanager
def two_namespaces() -> Iterator[tuple[str, str]]:
    """Namespaces A (10.201.0.1/30) and B (10.201.0.2/30) joined by one veth pair; removed on exit."""
    tag = f"{os.getpid() % 100000}"
    ns_a, ns_b = f"glca{tag}", f"glcb{tag}"
    made: list[str] = []
    try:
        for ns in (ns_a, ns_b):
            _ip("netns", "add", ns)
            made.append(ns)
        _ip("link", "add", f"gca{tag}", "netns", ns_a, "type", "veth", "peer", "name", f"gcb{tag}", "netns", ns_b)
        for ns, dev, addr in ((ns_a, f"gca{tag}", "10.201.0.1/30"), (ns_b, f"gcb{tag}", "10.201.0.2/30")):
            _ip("-n", ns, "addr", "add", addr, "dev", dev)
            _ip("-n", ns, "link", "set", dev, "up")
            _ip("-n", ns, "link", "set", "lo", "up")
        yield ns_a, ns_b
    finally:
        for ns in made:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def _netns_unavailable() -> str | None:
    if shutil.which("ip") is None:
        return "needs iproute2 (ip)"
    if os.geteuid() != 0:
        return "needs root to create network namespaces and a veth pair"
    return None


TUNNEL_RIG = """
clock = "realtime"
[[bus]]
name = "can0"
{drive}
[[tunnel]]
kind = "cannelloni"
bus = "can0"
local = "{local}:20000"
remote = "{remote}:20000"
timeout_us = 500
"""


@pytest.mark.net
@pytest.mark.skipif(_netns_unavailable() is not None, reason=str(_netns_unavailable()))
def test_two_rigs_in_two_namespaces_over_a_veth_pair(tmp_path: Path) -> None:
    """The issue's proof: `gatewaylab run` rig A (a drive) in namespace A and rig B in namespace B, whose
    only link is a veth pair; a canopen client on rig B (its Unix endpoint) runs SDO and PDO with the
    drive on rig A."""
    logging.getLogger("canopen").setLevel(logging.ERROR)
    drive = '[[drive]]\nbus = "can0"\nnode_id = 2\nserial = 0x1002\nname = "axis2"'
    (tmp_path / "a.toml").write_text(TUNNEL_RIG.format(drive=drive, local="10.201.0.1", remote="10.201.0.2"))
    (tmp_path / "b.toml").write_text(TUNNEL_RIG.format(drive="", local="10.201.0.2", remote="10.201.0.1"))
    with two_namespaces() as (ns_a, ns_b):
        (tmp_path / "a").mkdir()
        (tmp_path / "b").mkdir()
        with RigProcess(tmp_path / "a.toml", workdir=tmp_path / "a", prefix=("ip", "netns", "exec", ns_a)) as rig_a, \
                RigProcess(tmp_path / "b.toml", workdir=tmp_path / "b", prefix=("ip", "netns", "exec", ns_b)) as rig_b:
            assert rig_a.info["tunnels"]["tunnel-can0"]["local"] == "10.201.0.1:20000"
            network = canopen.Network()
            network.connect(interface="gatewaylab", channel=rig_b.endpoint("can0"))
            try:
                assert sdo_and_pdo(network, rig_a.info["canopen"]["can0"]["axis2"]["eds"]) >= 95
            finally:
                network.disconnect()
            assert rig_a.proc.poll() is None and rig_b.proc.poll() is None
