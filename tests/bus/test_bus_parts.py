"""The parts of the virtual bus talk through named interfaces: each file of ``gatewaylab/bus/`` reads alone.

A controller asks its bus only what :class:`ControllerBus` names, the fault injector only what
:class:`FaultedBus` names (``VirtualBus`` implements both; mypy checks that in ``bus.py``), and no file
reaches into another object's underscore names.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import gatewaylab.bus
from gatewaylab.bus.controller import ControllerBus
from gatewaylab.bus.faults import FaultedBus

BUS = Path(gatewaylab.bus.__file__).resolve().parent
#: the files VirtualBus is made of
PARTS = ("bus.py", "controller.py", "faults.py", "audience.py", "stats.py", "transmission.py")


def members(protocol: type) -> set[str]:
    """The public names a Protocol declares (attributes, properties, methods)."""
    names = {n for n in vars(protocol) if not n.startswith("_")}
    return names | {n for n in getattr(protocol, "__annotations__", {}) if not n.startswith("_")}


def bus_uses(source: str, class_name: str) -> set[str]:
    """Every attribute the class reads or calls on its bus: ``self.bus.X`` and ``bus.X`` where a method
    took ``bus = self.bus``."""
    tree = ast.parse(source)
    cls = next(n for n in ast.walk(tree) if isinstance(n, ast.ClassDef) and n.name == class_name)
    used: set[str] = set()
    for node in ast.walk(cls):
        if not isinstance(node, ast.Attribute):
            continue
        value = node.value
        local_bus = isinstance(value, ast.Name) and value.id == "bus"
        self_bus = (isinstance(value, ast.Attribute) and value.attr == "bus"
                    and isinstance(value.value, ast.Name) and value.value.id == "self")
        if local_bus or self_bus:
            used.add(node.attr)
    return used


@pytest.mark.parametrize(("path", "class_name", "protocol"), [
    ("controller.py", "Controller", ControllerBus),
    ("faults.py", "BusFaults", FaultedBus),
])
def test_a_part_uses_only_its_bus_interface(path: str, class_name: str, protocol: type) -> None:
    """What a part calls on its bus is declared in its Protocol (the list a reader of that file sees)."""
    used = bus_uses((BUS / path).read_text(), class_name)
    assert used, f"{class_name} reads nothing of its bus: the check looks at the wrong names"
    assert used <= members(protocol), f"{class_name} uses {sorted(used - members(protocol))} beyond {protocol.__name__}"


def foreign_private(path: Path) -> list[str]:
    """``x._name`` where ``x`` is not ``self``: another object's underscore name."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")
                and not (isinstance(node.value, ast.Name) and node.value.id in {"self", "cls"})):
            found.append(f"{path.name}:{node.lineno} .{node.attr}")
    return found


@pytest.mark.parametrize("name", PARTS)
def test_no_part_reaches_into_another_objects_private_names(name: str) -> None:
    """No file of the bus calls or reads another object's underscore members (issue: the parts called each
    other's ``_invalidate``, ``_kick``, ``_hold``, ``_update_state``, ``_head_key``)."""
    assert foreign_private(BUS / name) == []


def test_the_check_finds_a_foreign_private_name(tmp_path: Path) -> None:
    """The AST check above sees what it must: ``bus._kick()`` is found, ``self._kick()`` is not."""
    sample = tmp_path / "sample.py"
    sample.write_text("def f(self, bus):\n    self._kick()\n    bus._kick()\n")
    assert foreign_private(sample) == ["sample.py:3 ._kick"]
