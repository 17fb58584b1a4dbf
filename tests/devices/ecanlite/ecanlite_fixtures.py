"""Fixtures of the ECAN-Lite device and host tests (helpers: ``ecanlite_device_kit``); their conftests import them."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from ecanlite_device_kit import Rig, VethNs, make_rig, net_capable, veth_pair


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    yield make_rig(tmp_path)


@pytest.fixture(scope="module")
def veth_ns() -> Iterator[VethNs]:
    reason = net_capable()
    if reason is not None:
        pytest.skip(reason)
    with veth_pair() as v:
        yield v
