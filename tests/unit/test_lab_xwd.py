"""tests/lab/xwd.py: X Window Dumps as xwd writes them (header big-endian,
pixels in the server's byte order), read into RGB and written as PNG."""

from __future__ import annotations

import struct
import zlib

import pytest

from tests.lab import xwd


def dump(
    width, height, pixels, *, bits=32, byte_order=0, masks=(0xFF0000, 0xFF00, 0xFF), visual=4, colormap=None, pad=0
):
    """An XWD of these (r, g, b) pixels, rows padded by ``pad`` bytes; colormap: its (r, g, b) CARD16 entries."""
    name = b"xwdump\0"
    step = bits // 8
    bytes_per_line = width * step + pad
    header_size = 100 + len(name)
    entries = colormap if colormap is not None else [(0, 0, 0), (65535, 65535, 65535)]
    header = [header_size, 7, 2, 24, width, height, 0, byte_order, 32, byte_order, 32, bits, bytes_per_line, visual]
    header += [*masks, 8, 256, len(entries), width, height, 0, 0, 0]
    colormap = b"".join(struct.pack(">IHHHBB", i, *entry, 7, 0) for i, entry in enumerate(entries))
    rows = []
    for row in range(height):
        line = b""
        for r, g, b in pixels[row * width : (row + 1) * width]:
            value = 0
            for channel, mask in zip((r, g, b), masks):
                value |= (channel << max(mask.bit_length() - 8, 0)) & mask
            line += value.to_bytes(step, "little" if byte_order == 0 else "big")
        rows.append(line + bytes(pad))
    return struct.pack(">25I", *header) + name + colormap + b"".join(rows)


PIXELS = [(48, 48, 48), (160, 160, 164), (255, 0, 0), (0, 0, 255), (0, 255, 0), (1, 2, 3)]


@pytest.mark.parametrize("byte_order", [0, 1])
@pytest.mark.parametrize("bits", [24, 32])
def test_reads_pixels_in_either_byte_order_and_width(bits, byte_order):
    shot = xwd.read(dump(3, 2, PIXELS, bits=bits, byte_order=byte_order, pad=4))
    assert (shot.width, shot.height) == (3, 2)
    assert [shot.pixel(x, y) for y in range(2) for x in range(3)] == PIXELS


def test_bgr_masks():
    shot = xwd.read(dump(3, 2, PIXELS, masks=(0xFF, 0xFF00, 0xFF0000)))
    assert shot.pixel(0, 1) == (0, 0, 255)


def test_direct_colour_goes_through_the_colormap():
    # Xvfb's default visual at depth 24: entry i says what value i of each channel shows.
    ramp = [(257 * (255 - i), 257 * i, 257 * (i // 2)) for i in range(256)]
    shot = xwd.read(dump(3, 2, PIXELS, bits=24, visual=5, colormap=ramp))
    assert shot.pixel(0, 0) == (255 - 48, 48, 24)
    assert shot.pixel(0, 1) == (255, 0, 127)
    with pytest.raises(ValueError, match="DirectColor with 2 colormap entries, 256 needed"):
        xwd.read(dump(1, 1, PIXELS[:1], visual=5))


def test_crop_and_colours():
    shot = xwd.read(dump(3, 2, PIXELS))
    part = shot.crop(1, 0, 5, 1)  # clipped to the screen
    assert (part.width, part.height) == (2, 1)
    assert part.colours() == {(160, 160, 164): 1, (255, 0, 0): 1}
    assert shot.crop(-1, 1, 2, 1).colours() == {(0, 0, 255): 1}


def test_png_decodes_to_the_same_pixels():
    shot = xwd.read(dump(3, 2, PIXELS))
    data = xwd.png(shot)
    assert data.startswith(b"\x89PNG\r\n\x1a\n")
    chunks, at = {}, 8
    while at < len(data):
        (length,) = struct.unpack(">I", data[at : at + 4])
        kind, body = data[at + 4 : at + 8], data[at + 8 : at + 8 + length]
        assert struct.unpack(">I", data[at + 8 + length : at + 12 + length])[0] == zlib.crc32(kind + body)
        chunks[kind] = body
        at += 12 + length
    assert struct.unpack(">II", chunks[b"IHDR"][:8]) == (3, 2)
    raw = zlib.decompress(chunks[b"IDAT"])
    assert raw == b"".join(b"\0" + bytes(v for p in PIXELS[r * 3 : r * 3 + 3] for v in p) for r in range(2))


@pytest.mark.parametrize(
    "data, says",
    [
        (b"\0" * 10, "shorter than its header"),
        (dump(1, 1, PIXELS[:1])[:-2], "expected for 1x1"),
        (dump(1, 1, PIXELS[:1], bits=16, masks=(0xF800, 0x7E0, 0x1F)), "16 bits per pixel"),
        (dump(1, 1, PIXELS[:1], visual=3), "visual class 3"),
        (dump(1, 1, PIXELS[:1], masks=(0xFF0000, 0xFF00, 0xF)), "mask 0xf is not one whole byte"),
    ],
)
def test_refuses_what_it_cannot_read(data, says):
    with pytest.raises(ValueError, match=says):
        xwd.read(data)
