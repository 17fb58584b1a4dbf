"""SdoClient downloads without the size indicator (expedited ``0x22``, segmented ``0x20``).

Manual: CiA 301 7.2.4.3.3 'Initiate SDO download' (IDX Communication Guide 3.3.3.2 names the
SDO protocol): "s: size indicator, 0: data set size is not indicated"; with e = 1 and s = 0 the
data bytes 4..7 "contain unspecified number of bytes to be downloaded", so the server takes the
object's own length. The maxon IDX gateway forwards such requests.
"""

from __future__ import annotations

from typing import Any

from gatewaylab.bus import CanFrame
from gatewaylab.canopen.sdo_client import SdoClient


class _Client:
    def __init__(self, clock: Any, vbus: Any) -> None:
        self.clock = clock
        self.vbus = vbus
        self.results: list[Any] = []
        self.frames: list[CanFrame] = []
        self.ctrl = vbus.attach("sdo-client", on_frame=self._on_frame)
        self.client = SdoClient(clock, self._send, timeout=0.5)

    def _send(self, frame: CanFrame) -> None:
        self.frames.append(frame)
        self.ctrl.send(frame)

    def _on_frame(self, frame: CanFrame, t: float) -> None:
        self.client.on_frame(frame, t)

    def download(self, *args: Any, **kw: Any) -> Any:
        self.client.download(*args, self.results.append, **kw)
        with self.clock.lock:
            self.clock.run_while(lambda: self.vbus.busy)
        return self.results.pop()


def test_expedited_download_without_size_is_0x22_and_the_server_takes_the_object_length(
        clock, vbus, make_node) -> None:
    """CiA 301 7.2.4.3.3: e = 1, s = 0 -> command 0x22, data padded, server uses its size."""
    node = make_node()
    c = _Client(clock, vbus)
    assert c.download(5, 0x2011, 0, b"\x22\x11", size_indicated=False) is None
    assert c.frames[-1] == CanFrame(0x605, bytes((0x22, 0x11, 0x20, 0x00, 0x22, 0x11, 0x00, 0x00)))
    assert node.get(0x2011) == 0x1122
    assert c.download(5, 0x2000, 0, b"\x04\x03\x02\x01", size_indicated=False) is None
    assert c.frames[-1].data == bytes((0x22, 0x00, 0x20, 0x00, 0x04, 0x03, 0x02, 0x01))
    assert node.get(0x2000) == 0x01020304


def test_default_download_still_indicates_the_size(clock, vbus, make_node) -> None:
    """CiA 301 7.2.4.3.3: e = 1, s = 1, n = 4 - length -> 0x2B for two bytes (unchanged default)."""
    make_node()
    c = _Client(clock, vbus)
    assert c.download(5, 0x2011, 0, b"\x22\x11") is None
    assert c.frames[-1].data[0] == 0x2B


def test_segmented_download_without_size_is_0x20(clock, vbus, make_node) -> None:
    """CiA 301 7.2.4.3.3: e = 0, s = 0 -> command 0x20, size field 0; the segments carry the data."""
    node = make_node()
    c = _Client(clock, vbus)
    assert c.download(5, 0x2001, 0, b"no size given", size_indicated=False) is None
    assert c.frames[0].data == bytes((0x20, 0x01, 0x20, 0x00, 0, 0, 0, 0))
    assert node.get(0x2001) == "no size given"
