"""`gatewaylab monitor` at full load (target: "keeps up with a bus at 100 % load at 1 Mbit/s, about
8,000 frames/s, without falling behind or dropping frames").

1. Decoder alone: frames/s of ``BusMonitor.feed`` over a recorded CANopen session (SDO of every kind,
   PDOs with dictionaries, heartbeats, LSS Fastscan), next to the 8,000 frames/s a saturated 1 Mbit/s bus
   carries.
2. End to end: a rig process with one bus, a python-can client sending 8,000 frames/s for a few seconds
   (the bus at ~100 % load), and a listen-only monitor connection decoding them; frames sent vs decoded.
"""

from __future__ import annotations

import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import can

from gatewaylab.bus import CanFrame
from gatewaylab.canopen.monitor import BusMonitor
from gatewaylab.od.eds import import_eds
from gatewaylab.rig.process import RigProcess

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "canopen"))
from canopen_monitor_kit import record_session  # type: ignore[import-not-found]

SATURATED = 8_000
SECONDS = float(os.environ.get("BENCH_MONITOR_SECONDS", "3"))


def decoder_rate() -> tuple[float, int]:
    session = record_session()
    dictionaries = {n: d.node.to_eds() for n, d in session.drives.items()}
    frames = session.frames * 40
    best = 0.0
    for _ in range(3):
        monitor = BusMonitor({n: import_eds(text, n) for n, text in dictionaries.items()})
        t0 = time.perf_counter()
        for i, (frame, _t) in enumerate(frames):
            monitor.feed(frame, i * 0.000125)
        best = max(best, len(frames) / (time.perf_counter() - t0))
    return best, len(frames)


RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
"""


def end_to_end() -> tuple[int, int, float]:
    """(sent, decoded, seconds) with a sender at the saturated rate and a listen-only monitor."""
    with tempfile.TemporaryDirectory() as tmp:
        rig_file = Path(tmp) / "rig.toml"
        rig_file.write_text(RIG)
        with RigProcess(rig_file, workdir=tmp, timeout=30) as rig:
            ep = rig.endpoint("can0")
            mon = can.Bus(interface="gatewaylab", channel=ep, listen_only=True)
            rx = can.Bus(interface="gatewaylab", channel=ep)   # an acknowledging node
            monitor = BusMonitor(bitrate=1_000_000)
            decoded = 0
            done = threading.Event()

            def watch() -> None:
                nonlocal decoded
                while True:
                    msg = mon.recv(1.0)
                    if msg is None:
                        if done.is_set():
                            return   # quiet for a second after the sender finished
                        continue
                    monitor.feed(CanFrame.from_message(msg), msg.timestamp)
                    decoded += 1

            def keep_reading() -> None:
                while not done.is_set():
                    rx.recv(0.5)

            drain = threading.Thread(target=keep_reading)
            watcher = threading.Thread(target=watch)
            watcher.start()
            drain.start()
            tx = can.Bus(interface="gatewaylab", channel=ep, tx_queue_len=512)
            n = int(SATURATED * SECONDS)
            t0 = time.perf_counter()
            for i in range(n):
                tx.send(can.Message(arbitration_id=0x181 + (i % 4), data=i.to_bytes(8, "little"),
                                    is_extended_id=False), timeout=5)
            tx.shutdown()
            seconds = time.perf_counter() - t0
            done.set()
            watcher.join(30)
            drain.join(5)
            mon.shutdown()
            rx.shutdown()
            return n, decoded, seconds


def main() -> None:
    rate, count = decoder_rate()
    print(f"monitor decoder: {rate:,.0f} frames/s over {count:,} recorded frames "
          f"({rate / SATURATED:.1f}x a saturated 1 Mbit/s bus of {SATURATED:,} frames/s)")
    sent, decoded, seconds = end_to_end()
    print(f"monitor end to end: {sent:,} frames sent in {seconds:.1f} s ({sent / seconds:,.0f}/s, bus ~100 % load), "
          f"{decoded:,} decoded by the listen-only monitor, {sent - decoded} missing")


if __name__ == "__main__":
    main()
