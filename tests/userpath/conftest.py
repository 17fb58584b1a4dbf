"""The user's path (issue 21, "The user's path as a suite"): every test here starts the rig exactly as a
user does -- ``gatewaylab run RIG.toml --ready-file ready.json`` in a child process -- reads the endpoints
from the ready file only, and drives them with the clients users have (python-can, canopen, pyserial,
pymodbus, a browser, pysoem/KickCAT over veth). The in-process suite cannot see what goes wrong between
those clients and a running rig; this folder does.

Fixtures (generic, for every ``test_userpath_*.py`` module):

* ``start_rig(toml_text, *extra_args) -> RigProcess``: starts one ``gatewaylab run`` child with that rig
  file (``extra_args`` are more ``gatewaylab run`` options, e.g. ``"--web"``) and returns once its ready
  file is written (``rig.info`` is the ready file's contents). Module-scoped: a module starts its rigs
  once and shares them between its tests (rig start-up is most of this folder's time); every rig the
  module started is stopped (SIGTERM, then SIGKILL) when the module ends.

Helpers for any module: ``userpath_kit.py`` -- frames stamped with the sender's wall clock, ``Latencies``
(first + steady state, median/p99 bounds, printed), ``@measured`` (measure once more when only a latency
bound broke), ``CyclicDrain`` (a cyclic task's ``recv(0)`` loop), ``wait_until``, ``RIG_TWO_DRIVES``.
Keep the folder fast: one rig per module, a few hundred frames per measurement.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from gatewaylab.rig.process import RigProcess

#: seconds a rig may take to write its ready file (CI machines are shared)
START_TIMEOUT = 60.0

StartRig = Callable[..., RigProcess]


@pytest.fixture(scope="module")
def start_rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StartRig]:
    """Factory: ``start_rig(toml_text, *extra)`` runs ``gatewaylab run RIG.toml --ready-file ... *extra``."""
    started: list[RigProcess] = []

    def _start(toml_text: str, *extra: str) -> RigProcess:
        folder = tmp_path_factory.mktemp("rig")
        rig_file = folder / "rig.toml"
        rig_file.write_text(toml_text)
        rig = RigProcess(rig_file, *extra, workdir=folder, timeout=START_TIMEOUT)
        started.append(rig)
        return rig

    yield _start
    for rig in started:
        rig.stop(20)
