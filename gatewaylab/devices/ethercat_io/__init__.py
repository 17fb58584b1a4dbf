"""The generic EtherCAT loop-back I/O slave (`ethercat_io`)."""

__all__ = []
