"""Clients that get killed mid-transfer (tests/rig/test_rig_client_kill.py); run in forked processes.

Each sets ``ready`` once it is inside its transfer loop (or, for the record writer, once half a record
is on the wire) and then works until it is killed with SIGKILL.
"""

import socket
import threading
from typing import Any

VICTIM_NODE = 3  # drive axis3 of the default rig; the surviving SDO loop talks to node 2


def segmented_sdo(endpoint: str, ready: Any) -> None:
    """canopen segmented uploads (0x1008, the device name) from node 3, forever."""
    import canopen

    network = canopen.Network()
    network.connect(interface="gatewaylab", channel=endpoint, name="victim-sdo")
    node = network.add_node(VICTIM_NODE, canopen.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = 2.0
    ready.set()
    while True:
        try:
            node.sdo.upload(0x1008, 0)
        except Exception:  # another victim's stale transfer may be answered; keep going until killed
            pass


def idx_request(tcp_url: str, ready: Any) -> None:
    """IDX requests over TCP: segmented gateway reads of node 3's 0x1008, forever."""
    from gatewaylab.hosts.maxon_idx.client import IdxClient

    client = IdxClient(tcp_url, timeout=2.0)
    ready.set()
    while True:
        try:
            client.read_segmented(VICTIM_NODE, 0x1008, 0)
        except Exception:
            pass


def half_record(endpoint: str, ready: Any) -> None:
    """Bus wire protocol: HELLO, then the first half of a FRAME record; then silence until killed."""
    from gatewaylab.bus.frame import CanFrame
    from gatewaylab.bus.wire import encode_frame, encode_hello

    path = endpoint[5:] if endpoint.startswith("unix:") else endpoint
    if endpoint.startswith("tcp:"):
        host, _, port = endpoint[4:].rpartition(":")
        sock = socket.create_connection((host, int(port)))
    else:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.connect(path)
    sock.sendall(encode_hello("victim-record", False, True))
    record = encode_frame(CanFrame(0x123, bytes(range(8))))
    sock.sendall(record[:len(record) // 2])
    ready.set()
    threading.Event().wait()  # hold the half record until SIGKILL
