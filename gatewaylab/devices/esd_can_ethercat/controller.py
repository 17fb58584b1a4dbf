"""The CAN controller side of the esd CAN-EtherCAT: bit rate, bus status, statistics, firmware.

:class:`EsdController` is what the gateway does with its one CAN controller apart from the message
queues: the bit rate of 0xF800 (5.1.5.9: off the bus, listen-only, a rate, autobaud), the bus status
of 0xF108 (5.1.5.8), the counters and handler times of 0x2010 (5.1.4.2) and the web page's CAN
statistics (6.2.1 Figure 41), the firmware update by FoE or web page (5.3, 6.1.2) and its FoE file
(:class:`FirmwareFiles`). The MDP 5000 counter-handshake queues build on it in :mod:`.device`.
"""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.controller import Controller, ErrorState
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import LocalError
from gatewaylab.devices.esd_can_ethercat import bitrate as br
from gatewaylab.devices.esd_can_ethercat.objects import API_BAUD, BAUD_INDEX, esd_description
from gatewaylab.ethercat.errors import FoeError, FoeErrorCode
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.slave import Slave, SlaveApplication
from gatewaylab.od import Entry, SdoAbort, SdoAbortCode

__all__ = [
    "FIRMWARE_FILE",
    "FIRMWARE_HEADER",
    "FIRMWARE_PASSWORD",
    "UPDATE_LINES",
    "WARNING_LIMIT",
    "EsdController",
    "FirmwareFiles",
    "FrameKinds",
    "GatewayStats",
    "UpdateRefused",
]


#: 5.3: the file name a firmware update is written to by FoE, and its password.
FIRMWARE_FILE = "firmwareUpdate"
FIRMWARE_PASSWORD = 0
#: A firmware file may start with this line to carry its version (docs/devices/esd_can_ethercat.md).
FIRMWARE_HEADER = re.compile(rb"\ACAN-EtherCAT firmware (\d{1,3}(?:\.\d{1,3}){0,3})[\r\n\0]")
#: Figure 39: the update's output, line by line (shown as the update proceeds).
UPDATE_LINES = ("End of file found. All good.", "Unpacking updater. Please wait...", "img_upd.raw",
                "Flashing updater and rebooting...")
#: ISO 11898-1 error warning limit (0xF108:02 'Warning Limit reached').
WARNING_LIMIT = 96
CYCLIC_WINDOW, CAN_WINDOW = 10_000, 1_000   # 5.1.4.2: "within its last 10000 / 1000 calls"


class UpdateRefused(LocalError, ValueError):
    """A firmware update cannot start (one runs already, or the file is empty); a ValueError too, for
    the web page's backend protocol (6.1.2), which refuses an upload with one."""


@dataclass(slots=True)
class FrameKinds:
    """The frames of one direction by kind (0x2010:38-3B received, :3C-3F transmitted; Figure 41's
    'Data/RTR' lines) and their data bytes: counted the same way on receive and on transmit."""

    std: int = 0
    std_rtr: int = 0
    ext: int = 0
    ext_rtr: int = 0
    data_bytes: int = 0

    def count(self, frame: CanFrame) -> None:
        """One more frame of ``frame``'s kind."""
        if frame.extended:
            if frame.rtr:
                self.ext_rtr += 1
            else:
                self.ext += 1
        elif frame.rtr:
            self.std_rtr += 1
        else:
            self.std += 1
        self.data_bytes += len(frame.data)


@dataclass(slots=True)
class GatewayStats:
    """The counters behind 0x2010 (5.1.4.2) and the web page's CAN statistics (Figure 41)."""

    watchdog: int = 0            # 0x2010:08
    tx_requested: int = 0        # :30
    tx_forwarded: int = 0        # :31
    rx_copied: int = 0           # :32
    fifo_overrun: int = 0        # :35
    error_frames: int = 0        # :36
    aborted: int = 0             # :37
    rx: FrameKinds = field(default_factory=FrameKinds)    # :38-:3B
    tx: FrameKinds = field(default_factory=FrameKinds)    # :3C-:3F
    rx_bits: int = 0             # Figure 41 'Rcv bits' (stuffing as the bus model counts it)

    def reset(self) -> None:
        """Every counter back to 0 (0x2010 'Reset', a reboot)."""
        self.watchdog = self.tx_requested = self.tx_forwarded = self.rx_copied = 0
        self.fifo_overrun = self.error_frames = self.aborted = self.rx_bits = 0
        self.rx = FrameKinds()
        self.tx = FrameKinds()

    @property
    def rx_bytes(self) -> int:
        """Data bytes received (Figure 41 'Bytes' Rcv)."""
        return self.rx.data_bytes

    @property
    def tx_bytes(self) -> int:
        """Data bytes transmitted (Figure 41 'Bytes' Xmit)."""
        return self.tx.data_bytes


class _Window:
    """Handler times in microseconds over the last ``size`` calls (min/max/avg of 5.1.4.2)."""

    __slots__ = ("busy", "size", "values")

    def __init__(self, size: int) -> None:
        self.size = size
        self.values: deque[int] = deque(maxlen=size)
        self.busy = 0.0   # seconds spent since the last CPU usage reading

    def add(self, seconds: float) -> None:
        self.values.append(int(seconds * 1e6))
        self.busy += seconds

    def summary(self) -> tuple[int, int, int]:
        v = self.values
        return (min(v), max(v), sum(v) // len(v)) if v else (0, 0, 0)


class EsdController(SlaveApplication):
    """The gateway's CAN controller side (see the module docstring); :class:`~.device.EsdGateway`
    adds the queues, the EtherCAT hooks and ``slave``.

    Two hooks tell the queue side when the controller's setting changes:
    :meth:`_take_back_frames` before, :meth:`_bitrate_applied` after.
    """

    #: the EtherCAT side (made by the gateway once its application hooks exist)
    slave: Slave

    def __init__(self, clock: Clock, bus: VirtualBus | None, name: str, serial: int, update_duration: float) -> None:
        self.clock = clock
        self.bus = bus
        self.name = name
        self.serial = serial
        self.update_duration = update_duration
        self.controller: Controller | None = None
        self.stats = GatewayStats()
        self._cyclic = _Window(CYCLIC_WINDOW)
        self._can = _Window(CAN_WINDOW)
        self._started_at = clock.now()
        self._cpu_read_at = clock.now()
        self.setting: br.BitRateSetting = br.no_baudrate()
        self.detected: int = 0            # autobaud: the rate found (0 while detecting)
        self._autobaud_index = 0
        self._autobaud_next: TimerHandle | None = None
        self._status_cache: tuple[Any, ...] = ()
        # firmware update (5.3, 6.1.2)
        self.firmware_version = esd_description().software_version
        self._update_timer: TimerHandle | None = None
        self._update_started = 0.0
        self._update_version: str | None = None
        self.updates = 0
        self.reboots = 0

    # ------------------------------------------------------------------ hooks of the queue side
    def _take_back_frames(self) -> None:
        """The controller is about to change its setting: frames handed to it and not yet sent come back."""

    def _bitrate_applied(self) -> None:
        """The controller runs at its new setting (or found its rate): send what waits, or abort it."""

    def reboot(self) -> None:
        """Restart the whole device (6.1.3, the end of a firmware update): the gateway resets its
        settings, queues and statistics and brings the controller side back with them."""

    def _check_bitrate(self, entry: Entry, value: Any) -> None:
        """5.1.5.9: Table 6 indexes 0..6 or 255; API values per Tables 7-10 (else 0x06090030)."""
        try:
            if entry.subindex == BAUD_INDEX:
                br.from_index(int(value))
            elif entry.subindex == API_BAUD:
                br.from_api(int(value))
        except br.BitRateError as exc:
            raise SdoAbort(SdoAbortCode.VALUE_RANGE_EXCEEDED, str(exc)) from None

    # ------------------------------------------------------------------ bit rate
    def _effective_setting(self) -> br.BitRateSetting:
        od = self.slave.od
        table = br.from_index(int(od.get(0xF800, BAUD_INDEX)))
        return table if table is not None else br.from_api(int(od.get(0xF800, API_BAUD)))

    def _apply_bitrate(self) -> None:
        """Put the controller in the mode 0xF800 asks for: off the bus (NTCAN_NO_BAUDRATE),
        listen-only while detecting (NTCAN_AUTOBAUD), or at a rate, active or listen-only (LOM)."""
        self.setting = setting = self._effective_setting()
        if self._autobaud_next is not None:
            self._autobaud_next.cancel()
            self._autobaud_next = None
        self.detected = 0
        ctrl, bus = self.controller, self.bus
        if ctrl is None or bus is None:
            return
        self._take_back_frames()
        if setting.mode is br.Mode.NONE:
            bus.disconnect(ctrl)
            ctrl.listen_only = True
        elif setting.mode is br.Mode.AUTOBAUD:
            self._autobaud_index = 0
            ctrl.listen_only = True
            ctrl.bitrate = br.TABLE9[br.AUTOBAUD_ORDER[0]]
            bus.reconnect(ctrl)
        else:
            ctrl.listen_only = setting.listen_only
            ctrl.bitrate = setting.bitrate
            bus.reconnect(ctrl)
        self._bitrate_applied()
        self._refresh_status()

    def _can_send(self) -> bool:
        ctrl = self.controller
        return (ctrl is not None and ctrl.connected and not ctrl.listen_only
                and ctrl.state is not ErrorState.BUS_OFF)

    def _may_send(self) -> bool:
        """The bit rate setting lets the gateway send (not off the bus, listen-only or still detecting)."""
        s = self.setting
        return not (s.mode is br.Mode.NONE or (s.listen_only and not self.detected))

    def _autobaud_step(self) -> None:
        """A frame at a foreign rate (form error): try the next rate of the table."""
        self._autobaud_next = None
        ctrl = self.controller
        if ctrl is None or self.setting.mode is not br.Mode.AUTOBAUD or self.detected:
            return
        self._autobaud_index = (self._autobaud_index + 1) % len(br.AUTOBAUD_ORDER)
        ctrl.bitrate = br.TABLE9[br.AUTOBAUD_ORDER[self._autobaud_index]]

    def _autobaud_found(self) -> None:
        """A frame received without error between two other nodes: the rate is found, go active."""
        ctrl = self.controller
        assert ctrl is not None
        self.detected = ctrl.bitrate
        ctrl.listen_only = False
        self._bitrate_applied()

    def actual_timing(self) -> br.BitTiming | None:
        """The controller's bit timing now (a detected autobaud rate included)."""
        if self.setting.mode is br.Mode.AUTOBAUD:
            return br.timing_for(self.detected) if self.detected else None
        return self.setting.timing

    # ------------------------------------------------------------------ status and statistics
    def _refresh_status(self) -> None:
        """0xF108 from the controller (5.1.5.8): bus off, warning limit, Rx overflow, REC, TEC."""
        ctrl = self.controller
        tec = ctrl.tec if ctrl is not None else 0
        rec = ctrl.rec if ctrl is not None else 0
        bus_off = ctrl is not None and ctrl.state is ErrorState.BUS_OFF
        status = (bus_off, tec >= WARNING_LIMIT or rec >= WARNING_LIMIT or bus_off,
                  self.stats.fifo_overrun > 0, min(rec, 255), tec, rec)
        if status == self._status_cache:
            return
        self._status_cache = status
        self.slave.od.put_many(((0xF108, 1), (0xF108, 2), (0xF108, 3), (0xF108, 0x21), (0xF108, 0x22)),
                               (status[0], status[1], status[2], status[3], min(tec, 255)))

    def statistics(self) -> dict[int, int]:
        """0x2010 subindex -> value now (5.1.4.2)."""
        st = self.stats
        rx, tx = st.rx, st.tx
        cmin, cmax, cavg = self._cyclic.summary()
        hmin, hmax, havg = self._can.summary()
        now = self.clock.now()
        span = now - self._cpu_read_at
        usage = 0 if span <= 0 else min(100, round(100 * (self._cyclic.busy + self._can.busy) / span))
        self._cpu_read_at = now
        self._cyclic.busy = self._can.busy = 0.0
        return {0x02: cmin, 0x03: cmax, 0x04: cavg, 0x05: hmin, 0x06: hmax, 0x07: havg, 0x08: st.watchdog,
                0x20: usage, 0x21: 0, 0x30: st.tx_requested, 0x31: st.tx_forwarded, 0x32: st.rx_copied,
                0x34: 0, 0x35: st.fifo_overrun, 0x36: st.error_frames, 0x37: st.aborted, 0x38: rx.std,
                0x39: rx.std_rtr, 0x3A: rx.ext, 0x3B: rx.ext_rtr, 0x3C: tx.std, 0x3D: tx.std_rtr,
                0x3E: tx.ext, 0x3F: tx.ext_rtr}

    def _refresh_statistics(self) -> None:
        od = self.slave.od
        for sub, value in self.statistics().items():
            od.put(0x2010, sub, value & 0xFFFFFFFF)

    def _reset_statistics(self, entry: Entry, value: Any) -> None:
        """5.1.4.2 'Reset': writing resets the statistics; reading then shows the time of the reset
        in milliseconds since the device started."""
        if entry.subindex != 1:
            return
        self.reset_statistics()

    def reset_statistics(self) -> None:
        """Zero every counter of 0x2010 (and the web page's statistics)."""
        self.stats.reset()
        self._cyclic = _Window(CYCLIC_WINDOW)
        self._can = _Window(CAN_WINDOW)
        self._cpu_read_at = self.clock.now()
        self.slave.od.put(0x2010, 1, round(1000 * (self.clock.now() - self._started_at)) & 0xFFFFFFFF)
        self._refresh_status()

    # ------------------------------------------------------------------ firmware update and reboot
    def start_update(self, data: bytes) -> None:
        """Begin a firmware update with ``data`` (FoE 5.3 or the web page 6.1.2): after
        ``update_duration`` on the clock the device takes the version the file carries and reboots."""
        if self._update_timer is not None:
            raise UpdateRefused("a firmware update is already running")
        if not data:
            raise UpdateRefused("the firmware file is empty")
        m = FIRMWARE_HEADER.match(data[:64])
        self._update_version = m.group(1).decode("ascii") if m else None
        self._update_started = self.clock.now()
        self.updates += 1
        self._update_timer = self.clock.call_later(self.update_duration, self._finish_update)

    def update_progress(self) -> str | None:
        """Figure 39's output so far; None when no update runs."""
        if self._update_timer is None:
            return None
        part = (self.clock.now() - self._update_started) / self.update_duration if self.update_duration > 0 else 1
        shown = 2 + int(part * (len(UPDATE_LINES) - 1))
        return "\n".join(UPDATE_LINES[:min(shown, len(UPDATE_LINES))]) + "\n"

    @property
    def updating(self) -> bool:
        """A firmware update is running."""
        return self._update_timer is not None

    def _finish_update(self) -> None:
        self._update_timer = None
        if self._update_version is not None:
            self.firmware_version = self._update_version
        self.reboot()


class FirmwareFiles:
    """FoE of 5.3: ``firmwareUpdate`` with password 0, in BOOT only (0x8008 'bootstrap only' in
    any other state); nothing to read."""

    def __init__(self, gateway: EsdController) -> None:
        self.gateway = gateway

    def foe_read(self, name: str, password: int) -> bytes:
        """The gateway offers no files."""
        raise FoeError(f"no file {name!r}", FoeErrorCode.NOT_FOUND)

    def foe_check_write(self, name: str, password: int) -> None:
        """The write request itself is refused (before any data) for another file name, another
        state than BOOT or another password."""
        if name != FIRMWARE_FILE:
            raise FoeError(f"no file {name!r} (only {FIRMWARE_FILE!r})", FoeErrorCode.NOT_FOUND)
        if self.gateway.slave.state != AlState.BOOT:
            raise FoeError("firmware updates only in BOOT", FoeErrorCode.BOOTSTRAP_ONLY)
        if password != FIRMWARE_PASSWORD:
            raise FoeError("wrong password", FoeErrorCode.NO_RIGHTS)

    def foe_write(self, name: str, password: int, data: bytes) -> None:
        """Start the update, or refuse with the FoE error code."""
        g = self.gateway
        self.foe_check_write(name, password)
        try:
            g.start_update(data)
        except UpdateRefused as exc:
            raise FoeError(str(exc), FoeErrorCode.ILLEGAL) from None
