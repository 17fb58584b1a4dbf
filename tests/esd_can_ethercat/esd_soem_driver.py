"""pysoem master against the esd CAN-EtherCAT, run in a subprocess inside the test's network namespace;
prints one JSON result. It speaks the MDP 5000 counter handshake with its own struct packing (manual
5.1.5.1-5.1.5.4), independent of the emulator's codec.

Usage: python esd_soem_driver.py INTERFACE SCENARIO [ARGS...]
  identity                      identity, version strings, SDO Info object list, default sizes
  handshake MODE                MODE 11 or 29: F800:02 = 2, Tx batches of 5/16/8 frames that the
                                emulator's echo node answers (id + 0x100), read back as Rx batches
  foe SECONDS                   FoE refused in PREOP, then BOOT + firmwareUpdate, wait for the reboot
"""

from __future__ import annotations

import json
import struct
import sys
import time
from typing import Any

import pysoem

RX_TIMEOUT_US = 100_000
SLOW_US = 3_000_000
OUT_HDR = struct.Struct("<HHH")
IN_HDR = struct.Struct("<HHHH")


def _open(iface: str) -> Any:
    master = pysoem.Master()
    master.sdo_read_timeout = SLOW_US
    master.sdo_write_timeout = SLOW_US
    master.open(iface)
    return master


def _init(master: Any) -> int:
    """config_init, repeated when a reply came too late on this shared machine (it then finds 0)."""
    n = 0
    for _ in range(10):
        n = master.config_init()
        if n > 0:
            return int(n)
        time.sleep(0.2)
    return int(n)


def _retry(fn: Any, *args: Any) -> Any:
    """A mailbox service repeated when this shared machine delayed a reply past SOEM's timeout
    (pysoem then raises WkcError/PacketError); every call here is idempotent."""
    for attempt in range(6):
        try:
            return fn(*args)
        except (pysoem.WkcError, pysoem.PacketError, pysoem.ConfigMapError, pysoem.MailboxError,
                pysoem.SdoInfoError):
            if attempt == 5:
                raise
            time.sleep(0.2)
    return None


def _text(value: Any) -> str:
    return value.decode("latin-1") if isinstance(value, bytes) else str(value)


def _u(raw: bytes) -> int:
    return int.from_bytes(raw, "little")


def _to_op(master: Any) -> str:
    for _ in range(5):   # the mapping is read by SDO: repeated when a reply came too late
        _retry(master.config_map)
        if all(len(sl.input) and len(sl.output) for sl in master.slaves):
            break
        time.sleep(0.2)
    master.state_check(pysoem.SAFEOP_STATE, 50_000)
    master.state = pysoem.OP_STATE
    master.send_processdata()
    master.receive_processdata(RX_TIMEOUT_US)
    master.write_state()
    for _ in range(400):
        master.send_processdata()
        master.receive_processdata(RX_TIMEOUT_US)
        if master.state_check(pysoem.OP_STATE, 5000) == pysoem.OP_STATE:
            return "OP"
    return f"state {master.state_check(pysoem.OP_STATE, 5000)}"


def scenario_identity(iface: str) -> dict[str, Any]:
    master = _open(iface)
    out: dict[str, Any] = {"count": _init(master)}
    s = master.slaves[0]
    out.update(name=s.name, man=s.man, id=s.id, rev=s.rev)
    out["device_type"] = _u(_retry(s.sdo_read, 0x1000, 0))
    out["device_name"] = _retry(s.sdo_read, 0x1008, 0).decode()
    out["hw"] = _retry(s.sdo_read, 0x1009, 0).decode()
    out["sw"] = _retry(s.sdo_read, 0x100A, 0).decode()
    out["identity"] = [_u(_retry(s.sdo_read, 0x1018, i)) for i in range(1, 5)]
    out["sm_types"] = [_u(_retry(s.sdo_read, 0x1C00, i)) for i in range(0, 5)]
    od = {obj.index: obj for obj in _retry(lambda: s.od)}
    out["od"] = sorted(od)
    out["od_names"] = {hex(i): _text(od[i].name) for i in (0x1600, 0x1A00, 0x6000, 0x7000, 0x8000, 0xF800) if i in od}
    out["map_1600"] = [_u(_retry(s.sdo_read, 0x1600, i)) for i in (0, 1, 4)]
    out["op"] = _to_op(master)
    out["sizes"] = [len(s.output), len(s.input)]
    master.close()
    return out


def _tx11(tn: int, can_id: int, data: bytes) -> bytes:
    return struct.pack("<HH8s", tn, can_id << 5 | len(data), data)


def _tx29(tn: int, can_id: int, data: bytes) -> bytes:
    return struct.pack("<HHI8s", tn, len(data), can_id | 0x80000000, data)


def _rx(raw: bytes, off: int, mode: int) -> tuple[int, str]:
    if mode == 11:
        word = _u(raw[off:off + 2])
        return word >> 5, raw[off + 2:off + 2 + (word & 0x0F)].hex()
    length, word = struct.unpack_from("<HI", raw, off)
    return word & 0x1FFFFFFF, raw[off + 6:off + 6 + (length & 0x0F)].hex()


def scenario_handshake(iface: str, mode: int) -> dict[str, Any]:
    master = _open(iface)
    out: dict[str, Any] = {"count": _init(master)}
    s = master.slaves[0]
    _retry(s.sdo_write, 0xF800, 2, bytes([2]))                   # 500 kbit/s (Table 6)
    if mode == 29:
        _retry(s.sdo_write, 0x8000, 0x20, (1).to_bytes(2, "little"))
    out["op"] = _to_op(master)
    out["sizes"] = [len(s.output), len(s.input)]
    tx_size, rx_size = (12, 10) if mode == 11 else (16, 14)
    base = 0x100 if mode == 11 else 0x18FF0000
    batches = [[(base + 16 * b + i, bytes([b, i, 0xEE])) for i in range(n)] for b, n in enumerate((5, 16, 8))]
    want = sum(len(b) for b in batches)
    tx_counter = rx_counter = 0
    outputs = bytearray(len(s.output))
    received: list[tuple[int, str]] = []
    rx_batches: list[int] = []
    acks: list[int] = []
    tn = 0
    pending = list(batches)
    next_tn = 1
    waiting_ack = False
    for cycle in range(20_000):
        inputs = bytes(s.input)
        in_tx, in_rx, num, tn = IN_HDR.unpack_from(inputs, 0)
        if waiting_ack and in_tx == tx_counter:
            acks.append(cycle)
            waiting_ack = False
        if not waiting_ack and pending and in_tx == tx_counter:
            batch = pending.pop(0)
            pack = _tx11 if mode == 11 else _tx29
            body = b"".join(pack(next_tn + k, cid, d) for k, (cid, d) in enumerate(batch))
            next_tn += len(batch)
            tx_counter = (tx_counter + 1) & 0xFFFF
            outputs[6:6 + len(body)] = body
            OUT_HDR.pack_into(outputs, 0, tx_counter, rx_counter, len(batch))
            waiting_ack = True
        if in_rx != rx_counter:
            for i in range(num):
                received.append(_rx(inputs, 8 + i * rx_size, mode))
            rx_batches.append(num)
            rx_counter = in_rx
            OUT_HDR.pack_into(outputs, 0, tx_counter, rx_counter, OUT_HDR.unpack_from(outputs, 0)[2])
        s.output = bytes(outputs)
        master.send_processdata()
        master.receive_processdata(RX_TIMEOUT_US)
        if len(received) >= want and not pending and not waiting_ack:
            break
        time.sleep(0.001)
    out.update(acks=acks, rx_batches=rx_batches, received=received, last_tn=tn,
               sent=[(cid, d.hex()) for b in batches for cid, d in b], tx_size=tx_size)
    out["stats"] = {hex(sub): _u(_retry(s.sdo_read, 0x2010, sub)) for sub in (0x30, 0x31, 0x32, 0x3C, 0x3E)}
    master.close()
    return out


def scenario_foe(iface: str, seconds: float) -> dict[str, Any]:
    master = _open(iface)
    out: dict[str, Any] = {"count": _init(master)}
    s = master.slaves[0]
    image = b"CAN-EtherCAT firmware 2.7\n" + bytes(range(256)) * 12
    out["preop_result"] = s.foe_write("firmwareUpdate", 0, image, SLOW_US)
    s.state = pysoem.INIT_STATE
    s.write_state()
    s.state_check(pysoem.INIT_STATE, 500_000)
    s.state = pysoem.BOOT_STATE
    s.write_state()
    out["boot_state"] = s.state_check(pysoem.BOOT_STATE, 500_000)
    out["boot_result"] = s.foe_write("firmwareUpdate", 0, image, SLOW_US)
    deadline = time.monotonic() + seconds + 10
    state = 0
    while time.monotonic() < deadline:
        master.read_state()
        state = s.state
        if state & 0x0F == pysoem.INIT_STATE:
            break
        time.sleep(0.05)
    out["after_update"] = state
    out["count_again"] = _init(master)
    out["sw"] = _retry(master.slaves[0].sdo_read, 0x100A, 0).decode()
    master.close()
    return out


if __name__ == "__main__":
    iface, scenario = sys.argv[1], sys.argv[2]
    if scenario == "identity":
        result = scenario_identity(iface)
    elif scenario == "handshake":
        result = scenario_handshake(iface, int(sys.argv[3]))
    elif scenario == "foe":
        result = scenario_foe(iface, float(sys.argv[3]))
    else:
        raise SystemExit(f"unknown scenario {scenario}")
    print(json.dumps(result))
