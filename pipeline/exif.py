"""Approximate intrinsics from an image's EXIF lens data (JPEG, PNG, WebP), read with the standard library only.

Better than an assumed field of view when there is no calibration: phones and cameras record
the focal length and either the sensor's pixel density or the 35 mm-equivalent focal length.
Distortion is unknown, so the result has none; the principal point is taken as the image centre.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .camera import Camera, assumed_camera
from .image import decode_image, exif_tiff, tiff_ifd

# The 35 mm-equivalent focal length is defined by the angle of view across the diagonal of a
# 36 x 24 mm frame, which keeps it independent of the image's aspect and orientation.
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
# Focal lengths giving a horizontal field of view outside this range are taken to be bogus EXIF.
PLAUSIBLE_HFOV_DEG = (5.0, 150.0)

_TAG_EXIF_IFD = 0x8769
_TAG_FOCAL_LENGTH = 0x920A
_TAG_FOCAL_35MM = 0xA405
_TAG_PLANE_X_RES = 0xA20E
_TAG_PLANE_UNIT = 0xA210
_TAG_PIXEL_X = 0xA002
_TAG_PIXEL_Y = 0xA003
# FocalPlaneResolutionUnit code -> millimetres per unit (2, inches, is the default).
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 1e-3}


@dataclass(frozen=True)
class LensExif:
    """Lens fields of one image's EXIF; None where absent or unusable.

    focal_mm: true focal length, mm. focal_35mm: 35 mm-equivalent focal length, mm. Both as
    recorded, 0 included (cameras write 0, or 65535, when they do not know it).
    plane_px_per_mm: sensor pixels per mm (FocalPlaneXResolution in its unit, converted).
    pixel_size: (width, height) px of the image the camera recorded, before any resizing.
    """

    focal_mm: float | None
    focal_35mm: float | None
    plane_px_per_mm: float | None
    pixel_size: tuple[int, int] | None


def _positive(value: float | None) -> float | None:
    return value if value is not None and value > 0 else None


def read_lens_exif(data: bytes) -> LensExif | None:
    """The lens fields of encoded image `data`'s EXIF (`exif_tiff`), or None when there is no EXIF or
    it is malformed."""
    tiff = exif_tiff(data)
    if tiff is None or tiff[:4] not in (b"II*\x00", b"MM\x00*"):
        return None
    order = "<" if tiff[:2] == b"II" else ">"
    try:
        ifd0 = tiff_ifd(tiff, struct.unpack_from(order + "I", tiff, 4)[0], order)
        if _TAG_EXIF_IFD not in ifd0:
            return None
        exif = tiff_ifd(tiff, int(ifd0[_TAG_EXIF_IFD]), order)
    except struct.error:  # offsets pointing outside the block: truncated or corrupt EXIF
        return None
    plane = _positive(exif.get(_TAG_PLANE_X_RES))
    unit_mm = _UNIT_MM.get(int(exif.get(_TAG_PLANE_UNIT, 2)))
    px, py = _positive(exif.get(_TAG_PIXEL_X)), _positive(exif.get(_TAG_PIXEL_Y))
    return LensExif(
        focal_mm=exif.get(_TAG_FOCAL_LENGTH),
        focal_35mm=exif.get(_TAG_FOCAL_35MM),
        plane_px_per_mm=plane / unit_mm if plane and unit_mm else None,
        pixel_size=(int(px), int(py)) if px and py else None,
    )


def _focal_lengths(lens: LensExif, width: int, height: int) -> list[tuple[str, float, float | None]]:
    """Each focal length `lens` records, the true one first: (what it is, its value in mm, in px for a
    `width` x `height` image or None when it cannot be converted). The true focal length is times
    the sensor's pixel density (scaled when the image was resized from `lens.pixel_size`), and
    cannot be converted without it; the 35 mm equivalent is over the diagonal. Orientation does
    not matter: both assume square pixels."""
    found = []
    if lens.focal_mm is not None:
        f = None
        if lens.plane_px_per_mm:
            scale = max(width, height) / max(lens.pixel_size) if lens.pixel_size else 1.0
            f = lens.focal_mm * lens.plane_px_per_mm * scale
        found.append(("focal length", lens.focal_mm, f))
    if lens.focal_35mm is not None:
        found.append(("35 mm-equivalent focal length", lens.focal_35mm,
                      lens.focal_35mm * math.hypot(width, height) / FULL_FRAME_DIAGONAL_MM))
    return found


def _plausible(f: float, width: int) -> bool:
    """Whether a focal length of `f` px gives a `width` px wide image a field of view in PLAUSIBLE_HFOV_DEG."""
    lo, hi = PLAUSIBLE_HFOV_DEG
    return f > 0 and lo <= math.degrees(2 * math.atan(width / (2 * f))) <= hi


def focal_px(lens: LensExif, width: int, height: int) -> float | None:
    """Focal length in px for a `width` x `height` image from `lens`, or None if it cannot be had:
    the first of `_focal_lengths` that converts to a plausible field of view."""
    return next((f for _, _, f in _focal_lengths(lens, width, height) if f is not None and _plausible(f, width)),
                None)


def ignored_focal(lens: LensExif, width: int, height: int) -> str | None:
    """For people, the focal lengths `lens` records that were refused for a `width` x `height` image as no
    real lens's (0, or 65535 mm: a field of view outside PLAUSIBLE_HFOV_DEG); None when `focal_px` has
    one, or none was refused (none recorded, or a true focal length without the sensor's density)."""
    if focal_px(lens, width, height) is not None:
        return None
    refused = [f"{what} of {mm:g} mm" for what, mm, f in _focal_lengths(lens, width, height)
               if mm <= 0 or (f is not None and not _plausible(f, width))]
    if not refused:
        return None
    verbs = "is implausible and was" if len(refused) == 1 else "are implausible and were"
    return f"the photo's EXIF {' and '.join(refused)} {verbs} ignored"


class ExifCamera(NamedTuple):
    """What a photo's EXIF gives for its camera: `camera`, from a plausible focal length, or None;
    then `ignored` says which focal length the EXIF records that was refused, if it records one."""

    camera: Camera | None = None
    ignored: str | None = None

    def or_assumed(self, width: int, height: int, hfov_deg: float) -> Camera:
        """The EXIF's camera, else one of `hfov_deg` horizontal field of view for the `width` x `height` px
        image (saying so when the EXIF records a focal length that was refused)."""
        return self.camera or assumed_camera(width, height, hfov_deg, self.ignored)


def exif_camera(data: bytes, width: int, height: int) -> ExifCamera:
    """A distortion-free camera for the decoded `width` x `height` image from the EXIF of its encoded
    `data` (JPEG, PNG, WebP), or why none (`ExifCamera`).

    `width`, `height` are of the image as decoded (after EXIF orientation). `source` names the
    EXIF fields used, e.g. "EXIF focal length 4.2 mm (35 mm equiv 26 mm)".
    """
    lens = read_lens_exif(data)
    f = focal_px(lens, width, height) if lens is not None else None
    if f is None:
        return ExifCamera(None, ignored_focal(lens, width, height) if lens is not None else None)
    parts = [f"focal length {lens.focal_mm:.3g} mm"] if lens.focal_mm else []
    if lens.focal_35mm:
        parts.append(f"35 mm equiv {lens.focal_35mm:.3g} mm")
    source = "EXIF " + (f"{parts[0]} ({parts[1]})" if len(parts) == 2 else parts[0])
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    return ExifCamera(Camera(K, np.zeros(5), width, height, source))


def decode_with_exif(data: bytes, name: str) -> tuple[np.ndarray, ExifCamera]:
    """Encoded image bytes -> ((H, W, 3) uint8 BGR as `decode_image` gives it, what its EXIF gives for
    the camera at that decoded size). Raises ImageError naming `name`."""
    image = decode_image(data, name)
    return image, exif_camera(data, image.shape[1], image.shape[0])
