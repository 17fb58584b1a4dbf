"""``[[bridge]]``: a virtual bus joined to any python-can bus (socketcan, pcan, kvaser, slcan, gs_usb,
udp_multicast, virtual, ...), frames both ways.

The bridge is one controller on the virtual bus and one python-can bus on the real side. Frames the
virtual bus carries go out with their virtual-bus time as ``Message.timestamp`` (Unix time; an
interface that keeps timestamps, e.g. ``virtual`` with ``preserve_timestamps``, passes it on);
frames of other nodes on the real side are put on the virtual bus. No echo loops: the bridge's
controller does not hear its own frames, and what the real side hands back of the bridge's own
frames (``receive_own_messages``, ``is_rx`` false) is dropped. The real side's failures (an adapter
unplugged, a driver error, bus-off) are logged in one line and the adapter is reopened with an
exponential back-off while the rig runs on; an interface python-can does not have (or whose driver
library is missing) stops the rig at start with one line.

Threads: a reader thread owns opening, receiving and reopening; a writer thread sends. Frames cross
to the rig thread with ``clock.call_soon_threadsafe``; nothing here touches protocol state otherwise.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Mapping
from typing import Any

import can

from gatewaylab.bus.bridge import Backoff, BridgeStats, EchoFilter, LinkState, Verdict, classify
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import ConfigError, FrameError, LocalError
from gatewaylab.plugin.participant import DeviceKind, Key, ParticipantBase, RigContext

__all__ = ["KEYS", "KIND", "LOOPING_INTERFACES", "MAX_QUEUE", "POLL", "SEND_TIMEOUT", "PythonCanBridge", "create"]


log = logging.getLogger(__name__)

#: seconds one recv() waits, so a stopping bridge notices within this
POLL = 0.05
#: seconds one send() may block on a full adapter queue before the frame counts as lost
SEND_TIMEOUT = 0.1
#: frames waiting for the writer thread; more are lost (a real bus slower than the virtual one)
MAX_QUEUE = 10_000
#: interfaces that hand a bus's own frames back as received ones (``echo_filter`` defaults on)
LOOPING_INTERFACES = frozenset({"udp_multicast"})


class PythonCanBridge(ParticipantBase):
    """One ``[[bridge]]``: the participant that joins ``bus`` to ``can.Bus(interface, channel, **kwargs)``."""

    def __init__(self, rig: RigContext, name: str, bus: str, interface: str, channel: str | int | None,
                 kwargs: Mapping[str, Any], *, retry_initial: float = 0.1, retry_max: float = 5.0,
                 echo_filter: bool | None = None) -> None:
        super().__init__(rig, name)
        self.clock = rig.clock
        self.vbus = rig.bus(bus)
        self.interface = interface
        self.channel = channel
        self.kwargs = dict(kwargs)
        self.stats = BridgeStats()
        self._state = LinkState.CONNECTING
        self._changed = threading.Condition()
        self.last_error = ""
        self.backoff = Backoff(retry_initial, retry_max)
        if echo_filter is None:
            echo_filter = interface in LOOPING_INTERFACES
        #: own frames the real side hands back unmarked (None: it marks them, ``is_rx`` false)
        self.echo_filter = EchoFilter() if echo_filter else None
        self._echo_lock = threading.Lock()
        self._real: can.BusABC | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._queue: queue.Queue[tuple[CanFrame, float] | None] = queue.Queue(MAX_QUEUE)
        self._overflow = 0
        self._lost_tx = 0
        self._failures = 0
        #: seconds the reader waits before the next attempt to open the real side
        self._pause = 0.0
        self._threads: list[threading.Thread] = []
        self.controller = self.attach(self.vbus, f"bridge {name}", on_frame=self._on_frame)

    @property
    def state(self) -> LinkState:
        """The link's state (LinkState), shown in ready info and logs."""
        return self._state

    @state.setter
    def state(self, value: LinkState) -> None:
        with self._changed:
            self._state = value
            self._changed.notify_all()

    def wait_for(self, state: LinkState, timeout: float) -> bool:
        """Block (any thread but the rig's) until the link is in ``state``; False after ``timeout``."""
        with self._changed:
            return self._changed.wait_for(lambda: self._state is state, timeout)

    @property
    def where(self) -> str:
        """The python-can interface and channel, as log lines name them."""
        return f"{self.interface} channel {self.channel!r}" if self.channel is not None else self.interface

    # -- life cycle ---------------------------------------------------------------------------
    def start(self) -> None:
        """Open the real side once now (a missing interface or driver is a ConfigError), then run."""
        self._open(first=True)
        for target, what in ((self._reader, "rx"), (self._writer, "tx")):
            thread = threading.Thread(target=target, name=f"bridge-{self.name}-{what}", daemon=True)
            thread.start()
            self._threads.append(thread)

    def stop(self) -> None:
        """Stop the bridge thread, close the python-can bus and detach from the virtual bus."""
        self._stop.set()
        try:
            self._queue.put_nowait(None)
        except queue.Full:
            pass
        for thread in self._threads:
            thread.join(2.0)
        self._close()
        self.state = LinkState.CLOSED
        self.detach_all()

    def ready_info(self) -> dict[str, Any]:
        """The bridge's bus, interface, channel and state for the --ready-file."""
        return {"bridges": {self.name: {"bus": self.vbus.name, "interface": self.interface,
                                        "channel": self.channel, "state": self.state.value}}}

    @property
    def lost(self) -> int:
        """virtual -> real frames that did not reach the real side."""
        return self._overflow + self._lost_tx

    # -- real side ----------------------------------------------------------------------------
    def _open(self, first: bool = False) -> bool:
        kwargs = dict(self.kwargs)
        if self.channel is not None:
            kwargs["channel"] = self.channel
        try:
            real = can.Bus(interface=self.interface, **kwargs)
        except can.CanInterfaceNotImplementedError as exc:
            if first:
                raise ConfigError(f"[[bridge]] {self.name}: python-can interface {self.interface!r} is not "
                                  f"available: {_one_line(exc)}") from None
            self._failed(exc, LinkState.DOWN)
            return False
        except Exception as exc:  # every driver fails its own way (CanError, OSError, serial, usb ...)
            self._failed(exc, LinkState.DOWN)
            return False
        if self._stop.is_set():          # stopped while the adapter was opening
            real.shutdown()
            return False
        with self._lock:
            self._real = real
        if self._failures:
            self.stats.reconnects += 1
            log.warning("bridge %s: %s is up again (after %d failed attempt(s))", self.name, self.where,
                        self._failures)
        self._failures = 0
        self.backoff.reset()
        self.state = LinkState.UP
        return True

    def _failed(self, exc: BaseException | str, state: LinkState) -> None:
        """One line per outage (then quiet until it is up again); the reader waits the back-off."""
        self._close()
        self.state = state
        self.last_error = exc if isinstance(exc, str) else _one_line(exc)
        delay = self.backoff.next()
        self._failures += 1
        level = logging.WARNING if self._failures == 1 else logging.DEBUG
        log.log(level, "bridge %s: %s %s: %s; retrying (next attempt in %.1f s, then up to every %.0f s)",
                self.name, self.where, state.value, self.last_error, delay, self.backoff.maximum)
        self._pause = delay

    def _close(self) -> None:
        with self._lock:
            real, self._real = self._real, None
        if real is not None:
            try:
                real.shutdown()
            except Exception as exc:
                log.debug("bridge %s: shutdown of %s failed: %s", self.name, self.where, exc)

    def _reader(self) -> None:
        while not self._stop.is_set():
            real = self._real
            if real is None:
                if self._pause:
                    self._stop.wait(self._pause)
                    self._pause = 0.0
                else:
                    self._open()
                continue
            try:
                msg = real.recv(POLL)
            except Exception as exc:
                if not self._stop.is_set():
                    self._failed(exc, LinkState.DOWN)
                continue
            if msg is None:
                continue
            verdict = classify(msg.is_error_frame, msg.is_rx, msg.arbitration_id)
            if verdict is Verdict.FORWARD:
                try:
                    frame = CanFrame.from_message(msg)
                except FrameError:
                    self.stats.error_frames += 1
                    continue
                if self.echo_filter is not None:
                    with self._echo_lock:
                        echo = self.echo_filter.is_echo(frame, time.monotonic())
                    if echo:
                        self.stats.echoes += 1
                        continue
                self.clock.call_soon_threadsafe(self._inject, frame)
            elif verdict is Verdict.ECHO:
                self.stats.echoes += 1
            else:
                self.stats.error_frames += 1
                if verdict is Verdict.BUS_OFF:
                    self._failed("the controller is bus-off", LinkState.BUS_OFF)

    def _writer(self) -> None:
        epoch = self.clock.wall_epoch
        while True:
            item = self._queue.get()
            if item is None or self._stop.is_set():
                return
            frame, t = item
            real = self._real
            if real is None:
                self._lost_tx += 1
                continue
            if self.echo_filter is not None:
                with self._echo_lock:
                    self.echo_filter.sent(frame, time.monotonic())
            try:
                real.send(frame.to_message(epoch + t, self.channel if isinstance(self.channel, str) else None),
                          SEND_TIMEOUT)
            except Exception as exc:
                self._lost_tx += 1
                log.debug("bridge %s: send to %s failed: %s", self.name, self.where, exc)
            else:
                self.stats.to_real += 1

    # -- rig thread ---------------------------------------------------------------------------
    def _on_frame(self, frame: CanFrame, t: float) -> None:
        if self.state is not LinkState.UP:
            self._overflow += 1
            return
        try:
            self._queue.put_nowait((frame, t))
        except queue.Full:
            self._overflow += 1

    def _inject(self, frame: CanFrame) -> None:
        if self.state is LinkState.CLOSED:
            return
        try:
            self.controller.send(frame)
        except LocalError as exc:
            self.stats.refused += 1
            log.debug("bridge %s: frame %s refused by the virtual bus: %s", self.name, frame, exc)
        else:
            self.stats.from_real += 1


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return f"{type(exc).__name__}: {text}" if type(exc).__name__ not in text else text


KEYS: dict[str, Key] = {
    "name": Key(str),
    "bus": Key(str, required=True, bus=True, help="the [[bus]] to bridge"),
    "interface": Key(str, required=True, help="a python-can interface: socketcan, pcan, kvaser, slcan, gs_usb, "
                                              "udp_multicast, virtual, ..."),
    "channel": Key(object, help="the interface's channel: a string or an integer"),
    "bitrate": Key(int, min=1, max=1_000_000, help="bit/s"),
    "fd": Key(bool),
    "data_bitrate": Key(int, min=1, max=12_000_000, help="bit/s"),
    "receive_own_messages": Key(bool),
    "options": Key(dict, help="more keyword arguments of can.Bus(), passed as they are"),
    "echo_filter": Key(bool, help="drop received frames equal to ones the bridge just sent (default: on for "
                                  "interfaces that loop their own frames back, udp_multicast)"),
    "retry_initial": Key(float, 0.1, min=0.001, max=60, help="seconds before the first reopen attempt"),
    "retry_max": Key(float, 5.0, min=0.001, max=3600, help="longest wait between reopen attempts, seconds"),
}


def create(rig: RigContext, cfg: dict[str, Any]) -> PythonCanBridge:
    """The ``[[bridge]]`` factory: a bridge between a rig bus and a python-can interface."""
    channel = cfg["channel"]
    if channel is not None and (isinstance(channel, bool) or not isinstance(channel, str | int)):
        raise ConfigError(f"channel must be a string or an integer, got {channel!r}")
    kwargs = {key: cfg[key] for key in ("bitrate", "fd", "data_bitrate", "receive_own_messages")
              if cfg[key] is not None}
    kwargs.update(cfg["options"] or {})
    name = KIND.name_of(cfg)
    assert name is not None
    return PythonCanBridge(rig, name, cfg["bus"], cfg["interface"], channel, kwargs,
                           retry_initial=cfg["retry_initial"], retry_max=max(cfg["retry_max"], cfg["retry_initial"]),
                           echo_filter=cfg["echo_filter"])


KIND = DeviceKind(
    "bridge", create, KEYS, summary="a virtual bus joined to a python-can bus (real adapter or other interface)",
    table="bridge", default_name=lambda cfg: f"bridge-{cfg.get('bus')}-{cfg.get('interface')}")
