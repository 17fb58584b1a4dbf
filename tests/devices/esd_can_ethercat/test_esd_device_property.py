"""Random output images against the counter handshake (manual 5.1.5.3/5.1.5.4, issue 11 'hypothesis
on random output images'): whatever a master writes (counters, NumTx, lengths, identifiers out of
range), the gateway does not crash and sends exactly the frames of the batches it acknowledged."""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gatewaylab.bus.frame import CanFrame

_SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
_images = st.lists(st.tuples(st.binary(min_size=262, max_size=262), st.integers(0, 3)), min_size=1, max_size=12)


def _model_11(image: bytes) -> list[CanFrame]:
    """5.1.5.3 read straight from the bits: NumTx (at most 16) messages of 12 bytes, bits 16-19
    length (DLC > 8 = 8 bytes), 20 RTR, 21-31 identifier, 32-95 data."""
    num = struct.unpack_from("<H", image, 4)[0]
    out = []
    for i in range(min(num, 16)):
        word = struct.unpack_from("<H", image, 6 + 12 * i + 2)[0]
        n = min(word & 0x0F, 8)
        data = image[6 + 12 * i + 4:6 + 12 * i + 4 + n]
        out.append(CanFrame(word >> 5, rtr=True, dlc=n) if word & 0x10 else CanFrame(word >> 5, data))
    return out


def _model_29(image: bytes) -> list[CanFrame]:
    """5.1.5.4: 16-byte messages, u16 length, u32 {id 0-28, RTR 30, 29-bit 31}; an 11-bit identifier
    above 0x7FF cannot be sent (counted as aborted)."""
    num = struct.unpack_from("<H", image, 4)[0]
    out = []
    for i in range(min(num, 16)):
        length, word = struct.unpack_from("<HI", image, 6 + 16 * i + 2)
        ext, rtr, can_id = bool(word >> 31), bool(word & 0x40000000), word & 0x1FFFFFFF
        if not ext and can_id > 0x7FF:
            continue
        n = min(length & 0x0F, 8)
        data = image[6 + 16 * i + 8:6 + 16 * i + 8 + n]
        out.append(CanFrame(can_id, b"", extended=ext, rtr=True, dlc=n) if rtr else CanFrame(can_id, data,
                                                                                              extended=ext))
    return out


def _run(kit: Any, images: list[tuple[bytes, int]], model: Callable[[bytes], list[CanFrame]]) -> None:
    committed: list[CanFrame] = []
    in_tx = 0
    for raw, cycles in images:
        image = raw[:kit.out_size]
        kit.master.pdo_write(0, 0, image)
        out_tx = struct.unpack_from("<H", image, 0)[0]
        if out_tx != in_tx:                 # the gateway takes a batch only on a new Tx counter
            committed += model(image)
            in_tx = out_tx
        kit.peer.send(CanFrame(0x7FF, raw[-2:]))   # Rx traffic meanwhile, acknowledged at random
        kit.cycle(cycles + 1)
        assert kit.inputs()[0] == in_tx
    kit.cycle(200)
    assert kit.heard == committed
    aborted = kit.master.sdo_upload32(0, 0x2010, 0x37)
    assert kit.master.sdo_upload32(0, 0x2010, 0x31) == len(committed)
    assert kit.master.sdo_upload32(0, 0x2010, 0x30) == len(committed) + aborted


@_SETTINGS
@given(images=_images)
def test_random_11_bit_output_images_send_only_committed_batches(kit_factory: Callable[..., Any],
                                                                  images: list[tuple[bytes, int]]) -> None:
    """11-bit queues (198-byte outputs): no crash, the frames on the bus are those of acknowledged batches."""
    kit = kit_factory()
    kit.op()
    _run(kit, images, _model_11)


@_SETTINGS
@given(images=_images)
def test_random_29_bit_output_images_send_only_committed_batches(kit_factory: Callable[..., Any],
                                                                  images: list[tuple[bytes, int]]) -> None:
    """29-bit queues (262-byte outputs, 0x8000:20 bit 0): identifiers out of range are aborted, never sent."""
    kit = kit_factory()
    kit.preop()
    kit.master.sdo_download16(0, 0x8000, 0x20, 1)
    kit.op()
    _run(kit, images, _model_29)
