"""Configuration flash: per-channel and device save/load/factory reset, start-up load and
corrupted images (ECAN-Lite manual 13.4 flash command, 13.7 0xB000, 18 'Flash configuration
image, CRC32')."""

from __future__ import annotations

import zlib
from pathlib import Path

import pytest
from ecanlite_mcan_kit import Rig, make_rig
from hypothesis import given
from hypothesis import strategies as st

from gatewaylab.devices.ecanlite import flash as fl


def _custom(r: Rig) -> None:
    """A non-default channel 0 (1M/5M, one filter, non-match std rejected, drop-oldest policy)."""
    r.w(0x8001, 49, 1)
    r.w(0x8001, 43, 0)
    for sub, v in ((50, 0), (51, 1), (53, 0x100), (54, 0x1FF)):
        r.w(0x8001, sub, v)
    r.w(0x8001, 45, 2)
    assert r.configure(0, 1_000_000, 5_000_000, s36=2) == 0
    r.w(0x8021, 8, 0)
    r.w(0x8021, 2, 1)
    r.w(0x8000, 10, 0xC0FFEE)


def test_device_save_survives_restart(tmp_path: Path) -> None:
    """13.7 bit0 'Save current configuration to Flash' then a power cycle: the channel comes up
    with the saved rates, filters and policies; 0xB000:07 active CRC == :08 stored CRC; status OK."""
    path = tmp_path / "ecan.flash"
    rig = make_rig(flash_path=path)
    assert rig.r(0xB000, 5) == 4                   # no image yet: factory defaults, image invalid
    assert rig.r(0xB000, 8) == 0
    _custom(rig)
    rig.w(0xB000, 4, 0x01)
    assert rig.r(0xB000, 5) == 0
    assert rig.r(0xB000, 7) == rig.r(0xB000, 8) != 0
    again = make_rig(flash_path=path)
    assert again.r(0xB000, 5) == 0
    assert again.r(0x8001, 19) == 1_000_000 and again.r(0x8001, 36) == 2 and again.r(0x8000, 10) == 0xC0FFEE
    assert again.r(0x8021, 8) == 0
    rt = again.model.channels[0].runtime
    assert rt is not None and rt.nominal_bitrate == 1_000_000 and len(rt.std_filters) == 1
    assert rt.std_filters[0].id2 == 0x1FF
    assert again.r(0xB000, 7) == again.r(0xB000, 8)


def test_channel_flash_commands() -> None:
    """13.4 SI3 bit0 save / bit1 load / bit2 factory reset per channel, SI4 status, SI5 sequence."""
    rig = make_rig(channels=2)
    _custom(rig)
    seq = rig.r(0x8001, 5)
    rig.w(0x8001, 3, 0x01)
    assert rig.r(0x8001, 4) == 0 and rig.r(0x8001, 5) == seq + 1
    rig.w(0x8001, 3, 0x04)                         # factory reset: running defaults
    assert rig.r(0x8001, 4) == 0 and rig.r(0x8001, 19) == 500_000 and rig.r(0x8001, 36) == 0
    assert rig.model.channels[0].runtime is not None and rig.model.channels[0].runtime.nominal_bitrate == 500_000
    rig.w(0x8001, 3, 0x02)                         # load back
    assert rig.r(0x8001, 4) == 0 and rig.r(0x8001, 19) == 1_000_000 and rig.r(0x8001, 36) == 2
    assert rig.model.channels[0].runtime is not None and rig.model.channels[0].runtime.nominal_bitrate == 1_000_000
    rig.w(0x8002, 3, 0x02)                         # nothing saved for CAN1 -> fail
    assert rig.r(0x8002, 4) == 1
    rig.w(0x8002, 3, 0x08)                         # unknown bit -> fail
    assert rig.r(0x8002, 4) == 1


def test_corrupted_image_gives_defaults(tmp_path: Path) -> None:
    """Issue 10: 'a corrupted or missing image at start-up -> factory defaults, reported in 0xB000':
    a flipped payload byte is a CRC error (status 3), a bad header 'image invalid' (4)."""
    path = tmp_path / "ecan.flash"
    rig = make_rig(flash_path=path)
    _custom(rig)
    rig.w(0xB000, 4, 0x01)
    image = bytearray(path.read_bytes())
    image[fl.HEADER_SIZE + 5] ^= 0xFF
    path.write_bytes(bytes(image))
    broken = make_rig(flash_path=path)
    assert broken.r(0xB000, 5) == 3
    assert broken.r(0x8001, 19) == 500_000 and broken.r(0x8001, 36) == 0
    path.write_bytes(b"garbage")
    assert make_rig(flash_path=path).r(0xB000, 5) == 4
    # the device load command reports the same without changing the running config
    broken.w(0x8001, 19, 1_000_000)
    broken.w(0xB000, 4, 0x02)
    assert broken.r(0xB000, 5) == 4 and broken.r(0x8001, 19) == 1_000_000


def test_image_codec_golden() -> None:
    """18 'Flash configuration image, CRC32': header magic/format/length and zlib CRC32 of the payload."""
    image = fl.encode_image([fl.Record(0x8001, 19, (1_000_000).to_bytes(4, "little"))])
    payload = b"\x01\x80\x13\x04\x40\x42\x0f\x00"     # 0x8001:19, 4 bytes, 1000000
    assert image == b"ECFG\x01\x00\x00\x00\x08\x00\x00\x00" + zlib.crc32(payload).to_bytes(4, "little") + payload
    assert fl.decode_image(image) == [fl.Record(0x8001, 19, b"\x40\x42\x0f\x00")]
    with pytest.raises(fl.ImageError) as exc:
        fl.decode_image(image[:-1])
    assert exc.value.status is fl.ImageStatus.IMAGE_INVALID


@given(st.binary(max_size=64))
def test_decode_random_bytes_only_image_errors(data: bytes) -> None:
    """Any stored bytes give records or an ImageError (crc error / image invalid), never a crash."""
    for blob in (data, fl.encode_image([])[:16] + data, b"ECFG\x01\x00\x00\x00" + data):
        try:
            fl.decode_image(blob)
        except fl.ImageError as exc:
            assert exc.status in (fl.ImageStatus.CRC_ERROR, fl.ImageStatus.IMAGE_INVALID)
