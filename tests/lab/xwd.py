"""Screenshots of a lab X display: `xwd -root` output (X Window Dump,
XWD version 7) read into RGB pixels, written as PNG, and looked at.

Only what an X server at depth 24 writes (Xvfb -screen 0 WxHx24): ZPixmap,
TrueColor or DirectColor (Xvfb's default visual: each channel through the
dump's colormap), 24 or 32 bits per pixel, one byte per colour channel.
Anything else is refused with one line saying what the dump is.
"""

from __future__ import annotations

import struct
import zlib
from collections import Counter
from dataclasses import dataclass

HEADER_FIELDS = 25  # CARD32s, big-endian whatever the pixels' byte order
ZPIXMAP, TRUECOLOR, DIRECTCOLOR, LSB_FIRST = 2, 4, 5, 0
XWD_COLOR_SIZE = 12


@dataclass(frozen=True)
class Screenshot:
    width: int
    height: int
    rgb: bytes  # width * height * 3, rows top to bottom

    def pixel(self, x: int, y: int) -> tuple[int, int, int]:
        at = 3 * (y * self.width + x)
        return tuple(self.rgb[at : at + 3])

    def crop(self, x: int, y: int, width: int, height: int) -> Screenshot:
        """The part inside the screen of the rectangle at x, y."""
        x0, y0 = max(x, 0), max(y, 0)
        x1, y1 = min(x + width, self.width), min(y + height, self.height)
        rows = [self.rgb[3 * (row * self.width + x0) : 3 * (row * self.width + x1)] for row in range(y0, y1)]
        return Screenshot(max(x1 - x0, 0), max(y1 - y0, 0), b"".join(rows))

    def colours(self) -> Counter:
        """{(r, g, b): pixels of that colour}."""
        rgb = self.rgb
        return Counter(zip(rgb[0::3], rgb[1::3], rgb[2::3]))


def _channel_byte(mask: int, bytes_per_pixel: int, lsb_first: bool) -> int:
    """Which byte of a pixel holds the channel of this mask (0xff0000 -> 2 in LSB first)."""
    for index in range(bytes_per_pixel):
        if mask == 0xFF << (8 * index):
            return index if lsb_first else bytes_per_pixel - 1 - index
    raise ValueError(f"XWD: colour mask {mask:#x} is not one whole byte")


def read(data: bytes) -> Screenshot:
    if len(data) < 4 * HEADER_FIELDS:
        raise ValueError(f"XWD: {len(data)} bytes, shorter than its header")
    header = struct.unpack(">25I", data[: 4 * HEADER_FIELDS])
    (size, version, pixmap_format, depth, width, height, _, byte_order) = header[:8]
    bits_per_pixel, bytes_per_line, visual_class, red, green, blue = header[11:17]
    ncolors = header[19]
    if version != 7:
        raise ValueError(f"XWD: file version {version}, not 7")
    if pixmap_format != ZPIXMAP or visual_class not in (TRUECOLOR, DIRECTCOLOR) or bits_per_pixel not in (24, 32):
        raise ValueError(
            f"XWD: format {pixmap_format}, visual class {visual_class}, {bits_per_pixel} bits per pixel "
            f"(depth {depth}): only ZPixmap TrueColor or DirectColor at 24 or 32 bits per pixel is read"
        )
    step = bits_per_pixel // 8
    lsb = byte_order == LSB_FIRST
    offsets = [_channel_byte(mask, step, lsb) for mask in (red, green, blue)]
    start = size + ncolors * XWD_COLOR_SIZE
    if len(data) < start + height * bytes_per_line:
        raise ValueError(f"XWD: {len(data)} bytes, {start + height * bytes_per_line} expected for {width}x{height}")
    pixels = b"".join(
        data[start + row * bytes_per_line : start + row * bytes_per_line + width * step] for row in range(height)
    )
    tables = _direct_colour_tables(data[size:start], ncolors) if visual_class == DIRECTCOLOR else (None,) * 3
    rgb = bytearray(3 * width * height)
    for channel, offset in enumerate(offsets):
        values = pixels[offset::step]
        rgb[channel::3] = values if tables[channel] is None else values.translate(tables[channel])
    return Screenshot(width, height, bytes(rgb))


def _direct_colour_tables(colormap: bytes, ncolors: int) -> tuple[bytes, bytes, bytes]:
    """DirectColor: entry i of the dump's colormap is what value i of each channel shows (xwd writes one
    entry per channel value: pixel, then red, green and blue as CARD16, big-endian)."""
    if ncolors < 256:
        raise ValueError(f"XWD: DirectColor with {ncolors} colormap entries, 256 needed")
    entries = [struct.unpack(">IHHH", colormap[i * XWD_COLOR_SIZE : i * XWD_COLOR_SIZE + 10])[1:] for i in range(256)]
    return tuple(bytes(entry[channel] >> 8 for entry in entries) for channel in range(3))


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def png(shot: Screenshot) -> bytes:
    """The screenshot as a PNG (8-bit RGB, no filter, zlib level 9)."""
    line = 3 * shot.width
    raw = b"".join(b"\0" + shot.rgb[row * line : (row + 1) * line] for row in range(shot.height))
    header = struct.pack(">IIBBBBB", shot.width, shot.height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(raw, 9)) + _chunk(b"IEND", b"")
    )
