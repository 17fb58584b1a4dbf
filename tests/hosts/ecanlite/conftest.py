"""Fixtures of the ECAN-Lite host tests: the device tests' ``rig`` and ``veth_ns`` (tests/devices/ecanlite)."""

from ecanlite_fixtures import rig, veth_ns

__all__ = ["rig", "veth_ns"]
