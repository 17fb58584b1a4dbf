"""EtherCAT masters: the in-process master, the MasterBackend contract and the pysoem backend."""
