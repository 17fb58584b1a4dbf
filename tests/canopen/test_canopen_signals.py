"""``--db FILE``: signal decoding beyond CANopen through cantools (issue 25, "Decoding beyond CANopen"), in
the decoder (bus/signals.py), the monitor (decoded and raw views), ``plot`` and the ``--web`` page."""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import can

from gatewaylab.bus import CanFrame
from gatewaylab.bus.signals import load_database
from gatewaylab.canopen.monitor import BusMonitor
from gatewaylab.cli.plot import panels, read_trace
from gatewaylab.rig.process import RigProcess

DBC = """VERSION ""
NS_ :
BS_:
BU_: ECU
BO_ 256 EngineData: 8 ECU
 SG_ EngineSpeed : 0|16@1+ (0.25,0) [0|16383.75] "rpm" Vector__XXX
 SG_ Temperature : 16|8@1- (1,-40) [-40|215] "degC" Vector__XXX
 SG_ Gear : 24|8@1+ (1,0) [0|3] "" Vector__XXX
BO_ 2147483904 Body: 2 ECU
 SG_ Doors : 0|8@1+ (1,0) [0|255] "" Vector__XXX
VAL_ 256 Gear 0 "Park" 1 "Reverse" 2 "Neutral" 3 "Drive" ;
"""
ENGINE = CanFrame(0x100, bytes([0x40, 0x1F, 0xF0, 0x03, 0, 0, 0, 0]))     # 2000 rpm, -56 degC, Drive


def dbc(tmp_path: Path) -> Path:
    path = tmp_path / "car.dbc"
    path.write_text(DBC)
    return path


def gl(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", *args], capture_output=True, text=True, timeout=120)


def test_decoder_scales_signs_names_and_keeps_the_id_space(tmp_path: Path) -> None:
    """DBC semantics as cantools applies them: factor/offset, signed signals, value tables (VAL_), and the
    29-bit flag of an id (0x80000000 in the DBC) kept apart from the 11-bit ids."""
    db = load_database(dbc(tmp_path))
    message = db.decode(ENGINE)
    assert message is not None
    assert message.text() == "EngineData: EngineSpeed=2000 rpm, Temperature=-56 degC, Gear=Drive"
    assert message.numbers() == {"EngineSpeed": 2000.0, "Temperature": -56.0}
    body = db.decode(CanFrame(0x100, b"\x07\x00", extended=True))
    assert body is not None and body.text() == "Body: Doors=7"
    short = db.decode(CanFrame(0x100, b"\x07\x00"))      # the database's id, 2 of the message's 8 bytes
    assert short is not None and short.name == "EngineData" and short.signals == () and short.error
    assert db.decode(CanFrame(0x101, b"")) is None


def test_monitor_decodes_database_frames_before_canopen(tmp_path: Path) -> None:
    """A frame the database defines is its message (0x100 here, not CANopen TIME); others as before."""
    m = BusMonitor(signals=load_database(dbc(tmp_path)))
    (ev,) = m.feed(ENGINE, 1.0)
    assert ev.kind == "signal" and ev.text.startswith("EngineData: EngineSpeed=2000 rpm")
    assert ev.to_json()["signals"] == {"EngineSpeed": 2000.0, "Temperature": -56, "Gear": "Drive"}
    assert m.feed(CanFrame(0x080), 1.1)[0].kind == "sync"


def test_cli_views_and_plot_with_a_database(tmp_path: Path) -> None:
    """dump --db appends cantools decode's single-line form; monitor --plain --db prints the message;
    plot --db draws one panel per numeric signal (the arrays checked); a broken file is exit 2, one line."""
    trace = tmp_path / "car.log"
    speeds = [(4 * (1000 + 100 * k)).to_bytes(2, "little").hex() for k in range(5)]
    trace.write_text("".join(f"({1700000000 + k * 0.1:.6f}) can0 100#{speeds[k]}F00300000000\n" for k in range(5)))
    db = str(dbc(tmp_path))
    raw = gl("dump", "--replay", str(trace), "--db", db)
    assert raw.returncode == 0, raw.stderr
    assert raw.stdout.splitlines()[0] == ("  can0  100   [8]  A0 0F F0 03 00 00 00 00 :: EngineData(EngineSpeed: "
                                          "1000.0 rpm, Temperature: -56 degC, Gear: 'Drive')")
    plain = gl("monitor", "--replay", str(trace), "--plain", "--db", db)
    assert plain.stdout.splitlines()[-1].endswith("EngineData: EngineSpeed=1400 rpm, Temperature=-56 degC, Gear=Drive")
    picture = read_trace(trace, signals=load_database(db))
    speed = next(p for p in panels(picture) if p.ylabel == "EngineData.EngineSpeed\n[rpm]")
    assert speed.lines[0][2][:5] == (1000.0, 1100.0, 1200.0, 1300.0, 1400.0)
    bad = tmp_path / "bad.dbc"
    bad.write_text("BO_ this is not a dbc\n")
    out = gl("monitor", "--replay", str(trace), "--plain", "--db", str(bad))
    assert out.returncode == 2 and out.stderr.startswith(f"gatewaylab: {bad}: not a signal database")
    assert "\n" not in out.stderr.strip() and "Traceback" not in out.stderr


def test_web_page_decodes_signals(tmp_path: Path) -> None:
    """`gatewaylab run --web --db FILE`: the page's log shows the messages the database defines."""
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text('clock = "realtime"\n[[bus]]\nname = "can0"\nbitrate = 1000000\n')
    with RigProcess(rig_file, "--web", "--db", str(dbc(tmp_path)), "--acker", workdir=tmp_path, timeout=60) as rig:
        with can.Bus(interface="gatewaylab", channel=rig.endpoint("can0")) as bus:
            bus.send(ENGINE.to_message())
        deadline = time.monotonic() + 30
        while True:
            with urllib.request.urlopen(rig.info["web"]["monitor"] + "state", timeout=10) as r:
                log = json.loads(r.read())["log"]
            if any(e["kind"] == "signal" for e in log):
                break
            assert time.monotonic() < deadline, log
            time.sleep(0.1)
    assert next(e for e in log if e["kind"] == "signal")["text"] == \
        "EngineData: EngineSpeed=2000 rpm, Temperature=-56 degC, Gear=Drive"
