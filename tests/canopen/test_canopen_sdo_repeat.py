"""Repeated expedited SDO uploads (a polling master) always carry the current value.

Manual: CiA 301 7.2.4.3.6 'Initiate SDO upload' (IDX Communication Guide 3.3.3.2): the server
answers every initiate upload request with the object's value at that moment, however often a
polling master repeats the identical request; these tests change the value, the read hook and the
entry between identical requests.
"""

from __future__ import annotations

from typing import Any

from gatewaylab.bus import CanFrame

REQUEST = CanFrame(0x605, bytes((0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0)))   # upload 0x2000:00


def _poller(clock: Any, vbus: Any) -> Any:
    got: list[CanFrame] = []
    ctrl = vbus.attach("poller", on_frame=lambda f, t: got.append(f))

    def upload() -> bytes:
        ctrl.send(REQUEST)
        clock.advance(0.01)
        return got.pop().data

    return upload


def test_repeated_uploads_follow_value_changes(clock, vbus, make_node) -> None:
    """CiA 301 7.2.4.3.6: each answer is 0x43 + index + sub + the value at that moment."""
    node = make_node()
    clock.advance(0.01)
    upload = _poller(clock, vbus)
    assert upload() == bytes((0x43, 0x00, 0x20, 0x00)) + (0x12345678).to_bytes(4, "little")
    assert upload() == bytes((0x43, 0x00, 0x20, 0x00)) + (0x12345678).to_bytes(4, "little")
    node.set(0x2000, 0, 7)
    assert upload() == bytes((0x43, 0x00, 0x20, 0x00, 7, 0, 0, 0))
    node.od.values[0x2000, 0] = 8            # device code writing the table directly
    assert upload() == bytes((0x43, 0x00, 0x20, 0x00, 8, 0, 0, 0))


def test_repeated_uploads_run_read_hooks_every_time(clock, vbus, make_node) -> None:
    """CiA 301 7.2.4.3.6: a value refreshed on read (device hook) is refreshed for every request."""
    node = make_node()
    clock.advance(0.01)
    upload = _poller(clock, vbus)
    assert upload()[4] == 0x78
    reads: list[int] = []

    def refresh(index: int, sub: int) -> None:
        reads.append(index)
        node.set(0x2000, 0, len(reads))

    node.on_read(0x2000, refresh)
    assert upload()[4:] == bytes((1, 0, 0, 0))
    assert upload()[4:] == bytes((2, 0, 0, 0))
    assert reads == [0x2000, 0x2000]
