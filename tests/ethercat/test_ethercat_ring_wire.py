"""Cable redundancy and open ports through ``gatewaylab run`` with SOEM (pysoem) in a namespace, the faults injected
with ``gatewaylab fault`` from another process (docs/faults.md, EtherCAT table).

ETG.1000.4 cable redundancy, as SOEM implements it (nicdrv.c ``ecx_outframe_red`` / ``ecx_waitinframe_red``): every
frame goes out on both interfaces; with the ring closed the primary frame passes every slave and comes back on the
secondary interface; with a break the slaves before it answer on the primary interface and SOEM sends the frame
again through the secondary one to the slaves after it -- the working counter stays whole. ET1100 register 0x0110:
a port without a link is closed (0x0400 for port 1), and on a line the slaves behind an open port vanish.

Two redundant masters: pysoem's ``Master.open(IF_A, IF_B)`` (``ecx_init_redundant``), counting every cycle, and
SOEM's own ``red_test`` sample (soem_samples.py red_test_redundant: as shipped in the pysoem 1.1.13 sdist it has
``ec_init_redundant`` commented out; the kit puts it back), whose printed working counters are sampled every
20 ms. Rule of the wire tests: a wrong working counter fails; a lost cycle (no frame within SOEM's 2 ms) is
counted and tolerated up to 2 %.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from soem_samples import build_soem_sample
from wire_kit import lost_allowed, net_capable, run_fault, veth_namespace, veth_namespace_two

from gatewaylab.rig.process import RigProcess

DRIVER = Path(__file__).with_name("ethercat_ring_driver.py")
CYCLES = 300

RIG = """
[[device]]
kind = "ethercat_io"
name = "io-a"
[[device]]
kind = "ethercat_io"
name = "io-b"
serial = 7
[[device]]
kind = "ethercat_io"
name = "io-c"
serial = 8
[[device]]
kind = "ethercat_io"
name = "io-d"
serial = 9
[ethercat]
interface = "{a}"
{redundant}
"""


class Driver:
    """The pysoem master in the namespace; phases run on request, their results read back."""

    def __init__(self, ns: str, if_a: str, if_b: str, workdir: Path) -> None:
        self.err = (workdir / "driver.err").open("wb")
        self.proc = subprocess.Popen(["ip", "netns", "exec", ns, sys.executable, str(DRIVER), if_a, if_b,
                                      str(CYCLES)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.err,
                                     text=True)
        self.err_path = workdir / "driver.err"

    def event(self, timeout: float = 120.0) -> dict[str, Any]:
        assert self.proc.stdout is not None
        box: list[str] = []
        reader = threading.Thread(target=lambda: box.append(self.proc.stdout.readline()), daemon=True)  # type: ignore[union-attr]
        reader.start()
        reader.join(timeout)
        assert box and box[0], f"the master said nothing: {self.err_path.read_text()[-3000:]}"
        event: dict[str, Any] = json.loads(box[0])
        return event

    def phase(self, name: str) -> dict[str, Any]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(name + "\n")
        self.proc.stdin.flush()
        event = self.event()
        assert event["ev"] == "phase" and event["name"] == name
        print(f"phase {name}: wkc {event['wkc']}, lost {event['lost']}/{event['cycles']}, dl "
              f"{[None if v is None else hex(v) for v in event['dl']]}")
        return event

    def close(self) -> None:
        if self.proc.poll() is None and self.proc.stdin is not None:
            with contextlib.suppress(OSError):
                self.proc.stdin.write("end\n")
                self.proc.stdin.close()
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.err.close()


def fault(rig: RigProcess, *args: str) -> dict[str, Any]:
    """``gatewaylab fault READY-FILE ...`` from another process, its JSON answer."""
    return run_fault(rig.ready_file, *args)


@contextlib.contextmanager
def rig_on_veth(workdir: Path, redundant: bool, extra: str = "") -> Iterator[tuple[RigProcess, str, str, str]]:
    """The 4-slave rig run by ``gatewaylab run`` on one veth pair (or two, ``redundant``): (rig, namespace, the
    master's end A, its end B or "-"); the rig must have logged no error."""
    reason = net_capable("pysoem")
    if reason is not None:
        pytest.skip(reason)
    pairs: Any = veth_namespace_two("gl-rr-", "glr") if redundant else veth_namespace("gl-rl-", "glr")
    with pairs as ends:
        ns, emu_a, mst_a = ends[:3]
        emu_b, mst_b = (ends[3], ends[4]) if redundant else ("", "-")
        path = workdir / "rig.toml"
        path.write_text(RIG.format(a=emu_a, redundant=f'redundant = "{emu_b}"' if redundant else "") + extra)
        with RigProcess(path, workdir=workdir, timeout=60) as rig:
            assert rig.info["ethercat"]["redundant"] == (emu_b or None)
            yield rig, ns, mst_a, mst_b
            log = rig.log_text()
            bad = [line for line in log.splitlines() if line.startswith(("ERROR", "CRITICAL", "Traceback"))]
            assert not bad, bad[:10]


@contextlib.contextmanager
def running(workdir: Path, redundant: bool, extra: str = "") -> Iterator[tuple[RigProcess, Driver]]:
    """:func:`rig_on_veth` with the pysoem master started on it."""
    with rig_on_veth(workdir, redundant, extra) as (rig, ns, mst_a, mst_b):
        driver = Driver(ns, mst_a, mst_b, workdir)
        try:
            yield rig, driver
        finally:
            driver.close()


def _partial(counts: dict[str, int], expected: int) -> int:
    """Cycles that read a part of the expected counter: SOEM sends a cycle's frame out of both ports and adds up
    the counters of the frames that came back, so while the ring is broken a frame lost on one side (dropped as
    late on this loaded machine) leaves the other side's part (seen: 6 of 12) -- a lost frame, counted with the
    lost cycles; a counter above the expected one, or none of them full, is a wrong answer."""
    assert all(0 < int(wkc) <= expected for wkc in counts if wkc != "-1"), f"wrong working counters: {counts}"
    return sum(n for wkc, n in counts.items() if wkc not in ("-1", str(expected)))


def _only_full(event: dict[str, Any], expected: int) -> None:
    partial = _partial(event["wkc"], expected)
    lost, cycles = event["lost"] + partial, event["cycles"]
    assert str(expected) in event["wkc"], f"no full working counter in {event['name']}: {event['wkc']}"
    assert lost <= lost_allowed(cycles), f"{lost} of {cycles} cycles lost in {event['name']}"


def test_redundant_master_keeps_every_working_counter_across_a_ring_break(tmp_path: Path) -> None:
    """SOEM with two interfaces on a redundant rig of 4 slaves: closed ring, broken after io-b, healed -- every
    cycle that got its frames back has the full working counter (0 wrong), those while the ring breaks and heals
    included (a frame lost on one side is a lost cycle, :func:`_partial`); while broken,
    io-b's port 1 and io-c's port 0 show no link and closed loops in DL status 0x0110, and all 4 slaves stay in
    OP."""
    with running(tmp_path, redundant=True) as (rig, driver):
        op = driver.event()
        assert op["ev"] == "op" and op["count"] == 4 and op["op"] == 8, op
        expected = op["expected_wkc"]
        assert op["dl"][3] & 0x0F30 == 0x0A30      # the last slave's port 1 is cabled to the secondary interface
        _only_full(driver.phase("closed"), expected)
        answer = fault(rig, "ec-ring-break", "io-b")
        assert (answer["primary"], answer["secondary"]) == (["io-a", "io-b"], ["io-c", "io-d"])
        broken = driver.phase("broken")
        _only_full(broken, expected)
        assert broken["dl"][1] & 0x0F30 == 0x0610 and broken["dl"][2] & 0x0F30 == 0x0920
        assert broken["states"] == [8, 8, 8, 8]
        healed = fault(rig, "ec-ring-heal")
        assert healed["healed"] == ["io-b"] and healed["primary_returns_on"] == "secondary"
        healed_phase = driver.phase("healed")
        _only_full(healed_phase, expected)
        assert healed_phase["dl"][1] & 0x0F30 == 0x0A30
        # every cycle since OP, the ones while the faults were injected and cleared included (between phases)
        every = healed_phase["every"]
        print(f"every cycle since OP: {every}")
        total = sum(every.values())
        lost = every.get("-1", 0) + _partial(every, expected)
        assert lost <= lost_allowed(total), f"{lost} of {total} cycles lost: {every}"


def test_open_port_on_a_line_hides_the_slaves_behind_it_until_it_closes(tmp_path: Path) -> None:
    """SOEM with one interface on a line of 4: ec-port-open io-b 1 -- the LRW working counter drops to what io-a and
    io-b contribute, io-c and io-d no longer answer (FPRD of 0x0110: no reply), io-b's DL status shows port 1
    closed without link; ec-clear closes the port and, after the master's usual recovery, the full working counter
    is back without restarting the rig."""
    with running(tmp_path, redundant=False) as (rig, driver):
        op = driver.event()
        assert op["ev"] == "op" and op["count"] == 4 and op["op"] == 8, op
        expected = op["expected_wkc"]
        _only_full(driver.phase("line"), expected)
        answer = fault(rig, "ec-port-open", "io-b", "1")
        assert answer["primary"] == ["io-a", "io-b"]
        opened = driver.phase("open")
        assert set(opened["wkc"]) == {str(expected // 2)}, opened["wkc"]     # 2 of 4 identical slaves answer
        assert opened["dl"][2:] == [None, None] and opened["dl"][1] & 0x0F30 == 0x0610
        ended = fault(rig, "ec-clear")
        assert [e["fault"] for e in ended["ended"]] == ["ec-port-open"]
        back = driver.phase("recover")
        _only_full(back, expected)
        assert back["states"] == [8, 8, 8, 8] and back["dl"][1] & 0x0F30 == 0x0A30



def test_hot_connect_group_leaves_and_rejoins_under_a_cycling_master(tmp_path: Path) -> None:
    """SOEM with one interface, ``hot_connect = "io-b, io-d"`` (io-b heads io-b + io-c): ec-hot-unplug io-b -- the
    LRW working counter drops to io-a's and io-d's share while io-d keeps answering (the line joined around the
    group), io-b and io-c answer no register read; ec-hot-plug io-b -- the group is back in INIT without station
    address, and SOEM's own recovery (ecx_recover_slave: the address again by position, ecx_reconfig_slave) brings
    all 4 to OP with the full working counter, the rig never restarted."""
    with running(tmp_path, redundant=False, extra='hot_connect = "io-b, io-d"\n') as (rig, driver):
        op = driver.event()
        assert op["ev"] == "op" and op["count"] == 4 and op["op"] == 8, op
        expected = op["expected_wkc"]
        _only_full(driver.phase("line"), expected)
        answer = fault(rig, "ec-hot-unplug", "io-b")
        assert answer["group"] == ["io-b", "io-c"] and answer["primary"] == ["io-a", "io-d"]
        out = driver.phase("unplugged")
        assert set(out["wkc"]) == {str(expected // 2)}, out["wkc"]
        assert out["dl"][1:3] == [None, None] and out["dl"][0] is not None and out["dl"][3] is not None
        fault(rig, "ec-hot-plug", "io-b")
        back = driver.phase("recover-hot")
        _only_full(back, expected)
        assert back["states"] == [8, 8, 8, 8]


#: red_test's cycle in microseconds (its third argument)
RED_CYCLE_US = 1000
#: red_test's status lines (one each 20 ms) to see in each state of the ring
RED_SAMPLES = 40


class RedTest:
    """SOEM's red_test in the namespace, its output (status lines end in carriage returns) collected as it comes."""

    def __init__(self, program: Path, ns: str, if_a: str, if_b: str) -> None:
        self.proc = subprocess.Popen(["ip", "netns", "exec", ns, str(program), if_a, if_b, str(RED_CYCLE_US)],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        self.text = ""
        self.cond = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        while chunk := os.read(fd, 4096):
            with self.cond:
                self.text += chunk.decode("latin-1")
                self.cond.notify_all()
        with self.cond:
            self.cond.notify_all()

    def wait(self, done: Callable[[str], bool], timeout: float, what: str) -> None:
        with self.cond:
            ok = self.cond.wait_for(lambda: done(self.text) or self.proc.poll() is not None, timeout)
            assert ok and done(self.text), f"red_test: no {what}: {self.text[-3000:]}"

    def samples(self) -> list[int]:
        """The working counters of red_test's status lines since all slaves reached OP, once its cycle thread has
        received a frame (the line prints its cycle count: 1 until the first cycle completes, the counter then
        still its initial 0)."""
        with self.cond:
            after = self.text.partition("Operational state reached for all slaves.")[2]
        return [int(wkc) for cycle, wkc in re.findall(r"Processdata cycle\s+(\d+)\s*, Wck\s+(-?\d+)", after)
                if int(cycle) > 1]

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(30)


def test_soem_red_test_keeps_its_working_counter_across_a_ring_break(tmp_path: Path) -> None:
    """SOEM's red_test (cycle 1 ms, SOEM's own check thread) on a redundant rig of 4 slaves: the working counter it
    prints is its calculated one in every sample with the ring closed, broken after io-b and healed, and its check
    thread never finds a slave out of OP or lost."""
    program = build_soem_sample("red_test_redundant")
    with rig_on_veth(tmp_path, redundant=True) as (rig, ns, mst_a, mst_b):
        red = RedTest(program, ns, mst_a, mst_b)
        try:
            red.wait(lambda t: "Operational state reached for all slaves." in t, 180, "OP")
            expected = int(re.findall(r"Calculated workcounter (\d+)", red.text)[0])
            assert "4 slaves found and configured" in red.text
            red.wait(lambda t: len(red.samples()) >= RED_SAMPLES, 60, "status lines (closed ring)")
            fault(rig, "ec-ring-break", "io-b")
            red.wait(lambda t: len(red.samples()) >= 2 * RED_SAMPLES, 60, "status lines (broken ring)")
            fault(rig, "ec-ring-heal")
            red.wait(lambda t: len(red.samples()) >= 3 * RED_SAMPLES, 60, "status lines (healed ring)")
        finally:
            red.stop()
        samples = red.samples()
        lost = samples.count(-1)
        print(f"red_test: {len(samples)} samples, expected working counter {expected}, lost {lost}")
        assert [v for v in samples if v not in (expected, -1)] == [], samples
        assert lost <= lost_allowed(len(samples)), f"{lost} of {len(samples)} samples lost"
        assert not re.search(r"ERROR :|slave \d+ lost|SAFE_OP", red.text), red.text[-3000:]
