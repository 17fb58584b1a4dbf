"""SOEM (pysoem) brings two emulated EtherCAT CiA 402 drives up over a veth pair in a test-made
network namespace: default mapping, power state machine, CSP ramp, EMCY, fault reset, remapping,
DC SYNC0 (ETG.6010, ETG.1020, CiA 402)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from ecdrive_testkit import DriveVeth, serve
from wire_kit import lost_allowed

from gatewaylab.devices.ethercat_drive import PRODUCT_CODE
from gatewaylab.devices.ethercat_io.device import VENDOR_ID

pytestmark = [pytest.mark.net, pytest.mark.slow]
DRIVER = Path(__file__).with_name("ecdrive_soem_driver.py")
STATE_MASK = 0x006F


@pytest.fixture(scope="module")
def run(drive_veth: DriveVeth) -> dict[str, Any]:
    result, _drives = serve(drive_veth, DRIVER)
    return result


def test_soem_finds_two_drives_with_the_default_mapping(run: dict[str, Any]) -> None:
    """ETG.6010 default assignment read by SOEM's config_map over CoE: 0x1C12:01 = 0x1600 (13
    bytes of outputs), 0x1C13:01 = 0x1A00 (15 bytes of inputs); device type 0x00020192 (CiA 402
    servo); both reach OP with the full working counter; SM-synchronous mode without DC."""
    assert run["count"] == 2
    assert [(s["man"], s["id"]) for s in run["slaves"]] == [(VENDOR_ID, PRODUCT_CODE)] * 2
    assert run["device_type"] == 0x00020192
    assert run["assign"] == [0x1600, 0x1A00]
    assert run["rx_map"] == [0x60400010, 0x607A0020, 0x60FF0020, 0x60710010, 0x60600008]
    assert run["sizes"] == [[13, 15], [13, 15]] and run["image"] == 56
    assert run["op"] == 8 and run["expected_wkc"] == 6
    assert run["sync_mode"] == [1, 1]


def test_soem_controlword_sequence_reaches_operation_enabled(run: dict[str, Any]) -> None:
    """CiA 402 transitions 2, 3, 4 (controlword 0x06, 0x07, 0x0F) read back in the statusword of
    the TxPDO: 0x21, 0x23, 0x27 under mask 0x6F, with bit 9 'remote' in OP."""
    enable = run["enable"]
    assert [[sw & STATE_MASK for sw in seen] for seen in enable] == [[0x21, 0x23, 0x27]] * 2   # both drives
    assert [[bool(sw & 0x0200) for sw in seen] for seen in enable] == [[True] * 3] * 2


def test_soem_csp_ramp_for_2s_follows_within_the_window(run: dict[str, Any]) -> None:
    """CSP (mode 8) at 1 kHz for 2 s: every cycle the actual position is within the following
    error window 0x6065 of the previous target, no fault / warning / following error bit; the
    axes end at the last target; 0x6064 by SDO equals the TxPDO."""
    csp = run["csp"]
    assert all(w <= csp["window"] for w in csp["worst"]), csp
    assert csp["flags"] == [0, 0]
    assert all(abs(f - last) <= 10 for f, last in zip(csp["final"], csp["last"], strict=True))
    assert run["csp_position_sdo"] == csp["final"]
    assert run["bad_wkc_default"] == 0
    print(f"lost frames (no reply within 2 ms) in {run['cycles']} cycles: {run['lost']}")
    assert run["lost"] <= lost_allowed(run["cycles"])


def test_soem_following_error_is_an_emcy_and_fault_reset_clears_it(run: dict[str, Any]) -> None:
    """CiA 402 following error -> fault: statusword 'fault', 0x603F = 0x8611 in the TxPDO and a
    CoE emergency 0x8611 (error register generic + profile) through SOEM's emergency callback;
    fault reset (bit 7) -> 'switch on disabled', 0x603F = 0, emergency 0x0000; enable again."""
    fault, reset = run["fault"], run["reset"]
    assert fault["sw"] & STATE_MASK == 0x08 and fault["error"] == 0x8611
    assert fault["emcy"][0] == [0x8611, 0x21]
    assert reset["sw"] & STATE_MASK == 0x40 and reset["error"] == 0 and reset["sdo_603f"] == 0
    assert [0, 0] in reset["emcy"]
    assert run["re_enable"][-1] & STATE_MASK == 0x27


def test_soem_remapped_pdo_set_written_in_preop(run: dict[str, Any]) -> None:
    """PDO assignment written in PREOP (0x1C12 = 0x1601, 0x1C13 = 0x1A01, the fixed CSP PDOs):
    SOEM's config_map reads the new sizes (6 / 6 bytes), OP again, the controlword in the new
    layout is applied (0x06 -> ready to switch on)."""
    assert run["preop"] == 2 and run["remap"]["op"] == 8
    assert run["remap_sizes"] == [[6, 6], [13, 15]]
    assert run["remap_sw"] & STATE_MASK == 0x21


def test_soem_dc_sync0_configured_by_the_master(run: dict[str, Any]) -> None:
    """ETG.1020: SOEM's config_dc + dc_sync(1 ms) activate SYNC0; the drives report sync mode 2
    'DC SYNC0' with cycle time 1,000,000 ns in 0x1C32 and move in CSP sampled at SYNC0."""
    assert run["dc_slaves"]
    assert run["dc"]["op"] == 8
    assert run["dc_sync_mode"] == [[2, 1_000_000], [2, 1_000_000]]
    assert [sw & STATE_MASK for sw in run["dc_enable"]] == [0x21, 0x23, 0x27]
    assert abs(run["dc_final"] - 10 * 499) <= 10 and run["dc_flags"] == 0
    assert run["dc_bad_wkc"] == 0
