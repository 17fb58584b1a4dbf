"""The gateway core on a simulated clock: register requests become SDO transfers of its own
SDO client on the bus (CiA 301 7.2.4; docs/devices/modbus_gateway.md), and the rig-file section."""

from __future__ import annotations

from typing import Any

import pytest

from gatewaylab.bus import CanFrame
from gatewaylab.common.errors import ConfigError
from gatewaylab.devices.modbus_gateway.mapping import ModbusException, RegisterKind
from gatewaylab.devices.modbus_gateway.rig import ModbusGatewayParticipant
from gatewaylab.rig import Rig
from gatewaylab.rig.config import parse_rig

H, INP = RegisterKind.HOLDING, RegisterKind.INPUT


def _rig(**gateway: Any) -> Rig:
    section = {"kind": "modbus_gateway", "name": "mb", "bus": "can0", "node_id": 100, "nodes": [2, 5], **gateway}
    return Rig(parse_rig({"clock": "simulated", "bus": [{"name": "can0", "endpoint": "none"}],
                          "drive": [{"bus": "can0", "node_id": 2, "serial": 0x1002}],
                          "device": [section]}))


class Results:
    def __init__(self) -> None:
        self.got: list[Any] = []

    def __call__(self, result: Any) -> None:
        self.got.append(result)


def _run(rig: Rig, call: Any, *args: Any) -> Any:
    done = Results()
    call(*args, done)
    rig.clock.advance(1.0)          # longer than the SDO timeout: every request has ended
    assert len(done.got) == 1
    return done.got[0]


@pytest.fixture
def rig() -> Any:
    with _rig() as r:
        r.start()
        frames: list[CanFrame] = []
        r.buses["can0"].add_monitor(lambda frame, t: frames.append(frame))
        r.frames = frames  # type: ignore[attr-defined]
        yield r


def _gw(rig: Rig) -> Any:
    participant = rig.participants[-1]
    assert isinstance(participant, ModbusGatewayParticipant)
    return participant.gateway


def test_reads_are_sdo_uploads_of_the_mapped_objects(rig: Rig) -> None:
    """FC 4 input registers 0..5 of unit 2 = statusword, mode display, position, velocity of node 2,
    each read by an SDO upload request 0x40 on 0x602 (CiA 301 7.2.4.3.6)."""
    gw = _gw(rig)
    words = _run(rig, gw.read, 2, INP, 0, 6)
    assert words[0] & 0x6F == 0x40 and words[2:] == [0, 0, 0, 0]      # switch on disabled, at rest
    uploads = [f for f in rig.frames if f.can_id == 0x602]  # type: ignore[attr-defined]
    assert [(f.data[0], int.from_bytes(f.data[1:3], "little")) for f in uploads] == [
        (0x40, 0x6041), (0x40, 0x6061), (0x40, 0x6064), (0x40, 0x606C)]


def test_writes_drive_the_power_state_machine(rig: Rig) -> None:
    """FC 6 controlword 0x06, 0x07, 0x0F (CiA 402 transitions 2, 3, 4) -> statusword 0x27 pattern
    (operation enabled); FC 16 of target position is one expedited download of 4 bytes (0x23)."""
    gw = _gw(rig)
    for cw in (0x06, 0x07, 0x0F):
        assert _run(rig, gw.write, 2, 0, [cw]) is None
    assert _run(rig, gw.read, 2, INP, 0, 1)[0] & 0x6F == 0x27
    assert _run(rig, gw.write, 2, 2, [0x0001, 0x86A0]) is None          # 100000, high word first
    with rig.clock.lock:
        assert rig.participants[0].node.get(0x607A, 0) == 100_000  # type: ignore[attr-defined]
    assert any(f.can_id == 0x602 and f.data[0] == 0x23 for f in rig.frames)  # type: ignore[attr-defined]


def test_failures_become_modbus_exceptions(rig: Rig) -> None:
    """Modbus 7 exceptions: unmapped register 02, a served node that never answers 0B (SDO timeout
    0x05040000), a unit the gateway does not serve 0A, a read-only object written 02 (0x06010002)."""
    gw = _gw(rig)
    assert _run(rig, gw.read, 2, H, 100, 1) is ModbusException.ILLEGAL_DATA_ADDRESS
    assert _run(rig, gw.read, 5, H, 0, 1) is ModbusException.GATEWAY_TARGET_FAILED_TO_RESPOND
    assert _run(rig, gw.read, 7, H, 0, 1) is ModbusException.GATEWAY_PATH_UNAVAILABLE
    with _rig(map=[{"register": 0, "kind": "holding", "index": 0x1018, "subindex": 4, "type": "u32"},
                   {"register": 2, "kind": "holding", "index": 0x5FFF, "subindex": 0, "type": "u16"},
                   {"register": 3, "kind": "holding", "index": 0x6060, "subindex": 0, "type": "i8"}]) as other:
        other.start()
        ogw = _gw(other)
        assert _run(other, ogw.read, 2, H, 0, 2) == [0, 0x1002]
        assert _run(other, ogw.write, 2, 0, [0, 1]) is ModbusException.ILLEGAL_DATA_ADDRESS   # read only
        assert _run(other, ogw.read, 2, H, 2, 1) is ModbusException.ILLEGAL_DATA_ADDRESS     # 0x06020000
        assert _run(other, ogw.write, 2, 3, [0x7F]) is ModbusException.ILLEGAL_DATA_VALUE     # 0x06090030
    assert "ok" not in gw.counters and gw.counters["GATEWAY_TARGET_FAILED_TO_RESPOND"] == 1


def test_simulated_rig_opens_no_port() -> None:
    """A simulated clock runs only when its owner moves it, so no server thread is started and the
    ready info names no Modbus endpoint (docs/decisions.md)."""
    with _rig() as r:
        r.start()
        assert "modbus" not in r.ready_info()


@pytest.mark.parametrize(("change", "message"), [
    ({"nodes": [2, 200]}, "1..127"),
    ({"nodes": [2, 2]}, "twice"),
    ({"nodes": [100]}, "own node_id"),
    ({"nodes": []}, "at least one"),
    ({"map": [{"register": 0, "index": 0x6040, "type": "u64"}]}, "type must be"),
    ({"tcp_port": 70000}, "tcp_port"),
    ({"node_id": 2}, "node-ID 2|node_id = 2"),
])
def test_rig_file_errors_are_one_line(change: dict[str, Any], message: str) -> None:
    """docs/devices/writing-a-device.md 2: a bad section is one ConfigError line naming it."""
    with pytest.raises(ConfigError, match=message) as exc:
        _rig(**change).close()
    assert "\n" not in str(exc.value)
