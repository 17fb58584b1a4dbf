"""Every test folder that holds kits and drivers, on ``sys.path``: tests/ mirrors the package's rooms
(devices/, hosts/, cli/, ...) and a test or a subprocess driver imports any kit by its unique basename.

The root conftest calls :func:`add_all`; a driver run as a script puts tests/ on its path and does too.
"""

from __future__ import annotations

import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def add_all() -> None:
    """Append each folder below tests/ that has a module other than tests and conftests (once)."""
    folders = {p.parent for p in TESTS.rglob("*.py")
               if not p.name.startswith(("test_", "conftest")) and "__pycache__" not in p.parts}
    for folder in sorted(folders):
        if str(folder) not in sys.path:
            sys.path.append(str(folder))
