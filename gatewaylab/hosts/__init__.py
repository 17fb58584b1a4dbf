"""What a user runs on the master side: EtherCAT masters and backends, the gateways' host libraries and
the python-can interfaces over them."""

__all__ = []
