"""SOEM's own C sample programs (``slaveinfo``, ``simple_test``, ``eepromtool``, ``red_test``, ...) built at test
time from the pysoem source distribution, as /work/shared/notes/soem-c-samples.md describes: an independent
master written in C by SOEM's authors, not by us.

``build_soem_sample("slaveinfo")`` returns the path of the program, built once per machine and pysoem version
under ``.venv/conformance/soem/<version>/`` from the sdist cached in ``.venv/conformance/sdist/`` (where the
canopen sdist of tests/devices/canopen_node is cached too). The test skips, with the reason, only when there is
no C compiler, or when the sdist cannot be downloaded and no copy is cached; a sample that does not compile
fails the test.

The one change to SOEM's sources: pysoem added ``DCtO`` and ``DCl`` to ``ecx_contextt`` just before ``DCtime``
but left the EC_VER1 global ``ecx_context`` initializer in ``soem/ethercatmain.c`` as it was, so gcc stops with
"initializer element is not computable at load time"; ``0, 0,`` for the two fields goes after ``&EcatError,``.
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

__all__ = ["SAMPLES", "build_soem_sample", "pysoem_sdist"]

ROOT = Path(__file__).resolve().parents[2]
CONFORMANCE = ROOT / ".venv" / "conformance"
#: the sdists `make conformance` and the canopen_node tests cache too
SDISTS = CONFORMANCE / "sdist"
#: the samples of SOEM's test/linux folder this helper knows how to build (one C file each);
#: ``red_test_redundant`` is red_test with the call its name and usage promise put back: as shipped it opens
#: only its first interface (``if (ec_init_redundant(ifname, ifname2))`` is commented out above ``ec_init``)
SAMPLES = {"slaveinfo": "slaveinfo/slaveinfo.c", "simple_test": "simple_test/simple_test.c",
           "eepromtool": "eepromtool/eepromtool.c", "red_test": "red_test/red_test.c",
           "red_test_redundant": "red_test/red_test.c"}
_FIX = re.compile(r"(&EcatError,[^\n]*\n)(\s*&ec_DCtime,)")
_RED = re.compile(r"//\s*(if \(ec_init_redundant\(ifname, ifname2\)\))\s*\n\s*if \(ec_init\(ifname\)\)")


def pysoem_sdist() -> Path:
    """The installed pysoem's source distribution, downloaded once (pip, no dependencies); skips with the
    reason when it cannot be downloaded and no copy is cached."""
    version = importlib.metadata.version("pysoem")
    SDISTS.mkdir(parents=True, exist_ok=True)
    tarball = SDISTS / f"pysoem-{version}.tar.gz"
    if not tarball.exists():
        with _locked("sdist"):
            if not tarball.exists():
                done = subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps",
                                       "--no-binary", ":all:", f"pysoem=={version}", "-d", str(SDISTS)],
                                      capture_output=True, text=True, timeout=900, check=False)
                if done.returncode != 0 or not tarball.exists():
                    pytest.skip(f"the pysoem {version} sdist cannot be downloaded here and none is cached in "
                                f"{SDISTS}: {done.stderr.strip()[-200:]}")
    return tarball


class _Lock:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.fd = -1

    def __enter__(self) -> None:
        self.fd = os.open(self.path, os.O_CREAT | os.O_RDWR, 0o644)
        fcntl.flock(self.fd, fcntl.LOCK_EX)

    def __exit__(self, *exc: object) -> None:
        fcntl.flock(self.fd, fcntl.LOCK_UN)
        os.close(self.fd)


def _locked(name: str) -> _Lock:
    """One builder at a time (pytest-xdist workers share the cache)."""
    CONFORMANCE.mkdir(parents=True, exist_ok=True)
    return _Lock(CONFORMANCE / f".{name}.lock")


def _compiler() -> str:
    cc = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")
    if not cc:
        pytest.skip("no C compiler (gcc or cc) to build SOEM's sample programs")
    return cc


def build_soem_sample(name: str) -> Path:
    """The program ``name`` of SOEM's test/linux samples (see :data:`SAMPLES`), built from the pysoem sdist."""
    source = SAMPLES[name]
    cc = _compiler()
    version = importlib.metadata.version("pysoem")
    out = CONFORMANCE / "soem" / version / name
    if out.exists():
        return out
    tarball = pysoem_sdist()
    with _locked("soem-build"):
        if out.exists():
            return out
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix="soem-") as tmp:
            with tarfile.open(tarball) as tar:
                tar.extractall(tmp, filter="data")
            soem = next(Path(tmp).glob("pysoem-*/soem"))
            main = soem / "soem" / "ethercatmain.c"
            text = main.read_text(encoding="latin-1")
            if "DCtO" in (soem / "soem" / "ethercatmain.h").read_text(encoding="latin-1"):
                text, n = _FIX.subn(r"\g<1>    0, 0,               // .DCtO, .DCl (pysoem's fields)\n\g<2>", text)
                assert n == 1, f"{main}: the ecx_context initializer is not where the notes say"
                main.write_text(text, encoding="latin-1")
            if name == "red_test_redundant":
                red = soem / "test" / "linux" / source
                text, n = _RED.subn(r"\g<1>", red.read_text(encoding="latin-1"))
                assert n == 1, f"{red}: the commented-out ec_init_redundant call is not where it was"
                red.write_text(text, encoding="latin-1")
            cmd = [cc, "-O2", "-w", "-Isoem", "-Iosal", "-Iosal/linux", "-Ioshw/linux",
                   *sorted(str(p.relative_to(soem)) for d in ("soem", "osal/linux", "oshw/linux")
                           for p in (soem / d).glob("*.c")),
                   f"test/linux/{source}", "-o", str(out) + ".tmp", "-lpthread", "-lrt", "-lm"]
            done = subprocess.run(cmd, cwd=soem, capture_output=True, text=True, timeout=600, check=False)
            assert done.returncode == 0, f"{name} does not build: {done.stderr[-3000:]}"
            os.replace(str(out) + ".tmp", out)
    return out
