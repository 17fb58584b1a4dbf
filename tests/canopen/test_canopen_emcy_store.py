"""EMCY producer with 0x1001/0x1003, and store/restore 0x1010/0x1011 persisted to a file.

Manual: IDX Communication Guide 3.3.3.4 (EMCY: once per error event), table 3-11 (reset node
loads what 0x1010 stored), table 6-20 (0x08000020); CiA 301 7.2.7 and 7.5.2.13-14.
"""

from __future__ import annotations

import json

import canopen
import pytest
from canopen_testkit import RawClient, barrier, remote_for, sample_od

from gatewaylab.bus import CanFrame
from gatewaylab.canopen.emcy import ERR_CURRENT, ERR_TEMPERATURE
from gatewaylab.canopen.node import Node
from gatewaylab.od.aborts import SdoAbortCode


def sdo_code(answer: bytes | None) -> int:
    assert answer is not None
    return 0 if answer[0] in (0x60, 0x43, 0x4B, 0x4F, 0x47) else int.from_bytes(answer[4:], "little")


def test_emcy_frames_register_and_history(make_node, raw, clock) -> None:
    """IDX 3.3.3.4 / CiA 301 7.2.7: EMCY = code, error register, 5 bytes; sent once per error event;
    0x1003 lists the newest first; an error going away sends code 0 with the remaining register."""
    node = make_node()
    clock.advance(0.001)
    raw.received.clear()
    node.emcy.raise_error(0x2310, ERR_CURRENT, b"\x01\x02")
    node.emcy.raise_error(0x2310, ERR_CURRENT, b"\x01\x02")          # same event: not repeated
    node.emcy.raise_error(0x4210, ERR_TEMPERATURE)
    clock.advance(0.001)
    assert raw.take(0x85) == [CanFrame(0x85, bytes([0x10, 0x23, 0x03, 1, 2, 0, 0, 0])),
                              CanFrame(0x85, bytes([0x10, 0x42, 0x0B, 0, 0, 0, 0, 0]))]
    assert node.get(0x1001) == 0x0B
    assert [node.get(0x1003, s) for s in range(3)] == [2, 0x4210, 0x02012310]
    node.emcy.clear_error(0x2310)
    clock.advance(0.001)
    assert raw.take(0x85) == [CanFrame(0x85, bytes([0, 0, 0x09, 0, 0, 0, 0, 0]))]
    node.emcy.clear_error(0x4210)
    clock.advance(0.001)
    assert raw.take(0x85) == [CanFrame(0x85, bytes(8))]
    assert node.get(0x1001) == 0
    # 0x1003:00 = 0 clears the history, anything else is refused
    assert sdo_code(raw.sdo(5, [0x2F, 0x03, 0x10, 0x00, 0x01])) == SdoAbortCode.VALUE_RANGE_EXCEEDED
    assert sdo_code(raw.sdo(5, [0x2F, 0x03, 0x10, 0x00, 0x00])) == 0
    assert node.get(0x1003, 0) == 0


def test_emcy_seen_by_python_canopen(make_node, network) -> None:
    """Interop: python-canopen's EMCY consumer decodes our EMCY frames."""
    node = make_node()
    remote = remote_for(network, node)
    node.emcy.raise_error(0x8130, 0x10, b"\x07")
    barrier(remote)
    assert [(e.code, e.register, e.data) for e in remote.emcy.active] == [(0x8130, 0x11, b"\x07\x00\x00\x00\x00")]
    node.emcy.clear_error(0x8130)
    barrier(remote)
    assert remote.emcy.active == [] and len(remote.emcy.log) == 2


def test_emcy_inhibit_time_and_disable(make_node, raw, clock, sniffer) -> None:
    """CiA 301 7.5.2.15/16: 0x1015 (x100 us) spaces EMCY messages; COB-ID bit 31 disables them;
    in Stopped they are not sent (IDX table 3-11) but still recorded in 0x1003."""
    node = make_node()
    assert sdo_code(raw.sdo(5, [0x2B, 0x15, 0x10, 0x00, 100, 0])) == 0          # 10 ms
    sniffer.clear()
    node.emcy.raise_error(0x1000)
    node.emcy.raise_error(0x2000)
    clock.advance(0.05)
    times = [t for t, _ in sniffer.ids(0x85)]
    assert len(times) == 2 and times[1] - times[0] >= 0.01 - 1e-9
    raw.send(0, [0x02, 5])
    sniffer.clear()
    node.emcy.raise_error(0x3000)
    clock.advance(0.05)
    assert sniffer.ids(0x85) == [] and node.get(0x1003, 1) == 0x3000
    raw.send(0, [0x80, 5])
    assert sdo_code(raw.sdo(5, [0x23, 0x14, 0x10, 0x00, 0x85, 0, 0, 0x80])) == 0
    node.emcy.raise_error(0x5000)
    clock.advance(0.05)
    assert sniffer.ids(0x85) == []


def _save(raw: RawClient, sub: int, signature: bytes = b"save") -> int:
    return sdo_code(raw.sdo(5, bytes([0x23, 0x10, 0x10, sub]) + signature))


def test_store_survives_reset_and_power_cycle(make_node, raw, clock, vbus, tmp_path) -> None:
    """IDX table 3-11 (reset node) / CiA 301 7.5.2.13: 'save' to 0x1010 keeps the parameters in a
    file; a reset node and a new node on the same file come back with them."""
    path = tmp_path / "node5.json"
    node = make_node(store_path=path)
    assert sdo_code(raw.sdo(5, [0x2B, 0x17, 0x10, 0x00, 0xE8, 0x03])) == 0       # 0x1017 = 1000
    assert sdo_code(raw.sdo(5, [0x2F, 0x00, 0x60, 0x00, 0x2A])) == 0             # 0x6000 = 42
    assert sdo_code(raw.sdo(5, [0x40, 0x10, 0x10, 0x01])) == 0
    assert raw.sdo(5, [0x40, 0x10, 0x10, 0x01])[4:] == b"\x01\x00\x00\x00"       # device saves on command
    assert _save(raw, 1, b"safe") == SdoAbortCode.DATA_CANNOT_BE_STORED
    assert not path.exists()
    assert _save(raw, 1) == 0
    stored = json.loads(path.read_text())["values"]
    assert stored["101700"] == "e803" and stored["600000"] == "2a"
    raw.send(0, [0x81, 5])
    assert node.get(0x1017) == 1000 and node.get(0x6000) == 42
    node.stop()
    again = Node(clock, vbus, 5, sample_od(), store_path=path)
    again.start()
    assert again.get(0x1017) == 1000 and again.get(0x6000) == 42


def test_restore_defaults_after_reset(make_node, network, tmp_path) -> None:
    """CiA 301 7.5.2.14 via python-canopen's store()/restore(): 'load' forgets the stored values;
    the defaults are back after the next reset."""
    path = tmp_path / "node5.json"
    node = make_node(store_path=path)
    remote = remote_for(network, node)
    remote.sdo[0x6000].raw = 77
    remote.sdo[0x1017].raw = 500
    remote.store(3)                                   # application only
    remote.nmt.state = "RESET"
    barrier(remote)
    assert node.get(0x6000) == 77 and node.get(0x1017) == 0
    remote.restore(1)
    assert node.get(0x6000) == 77                     # takes effect with the next reset
    remote.nmt.state = "RESET"
    barrier(remote)
    assert node.get(0x6000) == 3
    assert json.loads(path.read_text())["values"] == {}
    with pytest.raises(canopen.SdoAbortedError) as info:
        remote.sdo.download(0x1011, 1, b"lead")
    assert info.value.code == SdoAbortCode.DATA_CANNOT_BE_STORED


def test_sync_counter_rules(make_node, raw) -> None:
    """CiA 301 7.5.2.22: 0x1019 accepts 0 and 2..240, and only while 0x1006 is 0 (else 0x08000022)."""
    make_node()
    assert sdo_code(raw.sdo(5, [0x2F, 0x19, 0x10, 0x00, 1])) == SdoAbortCode.VALUE_RANGE_EXCEEDED
    assert sdo_code(raw.sdo(5, [0x2F, 0x19, 0x10, 0x00, 241])) == SdoAbortCode.VALUE_RANGE_EXCEEDED
    assert sdo_code(raw.sdo(5, [0x2F, 0x19, 0x10, 0x00, 2])) == 0
    assert sdo_code(raw.sdo(5, [0x23, 0x06, 0x10, 0x00, 0x10, 0x27, 0, 0])) == 0
    assert sdo_code(raw.sdo(5, [0x2F, 0x19, 0x10, 0x00, 3])) == SdoAbortCode.DATA_CANNOT_BE_STORED_DEVICE_STATE


def test_sync_producer(make_node, raw, sniffer, clock) -> None:
    """CiA 301 7.5.2.5: bit 30 of 0x1005 makes the node produce SYNC every 0x1006 us, with the
    counter of 0x1019 running 1..n."""
    node = make_node()
    assert sdo_code(raw.sdo(5, [0x2F, 0x19, 0x10, 0x00, 3])) == 0
    assert sdo_code(raw.sdo(5, [0x23, 0x06, 0x10, 0x00, 0x10, 0x27, 0, 0])) == 0         # 10 ms
    assert sdo_code(raw.sdo(5, [0x23, 0x05, 0x10, 0x00, 0x80, 0, 0, 0x40])) == 0
    sniffer.clear()
    clock.advance(0.055)
    assert [f.data for _, f in sniffer.ids(0x80)] == [b"\x01", b"\x02", b"\x03", b"\x01", b"\x02"]
    assert node.sync.received == 5


def test_store_object_replaces_the_file(make_node, raw, clock, vbus) -> None:
    """CiA 301 7.5.2.13: 'save' keeps the parameters in the node's store object (here memory, no
    file); a new node given the same store comes back with them."""
    from gatewaylab.common.store import MemoryStore

    store = MemoryStore()
    node = make_node(store=store)
    assert sdo_code(raw.sdo(5, [0x2B, 0x17, 0x10, 0x00, 0xE8, 0x03])) == 0       # 0x1017 = 1000
    assert _save(raw, 2) == 0
    saved = store.load()
    assert saved is not None and saved["values"]["101700"] == "e803"
    node.stop()
    again = Node(clock, vbus, 5, sample_od(), store=store)
    again.start()
    assert again.get(0x1017) == 1000
