"""Process data of the in-process master (SOEM's ethercatmain send/receive_processdata): the image and its LRW cycle."""

from __future__ import annotations

import struct
from collections.abc import Callable

from gatewaylab.common.clock import PeriodicTimer
from gatewaylab.common.errors import TimeoutError_
from gatewaylab.ethercat.datagram import MAX_DATAGRAM_DATA, Command, Datagram
from gatewaylab.ethercat.errors import MasterError
from gatewaylab.hosts.ethercat.base import Port
from gatewaylab.hosts.ethercat.config import Configuration

__all__ = ["ProcessImage"]


class ProcessImage:
    """The process image (outputs first, then inputs) and its exchange: one LRW frame per image chunk."""

    def __init__(self, port: Port, config: Configuration) -> None:
        self.port = port
        self.config = config
        self.image = bytearray()
        #: (logical start, length) of each LRW datagram; images larger than one datagram take several.
        self.chunks: list[tuple[int, int]] = []
        self.outputs_size = 0
        self.expected_wkc = 0
        self.last_wkc = 0
        self._cyclic: PeriodicTimer | None = None

    def lay_out(self, outputs_size: int, size: int) -> None:
        """A fresh image of ``size`` bytes whose first ``outputs_size`` are outputs, after the slaves were mapped."""
        self.outputs_size = outputs_size
        self.image = bytearray(size)
        self.chunks = [(a, min(MAX_DATAGRAM_DATA, size - a)) for a in range(0, size, MAX_DATAGRAM_DATA)]
        # Each slave counts in every frame its outputs (+2) or inputs (+1) overlap.
        self.expected_wkc = 0
        for a, n in self.chunks:
            for s in self.config.slaves:
                if s.output_bytes and s.output_offset < a + n and a < s.output_offset + s.output_bytes:
                    self.expected_wkc += 2
                if s.input_bytes and s.input_offset < a + n and a < s.input_offset + s.input_bytes:
                    self.expected_wkc += 1

    def exchange(self) -> int:
        """The cyclic exchange, one LRW frame per image chunk; returns the summed working counter (see expected_wkc)."""
        total = 0
        image = self.image
        port = self.port
        outputs_size = self.outputs_size
        for a, n in self.chunks:
            try:
                d = port.exchange([Datagram(Command.LRW, port.next_index(), a, bytes(image[a:a + n]))])[0]
            except TimeoutError_:
                continue
            lo = max(a, outputs_size)
            if lo < a + n:
                image[lo:a + n] = d.data[lo - a:]
            total += d.wkc
        self.last_wkc = total
        return total

    # ------------------------------------------------------------------ slave views
    def write(self, position: int, offset: int, data: bytes) -> None:
        """Put bytes into one slave's outputs in the image, sent with the next process data exchange."""
        s = self.config.slave(position)
        if offset + len(data) > s.output_bytes:
            raise MasterError(f"outputs of slave {position} are {s.output_bytes} bytes")
        start = s.output_offset + offset
        self.image[start:start + len(data)] = data

    def read(self, position: int, offset: int, length: int) -> bytes:
        """Bytes of one slave's inputs as the last process data exchange brought them."""
        s = self.config.slave(position)
        if offset + length > s.input_bytes:
            raise MasterError(f"inputs of slave {position} are {s.input_bytes} bytes")
        start = s.input_offset + offset
        return bytes(self.image[start:start + length])

    def write_uint(self, position: int, offset: int, st: struct.Struct, value: int) -> None:
        """Put an unsigned output of the struct's size into the image."""
        self.write(position, offset, st.pack(value))

    def read_uint(self, position: int, offset: int, st: struct.Struct) -> int:
        """An unsigned input of the struct's size from the image."""
        return int(st.unpack(self.read(position, offset, st.size))[0])

    # ------------------------------------------------------------------ cycle
    def start_cyclic(self, period: float, cycle: Callable[[], None]) -> None:
        """Call ``cycle`` every ``period`` seconds on the clock (replacing a running cycle)."""
        self.stop_cyclic()
        self._cyclic = self.port.clock.call_every(period, cycle)

    def stop_cyclic(self) -> None:
        """Stop the cycle started by start_cyclic (slaves with a watchdog then leave OP)."""
        if self._cyclic is not None:
            self._cyclic.cancel()
            self._cyclic = None

