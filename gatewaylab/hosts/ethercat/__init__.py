"""EtherCAT masters: the in-process master (``master.py`` and its parts), the MasterBackend contract
(``backend.py``), its two implementations (``inprocess.py``, ``pysoem_backend.py``) and what they share
(``shared.py``). Each name is imported from its module; the package re-exports nothing."""
