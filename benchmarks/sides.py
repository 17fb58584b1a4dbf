"""Pure and compiled side by side in one run: one measurement in two child processes.

An in-process benchmark module that offers ``measure() -> dict`` (it prints its details and returns
the numbers) is run twice by :func:`run_sides`: once with ``GATEWAYLAB_PURE=1`` (pure Python forced at
import time) and once without (the compiled build where one is installed). Each child prints its
details, then one marked JSON line with the numbers and the ``gatewaylab`` modules it actually ran
compiled (loaded from an extension module: a ``.so``, whatever the packaging calls its list). Where
nothing is compiled both rows run pure Python, and :func:`print_sides` says so plainly.

``python -m benchmarks.sides MODULE`` is the child's entry point.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import json
import os
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from benchmarks.wire import ROOT

MARK = "@@gl-bench-result "
PURE_ENV = "GATEWAYLAB_PURE"


def compiled_modules() -> list[str]:
    """The ``gatewaylab`` modules of this process loaded from extension modules (mypyc's ``.so``; its
    shared ``*__mypyc`` helper libraries left out)."""
    suffixes = tuple(importlib.machinery.EXTENSION_SUFFIXES)
    return sorted(name for name, module in list(sys.modules.items())
                  if name.split(".")[0] == "gatewaylab" and not name.endswith("__mypyc")
                  and str(getattr(module, "__file__", "") or "").endswith(suffixes))


def quick() -> bool:
    """A short development run (GL_BENCH_SECONDS below 10): the in-process benches do fewer rounds."""
    return float(os.environ.get("GL_BENCH_SECONDS", "60")) < 10


@dataclass(frozen=True)
class Side:
    """One child's run: forced pure or not, the modules that ran compiled, the numbers."""

    forced_pure: bool
    compiled: tuple[str, ...]
    result: dict[str, Any]

    @property
    def label(self) -> str:
        return "compiled" if self.compiled else "pure"


def _child(module: str, forced_pure: bool) -> Side:
    env = dict(os.environ)
    env.pop(PURE_ENV, None)
    if forced_pure:
        env[PURE_ENV] = "1"
    env["PYTHONPATH"] = os.pathsep.join(p for p in (ROOT, env.get("PYTHONPATH", "")) if p)
    tag = "[pure forced]" if forced_pure else "[default]    "
    proc = subprocess.Popen([sys.executable, "-m", "benchmarks.sides", module], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    payload: dict[str, Any] | None = None
    for line in proc.stdout:
        if line.startswith(MARK):
            payload = json.loads(line[len(MARK):])
        else:
            print(f"{tag} {line.rstrip()}", flush=True)
    if proc.wait() != 0 or payload is None:
        side = "pure" if forced_pure else "default"
        raise RuntimeError(f"{module}: the {side} child failed (exit {proc.returncode})")
    return Side(forced_pure, tuple(payload["compiled"]), payload["result"])


def run_sides(module: str) -> tuple[Side, Side]:
    """``module``'s ``measure()`` in a pure child, then in a default child: (pure, default)."""
    return _child(module, True), _child(module, False)


def print_sides(title: str, sides: tuple[Side, Side], rows: Sequence[tuple[str, str, str]]) -> None:
    """One line per (label, result key, format spec): the pure child's value, then the default child's."""
    pure, default = sides
    head = f"PURE=1: {pure.label}", f"default: {default.label}"
    print(f"{title}: side by side in this run")
    print(f"  {'':<44} {head[0]:>16} {head[1]:>18}")
    for label, key, spec in rows:
        print(f"  {label:<44} {format(pure.result[key], spec):>16} {format(default.result[key], spec):>18}")
    if pure.compiled:
        print(f"  WARNING: GATEWAYLAB_PURE=1 still loaded compiled modules: {', '.join(pure.compiled)}")
    if default.compiled:
        print(f"  compiled in the default row: {', '.join(default.compiled)}")
    else:
        print("  nothing is compiled in this installation: BOTH rows ran pure Python")


def compare(module: str, title: str, rows: Sequence[tuple[str, str, str]]) -> tuple[Side, Side]:
    """:func:`run_sides`, :func:`print_sides`, and the default child's compiled modules noted for the
    targets table; (pure, default)."""
    from benchmarks.targets import record_compiled

    sides = run_sides(module)
    print_sides(title, sides, rows)
    record_compiled(sides[1].compiled)
    return sides


def both(sides: tuple[Side, Side], key: str, spec: str, unit: str = "") -> str:
    """The default child's value and the pure child's, for the targets table: '3.10x (compiled); pure 2.00x'."""
    pure, default = sides
    return f"{format(default.result[key], spec)}{unit} ({default.label}); pure {format(pure.result[key], spec)}{unit}"


def child_main(module: str) -> None:
    """Run ``benchmarks.<module>.measure()`` and print its numbers as the marked JSON line."""
    result = importlib.import_module(f"benchmarks.{module}").measure()
    print(MARK + json.dumps({"result": result, "compiled": compiled_modules()}), flush=True)


if __name__ == "__main__":
    child_main(sys.argv[1])
