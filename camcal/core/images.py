"""Frame images: decoding PNG/TIFF bytes into frames (a fast path for the unfiltered 8-bit PNGs
camcal writes, OpenCV for the rest) and encoding them.

Frames are 8-bit grayscale, or 16-bit grayscale for a camera of 10 to 16 bits (Mono12: the
12-bit values MSB-aligned in 16-bit samples, the PNG's ``sBIT`` chunk saying 12, as the PNG
standard keeps a depth it has no type for; lossless). `significant_bits` reads the depth back,
`full_scale` turns it into the saturation level the analysis is told.

`FrameReadError` says why one image cannot be used, with its frame-set reason word.
"""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import deflate
import numpy as np

from camcal.core.wire.image import PNG_HEAD_BYTES, png_significant_bits

# OpenCV's own warnings ("[ WARN:0@0.09] global grfmt_png.cpp ... PNG input buffer is incomplete")
# would reach the user's console beside the frame's reason, which says it better: errors only.
cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


class FrameReadError(Exception):
    """One image cannot be used; ``reason`` is the frame-set reason word."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


def decode_frame(data: bytes | np.ndarray, name: str = "frame") -> np.ndarray:
    """Decode PNG/TIFF bytes into a 2-D ``uint8`` or ``uint16`` frame or raise `FrameReadError`."""
    buf = np.frombuffer(data, dtype=np.uint8) if isinstance(data, bytes | bytearray) else data
    if buf.size == 0:
        raise FrameReadError("unreadable", f"{name}: empty file")
    other = _not_png_or_tiff(bytes(buf[:12]))
    if other:
        raise FrameReadError("unreadable", f"{name}: {other}, not PNG or TIFF: frames must be lossless")
    if bytes(buf[:8]) == _PNG_SIGNATURE and b"IEND" not in bytes(buf[-1024:]):
        # cut short (a copy or a card that stopped): said here, before libpng prints its own error
        raise FrameReadError(
            "unreadable", f"{name}: PNG cut short (no IEND chunk at its end): a truncated file"
        )
    image = _decode_unfiltered_png(buf)
    if image is None:  # any other PNG, a TIFF, or a damaged file: OpenCV decides
        image = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise FrameReadError("unreadable", f"{name}: not a decodable PNG/TIFF (truncated or corrupt?)")
    if image.ndim != 2:
        raise FrameReadError(
            "bad_format", f"{name}: {image.shape[2]}-channel image, expected 8- or 16-bit grayscale"
        )
    if image.dtype not in (np.uint8, np.uint16):
        raise FrameReadError(
            "bad_format", f"{name}: {image.dtype} pixels, expected 8- or 16-bit grayscale (uint8, uint16)"
        )
    return image


def decode_frame_scaled(data: bytes | np.ndarray, name: str = "frame") -> tuple[np.ndarray, int]:
    """`decode_frame`, and the frame's full scale (`full_scale`, from the image's own header)."""
    frame = decode_frame(data, name)
    head = bytes(data[:PNG_HEAD_BYTES])
    return frame, full_scale(frame.dtype, significant_bits(head))


def significant_bits(head: bytes) -> int | None:
    """The significant bits a 16-bit PNG's ``sBIT`` chunk states (12 for Mono12), or None.

    ``head`` is the file's start (the chunks before the image data). None: no ``sBIT`` (all the
    sample's bits count), or not a 16-bit grey PNG.
    """
    if len(head) < 33 or head[24] != 16:
        return None
    return png_significant_bits(head)


def full_scale(dtype: np.dtype | type, bits: int | None = None) -> int:
    """The saturation level of a frame: 255 for 8-bit; for 16-bit samples holding ``bits``
    MSB-aligned significant bits, ``(2**bits - 1) << (16 - bits)`` (65520 for 12 bits, 65535 for 16)."""
    if np.dtype(dtype) == np.uint8:
        return 255
    b = 16 if bits is None else int(bits)
    if not 8 <= b <= 16:
        raise ValueError(f"significant bits must be 8 to 16, got {b}")
    return ((1 << b) - 1) << (16 - b)


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_TIFF_SIGNATURES = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")  # classic and BigTIFF
_OTHER_FORMATS = ((b"\xff\xd8\xff", "JPEG data"), (b"BM", "BMP data"), (b"GIF8", "GIF data"))


def _not_png_or_tiff(head: bytes) -> str | None:
    """What a file that is neither PNG nor TIFF holds ("JPEG data", "WebP data"), else None.

    OpenCV would decode a JPEG renamed .png, and its lossy blocks would move I_center: the frame-set
    format takes PNG and TIFF only. Unknown bytes are left to the decoder (it says unreadable).
    """
    if head.startswith(_PNG_SIGNATURE) or head.startswith(_TIFF_SIGNATURES):
        return None
    if head.startswith(b"RIFF") and head[8:12] == b"WEBP":
        return "WebP data"
    for magic, what in _OTHER_FORMATS:
        if head.startswith(magic):
            return what
    return None


def _decode_unfiltered_png(buf: np.ndarray) -> np.ndarray | None:
    """The pixels of the PNGs modules write (8-bit grey, no interlace, every row
    unfiltered), or None for anything else: then OpenCV decodes it.

    Inflating is most of a PNG's decoding; libdeflate does it in less than
    half zlib's time (``bench/bench_analysis.py`` prints both). Every chunk's
    CRC and the zlib stream's Adler-32 are checked, and the inflated size
    must be exact, so a damaged file never comes back as pixels from here.
    """
    data = buf.data
    if bytes(data[:8]) != _PNG_SIGNATURE:
        return None
    width = height = 0
    idat: list[memoryview] = []
    pos, end, seen_end = 8, len(data), False
    while pos + 12 <= end:
        length, kind = struct.unpack_from(">I4s", data, pos)
        body_end = pos + 8 + length
        if body_end + 4 > end:
            return None
        (crc,) = struct.unpack_from(">I", data, body_end)
        if deflate.crc32(data[pos + 4 : body_end]) != crc:
            return None
        body = data[pos + 8 : body_end]
        if kind == b"IHDR":
            if length != 13 or pos != 8:
                return None
            width, height, depth, colour, method, filtering, interlace = struct.unpack(">IIBBBBB", body)
            if (depth, colour, method, filtering, interlace) != (8, 0, 0, 0, 0) or not width or not height:
                return None
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            seen_end = True
            break
        elif kind[0] & 0x20 == 0 or kind == b"tRNS":  # another critical chunk, or transparency
            return None
        pos = body_end + 4
    if not (seen_end and width and idat):
        return None
    size = height * (width + 1)  # each row: a filter-type byte, then the pixels
    try:
        raw = deflate.zlib_decompress(b"".join(idat), size)
    except deflate.DeflateError:
        return None
    if len(raw) != size:
        return None
    rows = np.frombuffer(raw, dtype=np.uint8).reshape(height, width + 1)
    if rows[:, 0].any():  # some rows filtered: leave the undoing to OpenCV
        return None
    return rows[:, 1:].copy()


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise FrameReadError("unreadable", f"{path.name}: file not found") from None
    except OSError as exc:
        raise FrameReadError("unreadable", f"{path.name}: {exc.strerror or exc}") from None


def read_frame(path: Path) -> np.ndarray:
    """Read one frame file; missing, undecodable or not grayscale files raise `FrameReadError`."""
    path = Path(path)
    return decode_frame(_read(path), path.name)


def read_frame_scaled(path: Path) -> tuple[np.ndarray, int]:
    """`read_frame`, and the frame's full scale (`decode_frame_scaled`)."""
    path = Path(path)
    return decode_frame_scaled(_read(path), path.name)


#: PNG without row filters at zlib level 1: as small as OpenCV's default on
#: camera frames (dark, noisy) and as fast to write, but a third faster to
#: read, because the reader has no filter to undo (bench/bench_frame_storage.py).
PNG_PARAMS = (cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE, cv2.IMWRITE_PNG_COMPRESSION, 1)


def encode_png(frame: np.ndarray, bits: int | None = None) -> bytes:
    """Lossless PNG bytes of a frame (no row filters, zlib level 1: see `PNG_PARAMS`).

    A ``uint16`` frame of fewer than 16 significant ``bits`` (MSB-aligned: Mono12 as ``v << 4``)
    gets an ``sBIT`` chunk saying so, which `significant_bits` reads back.
    """
    ok, buf = cv2.imencode(".png", frame, list(PNG_PARAMS))
    if not ok:
        raise ValueError("PNG encoding failed")
    data = buf.tobytes()
    if frame.dtype == np.uint16 and bits is not None and bits < 16:
        if not 8 < bits < 16:
            raise ValueError(f"a 16-bit frame holds 9 to 16 significant bits, not {bits}")
        chunk = b"sBIT" + bytes([bits])
        # after IHDR (8-byte signature + 25-byte chunk), before any image data
        data = data[:33] + struct.pack(">I", 1) + chunk + struct.pack(">I", deflate.crc32(chunk)) + data[33:]
    return data
