"""Compiled hot paths (issue 23, "Packaging"): ``pip install .`` / ``make install`` compile the modules of
``gatewaylab.build_info.COMPILED_MODULES`` with mypyc when a C compiler is present; ``GATEWAYLAB_PURE=1``
forces pure Python at import time; ``gatewaylab --version`` says which modules run compiled."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from importlib.machinery import EXTENSION_SUFFIXES, SourceFileLoader
from pathlib import Path

import pytest

import gatewaylab
from gatewaylab import build_info

PACKAGE_DIR = Path(gatewaylab.__file__).resolve().parent

# Imports every listed module and a few that import them, then reports what runs compiled.
PROBE = """
import json, sys
from importlib.machinery import ExtensionFileLoader
import gatewaylab.cli.main
from gatewaylab import build_info
compiled = build_info.compiled_modules()
loaded = sorted(name for name, module in list(sys.modules.items())
                if name.startswith("gatewaylab.") and isinstance(getattr(module, "__spec__", None) and
                                                                 module.__spec__.loader, ExtensionFileLoader))
print(json.dumps({"compiled": compiled, "extensions_loaded": loaded,
                  "shared_lib": "gatewaylab__mypyc" in sys.modules}))
"""


def _run(pure: bool, *args: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != build_info.PURE_ENV}
    if pure:
        env[build_info.PURE_ENV] = "1"
    return subprocess.run([sys.executable, *args], env=env, capture_output=True, text=True, timeout=120, check=True)


def _extension_files() -> list[Path]:
    """Compiled extensions inside the package folder (the shims mypyc puts beside each .py)."""
    return sorted(p for suffix in EXTENSION_SUFFIXES for p in PACKAGE_DIR.rglob("*" + suffix))


def _module_of(extension: Path) -> str:
    relative = extension.relative_to(PACKAGE_DIR)
    return ".".join(("gatewaylab", *relative.parent.parts, relative.name.split(".")[0]))


def test_pure_env_runs_no_compiled_module() -> None:
    """Issue 23: "GATEWAYLAB_PURE=1 forces pure Python at import time for debugging" -- no gatewaylab
    extension and not the shared mypyc library is loaded, and --version says so."""
    got = json.loads(_run(True, "-c", PROBE).stdout)
    assert got == {"compiled": [], "extensions_loaded": [], "shared_lib": False}
    assert _run(True, "-m", "gatewaylab", "--version").stdout.strip() == (
        f"gatewaylab {gatewaylab.__version__} (pure Python, GATEWAYLAB_PURE set)")


def test_source_only_finder_finds_the_py_file() -> None:
    """Issue 23: pure Python from the same source -- the finder GATEWAYLAB_PURE installs takes a listed
    module's .py even when its compiled extension lies beside it, and leaves other packages alone."""
    finder = gatewaylab._SourceOnlyFinder()
    for name in build_info.COMPILED_MODULES:
        spec = finder.find_spec(name, [str(build_info.source_path(name).parent)])   # the parent's __path__
        assert spec is not None and isinstance(spec.loader, SourceFileLoader)
        assert spec.origin == str(build_info.source_path(name))
    assert finder.find_spec("json.decoder", [str(Path(json.__file__).parent)]) is None


def test_compiled_modules_are_exactly_the_list() -> None:
    """Issue 23: "gatewaylab --version (and the ready file) say which modules run compiled" -- in a
    compiled build every listed module runs compiled and no extension is left beside a module that is
    no longer listed (it would run stale code)."""
    extensions = _extension_files()
    if not extensions:
        pytest.skip("nothing compiled here (plain source checkout or a build without a C compiler); "
                    "`make install` compiles the listed modules")
    assert sorted({_module_of(p) for p in extensions}) == sorted(build_info.COMPILED_MODULES)
    got = json.loads(_run(False, "-c", PROBE).stdout)
    assert got["compiled"] == list(build_info.COMPILED_MODULES)
    assert got["extensions_loaded"] == sorted(build_info.COMPILED_MODULES)
    assert got["shared_lib"] is True
    version = _run(False, "-m", "gatewaylab", "--version").stdout
    assert " ".join(version.split()) == (f"gatewaylab {gatewaylab.__version__} (compiled: " + ", ".join(
        name.removeprefix("gatewaylab.") for name in build_info.COMPILED_MODULES) + ")")


def test_an_extension_older_than_its_source_is_stale(tmp_path: Path) -> None:
    """Issue 23 packaging: an edited compiled module must not silently run as its old .so -- an extension
    older than its .py is reported (the import warning of a source checkout), a newer one is not."""
    source = tmp_path / "bus" / "bus.py"
    source.parent.mkdir()
    source.write_text("")
    extension = source.with_name("bus" + EXTENSION_SUFFIXES[0])
    extension.write_bytes(b"")
    os.utime(extension, (1_000_000, 1_000_000))
    os.utime(source, (1_000_100, 1_000_100))
    assert build_info.stale_extensions(("gatewaylab.bus.bus",), tmp_path) == ["gatewaylab.bus.bus"]
    os.utime(extension, (1_000_200, 1_000_200))
    assert build_info.stale_extensions(("gatewaylab.bus.bus",), tmp_path) == []
    assert build_info.stale_extensions(("gatewaylab.bus.frame",), tmp_path) == []


def test_the_ready_file_names_the_modules_that_run_compiled() -> None:
    """Issue 23 packaging: '`gatewaylab --version` (and the ready file) say which modules run compiled' --
    the ready file's ``compiled`` list is what runs compiled in the rig's process (empty when pure)."""
    from gatewaylab.rig.config import parse_rig
    from gatewaylab.rig.runtime import Rig

    with Rig(parse_rig({"clock": "simulated", "bus": [{"name": "can0", "endpoint": "none"}]})) as rig:
        info = rig.ready_info()
    assert info["compiled"] == build_info.compiled_modules()
    assert set(info["compiled"]) <= set(build_info.COMPILED_MODULES)
    if build_info.pure_forced():
        assert info["compiled"] == []


def test_architecture_names_exactly_the_compiled_modules() -> None:
    """Issue 23 "Done when": docs/architecture.md says which modules are compiled -- the same list as
    COMPILED_MODULES, the one the build compiles."""
    import re

    text = (Path(gatewaylab.__file__).parent.parent / "docs" / "architecture.md").read_text()
    bullet = text[text.index("* **Compiled modules**"):]
    bullet = bullet[:bullet.index("\n*")] if "\n*" in bullet else bullet
    listed = bullet[bullet.index("Compiled today"):bullet.index("Rules that keep")]
    named = {f"gatewaylab.{m}" for m in re.findall(r"`([a-z_.]+)`", listed) if "." in m.strip(".")}
    assert named == set(build_info.COMPILED_MODULES)
