"""`gatewaylab monitor --json` event kinds (docs/monitor.md "JSON events"): a signal event says whether its
id is 29-bit (0x100 and the extended 0x100 are different frames, ISO 11898-1 identifier formats), and a
frame of a database id that does not fit its message is its own kind, ``undecodable``, with the frame and
cantools' reason -- not a signal named "(not decodable)". `dump --db` prints that reason as
``cantools decode`` does (`` :: REASON``)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from gatewaylab.bus import CanFrame
from gatewaylab.bus.signals import load_database
from gatewaylab.canopen.monitor import BusMonitor

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
#: candump -L lines: the 11-bit 0x100 (EngineData), the 29-bit 0x100 (Body), the 11-bit 0x100 with 2 of its
#: 8 bytes, a 29-bit id the database does not define
TRACE = """(1700000000.000000) can0 100#401FF00300000000
(1700000000.100000) can0 00000100#0700
(1700000000.200000) can0 100#0700
(1700000000.300000) can0 00000101#01
"""


def _files(tmp_path: Path) -> tuple[str, str]:
    (tmp_path / "car.dbc").write_text(DBC)
    (tmp_path / "car.log").write_text(TRACE)
    return str(tmp_path / "car.dbc"), str(tmp_path / "car.log")


def gl(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gatewaylab", *args], capture_output=True, text=True, timeout=120)


def test_json_events_tell_the_id_format_and_undecodable_frames(tmp_path: Path) -> None:
    """One JSON object per event: ``signal`` with ``extended`` false/true for the two ids 0x100,
    ``undecodable`` with id, extended, data, message and reason, ``frame`` (raw) with ``extended``."""
    db, trace = _files(tmp_path)
    out = gl("monitor", "--replay", trace, "--json", "--db", db)
    assert out.returncode == 0, out.stderr
    engine, body, short, other = (json.loads(line) for line in out.stdout.splitlines())
    assert (engine["kind"], engine["id"], engine["extended"], engine["message"]) == ("signal", 256, False, "EngineData")
    assert engine["signals"] == {"EngineSpeed": 2000.0, "Temperature": -56, "Gear": "Drive"}
    assert (body["kind"], body["id"], body["extended"], body["message"]) == ("signal", 256, True, "Body")
    assert body["signals"] == {"Doors": 7}
    assert (short["kind"], short["id"], short["extended"], short["data"], short["message"]) == \
        ("undecodable", 256, False, "0700", "EngineData")
    assert short["reason"] and "signals" not in short and "(not decodable)" not in out.stdout
    assert (other["kind"], other["id"], other["extended"], other["data"]) == ("frame", 0x101, True, "01")


def test_plain_and_dump_show_an_undecodable_frame_with_the_reason(tmp_path: Path) -> None:
    """--plain: the frame as candump prints it and why its message does not decode; dump --db: what
    `candump | cantools decode --single-line` prints for it (`` :: REASON``)."""
    db, trace = _files(tmp_path)
    reason = BusMonitor(signals=load_database(db)).feed(CanFrame(0x100, b"\x07\x00"), 0.0)[0].fields["reason"]
    plain = gl("monitor", "--replay", trace, "--plain", "--db", db).stdout.splitlines()
    assert plain[2].split("  ", 1)[1].strip() == f"100   [2]  07 00   (EngineData: not decodable ({reason}))"
    raw = gl("dump", "--replay", trace, "--db", db).stdout.splitlines()
    assert raw[2] == f"  can0       100   [2]  07 00 :: {reason}"      # indented: a 29-bit id came before
