"""One endpoint syntax (issue 15, docs/endpoints.md): ``unix:PATH`` and ``tcp:HOST:PORT`` canonical,
``socket://HOST:PORT``, ``HOST:PORT`` and bare paths accepted as aliases, by one parser."""

from __future__ import annotations

import pytest

from gatewaylab.common.endpoint import Endpoint, EndpointError, EndpointKind, format_tcp, parse_endpoint


@pytest.mark.parametrize("text, canonical", [
    ("unix:/tmp/gl/can0.sock", "unix:/tmp/gl/can0.sock"),
    ("unix:///tmp/gl/can0.sock", "unix:/tmp/gl/can0.sock"),
    ("tcp:127.0.0.1:4000", "tcp:127.0.0.1:4000"),
    ("socket://127.0.0.1:4000", "tcp:127.0.0.1:4000"),
    ("tcp://127.0.0.1:4000", "tcp:127.0.0.1:4000"),
    ("127.0.0.1:4000", "tcp:127.0.0.1:4000"),
    ("localhost:16", "tcp:localhost:16"),
    ("tcp:[::1]:4000", "tcp:[::1]:4000"),
    ("/dev/pts/3", "/dev/pts/3"),
    ("COM3", "COM3"),
    ("usb", "usb"),
    ("usb:24e7:3b01", "usb:24E7:3B01"),
    ("rfc2217://host:2217", "rfc2217://host:2217"),
])
def test_every_alias_parses_to_its_canonical_form(text: str, canonical: str) -> None:
    """The form the ready file prints is str(parse_endpoint(any accepted alias))."""
    ep = parse_endpoint(text)
    assert str(ep) == canonical
    assert str(parse_endpoint(str(ep))) == canonical          # canonical forms are fixed points


def test_a_bare_path_means_what_the_client_connects_to() -> None:
    """A bus client connects to a Unix socket by path, an IDX client to a serial device."""
    assert parse_endpoint("/tmp/x.sock", bare_path=EndpointKind.UNIX).kind is EndpointKind.UNIX
    assert parse_endpoint("/dev/ttyACM0").kind is EndpointKind.SERIAL


def test_pyserial_url_of_a_tcp_endpoint() -> None:
    """pyserial opens TCP endpoints as socket:// URLs (what the IDX's TCP port speaks)."""
    assert parse_endpoint("tcp:127.0.0.1:5000").pyserial_url() == "socket://127.0.0.1:5000"
    assert Endpoint(EndpointKind.TCP, host="::1", port=5).pyserial_url() == "socket://[::1]:5"
    assert format_tcp("::1", 5) == "tcp:[::1]:5"
    with pytest.raises(EndpointError):
        parse_endpoint("unix:/x").pyserial_url()


@pytest.mark.parametrize("text, message", [
    ("", "empty endpoint"),
    ("tcp:127.0.0.1", "expected HOST:PORT"),
    ("tcp:127.0.0.1:x", "is not a number"),
    ("tcp:127.0.0.1:0", "outside 1..65535"),
    ("usb:1", "usb:VID:PID"),
    ("unix:", "needs a path"),
])
def test_malformed_endpoints_are_one_clear_error(text: str, message: str) -> None:
    """EndpointError is a ConfigError and a ValueError: the CLI maps it to exit 2."""
    with pytest.raises(EndpointError, match=message):
        parse_endpoint(text)
    with pytest.raises(ValueError):
        parse_endpoint(text)


def test_python_can_interface_refuses_a_non_bus_endpoint() -> None:
    """can.Bus(interface="gatewaylab") parses its channel with the same parser."""
    import can

    with pytest.raises(can.CanInitializationError, match="not a bus endpoint"):
        can.Bus(interface="gatewaylab", channel="usb")
    with pytest.raises(can.CanInitializationError, match="port"):
        can.Bus(interface="gatewaylab", channel="tcp:127.0.0.1:x")


def test_a_rig_bus_accepts_every_alias_of_its_endpoint(start_rig) -> None:
    """What the ready file prints (tcp:127.0.0.1:PORT) and its aliases all reach the same bus."""
    import can

    rig = start_rig("[[bus]]\nname = 'can0'\nendpoint = 'tcp'\n")
    endpoint = rig.endpoint("can0")
    assert endpoint.startswith("tcp:127.0.0.1:")
    hostport = endpoint[len("tcp:"):]
    with can.Bus(interface="gatewaylab", channel=endpoint) as rx:
        for alias in (f"socket://{hostport}", hostport):
            with can.Bus(interface="gatewaylab", channel=alias) as tx:
                tx.send(can.Message(arbitration_id=0x42, data=b"\x01", is_extended_id=False))
                msg = rx.recv(5.0)
                assert msg is not None and msg.arbitration_id == 0x42
