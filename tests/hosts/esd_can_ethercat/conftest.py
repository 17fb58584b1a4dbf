"""The veth pair of the esd host scenarios' pysoem runs: ``esd_veth`` is the shared EtherCAT
``veth_ns`` (``ethercat_fixtures``: emulator end here, master end in a test-made namespace)."""

from __future__ import annotations

import pytest
from ethercat_fixtures import VethNs, veth_ns

__all__ = ["esd_veth", "veth_ns"]


@pytest.fixture(scope="module")
def esd_veth(veth_ns: VethNs) -> VethNs:
    """The namespace and the two interface names the scenario runner needs."""
    return veth_ns
