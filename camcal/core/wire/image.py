"""What a frame payload claims to be, read from its first bytes (no pixels decoded).

The ship refuses at the door a frame whose image is not what its header
says: not a PNG or TIFF, not single-channel of the header's bit depth (8-bit,
or 16-bit for 9 to 16 significant bits, which a PNG's ``sBIT`` chunk states
when fewer than 16), or of another width or height. Pixels are decoded
later, by the analysis; a file whose header is right but whose pixels are
damaged is stored as sent (it is the module's record) and its analysis says
``unreadable``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_COLOURS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}  # colour type -> channels (3: palette)
_TIFF_TAGS = {256: "width", 257: "height", 258: "bits", 277: "channels"}
_TIFF_TYPE_SIZES = {3: 2, 4: 4}  # SHORT, LONG: the types these tags use


class ImageHeaderError(ValueError):
    """A payload that is not the image it claims to be."""


@dataclass(frozen=True)
class ImageHeader:
    width_px: int
    height_px: int
    bits: int
    channels: int
    palette: bool = False
    #: Significant bits per sample: a PNG's ``sBIT`` (grey) where it has one, else ``bits``.
    significant_bits: int = 0

    def __post_init__(self) -> None:
        if not self.significant_bits:
            object.__setattr__(self, "significant_bits", self.bits)


#: How far into a PNG its ``sBIT`` chunk is looked for (it comes before the image data).
PNG_HEAD_BYTES = 4096


def read_header(data: bytes | memoryview, encoding: str) -> ImageHeader:
    """Width, height, bit depth, significant bits and channels of a PNG or TIFF payload."""
    head = bytes(memoryview(data)[: 64 * 1024 if encoding == "tiff" else PNG_HEAD_BYTES])
    if encoding == "png":
        return _png(head)
    if encoding == "tiff":
        return _tiff(head)
    raise ImageHeaderError(f"unknown encoding {encoding!r}")


def check_frame(
    data: bytes | memoryview, encoding: str, width_px: int, height_px: int, bit_depth: int = 8
) -> None:
    """Raise `ImageHeaderError` unless the payload is a grey image of the stated size and depth:
    8-bit for ``bit_depth`` 8, 16-bit with ``bit_depth`` significant bits for 9 to 16."""
    h = read_header(data, encoding)
    bits = 8 if bit_depth == 8 else 16
    if h.bits != bits or h.channels != 1 or h.palette:
        kind = "palette" if h.palette else f"{h.bits}-bit, {h.channels}-channel"
        said = "8-bit grayscale" if bits == 8 else f"16-bit grayscale (bit_depth {bit_depth})"
        raise ImageHeaderError(f"{encoding.upper()} is {kind}; the header says {said}")
    if h.significant_bits != bit_depth:
        raise ImageHeaderError(
            f"{encoding.upper()} holds {h.significant_bits} significant bits, header says bit_depth "
            f"{bit_depth}" + (" (a PNG states fewer than 16 in its sBIT chunk)" if encoding == "png" else "")
        )
    if (h.width_px, h.height_px) != (width_px, height_px):
        raise ImageHeaderError(
            f"image is {h.width_px} x {h.height_px} px, header says {width_px} x {height_px}"
        )


def _png(head: bytes) -> ImageHeader:
    if len(head) < 33 or head[:8] != _PNG_SIGNATURE:
        raise ImageHeaderError("not a PNG (no PNG signature)")
    length, kind = struct.unpack_from(">I4s", head, 8)
    if kind != b"IHDR" or length != 13:
        raise ImageHeaderError("PNG does not start with its IHDR chunk")
    width, height, bits, colour = struct.unpack_from(">IIBB", head, 16)
    if colour not in _PNG_COLOURS or not width or not height:
        raise ImageHeaderError("PNG header is invalid")
    sig = png_significant_bits(head) if colour == 0 and bits == 16 else None
    channels = _PNG_COLOURS[colour]
    return ImageHeader(width, height, bits, channels, palette=colour == 3, significant_bits=sig or 0)


def png_significant_bits(head: bytes) -> int | None:
    """The significant bits a grey PNG's ``sBIT`` chunk states (12 for Mono12 in 16-bit samples), or
    None (no ``sBIT`` before the image data within ``head``: every bit of a sample counts)."""
    if len(head) < 33 or head[:8] != _PNG_SIGNATURE:
        return None
    pos = 8
    while pos + 12 <= len(head):
        length, kind = struct.unpack_from(">I4s", head, pos)
        if kind == b"sBIT" and length == 1 and pos + 9 <= len(head):
            return head[pos + 8] if 1 <= head[pos + 8] <= head[24] else None
        if kind in (b"IDAT", b"IEND"):
            return None
        pos += 12 + length
    return None


def _tiff(head: bytes) -> ImageHeader:
    if head[:4] == b"II*\x00":
        order = "<"
    elif head[:4] == b"MM\x00*":
        order = ">"
    else:
        raise ImageHeaderError("not a TIFF (no TIFF signature)")
    try:
        (ifd,) = struct.unpack_from(order + "I", head, 4)
        (n,) = struct.unpack_from(order + "H", head, ifd)
        found: dict[str, int] = {"bits": 1, "channels": 1}
        for i in range(min(n, 512)):
            tag, kind, count, _ = struct.unpack_from(order + "HHI4s", head, ifd + 2 + 12 * i)
            if tag not in _TIFF_TAGS or kind not in _TIFF_TYPE_SIZES:
                continue
            fmt = "H" if kind == 3 else "I"
            if count * _TIFF_TYPE_SIZES[kind] <= 4:
                (value,) = struct.unpack_from(order + fmt, head, ifd + 2 + 12 * i + 8)
            else:  # several values elsewhere (bits per sample of a colour image): the first says enough
                (offset,) = struct.unpack_from(order + "I", head, ifd + 2 + 12 * i + 8)
                (value,) = struct.unpack_from(order + fmt, head, offset)
            found[_TIFF_TAGS[tag]] = value
    except struct.error:
        raise ImageHeaderError(
            "TIFF header is truncated or its first directory is not in the first 64 KiB"
        ) from None
    if "width" not in found or "height" not in found:
        raise ImageHeaderError("TIFF has no width or height")
    return ImageHeader(found["width"], found["height"], found["bits"], found["channels"])
