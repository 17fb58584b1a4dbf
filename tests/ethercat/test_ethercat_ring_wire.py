"""Cable redundancy and open ports through ``gatewaylab run`` with SOEM (pysoem) in a namespace, the faults injected
with ``gatewaylab fault`` from another process (docs/faults.md, EtherCAT table).

ETG.1000.4 cable redundancy, as SOEM implements it (nicdrv.c ``ecx_outframe_red`` / ``ecx_waitinframe_red``): every
frame goes out on both interfaces; with the ring closed the primary frame passes every slave and comes back on the
secondary interface; with a break the slaves before it answer on the primary interface and SOEM sends the frame
again through the secondary one to the slaves after it -- the working counter stays whole. ET1100 register 0x0110:
a port without a link is closed (0x0400 for port 1), and on a line the slaves behind an open port vanish.

SOEM's own ``red_test`` sample (test/linux/red_test) as shipped in the pysoem 1.1.13 sdist calls ``ec_init`` with
``ec_init_redundant`` commented out, so it never opens its second interface: pysoem's ``Master.open(IF_A, IF_B)``
(``ecx_init_redundant``) is the redundant master here. Rule of the wire tests: a wrong working counter fails; a lost
cycle (no frame within SOEM's 2 ms) is counted and tolerated up to 2 %.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from wire_kit import net_capable, veth_namespace, veth_namespace_two

from gatewaylab.rig.process import RigProcess

DRIVER = Path(__file__).with_name("ethercat_ring_driver.py")
CYCLES = 300
#: lost cycles tolerated per phase (the helpers' rule: 2 %)
LOST_OK = CYCLES * 2 // 100

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
    done = subprocess.run([sys.executable, "-m", "gatewaylab", "fault", str(rig.ready_file), "--json", *args],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    answer: dict[str, Any] = json.loads(done.stdout)
    return answer


@contextlib.contextmanager
def running(workdir: Path, redundant: bool) -> Iterator[tuple[RigProcess, Driver]]:
    reason = net_capable("pysoem")
    if reason is not None:
        pytest.skip(reason)
    pairs: Any = veth_namespace_two("gl-rr-", "glr") if redundant else veth_namespace("gl-rl-", "glr")
    with pairs as ends:
        ns, emu_a, mst_a = ends[:3]
        emu_b, mst_b = (ends[3], ends[4]) if redundant else ("", "-")
        path = workdir / "rig.toml"
        path.write_text(RIG.format(a=emu_a, redundant=f'redundant = "{emu_b}"' if redundant else ""))
        with RigProcess(path, workdir=workdir, timeout=60) as rig:
            assert rig.info["ethercat"]["redundant"] == (emu_b or None)
            driver = Driver(ns, mst_a, mst_b, workdir)
            try:
                yield rig, driver
            finally:
                driver.close()
                log = rig.log_text()
                bad = [line for line in log.splitlines() if line.startswith(("ERROR", "CRITICAL", "Traceback"))]
                assert not bad, bad[:10]


def _only_full(event: dict[str, Any], expected: int) -> None:
    assert set(event["wkc"]) <= {str(expected)}, f"wrong working counters in {event['name']}: {event['wkc']}"
    assert event["lost"] <= LOST_OK, f"{event['lost']} of {event['cycles']} cycles lost in {event['name']}"


def test_redundant_master_keeps_every_working_counter_across_a_ring_break(tmp_path: Path) -> None:
    """SOEM with two interfaces on a redundant rig of 4 slaves: closed ring, broken after io-b, healed -- every
    cycle has the full working counter (0 wrong), those while the ring breaks and heals included; while broken,
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
        assert set(every) <= {str(expected), "-1"}, f"wrong working counters across break and heal: {every}"
        assert every.get("-1", 0) <= total * 2 // 100, f"{every.get('-1')} of {total} cycles lost"


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
