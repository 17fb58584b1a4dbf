"""The Modbus TCP to CANopen gateway's core: register requests become SDO transfers (sans-I/O).

A request for unit id N (= CANopen node N) is planned on the :class:`~.mapping.RegisterMap`
(unmapped registers, partly written 32-bit objects and values out of range are refused before
anything is sent), then its objects are transferred one after the other by the gateway's own
:class:`~gatewaylab.canopen.sdo_client.SdoClient` on the bus; the first SDO abort ends the
request with the Modbus exception :func:`~.mapping.exception_for_abort` names. The result comes
back through the request's ``done`` callback, on the clock's thread: a list of registers (read),
None (write) or a :class:`~.mapping.ModbusException`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from gatewaylab.bus.bus import VirtualBus
from gatewaylab.bus.controller import Controller
from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.sdo_client import SdoClient
from gatewaylab.common.clock import Clock
from gatewaylab.devices.modbus_gateway.mapping import (
    MappedObject,
    ModbusError,
    ModbusException,
    RegisterKind,
    RegisterMap,
    exception_for_abort,
    to_registers,
)
from gatewaylab.od import SdoAbort

__all__ = ["ModbusGateway", "ReadDone", "WriteDone"]


ReadDone = Callable[[list[int] | ModbusException], None]
WriteDone = Callable[[ModbusException | None], None]


class ModbusGateway:
    """SDO client of the gateway on one bus, serving ``nodes`` (unit id = node id)."""

    def __init__(self, clock: Clock, bus: VirtualBus, name: str, nodes: Sequence[int], register_map: RegisterMap,
                 *, sdo_timeout: float = 0.5) -> None:
        self.clock = clock
        self.bus = bus
        self.name = name
        self.nodes = frozenset(nodes)
        self.map = register_map
        self.sdo_timeout = sdo_timeout
        self.controller: Controller | None = None
        self.sdo = SdoClient(clock, self._send, timeout=sdo_timeout)
        #: Requests answered, by outcome ("ok" or the exception's name): what a test or an operator counts.
        self.counters: dict[str, int] = {}

    def start(self) -> None:
        """Attach to the CAN bus: the SDO client receives the drives' answers."""
        if self.controller is None:
            self.controller = self.bus.attach(self.name, on_frame=self.sdo.on_frame)

    def stop(self) -> None:
        """Cancel pending SDO transfers and detach from the bus."""
        self.sdo.cancel_all()
        if self.controller is not None:
            self.bus.detach(self.controller)
            self.controller = None

    def _send(self, frame: CanFrame) -> None:
        if self.controller is not None:
            self.controller.send(frame)

    def _count(self, outcome: ModbusException | None) -> None:
        key = "ok" if outcome is None else outcome.name
        self.counters[key] = self.counters.get(key, 0) + 1

    def _check_unit(self, unit: int) -> None:
        if unit not in self.nodes:
            raise ModbusError(ModbusException.GATEWAY_PATH_UNAVAILABLE,
                              f"unit {unit} is not a node this gateway serves")

    # -- reads ----------------------------------------------------------------------------------
    def read(self, unit: int, kind: RegisterKind, address: int, count: int, done: ReadDone) -> None:
        """FC 3 (holding) / FC 4 (input): ``count`` registers from ``address`` of node ``unit``."""
        try:
            self._check_unit(unit)
            objects = self.map.plan_read(kind, address, count)
        except ModbusError as exc:
            self._finish_read(done, exc.exception)
            return
        words: list[tuple[int, ...]] = []

        def next_object() -> None:
            if len(words) == len(objects):
                self._finish_read(done, self.map.slice_words(objects, words, address, count))
                return
            obj = objects[len(words)]
            self.sdo.upload(unit, obj.index, obj.subindex, lambda result: uploaded(obj, result))

        def uploaded(obj: MappedObject, result: bytes | SdoAbort) -> None:
            if isinstance(result, SdoAbort):
                self._finish_read(done, exception_for_abort(result.code))
                return
            words.append(to_registers(obj, result))
            next_object()

        next_object()

    def _finish_read(self, done: ReadDone, result: list[int] | ModbusException) -> None:
        self._count(result if isinstance(result, ModbusException) else None)
        done(result)

    # -- writes ---------------------------------------------------------------------------------
    def write(self, unit: int, address: int, values: Sequence[int], done: WriteDone) -> None:
        """FC 6 / FC 16: ``values`` to the holding registers from ``address`` of node ``unit``, object by
        object in register order (expedited SDO downloads of the object's size)."""
        try:
            self._check_unit(unit)
            plan = self.map.plan_write(address, values)
        except ModbusError as exc:
            self._finish_write(done, exc.exception)
            return
        pending = list(plan)

        def next_object() -> None:
            if not pending:
                self._finish_write(done, None)
                return
            obj, data = pending.pop(0)
            self.sdo.download(unit, obj.index, obj.subindex, data, downloaded)

        def downloaded(result: SdoAbort | None) -> None:
            if result is not None:
                self._finish_write(done, exception_for_abort(result.code))
                return
            next_object()

        next_object()

    def _finish_write(self, done: WriteDone, result: ModbusException | None) -> None:
        self._count(result)
        done(result)
