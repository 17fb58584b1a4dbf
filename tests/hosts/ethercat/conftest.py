"""The EtherCAT fixtures (defined in ``ethercat_fixtures``, shared with tests/ethercat)."""

from ethercat_fixtures import chunked_description, clock, master, segment, veth_ns

__all__ = ["chunked_description", "clock", "master", "segment", "veth_ns"]
