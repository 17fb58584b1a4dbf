"""The gateway's Modbus TCP face: a pymodbus ``ModbusTcpServer`` in its own thread and asyncio loop.

pymodbus parses and answers Modbus TCP (MBAP framing, function codes, exception responses, one
``SimDevice`` per unit id). Each served node's device has the gateway's register map and an
``action`` coroutine that pymodbus awaits on every access: it hands the request to the rig's
thread with ``clock.call_soon_threadsafe`` (docs/architecture.md "Threads": the rig thread owns
the protocol state) and awaits an asyncio future that the gateway's ``done`` callback resolves
through ``loop.call_soon_threadsafe``. Nothing sleeps; a request waits at most the SDO timeout.

Unit ids the gateway does not serve fall through to pymodbus's catch-all device 0. Its one
register block spans the whole address space, so pymodbus's address check never answers for it
and its action answers 0x0A (gateway path unavailable) whatever the function, address and count:
the unit is checked first, as a gateway does before it forwards anything. Coils and discrete
inputs do not exist: 0x01.

What clients send that is no valid request (junk, a bad MBAP header, an undecodable PDU) pymodbus
logs, with tracebacks and per-byte hex dumps of the last frames. :func:`quiet_pymodbus` configures
its logger (``pymodbus.logging``): each of its records becomes one line of ours, and
:class:`LogLimiter` keeps a flood of them to :data:`LOG_BURST` lines per :data:`LOG_WINDOW`
seconds plus one line counting the rest. ``gatewaylab run -v`` (pymodbus's logger at DEBUG)
leaves pymodbus's own output as it is.
"""

from __future__ import annotations

import asyncio
import errno
import functools
import logging
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from gatewaylab.common.clock import Clock
from gatewaylab.common.errors import LocalError
from gatewaylab.devices.modbus_gateway.device import ModbusGateway
from gatewaylab.devices.modbus_gateway.mapping import ModbusException, RegisterKind

__all__ = [
    "LOG_BURST",
    "LOG_WINDOW",
    "PYMODBUS_LOGGER",
    "START_TIMEOUT",
    "BadRequestLog",
    "LogLimiter",
    "ModbusServerError",
    "ModbusTcpFace",
    "one_line",
    "quiet_pymodbus",
]


log = logging.getLogger(__name__)

#: Function codes of coils and discrete inputs: the gateway has neither (0x01 illegal function).
_BIT_FUNCTIONS = frozenset((1, 2, 5, 15))
#: Function codes that read registers (22 mask write and 23 read/write read the holding registers first).
_READ_FUNCTIONS = {3: RegisterKind.HOLDING, 4: RegisterKind.INPUT, 22: RegisterKind.HOLDING, 23: RegisterKind.HOLDING}
#: Writes whose response pymodbus builds by reading back what it has just stored: nothing to fetch.
_ECHO_FUNCTIONS = frozenset((6, 16))
#: How long :meth:`ModbusTcpFace.start` waits for the server thread to listen (or fail).
START_TIMEOUT = 10.0
#: At most this many lines about bad requests per :data:`LOG_WINDOW` seconds (then one line counting the rest).
LOG_BURST = 10
LOG_WINDOW = 10.0
#: pymodbus's logger (``pymodbus.logging.Log`` writes to it; ``Log.setLevel`` sets its level).
PYMODBUS_LOGGER = "pymodbus.logging"


class ModbusServerError(LocalError, OSError):
    """The Modbus TCP server cannot listen (port in use, no start in time); an OSError with the errno
    too, so that callers that handle socket errors (``gatewaylab run``, the rig) keep doing so."""

    def __init__(self, err: int, message: str) -> None:
        OSError.__init__(self, err, message)

    def __str__(self) -> str:
        return self.strerror or OSError.__str__(self)


class LogLimiter:
    """At most ``burst`` lines per ``window`` seconds (sans-I/O: the caller gives the time).

    :meth:`admit` says whether a line may be written now; a line kept back is counted, and the
    first line of the next window is preceded by one :meth:`admit` result saying how many were."""

    def __init__(self, burst: int = LOG_BURST, window: float = LOG_WINDOW) -> None:
        self.burst = burst
        self.window = window
        self._start = -float("inf")
        self._lines = 0
        #: lines kept back in the current window; ``dropped`` in all
        self.held = 0
        self.dropped = 0

    def admit(self, now: float) -> tuple[bool, int]:
        """(write this line?, lines kept back in the window that just ended: say so first when > 0)."""
        held = 0
        if now - self._start >= self.window:
            held, self.held = self.held, 0
            self._start, self._lines = now, 0
        if self._lines < self.burst:
            self._lines += 1
            return True, held
        self.held += 1
        self.dropped += 1
        return False, held


def one_line(text: str) -> str:
    """pymodbus's message without what follows its first line (its frame dump) or a traceback."""
    first = text.split("\n", 1)[0]
    return first.split("; Traceback", 1)[0].strip().rstrip(";")


class BadRequestLog(logging.Handler):
    """pymodbus's records as one line each on the gateway's logger, rate-limited (a client cannot
    flood the rig's log); ``count`` counts them all, written or not."""

    def __init__(self, target: logging.Logger, limiter: LogLimiter | None = None) -> None:
        super().__init__(logging.WARNING)
        self.target = target
        self.limiter = limiter or LogLimiter()
        self.count = 0
        self._guard = threading.Lock()
        self._last = ""

    def emit(self, record: logging.LogRecord) -> None:
        """Count a pymodbus complaint about a request and log it as one line, rate-limited."""
        try:
            text = one_line(record.getMessage())
        except Exception:           # a record pymodbus could not format: still one line
            text = str(record.msg).split("\n", 1)[0]
        if text == "Repeating....":  # pymodbus folds a message that repeats the one before it
            text = f"{self._last} (again)"
        self._last = text
        self.report(text, record.levelno)

    def report_held(self) -> None:
        """Say how many lines the limit kept back so far (a server stops). Not ``flush``: logging's
        shutdown flushes handlers when the rig's stderr handler may be gone."""
        with self._guard:
            held, self.limiter.held = self.limiter.held, 0
        if held:
            self._held(held)

    def _held(self, held: int) -> None:
        self.target.warning("Modbus TCP: %d more bad requests not logged (at most %d lines per %g s)",
                            held, self.limiter.burst, self.limiter.window)

    def report(self, text: str, level: int = logging.WARNING) -> None:
        """One bad request (or connection error) of a client: one line, if the limit allows."""
        with self._guard:
            self.count += 1
            write, held = self.limiter.admit(time.monotonic())
        if held:
            self._held(held)
        if write:
            self.target.log(max(level, logging.WARNING), "Modbus TCP: bad request: %s", text)


def quiet_pymodbus() -> BadRequestLog | None:
    """Route pymodbus's log through one :class:`BadRequestLog` (once per process; pymodbus's logger
    is global). None when pymodbus's logger is at DEBUG (``gatewaylab run -v``): left as it is."""
    logger = logging.getLogger(PYMODBUS_LOGGER)
    for handler in logger.handlers:
        if isinstance(handler, BadRequestLog):
            return handler
    if logger.isEnabledFor(logging.DEBUG):
        return None
    handler = BadRequestLog(log)
    logger.setLevel(logging.WARNING)     # what pymodbus.logging.Log.setLevel does: it builds no debug text
    logger.addHandler(handler)
    logger.propagate = False
    return handler


def _block(registers: list[tuple[int, int]], readonly: bool) -> list[SimData]:
    """pymodbus register blocks: the mapped registers; every other address is invalid (02)."""
    if not registers:
        return [SimData(0, datatype=DataType.INVALID)]
    return [SimData(first, count=count, datatype=DataType.REGISTERS, readonly=readonly) for first, count in registers]


class ModbusTcpFace:
    """Serves ``gateway`` on ``host:port`` (port 0: a free one, see :attr:`port` after :meth:`start`)."""

    def __init__(self, gateway: ModbusGateway, clock: Clock, port: int = 0, host: str = "127.0.0.1") -> None:
        self.gateway = gateway
        self.clock = clock
        self.host = host
        self.port = port
        self.thread: threading.Thread | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._started = threading.Event()
        self._error: BaseException | None = None
        self._digest: BadRequestLog | None = None

    # -- life cycle (rig thread) -------------------------------------------------------------------------
    def start(self) -> None:
        """Listen, or raise the OSError of a port that cannot be used (after cleaning up)."""
        self._probe()
        self._digest = quiet_pymodbus()
        self.thread = threading.Thread(target=self._run, name=f"modbus-{self.gateway.name}", daemon=True)
        self.thread.start()
        if not self._started.wait(START_TIMEOUT):
            self.stop()
            raise ModbusServerError(errno.ETIMEDOUT, f"the Modbus TCP server did not start within {START_TIMEOUT:g} s")
        if self._error is not None:
            error = self._error
            self.stop()
            if isinstance(error, OSError):
                raise error
            raise ModbusServerError(errno.EADDRINUSE, f"cannot listen on {self.host}:{self.port}: {error}")

    def _probe(self) -> None:
        """Bind the port once as asyncio will (SO_REUSEADDR): a port in use fails here with its errno,
        which pymodbus would only log. Port 0 picks the free port the server then takes."""
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((self.host, self.port))
            sock.listen(1)
            if self.port == 0:
                self.port = sock.getsockname()[1]

    def stop(self) -> None:
        """Close the listener and every connection and end the thread (idempotent)."""
        loop, stop = self.loop, self._stop
        if loop is not None and stop is not None:
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:        # the loop has ended already
                pass
        if self.thread is not None and self.thread is not threading.current_thread():
            self.thread.join(START_TIMEOUT)
        self.thread = None
        if self._digest is not None:
            self._digest.report_held()

    # -- server thread -------------------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:        # reported to start(), never lost in a thread
            self._error = exc
            log.debug("Modbus TCP server %s ended: %r", self.gateway.name, exc)
        finally:
            self._started.set()

    def _devices(self) -> list[SimDevice]:
        holding = self.gateway.map.registers(RegisterKind.HOLDING)
        inputs = self.gateway.map.registers(RegisterKind.INPUT)

        def device(unit: int) -> SimDevice:
            bits = [SimData(0, datatype=DataType.BITS, values=False)]
            return SimDevice(unit, simdata=(list(bits), list(bits), _block(holding, False), _block(inputs, True)),
                             action=functools.partial(self._action, unit))

        # the catch-all for unserved unit ids: one block over every address of every table, so no
        # address or count is refused before its action answers 0x0A
        anywhere = SimDevice(0, simdata=[SimData(0, count=0x10000, datatype=DataType.REGISTERS)],
                             action=functools.partial(self._action, 0))
        return [anywhere] + [device(unit) for unit in sorted(self.gateway.nodes)]

    async def _serve(self) -> None:
        self.loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        if self._digest is not None:
            # an exception escaping pymodbus's protocol callbacks: one line, not asyncio's traceback
            self.loop.set_exception_handler(functools.partial(_loop_error, self._digest))
        server = ModbusTcpServer(self._devices(), address=(self.host, self.port))
        await server.serve_forever(background=True)     # RuntimeError when it cannot listen
        try:
            self._started.set()
            await self._stop.wait()
        finally:
            await server.shutdown()  # type: ignore[no-untyped-call]

    async def _action(self, unit: int, function_code: int, start_address: int, address: int, count: int,
                      registers: list[int], set_values: list[int] | list[bool] | None) -> ExcCodes | None:
        """pymodbus's hook on every access of a mapped register: the gateway does the work on the rig thread.
        The unit comes first: a unit the gateway does not serve is 0x0A whatever the request."""
        if unit == 0 or unit not in self.gateway.nodes:
            return ExcCodes(int(ModbusException.GATEWAY_PATH_UNAVAILABLE))
        if function_code in _BIT_FUNCTIONS:
            return ExcCodes.ILLEGAL_FUNCTION
        loop = asyncio.get_running_loop()
        future: asyncio.Future[Any] = loop.create_future()

        def done(result: Any) -> None:           # rig thread
            try:
                loop.call_soon_threadsafe(_resolve, future, result)
            except RuntimeError:                  # the server loop has ended (rig stopping)
                pass

        if set_values is None and function_code in _ECHO_FUNCTIONS:
            return None
        if set_values is not None:
            values = [int(v) for v in set_values]
            self._hand_over(self.gateway.write, unit, address, values, done)
        elif function_code in _READ_FUNCTIONS:
            self._hand_over(self.gateway.read, unit, _READ_FUNCTIONS[function_code], address, count, done)
        else:
            return ExcCodes.ILLEGAL_FUNCTION
        result = await future
        if isinstance(result, ModbusException):
            return ExcCodes(int(result))
        if isinstance(result, list):
            offset = address - start_address
            registers[offset:offset + len(result)] = result
        return None

    def _hand_over(self, call: Callable[..., None], *args: Any) -> None:
        self.clock.call_soon_threadsafe(call, *args)


def _resolve(future: asyncio.Future[Any], result: Any) -> None:
    if not future.done():
        future.set_result(result)


def _loop_error(digest: BadRequestLog, loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
    exc = context.get("exception")
    digest.report(f"{context.get('message', 'error')}: {exc!r}" if exc is not None
                  else str(context.get("message", context)), logging.ERROR)
