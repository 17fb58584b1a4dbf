"""Fixtures for the maxon IDX tests; the helper classes live in maxon_helpers.py."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from maxon_helpers import RunningRig, SlaveHarness


@pytest.fixture
def harness() -> SlaveHarness:
    h = SlaveHarness()
    h.objects.add(0x30B0, 0, (0x9001).to_bytes(4, "little"), size=4)     # home position (2.2.8)
    h.objects.add(0x2006, 0, (500).to_bytes(4, "little"), size=4)
    h.objects.add(0x1001, 0, b"\x00", size=1, access="ro")
    h.objects.add(0x6040, 0, b"\x00\x00", size=2)
    h.objects.add(0x1008, 0, b"IDX 56 M CAN maxon motor emulated drive", size=None, access="ro")
    h.objects.add(0x2100, 1, bytes(600), size=None)
    h.objects.add(0x1011, 1, b"", size=4, access="wo")
    return h


@pytest.fixture
def realtime_rig() -> Iterator[RunningRig]:
    r = RunningRig({"clock": "realtime", "bus": [{"name": "can0", "endpoint": "none"}]})
    yield r
    r.close()
