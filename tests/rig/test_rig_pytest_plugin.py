"""gatewaylab's pytest plugin (issue 24, 'pytest plugin'): the ``gatewaylab_rig`` fixture factory used by
this module itself -- a simulated rig from a dict, a real-time `gatewaylab run` child with socketcand, an
in-process real-time rig -- and a user's own suite run with pytest-xdist, every worker starting rigs
that never collide, plus the root/veth markers."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import can
import canopen
import pytest

from gatewaylab.rig.process import rig_toml

DRIVE = {"bus": "can0", "node_id": 2, "serial": 0x1002, "name": "axis2"}
ROOT = Path(__file__).resolve().parents[2]


def test_simulated_rig_from_a_dict(gatewaylab_rig) -> None:
    """clock="simulated": an in-process rig the test drives; canopen reads the drive's 0x1008 (CiA 301
    SDO upload) through ``handle.can_bus()`` without anybody advancing the clock."""
    handle = gatewaylab_rig({"bus": [{"name": "can0"}], "drive": [DRIVE]}, clock="simulated")
    assert handle.clock.is_simulated and handle.rig is not None
    network = canopen.Network(handle.can_bus())
    network.connect()
    try:
        node = network.add_node(2, handle.eds("axis2"))
        assert "gatewaylab" in node.sdo[0x1008].raw
    finally:
        network.disconnect()


def test_realtime_child_process_with_socketcand(gatewaylab_rig) -> None:
    """The default: `gatewaylab run` as a child (a master in another process sees what a user's does);
    its ready file is ``handle.info``; a gatewaylab-interface client and a socketcand client share can0."""
    handle = gatewaylab_rig({"bus": [{"name": "can0", "socketcand": True}], "drive": [DRIVE]})
    assert handle.process is not None and handle.process.proc.poll() is None
    plugin_bus = handle.can_bus()
    sc_bus = can.Bus(interface="socketcand", host="127.0.0.1", port=handle.socketcand(), channel="can0")
    try:
        sc_bus.send(can.Message(arbitration_id=0x7A1, data=b"\x01", is_extended_id=False))
        msg = plugin_bus.recv(10)
        while msg is not None and msg.arbitration_id != 0x7A1:
            msg = plugin_bus.recv(10)
        assert msg is not None and bytes(msg.data) == b"\x01"
    finally:
        sc_bus.shutdown()


def test_in_process_realtime_rig(gatewaylab_rig) -> None:
    """in_process=True: the rig runs on a thread of the test process; its endpoints are in its own state
    folder."""
    handle = gatewaylab_rig({"bus": [{"name": "can0"}], "drive": [DRIVE]}, in_process=True)
    assert handle.rig is not None and not handle.clock.is_simulated
    assert handle.endpoint().startswith("unix:") and str(handle.rig.state_dir) in handle.endpoint()
    network = canopen.Network(handle.can_bus())
    network.connect()
    try:
        assert "gatewaylab" in network.add_node(2, handle.eds("axis2")).sdo[0x1008].raw
    finally:
        network.disconnect()


def test_rig_dicts_become_rig_files() -> None:
    """What the fixture writes for a dict reads back as the same dict (TOML 1.0: arrays of tables, inline
    tables, strings with quotes and backslashes)."""
    data = {"clock": "realtime", "bus": [{"name": "can0", "bitrate": 500000, "timing": False},
                                         {"name": "can 1", "data_bitrate": 2000000}],
            "device": [{"kind": "maxon_idx", "name": 'i"d\\x', "usb": {"pty": True, "tcp_port": 0},
                        "ratios": [1.5, 2]}],
            "ethercat": {"interface": "veth0"}}
    assert tomllib.loads(rig_toml(data)) == data


def doc_suite() -> str:
    """The suite of docs/testing-your-master.md (the python block after its ``file: test_my_master.py``)."""
    text = (ROOT / "docs" / "testing-your-master.md").read_text()
    block = text.split("<!-- file: test_my_master.py -->", 1)[1].split("```python\n", 1)[1]
    return block.split("```", 1)[0]


USER_CONFTEST = '''
import gatewaylab.rig.pytest_plugin as plugin

plugin._veth_unavailable = lambda: "pretend: no veth pairs on this machine"
'''


def test_a_users_suite_with_xdist_workers(tmp_path: Path) -> None:
    """The suite of docs/testing-your-master.md under pytest-xdist: two workers start five rigs (each its
    own state folder, work folder and ports) and every test passes; a gatewaylab_veth test is skipped
    with its reason where veth pairs are missing."""
    (tmp_path / "test_master.py").write_text(doc_suite())
    (tmp_path / "conftest.py").write_text(textwrap.dedent(USER_CONFTEST))
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "2", "-p", "gatewaylab.rig.pytest_plugin",
                          "-rs", "-p", "no:cacheprovider", "test_master.py"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    out = run.stdout + run.stderr
    assert run.returncode == 0, out
    passed = 6 if os.geteuid() == 0 else 5          # test_needs_root runs only as root
    assert f"{passed} passed" in out and "pretend: no veth pairs on this machine" in out, out


@pytest.mark.gatewaylab_root
def test_the_root_marker_runs_as_root() -> None:
    """Marked gatewaylab_root: it runs only as root (skipped otherwise, with the reason)."""
    assert os.geteuid() == 0


def test_plugin_is_registered_once(pytestconfig: pytest.Config) -> None:
    """The pytest11 entry point is named after the module, so conftest's pytest_plugins and the entry
    point are one registration."""
    found = [p for p in pytestconfig.pluginmanager.get_plugins()
             if getattr(p, "__name__", "") == "gatewaylab.rig.pytest_plugin"]
    assert len(found) == 1
    text = (ROOT / "pyproject.toml").read_text()
    assert '"gatewaylab.rig.pytest_plugin" = "gatewaylab.rig.pytest_plugin"' in text
