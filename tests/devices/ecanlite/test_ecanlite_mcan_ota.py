"""FoE OTA of the ECAN-Lite application and ``gatewaylab ecan pack`` (manual 15.3.1, 13.7, 13.8)."""

from __future__ import annotations

import os
import subprocess
import sys
import zlib
from pathlib import Path

import pytest
from ecanlite_mcan_kit import Rig, make_rig

from gatewaylab.devices.ecanlite.ota import (
    APP_FILE_NAME,
    HEADER_SIZE,
    FirmwareVersion,
    OtaError,
    pack,
    unpack,
)
from gatewaylab.ethercat.errors import FoeError, FoeErrorCode
from gatewaylab.ethercat.foe import FoeOpcode, FoeServer, foe_packet

APP = bytes(range(256)) * 20


def _write(rig: Rig, name: str, password: int, data: bytes) -> tuple[list[float], int]:
    """A master's FoE write through the slave's FoeServer: returns (resets, FoE error code or 0)."""
    resets: list[float] = []
    server = FoeServer(rig.model.ota_handler(lambda: resets.append(rig.clock.now())), 128)
    replies = server.handle(foe_packet(FoeOpcode.WRQ, password, name.encode()))
    n = 0
    chunk = server.max_data
    pos = 0
    while True:
        part = data[pos:pos + chunk]
        n += 1
        replies = server.handle(foe_packet(FoeOpcode.DATA, n, part))
        if replies and replies[0][0] == FoeOpcode.ERR:
            return resets, int.from_bytes(replies[0][2:6], "little")
        pos += len(part)
        if len(part) < chunk:
            return resets, 0


def test_good_package_updates_version_and_resets() -> None:
    """15.3.1: 'ecan_lite_app', password 0, packaged image -> the device resets and 0xF000:05/06
    (and 0x100A) show the new version; 0xB000:09..11 report the image."""
    rig = make_rig()
    package = pack(APP, FirmwareVersion(1, 4, 0x2291))
    resets, code = _write(rig, APP_FILE_NAME, 0, package)
    assert code == 0 and len(resets) == 1
    assert rig.model.version == FirmwareVersion(1, 4, 0x2291)
    assert (rig.r(0xF000, 5), rig.r(0xF000, 6)) == (0x0104, 0x2291)
    assert rig.od.read(0x100A, 0) == b"1.4 build 0x2291"
    assert (rig.r(0xB000, 9), rig.r(0xB000, 10), rig.r(0xB000, 11)) == (len(package), zlib.crc32(package), 0)


@pytest.mark.parametrize(("name", "password", "mangle", "code"), [
    ("ecan_lite_boot", 0, None, FoeErrorCode.NOT_FOUND),
    (APP_FILE_NAME, 1234, None, FoeErrorCode.NO_RIGHTS),
    (APP_FILE_NAME, 0, "bare", FoeErrorCode.PROGRAM_ERROR),
    (APP_FILE_NAME, 0, "payload", FoeErrorCode.PROGRAM_ERROR),
    (APP_FILE_NAME, 0, "header", FoeErrorCode.PROGRAM_ERROR),
    (APP_FILE_NAME, 0, "short", FoeErrorCode.PROGRAM_ERROR),
    (APP_FILE_NAME, 0, "device", FoeErrorCode.PROGRAM_ERROR),
])
def test_bad_updates_keep_version(name: str, password: int, mangle: str | None, code: int) -> None:
    """15.3.1 common mistakes: 'Password invalid', 'FoE OTA verify failed' (not packaged, header
    or CRC mismatch): the master gets an FoE error, the version stays, no reset; 0xB000:11 keeps
    the code."""
    rig = make_rig()
    data = pack(APP, FirmwareVersion(1, 4, 0x2291))
    if mangle == "bare":
        data = APP
    elif mangle == "payload":
        data = data[:-1] + bytes([data[-1] ^ 1])
    elif mangle == "header":
        data = data[:12] + bytes([data[12] ^ 1]) + data[13:]
    elif mangle == "short":
        data = data[:-10]
    elif mangle == "device":
        data = pack(APP, FirmwareVersion(1, 4, 0x2291), device_type=7)
    resets, got = _write(rig, name, password, data)
    assert got == code and resets == []
    assert rig.model.version == FirmwareVersion(1, 3, 0x2100)
    assert rig.r(0xF000, 5) == 0x0103
    assert rig.r(0xB000, 11) == code


def test_firmware_cannot_be_read_back() -> None:
    """15.3.1: the application file is write-only (FoE access denied); other names are not found."""
    handler = make_rig().model.ota_handler(lambda: None)
    with pytest.raises(FoeError) as exc:
        handler.foe_read(APP_FILE_NAME, 0)
    assert exc.value.code == FoeErrorCode.ACCESS_DENIED


def test_package_header_layout() -> None:
    """The package header (docs/devices/ecanlite-mcan.md): magic, header version/size, device word,
    version word (0xF000:05 = major << 8 | minor, :06 = build), payload size and CRC32, header CRC32."""
    data = pack(b"\x01\x02\x03", FirmwareVersion(1, 4, 0x2291))
    assert len(data) == HEADER_SIZE + 3 == 35
    assert data[:4] == b"ECLA"
    assert data[4:8] == b"\x01\x00\x20\x00"
    assert int.from_bytes(data[8:12], "little") >> 24 == 0
    assert int.from_bytes(data[12:16], "little") == 0x01042291
    assert int.from_bytes(data[16:20], "little") == 3
    assert int.from_bytes(data[20:24], "little") == zlib.crc32(b"\x01\x02\x03")
    assert int.from_bytes(data[28:32], "little") == zlib.crc32(data[:28])
    assert unpack(data).payload == b"\x01\x02\x03"
    with pytest.raises(OtaError):
        pack(b"x", FirmwareVersion(256, 0, 0))


def test_maintenance_validate_and_activate() -> None:
    """13.7 bit3 'FoE image validate' / bit4 'FoE image activate' act on the last FoE image;
    activation needs engineering access (denied 2 in run mode), a bad image is 'image invalid' 4."""
    rig = make_rig()
    _write(rig, APP_FILE_NAME, 0, APP)                # bare: refused
    rig.w(0xB000, 4, 0x08)
    assert rig.r(0xB000, 5) == 4
    _write(rig, APP_FILE_NAME, 0, pack(APP, FirmwareVersion(2, 0, 1)))
    rig.w(0xB000, 4, 0x08)
    assert rig.r(0xB000, 5) == 0
    rig.w(0xB000, 4, 0x10)
    assert rig.r(0xB000, 5) == 2
    rig.w(0xB000, 1, 1)
    rig.w(0xB000, 4, 0x10)
    rig.run(0.001)
    assert rig.r(0xB000, 5) == 0 and rig.reboots


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": "100"}
    return subprocess.run([sys.executable, "-m", "gatewaylab", "ecan", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=60, check=False)


def test_pack_command(tmp_path: Path) -> None:
    """15.3.1 'Use the packaged ecan_lite_v*.bin, not the bare app bin': ``gatewaylab ecan pack
    APP.bin --version 1.4 --build 0x2291 -o ecan_lite_v140.bin`` writes a package the device takes."""
    (tmp_path / "APP.bin").write_bytes(APP)
    done = _cli("pack", "APP.bin", "--version", "1.4", "--build", "0x2291", "-o", "ecan_lite_v140.bin",
                cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "1.4 build 0x2291" in done.stdout
    package = unpack((tmp_path / "ecan_lite_v140.bin").read_bytes())
    assert package.version == FirmwareVersion(1, 4, 0x2291) and package.payload == APP
    rig = make_rig()
    resets, code = _write(rig, APP_FILE_NAME, 0, (tmp_path / "ecan_lite_v140.bin").read_bytes())
    assert code == 0 and resets


@pytest.mark.parametrize("args", [
    ("pack", "APP.bin", "--version", "1.x", "--build", "1", "-o", "o.bin"),
    ("pack", "APP.bin", "--version", "1.4", "--build", "0x10000", "-o", "o.bin"),
    ("pack", "missing.bin", "--version", "1.4", "--build", "1", "-o", "o.bin"),
    ("pack", "APP.bin", "--version", "1.4", "--build", "1"),
    ("pack", "PKG.bin", "--version", "1.4", "--build", "1", "-o", "o.bin"),
])
def test_pack_command_errors(tmp_path: Path, args: tuple[str, ...]) -> None:
    """Errors a user can act on: exit code 2 and one line on stderr, no traceback, no output file."""
    (tmp_path / "APP.bin").write_bytes(APP)
    (tmp_path / "PKG.bin").write_bytes(pack(APP, FirmwareVersion(1, 0, 0)))
    done = _cli(*args, cwd=tmp_path)
    assert done.returncode == 2
    assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr
    assert not (tmp_path / "o.bin").exists()


def test_pack_help_has_example(tmp_path: Path) -> None:
    """``--help`` shows a worked example."""
    done = _cli("pack", "--help", cwd=tmp_path)
    assert done.returncode == 0
    assert "gatewaylab ecan pack APP.bin --version 1.4 --build 0x2291 -o ecan_lite_v140.bin" in done.stdout


def test_new_firmware_survives_the_reset(tmp_path: Path) -> None:
    """15.3.1 'the firmware writes to the free APP partition and requests a reset': a model built
    after the reset on the same flash (file or the in-memory medium) runs the new version."""
    path = tmp_path / "ecan.flash"
    rig = make_rig(flash_path=path)
    resets, code = _write(rig, APP_FILE_NAME, 0, pack(APP, FirmwareVersion(1, 4, 0x2291)))
    assert code == 0 and resets
    rig.model.close()
    again = make_rig(flash_path=path)
    assert tuple(again.model.version) == (1, 4, 0x2291)
    assert again.r(0xF000, 5) == 0x0104
    major, minor, build = again.model.version
    assert (major, minor, build) == (1, 4, 0x2291)
    mem = make_rig()
    _write(mem, APP_FILE_NAME, 0, pack(APP, FirmwareVersion(1, 5, 7)))
    from gatewaylab.devices.ecanlite.model import McanModel
    fresh = McanModel(mem.clock, [], mem.model.flash)
    assert fresh.version == FirmwareVersion(1, 5, 7)
    assert McanModel(mem.clock, [], None).version == FirmwareVersion(1, 3, 0x2100)
