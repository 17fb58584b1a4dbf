"""The esd CAN-EtherCAT (and the ECAN-Lite behind the same esd queue API) in a real-time rig whose loop
runs in its own thread while a master on another thread exchanges the process data, as the EtherCAT
wire thread of `gatewaylab run` does (issue 21 defect 3).

The master's thread takes the Tx batch into the gateway under ``clock.lock`` and the gateway hands the
frame to its CAN controller, which schedules the arbitration on the clock. The rig loop sleeps in
``select`` until the event it knew of when it went to sleep; before the fix nothing woke it for the
new one, so the frame waited for the loop's next timeout (250 ms in ``Rig.run``; here the loop polls
with a 60 s timeout, so a loop that is not woken misses every bound below by far). No SM watchdog
timer runs (0x0420 = 0), so nothing else wakes the loop either.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from gatewaylab.bus.frame import CanFrame
from gatewaylab.hosts.esd_can_ethercat import BitRate, EsdHost, EsdQueueApi
from gatewaylab.hosts.ethercat.inprocess import InProcessBackend
from gatewaylab.migrate.esdqueue import EsdQueueOnEcanLite
from gatewaylab.rig.runtime import Rig

#: How long the rig loop would sleep when nobody wakes it (far beyond every bound of the tests).
LOOP_TIMEOUT = 60.0
#: Generous bound for a frame to reach the bus once the gateway took it (a loaded 2-CPU machine).
BOUND = 2.0
DEVICES = {"esd": 'kind = "esd_can_ethercat"\nname = "esd1"\nbus = "can0"',
           "ecanlite": 'kind = "ecanlite"\nname = "ecan"\nchannels = ["can0"]'}
REG_WD_TIME_SM = 0x0420


class LoopRig:
    """A real-time rig (no endpoints) whose loop runs in a thread, a peer node timing arrivals."""

    def __init__(self, path: Path) -> None:
        self.rig = Rig.from_file(str(path), endpoints=False)
        self.heard: queue.Queue[tuple[CanFrame, float]] = queue.Queue()
        self.rig.bus("can0").attach("peer", on_frame=lambda f, t: self.heard.put((f, time.monotonic())))
        self.rig.start()
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, name="test-rig-loop", daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while not self._stop.is_set():
            self.rig.poll(LOOP_TIMEOUT)

    def close(self) -> None:
        self._stop.set()
        self.rig.wake()
        self.thread.join(5.0)
        self.rig.close()


@pytest.fixture(params=sorted(DEVICES))
def loop_rig(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[str, LoopRig]]:
    path = tmp_path / "rig.toml"
    path.write_text(f'clock = "realtime"\n\n[[bus]]\nname = "can0"\nbitrate = 500000\n\n'
                    f'[[device]]\n{DEVICES[request.param]}\n')
    lr = LoopRig(path)
    try:
        yield request.param, lr
    finally:
        lr.close()


def _host(kind: str, rig: Rig) -> EsdQueueApi:
    backend = InProcessBackend.from_rig(rig, timeout=1.0)
    master: Any = backend.master
    master.fpwr(master.slave(0).station, REG_WD_TIME_SM, b"\0\0")   # SM watchdog off: no timer wakes the loop
    host: EsdQueueApi = EsdHost(backend) if kind == "esd" else EsdQueueOnEcanLite(backend)
    host.configure(bitrate=BitRate.table6(2))                        # 500 kbit/s (Table 6)
    host.start(timeout=10.0)
    return host


def test_the_first_tx_batch_after_op_reaches_the_bus_while_the_rig_loop_waits(
        loop_rig: tuple[str, LoopRig]) -> None:
    """5.1.5.3 (Tx): once the gateway copied the batch into its local Tx queue (input Tx counter equal)
    the frames go to the CAN bus one after the other -- in a running rig too, where the master's thread
    is not the loop's: the first batch after OP and the next ones reach a node on the bus within a
    generous bound of their acknowledgement (issue 21: 240 ms after `gatewaylab run`'s handshake), in
    order."""
    kind, lr = loop_rig
    host = _host(kind, lr.rig)
    delays = []
    for b in range(5):
        frames = [CanFrame(0x300 + k, bytes([b, k])) for k in range(4)]
        host.send(frames, timeout=10.0)                 # returns once the gateway took the batch
        acked = time.monotonic()
        for k in range(4):
            try:
                frame, at = lr.heard.get(timeout=10.0 if k else LOOP_TIMEOUT / 4)
            except queue.Empty:
                pytest.fail(f"{kind}: frame {k} of batch {b} not on the bus {LOOP_TIMEOUT / 4:g} s after the "
                            f"gateway took it (the rig loop slept through the arbitration event)")
            assert (frame.can_id, frame.data) == (0x300 + k, bytes([b, k]))
            if k == 0:
                delays.append(at - acked)
    host.stop()
    assert max(delays) < BOUND, f"{kind}: batch -> bus delays {[round(d * 1e3, 1) for d in delays]} ms"
