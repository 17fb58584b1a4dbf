"""The SDO server against python-canopen's LocalNode, same run: the servers alone, and whole uploads.

Server only (the number of the target "SDO server >= 2x canopen LocalNode (median)"):
the same request frames -- an expedited upload, an expedited download, a segmented upload and a
segmented download of 20 bytes -- are fed to each server directly, in one process, in alternating
rounds: our :class:`Node`'s ``sdo.on_frame`` (answers queue on the node's controller, drained per
batch) and the LocalNode's ``sdo.on_request`` on a python-canopen ``Network`` whose
``send_message`` -- the hook python-canopen documents for a custom backend -- keeps the frames.
Both hold the same objects, and their answers are checked byte for byte before anything is timed
(tests/canopen/test_canopen_sdo_localnode.py asserts them against CiA 301 too). Times are CPU time
(``time.thread_time``) per batch, divided by the requests of the batch; the ratio is of the median
time per request over the four transfers (10 requests), each transfer is printed too.

End to end (context): expedited uploads per second by one python-canopen client, against our
Node and the LocalNode on one simulated virtual bus. Both servers hold the same UNSIGNED32 object
0x2000; the client reads them alternately in rounds, so both see the same machine load. The
LocalNode needs its own python-canopen network (a notifier thread answers its requests); our Node
answers inside the simulation. Every python-can endpoint accepts only the COB-IDs it consumes (the
acceptance filter of a real controller: the controller's ``rx_table``, as for our Node), so neither
server pays for the other's traffic waking threads. Rates come from the median time per upload
(robust against other load on the machine) and from the best round. Here the client, python-can's
``Message`` objects and the thread hand-offs take nearly all the time, the same for both servers,
so this ratio cannot show a server's speed (docs/decisions.md).

Pure and compiled side by side, each in its own child process (benchmarks/sides.py).
"""

from __future__ import annotations

import io
import statistics
import time
from collections.abc import Sequence

import can
import canopen

from benchmarks.sides import both, compare, quick
from benchmarks.targets import record
from gatewaylab.bus import VirtualBus
from gatewaylab.bus.frame import CanFrame
from gatewaylab.bus.transport.inprocess import InProcessBus
from gatewaylab.canopen.node import Node
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.od import Access, DataType, ObjectDictionary

ROUNDS = 7
PER_ROUND = 500
TIMING = True
#: Server only: rounds (each: one batch per transfer and server) and transfers per batch.
SERVER_ROUNDS = 61
SERVER_BATCH = 200

NODE_ID = 5
#: The segmented objects' content (20 bytes: segments of 7, 7 and 6 bytes).
TEXT = "gatewaylab SDO bench"
_T = TEXT.encode()
#: CiA 301 7.2.4.3: the request frames of each transfer, client to server (COB-ID 0x600 + node-id).
TRANSFERS: dict[str, tuple[bytes, ...]] = {
    # initiate upload 0x2000:00 -> 43 00 20 00 + 4 bytes
    "expedited upload": (bytes.fromhex("4000200000000000"),),
    # initiate download, expedited, 4 bytes indicated, 0x2001:00 = 0x12345678 -> 60 01 20 00
    "expedited download": (bytes.fromhex("2301200078563412"),),
    # initiate upload 0x2002:00 (size 20 answered), then three upload segment requests, toggle 0/1/0
    "segmented upload": (bytes.fromhex("4002200000000000"), bytes.fromhex("6000000000000000"),
                         bytes.fromhex("7000000000000000"), bytes.fromhex("6000000000000000")),
    # initiate download 0x2002:00 of 20 bytes, then segments t=0, t=1, t=0 (n=1, c=1)
    "segmented download": (bytes.fromhex("2102200014000000"), b"\x00" + _T[0:7], b"\x10" + _T[7:14],
                           b"\x03" + _T[14:20] + b"\x00"),
}


class CaptureNetwork(canopen.Network):
    """A python-canopen network that keeps what its nodes send: ``send_message`` is the hook
    python-canopen documents for integrating it with a custom backend."""

    def __init__(self) -> None:
        super().__init__()
        self.sent: list[tuple[int, bytes | bytearray]] = []

    def send_message(self, can_id: int, data: bytes | bytearray, remote: bool = False) -> None:
        self.sent.append((can_id, data))


def server_od() -> ObjectDictionary:
    """Our dictionary of the server-only comparison: 0x2000/0x2001 UNSIGNED32, 0x2002 VISIBLE_STRING."""
    od = ObjectDictionary()
    od.add_variable(0x2000, "Value", DataType.UNSIGNED32, Access.RW, 0x12345678)
    od.add_variable(0x2001, "Setpoint", DataType.UNSIGNED32, Access.RW, 0)
    od.add_variable(0x2002, "Text", DataType.VISIBLE_STRING, Access.RW, TEXT)
    return od


def local_server_od() -> canopen.ObjectDictionary:
    """The same objects as :func:`server_od` for python-canopen."""
    od = canopen.ObjectDictionary()  # type: ignore[no-untyped-call]
    types = canopen.objectdictionary
    for index, name, data_type, default in ((0x2000, "Value", types.UNSIGNED32, 0x12345678),
                                            (0x2001, "Setpoint", types.UNSIGNED32, 0),
                                            (0x2002, "Text", types.VISIBLE_STRING, TEXT)):
        var = types.ODVariable(name, index, 0)
        var.data_type = data_type
        var.access_type = "rw"
        var.default = default
        od.add_object(var)
    return od


class OurServer:
    """Our Node's SDO server fed directly: requests to ``sdo.on_frame`` as the bus delivers them,
    answers taken from the node's controller queue."""

    def __init__(self) -> None:
        self.clock = SimulatedClock()
        self.node = Node(self.clock, VirtualBus(self.clock, "sdo-server", bitrate=1_000_000), NODE_ID,
                         server_od())
        self.node.start()
        self.queue = self.node.controller.tx_queue
        self.queue.clear()          # the boot-up message

    def frames(self, requests: Sequence[bytes]) -> list[CanFrame]:
        return [CanFrame(0x600 + NODE_ID, r) for r in requests]

    def run(self, frames: Sequence[CanFrame], n: int) -> float:
        """CPU seconds of ``n`` runs of the transfer."""
        on_frame = self.node.sdo.on_frame
        with self.clock.lock:
            t0 = time.thread_time()
            for _ in range(n):
                for frame in frames:
                    on_frame(frame, 0.0)
            t = time.thread_time() - t0
        self.queue.clear()
        return t

    def answers(self, requests: Sequence[bytes]) -> list[tuple[int, bytes]]:
        for frame in self.frames(requests):
            self.node.sdo.on_frame(frame, 0.0)
        out = [(f.can_id, bytes(f.data)) for f in self.queue]
        self.queue.clear()
        return out


class LocalServer:
    """python-canopen's LocalNode fed directly: requests to ``sdo.on_request`` as its network's
    ``notify`` passes them (python-can's data is a bytearray), answers kept by :class:`CaptureNetwork`."""

    def __init__(self) -> None:
        self.network = CaptureNetwork()
        self.node = canopen.LocalNode(NODE_ID, local_server_od())
        self.network.add_node(self.node)

    def frames(self, requests: Sequence[bytes]) -> list[bytearray]:
        return [bytearray(r) for r in requests]

    def run(self, frames: Sequence[bytearray], n: int) -> float:
        """CPU seconds of ``n`` runs of the transfer."""
        on_request = self.node.sdo.on_request
        cob_id = 0x600 + NODE_ID
        t0 = time.thread_time()
        for _ in range(n):
            for data in frames:
                on_request(cob_id, data, 0.0)
        t = time.thread_time() - t0
        self.network.sent.clear()
        return t

    def answers(self, requests: Sequence[bytes]) -> list[tuple[int, bytes]]:
        for data in self.frames(requests):
            self.node.sdo.on_request(0x600 + NODE_ID, data, 0.0)
        out = [(can_id, bytes(data)) for can_id, data in self.network.sent]
        self.network.sent.clear()
        return out


def measure_servers() -> dict[str, float]:
    """Server only: ns per request by the median of alternating rounds, per transfer and over all four."""
    rounds, batch = (21, 100) if quick() else (SERVER_ROUNDS, SERVER_BATCH)
    ours, local = OurServer(), LocalServer()
    for name, requests in TRANSFERS.items():
        a, b = ours.answers(requests), local.answers(requests)
        if a != b:
            raise AssertionError(f"{name}: the servers answer differently: {a} != {b}")
    prepared = [(name, len(requests), ours.frames(requests), local.frames(requests))
                for name, requests in TRANSFERS.items()]
    for _, _, our_frames, local_frames in prepared:      # warm up
        ours.run(our_frames, batch)
        local.run(local_frames, batch)
    per_transfer: dict[str, tuple[list[float], list[float]]] = {name: ([], []) for name in TRANSFERS}
    mix_ours: list[float] = []
    mix_local: list[float] = []
    total = sum(len(requests) for requests in TRANSFERS.values())
    for r in range(rounds):
        sum_ours = sum_local = 0.0
        for name, count, our_frames, local_frames in prepared:
            if r % 2:                   # alternate which server goes first
                t_local = local.run(local_frames, batch)
                t_ours = ours.run(our_frames, batch)
            else:
                t_ours = ours.run(our_frames, batch)
                t_local = local.run(local_frames, batch)
            per_transfer[name][0].append(t_ours / batch / count)
            per_transfer[name][1].append(t_local / batch / count)
            sum_ours += t_ours / batch
            sum_local += t_local / batch
        mix_ours.append(sum_ours / total)
        mix_local.append(sum_local / total)
    result: dict[str, float] = {}
    print(f"SDO server only: ns per request (CPU time, median of {rounds} alternating rounds of {batch} "
          "transfers), same request frames, byte-identical answers")
    for name, (o, lo) in [*per_transfer.items(), ("all four (10 requests)", (mix_ours, mix_local))]:
        mo, ml = statistics.median(o) * 1e9, statistics.median(lo) * 1e9
        key = name.split(" (")[0].replace(" ", "_")
        result[f"server_{key}_ours"], result[f"server_{key}_local"] = mo, ml
        result[f"server_{key}_ratio"] = ml / mo
        print(f"  {name:<24} gatewaylab Node: {mo:7.0f}  canopen LocalNode: {ml:7.0f}  ratio: {ml / mo:5.2f}x")
    result["server_ratio"] = result["server_all_four_ratio"]
    return result


class _FilteredBus(InProcessBus):
    """The in-process python-can bus behind a hardware-like acceptance filter: the controller's
    ``rx_table`` passes only the listed standard COB-IDs to the queue (our Node's controller
    filters the same way)."""

    def __init__(self, vbus: VirtualBus, accept: set[int], name: str) -> None:
        super().__init__(vbus, name=name)
        with vbus.clock.lock:
            self.controller.rx_table = dict.fromkeys(accept, self._on_frame)


def _local_od() -> canopen.ObjectDictionary:
    od = canopen.ObjectDictionary()  # type: ignore[no-untyped-call]
    var = canopen.objectdictionary.ODVariable("Value", 0x2000, 0)
    var.data_type = canopen.objectdictionary.UNSIGNED32
    var.access_type = "rw"
    var.default = 0x12345678
    od.add_object(var)
    return od


def _round(remote: canopen.RemoteNode, n: int) -> tuple[float, list[float]]:
    """(uploads per second, seconds per upload) of ``n`` uploads."""
    upload = remote.sdo.upload
    clock = time.perf_counter
    times = []
    start = clock()
    for _ in range(n):
        t0 = clock()
        upload(0x2000, 0)
        times.append(clock() - t0)
    return n / (clock() - start), times


def measure() -> dict[str, float]:
    """The servers alone (:func:`measure_servers`), then whole uploads (:func:`measure_end_to_end`)."""
    return measure_servers() | measure_end_to_end()


def measure_end_to_end() -> dict[str, float]:
    """Both servers in alternating rounds; uploads/s by the median upload and by the best round."""
    global ROUNDS, PER_ROUND
    if quick():
        ROUNDS, PER_ROUND = 3, 200
    clock = SimulatedClock()
    vbus = VirtualBus(clock, "bench", bitrate=1_000_000, timing=TIMING)
    od = ObjectDictionary()
    od.add_variable(0x2000, "Value", DataType.UNSIGNED32, Access.RW, 0x12345678)
    ours = Node(clock, vbus, 5, od, name="gatewaylab-node")

    server_net = canopen.Network(_FilteredBus(vbus, {0x000, 0x606}, "localnode"))
    server_net.NOTIFIER_CYCLE = 0.05
    server_net.connect()
    local = canopen.LocalNode(6, _local_od())
    server_net.add_node(local)

    client_net = canopen.Network(_FilteredBus(vbus, {0x585, 0x586, 0x705, 0x706}, "client"))
    client_net.NOTIFIER_CYCLE = 0.05
    client_net.connect()
    try:
        with clock.lock:
            ours.start()
        assert isinstance(client_net.bus, can.BusABC)
        stream = io.StringIO(ours.to_eds())
        stream.name = "ours.eds"
        remote_ours = canopen.RemoteNode(5, stream)
        remote_local = canopen.RemoteNode(6, _local_od())
        client_net.add_node(remote_ours)
        client_net.add_node(remote_local)
        assert remote_ours.sdo.upload(0x2000, 0) == remote_local.sdo.upload(0x2000, 0)
        _round(remote_ours, 100)            # warm up both paths
        _round(remote_local, 100)
        ours_rates: list[float] = []
        local_rates: list[float] = []
        ours_times: list[float] = []
        local_times: list[float] = []
        for _ in range(ROUNDS):
            rate, times = _round(remote_ours, PER_ROUND)
            ours_rates.append(rate)
            ours_times += times
            rate, times = _round(remote_local, PER_ROUND)
            local_rates.append(rate)
            local_times += times
        ours_median = 1.0 / statistics.median(ours_times)
        local_median = 1.0 / statistics.median(local_times)
        print(f"end to end, expedited SDO uploads/s (median)  gatewaylab Node: {ours_median:8.0f}  "
              f"canopen LocalNode: {local_median:8.0f}  ratio: {ours_median / local_median:.2f}x (context)")
        print(f"end to end, expedited SDO uploads/s (best round)  gatewaylab Node: {max(ours_rates):8.0f}  "
              f"canopen LocalNode: {max(local_rates):8.0f}  ratio: {max(ours_rates) / max(local_rates):.2f}x")
        print(f"  {ROUNDS} rounds x {PER_ROUND} uploads per server, simulated time {clock.now():.3f} s")
        return {"ours": ours_median, "local": local_median, "ratio": ours_median / local_median,
                "best_ratio": max(ours_rates) / max(local_rates)}
    finally:
        client_net.disconnect()
        server_net.disconnect()


def targets() -> None:
    """Both measurements in a pure and a default child side by side; records the SDO server target
    by the server-only ratio (the end-to-end ratio printed as context)."""
    rows = [(f"server: {name}, ratio", f"server_{name.replace(' ', '_')}_ratio", ".2f") for name in TRANSFERS]
    sides = compare("bench_canopen_sdo", "SDO server vs canopen LocalNode (ratios Node / LocalNode)", [
        ("server: ns per request, LocalNode (baseline)", "server_all_four_local", ",.0f"),
        ("server: ns per request, gatewaylab Node", "server_all_four_ours", ",.0f"),
        *rows,
        ("server: all four, ratio (the target)", "server_ratio", ".2f"),
        ("end to end: uploads/s LocalNode, median", "local", ",.0f"),
        ("end to end: uploads/s gatewaylab Node, median", "ours", ",.0f"),
        ("end to end: ratio (median)", "ratio", ".2f"),
        ("end to end: ratio (best round)", "best_ratio", ".2f")])
    default = sides[1].result
    record("sdo", both(sides, "server_ratio", ".2f", "x") + f", server only; end to end {default['ratio']:.2f}x",
           default["server_ratio"] >= 2)


def main() -> None:
    targets()


if __name__ == "__main__":
    main()
