"""``canopen_node``: a CANopen device from its DCF alone, on the simulated clock (CiA 301 behaviour from
the dictionary: boot-up, heartbeat, PDOs by transmission type, access and ranges; behaviour rules; LSS),
and the one-line errors of files and rules that do not fit."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import canopen
import pytest

from gatewaylab.bus import CanFrame, python_can_bus
from gatewaylab.common.errors import ConfigError
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.runtime import Rig

DCF = Path(__file__).with_name("data") / "io-module.dcf"


def make_rig(tmp_path: Path, node: dict[str, Any] | None = None, text: str | None = None) -> Rig:
    eds = DCF
    if text is not None:
        eds = tmp_path / "device.dcf"
        eds.write_text(text)
    device = {"kind": "canopen_node", "eds": str(eds), "bus": "can0", **(node or {})}
    return Rig(parse_rig({"clock": "simulated", "bus": [{"name": "can0", "endpoint": "none"}], "device": [device]}))


@pytest.fixture
def frames(tmp_path: Path) -> Iterator[tuple[Rig, list[tuple[float, CanFrame]]]]:
    rig = make_rig(tmp_path, {"behaviour": {"0x6000:01": {"echo": "0x6200:01"},
                                            "0x6401:01": {"sine": {"amplitude": 1000, "period": 1.0}},
                                            "0x6401:02": {"counter": 3}}})
    seen: list[tuple[float, CanFrame]] = []
    rig.buses["can0"].attach("listener", on_frame=lambda frame, t: seen.append((t, frame)))
    with rig:
        rig.start()
        yield rig, seen


def test_boot_up_then_heartbeat_from_the_dcf(frames: tuple[Rig, list[tuple[float, CanFrame]]]) -> None:
    """CiA 301 7.2.8.3.3: the boot-up message 0x700 + node-ID [0x00] first (node-ID 0x0C from the DCF's
    [DeviceComissioning]); then heartbeats [0x7F] (Pre-operational) every 0x1017 = 100 ms, the DCF's
    ParameterValue (the EDS default is 0)."""
    rig, seen = frames
    rig.clock.advance(0.35)
    heart = [(t, f.data) for t, f in seen if f.can_id == 0x70C]
    assert heart[0][1] == b"\x00"
    assert [d for _, d in heart[1:]] == [b"\x7f"] * 3
    assert [round(t2 - t1, 6) for (t1, _), (t2, _) in itertools.pairwise(heart[1:])] == [0.1, 0.1]


def test_rpdo_output_echoes_to_an_event_tpdo(frames: tuple[Rig, list[tuple[float, CanFrame]]]) -> None:
    """After NMT start, RPDO1 (0x20C) writes 0x6200:01 (CiA 301 7.2.2); the echo rule copies it to 0x6000:01,
    mapped in TPDO1 (transmission type 255: event-driven, inhibit time 100 x 100 us from the DCF)."""
    rig, seen = frames
    bus = rig.buses["can0"]
    master = bus.attach("master")
    master.send(CanFrame(0x000, bytes([0x01, 0x0C])))
    rig.clock.advance(0.05)
    master.send(CanFrame(0x20C, bytes([0xA5])))
    rig.clock.advance(0.05)
    tpdo1 = [f.data for _, f in seen if f.can_id == 0x18C]
    assert tpdo1 and tpdo1[-1] == bytes([0xA5])


def test_sync_tpdo_carries_the_sine_and_counter_rules(frames: tuple[Rig, list[tuple[float, CanFrame]]]) -> None:
    """TPDO2 (transmission type 1: every SYNC) maps 0x6401:01 (sine, amplitude 1000, period 1 s) and 0x6401:02
    (counter, +3 per 10 ms tick): what SYNC brings follows the rules."""
    rig, seen = frames
    bus = rig.buses["can0"]
    master = bus.attach("master")
    master.send(CanFrame(0x000, bytes([0x01, 0x0C])))
    rig.clock.run_until(0.2505)
    master.send(CanFrame(0x080, b""))
    rig.clock.advance(0.002)
    (frame,) = [f for _, f in seen if f.can_id == 0x28C]
    sine = int.from_bytes(frame.data[0:2], "little", signed=True)
    counter = int.from_bytes(frame.data[2:4], "little", signed=True)
    assert abs(sine - 1000 * math.sin(2 * math.pi * 0.25)) <= 63      # evaluated at the last 10 ms tick
    assert counter % 3 == 0 and 60 <= counter <= 78


def test_sdo_access_and_ranges_from_the_dcf(tmp_path: Path) -> None:
    """python canopen over the simulated bus: 0x2000 has LowLimit 1 / HighLimit 1000 -> 0x06090030 "value range
    of parameter exceeded" above (CiA 301 table 22; the one range abort of every node here, as the drive's);
    0x6000:01 is ro -> 0x06010002; 0x1018:02 reads the DCF's product code."""
    rig = make_rig(tmp_path)
    with rig:
        rig.start()
        network = canopen.Network(python_can_bus(rig.buses["can0"]))
        network.connect()
        node = network.add_node(0x0C, str(DCF))
        assert node.sdo.upload(0x1018, 2) == (0x401).to_bytes(4, "little")
        node.sdo.download(0x2000, 0, (500).to_bytes(2, "little"))
        with pytest.raises(canopen.SdoAbortedError) as high:
            node.sdo.download(0x2000, 0, (2000).to_bytes(2, "little"))
        assert high.value.code == 0x06090030
        with pytest.raises(canopen.SdoAbortedError) as ro:
            node.sdo.download(0x6000, 1, b"\x01")
        assert ro.value.code == 0x06010002
        network.disconnect()


def test_lss_when_the_file_says_lss_supported(tmp_path: Path) -> None:
    """LSS_Supported=1: an LSS slave (CiA 305) answers with the identity of 0x1018 and the rig's serial."""
    rig = make_rig(tmp_path, {"serial": 0xC0FFEE})
    with rig:
        rig.start()
        (device,) = rig.participants
        assert device.lss is not None
        address = device.lss.machine.address
        assert address.serial == 0xC0FFEE and address.product_code == 0x401 and address.vendor_id == 0xABC


@pytest.mark.parametrize(("change", "message"), [
    (("DataType=0x0007\nAccessType=ro\nDefaultValue=0x000F0191", "DataType=seven\nAccessType=ro\nDefaultValue=0"),
     "[1000]: bad or missing DataType"),
    (("[DeviceInfo]", "DeviceInfo"), "not an EDS/DCF"),
])
def test_a_bad_file_is_one_line_naming_file_and_section(tmp_path: Path, change: tuple[str, str],
                                                        message: str) -> None:
    text = DCF.read_text()
    assert change[0] in text
    with pytest.raises(ConfigError) as err:
        make_rig(tmp_path, text=text.replace(change[0], change[1], 1))
    line = str(err.value)
    assert "\n" not in line and "device.dcf" in line and message in line


@pytest.mark.parametrize(("behaviour", "message"), [
    ({"0x6000:09": "counter"}, "no such entry"),
    ({"0x1008": "counter"}, "needs a numeric entry"),
    ({"0x6000:01": {"echo": "0x7000"}}, "not in the dictionary"),
    ({"0x6000:01": {"spin": 1}}, "unknown rule 'spin'"),
    ({"0x6401:01": {"sine": {"amplitude": 1}}}, "period must be a number (missing)"),
    ({"0x6000:01": {"value": 300}}, "does not fit UNSIGNED8"),
])
def test_a_rule_that_does_not_fit_is_one_line(tmp_path: Path, behaviour: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError) as err:
        make_rig(tmp_path, {"behaviour": behaviour})
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_missing_file_names_the_key(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"eds = '.*nope.dcf': cannot read"):
        make_rig(tmp_path, {"eds": str(tmp_path / "nope.dcf")})


def test_strings_of_an_eds_take_more_than_their_default() -> None:
    """CiA 306 declares no string sizes: a string read from an EDS holds 255 bytes (or its default's length
    when longer), so a name longer than the default can be written; more aborts 0x06070012 (CiA 301)."""
    from gatewaylab.od.eds import read_eds

    text = DCF.read_text() + "\n[2001]\nParameterName=Tag\nObjectType=0x7\nDataType=0x0009\nAccessType=rw\n" \
                             "DefaultValue=ab\nPDOMapping=0\n"
    od, warnings = read_eds(text)
    assert not warnings
    assert od.entries[(0x2001, 0)].max_length == 255


def test_two_nodes_with_one_node_id_from_their_files_are_refused(tmp_path: Path) -> None:
    """CiA 301: a node-ID is unique per network; the DCF's NodeID counts like the rig file's."""
    device = {"kind": "canopen_node", "eds": str(DCF), "bus": "can0"}
    with pytest.raises(ConfigError, match=r"node_id 12 \(from io-module.dcf\) is already used on bus 'can0'"):
        Rig(parse_rig({"clock": "simulated", "bus": [{"name": "can0", "endpoint": "none"}],
                       "device": [device, dict(device, name="second")]}))


@pytest.mark.parametrize("kind", ["drive", "maxon_idx"])
def test_an_exported_eds_runs_as_the_same_dictionary(tmp_path: Path, kind: str) -> None:
    """`gatewaylab eds KIND` writes what the device answers; a canopen_node built from that file holds the same
    entries (data type, access, PDO mapping) with the same power-on values (CiA 306 round trip)."""
    from gatewaylab.cli.eds import KINDS, eds_of
    from gatewaylab.plugin.capabilities import HasNode

    path = tmp_path / f"{kind}.eds"
    path.write_text(eds_of(kind, 2))
    rigs = {}
    for source in ("original", "eds"):
        section = {"kind": "canopen_node", "eds": str(path)} if source == "eds" else KINDS[kind]
        rigs[source] = Rig(parse_rig({"clock": "simulated", "bus": [{"name": "can0", "endpoint": "none"}],
                                      "device": [{**section, "bus": "can0", "node_id": 2, "name": "n"}]}))
    try:
        a, b = ((p for p in r.participants if isinstance(p, HasNode)) for r in rigs.values())
        od_a, od_b = next(a).node.od, next(b).node.od
        rows = {key: (e.data_type, e.access, e.pdo_mappable) for key, e in od_a.entries.items() if key[0] >= 0x1000}
        assert rows == {key: (e.data_type, e.access, e.pdo_mappable) for key, e in od_b.entries.items()
                        if key[0] >= 0x1000}
        assert {k: od_a.values[k] for k in rows} == {k: od_b.values[k] for k in rows}
        assert len(rows) > 100
    finally:
        for r in rigs.values():
            r.close()
