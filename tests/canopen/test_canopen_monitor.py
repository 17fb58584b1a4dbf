"""The bus monitor's decoder on a recorded session, and ``gatewaylab monitor`` as a user runs it (issue 14,
"Watch": SDO transfers reassembled into one line each, interleaved transfers of two nodes, aborts by name,
PDOs with mapped values where the dictionary is known, NMT, SYNC, TIME, heartbeat, EMCY with the error
code's name, LSS Fastscan as a bisection; ``--plain`` and ``--json``; listen-only)."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import can
import canopen
import pytest
from canopen_monitor_kit import UNCONFIGURED_SERIAL, Session, record_session
from hypothesis import given, settings
from hypothesis import strategies as st

from gatewaylab.bus import CanFrame
from gatewaylab.canopen.monitor import BusMonitor, MonitorEvent
from gatewaylab.od.eds import import_eds
from gatewaylab.rig.process import RigProcess


@pytest.fixture(scope="module")
def session() -> Session:
    return record_session()


@pytest.fixture(scope="module")
def decoded(session: Session) -> tuple[BusMonitor, list[MonitorEvent]]:
    monitor = BusMonitor({n: import_eds(d.node.to_eds(), n) for n, d in session.drives.items()})
    return monitor, monitor.feed_many(session.frames)


def texts(events: list[MonitorEvent], kind: str) -> list[str]:
    return [e.text for e in events if e.kind == kind]


def test_interleaved_uploads_of_two_nodes_are_one_line_each(decoded: tuple[BusMonitor, list[MonitorEvent]],
                                                             session: Session) -> None:
    """CiA 301 7.2.4.3: a segmented upload from node 2 and an expedited and a block upload from node 3 run at
    the same time; each becomes one line with the whole value, its protocol, segments and duration."""
    _, events = decoded
    sdo = texts(events, "sdo")
    name = session.results["name2"].decode()
    assert any(re.fullmatch(rf"node 2 read 0x1008:00 Manufacturer device name = '{re.escape(name)}' "
                            r"\(segmented, 5 segments, \d+\.\d ms\)", line) for line in sdo), sdo
    assert any(re.fullmatch(rf"node 3 read 0x1008:00 Manufacturer device name = '{re.escape(name)}' "
                            r"\(block, 5 segments, \d+\.\d ms\)", line) for line in sdo), sdo
    assert any(line.startswith("node 3 read 0x1018:04 Identity object/Serial number = 4099 (0x00001003) (expedited")
               for line in sdo)
    # the frames really did interleave: node 3's transfer ended inside node 2's
    t = {e.text.split(" = ")[0]: e for e in events if e.kind == "sdo"}
    two = t["node 2 read 0x1008:00 Manufacturer device name"]
    three = t["node 3 read 0x1008:00 Manufacturer device name"]
    assert three.t < two.t and two.t - two.fields["ms"] / 1000 < three.t


def test_downloads_and_abort_by_name(decoded: tuple[BusMonitor, list[MonitorEvent]]) -> None:
    """Segmented and block downloads (CiA 301 7.2.4.3.3, 7.2.4.3.9) to a node without a known dictionary show
    the raw value; an abort shows the CiA 301 abort code's text."""
    _, events = decoded
    sdo = texts(events, "sdo")
    assert any(line.startswith("node 5 write 0x2001:00 = 'hello monitor' (segmented, 2 segments") for line in sdo)
    assert any(line.startswith("node 5 write 0x2002:00 = 00 01 02 03 04 05 06 07 08 09 0a 0b 0c 0d 0e 0f ... "
                               "(100 bytes) (block, 15 segments") for line in sdo), sdo
    assert texts(events, "sdo-abort") == [
        "node 2 read 0x1234:00 aborted by the server: Object does not exist in the object dictionary (0x06020000)"]


def test_pdos_decode_with_the_mapping_the_monitor_saw_written(decoded: tuple[BusMonitor, list[MonitorEvent]]) -> None:
    """CiA 301 7.5.2.36: drive 3's TPDO1 was remapped by SDO to statusword + velocity actual value; the monitor
    follows the writes and decodes the new layout, drive 2 keeps the default one."""
    _, events = decoded
    pdo = texts(events, "pdo")
    assert "TPDO1 node 2: Statusword=1591 (0x0637), Position actual value=0" in pdo
    assert "TPDO1 node 3: Statusword=576 (0x0240), Velocity actual value=0" in pdo
    assert not any(line.startswith("TPDO1 node 3") and "Position" in line for line in pdo)


def test_node_table(decoded: tuple[BusMonitor, list[MonitorEvent]]) -> None:
    """The node table: NMT state from heartbeats and NMT commands, CiA 402 state from the statusword, last EMCY
    with its CiA 402 error-code name."""
    monitor, _ = decoded
    two, three = monitor.nodes[2], monitor.nodes[3]
    assert two.cia402_state == "operation enabled" and two.statusword == 0x637 and two.position == 0
    assert three.cia402_state == "fault" and three.emcy == "0x8611 following error"
    assert two.nmt == three.nmt == "Stopped" and two.heartbeat_t is not None


def test_nmt_sync_time_emcy_boot_lines(decoded: tuple[BusMonitor, list[MonitorEvent]]) -> None:
    """CiA 301 7.2.8 NMT, 7.2.5 SYNC, 7.2.6 TIME (ms after midnight, days since 1984-01-01), 7.2.7 EMCY,
    7.2.8.3.2.1 boot-up."""
    _, events = decoded
    assert texts(events, "nmt") == ["NMT start (-> Operational) to all nodes", "NMT stop (-> Stopped) to all nodes"]
    assert len(texts(events, "sync")) == 3
    assert texts(events, "time") == ["TIME 1984-04-10T00:00:10.000+00:00"]
    assert texts(events, "emcy") == ["EMCY node 3: 0x8611 following error, error register 0x21"]
    assert texts(events, "boot-up") == ["boot-up of node 2", "boot-up of node 3", "boot-up of node 5"]


def test_fastscan_is_told_as_a_bisection(decoded: tuple[BusMonitor, list[MonitorEvent]], session: Session) -> None:
    """CiA 305 8.3.5 Fastscan: each BitChecked request answered means 0, unanswered 1; the 128 steps spell
    the address the master found."""
    _, events = decoded
    steps = [e.fields for e in events if e.kind == "lss" and "bit" in e.fields]
    assert len(steps) == 128
    parts = {"vendor": 0, "product": 0, "revision": 0, "serial": 0}
    for step in steps:
        parts[step["part"]] |= step["value"] << step["bit"]
    found = session.results["fastscan"]
    assert parts == {"vendor": found.vendor_id, "product": found.product_code, "revision": found.revision,
                     "serial": UNCONFIGURED_SERIAL}


frames = st.builds(lambda cid, data, ext: CanFrame(cid if not ext else cid | 0x800, data, extended=ext),
                   st.integers(0, 0x7FF), st.binary(max_size=8), st.booleans())
sdo_frames = st.builds(lambda node, req, data: CanFrame((0x600 if req else 0x580) + node, data),
                       st.sampled_from([2, 3]), st.booleans(), st.binary(min_size=0, max_size=8))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(frames, sdo_frames), max_size=60))
def test_any_frame_sequence_is_decoded_without_error(sequence: list[CanFrame]) -> None:
    """Whatever is on the bus (garbage SDO sequences included), the monitor returns events, never raises."""
    monitor = BusMonitor()
    for i, frame in enumerate(sequence):
        for event in monitor.feed(frame, i * 0.001):
            assert isinstance(event.text, str)
            json.dumps(event.to_json())


def test_replay_of_a_trace_file_as_json(session: Session, tmp_path: Path) -> None:
    """``gatewaylab monitor --replay TRACE --json --eds NODE=FILE``: a trace written by python-can's own writer
    decodes to the same events, one JSON object per line."""
    trace = tmp_path / "session.asc"
    with can.ASCWriter(str(trace)) as writer:
        for frame, t in session.frames:
            writer.on_message_received(frame.to_message(t, "can0"))
    eds = tmp_path / "drive2.eds"
    eds.write_text(session.drives[2].node.to_eds())
    out = subprocess.run([sys.executable, "-m", "gatewaylab", "monitor", "--replay", str(trace), "--json",
                          "--eds", f"2={eds}"], capture_output=True, text=True, timeout=120, check=True)
    events = [json.loads(line) for line in out.stdout.splitlines()]
    sdo = [e for e in events if e["kind"] == "sdo" and e["node"] == 2 and e["index"] == 0x1008]
    assert sdo and sdo[0]["value"] == session.results["name2"].decode() and sdo[0]["segments"] == 5
    assert any(e["kind"] == "pdo" and e["node"] == 2 and "0x6064:00" in e["values"] for e in events)


RIG = """
clock = "realtime"
[[bus]]
name = "can0"
bitrate = 1000000
[[drive]]
bus = "can0"
node_id = 2
serial = 0x1002
"""


def test_live_monitor_from_another_process(tmp_path: Path) -> None:
    """As a user: `gatewaylab run` in one process, `gatewaylab monitor READY --plain` in another (listen-only,
    dictionaries from the ready file), a canopen client in a third; the monitor prints the client's SDO read
    as one line and the drive's TPDO with object names; SIGINT ends it with status 0."""
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(RIG)
    with RigProcess(rig_file, workdir=tmp_path, timeout=30) as rig:
        mon = subprocess.Popen([sys.executable, "-m", "gatewaylab", "monitor", str(rig.ready_file), "--plain"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        watchdog = threading.Timer(120, mon.kill)   # a monitor that never prints must not hang the suite
        watchdog.start()
        try:
            assert mon.stderr is not None and mon.stdout is not None
            header = mon.stderr.readline()      # and the time base (issue 25): since the rig's start
            assert "listen-only" in header and "times: seconds since the rig started" in header
            network = canopen.Network()
            network.connect(interface="gatewaylab", channel=rig.endpoint("can0"))
            try:
                name = network.add_node(2).sdo.upload(0x1008, 0).decode()
                network.nmt.state = "OPERATIONAL"
            finally:
                network.disconnect()
            seen: list[str] = []
            while not (any("read 0x1008:00" in line for line in seen)
                       and any(line.split("  ", 1)[-1].startswith("TPDO1 node 2: Statusword=") for line in seen)):
                line = mon.stdout.readline()
                assert line, f"monitor ended early: {seen}"
                seen.append(line.rstrip("\n"))
            assert any(f"node 2 read 0x1008:00 Manufacturer device name = '{name}' (segmented" in line for line in seen)
        finally:
            mon.send_signal(signal.SIGINT)
            code = mon.wait(20)
            watchdog.cancel()
        assert code == 0
