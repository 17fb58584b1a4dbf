"""Devices as plugins (issue 9 'Pluggable devices'; docs/devices/writing-a-device.md).

The example device package under examples/ is installed into the test environment and used in
a rig exactly as a device package from outside this repository would be.
"""

from __future__ import annotations

import importlib
import importlib.util
import subprocess
import sys
from pathlib import Path

import can
import pytest

from gatewaylab.bus import CanFrame
from gatewaylab.common.errors import ConfigError
from gatewaylab.plugin import DeviceKind
from gatewaylab.rig import kinds
from gatewaylab.rig.config import load_rig, parse_rig
from gatewaylab.rig.runtime import Rig

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "gatewaylab-example-device"


def _installed_matches_source() -> bool:
    spec = importlib.util.find_spec("gatewaylab_example_device")
    if spec is None or spec.origin is None or "example_echo" not in kinds.registered():
        return False
    source = EXAMPLE / "gatewaylab_example_device" / "__init__.py"
    return Path(spec.origin).read_bytes() == source.read_bytes()


@pytest.fixture(scope="module")
def example_device() -> None:
    """Install the example device package (as a user would: pip) unless this exact version is."""
    if not _installed_matches_source():
        subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--force-reinstall",
                        str(EXAMPLE)], check=True, timeout=300)
        importlib.invalidate_caches()
    assert _installed_matches_source()


def test_builtin_devices_are_registered_through_the_entry_point_group() -> None:
    """Issue 9: 'a gatewaylab.devices entry-point group (built-in devices registered through it too)'."""
    found = kinds.registered()
    for name, module in [("drive", "gatewaylab.devices.canopen_drive.rig"),
                         ("maxon_idx", "gatewaylab.devices.maxon_idx.rig"),
                         ("ethercat_io", "gatewaylab.devices.ethercat_io.rig"), ("ethercat", "gatewaylab.rig.segment")]:
        assert found[name].group == kinds.GROUP and found[name].module == module
        kind = kinds.load(name)
        assert isinstance(kind, DeviceKind) and kind.kind == name and kind.keys
    assert not hasattr(kinds, "DEVICE_FACTORIES")  # no second, hand-written table


def test_example_package_adds_a_kind_without_touching_gatewaylab(example_device: None) -> None:
    """Issue 9: 'a device package outside this repository adds a rig-file kind without touching
    gatewaylab': the example echo box answers on its own CAN-ID in a simulated rig."""
    rig = Rig(parse_rig({"clock": "simulated", "bus": [{"name": "can0", "endpoint": "none"}],
                         "device": [{"kind": "example_echo", "name": "echo1", "bus": "can0",
                                     "request_id": 0x123, "reply_id": 0x124, "delay_ms": 2}]}))
    with rig:
        rig.start()
        got: list[tuple[CanFrame, float]] = []
        tester = rig.buses["can0"].attach("tester", on_frame=lambda f, t: got.append((f, t)))
        tester.send(CanFrame(0x123, b"\x01\x02\x03"))
        tester.send(CanFrame(0x200, b"\x09"))  # not its id: no answer
        rig.clock.advance(0.01)  # type: ignore[attr-defined]
        assert [f for f, _ in got] == [CanFrame(0x124, b"\x03\x02\x01")]
        echo = rig.participants[0]
        assert type(echo).__module__ == "gatewaylab_example_device" and echo.echoed == 1  # type: ignore[attr-defined]
        assert rig.ready_info()["example_echo"] == {"echo1": {"request_id": 0x123, "reply_id": 0x124}}


def test_example_package_in_a_gatewaylab_run_process(example_device: None, start_rig) -> None:
    """The plugin kind in a real `gatewaylab run`: a python-can client in this process talks to it
    through the `gatewaylab` interface (docs/devices/writing-a-device.md, last step)."""
    rig = start_rig('[[bus]]\nname = "can0"\n[[device]]\nkind = "example_echo"\nname = "echo1"\n')
    assert rig.info["example_echo"] == {"echo1": {"request_id": 0x321, "reply_id": 0x322}}
    with can.Bus(interface="gatewaylab", channel=rig.endpoint("can0")) as bus:
        bus.send(can.Message(arbitration_id=0x321, data=b"abc", is_extended_id=False))
        for _ in range(10):
            msg = bus.recv(timeout=10)
            assert msg is not None
            if msg.arbitration_id == 0x322:
                break
        assert msg.arbitration_id == 0x322 and bytes(msg.data) == b"cba"


@pytest.mark.parametrize("section, message", [
    ('[[drive]]\nbus = "can0"\nnode_id = 0\nserial = 1\nname = "a"',
     "[[drive]] #1 (a): node_id must be 1..127 (omit it for an unconfigured drive), got 0"),
    ('[[drive]]\nbus = "can0"\nnode_id = 5', "[[drive]] #1: serial is required"),
    ('[[drive]]\nbus = "can0"\nserial = "x"', "[[drive]] #1: serial must be 0..0xFFFFFFFF"),
    ('[[device]]\nkind = "maxon_idx"\nname = "idx1"\nspeed = 3', "[[device]] #1 (idx1): unknown keys ['speed']"),
    ('[[device]]\nkind = "maxon_idx"\nusb = { latency_ms = "slow" }',
     "[[device]] #1: usb.latency_ms must be a number >= 0, got 'slow'"),
    ('[[device]]\nkind = "maxon_idx"\nsdo_timeout = true', "[[device]] #1: sdo_timeout must be a number"),
    ('[[device]]\nkind = "ethercat_io"\nserial = -1', "[[device]] #1: serial must be 0..0xFFFFFFFF"),
    ('[[device]]\nkind = "ethercat_io"\n[ethercat]\ncpu = 1', "[ethercat]: interface is required"),
    ('[[device]]\nkind = "example_echo"\nname = "e"\nrequest_id = 0x800',
     "[[device]] #1 (e): request_id must be 0..0x7FF (an 11-bit CAN-ID), got 0x800"),
    ('[[device]]\nkind = "example_echo"', "[[device]] #1: name is required"),
    ('[[device]]\nkind = "example_echo"\nname = "e"\nbus = "can7"', "bus = 'can7' names an unknown bus"),
    ('[[device]]\nkind = "sundial"',
     "[[device]] #1: kind = 'sundial' is not installed (known kinds: bridge, canopen_node, drive, "),
    ('[[bus]]\nname = "can1"\ntcp_port = "x"', "[[bus]] #2 (can1): tcp_port must be 0..65535"),
    ('[[bus]]\nname = "can1"\ntiming = "no"', "[[bus]] #2 (can1): timing must be true or false, got 'no'"),
])
def test_one_validator_one_line_naming_file_section_and_key(example_device: None, tmp_path: Path,
                                                            section: str, message: str) -> None:
    """Issue 9: 'one shared rig-section validator (unknown keys, types, ranges -> one-line
    ConfigError)'; issue 15: the error names the file, the section and the key."""
    path = tmp_path / "bad.toml"
    path.write_text(f'[[bus]]\nname = "can0"\n{section}\n')
    with pytest.raises(ConfigError) as err:
        load_rig(path)
    text = str(err.value)
    assert text.startswith(f"{path} ") and "\n" not in text
    assert message in text


def test_section_keys_are_filled_with_their_defaults(example_device: None) -> None:
    """A factory gets every key of its table, defaults filled in (writing-a-device.md 'keys')."""
    (section,) = kinds.plan(parse_rig({"bus": [{"name": "can0"}],
                                       "device": [{"kind": "example_echo", "name": "e"}]}))
    assert section.cfg == {"name": "e", "bus": "can0", "request_id": 0x321, "reply_id": 0x322, "delay_ms": 0.0}
    assert section.where == "<memory> [[device]] #1 (e)"


def test_a_kind_can_also_be_written_as_device_section() -> None:
    """`[[device]] kind = "drive"` is the same as `[[drive]]` (one registry for every kind)."""
    config = parse_rig({"clock": "simulated", "bus": [{"name": "can0", "endpoint": "none"}],
                        "device": [{"kind": "drive", "bus": "can0", "node_id": 4, "serial": 4}]})
    with Rig(config) as rig:
        assert [p.name for p in rig.participants] == ["drive4"]
