"""The gateway CAN channels an :class:`~gatewaylab.hosts.canhost.host.EthercatHost` drives, one class per gateway.

A channel is anything with ``before_exchange()``, ``after_exchange(wkc, expected)``, ``submit``
and ``stop`` (:class:`Channel`): :class:`EsdChannel` wraps the esd counter handshake
(:class:`~gatewaylab.hosts.esd_can_ethercat.EsdHost`), :class:`EcanChannel` one MCAN channel
of an ECAN-Lite through the MCAN Port (:mod:`gatewaylab.hosts.ecanlite.port`); with
ECAN-Lite channels the port's ``cycle_end`` makes the one exchange of the cycle for everybody.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Protocol

import can

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import LocalError
from gatewaylab.hosts.ecanlite.port import ChannelConfig
from gatewaylab.hosts.esd_can_ethercat import BitRate, EsdHost, for_bitrate

if TYPE_CHECKING:
    from gatewaylab.hosts.canhost.host import EthercatHost

#: Chapter 7 status word bits 0..2 = 3: the MCAN channel is bus-off.
_ECAN_BUSOFF = 3


class Channel(Protocol):
    """One gateway CAN channel as the host drives it."""

    name: str
    fd: bool
    position: int

    def before_exchange(self) -> None:
        """Write this cycle's outputs into the process image."""

    def after_exchange(self, wkc: int, expected: int) -> None:
        """Read the inputs the exchange brought (only trusted when ``wkc == expected``)."""

    def submit(self, frame: CanFrame) -> Callable[[], bool]:
        """Hand ``frame`` to the gateway; the returned check says when it is done (on the bus)."""

    def room(self, frame: CanFrame) -> bool:
        """Whether the Tx path takes ``frame`` now (else ``send()`` waits)."""

    def take(self) -> list[can.Message]:
        """The frames and error frames received since the last call, for the channel's buses."""

    def idle(self) -> bool:
        """Nothing in flight: ``send()`` settling and ``close()`` wait for this."""

    def stop(self) -> None:
        """Stop the channel's gateway side (close() brings the gateway to PREOP)."""

    def bus_off(self) -> bool:
        """The gateway's CAN controller is bus-off (``send()`` refuses, the bus state is ERROR)."""


class EsdChannel:
    """The one CAN channel of an esd CAN-EtherCAT at ``position`` (manual 5.1.5), configured at
    :meth:`EthercatHost.start`: bit rate (0xF800), status PDO 0x1A85 assigned for bus-off and Rx
    overflow. Received frames carry the time of the cycle that brought them (the esd Rx PDO has no
    time stamp, 5.1.5.1). Its Tx path holds the gateway's local Tx queue (0x8000:24) plus one Tx
    batch (0x8000:22): the frames queued or in flight beyond that wait in ``send()``."""

    fd = False

    def __init__(self, host: EthercatHost, position: int, bitrate: int, name: str) -> None:
        self.host = host
        self.position = position
        self.bitrate = bitrate
        self.name = name
        self.esd = EsdHost(host.backend, position, cycle_time=host.cycle_s, external_cycle=True)
        self._errors: list[can.Message] = []
        self._was_bus_off = False

    def configure(self) -> None:
        """Write the bit rate and assign the status PDO in PREOP (before the mapping is made)."""
        rate: BitRate = for_bitrate(self.bitrate)
        self.esd.configure(bitrate=rate, status_pdo=True)

    def attach(self) -> None:
        """Start the counter handshake in OP, its Tx limit the gateway's local queue plus one batch."""
        cfg = self.esd.config
        if cfg is not None:
            self.esd.tx_limit = cfg.local_tx_queue + cfg.tx_queue
        self.esd.attach()

    def before_exchange(self) -> None:
        """A new Tx batch and the Rx acknowledgement into the outputs."""
        self.esd.before_exchange()

    def after_exchange(self, wkc: int, expected: int) -> None:
        """Advance the handshake; an error frame when the status PDO turns bus-off."""
        if not self.esd.after_exchange(wkc, expected):
            return
        status = self.esd.pdo_status()
        off = bool(status is not None and status.bus_off)
        if off and not self._was_bus_off:
            self._errors.append(self.host.error_frame(self.name, bus_off=True))
        self._was_bus_off = off

    def submit(self, frame: CanFrame) -> Callable[[], bool]:
        """Queue ``frame``; done when the input Tx Transaction Number reached its number."""
        tn = self.esd.queue([frame])[0]
        return lambda: self.esd.completed(tn)

    def room(self, frame: CanFrame) -> bool:
        """Fewer frames queued and in flight than the gateway's Tx queues hold."""
        hs = self.esd.handshake
        return hs is None or hs.pending + hs.in_flight < hs.tx_limit

    def take(self) -> list[can.Message]:
        """Error frames first (bus-off, Rx overflow), then the received frames in order."""
        out, self._errors = self._errors, []
        hs = self.esd.handshake
        if hs is None:
            return out
        if hs.overflow_reported():
            out.append(self.host.error_frame(self.name, overflow=True))
        for rx in hs.take_received():
            out.append(rx.frame.to_message(self.host.timestamp(rx.timestamp), self.name))
        return out

    def idle(self) -> bool:
        """No frame written into a batch or accepted by the gateway is still waiting to complete."""
        hs = self.esd.handshake
        return hs is None or hs.in_flight == 0

    def bus_off(self) -> bool:
        """Bus-off as the status PDO 0x1A85 reported it in the last good cycle."""
        return self._was_bus_off

    def stop(self) -> None:
        """Back to PREOP: the gateway takes no more batches (queued frames stay unsent)."""
        self.esd.stop()


class EcanChannel:
    """One MCAN channel ``can_channel`` (0..3) of an ECAN-Lite at ``position`` through the MCAN
    Port of the host's adapter (manual 15.1). Configured at :meth:`EthercatHost.start` (classic or
    FD bit rates, 13.4; PDO multiplier ``pdo_n``, 5.2). The host parses each TxPDO once and hands
    each channel its frames; the chapter-7 status word's BUSOFF and the header's overflow count
    become error frames, a rejected TxPDO (parse error) an error frame of class CAN_ERR_CRTL.
    The TxPDO profile is 1 (delta16 timestamps, chapter 9): received frames carry the device's bus
    receive instant (8.4). Its Tx path is the next RxPDO's frame area: frames beyond one image
    wait in ``send()``."""

    def __init__(self, host: EthercatHost, position: int, can_channel: int, bitrate: int,
                 data_bitrate: int | None, fd: bool, pdo_n: int, name: str) -> None:
        if not 0 <= can_channel <= 3:
            raise LocalError(f"MCAN channel {can_channel} is not 0..3")
        self.host = host
        self.position = position
        self.can_channel = can_channel
        self.fd = fd
        self.pdo_n = pdo_n
        self.name = name
        # a python-can bus hands over every frame: the data path drains the whole RX cache each cycle
        self.config = replace(ChannelConfig.canfd(bitrate, data_bitrate or bitrate) if fd
                              else ChannelConfig.classic(bitrate), drain_all=True)
        self.slave_k = -1      # the adapter slave, set at start
        self._rx: list[can.Message] = []
        self._was_bus_off = False

    def before_exchange(self) -> None:
        """Nothing: the MCAN Port writes every channel's RxPDO in the host's one exchange."""

    def after_exchange(self, wkc: int, expected: int) -> None:
        """An error frame when the chapter-7 status word turns bus-off."""
        port = self.host.port
        assert port is not None
        word = port.status_words(self.slave_k)[self.can_channel]
        off = word & 0x07 == _ECAN_BUSOFF
        if off and not self._was_bus_off:
            self._rx.append(self.host.error_frame(self.name, bus_off=True))
        self._was_bus_off = off

    def deliver(self, msg: can.Message) -> None:
        """Keep a frame the host parsed out of the TxPDO for this channel until :meth:`take`."""
        self._rx.append(msg)

    def submit(self, frame: CanFrame) -> Callable[[], bool]:
        """Put ``frame`` in the next RxPDO; done when the slave has nothing pending."""
        port = self.host.port
        if port is None:
            raise LocalError("the host is not started")
        port.send_frame(self.slave_k, self.can_channel, frame)
        k = self.slave_k
        return lambda: port.pending(k) == 0

    def room(self, frame: CanFrame) -> bool:
        """``frame`` still fits into the next RxPDO's frame area."""
        port = self.host.port
        return port is None or port.fits_next_image(self.slave_k, port.frame_packet(self.can_channel, frame))

    def take(self) -> list[can.Message]:
        """The frames and error frames delivered since the last call."""
        out, self._rx = self._rx, []
        return out

    def idle(self) -> bool:
        """The slave has no frame pending in the Port."""
        port = self.host.port
        return port is None or port.pending(self.slave_k) == 0

    def bus_off(self) -> bool:
        """Bus-off as the chapter-7 status word reported it in the last cycle."""
        return self._was_bus_off

    def stop(self) -> None:
        """Nothing: the adapter brings every ECAN-Lite to PREOP (EthercatHost.close)."""


__all__ = ["Channel", "EcanChannel", "EsdChannel"]
