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
import re
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


REPO = ROOT.parent
#: the history may name issues (docs/decisions.md); the product and what its users read may not
ISSUE_NUMBER = re.compile(r"\bissues? #?[0-9]+", re.IGNORECASE)
TEXT_SUFFIXES = frozenset({".py", ".toml", ".md", ".c", ".html", ".csv"})


def product_texts() -> list[Path]:
    """Every text file of the product and of what its users read: gatewaylab/, docs/ (without
    docs/decisions.md), README.md, benchmarks/ (its printed tables and its README)."""
    files = [p for folder in ("gatewaylab", "docs", "benchmarks") for p in (REPO / folder).rglob("*")
             if p.is_file() and p.suffix in TEXT_SUFFIXES and "__pycache__" not in p.parts]
    files.append(REPO / "README.md")
    return sorted(p for p in files if p != REPO / "docs" / "decisions.md")


def issue_numbers(path: Path, root: Path = REPO) -> list[str]:
    """``file:line text`` (relative to ``root``) of every line that names an issue by number."""
    return [f"{path.relative_to(root)}:{n} {line.strip()}"
            for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1) if ISSUE_NUMBER.search(line)]


def test_no_issue_numbers_in_the_product_or_user_docs() -> None:
    """Product code and user docs speak of the product, not of how it was built: no "issue 23" in
    gatewaylab/, docs/ (docs/decisions.md keeps the history), README.md or benchmarks/."""
    texts = product_texts()
    assert REPO / "gatewaylab" / "bus" / "bus.py" in texts and REPO / "docs" / "architecture.md" in texts
    found = [hit for path in texts for hit in issue_numbers(path)]
    assert not found, "say what the product does instead:\n" + "\n".join(found)


def test_the_issue_number_check_finds_one(tmp_path: Path) -> None:
    """The pattern catches the forms the history used ("issue 23", "Issue 22's", "issues 9 + 15",
    "issue #4") and leaves plain words alone."""
    sample = tmp_path / "sample.md"
    sample.write_text("issue 23\nIssue 22's split\nafter issues 9 + 15\nsee issue #4\nan issue of timing\n")
    assert [hit.split(" ", 1)[0] for hit in issue_numbers(sample, tmp_path)] == [
        "sample.md:1", "sample.md:2", "sample.md:3", "sample.md:4"]


def files_block() -> str:
    """The ``gatewaylab/`` part of the code block under "## Files" in docs/architecture.md."""
    page = (REPO / "docs" / "architecture.md").read_text()
    block = page.split("\n## Files\n", 1)[1].split("```", 2)[1]
    return block.split("\ntests/", 1)[0]


def folder_entry(block: str, folders: tuple[str, ...]) -> str:
    """The text of the Files block that describes ``gatewaylab/<folders...>/``: a room's entry runs from its
    line (``  bus/``) to the next room's; inside it, a folder's from ``name/`` to the next sibling folder's
    ``name/``. The top-level files (no folders) are the lines before the first room."""
    rooms = re.compile(r"^  [a-z_]+/", re.M)
    if not folders:
        first = rooms.search(block)
        assert first is not None
        return block[:first.start()]
    room = re.search(rf"^  {folders[0]}/", block, re.M)
    assert room is not None, f"no entry for gatewaylab/{folders[0]}/"
    text = block[room.end():]
    nxt = rooms.search(text)
    text = text[:nxt.start()] if nxt else text
    for depth in range(1, len(folders)):
        name, parent = folders[depth], ROOT.joinpath(*folders[:depth])
        start = re.search(rf"(?<![\w/]){name}/", text)
        assert start is not None, f"no entry for gatewaylab/{'/'.join(folders[:depth + 1])}/"
        text = text[start.end():]
        siblings = [d.name for d in parent.iterdir() if d.is_dir() and d.name not in (name, "__pycache__")]
        ends = [m.start() for s in siblings if (m := re.search(rf"(?<![\w/]){s}/", text))]
        text = text[:min(ends)] if ends else text
    return text


def test_architecture_names_every_file() -> None:
    """docs/architecture.md's Files block says what every module is for: each ``.py`` file under gatewaylab/
    is named by its file name in its folder's entry (a package's ``__init__.py`` is the folder's line)."""
    block = files_block()
    unnamed = []
    for path in SOURCES:
        if path.name == "__init__.py":
            continue
        folders = path.relative_to(ROOT).parts[:-1]
        if not re.search(rf"(?<![\w/.]){re.escape(path.name)}", folder_entry(block, folders)):
            unnamed.append(_rel(path))
    assert not unnamed, "name these in docs/architecture.md's Files block, in their folder's entry:\n" + "\n".join(
        unnamed)


def test_the_files_check_reads_one_folder_at_a_time() -> None:
    """A file is found only in its own folder's entry: ``bus/timing.py`` is in bus/'s text, not in od/'s;
    ``devices/ecanlite/bittiming.py`` is in ecanlite/'s text, not in esd_can_ethercat/'s."""
    block = files_block()
    assert "timing.py" in folder_entry(block, ("bus",)) and "timing.py" not in folder_entry(block, ("od",))
    assert "bittiming.py" in folder_entry(block, ("devices", "ecanlite"))
    assert "bittiming.py" not in folder_entry(block, ("devices", "esd_can_ethercat"))


def _module_names(tree: ast.Module) -> tuple[list[str] | None, set[str]]:
    """(the names of ``__all__`` or None, every name the module binds at top level)."""
    declared: list[str] | None = None
    bound: set[str] = set()
    for node in tree.body:
        targets: list[ast.expr] = []
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            bound.add(node.name)
        elif isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, ast.AnnAssign):
            targets = [node.target]
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            bound.update((a.asname or a.name).split(".")[0] for a in node.names)
        elif isinstance(node, ast.If):   # TYPE_CHECKING blocks and guarded definitions
            for child in ast.walk(node):
                if isinstance(child, (ast.FunctionDef, ast.ClassDef)):
                    bound.add(child.name)
                elif isinstance(child, (ast.Import, ast.ImportFrom)):
                    bound.update((a.asname or a.name).split(".")[0] for a in child.names)
                elif isinstance(child, ast.Assign):
                    bound.update(t.id for t in child.targets if isinstance(t, ast.Name))
        for target in targets:
            if isinstance(target, ast.Tuple):
                bound.update(e.id for e in target.elts if isinstance(e, ast.Name))
            if isinstance(target, ast.Name):
                bound.add(target.id)
                if target.id == "__all__" and isinstance(node.value, (ast.List, ast.Tuple)):
                    declared = [e.value for e in node.value.elts if isinstance(e, ast.Constant)]
    return declared, bound


def test_every_public_module_declares_all() -> None:
    """One public path per name: every public module of gatewaylab/ (no part of its path starts with ``_``)
    says what it exports in ``__all__``, and each name listed is one the module binds."""
    missing, unbound = [], []
    for path in SOURCES:
        parts = path.relative_to(ROOT).with_suffix("").parts
        if any(p.startswith("_") and p != "__init__" for p in parts):
            continue
        declared, bound = _module_names(ast.parse(path.read_text()))
        if declared is None:
            missing.append(_rel(path))
        else:
            unbound += [f"{_rel(path)}: {name}" for name in declared if name not in bound]
    assert not missing, "modules without __all__:\n" + "\n".join(missing)
    assert not unbound, "__all__ names nothing of that name:\n" + "\n".join(unbound)
