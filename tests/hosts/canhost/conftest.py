"""Fixtures of the python-can-over-EtherCAT tests: a veth pair in a test-made network namespace
for the pysoem runs (the master side runs in the driver script ``canhost_driver.py`` inside it)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import pytest
from wire_kit import net_capable, veth_namespace


def _net_capable() -> str | None:
    """None when we may create namespaces and raw sockets, else the reason to skip (tests/wire_kit.py)."""
    return net_capable("pysoem")


@dataclass(frozen=True)
class CanhostVeth:
    """Emulator end in this namespace, master end inside ``namespace``."""

    namespace: str
    emulator_iface: str
    master_iface: str


@pytest.fixture(scope="module")
def canhost_veth() -> Iterator[CanhostVeth]:
    reason = _net_capable()
    if reason is not None:
        pytest.skip(reason)
    with veth_namespace("gl-ch-", "glc") as (ns, emu, mst):
        yield CanhostVeth(ns, emu, mst)
