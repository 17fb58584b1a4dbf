"""SOEM's own redundancy sample, ``red_test``, built at test time from the pysoem source distribution
(/work/shared/notes/soem-c-samples.md): an independent master in C, written by SOEM's authors.

Two changes to SOEM's sources, both restoring what the sources themselves say:

- the notes' one-line initializer fix: pysoem added ``DCtO`` and ``DCl`` to ``ecx_contextt`` before ``DCtime`` but
  not to the EC_VER1 global ``ecx_context`` initializer in ``soem/ethercatmain.c``; ``0, 0,`` goes after
  ``&EcatError,``;
- ``red_test.c`` as shipped opens only its first interface: ``if (ec_init_redundant(ifname, ifname2))`` is commented
  out above ``if (ec_init(ifname))``. The build puts the redundant call back (the program's name and usage say it
  tests redundancy: ``red_test ifname1 ifname2 cycletime``).

:func:`build_red_test` returns the program, built once per pysoem version under ``.venv/conformance/soem/<version>/``
from the sdist cached in ``.venv/conformance/sdist/`` (shared with the other SOEM sample builders); the test skips
only when there is no C compiler or the sdist can neither be downloaded nor found cached; a build failure fails.
"""

from __future__ import annotations

import fcntl
import importlib.metadata
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

import pytest

__all__ = ["build_red_test"]

ROOT = Path(__file__).resolve().parents[2]
CONFORMANCE = ROOT / ".venv" / "conformance"
SDISTS = CONFORMANCE / "sdist"
_FIX = re.compile(r"(&EcatError,[^\n]*\n)(\s*&ec_DCtime,)")
_RED = re.compile(r"//\s*(if \(ec_init_redundant\(ifname, ifname2\)\))\s*\n\s*if \(ec_init\(ifname\)\)")


def _locked(path: Path) -> int:
    CONFORMANCE.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o644)
    fcntl.flock(fd, fcntl.LOCK_EX)
    return fd


def _sdist(version: str) -> Path:
    SDISTS.mkdir(parents=True, exist_ok=True)
    tarball = SDISTS / f"pysoem-{version}.tar.gz"
    if not tarball.exists():
        done = subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--no-binary", ":all:",
                               f"pysoem=={version}", "-d", str(SDISTS)], capture_output=True, text=True, timeout=900,
                              check=False)
        if done.returncode != 0 or not tarball.exists():
            pytest.skip(f"the pysoem {version} sdist cannot be downloaded and none is cached in {SDISTS}: "
                        f"{done.stderr.strip()[-200:]}")
    return tarball


def build_red_test() -> Path:
    """SOEM's ``red_test`` with its redundant initialisation, built from the installed pysoem's sdist."""
    cc = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")
    if not cc:
        pytest.skip("no C compiler (gcc or cc) to build SOEM's red_test")
    version = importlib.metadata.version("pysoem")
    out = CONFORMANCE / "soem" / version / "red_test_redundant"
    if out.exists():
        return out
    fd = _locked(CONFORMANCE / ".soem-red-test.lock")
    try:
        if out.exists():
            return out
        tarball = _sdist(version)
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix="soem-red-") as tmp:
            with tarfile.open(tarball) as tar:
                tar.extractall(tmp, filter="data")
            soem = next(Path(tmp).glob("pysoem-*/soem"))
            main = soem / "soem" / "ethercatmain.c"
            text = main.read_text(encoding="latin-1")
            if "DCtO" in (soem / "soem" / "ethercatmain.h").read_text(encoding="latin-1"):
                text, n = _FIX.subn(r"\g<1>    0, 0,               // .DCtO, .DCl (pysoem's fields)\n\g<2>", text)
                assert n == 1, f"{main}: the ecx_context initializer is not where the notes say"
                main.write_text(text, encoding="latin-1")
            red = soem / "test" / "linux" / "red_test" / "red_test.c"
            text, n = _RED.subn(r"\g<1>", red.read_text(encoding="latin-1"))
            assert n == 1, f"{red}: the commented-out ec_init_redundant call is not where it was"
            red.write_text(text, encoding="latin-1")
            cmd = [cc, "-O2", "-w", "-Isoem", "-Iosal", "-Iosal/linux", "-Ioshw/linux",
                   *sorted(str(p.relative_to(soem)) for d in ("soem", "osal/linux", "oshw/linux")
                           for p in (soem / d).glob("*.c")),
                   "test/linux/red_test/red_test.c", "-o", str(out) + ".tmp", "-lpthread", "-lrt", "-lm"]
            done = subprocess.run(cmd, cwd=soem, capture_output=True, text=True, timeout=900, check=False)
            assert done.returncode == 0, f"red_test does not build: {done.stderr[-3000:]}"
            os.replace(str(out) + ".tmp", out)
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
    return out
