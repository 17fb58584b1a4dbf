"""The EtherCAT master of the user-path tests (issue 21), run inside the test's network namespace the way a
user runs his master next to ``gatewaylab run``: pysoem (SOEM) or KickCAT on the master end of the veth pair,
the device kind's bring-up from its manual, then a paced 1 kHz cyclic task for SECONDS.

It prints one JSON line per event as it happens (flushed, so the test can act on ``op`` while this runs and
can kill it mid-exchange): ``op`` (OP reached), ``tx`` (a frame put into the outputs, wall time of the cycle
that carried it first), ``ack`` (esd: the gateway acknowledged the batch), ``rx`` (a frame from the CAN
side seen in the inputs), ``late`` (a cycle started more than 20 ms late: from when to when this process
stalled), and a final ``done`` with the counters. Every time is ``time.time()``: the test's
python-can client stamps with the same clock of the same machine.

The bring-ups are the project's drivers' (imported, not written again): ECAN-Lite manual 5.4.3 phases A-E
(tests/ecanlite/ecanlite_soem_driver.py), KickCAT's scan/OP session (ecanlite_kickcat_driver.py), the esd
MDP 5000 message layouts (tests/esd_can_ethercat/esd_soem_driver.py), the ETG.6010 default PDOs
(tests/ethercat_drive/ecdrive_soem_driver.py).

Usage: python ethercat_userpath_master.py INTERFACE soem|kickcat ecanlite|esd|drive_io SECONDS
"""

from __future__ import annotations

import json
import os
import struct
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import kit_paths

kit_paths.add_all()

import ecanlite_kickcat_driver as kc  # noqa: E402
import ecanlite_soem_driver as es  # noqa: E402
import ecdrive_soem_driver as dr  # noqa: E402
import esd_soem_driver as esd  # noqa: E402

from gatewaylab.devices.ecanlite.stream import (  # noqa: E402
    CanPacket,
    Commit,
    Direction,
    StreamError,
    StreamLayout,
    commit_state,
    decode_stream,
    encode_stream,
)

#: the cyclic task's period; a frame to the CAN side every FRAME_EVERY cycles
PERIOD = 0.001
#: process data: an answer later than this counts as a lost cycle (counted, never fatal)
PD_TIMEOUT_S = 0.020
FRAME_EVERY = 5
#: master -> CAN frames carry this id, CAN -> master frames the client's (tests/userpath/ethercat_userpath_kit.py)
M2C_ID, C2M_ID = 0x123, 0x2A5
#: ECAN-Lite chunks per direction (manual 5.1: classic CAN from N = 3)
ECAN_N = 3
#: ethercat_io process image (tests/ethercat/ethercat_kickcat_driver.py)
IO_OUT = struct.Struct("<Bhh")
IO_IN = struct.Struct("<BhhI")


def emit(event: str, **fields: Any) -> None:
    print(json.dumps({"ev": event, **fields}), flush=True)


#: a frame's 8 data bytes: its sequence number and the sender's tag (this process's pid, a client's own
#: number), so frames a killed master or a closed client left in the gateway are not taken for new ones
FRAME = struct.Struct("<II")


def payload(seq: int) -> bytes:
    return FRAME.pack(seq, os.getpid())


def rx_event(data: bytes, t: float) -> None:
    seq, src = FRAME.unpack_from(data)
    emit("rx", seq=seq, src=src, t=t)


# ------------------------------------------------------------------------------------------ the two masters
class Soem:
    """pysoem: scan, SDO access, OP (esd_soem_driver's retrying _to_op), one LRW per cycle."""

    def __init__(self, iface: str) -> None:
        self.m = es._open(iface)
        self.count = esd._init(self.m)
        if self.count == 0:
            raise RuntimeError("SOEM found no slave")
        self.slaves = list(self.m.slaves)

    def sdo_slave(self, k: int) -> Any:
        return self.slaves[k]

    def sdo_write(self, k: int, index: int, sub: int, data: bytes) -> None:
        esd._retry(self.slaves[k].sdo_write, index, sub, data)

    def to_op(self) -> str:
        for s in self.slaves:
            esd._retry(s.set_watchdog, "processdata", 1000)  # a stall of this shared VM must not end OP
        return str(esd._to_op(self.m))

    def cycle(self) -> bool:
        self.m.send_processdata()
        return bool(self.m.receive_processdata(int(PD_TIMEOUT_S * 1e6)) == self.m.expected_wkc)

    def write(self, k: int, data: bytes) -> None:
        self.slaves[k].output = data

    def read(self, k: int) -> bytes:
        return bytes(self.slaves[k].input)

    def out_size(self, k: int) -> int:
        return len(self.slaves[k].output)


class _KickcatSdo:
    """A KickCAT slave seen through pysoem's ``sdo_read``/``sdo_write`` (what ecanlite_soem_driver's
    5.4.3 phases call)."""

    def __init__(self, session: kc.Session) -> None:
        self.s = session

    def sdo_read(self, index: int, sub: int) -> bytes:
        return bytes(self.s.read(index, sub))

    def sdo_write(self, index: int, sub: int, data: bytes) -> None:
        self.s.write(index, sub, data)


class Kickcat:
    """KickCAT: ecanlite_kickcat_driver's Session (scan and mailbox with KickCAT's default timeouts, OP)."""

    def __init__(self, iface: str) -> None:
        self.s = kc.Session(iface)
        self.slaves = list(self.s.bus.slaves())
        self.count = len(self.slaves)

    def sdo_slave(self, k: int) -> Any:
        assert k == 0
        return _KickcatSdo(self.s)

    def sdo_write(self, k: int, index: int, sub: int, data: bytes) -> None:
        assert k == 0
        self.s.write(index, sub, data)

    def to_op(self) -> str:
        state = self.s.to_op()
        self.s.link.set_timeout(PD_TIMEOUT_S)
        return "OP" if state == "State.OPERATIONAL" else state

    def cycle(self) -> bool:
        return bool(self.s.cycle())

    def write(self, k: int, data: bytes) -> None:
        self.slaves[k].set_output_bytes(data)

    def read(self, k: int) -> bytes:
        return bytes(self.slaves[k].input_data)

    def out_size(self, k: int) -> int:
        return int(self.slaves[k].output_size)


# ------------------------------------------------------------------------------------------ the cyclic task
class Task:
    """The paced cyclic task: ``step(i)`` before each exchange, ``after(i, ok)`` after it."""

    def __init__(self, line: Soem | Kickcat) -> None:
        self.line = line
        self.late = 0
        self.bad = 0
        self.cycles = 0

    def run(self, seconds: float, step: Any, after: Any, until: Any = None) -> None:
        """Cycles for ``seconds``, or until ``until()`` holds."""
        t_next = time.perf_counter()
        end = t_next + seconds
        i = 0
        while t_next < end and not (until is not None and until()):
            step(i)
            ok = self.line.cycle()
            self.cycles += 1
            if not ok:
                self.bad += 1
            after(i, ok)
            t_next += PERIOD
            slack = t_next - time.perf_counter()
            if slack > 0:
                time.sleep(slack)
            else:           # late: missed periods are skipped, not caught up in a burst (a timer's task)
                if slack < -0.02:      # a cycle later than 20 ms: counted and reported
                    self.late += 1
                    now = time.time()
                    emit("late", t0=now + slack - PERIOD, t=now)    # this process (or its answer) stalled
                t_next = time.perf_counter()
            i += 1


def run_ecanlite(line: Soem | Kickcat, seconds: float) -> dict[str, Any]:
    """5.4.3 phases A-E (N = 3), OP, then a frame to CAN0 every FRAME_EVERY cycles (the first one in the
    first cycle after OP, 5.4.4.1), every TxPDO image parsed (chapter 6) for the client's frames."""
    es._configure(line.sdo_slave(0), ECAN_N)
    op = line.to_op()
    emit("op", t=time.time(), state=op)
    rx = StreamLayout(multiplier=ECAN_N, direction=Direction.RX)
    tx = StreamLayout(multiplier=ECAN_N, direction=Direction.TX)
    previous: list[bytes | None] = [None]
    errors: list[int] = []
    counts = {"tx": 0, "rx": 0}

    def step(i: int) -> None:
        if i % FRAME_EVERY == 0:
            seq = i // FRAME_EVERY
            line.write(0, encode_stream(rx, seq + 1, [CanPacket.of(0, M2C_ID, data=payload(seq))]))
            emit("tx", seq=seq, t=time.time())
            counts["tx"] += 1

    def after(i: int, ok: bool) -> None:
        if not ok:
            return
        image = line.read(0)
        if len(image) != tx.pdo_bytes or commit_state(image, previous[0]) is not Commit.NEW:
            return
        previous[0] = image
        t = time.time()
        try:
            for p in decode_stream(image, tx).packets:
                if isinstance(p, CanPacket) and p.can_id == C2M_ID:
                    rx_event(p.data, t)
                    counts["rx"] += 1
        except StreamError as exc:
            errors.append(int(exc.pdo_error))

    task = Task(line)
    task.run(seconds, step, after)
    return {"op": op, **counts, "stream_errors": errors, "bad_wkc": task.bad, "late": task.late,
            "cycles": task.cycles}


def run_esd(line: Soem | Kickcat, seconds: float) -> dict[str, Any]:
    """PREOP: 0xF800:02 = 2 (500 kbit/s, Table 6); OP; the MDP 5000 counter handshake (shared note
    esd-mdp5000-queues): a one-frame Tx batch whenever the previous one is acknowledged and FRAME_EVERY
    cycles passed (the first in the first cycle after OP), every Rx batch read and acknowledged."""
    line.sdo_write(0, 0xF800, 2, bytes([2]))
    op = line.to_op()
    emit("op", t=time.time(), state=op)
    outputs = bytearray(line.out_size(0))
    st = {"tx_counter": 0, "rx_counter": 0, "pending": -1, "seq": 0, "last_tx": -FRAME_EVERY, "tx": 0, "rx": 0,
          "acks": 0}

    def step(i: int) -> None:
        if st["pending"] < 0 and i - st["last_tx"] >= FRAME_EVERY:
            seq = st["seq"]
            body = esd._tx11(seq & 0xFFFF or 1, M2C_ID, payload(seq))
            outputs[6:6 + len(body)] = body
            st["tx_counter"] = (st["tx_counter"] + 1) & 0xFFFF
            esd.OUT_HDR.pack_into(outputs, 0, st["tx_counter"], st["rx_counter"], 1)
            st["pending"], st["seq"], st["last_tx"] = seq, seq + 1, i
            emit("tx", seq=seq, t=time.time())
            st["tx"] += 1
        line.write(0, bytes(outputs))

    def after(i: int, ok: bool) -> None:
        if not ok:
            return
        inputs = line.read(0)
        t = time.time()
        in_tx, in_rx, num, _tn = esd.IN_HDR.unpack_from(inputs, 0)
        if st["pending"] >= 0 and in_tx == st["tx_counter"]:
            emit("ack", seq=st["pending"], t=t)
            st["pending"] = -1
            st["acks"] += 1
        if in_rx != st["rx_counter"]:
            for k in range(num):
                can_id, data = esd._rx(inputs, 8 + 10 * k, 11)
                if can_id == C2M_ID:
                    rx_event(bytes.fromhex(data), t)
                    st["rx"] += 1
            st["rx_counter"] = in_rx
            esd.OUT_HDR.pack_into(outputs, 0, st["tx_counter"], in_rx, esd.OUT_HDR.unpack_from(outputs, 0)[2])

    task = Task(line)
    task.run(seconds, step, after)
    return {"op": op, "tx": st["tx"], "rx": st["rx"], "acks": st["acks"], "bad_wkc": task.bad, "late": task.late,
            "cycles": task.cycles}


def run_drive_io(line: Soem | Kickcat, seconds: float) -> dict[str, Any]:
    """The ethercat_drive (position 0) and the ethercat_io (position 1) to OP. The io outputs carry a new
    value every cycle and the time until the inputs echo it is measured (the io box is a loop-back). The
    drive's axis is enabled by PDO (CiA 402 controlwords: 0x80 fault reset, 0x06, 0x07, 0x0F; the target
    follows the actual position until then) in CSP and follows a ramp of 20 increments per cycle for 500
    cycles, then holds (ending 300 cycles after the ramp, or after SECONDS)."""
    op = line.to_op()
    t_op = time.time()
    emit("op", t=t_op, state=op)
    written: dict[int, float] = {}
    echoes: list[float] = []
    st: dict[str, Any] = {"cw": 0x06, "sw": [], "enabled_at": None, "ramp_from": None, "x0": 0, "worst": 0,
                          "target": 0, "x": 0, "last": -1, "first_after_op": None,
                          "last_after": t_op, "skip": 0, "skipped": 0}
    ramp = 500

    def step(i: int) -> None:
        value = i % 250 + 1
        written[value] = time.time()
        line.write(1, IO_OUT.pack(value, i & 0x7FFF, -i & 0x7FFF))
        if st["ramp_from"] is not None:
            st["target"] = st["x0"] + 20 * min(i - st["ramp_from"], ramp)
        line.write(0, dr.RX.pack(st["cw"], st["target"], 0, 0, dr.CSP) + bytes(line.out_size(0) - dr.RX.size))

    def after(i: int, ok: bool) -> None:
        if not ok:
            return
        t = time.time()
        digital = IO_IN.unpack(line.read(1)[:IO_IN.size])[0]
        if digital != st["last"] and digital in written:
            echoes.append(t - written[digital])
            if st["first_after_op"] is None:
                st["first_after_op"] = t - t_op
        st["last"] = digital
        sw, x, *_ = dr.TX.unpack(line.read(0)[:dr.TX.size])
        st["x"] = x
        if not st["sw"] or st["sw"][-1] != sw:
            st["sw"].append(sw)
        gap, st["last_after"] = t - st["last_after"], t
        if gap > PD_TIMEOUT_S:          # this process stalled: the following error is not judged for 5 cycles
            st["skip"] = 5
        if st["enabled_at"] is not None:
            if st["skip"]:
                st["skip"] -= 1
                st["skipped"] += 1
            elif st["ramp_from"] < i <= st["ramp_from"] + ramp:
                st["worst"] = max(st["worst"], abs(st["target"] - x))
            return
        st["target"] = x
        if sw & 0x4F == 0x08:                       # fault (the previous master vanished): fault reset
            st["cw"] = 0x80
        elif sw & 0x4F == 0x40:                     # switch on disabled
            st["cw"] = 0x06
        elif sw & 0x6F == 0x21:                     # ready to switch on
            st["cw"] = 0x07
        elif sw & 0x6F == 0x23:                     # switched on
            st["cw"] = 0x0F
        elif sw & 0x6F == 0x27:                     # operation enabled
            st["enabled_at"] = t - t_op
            st["ramp_from"], st["x0"] = i + 1, x

    task = Task(line)
    settle = 300       # cycles after the ramp: the axis reaches its last target, the io keeps echoing
    task.run(seconds, step, after,
             until=lambda: st["ramp_from"] is not None and task.cycles - st["ramp_from"] > ramp + settle)
    return {"op": op, "first_echo_after_op": st["first_after_op"], "echoes": echoes, "statuswords": st["sw"],
            "enabled_after": st["enabled_at"],
            "ramp_done": st["ramp_from"] is not None and task.cycles - st["ramp_from"] > ramp,
            "following_worst": st["worst"], "following_skipped": st["skipped"], "final": st["x"] - st["x0"],
            "ramp_end": 20 * ramp,
            "bad_wkc": task.bad, "late": task.late, "cycles": task.cycles}


def main(iface: str, lib: str, kind: str, seconds: float) -> dict[str, Any]:
    t0 = time.time()
    line: Soem | Kickcat = Soem(iface) if lib == "soem" else Kickcat(iface)
    emit("scanned", t=time.time(), count=line.count, took=time.time() - t0)
    run = {"ecanlite": run_ecanlite, "esd": run_esd, "drive_io": run_drive_io}[kind]
    out = run(line, seconds)
    out["retries"] = [*es._Retry.retries, *kc.Session.retries]
    return out


if __name__ == "__main__":
    emit("done", **main(sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])))
