"""python-can in process: canopen, notifiers and loggers work unchanged on python_can_bus (issue 2, section 3)."""

import threading
from pathlib import Path

import can
import canopen
import pytest

from gatewaylab.bus import VirtualBus, python_can_bus
from gatewaylab.common.clock import SimulatedClock


def _od() -> canopen.ObjectDictionary:
    od = canopen.ObjectDictionary()
    name = canopen.objectdictionary.ODVariable("Manufacturer device name", 0x1008)
    name.data_type = canopen.objectdictionary.VISIBLE_STRING
    name.access_type = "ro"
    name.default = "gatewaylab LocalNode, a long name that needs a segmented transfer"
    od.add_object(name)
    value = canopen.objectdictionary.ODVariable("Test value", 0x2000)
    value.data_type = canopen.objectdictionary.UNSIGNED32
    value.access_type = "rw"
    value.default = 0xCAFEBABE
    od.add_object(value)
    return od


@pytest.fixture
def networks():
    clock = SimulatedClock()
    vbus = VirtualBus(clock, "can0", 1_000_000)
    server = canopen.Network(python_can_bus(vbus, name="local-node"))
    client = canopen.Network(python_can_bus(vbus, name="master"))
    for network in (server, client):
        network.NOTIFIER_CYCLE = 0.05  # its notifier thread notices a stop within 50 ms
        network.connect()
    yield clock, vbus, server, client
    client.disconnect()
    server.disconnect()


def test_canopen_reads_sdo_from_a_canopen_local_node(networks) -> None:
    """CiA 301 SDO expedited and segmented uploads, and a download, between two canopen stacks."""
    clock, vbus, server, client = networks
    server.create_node(5, _od())
    remote = client.add_node(5, _od())
    assert remote.sdo[0x2000].raw == 0xCAFEBABE
    remote.sdo[0x2000].raw = 0x12345678
    assert remote.sdo[0x2000].raw == 0x12345678
    assert remote.sdo[0x1008].raw.startswith("gatewaylab LocalNode")
    # Every SDO request and answer took real bus time on the simulated clock.
    assert vbus.stats.frames >= 6
    assert clock.now() == pytest.approx(vbus.stats.busy_time)


def test_notifier_and_logger_record_the_traffic(networks, tmp_path: Path) -> None:
    """python-can notifiers and loggers work unchanged on python_can_bus (issue 2 §3), recording CiA 301 SDO frames
    0x605/0x585."""
    _, vbus, server, client = networks
    server.create_node(5, _od())
    remote = client.add_node(5, _od())
    logfile = tmp_path / "trace.log"
    spy_bus = python_can_bus(vbus, name="spy", listen_only=True)
    logger = can.Logger(str(logfile))
    seen = threading.Semaphore(0)

    class Counter(can.Listener):
        def on_message_received(self, msg: can.Message) -> None:
            seen.release()

    notifier = can.Notifier(spy_bus, [logger, Counter()], timeout=0.05)
    assert remote.sdo[0x2000].raw == 0xCAFEBABE
    # The notifier thread logs asynchronously: wait until it has handled request and answer.
    assert seen.acquire(timeout=5) and seen.acquire(timeout=5)
    notifier.stop(timeout=1.0)
    logger.stop()
    spy_bus.shutdown()
    frames = list(can.LogReader(str(logfile)))
    assert [m.arbitration_id for m in frames] == [0x605, 0x585]
    assert frames[1].data[:1] == b"\x43"  # expedited upload response, 4 bytes
