"""The ECAN-Lite configuration flash image (manual 13.4 flash command, 13.7 0xB000, 18 'Flash
configuration image, CRC32').

The image is a 16-byte header and a payload of records::

    header:  magic "ECFG" | format u16 = 1 | flags u16 = 0 | payload_len u32 | payload_crc32 u32
    record:  index u16 | subindex u8 | length u8 | value (little-endian, ``length`` bytes)

all little-endian, the CRC32 being ``zlib.crc32`` of the payload. Records carry the persisted
subindexes of 0x8000, 0x8001..0x8004, 0x8020 and 0x8021..0x8024; a channel's filter elements
are records of its 0x800x object at subindex 0x80 + i (standard list) and 0xC0 + i (extended
list) whose 11-byte value is type u8, action u8, sync u8, ID1 u32, ID2 u32.

:func:`encode_image` / :func:`decode_image` are pure; :class:`MemoryFlash` and :class:`FileFlash`
are the media (the file is replaced atomically, as :class:`~gatewaylab.common.store.JsonFileStore`
does).
"""

from __future__ import annotations

import enum
import os
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from gatewaylab.common.errors import LocalError

__all__ = [
    "EXT_FILTER_SUB",
    "HEADER_SIZE",
    "IMAGE_FORMAT",
    "IMAGE_MAGIC",
    "STD_FILTER_SUB",
    "FileFlash",
    "FlashMedium",
    "ImageError",
    "ImageStatus",
    "MemoryFlash",
    "Record",
    "decode_image",
    "encode_image",
    "encode_payload",
    "image_crc",
    "pack_filter",
    "unpack_filter",
]


IMAGE_MAGIC = b"ECFG"
IMAGE_FORMAT = 1
_HEADER = struct.Struct("<4sHHII")
_RECORD = struct.Struct("<HBB")
_FILTER = struct.Struct("<BBBII")
HEADER_SIZE = _HEADER.size
#: Subindex bases of the filter element records in a channel's 0x800x object.
STD_FILTER_SUB = 0x80
EXT_FILTER_SUB = 0xC0


class ImageStatus(enum.IntEnum):
    """Why an image could not be used (the 0xB000:05 maintenance status it is reported as)."""

    OK = 0
    CRC_ERROR = 3
    IMAGE_INVALID = 4


class ImageError(LocalError):
    """An image that cannot be used; ``status`` says why (0xB000:05)."""

    def __init__(self, message: str, status: ImageStatus) -> None:
        super().__init__(message, int(status))
        self.status = status


@dataclass(frozen=True, slots=True)
class Record:
    """One stored value: the raw little-endian bytes of (index, subindex)."""

    index: int
    subindex: int
    value: bytes


def pack_filter(ftype: int, action: int, sync: int, id1: int, id2: int) -> bytes:
    """The 11-byte value of a filter element record."""
    return _FILTER.pack(ftype & 0xFF, action & 0xFF, sync & 0xFF, id1 & 0xFFFFFFFF, id2 & 0xFFFFFFFF)


def unpack_filter(value: bytes) -> tuple[int, int, int, int, int]:
    """(type, action, sync, id1, id2) of a filter element record."""
    if len(value) != _FILTER.size:
        raise ImageError(f"filter record of {len(value)} bytes", ImageStatus.IMAGE_INVALID)
    ftype, action, sync, id1, id2 = _FILTER.unpack(value)
    return ftype, action, sync, id1, id2


def encode_payload(records: Iterable[Record]) -> bytes:
    """The records, in the given order."""
    out = bytearray()
    for r in records:
        if len(r.value) > 255:
            raise ImageError("record value longer than 255 bytes", ImageStatus.IMAGE_INVALID)
        out += _RECORD.pack(r.index, r.subindex, len(r.value)) + r.value
    return bytes(out)


def encode_image(records: Iterable[Record]) -> bytes:
    """Header + payload of ``records``."""
    payload = encode_payload(records)
    return _HEADER.pack(IMAGE_MAGIC, IMAGE_FORMAT, 0, len(payload), zlib.crc32(payload)) + payload


def image_crc(image: bytes) -> int:
    """The payload CRC32 an image's header carries (0 when it has no valid header)."""
    if len(image) < HEADER_SIZE:
        return 0
    magic, _fmt, _flags, _length, crc = _HEADER.unpack_from(image)
    return int(crc) if magic == IMAGE_MAGIC else 0


def _records(payload: bytes) -> Iterator[Record]:
    pos = 0
    while pos < len(payload):
        if pos + _RECORD.size > len(payload):
            raise ImageError("record header cut short", ImageStatus.IMAGE_INVALID)
        index, sub, length = _RECORD.unpack_from(payload, pos)
        pos += _RECORD.size
        if pos + length > len(payload):
            raise ImageError(f"record 0x{index:04X}:{sub} cut short", ImageStatus.IMAGE_INVALID)
        yield Record(index, sub, payload[pos:pos + length])
        pos += length


def decode_image(image: bytes) -> list[Record]:
    """The records of a stored image; :class:`ImageError` (crc error / image invalid) otherwise."""
    if len(image) < HEADER_SIZE:
        raise ImageError(f"image of {len(image)} bytes has no header", ImageStatus.IMAGE_INVALID)
    magic, fmt, _flags, length, crc = _HEADER.unpack_from(image)
    if magic != IMAGE_MAGIC or fmt != IMAGE_FORMAT:
        raise ImageError("not a configuration image (magic/format)", ImageStatus.IMAGE_INVALID)
    payload = image[HEADER_SIZE:]
    if len(payload) != length:
        raise ImageError(f"payload is {len(payload)} bytes, header says {length}", ImageStatus.IMAGE_INVALID)
    if zlib.crc32(payload) != crc:
        raise ImageError("payload CRC32 mismatch", ImageStatus.CRC_ERROR)
    return list(_records(payload))


class FlashMedium(Protocol):
    """Where the configuration image and the application partition (the installed OTA package) live."""

    def read(self) -> bytes | None:
        """The stored configuration image, None when nothing was ever stored; OSError when unreadable."""

    def write(self, image: bytes) -> None:
        """Replace the configuration image; OSError when the medium fails."""

    def read_app(self) -> bytes | None:
        """The installed application package, None when the factory firmware runs."""

    def write_app(self, package: bytes) -> None:
        """Install an application package (a good FoE OTA image)."""


class MemoryFlash:
    """Flash kept in memory (``flash_path`` None): hand the same object to the next model to keep
    it across a device reset."""

    def __init__(self, image: bytes | None = None, app: bytes | None = None) -> None:
        self.image = image
        self.app = app

    def read(self) -> bytes | None:
        """The stored bytes."""
        return self.image

    def write(self, image: bytes) -> None:
        """Keep the bytes."""
        self.image = bytes(image)

    def read_app(self) -> bytes | None:
        """The installed package."""
        return self.app

    def write_app(self, package: bytes) -> None:
        """Keep the package."""
        self.app = bytes(package)


def _replace(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


class FileFlash:
    """The image in one file, the application package in ``PATH.app`` next to it; both replaced
    atomically on every write (the rig's state directory)."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self.app_path = self.path.with_name(self.path.name + ".app")

    def read(self) -> bytes | None:
        """The file's bytes, None when it does not exist."""
        try:
            return self.path.read_bytes()
        except FileNotFoundError:
            return None

    def write(self, image: bytes) -> None:
        """Write a temporary file next to the target and rename it over the target."""
        _replace(self.path, image)

    def read_app(self) -> bytes | None:
        """The installed package, None when there is none."""
        try:
            return self.app_path.read_bytes()
        except FileNotFoundError:
            return None

    def write_app(self, package: bytes) -> None:
        """Replace the installed package."""
        _replace(self.app_path, package)
