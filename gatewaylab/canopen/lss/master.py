"""The CiA 305 LSS master, sans-I/O: ``LssMaster(clock, send)``, fed with ``on_frame``.

Every service takes a callback; multi-step services (selective switch, identify, Fastscan) run as
generators that yield one request at a time (IDX guide 3.5, CiA 305 V3.0).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Any

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.lss.frames import (
    FASTSCAN_CONFIRM,
    LSS_MASTER_COB_ID,
    LSS_SLAVE_COB_ID,
    U32_FRAME,
    Cs,
    LssAddress,
    LssState,
    encode_activate_bit_timing,
    encode_configure_bit_timing,
    encode_configure_node_id,
    encode_cs,
    encode_fastscan,
    encode_switch_global,
    encode_u32,
)
from gatewaylab.common.clock import Clock, TimerHandle
from gatewaylab.common.errors import LocalError, RemoteError, TimeoutError_

__all__ = ["LssError", "LssMaster", "LssTimeout", "ResultCallback"]


class LssError(RemoteError):
    """An LSS slave answered with an error code (``.code``), or nobody answered."""


class LssTimeout(LssError, TimeoutError_):
    """No LSS slave answered in time."""


@dataclass(frozen=True, slots=True)
class _Request:
    data: bytes
    expect: int | None      # response cs, or None when no response exists
    collect: bool = False   # wait the whole timeout and count every response


_Proc = Generator[_Request, "bytes | int | None", Any]
ResultCallback = Callable[[Any], None]


class LssMaster:
    """A sans-I/O CiA 305 LSS master: ``send`` gets the frames, feed answers to ``on_frame``.

    Services queue; one runs at a time. Each callback receives the result or an
    :class:`LssError` / :class:`LssTimeout`. After a response arrives the master waits ``settle``
    seconds before the next request so that identical answers of other slaves to the same
    request are not taken for the answer to the next one.
    """

    def __init__(self, clock: Clock, send: Callable[[CanFrame], None], timeout: float = 0.1,
                 settle: float = 0.002) -> None:
        self.clock = clock
        self._send = send
        self.timeout = timeout
        self.settle = settle
        self._queue: deque[tuple[_Proc, ResultCallback | None]] = deque()
        self._proc: _Proc | None = None
        self._callback: ResultCallback | None = None
        self._request: _Request | None = None
        self._timer: TimerHandle | None = None
        self._count = 0
        self._answered = False
        self.unexpected = 0

    # -- services -------------------------------------------------------------------------
    def switch_state_global(self, state: LssState, callback: ResultCallback | None = None) -> None:
        """Switch state global: every slave to ``state`` (configuration or waiting)."""
        self._submit(self._single(encode_switch_global(state), None), callback)

    def switch_state_selective(self, address: LssAddress, callback: ResultCallback | None = None) -> None:
        """Result: True when a slave answered (it is now in configuration state)."""
        self._submit(self._selective(address), callback)

    def configure_node_id(self, node_id: int, callback: ResultCallback | None = None) -> None:
        """Give the selected slave a node-ID (0xFF = unconfigured)."""
        self._submit(self._configure(encode_configure_node_id(node_id)), callback)

    def configure_bit_timing(self, index: int, callback: ResultCallback | None = None) -> None:
        """Select a CiA 305 bit timing table index in the selected slave."""
        self._submit(self._configure(encode_configure_bit_timing(index)), callback)

    def activate_bit_timing(self, delay_ms: int, callback: ResultCallback | None = None) -> None:
        """Switch all slaves to the configured bit timing after ``delay_ms``."""
        self._submit(self._single(encode_activate_bit_timing(delay_ms), None), callback)

    def store_configuration(self, callback: ResultCallback | None = None) -> None:
        """Ask the selected slave to store node-ID and bit timing."""
        self._submit(self._configure(encode_cs(Cs.STORE_CONFIGURATION)), callback)

    def inquire(self, cs: Cs, callback: ResultCallback | None = None) -> None:
        """Inquire vendor/product/revision/serial (u32) or node-ID (u8) of the configured slave."""
        if not Cs.INQUIRE_VENDOR <= cs <= Cs.INQUIRE_NODE_ID:
            raise LocalError(f"not an inquire service: {cs!r}")
        self._submit(self._inquire(cs), callback)

    def identify_remote_slave(self, vendor_id: int, product_code: int, revision_low: int,
                              revision_high: int, serial_low: int, serial_high: int,
                              callback: ResultCallback | None = None) -> None:
        """Result: how many slaves answered within the timeout."""
        self._submit(self._identify((vendor_id, product_code, revision_low, revision_high,
                                     serial_low, serial_high)), callback)

    def identify_non_configured(self, callback: ResultCallback | None = None) -> None:
        """Result: how many non-configured slaves answered within the timeout."""
        req = _Request(encode_cs(Cs.IDENTIFY_NON_CONFIGURED), Cs.IDENTIFY_NON_CONFIGURED_SLAVE, True)
        self._submit(self._collect(req), callback)

    def fast_scan(self, callback: ResultCallback | None = None) -> None:
        """CiA 305 Fastscan. Result: the LssAddress of one non-configured slave (now in
        configuration state), or None when no non-configured slave answered."""
        self._submit(self._fastscan(), callback)

    # -- procedures -----------------------------------------------------------------------
    @staticmethod
    def _single(data: bytes, expect: int | None) -> _Proc:
        answer = yield _Request(data, expect)
        return answer

    @staticmethod
    def _collect(req: _Request) -> _Proc:
        count = yield req
        return count

    @staticmethod
    def _selective(address: LssAddress) -> _Proc:
        for sub in range(3):
            yield _Request(encode_u32(Cs.SWITCH_SELECTIVE_VENDOR + sub, address.part(sub)), None)
        answer = yield _Request(encode_u32(Cs.SWITCH_SELECTIVE_SERIAL, address.serial),
                                Cs.SWITCH_SELECTIVE_RESPONSE)
        return answer is not None

    @staticmethod
    def _configure(data: bytes) -> _Proc:
        answer = yield _Request(data, data[0])
        if not isinstance(answer, bytes):
            raise LssTimeout(f"no answer to LSS cs 0x{data[0]:02X}")
        if answer[1]:
            raise LssError(f"LSS cs 0x{data[0]:02X} refused with error {answer[1]} "
                           f"(specific {answer[2]})", answer[1])
        return None

    @staticmethod
    def _inquire(cs: int) -> _Proc:
        answer = yield _Request(encode_cs(cs), cs)
        if not isinstance(answer, bytes):
            raise LssTimeout(f"no answer to LSS inquire cs 0x{cs:02X}")
        if cs == Cs.INQUIRE_NODE_ID:
            return answer[1]
        return int(U32_FRAME.unpack(answer)[1])

    @staticmethod
    def _identify(values: tuple[int, ...]) -> _Proc:
        for step, value in enumerate(values[:5]):
            yield _Request(encode_u32(Cs.IDENTIFY_VENDOR + step, value), None)
        count = yield _Request(encode_u32(Cs.IDENTIFY_SERIAL_HIGH, values[5]), Cs.IDENTIFY_SLAVE, True)
        return count

    @staticmethod
    def _fastscan() -> _Proc:
        answer = yield _Request(encode_fastscan(0, FASTSCAN_CONFIRM, 0, 0), Cs.IDENTIFY_SLAVE)
        if answer is None:
            return None
        ids = [0, 0, 0, 0]
        for sub in range(4):
            for bit in range(31, -1, -1):
                answer = yield _Request(encode_fastscan(ids[sub], bit, sub, sub), Cs.IDENTIFY_SLAVE)
                if answer is None:
                    ids[sub] |= 1 << bit
            answer = yield _Request(encode_fastscan(ids[sub], 0, sub, (sub + 1) & 3), Cs.IDENTIFY_SLAVE)
            if answer is None:
                return None
        return LssAddress(*ids)

    # -- engine ---------------------------------------------------------------------------
    @property
    def busy(self) -> bool:
        """True while a request waits for its answer."""
        return self._proc is not None or bool(self._queue)

    def _submit(self, proc: _Proc, callback: ResultCallback | None) -> None:
        self._queue.append((proc, callback))
        if self._proc is None:
            self._next_proc()

    def _next_proc(self) -> None:
        while self._proc is None and self._queue:
            self._proc, self._callback = self._queue.popleft()
            self._step(None, first=True)

    def _step(self, value: bytes | int | None, first: bool = False) -> None:
        proc = self._proc
        assert proc is not None
        self._request = None
        try:
            req = next(proc) if first else proc.send(value)
        except StopIteration as stop:
            self._finish(stop.value)
            return
        except LssError as exc:
            self._finish(exc)
            return
        self._request = req
        self._count = 0
        self._answered = False
        self._send(CanFrame(LSS_MASTER_COB_ID, req.data))
        if req.expect is None:
            # unconfirmed service: continue once the request is queued
            self._timer = self.clock.call_soon(self._advance, None)
        else:
            self._timer = self.clock.call_later(self.timeout, self._expired)

    def _advance(self, value: bytes | int | None) -> None:
        self._timer = None
        if self._proc is not None:
            self._step(value)

    def _expired(self) -> None:
        self._timer = None
        req = self._request
        if req is not None and req.collect:
            self._step(self._count)
        else:
            self._step(None)

    def _finish(self, result: Any) -> None:
        callback = self._callback
        self._proc = self._callback = None
        self._request = None
        if callback is not None:
            callback(result)
        self._next_proc()

    def on_frame(self, frame: CanFrame, t: float) -> None:
        """Feed every received frame; only 0x7E4 responses are used."""
        if frame.can_id != LSS_SLAVE_COB_ID or frame.rtr or frame.extended or len(frame.data) != 8:
            return
        req = self._request
        if req is None or req.expect is None or frame.data[0] != req.expect:
            self.unexpected += 1
            return
        if req.collect:
            self._count += 1
            return
        if self._answered:
            self.unexpected += 1   # a second slave's copy of an answer already taken
            return
        self._answered = True
        if self._timer is not None:
            self._timer.cancel()
        self._timer = self.clock.call_later(self.settle, self._advance, frame.data)

    def stop(self) -> None:
        """Forget pending requests without callbacks (the owner shuts down)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._queue.clear()
        self._proc = self._callback = None
        self._request = None
