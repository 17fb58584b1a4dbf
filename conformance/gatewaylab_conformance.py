"""pytest plugin (the shim): runs python-can's and canopen's own test suites on the `gatewaylab` interface.

Those suites open their buses with ``interface="virtual"``. Here every such bus is a
:class:`~gatewaylab.bus.transport.plugin.GatewaylabBus` connected to a bus of the rig that
``conformance/run.py`` started: each virtual channel name gets its own rig bus (first come,
first served), each ``can.Bus`` its own connection. ``Message.channel`` stays the channel the test
passed, as the interface promises. Tests listed in ``inapplicable.toml`` are skipped with the reason
given there (a class's node id covers all its tests); a listed test that no longer exists is an
error, so the list cannot rot.
"""

from __future__ import annotations

import json
import os
import sys
import tomllib
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def _endpoints() -> list[str]:
    info = json.loads(Path(os.environ["GATEWAYLAB_CONFORMANCE_READY"]).read_text())
    return [bus["endpoint"] for _, bus in sorted(info["buses"].items())]


def pytest_configure(config: pytest.Config) -> None:
    import can.interfaces
    import can.io.printer
    from virtual_on_rig import VirtualOnRig

    # can.Printer's default file is the sys.stdout of the moment python-can is imported, and
    # listener_test stops Printers, which closes it. Run on its own, python-can is first imported
    # while pytest captures a test module's output, so a capture stream gets closed; this plugin
    # imports it earlier, when that would be pytest's own terminal. Same effect as upstream: a
    # default that writes to the sys.stdout of the moment and is never closed.
    can.io.printer.Printer.__init__.__defaults__ = (_Stdout(), False)

    VirtualOnRig.endpoints = _endpoints()
    can.interfaces.BACKENDS["virtual"] = ("virtual_on_rig", "VirtualOnRig")


class _Stdout:
    def write(self, text: str) -> int:
        return sys.stdout.write(text)

    def flush(self) -> None:
        sys.stdout.flush()

    def close(self) -> None:
        pass


def _inapplicable() -> dict[str, str]:
    data = tomllib.loads((HERE / "inapplicable.toml").read_text())
    out: dict[str, str] = {}
    for suite, tests in data.items():
        for test_id, reason in tests.items():
            if not isinstance(reason, str) or not reason.strip():
                raise pytest.UsageError(f"inapplicable.toml [{suite}] {test_id}: give a reason")
            out[test_id] = f"inapplicable to gatewaylab: {reason}"
    return out


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    listed = _inapplicable()
    seen: set[str] = set()
    for item in items:
        for key, reason in listed.items():
            if item.nodeid == key or item.nodeid.startswith(key + "::"):
                seen.add(key)
                item.add_marker(pytest.mark.skip(reason=reason))
                break
    if any("::" in arg for arg in config.args):
        return   # a few tests picked by node id: the list is checked on whole files only
    files = {item.nodeid.split("::")[0] for item in items}
    stale = sorted(key for key in set(listed) - seen if key.split("::")[0] in files)
    if stale:
        raise pytest.UsageError("inapplicable.toml lists tests that were not collected: " + ", ".join(stale))
