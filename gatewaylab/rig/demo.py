"""`make demo`: start the default rig like a user would, drive real traffic, explain it, exit.

The rig runs as its own process (`gatewaylab run --ready-file ...`); this script is a client that
connects through the `gatewaylab` python-can interface, exactly as any other program would.
"""

from __future__ import annotations

import json
import os
import selectors
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import can

from ..bus.frame import CanFrame
from .config import load_rig
from .explain import explain


class Narrator(can.Listener):
    """Prints every frame on the bus with what it means."""

    def __init__(self) -> None:
        self.t0: float | None = None
        self.count = 0
        self.quiet = False
        self.lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            return
        frame = CanFrame.from_message(msg)
        with self.lock:
            self.count += 1
            if self.t0 is None:
                self.t0 = msg.timestamp
            if not self.quiet:
                print(f"    {msg.timestamp - self.t0:9.6f}  {frame!s:<26} {explain(frame)}", flush=True)


def _wait_ready(proc: subprocess.Popen[bytes], ready: Path, timeout: float = 30.0) -> dict[str, Any]:
    """Wait for the rig's ready file by watching its stdout (it prints after writing the file)."""
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout
    while not ready.exists():
        remaining = deadline - time.monotonic()
        if remaining <= 0 or proc.poll() is not None:
            raise RuntimeError(f"the rig did not come up (exit code {proc.poll()})")
        if sel.select(remaining):
            line = os.read(proc.stdout.fileno(), 65536)
            sys.stdout.write("".join(f"  | {x}\n" for x in line.decode().splitlines()))
    sel.close()
    info: dict[str, Any] = json.loads(ready.read_text())
    return info


def step(title: str) -> None:
    print(f"\n== {title}", flush=True)


def demo_drives(bus: can.BusABC, narrator: Narrator, drives: list[int]) -> None:
    import canopen

    network = canopen.Network(bus)
    network.notifier = can.Notifier(bus, [network.listeners[0] if network.listeners else
                                          canopen.network.MessageListener(network), narrator], timeout=0.1)
    step("NMT 'reset communication' to all nodes: every drive answers with a boot-up message")
    network.nmt.send_command(0x82)
    time.sleep(0.3)
    for node_id in drives:
        node = network.add_node(node_id)
        assert isinstance(node, canopen.RemoteNode)
        step(f"SDO reads from node {node_id}: device type 0x1000, identity 0x1018, device name 0x1008")
        device_type = int.from_bytes(node.sdo.upload(0x1000, 0), "little")
        vendor = int.from_bytes(node.sdo.upload(0x1018, 1), "little")
        serial = int.from_bytes(node.sdo.upload(0x1018, 4), "little")
        name = node.sdo.upload(0x1008, 0).decode(errors="replace")
        print(f"  -> device type 0x{device_type:08X}, vendor 0x{vendor:08X}, serial 0x{serial:X}, name {name!r}")
    if drives:
        node_id = drives[0]
        first = network.nodes[node_id]
        assert isinstance(first, canopen.RemoteNode)
        step(f"CiA 402 on node {node_id}: enable the drive (controlword 6, 7, 15) and move 1000 increments in PP")
        sdo = first.sdo
        sdo.download(0x6060, 0, (1).to_bytes(1, "little", signed=True))
        for cw in (0x06, 0x07, 0x0F):
            sdo.download(0x6040, 0, cw.to_bytes(2, "little"))
        sdo.download(0x607A, 0, (1000).to_bytes(4, "little", signed=True))
        sdo.download(0x6040, 0, (0x1F).to_bytes(2, "little"))
        narrator.quiet = True
        deadline = time.monotonic() + 5.0
        position = 0
        while time.monotonic() < deadline:
            status = int.from_bytes(sdo.upload(0x6041, 0), "little")
            position = int.from_bytes(sdo.upload(0x6064, 0), "little", signed=True)
            if status & 0x0400 and position == 1000:
                break
        narrator.quiet = False
        print(f"  -> target reached: statusword 0x{status:04X}, position actual {position}")
    network.notifier.stop()


def demo_idx(info: dict[str, Any]) -> None:
    usb = info.get("usb", {})
    if not usb:
        return
    try:
        from ..devices.maxon_idx.host.client import IdxClient
    except ImportError:
        return
    for name, ports in usb.items():
        step(f"maxon IDX '{name}' over its virtual USB port {ports.get('pty')}: ReadObject 0x1008 and a gateway read")
        with IdxClient(ports["pty"]) as idx:
            print(f"  -> device name {idx.read_string(0, 0x1008, 0)!r}")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    config = load_rig(argv[0] if argv else None)
    drives = sorted(int(d["node_id"]) for d in config.drives if d.get("node_id") is not None)
    with tempfile.TemporaryDirectory(prefix="gatewaylab-demo-") as tmp:
        ready = Path(tmp) / "ready.json"
        trace = Path(tmp) / "can0.log"
        cmd = [sys.executable, "-m", "gatewaylab", "run", *argv, "--ready-file", str(ready),
               "--trace", f"can0={trace}"]
        step("Starting the rig: " + " ".join(["gatewaylab", *cmd[3:]]))
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE)
        try:
            info = _wait_ready(proc, ready)
            endpoint = info["buses"]["can0"]["endpoint"]
            print(f"  ready file: {json.dumps(info)}")
            step(f"Connecting with python-can: can.Bus(interface='gatewaylab', channel='{endpoint}')")
            bus = can.Bus(interface="gatewaylab", channel=endpoint, name="demo")
            narrator = Narrator()
            try:
                if drives:
                    demo_drives(bus, narrator, drives)
                else:
                    notifier = can.Notifier(bus, [narrator])
                    step("No drives in this rig: sending a few frames of our own and watching them go round")
                    with can.Bus(interface="gatewaylab", channel=endpoint, name="demo-peer") as peer:
                        for i in range(3):
                            peer.send(can.Message(arbitration_id=0x701 + i, data=b"\x05", is_extended_id=False))
                        peer.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
                        time.sleep(0.2)
                    notifier.stop()
                demo_idx(info)
            finally:
                bus.shutdown()
            step(f"Stopping the rig (SIGTERM); {narrator.count} frames seen; trace written by python-can:")
            proc.terminate()
            proc.wait(timeout=10)
            lines = trace.read_text().splitlines() if trace.exists() else []
            for line in lines[:5]:
                print(f"    {line}")
            if len(lines) > 5:
                print(f"    ... {len(lines) - 5} more lines")
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
