"""KickCAT master for the ECAN-Lite (run in a subprocess inside the test's network namespace): the power-on
default (N = 8) brought to OP untouched, then on a new scan manual 5.4.3 phases A-E over CoE in PREOP for
N = 3, OP, the 5.4.4.1 frame in the RxPDO, every TxPDO image parsed; prints one JSON result.

KickCAT 2.5's Python API has blocking SDO reads (``Bus.read_sdo``) and asynchronous SDO writes
(``slave.mailbox.write_sdo`` answered while ``Bus.process_mailboxes`` runs); its ``process_data`` is an
LRD followed by an LWR (the LRW path is not bound in Python).

Usage: python ecanlite_kickcat_driver.py INTERFACE CYCLES
"""

from __future__ import annotations

import json
import struct
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import kickcat

from gatewaylab.devices.ecanlite.stream import (
    CanPacket,
    Commit,
    Direction,
    StreamError,
    StreamLayout,
    commit_state,
    crc16,
    decode_stream,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))   # tests/: the kits by basename
import kit_paths

kit_paths.add_all()
from kickcat_kit import ATTEMPTS, MAILBOX_ATTEMPTS, run_as_kickcat_readme_says, run_step  # noqa: E402

#: KickCAT's own defaults: the link's 2 ms (lib/master/include/kickcat/Link.h ``timeout_{2ms}``) for every
#: datagram -- scan, mailbox, process data -- and 1 s for an SDO transfer (Bus.h readSDO/writeSDO). A step
#: that fails on a lost frame (KickCAT gives up a scan or an SDO on the first reply later than 2 ms) is run
#: again (tests/ethercat/kickcat_kit.py run_step), and every failure is printed with the result
#: (``retries``): the run shows how often this shared VM lost a frame instead of hiding it behind longer
#: timeouts.
LINK_TIMEOUT_S = 0.002
SDO_TIMEOUT_S = 1.0
RUNNING = kickcat.mailbox.request.MessageStatus.RUNNING
T = TypeVar("T")


def _u(data: bytes) -> int:
    return int.from_bytes(data, "little")


class Session:
    """One KickCAT bus on a fresh link, scanned (INIT -> PREOP)."""

    retries: list[str] = []

    def __init__(self, iface: str) -> None:
        run_as_kickcat_readme_says()
        self.iface = iface
        self.bus = self.step("init", self._scan)
        self.slave = self.bus.slaves()[0]
        self.bad_wkc = 0
        self.lost = 0

    def _scan(self) -> Any:
        self.link = kickcat.create_link(self.iface, "")
        self.link.set_timeout(LINK_TIMEOUT_S)
        bus = kickcat.Bus(self.link)
        bus.init(0.5)          # the slaves' watchdog (not a timeout of the master)
        return bus

    def step(self, name: str, step: Callable[[], T], attempts: int = ATTEMPTS) -> T:
        """``step()`` through kickcat_kit's run_step, its failed attempts added to ``retries``."""
        result, failed = run_step(name, step, attempts=attempts)
        self.retries.extend(failed)
        return result

    def read(self, index: int, sub: int, size: int = 4) -> bytes:
        return self.step(f"read {index:04X}:{sub}", lambda: bytes(
            self.bus.read_sdo(self.slave, index, sub, kickcat.Access.PARTIAL, size, SDO_TIMEOUT_S)), MAILBOX_ATTEMPTS)

    def write(self, index: int, sub: int, data: bytes) -> None:
        """SDO download through KickCAT's mailbox: queued, then driven by process_mailboxes."""
        def download() -> int:
            msg = self.slave.mailbox.write_sdo(index, sub, False, data, SDO_TIMEOUT_S)
            while msg.status() == RUNNING:
                self.bus.process_mailboxes()
            return int(msg.status())

        status = self.step(f"write {index:04X}:{sub}", download, MAILBOX_ATTEMPTS)
        if status != 0:
            raise RuntimeError(f"SDO download {index:04X}:{sub} answered status {status:#x}")

    def cycle(self) -> bool:
        """One process data exchange; False when a datagram came back with a wrong working counter
        (counted) or too late (counted apart: a stall of this VM, not a protocol error)."""
        try:
            self.bus.process_data()
        except RuntimeError as exc:
            if "INVALID_WKC" in str(exc):
                self.bad_wkc += 1
            else:
                self.lost += 1
            return False
        return True

    def to_op(self) -> str:
        """create_mapping (the assignment and the maps read over CoE: again after a lost mailbox frame),
        SAFEOP, OP with process data running."""
        self.step("create_mapping", lambda: self.bus.create_mapping(4096))
        self.bus.request_state(kickcat.State.SAFE_OP)
        self.bus.wait_for_state(kickcat.State.SAFE_OP, 2.0)
        self.cycle()
        self.bus.request_state(kickcat.State.OPERATIONAL)
        self.bus.wait_for_state(kickcat.State.OPERATIONAL, 2.0, self.cycle)
        return str(self.bus.get_state(self.slave))


def frame_5_4_4_1(n: int, seq: int) -> bytes:
    """5.4.4.1 written out as the manual does it (steps 1-4)."""
    image = bytearray(128 * n)
    image[24:36] = bytes.fromhex("40 00 23 01 11 22 33 44 55 66 77 88")
    word = (n - 1) & 0x1F | (0x0F << 5)
    layout_id = (word ^ (word >> 16)) & 0xFFFF
    struct.pack_into("<BBHHHHHBBBB", image, 0, 0x16, 0, seq, 0, 12, crc16(image[24:36]), layout_id, 0x0F, 1, 0, 1)
    struct.pack_into("<H", image, 4, seq)
    return bytes(image)


def run_cycles(s: Session, n: int, cycles: int, frame_at: int | None) -> dict[str, Any]:
    """``cycles`` exchanges, the 5.4.4.1 frame in the outputs from cycle ``frame_at``; every new TxPDO
    image is parsed (header, CRC, packets)."""
    tx = StreamLayout(multiplier=n, direction=Direction.TX)
    previous: bytes | None = None
    images = 0
    packets: list[list[Any]] = []
    errors: list[int] = []
    for i in range(cycles):
        if frame_at is not None and i == frame_at:
            s.slave.set_output_bytes(frame_5_4_4_1(n, 1))
        time.sleep(0.0005)          # a cyclic task, roughly 1 kHz: CAN peers get time to talk
        if not s.cycle():
            continue
        image = bytes(s.slave.input_data)
        if len(image) != tx.pdo_bytes or commit_state(image, previous) is not Commit.NEW:
            continue
        previous = image
        images += 1
        try:
            for p in decode_stream(image, tx).packets:
                if isinstance(p, CanPacket):
                    packets.append([p.channel, p.can_id, p.data.hex()])
        except StreamError as exc:
            errors.append(int(exc.pdo_error))
    return {"images": images, "rx_packets": packets, "tx_errors": errors}


def default_profile(s: Session, cycles: int) -> dict[str, Any]:
    """Nothing configured: the power-on assignment (5.1: N = 8) read by create_mapping."""
    out: dict[str, Any] = {"count": len(s.bus.slaves()), "name_1008": s.read(0x1008, 0, 32).decode()}
    out["assign"] = [[_u(s.read(a, 0, 1))] + [_u(s.read(a, i, 2)) for i in (1, 8)] for a in (0x1C12, 0x1C13)]
    out["op"] = s.to_op()
    out["sizes"] = [s.slave.output_size, s.slave.input_size]
    out.update(run_cycles(s, 8, cycles, None))
    out["bad_wkc"], out["lost"] = s.bad_wkc, s.lost
    s.bus.request_state(kickcat.State.INIT)
    return out


def configured(s: Session, n: int, cycles: int) -> dict[str, Any]:
    """5.4.3 phases A-E over CoE in PREOP, then create_mapping, OP and phase F (5.4.4.1)."""
    out: dict[str, Any] = {"A": {"channels": _u(s.read(0xF000, 2)), "n_min": _u(s.read(0xF000, 10)),
                                 "n_max": _u(s.read(0xF000, 11)), "unit": _u(s.read(0xF000, 17)),
                                 "header": _u(s.read(0xF000, 18))}}
    for assign, base in ((0x1C12, 0x1600), (0x1C13, 0x1A00)):                     # phase B
        s.write(assign, 0, bytes([0]))
        for i in range(n):
            s.write(assign, i + 1, struct.pack("<H", base + i))
        s.write(assign, 0, bytes([n]))
    out["B"] = [[_u(s.read(a, 0, 1))] + [_u(s.read(a, i + 1, 2)) for i in range(n)] for a in (0x1C12, 0x1C13)]
    for index in (0x8010, 0x8011):                                                 # phase C
        for sub, value in ((3, n), (4, 0x0F), (5, 0), (6, 0), (7, 0), (1, 1)):
            s.write(index, sub, bytes([value]))
    out["D"] = {hex(index): [_u(s.read(index, 2)), _u(s.read(index, 9)), _u(s.read(index, 10)),
                             _u(s.read(index, 12))] for index in (0x8010, 0x8011)}  # phase D
    for k in range(4):                                                             # phase E
        for sub, fmt, value in ((7, "<B", 0), (8, "<B", 0), (15, "<B", 1), (16, "<B", 1), (19, "<I", 1_000_000),
                                (20, "<I", 5_000_000), (21, "<H", 875), (22, "<H", 875), (23, "<H", 875),
                                (24, "<H", 875), (1, "<B", 1)):
            s.write(0x8001 + k, sub, struct.pack(fmt, value))
    out["E"] = [_u(s.read(0x8001 + k, 2)) for k in range(4)]
    out["op"] = s.to_op()
    out["sizes"] = [s.slave.output_size, s.slave.input_size]
    out.update(run_cycles(s, n, cycles, 5))                                        # phase F
    out["bad_wkc"], out["lost"] = s.bad_wkc, s.lost
    out["last_pdo_error"] = _u(s.read(0x8011, 14))
    out["pdo_errors"] = _u(s.read(0x8011, 15))
    s.bus.request_state(kickcat.State.INIT)
    return out


if __name__ == "__main__":
    iface, n_cycles = sys.argv[1], int(sys.argv[2])
    # a second create_mapping on one KickCAT Bus keeps the first mapping's block I/O entries (its
    # expected working counter doubles): the N = 3 bring-up scans again on a new Bus, as SOEM's does
    result = {"default": default_profile(Session(iface), n_cycles), "n3": configured(Session(iface), 3, n_cycles),
              "retries": Session.retries}
    print(json.dumps(result))
