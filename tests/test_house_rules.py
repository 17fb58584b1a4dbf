"""Issue 22 'Done when': the house rules that keep the rooms readable, checked on the source of gatewaylab/.

- no file over ~700 lines except generated tables (:data:`GENERATED`);
- every exception gatewaylab defines derives from ``GatewaylabError`` (callers catch one base), and library
  code raises no bare ValueError/RuntimeError/Exception/OSError/AssertionError (a subclass of
  GatewaylabError may also derive from the built-in a caller expects, as ``FrameError(LocalError, ValueError)``);
- public definitions (modules' functions and classes, public classes' methods) carry a docstring: at least
  95 % of them overall (DEVELOPERS.md principle 7: short docstrings that say why).
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import inspect
import pkgutil
from collections import defaultdict
from pathlib import Path

import pytest

import gatewaylab
from gatewaylab.common.errors import GatewaylabError

ROOT = Path(gatewaylab.__file__).resolve().parent
SOURCES = sorted(p for p in ROOT.rglob("*.py") if "__pycache__" not in p.parts)
MAX_LINES = 700
#: generated tables, exempt from the length rule
GENERATED: frozenset[str] = frozenset()
#: built-ins library code must not raise by name (a GatewaylabError subclass says which wire code or rule broke)
BANNED_RAISES = frozenset({"ValueError", "RuntimeError", "Exception", "OSError", "AssertionError", "IndexError",
                           "KeyError", "TypeError"})
#: dunder methods whose protocol is the built-in exception (``__getitem__`` raises KeyError/IndexError)
PROTOCOL_METHODS = frozenset({"__getitem__", "__getattr__", "__next__", "__delitem__", "__setitem__"})
DOCSTRING_COVERAGE = 0.95


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


@pytest.mark.parametrize("path", SOURCES, ids=_rel)
def test_no_file_over_700_lines(path: Path) -> None:
    """Issue 22: 'no file over ~700 lines except generated tables'."""
    if _rel(path) in GENERATED:
        return
    lines = len(path.read_text().splitlines())
    assert lines <= MAX_LINES, f"{_rel(path)} has {lines} lines: split it by concept"


def test_every_exception_derives_from_gatewaylab_error() -> None:
    """Issue 22: 'Every exception under GatewaylabError' (private control-flow exceptions, named with a
    leading underscore, excepted)."""
    outside: list[str] = []
    for info in pkgutil.walk_packages(gatewaylab.__path__, "gatewaylab."):
        if info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if (inspect.isclass(obj) and issubclass(obj, Exception) and obj.__module__ == module.__name__
                    and not name.startswith("_") and not issubclass(obj, GatewaylabError)):
                outside.append(f"{module.__name__}.{name}")
    assert not outside, f"exceptions outside GatewaylabError: {outside}"


def _banned_raises(path: Path) -> list[str]:
    found: list[str] = []

    def visit(node: ast.AST, function: str) -> None:
        for child in ast.iter_child_nodes(node):
            name = child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else function
            if isinstance(child, ast.Raise) and child.exc is not None:
                exc = child.exc.func if isinstance(child.exc, ast.Call) else child.exc
                if (isinstance(exc, ast.Name) and exc.id in BANNED_RAISES
                        and not (function in PROTOCOL_METHODS and exc.id in {"KeyError", "IndexError"})):
                    found.append(f"{_rel(path)}:{child.lineno} raise {exc.id}")
            visit(child, name)

    visit(ast.parse(path.read_text()), "")
    return found


def test_library_code_raises_gatewaylab_errors() -> None:
    """Issue 22: 'today ... 28 bare ValueError/RuntimeError raises in library code': none left."""
    found = [hit for path in SOURCES for hit in _banned_raises(path)]
    assert not found, "raise a GatewaylabError subclass instead:\n" + "\n".join(found)


def public_definitions(path: Path) -> list[tuple[str, bool]]:
    """(qualified name, has a docstring) of every public function, class and public class's method."""
    out: list[tuple[str, bool]] = []

    def visit(body: list[ast.stmt], prefix: str) -> None:
        for node in body:
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) or node.name.startswith("_"):
                continue
            if any((isinstance(d, ast.Name) and d.id == "overload")
                   or (isinstance(d, ast.Attribute) and d.attr in {"setter", "deleter"}) for d in node.decorator_list):
                continue
            out.append((f"{_rel(path)}:{node.lineno} {prefix}{node.name}", ast.get_docstring(node) is not None))
            if isinstance(node, ast.ClassDef):
                visit(node.body, f"{prefix}{node.name}.")

    visit(ast.parse(path.read_text()).body, "")
    return out


def room_of(path: Path) -> str:
    """The room a source file lives in: its first folder under gatewaylab/ (``.`` for the top-level files)."""
    parts = path.relative_to(ROOT).parts
    return parts[0] if len(parts) > 1 else "."


def room_coverage(defs_by_room: dict[str, list[tuple[str, bool]]]) -> list[str]:
    """One line per room, worst first: its docstring coverage, so each room's owner sees their share."""
    rows = []
    for room, defs in defs_by_room.items():
        missing = sum(not has for _, has in defs)
        rows.append((1 - missing / len(defs), room, len(defs), missing))
    return [f"  {room + '/':<12} {cov:6.1%} of {total:4d} ({missing} without)"
            for cov, room, total, missing in sorted(rows)]


def test_public_definitions_have_docstrings() -> None:
    """Issue 22: 'public definitions with docstrings >= 95 %'; the message says how far each room is."""
    by_room: dict[str, list[tuple[str, bool]]] = defaultdict(list)
    for path in SOURCES:
        by_room[room_of(path)] += public_definitions(path)
    defs = [d for room_defs in by_room.values() for d in room_defs]
    missing = [name for name, has in defs if not has]
    coverage = 1 - len(missing) / len(defs)
    assert coverage >= DOCSTRING_COVERAGE, (f"{coverage:.1%} of {len(defs)} public definitions have a docstring; "
                                            "per room:\n" + "\n".join(room_coverage(by_room))
                                            + "\nwithout:\n" + "\n".join(missing))
