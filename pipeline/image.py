"""Decoding input images into 8-bit BGR arrays, with clear errors for what cannot be used."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


class ImageError(ValueError):
    """An input that is not a usable image; the message says why."""


def decode_image(data: bytes, name: str = "image") -> np.ndarray:
    """Encoded bytes (JPEG, PNG, TIFF, WebP, BMP, GIF first frame, ...) -> (H, W, 3) uint8 BGR.

    EXIF orientation is applied; 16-bit images are scaled to 8 bits, alpha dropped, gray expanded.
    """
    if not data:
        raise ImageError(f"{name}: file is empty")
    buf = np.frombuffer(data, dtype=np.uint8)
    try:
        image = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    except cv2.error as exc:
        raise ImageError(f"{name}: cannot decode image: {exc.err or exc}") from None
    if image is None:
        raise ImageError(f"{name}: not a readable image (unknown format, truncated or corrupt)")
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
