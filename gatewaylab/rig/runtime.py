"""The rig runtime: builds buses and participants from a rig file and runs them.

In real time one thread (the one calling :meth:`Rig.run`) owns the clock and every protocol
state; it waits in ``select`` until the next timer or until a file descriptor is ready, and
holds ``clock.lock`` while it runs callbacks. With a simulated clock nothing runs by itself:
the owner drives ``rig.clock`` (tests, teaching scripts).
"""

from __future__ import annotations

import contextlib
import logging
import os
import selectors
import shutil
import socket
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from ..bus.bus import VirtualBus
from ..bus.transport.server import BusServer
from ..bus.transport.trace import Trace
from ..common.clock import Clock, RealTimeClock, SimulatedClock
from ..common.errors import ConfigError
from . import kinds
from .config import RigConfig, load_rig

log = logging.getLogger(__name__)


class Participant(Protocol):
    """Anything a rig file section creates: drives, gateways, EtherCAT segments."""

    name: str

    def start(self) -> None: ...
    def stop(self) -> None: ...
    def ready_info(self) -> dict[str, Any]: ...


def merge_info(into: dict[str, Any], info: dict[str, Any]) -> None:
    """Deep-merge one participant's ready info (e.g. {"usb": {"idx1": ...}}) into the whole."""
    for key, value in info.items():
        if isinstance(value, dict) and isinstance(into.get(key), dict):
            merge_info(into[key], value)
        else:
            into[key] = value


class Rig:
    """Buses, participants and (in real time) the loop that runs them."""

    def __init__(self, config: RigConfig, *, clock: Clock | None = None,
                 state_dir: Path | None = None, endpoints: bool | None = None) -> None:
        self.config = config
        if clock is None:
            clock = SimulatedClock() if config.clock == "simulated" else RealTimeClock()
        self.clock = clock
        self.realtime = not clock.is_simulated
        self._own_state_dir = state_dir is None
        self.state_dir = Path(tempfile.mkdtemp(prefix="gatewaylab-")) if state_dir is None else state_dir
        self.state_dir.mkdir(parents=True, exist_ok=True)
        self.buses: dict[str, VirtualBus] = {}
        self.participants: list[Participant] = []
        self.servers: dict[str, BusServer] = {}
        self.traces: list[Trace] = []
        # select() waits with microsecond resolution; epoll/poll round up to whole milliseconds,
        # which would stretch every 100 us CAN frame to 1 ms.
        self._selector = selectors.SelectSelector()
        self._readers: dict[int, Callable[[], None]] = {}
        self._writers: dict[int, Callable[[], None]] = {}
        self._stop = threading.Event()
        self.callback_errors = 0
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self.add_reader(self._wake_r.fileno(), self._drain_wakeups)
        if isinstance(clock.lock, contextlib.nullcontext):
            clock.lock = threading.RLock()
        clock.wakeup = self.wake
        if isinstance(clock, RealTimeClock):
            clock.on_error = self._callback_failed
        for bc in config.buses:
            self.buses[bc.name] = VirtualBus(clock, bc.name, bc.bitrate, bc.data_bitrate, bc.timing)
        with_endpoints = self.realtime if endpoints is None else endpoints
        if with_endpoints:
            for bc in config.buses:
                if bc.endpoint == "unix":
                    self.servers[bc.name] = BusServer(self.buses[bc.name], self,
                                                      unix_path=self.state_dir / f"{bc.name}.sock")
                elif bc.endpoint == "tcp":
                    self.servers[bc.name] = BusServer(self.buses[bc.name], self, tcp_port=bc.tcp_port)
        self._build_participants()
        self._started = False

    @classmethod
    def from_file(cls, path: str | Path | None = None, **kwargs: Any) -> Rig:
        return cls(load_rig(path), **kwargs)

    # -- construction -----------------------------------------------------------------------
    def _build_participants(self) -> None:
        cfg = self.config
        if cfg.drives:
            create_drive = kinds.resolve(kinds.DRIVE_FACTORY, "[[drive]]")
            for entry in cfg.drives:
                self.participants.append(create_drive(self, dict(entry)))
        ethercat_devices: list[Participant] = []
        for entry in cfg.devices:
            kind = entry["kind"]
            spec = kinds.DEVICE_FACTORIES.get(kind)
            if spec is None:
                raise ConfigError(f"unknown device kind {kind!r} (known: {sorted(kinds.DEVICE_FACTORIES)})")
            device = kinds.resolve(spec, f"device kind {kind!r}")(self, dict(entry))
            self.participants.append(device)
            if getattr(device, "is_ethercat", False):
                ethercat_devices.append(device)
        if cfg.ethercat is not None:
            create_segment = kinds.resolve(kinds.SEGMENT_FACTORY, "[ethercat]")
            self.participants.append(create_segment(self, dict(cfg.ethercat), ethercat_devices))

    def bus(self, name: str) -> VirtualBus:
        try:
            return self.buses[name]
        except KeyError:
            raise ConfigError(f"no bus named {name!r} in this rig (buses: {sorted(self.buses)})") from None

    def add_trace(self, bus_name: str, path: str | Path) -> Trace:
        """Record every frame of a bus with python-can's writer for the file's suffix."""
        trace = Trace(self.bus(bus_name), Path(path))
        self.traces.append(trace)
        return trace

    # -- reactor interface (used by transports) ----------------------------------------------
    def add_reader(self, fd: int, callback: Callable[[], None]) -> None:
        self._readers[fd] = callback
        self._update(fd)

    def remove_reader(self, fd: int) -> None:
        self._readers.pop(fd, None)
        self._update(fd)

    def add_writer(self, fd: int, callback: Callable[[], None]) -> None:
        self._writers[fd] = callback
        self._update(fd)

    def remove_writer(self, fd: int) -> None:
        self._writers.pop(fd, None)
        self._update(fd)

    def _update(self, fd: int) -> None:
        events = (selectors.EVENT_READ if fd in self._readers else 0) | (
            selectors.EVENT_WRITE if fd in self._writers else 0)
        try:
            self._selector.get_key(fd)
            registered = True
        except KeyError:
            registered = False
        if events and registered:
            self._selector.modify(fd, events)
        elif events:
            self._selector.register(fd, events)
        elif registered:
            self._selector.unregister(fd)

    def _callback_failed(self, exc: BaseException) -> None:
        """A participant's callback raised: log it with its traceback and keep the rig running."""
        self.callback_errors += 1
        log.error("callback failed, rig keeps running: %r", exc, exc_info=exc)

    def wake(self) -> None:
        """Interrupt the loop's wait (safe from any thread), e.g. after changing what it waits for."""
        try:
            self._wake_w.send(b"\0")
        except (BlockingIOError, OSError):
            pass

    def _drain_wakeups(self) -> None:
        try:
            while self._wake_r.recv(4096):
                pass
        except (BlockingIOError, OSError):
            pass

    # -- life cycle ---------------------------------------------------------------------------
    def start(self) -> None:
        if self._started:
            return
        self._started = True
        with self.clock.lock:
            for p in self.participants:
                p.start()

    def ready_info(self) -> dict[str, Any]:
        info: dict[str, Any] = {"pid": os.getpid(), "buses": {}}
        for name, bus in self.buses.items():
            entry: dict[str, Any] = {"bitrate": bus.bitrate}
            if bus.data_bitrate:
                entry["data_bitrate"] = bus.data_bitrate
            if name in self.servers:
                entry["endpoint"] = self.servers[name].endpoint
            info["buses"][name] = entry
        for p in self.participants:
            merge_info(info, p.ready_info())
        return info

    def poll(self, timeout: float | None) -> None:
        """One loop iteration: wait for I/O or the next timer, then run what is due."""
        clock = self.clock
        deadline = clock.next_deadline()
        if deadline is not None:
            wait = max(0.0, deadline - clock.now())
            timeout = wait if timeout is None else min(timeout, wait)
        for key, events in self._selector.select(timeout):
            fd = key.fd
            with clock.lock:
                try:
                    if events & selectors.EVENT_READ and fd in self._readers:
                        self._readers[fd]()
                    if events & selectors.EVENT_WRITE and fd in self._writers:
                        self._writers[fd]()
                except Exception as exc:
                    self._callback_failed(exc)
        if isinstance(clock, RealTimeClock):
            clock.run_due()

    def run(self, until: Callable[[], bool] | None = None) -> None:
        """Run in real time until :meth:`request_stop` (or ``until()`` returns True)."""
        if not self.realtime:
            raise ConfigError("Rig.run() needs a real-time clock; drive a simulated rig's clock yourself")
        self.start()
        while not self._stop.is_set() and not (until is not None and until()):
            self.poll(0.25)

    def request_stop(self) -> None:
        """Ask :meth:`run` to return; safe from signal handlers and other threads."""
        self._stop.set()
        self.wake()

    def run_in_thread(self) -> threading.Thread:
        """Run the real-time loop in a daemon thread (for tests and embedding)."""
        thread = threading.Thread(target=self.run, name="gatewaylab-rig", daemon=True)
        thread.start()
        return thread

    def close(self) -> None:
        """Stop participants, close endpoints and traces, remove the state folder."""
        with self.clock.lock:
            for p in reversed(self.participants):
                try:
                    p.stop()
                except Exception:
                    log.exception("stopping %s failed", getattr(p, "name", p))
            for server in self.servers.values():
                server.close()
            for trace in self.traces:
                trace.close()
        self.remove_reader(self._wake_r.fileno())
        self._wake_r.close()
        self._wake_w.close()
        self._selector.close()
        if self._own_state_dir:
            shutil.rmtree(self.state_dir, ignore_errors=True)

    def __enter__(self) -> Rig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
