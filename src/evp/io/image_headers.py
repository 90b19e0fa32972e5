"""An image file's format and size from its first bytes, without decoding it.

A decoder allocates the whole image before it can say anything about it: a 20000x20000 PNG of a
few kilobytes costs 1.2 GB to find out it is too large. Reading the size from the header first
lets the station and the dataset readers refuse such a file (and a payload that is not the format
it claims, such as a float TIFF sent as "png") before anything is allocated.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_SOI = b"\xff\xd8"
# JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic); C4, C8 and CC are
# other segments (Huffman tables, reserved, arithmetic conditioning).
JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


@dataclass(frozen=True)
class ImageHeader:
    format: str  # "png" or "jpeg"
    width: int
    height: int
    bit_depth: int  # bits per sample: 8 for what phones send; 16 (PNG) or 12 (JPEG) decode to uint16


def image_format(data: bytes) -> str | None:
    """ "png", "jpeg", or None for anything else (TIFF, BMP, garbage)."""
    if data.startswith(PNG_SIGNATURE):
        return "png"
    if data.startswith(JPEG_SOI):
        return "jpeg"
    return None


def read_image_header(data: bytes) -> ImageHeader | None:
    """The size of a PNG or JPEG from its header; None when the bytes are neither or the header
    is cut off or malformed (the decoder then says what is wrong)."""
    kind = image_format(data)
    if kind == "png":
        return _png_header(data)
    if kind == "jpeg":
        return _jpeg_header(data)
    return None


def _png_header(data: bytes) -> ImageHeader | None:
    # signature, then the IHDR chunk: length (4), b"IHDR", width, height (big-endian), bit depth
    if len(data) < 25 or data[12:16] != b"IHDR":
        return None
    width, height, depth = struct.unpack(">IIB", data[16:25])
    return ImageHeader("png", width, height, depth)


def _jpeg_header(data: bytes) -> ImageHeader | None:
    position = 2
    while position + 4 <= len(data):
        if data[position] != 0xFF:
            return None
        marker = data[position + 1]
        if marker == 0xFF:  # fill byte
            position += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # markers without a length
            position += 2
            continue
        (length,) = struct.unpack(">H", data[position + 2 : position + 4])
        if marker in JPEG_SOF:
            if position + 9 > len(data):
                return None
            depth, height, width = struct.unpack(">BHH", data[position + 4 : position + 9])
            return ImageHeader("jpeg", width, height, depth)
        if length < 2:
            return None
        position += 2 + length
    return None
