"""Fixtures of the ECAN-Lite device tests (defined in ``ecanlite_fixtures``, shared with tests/hosts/ecanlite)."""

from ecanlite_fixtures import rig, veth_ns

__all__ = ["rig", "veth_ns"]
