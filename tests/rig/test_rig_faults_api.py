"""The fault API of a rig (``rig.faults``), its control endpoint and the `gatewaylab fault` command line
(issue 14 'Break'; docs/faults.md 'Control protocol')."""

from __future__ import annotations

import json
import re
import socket
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.bus import CanFrame, ErrorState
from gatewaylab.canopen.cia402 import PdsState
from gatewaylab.canopen.nmt import NmtState
from gatewaylab.common.clock import RealTimeClock
from gatewaylab.devices.canopen_drive.device import Drive
from gatewaylab.rig.config import parse_rig
from gatewaylab.rig.control import MAX_LINE, answer_line
from gatewaylab.rig.faults import REQUESTS
from gatewaylab.rig.faults_core import FaultRefused
from gatewaylab.rig.runtime import Rig, RigStartError

TWO_DRIVES: dict[str, Any] = {
    "clock": "simulated", "bus": [{"name": "can0"}],
    "drive": [{"bus": "can0", "node_id": 2, "serial": 0x1002, "name": "axis2"},
              {"bus": "can0", "node_id": 3, "serial": 0x1003, "name": "axis3"}]}


def _sim_rig() -> Rig:
    rig = Rig(parse_rig(TWO_DRIVES))
    rig.start()
    rig.clock.advance(0.1)
    return rig


def _drive(rig: Rig, name: str) -> Drive:
    p = next(p for p in rig.participants if p.name == name)
    assert isinstance(p, Drive)
    return p


def test_controller_faults_by_name_and_by_node_id() -> None:
    """docs/faults.md: a node is named by device name or by node-ID on a bus; error-passive is TEC 128
    (CAN 2.0 §8 rule 9), bus-off recovers after 128 x 11 recessive bits (rule 12)."""
    with _sim_rig() as rig:
        ctrl = _drive(rig, "axis2").node.controller
        answer = rig.faults.error_passive("axis2")
        assert answer["state"] == "error-passive" and ctrl.state is ErrorState.ERROR_PASSIVE
        rig.faults.bus_off(3, bus="can0")
        assert _drive(rig, "axis3").node.controller.state is ErrorState.BUS_OFF
        rig.clock.advance(0.01)
        assert _drive(rig, "axis3").node.controller.state is ErrorState.ERROR_ACTIVE
        for bad in (lambda: rig.faults.bus_off(9, bus="can0"), lambda: rig.faults.bus_off(2),
                    lambda: rig.faults.bus_off("axis2", channel="can7"), lambda: rig.faults.drop("can9", 0x100)):
            with pytest.raises(FaultRefused):
                bad()


def test_power_cycle_resets_volatile_values_and_keeps_stored_ones() -> None:
    """CiA 301 0x1010 'store parameters': stored values survive a power cycle, the rest return to
    their defaults; the node leaves the bus while off and sends its boot-up message (CiA 301 NMT)."""
    with _sim_rig() as rig:
        drive = _drive(rig, "axis2")
        node = drive.node
        node.write(0x30B0, 0, struct.pack("<i", 77))
        node.write(0x1010, 1, b"save")
        node.write(0x6065, 0, struct.pack("<I", 1234))
        seen: list[CanFrame] = []
        rig.buses["can0"].add_monitor(lambda frame, t: seen.append(frame))
        rig.faults.power_cycle("axis2", off=0.5)
        assert not node.running and node.controller not in rig.buses["can0"].controllers
        with pytest.raises(FaultRefused):
            rig.faults.drive_fault("axis2")               # nothing to fault while off
        rig.clock.advance(0.6)
        assert node.running and node.nmt_state is NmtState.PRE_OPERATIONAL
        assert any(f.can_id == 0x702 and f.data == b"\x00" for f in seen)      # boot-up
        assert node.get(0x6065) == 2000 and node.get(0x30B0) == 77


def test_drive_fault_enters_fault_with_the_cia402_code() -> None:
    """CiA 402: a drive fault sets 0x603F, sends EMCY with that code and ends in Fault (transition 13, 14)."""
    with _sim_rig() as rig:
        drive = _drive(rig, "axis3")
        answer = rig.faults.drive_fault("axis3", "over-current")
        assert answer["error_code"] == 0x2310
        rig.clock.advance(0.2)
        assert drive.state is PdsState.FAULT and drive.node.get(0x603F) == 0x2310
        with pytest.raises(FaultRefused):
            rig.faults.drive_fault("axis3", "melted")


def test_can_unplug_and_replug_a_drive() -> None:
    """Unplugged, a drive's frames reach nobody; replugged, it is heard again (docs/faults.md)."""
    with _sim_rig() as rig:
        bus = rig.buses["can0"]
        drive = _drive(rig, "axis2")
        drive.node.write(0x1017, 0, struct.pack("<H", 10))
        seen: list[int] = []
        bus.add_monitor(lambda frame, t: seen.append(frame.can_id))
        rig.faults.can_unplug("axis2")
        rig.clock.advance(0.1)
        assert 0x702 not in seen
        rig.faults.can_replug("axis2")
        rig.clock.advance(0.1)
        assert 0x702 in seen


# -- the control endpoint -------------------------------------------------------------------------
def _realtime_rig(tmp_path: Path, **bus: Any) -> Rig:
    cfg = {**TWO_DRIVES, "clock": "realtime", "bus": [{"name": "can0", **bus}]}
    return Rig(parse_rig(cfg), clock=RealTimeClock(), state_dir=tmp_path / "state")


def _connect(endpoint: str) -> socket.socket:
    if endpoint.startswith("unix:"):
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.connect(endpoint[5:])
    else:
        host, port = endpoint[4:].rsplit(":", 1)
        s = socket.create_connection((host, int(port)))
    s.settimeout(20)
    return s


def _ask(s: socket.socket, line: bytes) -> dict[str, Any]:
    s.sendall(line)
    buf = b""
    while not buf.endswith(b"\n"):
        chunk = s.recv(65536)
        assert chunk, "the rig closed the control connection"
        buf += chunk
    answer: dict[str, Any] = json.loads(buf)
    return answer


@pytest.mark.parametrize("endpoint", ["unix", "tcp"])
def test_control_endpoint_survives_garbage_and_is_removed_on_close(tmp_path: Path, endpoint: str) -> None:
    """docs/faults.md: one JSON object per line in, one per line out; malformed input answers an
    error and never stops the rig; the endpoint is in the ready info and gone after close."""
    rig = _realtime_rig(tmp_path, endpoint=endpoint)
    try:
        rig.run_in_thread()
        control = rig.ready_info()["control"]
        assert control.startswith(f"{endpoint}:")
        with _connect(control) as s:
            for bad in (b"garbage\n", b"[1, 2]\n", b"\xff\xfe\n", b'{"fault": "melt"}\n',
                        b'{"fault": "drop", "bus": "can0"}\n', b'{"fault": "drop", "bus": "can0", "can_id": "x"}\n',
                        b'{"fault": "bus-off", "device": "axis2", "node": 2}\n',
                        b'{"fault": "drop", "bus": "can0", "can_id": 1, "colour": 1}\n',
                        b'{"fault": "stuck-dominant", "bus": "can0", "duration": Infinity}\n',
                        b'{"fault": "power-cycle", "device": "axis2", "off": NaN}\n'):
                answer = _ask(s, bad)
                assert answer["ok"] is False and answer["error"], bad
            answer = _ask(s, b'{"fault": "drop", "bus": "can0", "can_id": 386, "count": 2}\n')
            assert answer == {"ok": True, "fault": "drop", "bus": "can0", "can_id": 386, "count": 2}
        with _connect(control) as s:       # a half line, then gone
            s.sendall(b'{"fault": ')
        with _connect(control) as s:       # an over-long line: refused, skipped to its end
            answer = _ask(s, b"x" * (MAX_LINE + 10))
            assert answer["ok"] is False and "longer" in answer["error"]
            s.sendall(b"y" * 100 + b"\n")
            assert _ask(s, b'{"fault": "drop", "bus": "can0", "can_id": 1}\n')["ok"] is True
        with _connect(control) as s:
            assert _ask(s, b'{"fault": "bus-off", "node": 2, "bus": "can0"}\n')["ok"] is True
        assert rig.callback_errors == 0
    finally:
        rig.request_stop()
        rig.close()
    if endpoint == "unix":
        assert not Path(control[5:]).exists()


def test_control_socket_removed_after_a_failed_start(tmp_path: Path) -> None:
    """A rig whose start fails (an IDX TCP port in use) leaves no control socket behind."""
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    cfg = {**TWO_DRIVES, "clock": "realtime",
           "device": [{"kind": "maxon_idx", "name": "idx1", "bus": "can0", "node_id": 1,
                       "usb": {"pty": False, "tcp_port": busy.getsockname()[1]}}]}
    rig = Rig(parse_rig(cfg), clock=RealTimeClock(), state_dir=tmp_path / "state")
    control = Path(rig.ready_info()["control"][5:])
    assert control.exists()
    try:
        with pytest.raises(RigStartError):
            rig.start()
    finally:
        rig.close()
        busy.close()
    assert not control.exists()


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", "fault", *args], capture_output=True,
                          text=True, timeout=60)


def test_fault_cli_help_usage_and_refusal(tmp_path: Path) -> None:
    """docs/faults.md: --help shows examples; usage errors exit 2 with one line; a fault the rig
    refuses exits 1 with one line; a done fault prints what the rig did."""
    helped = _cli("--help")
    assert helped.returncode == 0 and "examples:" in helped.stdout and "bus-errors can0 0.5" in helped.stdout
    sub = _cli("x.json", "power-cycle", "--help")
    assert sub.returncode == 0 and "example:" in sub.stdout
    usage = _cli("x.json", "drop", "can0", "zz")
    assert usage.returncode == 2 and "not a number" in usage.stderr
    missing = _cli(str(tmp_path / "none.json"), "usb-unplug", "idx1")
    assert missing.returncode == 2 and len(missing.stderr.strip().splitlines()) == 1   # not found: docs/cli.md
    rig = _realtime_rig(tmp_path)
    try:
        rig.run_in_thread()
        ready = tmp_path / "ready.json"
        ready.write_text(json.dumps(rig.ready_info()))
        refused = _cli(str(ready), "usb-unplug", "axis2")
        assert refused.returncode == 1 and refused.stderr.strip() == "gatewaylab: fault refused: axis2 has no USB port"
        done = _cli(str(ready), "corrupt", "can0", "0x702", "-n", "2", "--json")
        assert done.returncode == 0, done.stderr
        assert json.loads(done.stdout) == {"ok": True, "fault": "corrupt", "bus": "can0", "can_id": 0x702, "count": 2}
    finally:
        rig.request_stop()
        rig.close()


class _Gateway:
    """A device with several CAN channels, as an EtherCAT-to-CAN gateway registers them."""

    def __init__(self, rig: Rig) -> None:
        self.name = "gw1"
        self.ctrls = {"can0": rig.buses["can0"].attach("gw1/can0"), "can1": rig.buses["can1"].attach("gw1/can1")}

    def can_channels(self) -> dict[str, Any]:
        return self.ctrls

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def ready_info(self) -> dict[str, Any]:
        return {}


def test_a_gateways_can_channels_are_unplugged_one_by_one() -> None:
    """docs/faults.md 'Devices and faults': a device listing its channels (can_channels) has each
    unplugged by name; without a channel name the fault is refused (which one?)."""
    cfg = {**TWO_DRIVES, "bus": [{"name": "can0"}, {"name": "can1"}]}
    with Rig(parse_rig(cfg)) as rig:
        gw = _Gateway(rig)
        rig.participants.append(gw)
        with pytest.raises(FaultRefused, match="say which"):
            rig.faults.can_unplug("gw1")
        answer = rig.faults.can_unplug("gw1", channel="can1")
        assert answer["bus"] == "can1"
        assert gw.ctrls["can0"].connected and not gw.ctrls["can1"].connected
        rig.faults.can_replug("gw1", channel="can1")
        assert gw.ctrls["can1"].connected


_ARGS = sorted({k for _, params in REQUESTS.values() for k in params} | {"colour"})
_JSON_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-2**40, 2**40),
                         st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                         st.sampled_from(["can0", "axis2", "axis3", "nope", "following-error", "over-current"]),
                         st.lists(st.integers(), max_size=2))


@settings(max_examples=300, deadline=None)
@given(fault=st.one_of(st.sampled_from(sorted(REQUESTS)), st.text(max_size=6), st.integers()),
       args=st.dictionaries(st.sampled_from(_ARGS), _JSON_VALUES, max_size=4))
def test_any_request_gets_an_answer_and_only_fault_errors(fault: object, args: dict[str, object]) -> None:
    """docs/faults.md 'Control protocol': whatever a request holds, the answer is one JSON line with
    ok true, or ok false and the rig's own refusal (never an exception of the rig's code)."""
    with _sim_rig() as rig:
        line = json.dumps({"fault": fault, **args}).encode()
        raw = answer_line(rig.faults.request, line)
        assert raw.endswith(b"\n") and raw.count(b"\n") == 1
        answer = json.loads(raw)
        assert isinstance(answer["ok"], bool)
        if not answer["ok"]:
            assert not re.match(r"[A-Z]\w*(Error|Exception)\b", answer["error"]), answer["error"]
        rig.clock.advance(0.05)      # what a fault scheduled runs without raising


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=200))
def test_any_bytes_get_an_answer(data: bytes) -> None:
    """docs/faults.md: non-UTF-8, non-JSON or non-object lines are answered with ok false."""
    with _sim_rig() as rig:
        answer = json.loads(answer_line(rig.faults.request, data))
        assert isinstance(answer["ok"], bool)


def test_ethercat_gateways_offer_their_can_channels_and_leave_the_line() -> None:
    """docs/faults.md 'Devices and faults': the ECAN-Lite lists its MCAN channels and the esd gateway
    its one controller (can_channels), each unplugged by name; both are EtherCAT devices of the
    segment, so ethercat-unplug cuts them off (ETG.1000.4 working counter)."""
    cfg = {"clock": "simulated", "bus": [{"name": "can0"}, {"name": "can1"}],
           "device": [{"kind": "ecanlite", "name": "ecan1", "channels": ["can0", "can1"]},
                      {"kind": "esd_can_ethercat", "name": "esd1", "bus": "can1"}],
           "ethercat": {"interface": "gl-none"}}
    with Rig(parse_rig(cfg)) as rig:
        rig.start()
        ecan = next(p for p in rig.participants if p.name == "ecan1")
        channels = ecan.can_channels()  # type: ignore[attr-defined]
        assert sorted(channels) == ["mcan0", "mcan1"]
        answer = rig.faults.can_unplug("ecan1", channel="mcan1")
        assert answer["bus"] == "can1" and not channels["mcan1"].connected and channels["mcan0"].connected
        esd = next(p for p in rig.participants if p.name == "esd1")
        if esd.can_channels():  # type: ignore[attr-defined]
            assert rig.faults.can_unplug("esd1")["channel"] == "can"
        assert rig.faults.ethercat_unplug("ecan1")["unreachable"] == ["ecan1", "esd1"]
        assert rig.faults.ethercat_replug("ecan1")["al_status"] == 1
