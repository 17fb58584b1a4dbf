"""``make soak-ethercat`` and ``bench_ethercat_tail`` without a veth pair: the command line, the rig files
they give ``gatewaylab run``, the pairing of captured requests and replies, the classification of a failed
bring-up and the printed report (docs/performance.md "The EtherCAT wire's tail")."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from benchmarks.bench_ethercat_tail import MIXED_PLAN, classify
from benchmarks.capture import Pair, Tail, frame_key, pairs
from benchmarks.soak_ethercat import SOAK_PLAN, LineResult, parse_args, report, residence_limit_ms, rig_toml
from gatewaylab.rig.config import parse_rig

MS = 1_000_000  # ns


def key(index: int, data: bytes = b"\0" * 8, cmd: int = 12) -> bytes:
    """The key of a frame whose first datagram is ``cmd`` with frame index ``index`` and ``data``."""
    frame = bytes(12) + b"\x88\xa4" + b"\x1c\x10" + bytes([cmd, index]) + b"\0\0\0\0" + b"\x10\0\0\0" + data
    return frame_key(frame)


def test_soak_minutes_come_from_soak_minutes_like_make_soak(monkeypatch: pytest.MonkeyPatch) -> None:
    """`SOAK_MINUTES=60 make soak-ethercat` runs an hour, as `make soak` does; --set passes [ethercat] keys."""
    monkeypatch.setenv("SOAK_MINUTES", "60")
    args = parse_args(["--set", "busy_poll=true", "--set", "max_residence_ms = 0"])
    assert args.minutes == 60 and args.load == "quiet"
    assert args.ethercat == {"busy_poll": "true", "max_residence_ms": "0"}
    assert parse_args(["--minutes", "0.5", "--load", "loaded"]).minutes == 0.5


@pytest.mark.parametrize("argv", [["--minutes", "0"], ["--set", "busy_poll"], ["--load", "busy"]])
def test_a_wrong_command_line_is_one_argparse_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        parse_args(argv)
    assert exc.value.code == 2 and "error:" in capsys.readouterr().err


@pytest.mark.parametrize("plan", [SOAK_PLAN, MIXED_PLAN], ids=["soak", "mixed"])
def test_the_rig_files_are_valid_rigs(plan: object) -> None:
    """docs/rig.md: every section is checked before anything is created. The soak's and the bench's rig
    files pass that check with this gatewaylab (max_residence_ms written only where the rig knows it),
    their EtherCAT devices in the order the master expects."""
    assert isinstance(plan, type(SOAK_PLAN))
    text = rig_toml(plan, "gl-x0", residence_limit_ms())
    parse_rig(tomllib.loads(text))
    kinds = [d["kind"] for d in tomllib.loads(text)["device"]]
    names = {"ecanlite": "ecanlite", "esd": "esd_can_ethercat", "drive": "ethercat_drive", "io": "ethercat_io"}
    assert kinds == [names[k] for k in plan.kinds()]


def test_a_reply_belongs_to_the_request_its_data_came_back_from() -> None:
    """A segment answers in order (ETG.1000.3: a frame passes the slaves and returns); SOEM reuses its 16
    frame indexes, so after a dropped request the next reply of that index belongs to the later request
    whose outputs it carries, and the dropped one was never answered."""
    a, b = key(3, b"\x01" * 8), key(3, b"\x02" * 8)
    records = [(0, True, a), (16 * MS, True, b), (17 * MS, False, b)]
    assert list(pairs(records, True)) == [Pair(0, None, a), Pair(16 * MS, 17 * MS, b)]


def test_a_read_reply_pairs_with_the_first_request_of_its_header() -> None:
    """A read's data changes on the way (FPRD): the first waiting request with the datagram header."""
    req, rep = key(5, bytes(8), cmd=4), key(5, b"\x08" + bytes(7), cmd=4)
    records = [(0, False, req), (MS // 10, True, rep), (2 * MS, False, req)]
    got = list(pairs(records, False))
    assert got == [Pair(0, MS // 10, req), Pair(2 * MS, None, req)]
    assert got[0].delay_us == 100.0


def test_classify_says_where_a_failed_bring_up_lost_its_frame() -> None:
    """Each failed bring-up explained (docs/performance.md): lost by the VM, dropped or late from the
    emulator, late in the VM, or neither (the master's own timing)."""
    k = key(1, cmd=4)
    master = [Pair(10 * MS, None, k)]
    assert classify(0, 20 * MS, master, []).startswith("lost by the VM")
    assert classify(0, 20 * MS, master, [Pair(10 * MS + 5000, None, k)]).startswith("dropped by the emulator")
    late = classify(0, 20 * MS, master, [Pair(10 * MS + 5000, 13 * MS, k)])
    assert late.startswith("late from the emulator") and "2995 us" in late
    vm = classify(0, 20 * MS, [Pair(10 * MS, 13 * MS, k)], [Pair(10 * MS, 10 * MS + 80_000, k)])
    assert vm.startswith("late in the VM") and "80 us" in vm
    assert classify(0, 20 * MS, [Pair(10 * MS, 10 * MS + 90_000, k)], []).startswith("no frame lost or late")


def test_the_report_names_every_count() -> None:
    """The soak prints wrong working counters, late replies on the master's wire and the rig's dropped-late
    frames; a rig without the counter says so instead of printing 0."""
    tail = Tail((2000.0, 5000.0), keep=True)
    for t, d in ((0, 300), (MS, 2500), (2 * MS, 7000)):
        tail.add(Pair(t, t + d * 1000, key(t // MS)))
    tail.add(Pair(3 * MS, None, key(3)))
    r = LineResult(SOAK_PLAN, "loaded", 4, 5.0, False, master={"cycles": 4, "wrong_wkc": 2, "first_wrong": [1, 3]},
                   master_tail=tail, residence=tail)
    text = report(r)
    assert "soak-ethercat (loaded)" in text and "wrong working counters: 2 (first at cycles [1, 3])" in text
    assert "late replies (master's capture): 2 after 2 ms, 1 after 5 ms; never answered 1 of 4 frames" in text
    assert "dropped late by the rig: not reported by this rig (limit 5 ms (this rig has no max_residence_ms))" in text
    r.counters = {"frames_dropped_late": 7}
    r.limit_configurable = True
    assert "dropped late by the rig: 7 (limit max_residence_ms 5)" in report(r)
