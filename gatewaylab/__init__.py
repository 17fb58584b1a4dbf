"""gatewaylab: byte-exact emulators of industrial CAN gateways on shared virtual CAN buses."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from importlib.abc import MetaPathFinder
from importlib.machinery import SOURCE_SUFFIXES, FileFinder, ModuleSpec, SourceFileLoader
from types import ModuleType

from gatewaylab import build_info

__version__ = "0.1.0"


class _SourceOnlyFinder(MetaPathFinder):
    """Finds ``gatewaylab.*`` modules by their ``.py`` source only, never a compiled extension beside it."""

    def find_spec(self, fullname: str, path: Sequence[str] | None,
                  target: ModuleType | None = None) -> ModuleSpec | None:
        if not fullname.startswith(__name__ + ".") or path is None:
            return None
        for entry in path:
            spec = FileFinder(entry, (SourceFileLoader, SOURCE_SUFFIXES)).find_spec(fullname)
            if spec is not None and spec.loader is not None:
                return spec
        return None   # e.g. a folder without __init__.py: the ordinary finders make it a namespace package


if build_info.pure_forced():
    sys.meta_path.insert(0, _SourceOnlyFinder())
else:
    build_info.warn_if_stale()
