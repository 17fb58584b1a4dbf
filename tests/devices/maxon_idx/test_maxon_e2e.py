"""End to end: pyserial host client -> pseudo-terminal -> emulated IDX -> virtual CAN bus -> drives.

IDX guide chapter 2 (USB commands), chapter 5 (gateway), 3.3.3.5 (NMT), 3.5 (LSS), chapter 6 (codes).
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from maxon_helpers import IdxRig

from gatewaylab.bus import CanFrame
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.devices.maxon_idx.commands import NmtCommand
from gatewaylab.hosts.maxon_idx.client import IdxClient, IdxError

MAXON_VENDOR_ID = 0x000000FB


@pytest.fixture(scope="module")
def rig() -> Iterator[IdxRig]:
    r = IdxRig([(2, 0x1002), (3, 0x1003)])
    yield r
    r.close()


@pytest.fixture
def client(rig: IdxRig) -> Iterator[IdxClient]:
    with IdxClient(rig.info["usb"]["idx1"]["pty"], timeout=2.0) as c:
        yield c


def _error(call: object, *args: object) -> int:
    try:
        call(*args)  # type: ignore[operator]
    except IdxError as exc:
        return exc.code
    raise AssertionError("no error")


def test_ready_info_names_pty_and_tcp(rig: IdxRig) -> None:
    """2.3.1 USB port, emulated: the rig ready info names it {"usb": {"idx1": {"pty": "/dev/pts/N",
    "tcp": "tcp:127.0.0.1:PORT"}}} (issue 4 rig file; the endpoint form of docs/endpoints.md)."""
    usb = rig.info["usb"]["idx1"]
    assert usb["pty"].startswith("/dev/pts/")
    assert usb["tcp"].startswith("tcp:127.0.0.1:") and int(usb["tcp"].rsplit(":", 1)[1]) > 0


def test_local_objects(rig: IdxRig, client: IdxClient) -> None:
    """Chapter 5: node 0 and the IDX's own node id 1 are executed on its own dictionary (2.2.8: 0x30B0)."""
    assert client.read(1, 0x1018, 4) == 0x2001
    assert client.read(0, 0x1018, 1) == MAXON_VENDOR_ID
    client.write(1, 0x30B0, 0, -36865, "i32")
    assert client.read(0, 0x30B0, 0, "i32") == -36865
    assert client.read(0, 0x2006, 0, "u16") == 500
    assert "IDX" in client.read_string(0, 0x1008, 0)
    assert _error(client.read, 0, 0x5FFF, 0) == 0x06020000
    assert _error(client.write, 0, 0x1018, 4, 1) == 0x06010002


def test_tcp_url_reaches_same_device(rig: IdxRig) -> None:
    """2.2 data link over the TCP transport (pyserial socket:// URL): the same device, its own 0x1018:04."""
    with IdxClient(rig.info["usb"]["idx1"]["tcp"].replace("tcp:", "socket://", 1)) as c:
        assert c.read(0, 0x1018, 4) == 0x2001


def test_gateway_read_write(rig: IdxRig, client: IdxClient) -> None:
    """Chapter 5: other node ids become SDO transfers on the bus (0x600+n / 0x580+n)."""
    assert client.read(2, 0x1018, 4) == 0x1002
    assert client.read(3, 0x1018, 4) == 0x1003
    client.write(2, 0x30B0, 0, 1234, "i32")
    with rig.rig.clock.lock:
        assert rig.drives[0].node.get(0x30B0, 0) == 1234
    client.write(3, 0x2006, 0, 250, "u16")          # a 2-byte object through a 4-byte WriteObject
    assert client.read(3, 0x2006, 0, "u16") == 250
    assert any(f.can_id == 0x602 for f in rig.frames) and any(f.can_id == 0x582 for f in rig.frames)


def test_gateway_segmented_string(rig: IdxRig, client: IdxClient) -> None:
    """2.1.1.2 through the gateway: a string longer than 4 bytes via segmented SDO upload."""
    with rig.rig.clock.lock:
        expected = rig.drives[0].node.read(0x1008, 0)
    assert len(expected) > 4
    assert client.read_segmented(2, 0x1008, 0) == expected


def test_gateway_abort_codes_pass_through(rig: IdxRig, client: IdxClient) -> None:
    """Chapter 5/6: the node's SDO abort code is the USB error code."""
    assert _error(client.read, 2, 0x5FFF, 0) == 0x06020000
    assert _error(client.write, 2, 0x1018, 1, 5) == 0x06010002


def test_gateway_missing_node_times_out(rig: IdxRig, client: IdxClient) -> None:
    """Chapter 6: no answer from node 9 -> 0x05040000 SDO timeout."""
    assert _error(client.read, 9, 0x1000, 0) == 0x05040000


def test_segmented_write_through_gateway_refused(rig: IdxRig, client: IdxClient) -> None:
    """2.1.2.2: gateway communication is not supported for segmented writes."""
    assert _error(client.write_segmented, 2, 0x1008, 0, b"name") == 0x06010000


def test_nmt_start_stop_seen_on_bus(rig: IdxRig, client: IdxClient) -> None:
    """2.1.2.4 / table 3-12: SendNMTService puts CS + node id on COB-ID 0; the drive changes state."""
    client.nmt(2, NmtCommand.START_REMOTE_NODE)
    # Barrier: an SDO round trip to node 3 leaves the IDX's transmit FIFO after the NMT frame.
    client.read(3, 0x1018, 4)
    assert CanFrame(0, bytes([0x01, 2])) in rig.frames
    with rig.rig.clock.lock:
        assert rig.drives[0].node.nmt_state is NmtState.OPERATIONAL
    client.nmt(2, NmtCommand.STOP_REMOTE_NODE)
    client.read(3, 0x1018, 4)
    assert CanFrame(0, bytes([0x02, 2])) in rig.frames
    with rig.rig.clock.lock:
        assert rig.drives[0].node.nmt_state is NmtState.STOPPED
    client.nmt(2, NmtCommand.ENTER_PRE_OPERATIONAL)


def test_read_lss_needs_send_lss() -> None:
    """2.1.3.2: "a LSS slave message can be read only if a SendLSS command has been executed before"."""
    r = IdxRig([])
    try:
        with IdxClient(r.info["usb"]["idx1"]["pty"]) as c:
            assert _error(c.read_lss, 10) == 0x08000022
            c.send_lss(bytes([0x4C]))
            assert c.read_lss(10) is None            # nobody unconfigured: timeout
    finally:
        r.close()


def test_lss_fastscan_finds_and_configures_unconfigured_drive() -> None:
    """3.5 + CiA 305 fastscan through SendLSS/ReadLSS: find the drive without node id, give it id 5."""
    r = IdxRig([(2, 0x1002), (None, 0x3003)])
    try:
        with IdxClient(r.info["usb"]["idx1"]["pty"], timeout=2.0) as c:
            assert c.identify_non_configured()
            address = c.fastscan(timeout_ms=20)
            assert address is not None
            assert address.serial == 0x3003 and address.vendor_id == MAXON_VENDOR_ID
            assert c.inquire("serial") == 0x3003
            c.configure_node_id(5)
            c.switch_state_global(False)
            assert c.read(5, 0x1018, 4) == 0x3003
            assert not c.identify_non_configured()
            assert c.fastscan(timeout_ms=10) is None
    finally:
        r.close()


def test_late_reply_after_client_timeout_is_not_taken_for_the_next_answer(rig: IdxRig) -> None:
    """2.2.8 D "Do not send any data before the receive frame or a timeout is present": after the
    client gave up on node 9 (0.2 s < the gateway's 0.5 s SDO timeout) the IDX still answers
    0x05040000 late; the client drops that reply, so the next read gets its own value."""
    with IdxClient(rig.info["usb"]["idx1"]["pty"], timeout=0.2) as c:
        assert _error(c.read, 9, 0x1000, 0) == 0x05040000          # the client's own timeout
        c.timeout = 2.0
        assert c.read(0, 0x1018, 4) == 0x2001
        assert c.read(2, 0x1018, 4) == 0x1002
        assert c.late_replies_dropped == 1


def test_guide_example_bytes_against_the_emulated_idx(rig: IdxRig) -> None:
    """2.2.8 end to end on the emulated IDX (not a fake dictionary): with Home Position 0x30B0 set to
    36865 inc, the guide's request bytes get exactly the guide's reception bytes over plain pyserial,
    on the pty and on the socket:// URL."""
    import serial

    request = bytes([0x90, 0x02, 0x60, 0x02, 0x01, 0xB0, 0x30, 0x00, 0x2E, 0x62])
    response = bytes([0x90, 0x02, 0x00, 0x04, 0x00, 0x00, 0x00, 0x00, 0x01, 0x90, 0x90, 0x00, 0x00, 0x9A, 0x5C])
    usb = rig.info["usb"]["idx1"]
    with IdxClient(usb["pty"]) as c:
        c.write(1, 0x30B0, 0, 36865, "i32")
    for url in (usb["pty"], usb["tcp"].replace("tcp:", "socket://", 1)):
        with serial.serial_for_url(url, timeout=2) as s:
            s.write(request)
            assert s.read(len(response)) == response, url
