"""A bus without frame timing (`timing = false`) carrying a drive, used from another process (issue 15)."""

import signal

import can
import canopen
import pytest

from gatewaylab.devices.canopen_drive.objects import DEVICE_NAME

RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
{data_bitrate}
timing = false
[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
name = "axis2"
"""


@pytest.mark.parametrize("fd", [False, True], ids=["classic", "fd"])
def test_drive_on_a_bus_without_timing_serves_clients_of_another_process(start_rig, fd: bool) -> None:
    """docs/rig.md `timing = false`: "frames take no time (load tests only)"; issue 15 "`timing = false`
    hangs the rig": with a `[[drive]]` on such a bus (classic or FD) `gatewaylab run` must still welcome
    python-can clients, carry their frames, answer a canopen SDO upload of the drive's 0x1008 (CiA 301
    7.4.8.2, manufacturer device name) and stop on SIGTERM."""
    rig = start_rig(RIG.format(data_bitrate="data_bitrate = 5000000" if fd else ""))
    endpoint = rig.endpoint()
    with can.Bus(interface="gatewaylab", channel=endpoint, fd=fd, connect_timeout=20.0) as sender, \
            can.Bus(interface="gatewaylab", channel=endpoint, fd=fd, connect_timeout=20.0) as listener:
        listener.set_filters([{"can_id": 0x321, "can_mask": 0x7FF}])
        payload = bytes(range(12)) if fd else bytes(range(8))
        sender.send(can.Message(arbitration_id=0x321, data=payload, is_extended_id=False, is_fd=fd))
        got = listener.recv(20.0)
        while got is not None and got.arbitration_id != 0x321:
            got = listener.recv(20.0)
        assert got is not None and bytes(got.data) == payload and got.is_fd == fd

        network = canopen.Network()
        network.connect(interface="gatewaylab", channel=endpoint, connect_timeout=20.0)
        try:
            node = network.add_node(2, canopen.ObjectDictionary())
            node.sdo.RESPONSE_TIMEOUT = 20.0
            assert node.sdo.upload(0x1008, 0) == DEVICE_NAME.encode()
        finally:
            network.disconnect()
    rig.proc.send_signal(signal.SIGTERM)
    rig.proc.wait(timeout=20)
