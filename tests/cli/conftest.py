"""Fixtures of the CLI tests: the EtherCAT tests' veth namespace (``ethercat_fixtures``) for the `ec` verbs
over SOEM."""

from ethercat_fixtures import veth_ns

__all__ = ["veth_ns"]
