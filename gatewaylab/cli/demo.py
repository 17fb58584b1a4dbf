"""`make demo`: start the default rig like a user would, drive real traffic, explain it, exit.

The rig runs as its own process (`gatewaylab run --ready-file ...`); this script is a client that
connects through the `gatewaylab` python-can interface, exactly as any other program would.
"""

from __future__ import annotations

import json
import os
import selectors
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from types import FrameType
from typing import Any

import can

from gatewaylab.bus.frame import CanFrame
from gatewaylab.canopen.explain import explain
from gatewaylab.common.errors import LocalError
from gatewaylab.rig.config import load_rig

__all__ = [
    "DemoRigDown",
    "Narrator",
    "demo_canopen",
    "demo_ethercat",
    "demo_ethercat_drive",
    "demo_idx",
    "main",
    "step",
]


class DemoRigDown(LocalError, RuntimeError):
    """The demo's rig exited or wrote no ready file in time."""


class Narrator(can.Listener):
    """Prints every frame on the bus with what it means, at its time on the rig's clock.

    ``wall_epoch`` is the Unix time of the rig's clock time 0 (from the ready file): a frame's
    ``Message.timestamp`` minus it is the time the trace files and the rig count from (docs/rig.md).
    """

    def __init__(self, wall_epoch: float = 0.0) -> None:
        self.wall_epoch = wall_epoch
        self.count = 0
        self.quiet = False
        self.lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        """Print each frame of the demo bus with its explanation, as the narrator of the tour."""
        if msg.is_error_frame:
            return
        frame = CanFrame.from_message(msg)
        with self.lock:
            self.count += 1
            if not self.quiet:
                print(f"    {self.clock_time(msg.timestamp):9.6f}  {frame!s:<26} {explain(frame)}", flush=True)

    def clock_time(self, timestamp: float) -> float:
        """Seconds since the rig's clock time 0 of a Unix ``timestamp``."""
        # A rig older than the one time base sent clock times already (nothing before 1973 is Unix time).
        return timestamp - self.wall_epoch if timestamp > 1e8 else timestamp


def _wait_ready(proc: subprocess.Popen[bytes], ready: Path, timeout: float = 30.0) -> dict[str, Any]:
    """Wait for the rig's ready file by watching its stdout (it prints after writing the file)."""
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout
    while not ready.exists():
        remaining = deadline - time.monotonic()
        if remaining <= 0 or proc.poll() is not None:
            raise DemoRigDown(f"the rig did not come up (exit code {proc.poll()})")
        if sel.select(remaining):
            line = os.read(proc.stdout.fileno(), 65536)
            sys.stdout.write("".join(f"  | {x}\n" for x in line.decode().splitlines()))
    sel.close()
    info: dict[str, Any] = json.loads(ready.read_text())
    return info


def step(title: str) -> None:
    """Print the heading of the next demo step."""
    print(f"\n== {title}", flush=True)


def _u(data: bytes, signed: bool = False) -> int:
    return int.from_bytes(data, "little", signed=signed)


def demo_canopen(bus: can.BusABC, narrator: Narrator, nodes: list[int], unconfigured: int) -> list[int]:
    """NMT, SDO, LSS Fastscan and a CiA 402 move, as a CANopen master in another process sees them."""
    import canopen

    network = canopen.Network(bus)
    # The narrator listens first, so each frame is printed before canopen acts on it.
    network.notifier = can.Notifier(bus, [narrator, canopen.network.MessageListener(network)], timeout=0.05)
    try:
        step("NMT 'reset communication' to all nodes: every configured node answers with a boot-up message")
        network.nmt.send_command(0x82)
        time.sleep(0.2)
        for node_id in nodes:
            node = network.add_node(node_id)
            assert isinstance(node, canopen.RemoteNode)
            step(f"SDO reads from node {node_id}: device type 0x1000, identity 0x1018, device name 0x1008")
            device_type = _u(node.sdo.upload(0x1000, 0))
            vendor = _u(node.sdo.upload(0x1018, 1))
            serial = _u(node.sdo.upload(0x1018, 4))
            name = node.sdo.upload(0x1008, 0).decode(errors="replace")
            print(f"  -> device type 0x{device_type:08X} (CiA 402 servo), vendor 0x{vendor:08X} (maxon), "
                  f"serial 0x{serial:X}, name {name!r}")
        if unconfigured:
            new_id = max([*nodes, 3]) + 1
            step(f"LSS Fastscan (CiA 305): find the {unconfigured} drive(s) without a node id and give one id {new_id}")
            network.lss.RESPONSE_TIMEOUT = 0.02
            narrator.quiet = True
            found, address = network.lss.fast_scan()
            if not found:
                # a busy machine can miss a 20 ms answer window (each missed answer reads as a 1 bit)
                network.lss.RESPONSE_TIMEOUT = 0.1
                found, address = network.lss.fast_scan()
            narrator.quiet = False
            if found:
                print(f"  -> found vendor 0x{address[0]:X} product 0x{address[1]:X} revision 0x{address[2]:X} "
                      f"serial 0x{address[3]:X} in {narrator.count} frames so far; it is now in LSS configuration "
                      "state")
                network.lss.configure_node_id(new_id)
                network.lss.send_switch_state_global(network.lss.WAITING_STATE)
                time.sleep(0.1)
                nodes = [*nodes, new_id]
        if len(nodes) > 1:
            node_id = nodes[1]
            first = network.add_node(node_id)
            assert isinstance(first, canopen.RemoteNode)
            step(f"CiA 402 on node {node_id}: Profile Position mode, enable (controlword 6, 7, 15), move to 1000")
            sdo = first.sdo
            sdo.download(0x6060, 0, (1).to_bytes(1, "little", signed=True))
            for cw in (0x06, 0x07, 0x0F):
                sdo.download(0x6040, 0, cw.to_bytes(2, "little"))
            sdo.download(0x607A, 0, (1000).to_bytes(4, "little", signed=True))
            sdo.download(0x6040, 0, (0x1F).to_bytes(2, "little"))
            narrator.quiet = True
            deadline = time.monotonic() + 10.0
            status = position = 0
            while time.monotonic() < deadline:
                status = _u(sdo.upload(0x6041, 0))
                position = _u(sdo.upload(0x6064, 0), signed=True)
                if status & 0x0400 and position == 1000:
                    break
            narrator.quiet = False
            print(f"  -> statusword 0x{status:04X} (operation enabled, target reached: {bool(status & 0x400)}), "
                  f"position actual {position}")
    finally:
        network.notifier.stop()
    return nodes


def demo_idx(info: dict[str, Any], nodes: list[int]) -> None:
    """The maxon IDX's USB protocol from a host program, through its virtual serial port."""
    from gatewaylab.hosts.maxon_idx.client import IdxClient

    for name, ports in info.get("usb", {}).items():
        step(f"maxon IDX {name!r} over its virtual USB port {ports['pty']} (pyserial, DLE/STX frames, CRC-CCITT)")
        with IdxClient(ports["pty"]) as idx:
            print(f"  -> ReadObject 0x1008 on the IDX itself: {idx.read_string(0, 0x1008, 0)!r}")
            for node_id in nodes[1:3]:
                position = idx.read(node_id, 0x6064, 0, "i32")
                print(f"  -> ReadObject 0x6064 of node {node_id} through the IDX's SDO gateway: {position}")


def demo_ethercat() -> None:
    """The two EtherCAT gateways in process: the in-process master on a simulated clock (no root needed;
    `make test` drives the same devices with SOEM over veth pairs)."""
    from dataclasses import replace

    from gatewaylab.bus import VirtualBus, python_can_bus
    from gatewaylab.common.clock import SimulatedClock
    from gatewaylab.devices.ecanlite.device import EcanLiteDevice
    from gatewaylab.devices.ecanlite.stream import CanPacket, Direction, StreamLayout, decode_stream, encode_stream
    from gatewaylab.devices.esd_can_ethercat import create_esd_gateway
    from gatewaylab.devices.esd_can_ethercat.codec import IN_HEADER, OUT_HEADER, decode_rx11, encode_tx11
    from gatewaylab.ethercat.esc import AlState
    from gatewaylab.ethercat.segment import Segment
    from gatewaylab.hosts.ethercat.master import Master

    step("ECAN-Lite (EtherCAT slave, 4 x CAN FD) in process: bring-up of manual 5.4.3, one CAN_FRAME each way")
    clock = SimulatedClock()
    can0 = VirtualBus(clock, "can0", 500_000)
    ecan = EcanLiteDevice(clock, [can0.attach("ecan.mcan0")])
    master = Master(clock, Segment([ecan.slave]))
    master.scan()
    master.set_state(AlState.PREOP)
    for sub, value, size in ((15, 0, 1), (19, 500_000, 4), (1, 1, 1)):    # classic CAN, 500 kbit/s, apply
        (master.sdo_download8 if size == 1 else master.sdo_download32)(0, 0x8001, sub, value)
    master.bring_up()
    info = master.slave(0)
    print(f"  -> {info.name!r} in {AlState(master.al_status(0)[0] & 0x0F).name}: power-on profile N = 8, "
          f"{info.output_bytes} B of RxPDO and {info.input_bytes} B of TxPDO (128 x N, manual 5.1)")
    peer = python_can_bus(can0)
    layout = StreamLayout.default()
    master.pdo_write(0, 0, encode_stream(layout, 1, [CanPacket.of(0, 0x123, data=bytes.fromhex("1122334455667788"))]))
    for _ in range(3):
        master.exchange_process_data()
        clock.advance(0.001)
    msg = peer.recv(0)
    print(f"  -> RxPDO CAN_FRAME (5.4.4.1) on MCAN0 -> can0: {msg.arbitration_id:03X}#{bytes(msg.data).hex().upper()}"
          if msg is not None else "  -> nothing on can0")
    peer.send(can.Message(arbitration_id=0x321, data=b"\xca\xfe", is_extended_id=False))
    tx_layout = replace(layout, direction=Direction.TX)
    frames: list[CanPacket] = []
    for _ in range(3):                        # each cycle's TxPDO image carries what arrived since the last
        master.exchange_process_data()
        frames += decode_stream(master.pdo_read(0, 0, layout.pdo_bytes), tx_layout).frames
        clock.advance(0.001)
    print("  -> TxPDO: " + (", ".join(f"CAN_FRAME ch {f.channel} {f.can_id:03X}#{f.data.hex().upper()}"
                                      for f in frames) or "no frame"))
    peer.shutdown()

    step("esd CAN-EtherCAT in process: MDP 5000 counter handshake, one Tx batch and the echo's Rx batch")
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0", bitrate=500_000)
    esd = create_esd_gateway(clock, bus, "esd1")
    echo = bus.attach("echo", on_frame=lambda f, t: echo.send(CanFrame(f.can_id + 1, f.data[::-1])))
    master = Master(clock, Segment([esd.slave]))
    master.bring_up()
    master.sdo_download8(0, 0xF800, 2, 2)        # 500 kbit/s (Table 6)
    info = master.slave(0)
    print(f"  -> {info.name!r} in {AlState(master.al_status(0)[0] & 0x0F).name}: {info.output_bytes} B out / "
          f"{info.input_bytes} B in (11-bit queues of 16: 6 + 16 x 12 and 8 + 16 x 10, manual 5.1.5)")
    master.pdo_write(0, 0, OUT_HEADER.pack(1, 0, 1) + encode_tx11(7, CanFrame(0x100, b"hello")))
    for _ in range(3):
        master.exchange_process_data()
        clock.advance(0.001)
    tx, rx, _n, tn = IN_HEADER.unpack(master.pdo_read(0, 0, IN_HEADER.size))
    print(f"  -> Tx counter {tx} (transaction {tn} sent on the bus), Rx batch {rx}: "
          f"{decode_rx11(master.pdo_read(0, 8, 10), 0)} (the echo node's answer)")


def demo_ethercat_drive() -> None:
    """Two CoE CiA 402 drives (``ethercat_drive``) to Operation Enabled and 1 s of cyclic synchronous
    position through the default PDOs (ETG.6010), in process on a simulated clock."""
    import struct

    from gatewaylab.common.clock import SimulatedClock
    from gatewaylab.devices.ethercat_drive.device import EthercatDrive
    from gatewaylab.ethercat.esc import AlState
    from gatewaylab.ethercat.segment import Segment
    from gatewaylab.hosts.ethercat.master import Master

    step("EtherCAT CiA 402 drives in process: controlword 0x06/0x07/0x0F by RxPDO 0x1600, 1 s of CSP at 1 kHz")
    clock = SimulatedClock()
    drives = [EthercatDrive(clock, f"GL-Drive #{i}", serial=0x3001 + i) for i in range(2)]
    m = Master(clock, Segment([d.slave for d in drives]))
    m.bring_up()
    # RxPDO 0x1600: controlword, target position, target velocity, target torque, mode (8 = CSP)
    for i, cw in enumerate([0x06] * 3 + [0x07] * 3 + [0x0F] * 3 + [0x0F] * 1000):
        for p in (0, 1):
            m.pdo_write(p, 0, struct.pack("<HiihB", cw, 40 * max(0, i - 9), 0, 0, 8))
        m.exchange_process_data()
        clock.advance(0.001)
    for p in (0, 1):
        sw, x = struct.unpack("<Hi", m.pdo_read(p, 0, 6))
        print(f"  -> {m.slave(p).name} in {AlState(m.al_status(p)[0] & 0x0F).name}: statusword 0x{sw:04X} "
              f"(operation enabled), position actual {x} following a ramp to 40,000 (one cycle behind)")


class _Stopped(BaseException):
    """SIGTERM (or SIGHUP) while the demo runs: unwind, so the rig child is stopped and the folders go."""


def _stop(signum: int, frame: FrameType | None) -> None:
    raise _Stopped(signum)


def _quiet_stdout() -> None:
    """stdout was closed (``make demo | head``): send the rest to /dev/null, no second error at exit."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


def _stop_rig(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM, so the rig removes its sockets and folder itself; SIGKILL only if it does not stop."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    if proc.stdout is not None:
        proc.stdout.close()


def main(argv: list[str] | None = None) -> int:
    """Run the demo; on SIGTERM/SIGINT/SIGHUP or a closed stdout (SIGPIPE) stop the rig child with SIGTERM
    and remove the temporary folder before leaving (exit 128 + signal, 0 for a closed pipe)."""
    handlers = {signum: signal.signal(signum, _stop) for signum in (signal.SIGTERM, signal.SIGHUP)}
    handlers[signal.SIGINT] = signal.getsignal(signal.SIGINT)
    try:
        return _main(argv)
    except _Stopped as stopped:
        return 128 + int(stopped.args[0])
    except KeyboardInterrupt:
        return 128 + signal.SIGINT
    except BrokenPipeError:
        _quiet_stdout()
        return 0
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)


def _main(argv: list[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    config = load_rig(argv[0] if argv else None)
    nodes = sorted(int(d["node_id"]) for d in [*config.drives, *config.devices] if d.get("node_id") is not None)
    unconfigured = sum(1 for d in config.drives if d.get("node_id") is None)
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
            bus = can.Bus(interface="gatewaylab", channel=endpoint, name="demo", receive_own_messages=True)
            epoch = float(info.get("wall_epoch", 0.0))
            print(f"  times below: seconds since the rig's clock time 0 (Unix time {epoch:.6f}); "
                  "the trace file has the same instants as Unix time")
            narrator = Narrator(epoch)
            try:
                if nodes:
                    nodes = demo_canopen(bus, narrator, nodes, unconfigured)
                else:
                    notifier = can.Notifier(bus, [narrator])
                    step("No CANopen nodes in this rig: sending a few frames of our own and watching them go round")
                    with can.Bus(interface="gatewaylab", channel=endpoint, name="demo-peer") as peer:
                        for i in range(3):
                            peer.send(can.Message(arbitration_id=0x701 + i, data=b"\x05", is_extended_id=False))
                        time.sleep(0.2)
                    notifier.stop()
                demo_idx(info, nodes)
            finally:
                bus.shutdown()
            demo_ethercat()
            demo_ethercat_drive()
            step(f"Stopping the rig (SIGTERM); {narrator.count} frames seen; trace written by python-can:")
            proc.terminate()
            proc.wait(timeout=10)
            lines = trace.read_text().splitlines() if trace.exists() else []
            for line in lines[:5]:
                print(f"    {line}")
            if len(lines) > 5:
                print(f"    ... {len(lines) - 5} more lines")
        finally:
            # a second signal must not cut the clean-up short: the rig gets SIGTERM and ten seconds
            for signum in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
                signal.signal(signum, signal.SIG_IGN)
            _stop_rig(proc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
