"""``[[tunnel]] kind = "cannelloni"``: a rig bus tunnelled over UDP to another rig or to cannelloni itself
(the format: :mod:`gatewaylab.bus.cannelloni`).

The tunnel is one controller on its bus and one UDP socket bound to ``local``; what the bus carries
is buffered and sent to ``remote`` when the buffer timeout expires or a datagram is full, and the
frames of datagrams from ``remote``'s host are put on the bus. It runs in the rig loop (``add_reader``,
the clock's timers); a garbage datagram, one from another host, or a peer that is gone (ICMP port
unreachable) is counted and logged, never fatal.
"""

from __future__ import annotations

import logging
import socket
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from gatewaylab.bus import cannelloni as cn
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import TimerHandle
from gatewaylab.common.errors import ConfigError, LocalError
from gatewaylab.plugin.participant import DeviceKind, Key, ParticipantBase, RigContext, section_error

__all__ = ["KEYS", "KIND", "CannelloniTunnel", "TunnelKind", "TunnelStats", "create"]


log = logging.getLogger(__name__)


@dataclass(slots=True)
class TunnelStats:
    """What the tunnel sent, received and lost (ready info, tests)."""
    sent_frames: int = 0
    sent_packets: int = 0
    send_errors: int = 0          # datagrams the socket refused (peer gone: ICMP unreachable, buffer full)
    received_frames: int = 0
    received_packets: int = 0
    bad_packets: int = 0          # garbage, wrong version/op code, truncated
    foreign_packets: int = 0      # from a host that is not ``remote`` (check_peer)
    refused: int = 0              # frames the bus could not carry (CAN FD on a classic bus, bus-off)


def _address(text: str, what: str, *, any_port: bool) -> tuple[str, int]:
    """``HOST:PORT`` (IPv6 as ``[::1]:PORT``); PORT 0 only where any free port will do."""
    host, _, port = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not host or not port.isdigit() or not (0 if any_port else 1) <= int(port) <= 65535:
        raise ConfigError(f"{what} = {text!r} is not HOST:PORT (PORT {'0' if any_port else '1'}..65535)")
    return host, int(port)


class CannelloniTunnel(ParticipantBase):
    """One ``[[tunnel]]``: the participant that joins ``bus`` to a cannelloni peer at ``remote``."""

    def __init__(self, rig: RigContext, name: str, bus: str, local: tuple[str, int], remote: tuple[str, int],
                 *, timeout: float = 0.001, timeouts: Mapping[tuple[int, bool], float] | None = None,
                 mtu: int = 1500, sort: bool = False, check_peer: bool = True) -> None:
        super().__init__(rig, name)
        self.clock = rig.clock
        self.vbus = rig.bus(bus)
        self.local = local
        self.remote = remote
        self.check_peer = check_peer
        family = socket.AF_INET6 if ":" in local[0] else socket.AF_INET
        header = cn.IPV6_HEADER_SIZE if family == socket.AF_INET6 else cn.IPV4_HEADER_SIZE
        self.sender = cn.Sender(mtu - header - cn.UDP_HEADER_SIZE, timeout, dict(timeouts or {}), sort)
        self.seq = cn.SeqTracker()
        self.stats = TunnelStats()
        self._due: TimerHandle | None = None
        self._due_at = 0.0
        self.sock: socket.socket | None = None
        self._family = family
        self.controller = self.attach(self.vbus, f"cannelloni {name}", on_frame=self._on_frame)

    # -- life cycle ---------------------------------------------------------------------------
    def start(self) -> None:
        """Bind the UDP socket and watch it on the rig's loop."""
        sock = socket.socket(self._family, socket.SOCK_DGRAM)
        try:
            sock.bind(self.local)
            sock.setblocking(False)
        except OSError:
            sock.close()
            raise
        self.sock = sock
        self.local = sock.getsockname()[:2]
        self.rig.add_reader(sock.fileno(), self._readable)

    def stop(self) -> None:
        """Cancel the pending send, close the socket and detach from the bus."""
        if self._due is not None:
            self._due.cancel()
            self._due = None
        if self.sock is not None:
            self.rig.remove_reader(self.sock.fileno())
            self.sock.close()
            self.sock = None
        self.detach_all()

    def ready_info(self) -> dict[str, Any]:
        """The tunnel's bus and local and remote addresses, for the --ready-file."""
        return {"tunnels": {self.name: {"kind": "cannelloni", "bus": self.vbus.name,
                                        "local": f"{self.local[0]}:{self.local[1]}",
                                        "remote": f"{self.remote[0]}:{self.remote[1]}"}}}

    # -- bus -> peer --------------------------------------------------------------------------
    def _on_frame(self, frame: CanFrame, t: float) -> None:
        within = self.sender.add(frame)
        if within <= 0:
            self._send_all()
            return
        when = self.clock.now() + within
        if self._due is None or when < self._due_at:
            if self._due is not None:
                self._due.cancel()
            self._due_at = when
            self._due = self.clock.call_at(when, self._timeout)

    def _timeout(self) -> None:
        self._due = None
        self._send_all()

    def _send_all(self) -> None:
        if self._due is not None:
            self._due.cancel()
            self._due = None
        while (packet := self.sender.packet()) is not None:
            self._send(packet)

    def _send(self, packet: bytes) -> None:
        if self.sock is None:
            return
        try:
            self.sock.sendto(packet, self.remote)
        except OSError as exc:   # the peer's port is closed (ICMP), the buffer is full: UDP loses it
            self.stats.send_errors += 1
            log.debug("tunnel %s: datagram to %s lost: %s", self.name, self.remote, exc)
            return
        self.stats.sent_packets += 1
        self.stats.sent_frames += cn.HEADER.unpack_from(packet)[3]

    # -- peer -> bus --------------------------------------------------------------------------
    def _readable(self) -> None:
        sock = self.sock
        if sock is None:
            return
        for _ in range(64):            # bounded: the loop serves the other endpoints in between
            try:
                data, addr = sock.recvfrom(65535)
            except BlockingIOError:
                return
            except OSError as exc:     # e.g. ECONNREFUSED reported for an earlier datagram
                self.stats.send_errors += 1
                log.debug("tunnel %s: %s", self.name, exc)
                continue
            if data:                   # udpthread.cpp parses only datagrams of > 0 bytes
                self._datagram(data, addr[0])

    def _datagram(self, data: bytes, host: str) -> None:
        if self.check_peer and host != self.remote[0]:
            self.stats.foreign_packets += 1
            if self.stats.foreign_packets == 1:
                log.warning("tunnel %s: datagram from %s, which is not the remote %s (check_peer = false "
                            "accepts any host)", self.name, host, self.remote[0])
            return
        packet = cn.decode_packet(data)
        if packet.error is not None:
            self.stats.bad_packets += 1
            level = logging.WARNING if self.stats.bad_packets == 1 else logging.DEBUG
            log.log(level, "tunnel %s: bad datagram from %s (%d bytes): %s", self.name, host, len(data),
                    packet.error)
        else:
            self.stats.received_packets += 1
            self.seq.seen(packet.seq_no)
        for frame in packet.frames:
            try:
                self.controller.send(frame)
            except LocalError:
                self.stats.refused += 1
            else:
                self.stats.received_frames += 1


def _timeouts(table: Mapping[str, Any], where: str) -> dict[tuple[int, bool], float]:
    """``timeouts = { "0x80" = 500, "0x18FF0001" = 2000 }``: per-id buffer timeouts in microseconds
    (upstream's -T table); an id above 0x7FF is a 29-bit one."""
    out: dict[tuple[int, bool], float] = {}
    for key, value in table.items():
        try:
            can_id = int(key, 0)
        except ValueError:
            raise section_error(where, f"timeouts: {key!r} is not a CAN id (e.g. \"0x80\")") from None
        if not 0 <= can_id <= cn.CAN_EFF_MASK or isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise section_error(where, f"timeouts: {key} = {value!r} must map a CAN id to microseconds >= 0")
        out[can_id, can_id > cn.CAN_SFF_MASK] = value / 1e6
    return out


KEYS: dict[str, Key] = {
    "name": Key(str),
    "bus": Key(str, required=True, bus=True, help="the [[bus]] to tunnel"),
    "local": Key(str, required=True, help="HOST:PORT to bind the UDP socket to (PORT 0: any free port)"),
    "remote": Key(str, required=True, help="HOST:PORT of the other end"),
    "timeout_us": Key(int, 1000, min=0, max=10_000_000, help="buffer timeout in microseconds (cannelloni -t)"),
    "timeouts": Key(dict, help="per-id buffer timeouts in microseconds, {\"0x80\" = 100} (cannelloni -T)"),
    "mtu": Key(int, 1500, min=100, max=65535, help="link MTU in bytes (cannelloni -m)"),
    "sort": Key(bool, False, help="send a buffer's frames ordered by id (cannelloni -s)"),
    "check_peer": Key(bool, True, help="accept datagrams only from remote's host (cannelloni without -p)"),
}


def create(rig: RigContext, cfg: dict[str, Any]) -> CannelloniTunnel:
    """The ``[[tunnel]]`` factory: a cannelloni UDP tunnel of a rig bus."""
    name = KIND.name_of(cfg)
    assert name is not None
    where = f"[[tunnel]] {name}"
    return CannelloniTunnel(rig, name, cfg["bus"], _address(cfg["local"], "local", any_port=True),
                            _address(cfg["remote"], "remote", any_port=False),
                            timeout=cfg["timeout_us"] / 1e6, timeouts=_timeouts(cfg["timeouts"] or {}, where),
                            mtu=cfg["mtu"], sort=cfg["sort"], check_peer=cfg["check_peer"])


@dataclass(frozen=True, slots=True)
class TunnelKind(DeviceKind):
    """``[[tunnel]]``: its ``kind`` names the tunnel format; cannelloni is the one there is."""

    def validate(self, cfg: Mapping[str, Any], where: str, buses: Any = None) -> dict[str, Any]:
        """Check a ``[[tunnel]]`` section (kind must be cannelloni), defaults filled in."""
        kind = cfg.get("kind", "cannelloni")
        if kind != "cannelloni":
            raise section_error(where, f"kind = {kind!r}: the tunnel kinds are 'cannelloni'")
        return DeviceKind.validate(self, cfg, where, buses)   # (a slotted dataclass: no zero-argument super())


KIND = TunnelKind("tunnel", create, KEYS, summary="a rig bus tunnelled over UDP in the cannelloni format",
                  table="tunnel", default_name=lambda cfg: f"tunnel-{cfg.get('bus')}")
