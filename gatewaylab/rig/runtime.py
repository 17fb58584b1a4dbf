"""The rig runtime: builds buses and participants from a rig file and runs them.

In real time one thread (the one calling :meth:`Rig.run`) owns the clock and every protocol
state; it waits in ``select`` until the next timer or until a file descriptor is ready, and
holds ``clock.lock`` while it runs callbacks. With a simulated clock nothing runs by itself:
the owner drives ``rig.clock`` (tests, teaching scripts).

Every rig section is checked (``kinds.plan``) before anything is created; whatever was created is
released on every exit path: a failed construction, :meth:`Rig.close` (or ``with Rig(...)``),
and, for a rig nobody closed, its finaliser (which warns with ``ResourceWarning``). SIGINT and
SIGTERM stop :meth:`Rig.run` within :data:`GRACE` whatever the loop is doing, and :meth:`Rig.close`
takes milliseconds (every participant's ``stop()`` wakes its threads at once), so `gatewaylab run`
exits within a second of SIGTERM in every state (docs/rig.md).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import selectors
import shutil
import signal
import socket
import tempfile
import threading
import time
import warnings
import weakref
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any

from gatewaylab import build_info
from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.transport.server import BusServer
from gatewaylab.bus.transport.socketcand import SocketcandServer
from gatewaylab.bus.transport.trace import Trace
from gatewaylab.bus.transport.unix_file import UNIX_PATH_MAX, SocketPathError
from gatewaylab.common.build_cache import BuildCache
from gatewaylab.common.clock import Clock, RealTimeClock, SimulatedClock
from gatewaylab.common.errors import ConfigError, GatewaylabError
from gatewaylab.plugin import Participant
from gatewaylab.plugin.participant import NAME_MAX, CheckedSection, state_file
from gatewaylab.rig import kinds
from gatewaylab.rig.config import CONTROL_SOCKET, RigConfig, load_rig
from gatewaylab.rig.control import ControlServer
from gatewaylab.rig.faults import Faults
from gatewaylab.rig.scenario_run import ScenarioRun

__all__ = ["GRACE", "Participant", "Rig", "RigStartError", "merge_info"]

log = logging.getLogger(__name__)


#: Seconds a loop asked to stop by SIGINT/SIGTERM gets to return by itself before it is
#: interrupted wherever it is (a callback that never returns, a clock that never runs dry). A pass
#: under a CAN flood took up to ~0.2 s on a loaded 2-CPU machine; close() and the exit need the
#: rest of the second SIGTERM promises (docs/rig.md).
GRACE = 0.3
#: The longest TMPDIR with which every bus's socket ``TMPDIR/gatewaylab-XXXXXXXX/NAME.sock`` fits AF_UNIX's
#: path, names being at most NAME_MAX characters (docs/rig.md "Names").
_TMPDIR_MAX = UNIX_PATH_MAX - len("/gatewaylab-XXXXXXXX/") - NAME_MAX - len(".sock")
#: A participant whose stop() takes longer than this is named in a warning: the whole rig has one
#: second to exit after SIGTERM (docs/rig.md), and every stop() should return within milliseconds.
SLOW_STOP = 0.1


class RigStartError(GatewaylabError):
    """A participant could not open what it needs (a pty, a socket) when the rig started."""


class _Interrupted(BaseException):
    """Raised into a loop that did not stop within :data:`GRACE` of a signal (not an Exception,
    so no participant's ``except Exception`` swallows it)."""


class _Resources:
    """What a rig must release even if nobody closes it; no reference to the rig itself, so the
    finaliser holding it does not keep the rig alive."""

    def __init__(self) -> None:
        self.state_dir: Path | None = None
        self.sockets: list[socket.socket] = []
        self.selector: selectors.BaseSelector | None = None

    def release(self) -> None:
        for sock in self.sockets:
            with contextlib.suppress(OSError):
                sock.close()
        self.sockets.clear()
        if self.selector is not None:
            self.selector.close()
            self.selector = None
        if self.state_dir is not None:
            shutil.rmtree(self.state_dir, ignore_errors=True)
            self.state_dir = None


def _make_state_dir(resources: _Resources) -> Path:
    """A new private ``gatewaylab-*`` folder in the temp directory, recorded in ``resources`` before it
    exists: SIGTERM while `gatewaylab run` starts unwinds it, and a signal between
    ``mkdtemp``'s mkdir and its return would leave an empty folder nobody knows about."""
    base = Path(tempfile.gettempdir())
    while True:
        # 8 characters, as mkdtemp's: the control socket's path below it must fit AF_UNIX's 107 bytes
        path = base / f"gatewaylab-{os.urandom(4).hex()}"
        resources.state_dir = path
        try:
            path.mkdir(mode=0o700)
        except FileExistsError:      # taken (32 random bits: rarely): not ours to remove, try another
            resources.state_dir = None
            continue
        return path


def _too_long_hint(exc: OSError, own_folder: bool) -> str:
    """What to do about a Unix socket path too long for AF_UNIX: the rig's own folder is under TMPDIR."""
    if not (isinstance(exc, SocketPathError) and exc.too_long):
        return ""
    where = (f"the rig's folder is in TMPDIR {tempfile.gettempdir()}: point TMPDIR at a folder of at most "
             f"{_TMPDIR_MAX} characters" if own_folder else "give the rig a state folder with a shorter path")
    return f" ({where}, or use endpoint = \"tcp\")"


def _release_unclosed(resources: _Resources, what: str) -> None:
    warnings.warn(f"{what} was not closed (use `with Rig(...)` or rig.close()); removing its endpoints "
                  f"and temporary folder now", ResourceWarning, stacklevel=2)
    resources.release()


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
                 state_dir: Path | None = None, endpoints: bool | None = None,
                 build_cache: BuildCache | None = None) -> None:
        # every section is checked before anything exists: a bad rig file leaves nothing behind
        self._sections = kinds.plan(config)
        self.config = config
        if clock is None:
            clock = SimulatedClock() if config.clock == "simulated" else RealTimeClock()
        self.clock = clock
        self.realtime = not clock.is_simulated
        #: where relative paths in the rig file start: the rig file's folder (the working folder for a
        #: rig built from a dict or the default rig)
        self.base_dir = Path(config.source).resolve().parent if Path(config.source).is_file() else Path.cwd()
        self.buses: dict[str, VirtualBus] = {}
        self.participants: list[Participant] = []
        #: files the sections read, parsed once for the build (emptied after it unless the caller gave it)
        self.build_cache = build_cache if build_cache is not None else BuildCache()
        self.servers: dict[str, BusServer] = {}
        #: socketcand servers of the buses with ``socketcand = true`` (docs/endpoints.md)
        self.socketcand: dict[str, SocketcandServer] = {}
        self.traces: list[Trace] = []
        #: fault injection (docs/faults.md); ``control`` serves it to other processes
        self.faults = Faults(self)
        #: the ``[[scenario]]`` steps (docs/faults.md "Scenarios"), armed by start(); None without
        self.scenario: ScenarioRun | None = None
        self.control: ControlServer | None = None
        self.callback_errors = 0
        self._started = False
        self._closed = False
        self._loop_thread: int | None = None
        self._wake_hook: Callable[[], None] | None = None
        self._stop = threading.Event()
        self._resources = res = _Resources()
        # select() waits with microsecond resolution; epoll/poll round up to whole milliseconds,
        # which would stretch every 100 us CAN frame to 1 ms.
        self._selector = res.selector = selectors.SelectSelector()
        self._readers: dict[int, Callable[[], None]] = {}
        self._writers: dict[int, Callable[[], None]] = {}
        self._wake_r, self._wake_w = socket.socketpair()
        res.sockets += [self._wake_r, self._wake_w]
        self._finalizer = weakref.finalize(self, _release_unclosed, res, f"Rig({config.source})")
        try:
            self._own_state_dir = state_dir is None
            if state_dir is None:
                self.state_dir = _make_state_dir(res)
            else:
                self.state_dir = state_dir
                self.state_dir.mkdir(parents=True, exist_ok=True)
            self._wake_r.setblocking(False)
            self._wake_w.setblocking(False)
            self.add_reader(self._wake_r.fileno(), self._drain_wakeups)
            self._install_clock_hooks()
            for bc in config.buses:
                self.buses[bc.name] = VirtualBus(clock, bc.name, bc.bitrate, bc.data_bitrate, bc.timing)
            with_endpoints = self.realtime if endpoints is None else endpoints
            if with_endpoints:
                self._open_endpoints()
            self._build_participants()
            if build_cache is None:
                self.build_cache.clear()
            if config.scenario:
                self.scenario = ScenarioRun(self, config.scenario)
        except BaseException:
            self.close()
            raise

    def _install_clock_hooks(self) -> None:
        """Wake the loop when other threads inject work; log failing callbacks. Neither hook holds
        a strong reference to the rig (a clock may outlive it)."""
        clock = self.clock
        clock.ensure_lock()   # the loop, wire threads and servers share the protocol state
        wake_w = self._wake_w

        def wake() -> None:
            try:
                wake_w.send(b"\0")
            except OSError:  # full (a wake-up is pending anyway) or closed with the rig
                pass

        clock.wakeup = wake
        if isinstance(clock, RealTimeClock):
            rig = weakref.ref(self)

            def failed(exc: BaseException) -> None:
                owner = rig()
                if owner is not None:
                    owner._callback_failed(exc)
                else:
                    log.error("callback failed after its rig was closed: %r", exc, exc_info=exc)

            clock.on_error = failed
        self._wake_hook = wake

    def _open_endpoints(self) -> None:
        for i, bc in enumerate(self.config.buses):
            where = f"{self.config.source} [[bus]] #{i + 1} ({bc.name})"
            try:
                if bc.endpoint == "unix":
                    path = state_file(self.state_dir, bc.name, ".sock")     # refuses a path outside the folder
                    server = BusServer(self.buses[bc.name], self, unix_path=path)
                elif bc.endpoint == "tcp":
                    server = BusServer(self.buses[bc.name], self, tcp_port=bc.tcp_port)
                else:
                    continue
            except OSError as exc:
                if bc.endpoint == "tcp":
                    raise RigStartError(f"{where}: tcp_port = {bc.tcp_port} cannot be used on 127.0.0.1 "
                                        f"({exc.strerror or exc})") from None
                raise RigStartError(f"{where}: cannot open the endpoint of bus {bc.name!r}: "
                                    f"{exc.strerror or exc}{_too_long_hint(exc, self._own_state_dir)}") from None
            self.servers[bc.name] = server
            self._resources.sockets.append(server.listener)
        self._open_socketcand()
        tcp = any(bc.endpoint == "tcp" for bc in self.config.buses)
        try:
            control_path = None if tcp else state_file(self.state_dir, CONTROL_SOCKET, ".sock")
            self.control = ControlServer(self, self.faults.request, tcp_port=0 if tcp else None, unix_path=control_path)
        except OSError as exc:
            raise RigStartError(f"{self.config.source}: cannot open the control endpoint: "
                                f"{exc.strerror or exc}{_too_long_hint(exc, self._own_state_dir)}") from None
        self._resources.sockets.append(self.control.listener)

    def _open_socketcand(self) -> None:
        for i, bc in enumerate(self.config.buses):
            if not bc.socketcand:
                continue
            try:
                server = SocketcandServer(self.buses[bc.name], self, bc.socketcand_port)
            except OSError as exc:
                raise RigStartError(f"{self.config.source} [[bus]] #{i + 1} ({bc.name}): socketcand_port = "
                                    f"{bc.socketcand_port} cannot be used on 127.0.0.1 "
                                    f"({exc.strerror or exc})") from None
            self.socketcand[bc.name] = server
            self._resources.sockets.append(server.listener)

    @classmethod
    def from_file(cls, path: str | Path | None = None, **kwargs: Any) -> Rig:
        """A rig from a rig file (default: the one load_rig finds)."""
        return cls(load_rig(path), **kwargs)

    # -- construction -----------------------------------------------------------------------
    def _build_participants(self) -> None:
        """One participant per checked section, in build order (``kinds.plan``)."""
        for section in self._sections:
            try:
                participant = section.kind.create(self, CheckedSection(section.kind.kind, section.cfg))
            except ConfigError as exc:
                message = str(exc)
                if not message.startswith(self.config.source):
                    message = f"{section.where}: {message}"
                raise ConfigError(message) from None
            missing = [m for m in ("name", "start", "stop", "ready_info") if not hasattr(participant, m)]
            if missing:
                raise ConfigError(f"{section.where}: kind {section.kind.kind!r} built a "
                                  f"{type(participant).__name__} without {', '.join(missing)} (not a participant)")
            self.participants.append(participant)

    def bus(self, name: str) -> VirtualBus:
        """The bus of that name; a ConfigError naming the declared ones otherwise."""
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
        """Call ``callback`` on the rig's loop when ``fd`` is readable (holding clock.lock)."""
        self._readers[fd] = callback
        self._update(fd)

    def remove_reader(self, fd: int) -> None:
        """Stop watching ``fd`` for readability."""
        self._readers.pop(fd, None)
        self._update(fd)

    def add_writer(self, fd: int, callback: Callable[[], None]) -> None:
        """Call ``callback`` on the rig's loop when ``fd`` is writable (holding clock.lock)."""
        self._writers[fd] = callback
        self._update(fd)

    def remove_writer(self, fd: int) -> None:
        """Stop watching ``fd`` for writability."""
        self._writers.pop(fd, None)
        self._update(fd)

    def _update(self, fd: int) -> None:
        if self._resources.selector is None:  # closed: nothing waits any more
            return
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
    @property
    def closed(self) -> bool:
        """True once close() ran: the rig cannot start again."""
        return self._closed

    def start(self) -> None:
        """Start every participant (open ptys, TCP ports, wires); a RigStartError (a run-time failure,
        exit 1 from `gatewaylab run`) names the section whose start failed, e.g. a port in use."""
        if self._closed:
            raise ConfigError("this rig is closed; build a new one")
        if self._started:
            return
        self._started = True
        with self.clock.lock:
            for section, p in zip(self._sections, self.participants):
                try:
                    p.start()
                except OSError as exc:
                    hint = " (choose another port)" if exc.errno == errno.EADDRINUSE else ""
                    raise RigStartError(f"{section.where}: cannot start {p.name}: "
                                        f"{exc.strerror or exc}{hint}") from None
            if self.scenario is not None:
                self.scenario.arm()

    def ready_info(self) -> dict[str, Any]:
        """What the --ready-file holds: pid, the modules that run compiled (so a master's test log
        says which build it ran against), buses and endpoints, then every participant's info."""
        info: dict[str, Any] = {"pid": os.getpid(), "compiled": build_info.compiled_modules(), "buses": {}}
        for name, bus in self.buses.items():
            entry: dict[str, Any] = {"bitrate": bus.bitrate}
            if bus.data_bitrate:
                entry["data_bitrate"] = bus.data_bitrate
            if name in self.servers:
                entry["endpoint"] = self.servers[name].endpoint
            if name in self.socketcand:
                entry["socketcand"] = self.socketcand[name].port
            info["buses"][name] = entry
        if self.control is not None:
            info["control"] = self.control.endpoint
        for p in self.participants:
            merge_info(info, p.ready_info())
        return info

    def poll(self, timeout: float | None) -> None:
        """One loop iteration: wait for I/O or the next timer, then run what is due."""
        clock = self.clock
        deadline = clock.begin_wait()  # an event another thread schedules before it wakes us
        if deadline is not None:
            wait = max(0.0, deadline - clock.now())
            timeout = wait if timeout is None else min(timeout, wait)
        try:
            ready = self._selector.select(timeout)
        finally:
            clock.end_wait()
        for key, events in ready:
            fd = key.fd
            clock.hand_over()    # a thread waiting for the lock (the EtherCAT wire) goes first
            with clock.lock:
                try:
                    if events & selectors.EVENT_READ and fd in self._readers:
                        self._readers[fd]()
                    if events & selectors.EVENT_WRITE and fd in self._writers:
                        self._writers[fd]()
                except Exception as exc:
                    self._callback_failed(exc)
        if isinstance(clock, RealTimeClock) and not self._stop.is_set():
            clock.run_due()

    def run(self, until: Callable[[], bool] | None = None, *, signals: bool = True) -> None:
        """Run in real time until :meth:`request_stop` (or ``until()`` returns True).

        On the main thread (and with ``signals``) SIGINT and SIGTERM stop it: the loop returns at
        its next pass, and if it is stuck (a callback that never returns) it is interrupted
        :data:`GRACE` seconds later; a second signal interrupts it at once. The previous handlers
        are restored when it returns. The caller still calls :meth:`close`.
        """
        if not self.realtime:
            raise ConfigError("Rig.run() needs a real-time clock; drive a simulated rig's clock yourself")
        self.start()
        previous = self._install_signals() if signals else None
        try:
            try:
                self._loop_thread = threading.get_ident()
                while not self._stop.is_set() and not (until is not None and until()):
                    self.poll(0.25)
            finally:
                self._loop_thread = None  # first: from here on the handlers do not interrupt
        except _Interrupted:
            log.warning("the rig loop did not stop within %.2f s of the signal; interrupted it", GRACE)
        finally:
            if previous is not None:
                self._restore_signals(previous)

    def _install_signals(self) -> dict[int, Any] | None:
        if threading.current_thread() is not threading.main_thread():
            return None
        previous: dict[int, Any] = {}
        for signum, handler in ((signal.SIGINT, self._on_signal), (signal.SIGTERM, self._on_signal),
                                (signal.SIGALRM, self._on_grace_expired)):
            previous[signum] = signal.signal(signum, handler)
        return previous

    def _restore_signals(self, previous: dict[int, Any]) -> None:
        signal.setitimer(signal.ITIMER_REAL, 0)
        for signum, handler in previous.items():
            signal.signal(signum, handler)

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        if self._stop.is_set() and self._loop_thread is not None:
            raise _Interrupted  # asked twice: do not wait
        log.info("signal %d: stopping the rig", signum)
        self.request_stop()
        signal.setitimer(signal.ITIMER_REAL, GRACE)

    def _on_grace_expired(self, signum: int, frame: FrameType | None) -> None:
        if self._loop_thread is not None:
            raise _Interrupted

    def request_stop(self) -> None:
        """Ask :meth:`run` to return at its next pass; safe from signal handlers and other threads."""
        self._stop.set()
        self.wake()

    def run_in_thread(self) -> threading.Thread:
        """Run the real-time loop in a daemon thread (for tests and embedding)."""
        thread = threading.Thread(target=self.run, name="gatewaylab-rig", daemon=True)
        thread.start()
        return thread

    def close(self) -> None:
        """Stop participants, close endpoints and traces, remove the state folder (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._finalizer.detach()
        try:
            with self.clock.lock:
                self.faults.cancel()
                if self.scenario is not None:
                    self.scenario.close()
                if self.control is not None:
                    self.control.close()
                for p in reversed(self.participants):
                    started = time.monotonic()
                    try:
                        p.stop()
                    except Exception:
                        log.exception("stopping %s failed", getattr(p, "name", p))
                    took = time.monotonic() - started
                    if took > SLOW_STOP:
                        log.warning("stopping %s took %.2f s (SIGTERM promises a second for the whole rig)",
                                    getattr(p, "name", p), took)
                for server in self.servers.values():
                    try:
                        server.close()
                    except Exception:
                        log.exception("closing the endpoint of bus %s failed", server.bus.name)
                for sc_server in self.socketcand.values():
                    try:
                        sc_server.close()
                    except Exception:
                        log.exception("closing the socketcand server of bus %s failed", sc_server.bus.name)
                for trace in self.traces:
                    try:
                        trace.close()
                    except Exception:
                        log.exception("closing a trace failed")
        finally:
            if self.clock.wakeup is self._wake_hook:
                self.clock.wakeup = None
            self._readers.clear()
            self._writers.clear()
            self._resources.release()

    def __enter__(self) -> Rig:
        if self._closed:
            raise ConfigError("this rig is closed; build a new one")
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
