"""What a python-can client and a canopen client see while faults hit the default rig (docs/faults.md).

    gatewaylab run --ready-file ready.json &
    python examples/fault_watch.py ready.json

python-can lines are printed as the script reads them (after each fault request returns), so
compare their timestamps, not their order with the other lines.
"""
import json
import struct
import sys
import time

import can
import canopen

from gatewaylab.cli.fault import send_request

ready = sys.argv[1]
with open(ready) as f:
    ep = json.load(f)["buses"]["can0"]["endpoint"]
net = canopen.Network()
net.connect(interface="gatewaylab", channel=ep)
axis2 = net.add_node(2, canopen.ObjectDictionary())
axis2.sdo.download(0x1017, 0, struct.pack("<H", 100))     # heartbeat every 100 ms
axis2.nmt.wait_for_heartbeat(5)
print("canopen: heartbeat of node 2 every 100 ms")
watcher = can.Bus(interface="gatewaylab", channel=ep, can_filters=[{"can_id": 0x702, "can_mask": 0x7FF}])
t0 = None


def fault(*args: str, **req: object) -> None:
    """What `gatewaylab fault ready.json ARGS...` does, without starting a second interpreter."""
    answer = send_request(ready, req)
    print(f"$ gatewaylab fault ready.json {' '.join(args)}   -> {json.dumps(answer)}")


def show(seconds: float) -> None:
    global t0
    errors = 0
    state = watcher.controller_state
    worst = "nowhere"
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        msg = watcher.recv(0.1)
        if msg is None:
            continue
        t0 = t0 or msg.timestamp
        if msg.is_error_frame:
            errors += 1
            if errors == 1:
                print(f"  python-can  +{msg.timestamp - t0:9.6f}  error frame")
        else:
            if errors > 1:
                print(f"  python-can  ... {errors} error frames in all; own controller went {worst}")
            errors = 0
            print(f"  python-can  +{msg.timestamp - t0:9.6f}  0x{msg.arbitration_id:03X} {msg.data.hex(' ')}")
        if watcher.controller_state is not state:
            state = watcher.controller_state
            if state.name != "ERROR_ACTIVE":
                worst = state.name.lower().replace("_", "-")


show(0.35)
fault("stuck-dominant", "can0", "0.5", fault="stuck-dominant", bus="can0", duration=0.5)
try:
    axis2.nmt.wait_for_heartbeat(0.3)
    print("canopen: heartbeat")
except canopen.nmt.NmtError as exc:
    print(f"canopen: heartbeat consumer timeout: {exc}")
show(0.6)
fault("power-cycle", "axis2", "--off", "0.5", fault="power-cycle", device="axis2", off=0.5)
axis2.nmt.wait_for_bootup(5)
print("canopen: boot-up of node 2; 0x1017 heartbeat time is back at",
      struct.unpack("<H", axis2.sdo.upload(0x1017, 0))[0], "ms")
show(0.3)
net.disconnect()
watcher.shutdown()
