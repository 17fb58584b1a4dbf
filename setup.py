"""Build gatewaylab: the modules listed in gatewaylab/build_info.py are compiled with mypyc when possible.

Everything else (metadata, entry points, package data) is in pyproject.toml. The compiled extensions
come from the same ``.py`` files, which stay in the wheel; without a usable C compiler (or without
mypyc) the build is pure Python and still succeeds.

GATEWAYLAB_COMPILE: ``auto`` (default: compile when possible), ``1`` (compile or fail the build),
``0`` (pure Python).
"""

from __future__ import annotations

import os
import runpy
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

from setuptools import setup

ROOT = Path(__file__).resolve().parent
COMPILED_MODULES: tuple[str, ...] = runpy.run_path(str(ROOT / "gatewaylab" / "build_info.py"))["COMPILED_MODULES"]


def log(message: str) -> None:
    """One line on stderr (``pip install -v`` shows it)."""
    print(f"gatewaylab build: {message}", file=sys.stderr, flush=True)


def compiler_problem() -> str | None:
    """Why no extension can be built here (None: a C compiler with Python's headers works)."""
    try:
        from distutils import ccompiler, sysconfig  # setuptools' own copy, after the import above
    except ImportError as exc:
        return f"no distutils ({exc})"
    compiler: Any = ccompiler.new_compiler()
    sysconfig.customize_compiler(compiler)
    with tempfile.TemporaryDirectory() as tmp:
        probe = Path(tmp, "probe.c")
        probe.write_text("#include <Python.h>\nint gatewaylab_probe(void) { return 0; }\n")
        try:
            compiler.compile([str(probe)], output_dir=tmp, include_dirs=[sysconfig.get_python_inc()])
        except Exception as exc:   # CompileError, or the compiler program is missing
            return f"no usable C compiler ({type(exc).__name__}: {exc})"
    return None


#: setup.py runs once per build step; these only write metadata, so mypyc need not analyse the code for them.
METADATA_COMMANDS = {"egg_info", "dist_info", "sdist"}
BUILD_COMMANDS = {"build", "build_ext", "bdist_wheel", "editable_wheel", "install", "develop", "bdist_egg"}


def extensions() -> list[Any]:
    """The mypyc extensions of COMPILED_MODULES, or [] for a pure-Python build (and why, in one line)."""
    commands = set(sys.argv[1:])
    if commands & METADATA_COMMANDS and not commands & BUILD_COMMANDS:
        return []
    # bdist_wheel packs all of build/lib*: an extension left there by an earlier build (a module since
    # taken off the list) would ship and shadow its .py. The C objects in build/temp* stay (incremental).
    for stale in ROOT.glob("build/lib*"):
        shutil.rmtree(stale)
    mode = os.environ.get("GATEWAYLAB_COMPILE", "auto")
    if mode == "0":
        log("pure Python (GATEWAYLAB_COMPILE=0)")
        return []
    try:
        from mypyc.build import mypycify
    except ImportError as exc:
        problem: str | None = f"mypyc not importable ({exc})"
    else:
        problem = compiler_problem()
    if problem is not None:
        if mode == "1":
            raise SystemExit(f"gatewaylab build: GATEWAYLAB_COMPILE=1 but {problem}")
        log(f"pure Python: {problem}")
        return []
    paths = [str(Path(*name.split(".")).with_suffix(".py")) for name in COMPILED_MODULES]
    log(f"compiling {len(paths)} modules with mypyc: {', '.join(COMPILED_MODULES)}")
    try:
        # One shared library for all of them (calls between compiled modules stay native), named after
        # the package rather than a hash of the list; mypy's options come from pyproject's [tool.mypy].
        return list(mypycify(paths, opt_level="3", debug_level="1", group_name="gatewaylab"))
    except (Exception, SystemExit) as exc:   # mypyc reports type errors by exiting
        if mode == "1":
            raise
        log(f"pure Python: mypyc failed ({type(exc).__name__}: {exc}); GATEWAYLAB_COMPILE=1 makes this an error")
        return []


setup(ext_modules=extensions())
