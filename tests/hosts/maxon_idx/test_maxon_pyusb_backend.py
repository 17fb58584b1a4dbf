"""pyusb against the emulated IDX: `IdxUsbBackend` presents it as a USB device (IDX guide 2.3.1:
USB 2.0; 2.2 frames on the bulk endpoints), so `usb.core.find(..., backend=...)`, a plain pyusb
program and `IdxClient`'s USB path (`UsbLink`) work unchanged.

The IdxClient tests of test_maxon_e2e.py run here again over pyusb, through both ways the backend
reaches an IDX: the rig's TCP port (what the ready file lists) and an in-process IdxDevice."""

from __future__ import annotations

import array
from collections.abc import Iterator
from pathlib import Path

import pytest
import usb.core
import usb.util
from maxon_helpers import IdxRig

from gatewaylab.bus import CanFrame, VirtualBus
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.devices.maxon_idx.commands import NmtCommand
from gatewaylab.devices.maxon_idx.device import IdxDevice
from gatewaylab.hosts.maxon_idx.client import IdxClient, IdxError
from gatewaylab.hosts.maxon_idx.link import UsbLink
from gatewaylab.hosts.maxon_idx.usb_backend import IdxUsbBackend
from gatewaylab.rig.process import RigProcess

MAXON_VENDOR_ID = 0x000000FB
#: IDX guide 2.2.8: ReadObject 0x30B0:00 of node 1, and the answer with Home Position 36865.
REQUEST = bytes([0x90, 0x02, 0x60, 0x02, 0x01, 0xB0, 0x30, 0x00, 0x2E, 0x62])
RESPONSE = bytes([0x90, 0x02, 0x00, 0x04, 0x00, 0x00, 0x00, 0x00, 0x01, 0x90, 0x90, 0x00, 0x00, 0x9A, 0x5C])


@pytest.fixture(scope="module")
def rig() -> Iterator[IdxRig]:
    r = IdxRig([(2, 0x1002), (3, 0x1003), (None, 0x3003)])
    yield r
    r.close()


@pytest.fixture(params=["tcp", "in-process"])
def backend(request: pytest.FixtureRequest, rig: IdxRig) -> IdxUsbBackend:
    if request.param == "tcp":
        return IdxUsbBackend(rig.info["usb"]["idx1"]["tcp"])
    return IdxUsbBackend(rig.idx.device)  # type: ignore[attr-defined]


@pytest.fixture
def client(backend: IdxUsbBackend) -> Iterator[IdxClient]:
    with IdxClient(UsbLink(backend=backend), timeout=2.0) as c:
        yield c


def _error(call: object, *args: object) -> int:
    try:
        call(*args)  # type: ignore[operator]
    except IdxError as exc:
        return exc.code
    raise AssertionError("no error")


def test_descriptors_of_a_real_idx(backend: IdxUsbBackend) -> None:
    """USB 2.0 9.6: the device enumerates as 24E7:3B01 (the EPOS4/IDX identity of the udev rules,
    docs/devices/maxon_idx.md) with one vendor-specific interface and bulk endpoints 0x01 OUT / 0x81 IN;
    the descriptors pyusb reads by GET_DESCRIPTOR on endpoint 0 say the same."""
    dev = usb.core.find(idVendor=0x24E7, idProduct=0x3B01, backend=backend)
    assert dev is not None
    assert (dev.bcdUSB, dev.bNumConfigurations, dev.speed) == (0x0200, 1, usb.util.SPEED_FULL)
    assert dev.manufacturer == "maxon" and "IDX" in dev.product
    intf = dev.get_active_configuration()[(0, 0)]
    assert intf.bInterfaceClass == 0xFF
    eps = [(e.bEndpointAddress, usb.util.endpoint_type(e.bmAttributes), e.wMaxPacketSize) for e in intf]
    assert eps == [(0x01, usb.util.ENDPOINT_TYPE_BULK, 64), (0x81, usb.util.ENDPOINT_TYPE_BULK, 64)]
    raw = dev.ctrl_transfer(0x80, 0x06, 0x0100, 0, 18)           # GET_DESCRIPTOR(DEVICE)
    assert bytes(raw[:2]) == b"\x12\x01" and int.from_bytes(bytes(raw[8:12]), "little") == 0x3B0124E7
    config = bytes(dev.ctrl_transfer(0x80, 0x06, 0x0200, 0, 255))
    assert len(config) == 32 and config[:2] == b"\x09\x02" and config[18:20] == b"\x07\x05"
    with pytest.raises(usb.core.USBError):
        dev.ctrl_transfer(0xC0, 0x01, 0, 0, 1)                    # vendor request: stall
    assert usb.core.find(idVendor=0x0403, idProduct=0xA8B0, backend=backend) is None
    usb.util.dispose_resources(dev)


def test_plain_pyusb_program_gets_the_guide_example(rig: IdxRig, backend: IdxUsbBackend) -> None:
    """IDX guide 2.2.8 through bulk endpoints: set Home Position 36865, then the guide's request bytes
    written to 0x01 get exactly the guide's reception bytes from 0x81; a read with nothing to answer
    raises USBTimeoutError as libusb's backend does (LIBUSB_ERROR_TIMEOUT)."""
    with IdxClient(UsbLink(backend=backend)) as c:
        c.write(1, 0x30B0, 0, 36865, "i32")
    dev = usb.core.find(idVendor=0x24E7, idProduct=0x3B01, backend=backend)
    dev.set_configuration()
    assert dev.write(0x01, REQUEST) == len(REQUEST)
    got = b""
    while len(got) < len(RESPONSE):
        got += bytes(dev.read(0x81, 64, timeout=2000))
    assert got == RESPONSE
    with pytest.raises(usb.core.USBTimeoutError) as exc:
        dev.read(0x81, 64, timeout=50)
    assert exc.value.backend_error_code == -7
    dev.write(0x01, REQUEST)                      # pyusb's other form: read into the caller's array
    got = b""
    while len(got) < len(RESPONSE):
        buf = array.array("B", bytes(64))
        n = dev.read(0x81, buf, 2000)
        got += buf[:n].tobytes()
    assert got == RESPONSE
    usb.util.dispose_resources(dev)


def test_local_objects(client: IdxClient) -> None:
    """Chapter 5 over USB: node 0 and the IDX's own id are its own dictionary; aborts pass through."""
    assert client.read(1, 0x1018, 4) == 0x2001
    assert client.read(0, 0x1018, 1) == MAXON_VENDOR_ID
    assert "IDX" in client.read_string(0, 0x1008, 0)
    client.write_segmented(1, 0x30B0, 0, (36865).to_bytes(4, "little"))
    assert client.read(0, 0x30B0, 0, "i32") == 36865
    assert _error(client.read, 0, 0x5FFF, 0) == 0x06020000


def test_gateway_sdo_to_drives(rig: IdxRig, client: IdxClient) -> None:
    """Chapter 5 over USB: other node ids are SDO transfers on the bus, expedited and segmented
    (2.1.1.2); a silent node is 0x05040000."""
    assert client.read(2, 0x1018, 4) == 0x1002
    client.write(3, 0x30B0, 0, -77, "i32")
    assert client.read(3, 0x30B0, 0, "i32") == -77
    with rig.rig.clock.lock:
        expected = rig.drives[0].node.read(0x1008, 0)
    assert client.read_segmented(2, 0x1008, 0) == expected
    assert _error(client.read, 2, 0x5FFF, 0) == 0x06020000
    assert _error(client.read, 9, 0x1000, 0) == 0x05040000


def test_nmt(rig: IdxRig, client: IdxClient) -> None:
    """2.1.2.4 over USB: SendNMTService puts CS + node id on COB-ID 0 and the drive changes state."""
    client.nmt(3, NmtCommand.START_REMOTE_NODE)
    client.read(2, 0x1018, 4)                      # barrier: the NMT frame has left the IDX
    assert CanFrame(0, bytes([0x01, 3])) in rig.frames
    with rig.rig.clock.lock:
        assert rig.drives[1].node.nmt_state is NmtState.OPERATIONAL
    client.nmt(3, NmtCommand.ENTER_PRE_OPERATIONAL)
    client.read(2, 0x1018, 4)
    with rig.rig.clock.lock:
        assert rig.drives[1].node.nmt_state is NmtState.PRE_OPERATIONAL


def test_lss_fastscan_over_usb(client: IdxClient) -> None:
    """3.5 + CiA 305 over USB (SendLSS/ReadLSS): the unconfigured drive is found by fastscan and
    its serial inquired; it is sent back to waiting state unconfigured, for the other transport."""
    assert client.identify_non_configured()
    address = client.fastscan(timeout_ms=20)
    assert address is not None and address.serial == 0x3003 and address.vendor_id == MAXON_VENDOR_ID
    assert client.inquire("serial") == 0x3003
    client.switch_state_global(False)


def test_simulated_clock_in_process() -> None:
    """Deterministic: an IdxDevice on a simulated clock; a bulk read runs the clock's events until
    the answer is there (no thread, nobody advances the clock), and its timeout is simulated time."""
    clock = SimulatedClock()
    bus = VirtualBus(clock, "can0")
    idx = IdxDevice(clock, bus, 1, 0x2001, "idx1")
    drive = Drive(clock, bus, 2, 0x1002, "drive2")
    idx.start()
    drive.start()
    backend = IdxUsbBackend(idx)
    with IdxClient(UsbLink(backend=backend)) as c:
        assert c.read(2, 0x1018, 4) == 0x1002
        t0 = clock.now()
        assert _error(c.read, 9, 0x1000, 0) == 0x05040000
        assert 0.49 < clock.now() - t0 < 0.6                    # the gateway's SDO timeout, simulated
    dev = usb.core.find(idVendor=0x24E7, idProduct=0x3B01, backend=backend)
    assert dev.serial_number == "00002001"
    t0 = clock.now()
    with pytest.raises(usb.core.USBTimeoutError):
        dev.read(0x81, 64, timeout=250)
    assert clock.now() - t0 == pytest.approx(0.25)
    usb.util.dispose_resources(dev)
    idx.stop()
    drive.stop()


def test_ready_file_of_a_running_rig(tmp_path: Path) -> None:
    """The default rig under `gatewaylab run` (a child process): the backend built from its ready file
    (the IDX's "usb" entry, its TCP port) is found by pyusb and serves IdxClient and the gateway."""
    with RigProcess(None, workdir=tmp_path, timeout=60) as rig:
        backend = IdxUsbBackend.from_ready_file(rig.ready_file)
        dev = usb.core.find(idVendor=0x24E7, idProduct=0x3B01, backend=backend)
        assert dev is not None
        usb.util.dispose_resources(dev)
        with IdxClient(UsbLink(backend=backend), timeout=2.0) as c:
            assert c.read(2, 0x1018, 1) == MAXON_VENDOR_ID
        with pytest.raises(ConfigError, match="no IDX"):
            IdxUsbBackend.from_ready_file(rig.ready_file, "nope")
    dev = usb.core.find(idVendor=0x24E7, idProduct=0x3B01, backend=backend)    # still enumerated...
    with pytest.raises(usb.core.USBError) as exc:                               # ...but gone: no device
        dev.write(0x01, REQUEST)
    assert exc.value.backend_error_code == -4
    usb.util.dispose_resources(dev)


def test_endpoint_halt_and_bad_endpoints(backend: IdxUsbBackend) -> None:
    """USB 2.0 9.4.5/9.4.9: SET_FEATURE(ENDPOINT_HALT) stalls the bulk IN endpoint and GET_STATUS
    reports it until CLEAR_FEATURE (pyusb's clear_halt); an endpoint the descriptors do not list is
    refused by pyusb before the backend sees it."""
    dev = usb.core.find(idVendor=0x24E7, idProduct=0x3B01, backend=backend)
    dev.ctrl_transfer(0x02, 0x03, 0, 0x81)                       # SET_FEATURE(ENDPOINT_HALT) on 0x81
    assert bytes(dev.ctrl_transfer(0x82, 0x00, 0, 0x81, 2)) == b"\x01\x00"
    with pytest.raises(usb.core.USBError) as exc:
        dev.read(0x81, 64, timeout=50)
    assert exc.value.backend_error_code == -9
    dev.clear_halt(0x81)
    assert bytes(dev.ctrl_transfer(0x82, 0x00, 0, 0x81, 2)) == b"\x00\x00"
    dev.write(0x01, REQUEST)
    got = b""
    while len(got) < 10:
        got += bytes(dev.read(0x81, 64, timeout=2000))
    assert got[:3] == b"\x90\x02\x00"                           # a ReadObject answer (2.2.2)
    with pytest.raises(ValueError, match="Invalid endpoint address 0x2"):
        dev.write(0x02, REQUEST)                                 # pyusb checks the descriptors itself
    usb.util.dispose_resources(dev)
