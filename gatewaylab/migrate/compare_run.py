"""``gatewaylab migrate compare``, the thin runner: one application, once through each gateway.

The rig layer opens the line (:data:`LineOpener`: a fresh copy of the rig with the gateway added,
a master backend on its EtherCAT segment, the CAN bus to record), so this module never imports
``gatewaylab.rig`` (docs/architecture.md layering). Here an :class:`EthercatHost` is started on it
(esd: its one CAN port; ECAN-Lite: MCAN channel 0), the bus is recorded from the moment the
application starts, the application's ``run(bus)`` is called with a :class:`RecordingBus`, and a
:class:`~.compare.Recording` comes out for :func:`~.compare.compare`.
"""

from __future__ import annotations

import inspect
import runpy
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import can

from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.errors import ConfigError, LocalError
from gatewaylab.hosts.canhost.host import EthercatHost, GatewayBus
from gatewaylab.hosts.ethercat.backend import MasterBackend
from gatewaylab.migrate.compare import AppEvent, AppEventKind, Frame, Recording

#: The two gateways in compare order: (rig device kind, trace prefix, display name).
ESD = ("esd_can_ethercat", "esd", "esd CAN-EtherCAT")
ECANLITE = ("ecanlite", "ecanlite", "ECAN-Lite MCAN0")
GATEWAYS = (ESD, ECANLITE)
#: Identity (vendor, product) of each gateway kind, to find its position on the segment.
IDENTITY = {"esd_can_ethercat": (0x17, 2), "ecanlite": (0x47574C42, 0x45434C54)}
#: Simulated seconds the bus is still recorded after ``run()`` returned (answers to the last frames).
SETTLE_S = 0.02
#: The ECAN-Lite's PDO multiplier: 3 x 128 B each way (the plugin's default).
PDO_N = 3


class CanRecorder(Protocol):
    """What a line gives the runner to record its CAN bus (a VirtualBus has it)."""

    bitrate: int

    def add_monitor(self, callback: Callable[[CanFrame, float], None]) -> None:
        """Call ``callback(frame, t)`` for every frame on the bus from now on."""

    def remove_monitor(self, callback: Callable[[CanFrame, float], None]) -> None:
        """Stop calling ``callback`` (the recording ends)."""


@dataclass
class Line:
    """An opened copy of the rig with one gateway: its master backend, the CAN bus, a closer."""

    backend: MasterBackend
    bus: CanRecorder
    close: Callable[[], None]


#: ``opener(gateway_kind)`` -> a fresh, started copy of the rig with that gateway on the compared bus.
LineOpener = Callable[[str], Line]

App = Callable[..., Any]


class Runner(Protocol):
    """One run of the application file through one gateway (in process or over the wire)."""

    def __call__(self, gateway: tuple[str, str, str], app_path: Path, seconds: float | None,
                 cycle_us: int) -> Recording: ...


def simulated_runner(opener: LineOpener) -> Runner:
    """Runs in process on fresh copies of the rig (``opener``), the application file loaded anew
    for each run (module state does not carry over from one gateway to the other)."""

    def run(gateway: tuple[str, str, str], app_path: Path, seconds: float | None, cycle_us: int) -> Recording:
        return run_once(opener, gateway, load_app(app_path), seconds=seconds, cycle_us=cycle_us)

    return run


def load_app(path: str | Path) -> App:
    """``run`` of the application file ``path`` (a ConfigError when there is none)."""
    try:
        namespace = runpy.run_path(str(path), run_name="__gatewaylab_compare_app__")
    except OSError as exc:
        raise ConfigError(f"cannot read application {path}: {exc}") from None
    run = namespace.get("run")
    if not callable(run):
        raise ConfigError(f"{path}: defines no run(bus) function")
    return run   # type: ignore[no-any-return]


def takes_seconds(app: App) -> bool:
    """Whether ``run`` accepts ``seconds=`` (else --seconds is a usage error, not a crash mid-run)."""
    try:
        return "seconds" in inspect.signature(app).parameters
    except (TypeError, ValueError):
        return False


def to_frame(frame: CanFrame | can.Message, t: float) -> Frame:
    """A bus frame or a python-can message as a trace frame at ``t``: both sides compare alike."""
    if isinstance(frame, can.Message):
        return Frame(t, frame.arbitration_id, b"" if frame.is_remote_frame else bytes(frame.data),
                     frame.is_extended_id, frame.is_remote_frame)
    return Frame(t, frame.can_id, b"" if frame.rtr else bytes(frame.data), frame.extended, frame.rtr)


@dataclass
class Recorder:
    """Bus frames and application events, times relative to ``t0`` (the application's start)."""

    t0: float = 0.0
    bus: list[Frame] = field(default_factory=list)
    app: list[AppEvent] = field(default_factory=list)

    def on_frame(self, frame: CanFrame, t: float) -> None:
        """Bus monitor: note ``frame`` at its time since the application's start."""
        self.bus.append(to_frame(frame, t - self.t0))


class RecordingBus(GatewayBus):
    """The application's ``can.BusABC``: a :class:`GatewayBus` that notes each ``send()`` call (its
    time) and each frame the host hands to ``recv()`` (the time of the cycle that delivered it: on a
    simulated clock, when a waiting ``recv()`` returns; independent of which thread reads it)."""

    def __init__(self, host: EthercatHost, channel_name: str, recorder: Recorder, **kwargs: Any) -> None:
        self.recorder = recorder
        super().__init__(host, channel_name, **kwargs)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Note the call time (the start of the master -> CAN latency), then send."""
        now = self.host.clock.now()
        if not self._is_shutdown:
            self.recorder.app.append(AppEvent(AppEventKind.SEND, to_frame(msg, now - self.recorder.t0)))
        super().send(msg, timeout)

    def deliver(self, msgs: list[can.Message]) -> None:
        """Note the delivery time of each data frame (the end of the CAN -> master latency), then queue them."""
        now = self.host.clock.now() - self.recorder.t0
        self.recorder.app.extend(AppEvent(AppEventKind.RECV, to_frame(m, now)) for m in msgs if not m.is_error_frame)
        super().deliver(msgs)


def position_of(backend: MasterBackend, kind: str) -> int:
    """Where the gateway of ``kind`` sits on the segment, found by identity (LocalError when missing)."""
    vendor, product = IDENTITY[kind]
    found = [s.position for s in backend.slaves() if (s.vendor_id, s.product_code) == (vendor, product)]
    if not found:
        raise LocalError(f"no {kind} on the EtherCAT segment")
    return found[-1]    # the one added last: the rig's own EtherCAT devices come first


def run_once(opener: LineOpener, gateway: tuple[str, str, str], app: App, *, seconds: float | None = None,
             cycle_us: int = 1000, settle: float = SETTLE_S) -> Recording:
    """Run ``app`` once through ``gateway`` (one of :data:`GATEWAYS`) on a fresh copy of the rig."""
    kind, prefix, display = gateway
    line = opener(kind)
    try:
        host = EthercatHost(line.backend, cycle_us=cycle_us)
        pos = position_of(line.backend, kind)
        bitrate = line.bus.bitrate
        if kind == ESD[0]:
            host.add_esd(pos, bitrate, name=prefix)
        else:
            host.add_ecanlite(pos, 0, bitrate, pdo_n=PDO_N, name=prefix)
        host.start()
        rec = Recorder(host.clock.now())
        line.bus.add_monitor(rec.on_frame)
        bus = RecordingBus(host, prefix, rec)
        try:
            if seconds is not None:
                app(bus, seconds=seconds)
            else:
                app(bus)
            duration = host.clock.now() - rec.t0
            host.run_for(settle)
        finally:
            line.bus.remove_monitor(rec.on_frame)
            bus.shutdown()
            host.close()
    finally:
        line.close()
    return Recording(display, tuple(rec.bus), tuple(rec.app), duration)


__all__ = ["ECANLITE", "ESD", "GATEWAYS", "IDENTITY", "Line", "LineOpener", "Recorder", "RecordingBus", "Runner",
           "load_app", "position_of", "run_once", "simulated_runner", "takes_seconds"]
