"""Run every benchmark module, then the table of the performance targets (``make bench``).

``python -m benchmarks [NAME ...]`` runs the modules named (exactly, with or without the ``bench_``
prefix; a name that is no module's is matched as a substring), all of them without names.
``python -m benchmarks targets`` runs only what the targets table needs (each module's
``targets()``). Options: ``--markdown PATH`` writes the table as a Markdown page (docs/performance-
table.md), ``--max-drives N`` ends the EtherCAT segment search at N drives (GL_BENCH_MAX_DRIVES).
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path

from benchmarks import targets
from benchmarks.sides import compiled_modules

#: the modules whose ``targets()`` measure the table, in order
TARGET_MODULES = ("bench_ecanlite_stream", "bench_bus", "bench_canopen_sdo", "bench_canopen_drive",
                  "bench_ethercat", "bench_ethercat_drive", "bench_ethercat_4khz", "bench_ethercat_tail")


def select(wanted: Sequence[str], names: Sequence[str]) -> list[str]:
    """The modules of ``names`` that ``wanted`` asks for: by exact name (``bench_`` optional), else by
    substring (``bench_ethercat`` and ``ethercat`` are bench_ethercat alone, ``drive`` every module with
    'drive' in its name)."""
    if not wanted:
        return list(names)
    chosen: set[str] = set()
    for w in wanted:
        exact = [n for n in names if n in (w, f"bench_{w}")]
        chosen.update(exact or [n for n in names if w in n])
    return [n for n in names if n in chosen]


def _call(module: str, function: str) -> bool:
    print(f"\n### {module}", flush=True)
    try:
        getattr(importlib.import_module(f"benchmarks.{module}"), function)()
    except Exception:
        traceback.print_exc()
        return False
    return True


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="benchmark modules, or 'targets'")
    parser.add_argument("--markdown", type=Path, metavar="PATH", help="write the targets table as Markdown")
    parser.add_argument("--max-drives", type=int, metavar="N", help="largest EtherCAT segment searched (drives)")
    args = parser.parse_args(argv)
    if args.max_drives is not None:
        os.environ["GL_BENCH_MAX_DRIVES"] = str(args.max_drives)
    if args.names == ["targets"]:
        runs = [(m, "targets") for m in TARGET_MODULES]
    else:
        names = sorted(m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)])
                       if m.name.startswith("bench_"))
        runs = [(m, "main") for m in select(args.names, names)]
        if not runs:
            parser.error(f"no benchmark module matches {' '.join(args.names)}")
    failed = sum(not _call(module, function) for module, function in runs)
    # the EtherCAT rows run their emulator in this process: what it ran compiled counts too
    targets.record_compiled(compiled_modules())
    print(targets.summary())
    if args.markdown:
        targets.write_markdown(args.markdown)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
