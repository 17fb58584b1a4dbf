"""The soak of ``make soak`` for 20 seconds (issue 15 'Held under load and faults': 'make test runs a
20-second version of the same code')."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from benchmarks.soak import run_soak

pytestmark = pytest.mark.slow


def test_default_rig_holds_2000_frames_per_second_and_an_sdo_loop() -> None:
    """issue 15: the default rig, 2,000 frames/s from three python-can client processes and a canopen
    SDO loop: every frame sent by a client is received, in order, by every other client; 0 SDO
    failures; the rig's RSS grows by less than 10 MB (after a 2 s warm-up)."""
    r = run_soak(20.0, warmup=2.0)
    print(r.report())
    assert len(r.sent) == 3 and all(n > 1000 for n in r.sent.values())
    for k, n in r.sent.items():
        assert r.received[k] == {j: n for j in range(3) if j != k}
    assert r.out_of_order == 0 and r.echoes_missing == 0
    assert r.sdo_transfers > 10 and r.sdo_failures == 0, r.sdo_errors
    assert r.rss_end - r.rss_start < 10 * 1024 * 1024
    assert r.ok, r.violations
