"""Decoding input images into 8-bit BGR arrays, with clear errors for what cannot be used."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

NOT_AN_IMAGE = "not an image file (use JPEG, PNG, TIFF, WebP or BMP)"
# How each format signpose reads begins: a file that begins so and cannot be read is that format
# damaged (cut short by a copy or download, or corrupt), not some other kind of file.
SIGNATURES = {
    "JPEG": re.compile(rb"\xff\xd8\xff"),
    "PNG": re.compile(rb"\x89PNG\r\n\x1a\n"),
    "GIF": re.compile(rb"GIF8[79]a"),
    "TIFF": re.compile(rb"II\*\x00|MM\x00\*"),
    "WebP": re.compile(rb"RIFF.{4}WEBP", re.DOTALL),
    "BMP": re.compile(rb"BM.{4}\x00{4}", re.DOTALL),  # the size, then 4 reserved zero bytes: not just text "BM..."
}


class ImageError(ValueError):
    """An input that is not a usable image; the message says why."""


def image_format(data: bytes) -> str | None:
    """The format encoded image `data` begins as ("JPEG", "PNG", ... a key of SIGNATURES), or None."""
    return next((name for name, signature in SIGNATURES.items() if signature.match(data)), None)


def unreadable(data: bytes, name: str) -> ImageError:
    """The error for `data`, the bytes of file `name`, that cannot be read as an 8-bit colour image:
    samples of a kind that has no 8-bit colour (floating point), a damaged or truncated file of its
    format when it begins as one, else not an image file at all."""
    kind = image_format(data)
    if kind is None:
        return ImageError(f"{name}: {NOT_AN_IMAGE}")
    try:
        decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        decoded = None
    if decoded is not None:
        return ImageError(f"{name}: a {kind} of {decoded.dtype} samples, which signpose does not read; "
                          "export it with 8- or 16-bit integer samples")
    return ImageError(f"{name}: damaged or truncated {kind} file (it begins as a {kind} but its image data cannot "
                      "be read); copy or export it again")


def transparent(data: bytes) -> bool:
    """Whether encoded image `data` says it has transparency: a PNG with an alpha channel or a
    transparent palette entry (tRNS), or a WebP with alpha."""
    kind = image_format(data)
    if kind == "PNG":  # the colour type in IHDR, the first chunk: 4 gray + alpha, 6 RGBA
        return data[25:26] in (b"\x04", b"\x06") or b"tRNS" in data[:max(0, data.find(b"IDAT"))]
    if kind == "WebP":
        if data[12:16] == b"VP8X":  # extended format: flags byte, alpha bit
            return bool(data[20] & 0x10)
        if data[12:16] == b"VP8L":  # lossless: 14-bit width - 1, 14-bit height - 1, then alpha_is_used
            return bool(int.from_bytes(data[21:25], "little") >> 28 & 1)
    return False


def on_white(image: np.ndarray) -> np.ndarray:
    """(H, W, 4) BGRA, 8- or 16-bit -> (H, W, 3) uint8 BGR over white, as a page shows it (a sign's
    artwork drawn on a transparent ground is a sign on white)."""
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)  # as IMREAD_COLOR scales 16 bits
    alpha = image[..., 3:].astype(np.float32) / 255
    return np.round(image[..., :3] * alpha + 255 * (1 - alpha)).astype(np.uint8)


def decode_image(data: bytes, name: str = "image") -> np.ndarray:
    """Encoded bytes (JPEG, PNG, TIFF, WebP, BMP, GIF first frame, ...) -> (H, W, 3) uint8 BGR.

    EXIF orientation is applied; 16-bit images are scaled to 8 bits, transparent pixels (PNG,
    WebP) shown over white, gray expanded.
    """
    if not data:
        raise ImageError(f"{name}: file is empty")
    buf = np.frombuffer(data, dtype=np.uint8)
    try:
        if transparent(data):
            image = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
            if image is not None and image.ndim == 3 and image.shape[2] == 4:
                return on_white(image)
        image = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    except cv2.error as exc:
        raise ImageError(f"{name}: cannot decode image: {exc.err or exc}") from None
    if image is None:
        raise unreadable(data, name)
    return image


def read_file(path: str | Path) -> bytes:
    """The bytes of an image file, with `ImageError` for what a user can fix (missing, a folder, no access)."""
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise ImageError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ImageError(f"{path}: is a directory") from None
    except PermissionError:
        raise ImageError(f"{path}: permission denied") from None


def read_image(path: str | Path) -> np.ndarray:
    """Read an image file from disk as (H, W, 3) uint8 BGR."""
    return decode_image(read_file(path), str(path))


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) BGR or (H, W) gray -> (H, W) uint8 gray."""
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
