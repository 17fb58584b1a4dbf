"""The veth-namespace fixture of the wire runs of ``gatewaylab ec`` (defined in ``ethercat_fixtures``)."""

from ethercat_fixtures import veth_ns

__all__ = ["veth_ns"]
