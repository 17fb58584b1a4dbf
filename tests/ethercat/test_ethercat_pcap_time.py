"""In-process EtherCAT captures carry real timestamps (issue 15, one time base): a PcapWriter given the
master's clock writes Unix time wall_epoch + clock time, not seconds since the clock's start."""

from __future__ import annotations

from pathlib import Path

from gatewaylab.common.clock import SimulatedClock
from gatewaylab.devices.ethercat_io.device import create_io_slave
from gatewaylab.ethercat.segment import Segment
from gatewaylab.ethercat.wire_pcap import PcapWriter, read_pcap
from gatewaylab.hosts.ethercat.master import Master


def test_in_process_capture_has_unix_timestamps(tmp_path: Path) -> None:
    """pcap record header ts_sec/ts_usec are Unix time (pcap-savefile(5)); frames at clock time t are
    stamped clock.wall_epoch + t, the instants trace files and client timestamps use (docs/rig.md)."""
    clock = SimulatedClock()
    path = tmp_path / "inprocess.pcap"
    pcap = PcapWriter(str(path), clock=clock)
    master = Master(clock, Segment([create_io_slave(clock)]), capture=pcap.write)
    master.bring_up()
    pcap.close()
    stamps = [t for t, _ in read_pcap(path.read_bytes())]
    assert stamps and all(clock.wall_epoch - 1e-6 <= t <= clock.wall_epoch + clock.now() + 1e-6 for t in stamps)
    assert stamps == sorted(stamps)


def test_wire_thread_timestamps_stay_unix_time() -> None:
    """Without a clock (the wire thread passes time.time()) the timestamps are written as given."""
    import io

    out = io.BytesIO()
    w = PcapWriter(out)
    w.write(1_700_000_000.25, b"\x01" * 60)
    w.flush()
    assert [t for t, _ in read_pcap(out.getvalue())] == [1_700_000_000.25]
