"""Distributed-clock faults and the DC model behind them, on a simulated clock with the in-process master doing
what SOEM does (ethercat_dc_kit.py: ecx_configdc, then FRMW of 0x0910 in every cycle).

ET1100 data sheet section I "Distributed Clocks" / section II registers 0x0900-0x0935 (ETG.1000.4 DC):
- a write to 0x0900 latches every port's receive time; a master takes a slave's propagation delay as half the
  difference of round trips (port 1 - port 0 receive times) of its parent and itself;
- a write to 0x0910 is compared with the local copy of the system time (+ the delay in 0x0928); the time
  control loop adjusts the local clock's speed; 0x092C holds the mean difference (bit 31: local copy smaller
  than the received time), 0x0932 the speed counter's deviation; a write to 0x0930 resets both.
"""

from __future__ import annotations

import itertools
import struct
from pathlib import Path

import pytest
from ethercat_dc_kit import MASTER_TIME_NS, compensate, config_dc, reset_dc, time_difference

from gatewaylab.cli.fault import build_request
from gatewaylab.cli.main import build_parser
from gatewaylab.common.clock import SimulatedClock
from gatewaylab.common.errors import ConfigError
from gatewaylab.ethercat.datagram import Command, Datagram
from gatewaylab.ethercat.esc import REG_DC_SYSTEM_DELAY, REG_DC_SYSTEM_TIME
from gatewaylab.ethercat.esc_dc import REG_DC_SPEED_DIFF, REG_DC_SPEED_START, REG_DC_TIME_DIFF
from gatewaylab.ethercat.esc_dc_clock import CABLE_NS_PER_M, FORWARD_NS, LOOP_LIMIT_PPM
from gatewaylab.ethercat.segment import Segment
from gatewaylab.hosts.ethercat.master import Master
from gatewaylab.rig.faults_core import FaultRefused
from gatewaylab.rig.runtime import Rig

RIG = """
clock = "simulated"
[[device]]
kind = "ethercat_io"
name = "io0"
[[device]]
kind = "ethercat_io"
name = "io1"
serial = 7
[[device]]
kind = "ethercat_io"
name = "io2"
serial = 8
[ethercat]
interface = "gl-none"
"""


def _rig(tmp_path: Path, extra: str = "") -> tuple[Rig, SimulatedClock, Segment, Master]:
    path = tmp_path / "rig.toml"
    path.write_text(RIG + extra)
    rig = Rig.from_file(path)
    rig.start()
    segment = next(p for p in rig.participants if p.name == "ethercat").segment  # type: ignore[attr-defined]
    assert isinstance(rig.clock, SimulatedClock)
    m = Master(rig.clock, segment)
    m.bring_up()
    reset_dc(m)
    return rig, rig.clock, segment, m


def _system_time(m: Master, position: int) -> int:
    return int(struct.unpack("<Q", m.fprd(m.slaves[position].station, REG_DC_SYSTEM_TIME, 8))[0])


def test_propagation_delays_follow_the_cable_lengths(tmp_path: Path) -> None:
    """2 m cables, 10 m into io2: SOEM's measurement (half the round-trip differences from the 0x0900 latches)
    gives each slave the time a frame takes from the first slave to it -- one ESC pass (FORWARD_NS) plus
    5 ns per metre per hop -- and writes it to 0x0928."""
    rig, _clock, _segment, m = _rig(tmp_path, 'cable_m = 2.0\ncables_m = "io2=10"\n')
    with rig:
        delays = config_dc(m)
        hop1 = FORWARD_NS + 2.0 * CABLE_NS_PER_M
        hop2 = FORWARD_NS + 10.0 * CABLE_NS_PER_M
        assert delays == [0, round(hop1), round(hop1 + hop2)]
        for i, d in enumerate(delays[1:], 1):
            assert struct.unpack("<I", m.fprd(m.slaves[i].station, REG_DC_SYSTEM_DELAY, 4))[0] == d


def test_bad_cable_lengths_are_refused(tmp_path: Path) -> None:
    for extra in ('cables_m = "nobody=3"\n', 'cables_m = "io1=much"\n', "cable_m = -1.0\n"):
        path = tmp_path / "rig.toml"
        path.write_text(RIG + extra)
        with pytest.raises(ConfigError):
            Rig.from_file(path).start()


def test_no_fault_compensation_keeps_every_difference_at_zero(tmp_path: Path) -> None:
    """Good crystals, delays measured: after the master's DC setup the differences settle at 0 ns and the
    system times of all slaves read alike (each read at the time the frame reaches it, minus its delay)."""
    rig, clock, _segment, m = _rig(tmp_path)
    with rig:
        delays = config_dc(m)
        compensate(m, clock, 100)
        assert [time_difference(m, i) for i in range(3)] == [0, 0, 0]
        frame = m.exchange([Datagram.physical(Command.FPRD, 0, s.station, REG_DC_SYSTEM_TIME, bytes(8))
                            for s in m.slaves])
        times = [struct.unpack("<Q", d.data)[0] for d in frame]
        assert [t - d for t, d in zip(times, delays, strict=True)] == [times[0]] * 3
        assert times[0] > MASTER_TIME_NS


def test_a_drift_within_the_loop_converges_and_ec_clear_ends_it(tmp_path: Path) -> None:
    """ec-dc-drift io1 100: without compensation io1's system time runs away from io0's by 100 ns per ms;
    with the FRMW of every cycle the loop follows: |0x092C| ends at <= 1 ns, 0x0932 shows a slowed clock. The
    fault is on the board until ec-clear; afterwards the loop follows back to a good crystal."""
    rig, clock, _segment, m = _rig(tmp_path)
    with rig:
        config_dc(m)
        compensate(m, clock, 100)                              # settled: no correction left
        answer = rig.faults.ec_dc_drift("io1", 100.0)
        assert answer["fault"] == "ec-dc-drift" and answer["position"] == 1 and answer["ppm"] == 100.0
        board = rig.faults.ethercat_states()["faults"]
        assert board == [{"id": answer["id"], "fault": "ec-dc-drift", "target": "io1", "ppm": 100.0}]
        before = _system_time(m, 1) - _system_time(m, 0)
        clock.advance(0.010)                                   # 10 ms without compensation: 1000 ns apart
        assert abs(_system_time(m, 1) - _system_time(m, 0) - before - 1000) <= 1   # (ns rounding)
        compensate(m, clock, 300)
        assert abs(time_difference(m, 1)) <= 1 and time_difference(m, 2) == 0
        speed = struct.unpack("<h", m.fprd(m.slaves[1].station, REG_DC_SPEED_DIFF, 2))[0]
        assert speed < 0                                       # running fast: slowed down
        ended = rig.faults.ec_clear("io1")["ended"]
        assert [e["fault"] for e in ended] == ["ec-dc-drift"] and rig.faults.ethercat_states()["faults"] == []
        compensate(m, clock, 300)
        assert abs(time_difference(m, 1)) <= 1
        assert struct.unpack("<h", m.fprd(m.slaves[1].station, REG_DC_SPEED_DIFF, 2))[0] == 0


def test_static_drift_compensation_with_armw_bursts(tmp_path: Path) -> None:
    """Static drift compensation as masters do it before the cycle starts (the QEC master's
    StaticDriftCompensationFrames: many separate ARMW frames of 0x0910 from the reference): frames 100 us apart
    bring a 300 ppm slave to |0x092C| <= 1 ns; ARMW reads the reference (position 0) and writes the others."""
    rig, clock, _segment, m = _rig(tmp_path)
    with rig:
        rig.faults.ec_dc_drift("io2", 300.0)
        clock.advance(0.5)
        config_dc(m)                                           # offsets first, as masters do
        compensate(m, clock, 1, period=0.010, command=Command.ARMW)
        assert time_difference(m, 2) > 1000                    # 3000 ns gained in 10 ms, less its 1010 ns delay
        compensate(m, clock, 2000, period=0.0001, command=Command.ARMW)
        assert abs(time_difference(m, 2)) <= 1 and time_difference(m, 1) == 0


def test_a_drift_beyond_the_loop_makes_the_difference_grow(tmp_path: Path) -> None:
    """ec-dc-drift io2 -2000: the loop speeds io2 up by at most LOOP_LIMIT_PPM, so 0x092C grows by the rest,
    (2000 - 500) ns per ms of compensation, negative (bit 31: io2's local copy is behind)."""
    rig, clock, _segment, m = _rig(tmp_path)
    with rig:
        config_dc(m)
        compensate(m, clock, 20)
        rig.faults.ec_dc_drift("io2", -2000.0)
        seen = []
        for _ in range(5):
            compensate(m, clock, 20)
            seen.append(time_difference(m, 2))
        steps = [b - a for a, b in itertools.pairwise(seen)]
        assert steps == [round(-(2000 - LOOP_LIMIT_PPM) * 20 * 1e-3 * 1e3)] * 4   # -30000 ns per 20 ms
        raw = struct.unpack("<I", m.fprd(m.slaves[2].station, REG_DC_TIME_DIFF, 4))[0]
        assert raw & 0x80000000 and raw & 0x7FFFFFFF == -seen[-1]
        rig.faults.ec_clear()
        compensate(m, clock, 400)
        assert abs(time_difference(m, 2)) <= 1


def test_a_jump_stays_visible_until_the_master_reinitialises_dc(tmp_path: Path) -> None:
    """ec-dc-jump io1 5 ms: 0x092C shows +5 ms at the next compensation; the loop slews it out at no more than
    LOOP_LIMIT_PPM (100 ms of compensation: at most 50 us); a new ec_configdc (offsets 0x0920) removes it."""
    rig, clock, _segment, m = _rig(tmp_path)
    with rig:
        config_dc(m)
        compensate(m, clock, 20)
        answer = rig.faults.ec_dc_jump("io1", 5_000_000)
        assert answer["fault"] == "ec-dc-jump" and "id" not in answer
        assert rig.faults.ethercat_states()["faults"] == []    # once: nothing stays in force
        compensate(m, clock, 1)
        assert 5_000_000 - 1000 <= time_difference(m, 1) <= 5_000_000 + 1000
        compensate(m, clock, 100)
        assert time_difference(m, 1) >= 5_000_000 - LOOP_LIMIT_PPM * 1e-6 * 0.101e9 - 1000
        config_dc(m)
        compensate(m, clock, 100)
        assert abs(time_difference(m, 1)) <= 1


def test_speed_counter_start_resets_the_loop_and_power_on_too(tmp_path: Path) -> None:
    """A write to 0x0930 resets 0x092C and 0x0932 (ET1100 section II, 0x0930); so does a power cycle."""
    rig, clock, segment, m = _rig(tmp_path)
    with rig:
        config_dc(m)
        rig.faults.ec_dc_drift("io1", -3000.0)
        compensate(m, clock, 20)
        station = m.slaves[1].station
        assert time_difference(m, 1) != 0 and m.fprd(station, REG_DC_SPEED_DIFF, 2) != b"\0\0"
        m.fpwr(station, REG_DC_SPEED_START, struct.pack("<H", 0x1000))
        assert time_difference(m, 1) == 0 and m.fprd(station, REG_DC_SPEED_DIFF, 2) == b"\0\0"
        assert segment.slaves[1].esc.clocks.local.correction_ppm == 0.0
        compensate(m, clock, 5)
        segment.slaves[1].esc.power_cycle()
        assert segment.slaves[1].esc.clocks.local.correction_ppm == 0.0
        assert segment.slaves[1].esc.clocks.local.drift_ppm == -3000.0   # the crystal is still bad


def test_refused_requests(tmp_path: Path) -> None:
    rig, _clock, _segment, _m = _rig(tmp_path)
    with rig:
        with pytest.raises(FaultRefused, match="ppm"):
            rig.faults.request({"fault": "ec-dc-drift", "device": "io1", "ppm": 1e6})
        with pytest.raises(FaultRefused, match="no device"):
            rig.faults.request({"fault": "ec-dc-drift", "device": "nobody", "ppm": 10})
        with pytest.raises(FaultRefused, match="ns must be int"):
            rig.faults.request({"fault": "ec-dc-jump", "device": "io1", "ns": 1.5})
        first = rig.faults.request({"fault": "ec-dc-drift", "device": "io1", "ppm": 10})
        second = rig.faults.request({"fault": "ec-dc-drift", "device": "io1", "ppm": 20})
        assert [e["id"] for e in rig.faults.ethercat_states()["faults"]] == [second["id"]] != [first["id"]]


def test_cli_verbs_build_the_requests() -> None:
    parser = build_parser()
    args = parser.parse_args(["fault", "r.json", "ec-dc-drift", "io1", "-25.5"])
    assert build_request(args) == {"fault": "ec-dc-drift", "device": "io1", "ppm": -25.5}
    args = parser.parse_args(["fault", "r.json", "ec-dc-jump", "io1", "--", "-0x10"])
    assert build_request(args) == {"fault": "ec-dc-jump", "device": "io1", "ns": -16}


def test_the_pytest_plugin_injects_a_drift(gatewaylab_rig) -> None:  # type: ignore[no-untyped-def]
    """RigHandle.fault("ec-dc-drift", ...) on a simulated rig from a dict: the in-process master's compensation
    follows it."""
    handle = gatewaylab_rig({"device": [{"kind": "ethercat_io", "name": "a"},
                                        {"kind": "ethercat_io", "name": "b", "serial": 9}],
                             "ethercat": {"interface": "gl-none", "cable_m": 3.0}}, clock="simulated")
    assert handle.rig is not None
    segment = next(p for p in handle.rig.participants if p.name == "ethercat").segment
    m = Master(handle.rig.clock, segment)
    m.bring_up()
    reset_dc(m)
    assert config_dc(m) == [0, round(FORWARD_NS + 3.0 * CABLE_NS_PER_M)]
    answer = handle.fault("ec-dc-drift", device="b", ppm=250.0)
    assert answer["fault"] == "ec-dc-drift"
    compensate(m, handle.rig.clock, 300)
    assert abs(time_difference(m, 1)) <= 1
