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


# ------------------------------------------------------------------ no back doors between files, no cycles
def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(("gatewaylab", *parts))


ALL_MODULES = sorted(p for p in ROOT.rglob("*.py") if "__pycache__" not in p.parts)
#: dotted name -> True for a package (its ``__init__.py``), False for a plain module
KNOWN: dict[str, bool] = {_module_name(p): p.name == "__init__.py" for p in ALL_MODULES}


def _is_private(name: str) -> bool:
    """A leading underscore that is not a dunder: the file's own business."""
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _absolute(path: Path, node: ast.ImportFrom) -> str:
    """The absolute module an ``ImportFrom`` names (relative imports resolved against ``path``'s package)."""
    if not node.level:
        return node.module or ""
    package = _module_name(path) if path.name == "__init__.py" else _module_name(path).rsplit(".", 1)[0]
    base = package.split(".")[: len(package.split(".")) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _runtime_imports(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement that can run: module level, in functions and classes, in ``try``/``if``
    blocks -- all but the bodies of ``if TYPE_CHECKING:`` (their ``else`` runs and counts)."""
    found: list[ast.Import | ast.ImportFrom] = []

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import | ast.ImportFrom):
            found.append(node)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return found


def _private_segment_outside(module: str, importer: str) -> str | None:
    """The first private segment of ``module`` whose package ``importer`` is not inside, else None: a
    private module (``pkg/_part.py``) is its package's business, re-exported by the package."""
    parts = module.split(".")
    for i, part in enumerate(parts):
        if _is_private(part):
            owner = ".".join(parts[:i])
            if not (importer == owner or importer.startswith(owner + ".")):
                return ".".join(parts[: i + 1])
    return None


def _private_uses(path: Path) -> list[str]:
    """Private names ``path`` takes from another gatewaylab module: ``from x import _y``, ``import
    x._y``, and ``x._y`` on a name bound to an imported gatewaylab module."""
    me = _module_name(path)
    tree = ast.parse(path.read_text(), str(path))
    found: list[str] = []
    modules_bound: dict[str, str] = {}    # local name -> gatewaylab module it is bound to
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            module = _absolute(path, node)
            if not module.startswith("gatewaylab"):
                continue
            if (seg := _private_segment_outside(module, me)) is not None:
                found.append(f"line {node.lineno}: from {module} import ... (private module {seg})")
            for alias in node.names:
                if _is_private(alias.name) and module != me and not (
                        KNOWN.get(f"{module}.{alias.name}") is not None and me.startswith(module + ".")):
                    found.append(f"line {node.lineno}: from {module} import {alias.name}")
                if f"{module}.{alias.name}" in KNOWN:
                    modules_bound[alias.asname or alias.name] = f"{module}.{alias.name}"
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if not alias.name.startswith("gatewaylab"):
                    continue
                if (seg := _private_segment_outside(alias.name, me)) is not None:
                    found.append(f"line {node.lineno}: import {alias.name} (private module {seg})")
                if alias.asname:
                    modules_bound[alias.asname] = alias.name
                else:
                    modules_bound["gatewaylab"] = "gatewaylab"
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Attribute) and _is_private(node.attr)):
            continue
        chain: list[str] = []
        value: ast.expr = node.value
        while isinstance(value, ast.Attribute):
            chain.append(value.attr)
            value = value.value
        if not isinstance(value, ast.Name) or value.id not in modules_bound:
            continue
        target = ".".join([modules_bound[value.id], *reversed(chain)])
        if target in KNOWN and target != me:
            found.append(f"line {node.lineno}: {target}.{node.attr}")
    return found


def test_no_module_takes_a_private_name_from_another() -> None:
    """Issue 30 'No private names across files': a leading underscore (not a dunder) means "this file's
    business", so no gatewaylab module imports one from another module -- ``from x import _y``, ``import
    x._y`` of a private module outside its package, or ``x._y`` on an imported module. What two files
    share gets a public name (in a module of its own where that reads better)."""
    offenders = {str(p.relative_to(ROOT)): uses for p in ALL_MODULES if (uses := _private_uses(p))}
    assert not offenders, "private names taken across files:\n" + "\n".join(
        f"  {path}: {use}" for path, uses in sorted(offenders.items()) for use in uses)


def _edges(path: Path) -> set[str]:
    """The gatewaylab modules ``path`` imports at run time. ``from pkg import name`` leads to the module
    ``pkg.name`` where that is a module, else to ``pkg``. Importing ``a.b.c`` also runs the
    ``__init__`` of the packages on the way (``a.b``): an edge too, except for the packages ``path``
    itself lives in -- those are already importing when it runs, and a package re-exporting its own
    submodules is no cycle."""
    me = _module_name(path)
    targets: set[str] = set()
    for node in _runtime_imports(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets.update(a.name for a in node.names if a.name in KNOWN)
            continue
        module = _absolute(path, node)
        for alias in node.names:
            if f"{module}.{alias.name}" in KNOWN:
                targets.add(f"{module}.{alias.name}")
            elif module in KNOWN:
                targets.add(module)
    out = set(targets)
    for target in targets:
        parts = target.split(".")
        for i in range(1, len(parts)):
            package = ".".join(parts[:i])
            if not (me == package or me.startswith(package + ".")):
                out.add(package)
    out.discard(me)
    return out


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        top = stack.pop()
                        on_stack.discard(top)
                        component.append(top)
                        if top == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def test_no_runtime_import_cycle() -> None:
    """Issue 30 'no runtime import cycle in gatewaylab/': the graph of every import that can run --
    module level and inside functions alike (a function-level import runs when called, so a cycle
    through one is a cycle that only hides until then) -- but not the bodies of ``if TYPE_CHECKING:``,
    which never run. Each file can then be read, and imported, after the files it names."""
    graph = {_module_name(p): _edges(p) for p in ALL_MODULES}
    cycles = _cycles(graph)
    assert not cycles, "import cycles (strongly connected modules):\n" + "\n".join(
        "  " + " <-> ".join(c) + "\n    edges: " + "; ".join(
            f"{a} -> {b}" for a in c for b in sorted(graph[a]) if b in c) for c in cycles)
