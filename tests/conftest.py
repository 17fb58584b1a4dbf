"""Suite-wide checks (issue 15 'Failed starts ... leave gatewaylab-* temporary folders ..., and so do
tests': a test counts the folders before and after the suite).

Every temporary folder of the run -- the suite's own and those of the `gatewaylab run` processes it
starts, which inherit TMPDIR -- goes into one private folder, so programs running beside the suite
cannot change the count.
"""

from __future__ import annotations

import gc
import multiprocessing.util
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import kit_paths
import pytest

_PRIVATE_TMP = pytest.StashKey[Path]()

kit_paths.add_all()  # kits and drivers of every folder by basename (tests/kit_paths.py)

#: gatewaylab's pytest plugin (the pytest11 entry point of an installed gatewaylab; named here too so the
#: suite has it in a checkout whose install predates the entry point)
pytest_plugins = ["gatewaylab.rig.pytest_plugin"]


def pytest_configure(config: pytest.Config) -> None:
    private = Path(tempfile.mkdtemp(prefix="glt-"))
    config.stash[_PRIVATE_TMP] = private
    if config.option.basetemp is None and not hasattr(config, "workerinput"):
        # Short tmp_path names: a rig's Unix sockets live below them and AF_UNIX paths end at
        # 107 bytes (pytest's own pytest-of-USER/pytest-N/popen-gwK prefix would eat 40 of them).
        config.option.basetemp = str(private / "t")
    os.environ["TMPDIR"] = str(private)
    tempfile.tempdir = None  # recomputed from TMPDIR on next use


def pytest_unconfigure(config: pytest.Config) -> None:
    private = config.stash.get(_PRIVATE_TMP, None)
    if private is not None and not any(private.glob("gatewaylab-*")):
        # After multiprocessing's own exit finalisers (the forkserver's pymp-* folder lives in here
        # and is removed at exitpriority -100): they run by descending priority.
        multiprocessing.util.Finalize(None, shutil.rmtree, args=(private,), kwargs={"ignore_errors": True},
                                      exitpriority=-200)


def gatewaylab_folders() -> set[Path]:
    """The rig state folders (``gatewaylab-*``) in the temporary directory of this run."""
    return set(Path(tempfile.gettempdir()).glob("gatewaylab-*"))


@pytest.fixture(scope="session", autouse=True)
def no_gatewaylab_folder_left_behind() -> Iterator[None]:
    """After the whole suite no rig state folder is left: rigs are closed on every exit path,
    `gatewaylab run` processes remove theirs when stopped, failed starts leave nothing."""
    before = gatewaylab_folders()
    yield
    gc.collect()  # a Rig nobody closed: its finaliser warns (ResourceWarning) and removes its folder
    left = gatewaylab_folders() - before
    assert not left, f"{len(left)} gatewaylab-* folder(s) left behind by the suite: {sorted(map(str, left))}"
