"""FoE firmware update of the ECAN-Lite (manual 15.3.1) and its package format.

The manual fixes the FoE file name (``ecan_lite_app``), the password (0) and that only a
*packaged* image is accepted; it names the header fields 0xF000 shows (device[31:24],
version[31:16] = major.minor, version[15:0] = build) but not the layout. gatewaylab's package is a
32-byte little-endian header followed by the bare application::

    off size field
    0   4    magic          "ECLA"
    4   2    header_version 1
    6   2    header_size    32
    8   4    device         bits 31..24 device type (0 = ECAN-Lite, 0xF000:01), 23..0 = 0x00EC4C
    12  4    version        bits 31..16 = major << 8 | minor (0xF000:05), 15..0 = build (0xF000:06)
    16  4    payload_size   bytes of the application after the header
    20  4    payload_crc32  zlib.crc32 of the application
    24  4    reserved       0
    28  4    header_crc32   zlib.crc32 of bytes 0..27

What a master sees (FoE error codes of ETG.1000.6): another file name -> 0x8001 not found, a
password other than 0 -> 0x800A no rights, a bare or corrupted image -> 0x800B program error with
the manual's text "FoE OTA verify failed", an image larger than the APP partition -> 0x8003 disk
full, reading the file back -> 0x8002 access denied.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from gatewaylab.common.errors import LocalError
from gatewaylab.ethercat.errors import FoeError, FoeErrorCode

__all__ = [
    "APP_FILE_NAME",
    "APP_PASSWORD",
    "DEVICE_FAMILY",
    "HEADER_SIZE",
    "HEADER_VERSION",
    "MAX_APP_BYTES",
    "PACKAGE_MAGIC",
    "FirmwareVersion",
    "OtaError",
    "OtaHandler",
    "OtaStatus",
    "Package",
    "pack",
    "unpack",
]


APP_FILE_NAME = "ecan_lite_app"
APP_PASSWORD = 0
PACKAGE_MAGIC = b"ECLA"
HEADER_VERSION = 1
_HEADER = struct.Struct("<4sHHIIIII")
_HEADER_CRC = struct.Struct("<I")
HEADER_SIZE = _HEADER.size + _HEADER_CRC.size
#: Low 24 bits of the device word: the ECAN-Lite hardware family.
DEVICE_FAMILY = 0x00EC4C
#: Largest application the free APP partition takes (1 MiB).
MAX_APP_BYTES = 1 << 20


class OtaError(LocalError):
    """A package that cannot be installed; ``foe_code`` is what the master sees."""

    def __init__(self, message: str, foe_code: FoeErrorCode = FoeErrorCode.PROGRAM_ERROR) -> None:
        super().__init__(message, int(foe_code))
        self.foe_code = foe_code


@dataclass(frozen=True, slots=True)
class FirmwareVersion:
    """major.minor and the 16-bit build (0xF000:05 = major << 8 | minor, 0xF000:06 = build)."""

    major: int
    minor: int
    build: int

    @property
    def word(self) -> int:
        """The package header's version u32."""
        return ((self.major & 0xFF) << 24) | ((self.minor & 0xFF) << 16) | (self.build & 0xFFFF)

    @property
    def major_minor(self) -> int:
        """0xF000:05: high byte major, low byte minor."""
        return ((self.major & 0xFF) << 8) | (self.minor & 0xFF)

    def __str__(self) -> str:
        return f"{self.major}.{self.minor} build 0x{self.build:04X}"

    def __iter__(self) -> Iterator[int]:
        """``major, minor, build = version``."""
        return iter((self.major, self.minor, self.build))


@dataclass(frozen=True, slots=True)
class Package:
    """A verified firmware package."""

    device_type: int
    version: FirmwareVersion
    payload: bytes


def pack(app: bytes, version: FirmwareVersion, device_type: int = 0) -> bytes:
    """Wrap a bare application into a package (what ``gatewaylab ecan pack`` writes)."""
    if not 0 <= device_type <= 0xFF:
        raise OtaError(f"device type {device_type} outside 0..255")
    if not (0 <= version.major <= 0xFF and 0 <= version.minor <= 0xFF and 0 <= version.build <= 0xFFFF):
        raise OtaError(f"version {version.major}.{version.minor} build {version.build} does not fit the header")
    head = _HEADER.pack(PACKAGE_MAGIC, HEADER_VERSION, HEADER_SIZE, (device_type << 24) | DEVICE_FAMILY,
                        version.word, len(app), zlib.crc32(app), 0)
    return head + _HEADER_CRC.pack(zlib.crc32(head)) + app


def unpack(image: bytes, device_type: int = 0) -> Package:
    """Verify a package (header, CRCs, size, device type); :class:`OtaError` otherwise."""
    if len(image) < HEADER_SIZE or image[:4] != PACKAGE_MAGIC:
        raise OtaError("FoE OTA verify failed: not a packaged image (bare application?)")
    _magic, hver, hsize, device, version, size, crc, _res = _HEADER.unpack_from(image)
    (hcrc,) = _HEADER_CRC.unpack_from(image, _HEADER.size)
    if zlib.crc32(image[:_HEADER.size]) != hcrc:
        raise OtaError("FoE OTA verify failed: header CRC32 mismatch")
    if hver != HEADER_VERSION or hsize != HEADER_SIZE:
        raise OtaError(f"FoE OTA verify failed: header version {hver} size {hsize} unsupported")
    if device >> 24 != device_type or device & 0xFFFFFF != DEVICE_FAMILY:
        raise OtaError(f"FoE OTA verify failed: package for device 0x{device:08X}")
    payload = image[HEADER_SIZE:]
    if len(payload) != size:
        raise OtaError(f"FoE OTA verify failed: payload is {len(payload)} bytes, header says {size}")
    if zlib.crc32(payload) != crc:
        raise OtaError("FoE OTA verify failed: payload CRC32 mismatch")
    return Package(device >> 24, FirmwareVersion(version >> 24, (version >> 16) & 0xFF, version & 0xFFFF),
                   payload)


@dataclass
class OtaStatus:
    """What 0xB000:09..11 report about the most recent FoE image."""

    image_size: int = 0
    image_crc32: int = 0
    #: 0 = OK, else the FoE error code sent to the master.
    status_code: int = 0
    last_image: bytes = b""


class OtaHandler:
    """The device's :class:`~gatewaylab.ethercat.foe.FoeHandler` for ``ecan_lite_app``.

    A good package calls ``install(package, data)`` (the model writes the APP partition and takes
    the new version) and then ``on_accepted()`` (the device resets); anything else raises the FoE
    error the master shows, and nothing changes.
    """

    def __init__(self, install: Callable[[Package, bytes], None], on_accepted: Callable[[], None],
                 status: OtaStatus, device_type: int = 0) -> None:
        self._install = install
        self._on_accepted = on_accepted
        self.status = status
        self.device_type = device_type

    def foe_read(self, name: str, password: int) -> bytes:
        """The application cannot be read back."""
        if name != APP_FILE_NAME:
            raise FoeError(f"no file {name!r}", FoeErrorCode.NOT_FOUND)
        raise FoeError(f"{APP_FILE_NAME} cannot be read", FoeErrorCode.ACCESS_DENIED)

    def foe_write(self, name: str, password: int, data: bytes) -> None:
        """Verify and install a package; refuse with the FoE error code otherwise."""
        try:
            if name != APP_FILE_NAME:
                raise OtaError(f"no file {name!r} (the firmware is {APP_FILE_NAME})", FoeErrorCode.NOT_FOUND)
            if password != APP_PASSWORD:
                raise OtaError("Password invalid", FoeErrorCode.NO_RIGHTS)
            if len(data) > HEADER_SIZE + MAX_APP_BYTES:
                raise OtaError(f"image of {len(data)} bytes does not fit the APP partition",
                               FoeErrorCode.DISK_FULL)
            self.status.image_size = len(data)
            self.status.image_crc32 = zlib.crc32(data)
            self.status.last_image = bytes(data)
            package = unpack(data, self.device_type)
        except OtaError as exc:
            self.status.status_code = int(exc.foe_code)
            raise FoeError(str(exc), exc.foe_code) from None
        try:
            self._install(package, bytes(data))
        except OSError as exc:
            self.status.status_code = int(FoeErrorCode.DISK_FULL)
            raise FoeError(f"file write fail: {exc}", FoeErrorCode.DISK_FULL) from None
        self.status.status_code = 0
        self._on_accepted()
