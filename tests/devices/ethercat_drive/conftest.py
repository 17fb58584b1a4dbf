"""Fixtures of the ethercat_drive tests: a veth pair inside a network namespace the test creates
and deletes (the pattern of tests/ethercat/conftest.py), for pysoem / KickCAT in a subprocess."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from ecdrive_testkit import DriveVeth, net_capable
from wire_kit import veth_namespace


@pytest.fixture(scope="module")
def drive_veth() -> Iterator[DriveVeth]:
    reason = net_capable()
    if reason is not None:
        pytest.skip(reason)
    with veth_namespace("gl-ecd-", "gld") as (ns, emu, mst):
        yield DriveVeth(ns, emu, mst)
