"""The MasterBackend contract as check functions, run against every backend.

``test_ec_backend.py`` calls each ``check_*`` with an :class:`InProcessBackend` on a simulated
clock, and (as root) ``ec_backend_driver.py`` calls the same function with a
:class:`PysoemBackend` inside a network namespace, against the same three ``ethercat_io``
slaves answering on the other veth end. Each returns a small JSON-able dict for the checks only
the emulator side can make (FoE store, SYNC0 pulses). Waiting is ``backend.clock.wait``.
"""

from __future__ import annotations

import struct
from typing import Any

from gatewaylab.devices.ethercat_io.device import PRODUCT_CODE, VENDOR_ID
from gatewaylab.ethercat.errors import AlStatusCode, AlStatusError, FoeError, FoeErrorCode
from gatewaylab.ethercat.esc import AlState
from gatewaylab.ethercat.sii import parse_sii
from gatewaylab.hosts.ethercat.backend import MasterBackend, MasterTimeout, SlaveIdentity
from gatewaylab.od import SdoAbort, SdoAbortCode

#: The segment every check runs on: names, serials and revisions (SOEM copies the SII of identical
#: neighbours, so they differ).
SLAVES = [(f"GL-IO #{i}", 1000 + i, i + 1) for i in range(3)]
FOE_PAYLOAD = bytes(range(256)) * 3 + b"tail"


def _raises(exc_type: type[BaseException], fn: Any, *args: Any) -> BaseException:
    try:
        fn(*args)
    except exc_type as exc:
        return exc
    raise AssertionError(f"{fn.__name__}{args} did not raise {exc_type.__name__}")


def check_identity_and_preop(b: MasterBackend) -> dict[str, Any]:
    """Scan: positions in line order, stations 0x1001.., SII identity; every slave in PREOP."""
    assert b.slaves() == [SlaveIdentity(i, 0x1001 + i, name, VENDOR_ID, PRODUCT_CODE, rev, serial)
                          for i, (name, serial, rev) in enumerate(SLAVES)]
    assert [b.state(i) for i in range(3)] == [(AlState.PREOP, 0)] * 3
    return {}


def check_states(b: MasterBackend) -> dict[str, Any]:
    """ETG.1000.6 AL state machine: PREOP -> OP is refused with 0x0011 and the error flag; a new
    request acknowledges the error; INIT and back to PREOP."""
    exc = _raises(AlStatusError, b.request_state, AlState.OP, 1)
    assert exc.code == AlStatusCode.INVALID_STATE_CHANGE
    status, code = b.al_status(1)
    assert status & 0x10 and code == AlStatusCode.INVALID_STATE_CHANGE
    assert b.request_state(AlState.PREOP, 1) == AlState.PREOP
    assert b.al_status(1) == (AlState.PREOP, 0)
    assert b.request_state(AlState.INIT) == AlState.INIT
    assert [b.state(i)[0] for i in range(3)] == [AlState.INIT] * 3
    assert b.request_state(AlState.PREOP) == AlState.PREOP
    assert b.sdo_upload(2, 0x1008, 0) == b"GL-IO #2"     # the mailbox works again after INIT
    return {}


def check_sdo(b: MasterBackend) -> dict[str, Any]:
    """CoE SDO: expedited, normal and segmented transfers, complete access, aborts with their codes."""
    assert b.sdo_upload(0, 0x1008, 0) == b"GL-IO #0"
    assert struct.unpack("<I", b.sdo_upload(1, 0x1018, 1))[0] == VENDOR_ID
    ca = b.sdo_upload(0, 0x1018, 0, complete=True)
    assert ca[0] == 4 and struct.unpack_from("<II", ca, 2) == (VENDOR_ID, PRODUCT_CODE)
    b.sdo_download(0, 0x8000, 2, struct.pack("<I", 4321))
    assert b.sdo_upload(0, 0x8000, 2) == struct.pack("<I", 4321)
    text = bytes(range(33, 127)) * 3 + b"END"
    b.sdo_download(0, 0x8000, 1, text)
    assert b.sdo_upload(0, 0x8000, 1) == text
    aborts = [_raises(SdoAbort, b.sdo_upload, 0, 0x5FFF, 0), _raises(SdoAbort, b.sdo_upload, 0, 0x1018, 9),
              _raises(SdoAbort, b.sdo_download, 0, 0x1018, 1, b"\0\0\0\0")]
    assert [a.code for a in aborts] == [SdoAbortCode.OBJECT_DOES_NOT_EXIST, SdoAbortCode.SUBINDEX_DOES_NOT_EXIST,
                                        SdoAbortCode.READ_ONLY]
    return {}


def check_sdo_information(b: MasterBackend) -> dict[str, Any]:
    """SDO Information: the OD list and the descriptions of 0x1018 and a VAR (0x1000)."""
    info = b.object_info(0, 0x1018)
    assert info.name == "Identity" and info.max_subindex == 4
    assert [e.name for e in info.entries] == ["SubIndex 000", "Vendor ID", "Product code", "Revision",
                                              "Serial number"]
    assert [(e.data_type, e.bit_length) for e in info.entries] == [(5, 8)] + [(7, 32)] * 4
    od = {o.index: o for o in b.object_dictionary(0)}
    assert len(od) >= 19 and {0x1000, 0x1008, 0x1018, 0x1C12, 0x1C13, 0x7010, 0x8000} <= od.keys()
    var = od[0x1000]
    assert var.name == "Device type" and [(e.subindex, e.data_type, e.bit_length) for e in var.entries] == \
        [(0, 7, 32)]
    assert _raises(SdoAbort, b.object_info, 0, 0x5FFF).code == SdoAbortCode.OBJECT_DOES_NOT_EXIST
    return {}


def check_foe(b: MasterBackend) -> dict[str, Any]:
    """FoE (ETG.1000.6): write with progress, read back, a missing file is FoE error 0x8001."""
    seen: list[tuple[int, int]] = []
    b.foe_write(0, "config.bin", FOE_PAYLOAD, progress=lambda done, total: seen.append((done, total)))
    assert seen[-1] == (len(FOE_PAYLOAD), len(FOE_PAYLOAD)) and len(seen) > 3
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)
    got: list[int] = []
    assert b.foe_read(0, "config.bin", progress=lambda done, _total: got.append(done)) == FOE_PAYLOAD
    assert got[-1] == len(FOE_PAYLOAD)
    exc = _raises(FoeError, b.foe_read, 0, "missing.bin")
    assert exc.code == FoeErrorCode.NOT_FOUND and "missing.bin" in str(exc)
    assert b.sdo_upload(0, 0x1008, 0) == b"GL-IO #0"     # SDO after FoE: mailbox counters still agree
    return {"written": "config.bin"}


def check_sii(b: MasterBackend) -> dict[str, Any]:
    """SII (ETG.2010): identity words 0x08..0x0F, the name string, the END category."""
    img = b.sii_read(2)
    assert struct.unpack_from("<IIII", img, 0x10) == (VENDOR_ID, PRODUCT_CODE, 3, 1002)
    assert parse_sii(img).name == "GL-IO #2"
    assert b.sii_info(2).mailbox_out[1] > 0
    return {}


def check_process_data(b: MasterBackend) -> dict[str, Any]:
    """PREOP -> SAFEOP -> OP with process data; expected WKC 2 per output slave + 1 per input slave;
    the ethercat_io inputs echo the outputs of the same cycle (io_device docstring). The images
    exist only once mapped."""
    from gatewaylab.ethercat.errors import MasterError

    _raises(MasterError, b.outputs, 0)
    assert b.config_map() == 3 * (5 + 9)
    assert b.state(0)[0] == AlState.PREOP            # config_map only maps
    assert b.request_state(AlState.SAFEOP) == AlState.SAFEOP
    assert b.request_state(AlState.OP) == AlState.OP
    errors_before = b.wkc_errors
    last: list[bytes] = []
    last_cycle = lost = 0
    for cycle in range(50):
        for pos in range(3):
            out = b.outputs(pos)
            out[0] = (cycle + pos) & 0xFF
            out[1:3] = struct.pack("<h", -pos)
        wkc, expected = b.exchange()
        if wkc < 0:     # no reply within the master's timeout: a lost frame (counted), never a wrong one
            lost += 1
            continue
        assert (wkc, expected) == (9, 9)
        last, last_cycle = [b.inputs(pos) for pos in range(3)], cycle
        b.clock.wait(0.001)
    assert lost <= 1 and b.wkc_errors == errors_before + lost       # tests/wire_kit.py lost_allowed(50)
    for pos in range(3):
        assert last[pos][0] == (last_cycle + pos) & 0xFF
        assert struct.unpack_from("<h", last[pos], 1)[0] == -pos
        assert struct.unpack_from("<I", last[pos], 5)[0] >= 50 - lost
    assert len(b.outputs(0)) == 5 and len(b.inputs(0)) == 9
    assert b.request_state(AlState.PREOP) == AlState.PREOP
    return {}


def check_dc(b: MasterBackend) -> dict[str, Any]:
    """DC SYNC0 (ETG.1000.6 / ESC 0x0981, 0x0990, 0x09A0) programmed in PREOP; the slaves count
    pulses while cycles run in OP."""
    for pos in range(3):
        b.configure_dc(pos, 1_000_000, 100_000)
    b.config_map()
    b.request_state(AlState.SAFEOP)
    b.request_state(AlState.OP)
    start = b.clock.now()
    while b.clock.now() - start < 0.3:
        b.exchange()
        b.clock.wait(0.001)
    b.request_state(AlState.PREOP)
    return {}


def check_bad_position(b: MasterBackend) -> dict[str, Any]:
    """A position past the line is a local error, not a hang."""
    from gatewaylab.ethercat.errors import MasterError

    for call in (lambda: b.state(7), lambda: b.sdo_upload(7, 0x1000, 0), lambda: b.sii_read(7)):
        try:
            call()
        except MasterError:
            continue
        except MasterTimeout as exc:
            raise AssertionError("a bad position timed out") from exc
        raise AssertionError("a bad position was accepted")
    return {}


CHECKS = {name[len("check_"):]: fn for name, fn in globals().items() if name.startswith("check_")}
