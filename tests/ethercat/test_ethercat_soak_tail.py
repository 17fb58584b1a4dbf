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
from benchmarks.capture import RECORD, Pair, Record, Tail, cycle_tag, explain_late, frame_key, pairs, tail_of
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


def _image_start(plan: object, cycle: int) -> bytes:
    """The first 8 bytes of the LRW the bench's master sends in ``cycle``: SOEM maps every slave's outputs
    before the inputs, in segment order; an io's outputs (5 bytes) carry the cycle tag."""
    assert isinstance(plan, type(SOAK_PLAN))
    head = b""
    for kind in plan.kinds():
        if kind != "io" or len(head) >= 8:
            break
        head += cycle_tag(cycle, 5)
    return head[:8]


@pytest.mark.parametrize("plan", [SOAK_PLAN, MIXED_PLAN], ids=["soak", "mixed"])
def test_after_a_stall_each_fresh_reply_pairs_with_its_own_request(plan: object) -> None:
    """Issue 31 benchmark, 'after a 200 ms stall: 0 replies older than the configured limit reach the
    master'. During the stall SOEM sends a request a cycle (its 16 frame indexes in turn) and the slaves
    leave OP (SM watchdog, SAFEOP + 0x001B), so the ECAN-Lite's image and the slaves' inputs stay constant;
    the rig drops what waited (never answered) and answers the fresh requests within 100 us. An LRW
    carries its outputs back as written (ETG.1000.4 logical addressing: only the input areas are filled in
    on the way), so the master's cycle number at the image's start makes each key unique: every fresh reply
    pairs with its own request (100 us, exact), none with a request of the pause -- the old pairing took
    the oldest request of the same index and data, and counted 1191 stale replies."""
    records = []
    for cycle in range(1000, 1100):                     # the stall: nothing answered
        records.append((cycle * MS, True, key(cycle % 16, _image_start(plan, cycle))))
    for cycle in range(1100, 1200):                     # after it: each answered in 100 us
        k = key(cycle % 16, _image_start(plan, cycle))
        records += [(cycle * MS, True, k), (cycle * MS + 100_000, False, k)]
    got = list(pairs(records, True))
    assert [p.t_request for p in got] == [c * MS for c in range(1000, 1200)]
    assert all(p.t_reply is None for p in got[:100])
    assert [p.delay_us for p in got[100:]] == [100.0] * 100
    assert not any(p.ambiguous for p in got)
    tail = Tail((2000.0,))
    for p in got:
        tail.add(p)
    assert (tail.unanswered, tail.over.get(2000.0, 0), tail.ambiguous) == (100, 0, 0)


def test_identical_waiting_requests_make_a_pair_ambiguous_not_stale() -> None:
    """A master that writes no tag (a constant image after the stall): a fresh reply matches every waiting
    request of its index and data, so which one it answers is not known; the pair is the oldest's but marked
    ambiguous (counted by Tail), never taken as a measured stale reply."""
    const = bytes(8)
    records = [(c * MS, True, key(c % 16, const)) for c in range(0, 32)]
    records += [(32 * MS, True, key(0, const)), (32 * MS + 100_000, False, key(0, const))]
    got = list(pairs(records, True))
    answered = [p for p in got if p.t_reply is not None]
    assert len(answered) == 1 and answered[0].ambiguous
    tail = Tail((2000.0,))
    for p in got:
        tail.add(p)
    assert tail.ambiguous == 1


def test_the_cycle_tag_is_unique_and_fits_an_io() -> None:
    """capture.cycle_tag: 32 bits of the cycle in the io's 5 output bytes (digital u8 + two int16)."""
    tags = {cycle_tag(n, 5) for n in range(0, 1 << 16)}
    assert len(tags) == 1 << 16 and all(len(t) == 5 for t in tags)
    assert cycle_tag(0x01020304, 5) == b"\x04\x03\x02\x01\x00" and cycle_tag(7, 2) == b"\x07\x00"
    assert SOAK_PLAN.kinds()[0] == MIXED_PLAN.kinds()[0] == "io"


def _write(path: Path, records: list[Record]) -> Path:
    path.write_bytes(b"".join(RECORD.pack(t, int(out), k) for t, out, k in records))
    return path


def test_a_frame_the_rig_held_when_it_stopped_counts_for_the_stall(tmp_path: Path) -> None:
    """A request that reached the rig 0.3 ms before the SIGSTOP, taken by the wire thread and answered after
    the SIGCONT, reaches the master 200 ms old (seen in a bench run): a stale reply of the stall, so the
    stall's window starts before the stop, and explain_late says where it waited (the emulator's capture:
    in before the stop, out after it -- the rig held it)."""
    t0 = 10_000 * MS
    k = key(5, _image_start(SOAK_PLAN, 9999))
    master = _write(tmp_path / "m.cap", [(t0 - 300_000, True, k), (t0 + 200 * MS + 400_000, False, k)])
    emulator = _write(tmp_path / "e.cap", [(t0 - 280_000, False, k), (t0 + 200 * MS + 380_000, True, k)])
    r = LineResult(SOAK_PLAN, "quiet", 3000, 2.0, True, stall=(t0, t0 + 200 * MS))
    window = r.stall_window()
    assert window is not None
    assert tail_of(master, True, (2000.0,), False, *window).over == {2000.0: 1}
    notes = explain_late(master, emulator, 2000.0, *window, t0)
    assert notes == ["reply older than 2 ms: request sent at -0.3 ms, answered after 200.7 ms; on the emulator's "
                     "end in at -0.3 ms, out at +200.4 ms (residence 200.7 ms: the rig held it)"]
    vm = _write(tmp_path / "v.cap", [(t0 - 280_000, False, k), (t0 - 180_000, True, k)])
    assert explain_late(master, vm, 2000.0, *window, t0)[0].endswith("(residence 0.1 ms: the VM delayed it)")


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
