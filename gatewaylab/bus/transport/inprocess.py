"""python-can ``BusABC`` on a :class:`~gatewaylab.bus.bus.VirtualBus` in the same process.

``canopen.Network``, python-can notifiers, loggers and periodic tasks work unchanged on it.

With a :class:`~gatewaylab.common.clock.SimulatedClock` nothing moves time on its own, so
``send()`` runs the simulation until this bus is quiet again: the frame is arbitrated, takes
its time on the wire, and every frame that the other participants answer with in the meantime
is delivered. Time beyond that (heartbeats, timeouts) passes only when the owner calls
``clock.advance()``. With a real-time clock, ``send()`` hands the frame to the thread that runs
the clock.
"""

from __future__ import annotations

import queue
from typing import Any

import can
from can.bus import BusState, CanProtocol

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.controller import Controller, ErrorState
from gatewaylab.bus.frame import CanFrame
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import GatewaylabError

__all__ = ["InProcessBus", "python_can_bus"]


class InProcessBus(can.BusABC):
    """A python-can bus attached to a gatewaylab virtual bus as one more controller."""

    def __init__(self, channel: VirtualBus, *, name: str = "", receive_own_messages: bool = False,
                 fd: bool | None = None, listen_only: bool = False,
                 can_filters: can.typechecking.CanFilters | None = None, **kwargs: Any) -> None:
        vbus = channel
        self.vbus = vbus
        self._queue: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        self._fd = vbus.is_fd if fd is None else fd
        self.channel_info = f"gatewaylab {vbus.name}"
        clock = vbus.clock
        self._simulated = isinstance(clock, SimulatedClock)
        if self._simulated:
            clock.ensure_lock()   # several threads may drive the simulation
        with clock.lock:
            self.controller: Controller = vbus.attach(
                name or f"python-can{len(vbus.controllers)}", receive_own=receive_own_messages,
                fd=self._fd, listen_only=listen_only, on_frame=self._on_frame)
        super().__init__(channel=vbus.name, can_filters=can_filters, **kwargs)
        self._can_protocol = CanProtocol.CAN_FD if self._fd else CanProtocol.CAN_20
        self._put = self._queue.put
        self._channel_name = vbus.name

    def _on_frame(self, frame: CanFrame, t: float) -> None:
        self._put(frame.to_message(t, self._channel_name))

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Queue a message on the virtual bus; on a simulated clock, run until the bus is quiet."""
        frame = CanFrame.from_message(msg)
        vbus = self.vbus
        clock = vbus.clock
        if self._simulated:
            assert isinstance(clock, SimulatedClock)
            with clock.lock:
                try:
                    self.controller.send(frame)
                except GatewaylabError as exc:
                    raise can.CanOperationError(str(exc)) from exc
                clock.run_while(vbus.is_busy)   # settle: the frame and every answer to it
        else:
            # Refuse here, in the caller's thread, what the controller would refuse in the loop's.
            ctrl = self.controller
            if ctrl.bus_off or ctrl.listen_only or (frame.fd and not (ctrl.fd and self.vbus.is_fd)):
                self._send_checked(frame)
            clock.call_soon_threadsafe(self._send_checked, frame)

    def _send_checked(self, frame: CanFrame) -> None:
        try:
            self.controller.send(frame)
        except GatewaylabError as exc:
            raise can.CanOperationError(str(exc)) from exc

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """``BusABC.recv`` without its filter loop when no filters are set (every message the
        controller receives is delivered; the notifier thread calls this once per frame)."""
        if self._filters is not None:
            return super().recv(timeout)
        return self._recv_internal(timeout)[0]   # it waits the whole timeout itself

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            if timeout is None:
                return self._queue.get(), False
            if timeout <= 0:
                return self._queue.get_nowait(), False
            return self._queue.get(timeout=timeout), False
        except queue.Empty:
            return None, False

    @property
    def state(self) -> BusState:
        """python-can's view of the controller: ERROR when bus-off, PASSIVE when listen-only."""
        if self.controller.listen_only:
            return BusState.PASSIVE
        return BusState.ERROR if self.controller.state is ErrorState.BUS_OFF else BusState.ACTIVE

    @state.setter
    def state(self, new_state: BusState) -> None:
        self.controller.listen_only = new_state is BusState.PASSIVE

    def shutdown(self) -> None:
        """Detach the controller from the virtual bus (idempotent)."""
        if not self._is_shutdown:
            with self.vbus.clock.lock:
                self.vbus.detach(self.controller)
        super().shutdown()


def python_can_bus(vbus: VirtualBus, **kwargs: Any) -> InProcessBus:
    """A python-can ``BusABC`` on ``vbus`` (kwargs: name, receive_own_messages, fd, can_filters)."""
    return InProcessBus(vbus, **kwargs)
