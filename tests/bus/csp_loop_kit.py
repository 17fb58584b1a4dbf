"""A canopen master's CiA 402 cyclic synchronous position loop, as the interop tests of the socketcand
server, the cannelloni tunnel and the bridges run it against a drive of a rig."""

from __future__ import annotations

import canopen


def csp_loop(network: canopen.Network, node: canopen.RemoteNode, cycles: int, step: int = 40) -> tuple[int, int, int]:
    """PDO 1 both ways synchronous (type 1), mode 8 (CSP), operation enabled, NMT operational; then
    ``cycles`` times RPDO1 (controlword 0x0F + target position) and SYNC, waiting up to 2 s for TPDO1.
    Returns (TPDOs received, start position, last target); leaves the node pre-operational."""
    for maps in (node.tpdo, node.rpdo):
        maps.read()
        maps[1].trans_type = 1
        maps[1].save()
    node.sdo[0x6060].raw = 8
    for cw in (0x06, 0x07, 0x0F):
        node.sdo[0x6040].raw = cw
    node.nmt.state = "OPERATIONAL"
    start = int(node.sdo[0x6064].raw)
    target, received = start, 0
    for _ in range(cycles):
        target += step
        node.rpdo[1]["Controlword"].raw = 0x0F
        node.rpdo[1]["Target position"].raw = target
        node.rpdo[1].transmit()
        network.send_message(0x80, b"")
        if node.tpdo[1].wait_for_reception(2.0) is not None:
            received += 1
    node.nmt.state = "PRE-OPERATIONAL"
    return received, start, target
