"""16-bit RGB(A) PNGs are read at 16 bits.

Pillow decodes them to 8 bits by dropping each sample's low byte, so a 16-bit photo or dataset image came in up to
1/255 darker (0.5/255 on average) while 16-bit grey kept its bits. ``format.colour_pixels`` now returns them as
uint16; the files here are written with every PNG row filter (none, sub, up, average, Paeth), since the low bytes are
recovered through the same decode."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from blender_mrvm.datasets import format as F
from blender_mrvm.datasets.loaders import read_colour


def _paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def write_png16(path: Path, pixels: np.ndarray) -> Path:
    """A 16-bit RGB or RGBA PNG whose rows cycle through the five filter types."""
    h, w, ch = pixels.shape
    colour_type = {3: 2, 4: 6}[ch]
    bpp = 2 * ch
    rows = [pixels[y].astype(">u2").tobytes() for y in range(h)]
    out, prev = bytearray(), bytes(len(rows[0]))
    for y, row in enumerate(rows):
        kind = y % 5
        out.append(kind)
        for x, v in enumerate(row):
            a = row[x - bpp] if x >= bpp else 0
            b = prev[x]
            c = prev[x - bpp] if x >= bpp else 0
            out.append((v - (0, a, b, (a + b) // 2, _paeth(a, b, c))[kind]) & 255)
        prev = row

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, colour_type, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(bytes(out))) + chunk(b"IEND", b""))
    return path


@pytest.mark.parametrize("channels", [3, 4])
def test_16_bit_rgb_and_rgba_pngs_keep_their_low_bytes(tmp_path, channels):
    pixels = np.random.default_rng(channels).integers(0, 65536, (13, 11, channels)).astype(np.uint16)
    path = write_png16(tmp_path / "p.png", pixels)
    assert Image.open(path).mode == ("RGB" if channels == 3 else "RGBA")  # (Pillow: 8 bits)
    got = F.read_png(path, colour=True)
    assert got.dtype == np.uint16 and np.array_equal(got, pixels)
    with Image.open(path) as im:  # an image loaded before it is read (photos: recover-poses) too
        im.load()
        assert np.array_equal(F.colour_pixels(im, path), pixels)


def test_a_16_bit_dataset_image_loads_at_16_bits_and_8_bit_ones_as_before(tmp_path):
    grey = (np.linspace(0, 1, 7 * 9).reshape(7, 9) * 65535).round().astype(np.uint16)
    pixels = np.repeat(grey[..., None], 3, -1)
    got = read_colour(write_png16(tmp_path / "g.png", pixels))
    assert np.abs(got - pixels / 65535.0).max() < 1e-6  # it was up to 1/255 low
    eight = (pixels >> 8).astype(np.uint8)
    Image.fromarray(eight).save(tmp_path / "e.png")
    back = F.read_png(tmp_path / "e.png", colour=True)
    assert back.dtype == np.uint8 and np.array_equal(back, eight)


def test_a_16_bit_photo_goes_into_rgb_rounded_not_truncated(tmp_path):
    from blender_mrvm.capture.export import photo_rgb8

    pixels = np.full((4, 5, 3), 0x12FF, np.uint16)  # 4863/65535 = 18.92/255: 19, where dropping the low byte gave 18
    path = write_png16(tmp_path / "p.png", pixels)
    with Image.open(path) as im:
        assert (photo_rgb8(im, path) == 19).all()
