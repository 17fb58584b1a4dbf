"""A CANopen application with python ``canopen``: SDO reads and writes of a drive, PDO configuration,
SYNC, reading TPDOs. The worked example of ``gatewaylab migrate compare``
(docs/migration-esd-to-ecanlite.md, "Timing differences"):

    gatewaylab migrate compare --rig examples/migrate_rig.toml --bus can0 \\
        --app examples/migrate_sdo_pdo_app.py --report docs/migration/sdo_pdo

``run(bus)`` takes any ``can.BusABC``: the same function runs behind an esd CAN-EtherCAT, an
ECAN-Lite or on a plain CAN interface. Nothing here knows which gateway carries the frames.
"""

from __future__ import annotations

import struct

import can
import canopen

NODE = 2
#: SYNC cycles with TPDOs read back (about 10 ms of CAN traffic each)
CYCLES_PER_SECOND = 100


def run(bus: can.BusABC, seconds: float = 0.2) -> None:
    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = 0.05
    network.connect()
    try:
        node = network.add_node(NODE, canopen.ObjectDictionary())
        sdo = node.sdo
        # SDO reads: identity, name (segmented), device type
        device_type = struct.unpack("<I", sdo.upload(0x1000, 0))[0]
        name = sdo.upload(0x1008, 0).decode(errors="replace")
        serial = struct.unpack("<I", sdo.upload(0x1018, 4))[0]
        print(f"node {NODE}: {name}, device type 0x{device_type:08X}, serial 0x{serial:X}")
        # SDO writes: heartbeat off, profile velocity, read back
        sdo.download(0x1017, 0, struct.pack("<H", 0))
        sdo.download(0x6081, 0, struct.pack("<I", 5000))
        assert struct.unpack("<I", sdo.upload(0x6081, 0))[0] == 5000
        # PDO configuration by SDO (CiA 301 7.2.8): TPDO1 = statusword + position actual value,
        # TPDO2 = velocity actual value, both sent on every SYNC (transmission type 1)
        for cob, mapping, tx in ((0x1800, 0x1A00, (0x60410010, 0x60640020)), (0x1801, 0x1A01, (0x606C0020,))):
            cob_id = 0x180 + NODE if cob == 0x1800 else 0x280 + NODE
            sdo.download(cob, 1, struct.pack("<I", 0x80000000 | cob_id))    # invalid while mapping
            sdo.download(mapping, 0, b"\x00")
            for k, entry in enumerate(tx, 1):
                sdo.download(mapping, k, struct.pack("<I", entry))
            sdo.download(mapping, 0, bytes([len(tx)]))
            sdo.download(cob, 2, b"\x01")
            sdo.download(cob, 1, struct.pack("<I", cob_id))
        # NMT operational, then SYNC cycles; the TPDOs answer each SYNC
        node.nmt.state = "OPERATIONAL"
        received: list[can.Message] = []
        network.subscribe(0x180 + NODE, lambda can_id, data, ts: received.append(
            can.Message(arbitration_id=can_id, data=data, timestamp=ts)))
        for _ in range(max(1, round(seconds * CYCLES_PER_SECOND))):
            network.sync.transmit()
        node.nmt.state = "PRE-OPERATIONAL"
        status = struct.unpack("<H", sdo.upload(0x6041, 0))[0]
        print(f"{len(received)} TPDO1 frames seen, statusword 0x{status:04X}")
    finally:
        network.disconnect()
