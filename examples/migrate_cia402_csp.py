"""A CiA 402 cyclic synchronous position (CSP) loop on plain python-can: NMT, CSP configuration by
SDO, enable (controlword 6 -> 7 -> 15 by RPDO), then cyclic target positions by RPDO with SYNC and
the actual positions back by TPDO. The worked example of ``gatewaylab migrate compare``
(docs/migration-esd-to-ecanlite.md, "Timing differences"):

    gatewaylab migrate compare --rig examples/migrate_rig.toml --bus can0 \\
        --app examples/migrate_cia402_csp.py --report docs/migration/cia402_csp

``run(bus)`` takes any ``can.BusABC``. Each motion cycle sends both drives' RPDO1 (controlword +
target position) and one SYNC, takes the TPDO1s (statusword + position actual value) the SYNC
triggers, then lets the rest of the period pass with ``recv(timeout)``.
"""

from __future__ import annotations

import struct

import can

NODES = (2, 3)
#: the motion period (seconds) and the distance every axis travels (increments)
PERIOD = 0.005
DISTANCE = 4000
RESPONSE_TIMEOUT = 0.5


def _frame(can_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)


def _answer(bus: can.BusABC, can_id: int) -> can.Message:
    """The next frame with ``can_id``; others (TPDOs, boot-ups) pass by."""
    for _ in range(100):
        msg = bus.recv(RESPONSE_TIMEOUT)
        if msg is None:
            break
        if msg.arbitration_id == can_id and not msg.is_error_frame:
            return msg
    raise TimeoutError(f"no frame 0x{can_id:03X}")


def sdo_write(bus: can.BusABC, node: int, index: int, sub: int, value: int, size: int) -> None:
    """Expedited SDO download (CiA 301 7.2.4.3.3): ccs 1, e = s = 1, n = 4 - size."""
    cmd = 0x23 | ((4 - size) << 2)
    bus.send(_frame(0x600 + node, struct.pack("<BHBI", cmd, index, sub, value)))
    ans = _answer(bus, 0x580 + node)
    if ans.data[0] != 0x60:
        code = struct.unpack_from("<I", ans.data, 4)[0]
        raise RuntimeError(f"node {node} 0x{index:04X}:{sub}: SDO abort 0x{code:08X}")


def sdo_read(bus: can.BusABC, node: int, index: int, sub: int) -> int:
    """Expedited SDO upload (CiA 301 7.2.4.3.5)."""
    bus.send(_frame(0x600 + node, struct.pack("<BHBI", 0x40, index, sub, 0)))
    ans = _answer(bus, 0x580 + node)
    if ans.data[0] & 0xE0 != 0x40:
        raise RuntimeError(f"node {node} 0x{index:04X}:{sub}: answer {ans.data.hex()}")
    return int(struct.unpack_from("<i", ans.data, 4)[0])


def configure_csp(bus: can.BusABC, node: int) -> None:
    """RPDO1 = controlword + target position, TPDO1 = statusword + position actual value, both on
    SYNC (type 1); heartbeat off; mode of operation 8 (CSP)."""
    writes = [(0x1400, 1, 0x80000200 + node, 4), (0x1600, 0, 0, 1), (0x1600, 1, 0x60400010, 4),
              (0x1600, 2, 0x607A0020, 4), (0x1600, 0, 2, 1), (0x1400, 2, 1, 1), (0x1400, 1, 0x200 + node, 4),
              (0x1800, 1, 0x80000180 + node, 4), (0x1A00, 0, 0, 1), (0x1A00, 1, 0x60410010, 4),
              (0x1A00, 2, 0x60640020, 4), (0x1A00, 0, 2, 1), (0x1800, 2, 1, 1), (0x1800, 1, 0x180 + node, 4),
              (0x1017, 0, 0, 2), (0x6060, 0, 8, 1)]
    for index, sub, value, size in writes:
        sdo_write(bus, node, index, sub, value, size)
    mode = sdo_read(bus, node, 0x6061, 0) & 0xFF
    if mode != 8:
        raise RuntimeError(f"node {node}: mode display {mode} after writing CSP")


def cycle(bus: can.BusABC, controlword: int, targets: dict[int, int]) -> dict[int, tuple[int, int]]:
    """One motion cycle: RPDO1 of every drive, SYNC, the TPDO1s back as {node: (statusword, position)}."""
    for node, target in targets.items():
        bus.send(_frame(0x200 + node, struct.pack("<Hi", controlword, target)))
    bus.send(_frame(0x080, b""))
    actual: dict[int, tuple[int, int]] = {}
    while len(actual) < len(targets):
        msg = bus.recv(RESPONSE_TIMEOUT)
        if msg is None:
            raise TimeoutError(f"TPDO1 missing from nodes {sorted(set(targets) - set(actual))}")
        node = msg.arbitration_id - 0x180
        if node in targets and len(msg.data) == 6:
            actual[node] = struct.unpack("<Hi", msg.data)
    while bus.recv(PERIOD) is not None:     # the rest of the period (no other traffic expected)
        pass
    return actual


def run(bus: can.BusABC, seconds: float = 0.5) -> None:
    bus.send(_frame(0x000, bytes([0x80, 0])))          # NMT: everybody to pre-operational
    for node in NODES:
        configure_csp(bus, node)
    start = {node: sdo_read(bus, node, 0x6064, 0) for node in NODES}
    bus.send(_frame(0x000, bytes([0x01, 0])))          # NMT: start all
    for cw in (0x06, 0x07, 0x0F):                      # shutdown, switch on, enable operation
        actual = cycle(bus, cw, start)
    if not all(sw & 0x6F == 0x27 for sw, _ in actual.values()):
        raise RuntimeError(f"not operation enabled: {actual}")
    steps = max(1, round(seconds / PERIOD))
    for k in range(1, steps + 1):                      # a linear ramp of DISTANCE increments
        targets = {node: start[node] + DISTANCE * k // steps for node in NODES}
        actual = cycle(bus, 0x0F, targets)
    for _ in range(20):                                # hold the last target until the axes settle
        actual = cycle(bus, 0x0F, targets)
    cycle(bus, 0x06, targets)                          # shutdown: power off, axes stay where they are
    bus.send(_frame(0x000, bytes([0x80, 0])))          # NMT: back to pre-operational
    for node, (sw, pos) in sorted(actual.items()):
        print(f"node {node}: target {targets[node]}, actual {pos}, statusword 0x{sw:04X}")
