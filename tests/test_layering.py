"""DEVELOPERS.md 'Architecture' and docs/architecture.md: dependencies point down the list common -> od ->
bus -> canopen -> ethercat (the protocol packages) -> plugin -> devices -> hosts -> migrate -> rig -> cli,
never up (issue 9 'Done means': no circular imports between the dictionary and its users; issue 22: plugin
below devices, hosts and cli above devices, protocol packages import no device). Checked on the import
statements of every module."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent / "gatewaylab"
LAYERS = ["common", "od", "bus", "canopen", "ethercat", "plugin", "devices", "hosts", "migrate", "rig", "cli"]


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == "gatewaylab" and parts[1] in LAYERS else None


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module) of every gatewaylab import in ``path``."""
    package = ".".join(("gatewaylab", *path.relative_to(ROOT).with_suffix("").parts))
    if path.name == "__init__.py":
        package = package.rsplit(".", 1)[0] + ".__init__"
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: -node.level]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            found.append((node.lineno, module))
        elif isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
    return [(line, m) for line, m in found if m.startswith("gatewaylab")]


MODULES = sorted(p for p in ROOT.rglob("*.py") if _layer("gatewaylab." + ".".join(p.relative_to(ROOT).parts)))


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_point_down_the_architecture_list(path: Path) -> None:
    own = _layer("gatewaylab." + ".".join(path.relative_to(ROOT).parts))
    assert own is not None
    upward = [(line, m) for line, m in _imports(path)
              if (layer := _layer(m)) is not None and LAYERS.index(layer) > LAYERS.index(own)]
    assert not upward, f"{path.relative_to(ROOT)} ({own}) imports from higher layers: {upward}"
