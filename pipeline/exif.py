"""What an image's EXIF (JPEG, PNG, WebP) says of its camera, read with the standard library only:
approximate intrinsics from its lens data, and how its orientation turns a camera file's.

Better than an assumed field of view when there is no calibration: phones and cameras record
the focal length and either the sensor's pixel density or the 35 mm-equivalent focal length.
Distortion is unknown, so the result has none; the principal point is taken as the image centre.
A camera file describes the pixels as the camera stored them; a photo is decoded turned as its
EXIF orientation says, and the camera is turned with it (`turned_camera`).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .camera import Camera, CameraError, assumed_camera
from .image import decode_image, exif_orientation, exif_tiff, tiff_ifd

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
    then `ignored` says which focal length the EXIF records that was refused, if it records one.
    `orientation`: its EXIF orientation (1-8), which turned its pixels as they were decoded."""

    camera: Camera | None = None
    ignored: str | None = None
    orientation: int = 1

    def camera_for(self, camera: Camera | None, width: int, height: int, hfov_deg: float) -> Camera:
        """The intrinsics the photo, decoded to `width` x `height` px, is recognised with: `camera` (a camera
        file's) turned as the photo was (`turned_camera`); without one the EXIF's camera, else one of `hfov_deg`
        horizontal field of view across the sensor as it stored the photo, as a focal length for the camera
        however it was held (saying so when the EXIF records a focal length that was refused).
        CameraError when `camera` cannot be turned, or does not fit the photo as stored."""
        if camera is not None:
            return turned_camera(camera, self.orientation, width, height)
        return self.camera or assumed_camera(width, height, hfov_deg, self.ignored, self.orientation in _SIDEWAYS)


# The EXIF orientations that turn a photo, and how: the 2x2 matrix A taking a point's (x, y) in the
# pixels as stored, about any centre, to (x, y) as shown, and in what words. The others mirror it.
_TURNS = {3: (np.array([[-1, 0], [0, -1]]), "a half turn"),
          6: (np.array([[0, -1], [1, 0]]), "a quarter turn clockwise"),
          8: (np.array([[0, 1], [-1, 0]]), "a quarter turn anticlockwise")}
_MIRRORS = {2: "left to right", 4: "top to bottom", 5: "across its diagonal", 7: "across its other diagonal"}
# The EXIF orientations that show a photo on its side, its width the sensor's height: the quarter turns
# and the mirrors across a diagonal.
_SIDEWAYS = (5, 6, 7, 8)


def stored_size(orientation: int, width: int, height: int) -> tuple[int, int]:
    """(width, height) px of the pixels as the camera stored them, of a photo of EXIF `orientation`
    shown `width` x `height` px."""
    return (height, width) if orientation in _SIDEWAYS else (width, height)


def turned_camera(camera: Camera, orientation: int, width: int, height: int) -> Camera:
    """`camera`, from a camera file, which describes the pixels as the camera stored them, for a photo of
    EXIF `orientation` decoded turned as it says (`pipeline.image.decode_image`) to `width` x `height` px.

    Under the turn, pixel centres map as x_shown = A x_stored + b (A in _TURNS, b keeping whole pixels at
    0 .. size - 1), and so do normalised image points, whose camera frame turns about its z axis: K's
    focal lengths swap under a quarter turn, and the distortion's tangential (p2, p1) and thin-prism
    (s1, s3), (s2, s4) terms turn as vectors do (OpenCV's model: x'' = x r(r²) + 2 p1 x y + p2 (r² +
    2x²) + s1 r² + s2 r⁴ and likewise for y, radial terms unchanged). R and t of a pose are then in
    the frame of the photo as shown, and the camera's position in the sign frame is the same
    whatever the orientation. Not scaled: the pipeline scales the result to the photo (with its
    note). CameraError for a mirrored photo (no camera sees a mirror image: its pose would be a
    mirror's), a skewed or tilted-sensor (tau) camera under a quarter turn (its K or model cannot
    hold the turn), or a camera that does not fit the photo's pixels as stored.
    """
    if orientation in _MIRRORS:
        raise CameraError(f"the photo's EXIF orientation {orientation} shows it mirrored {_MIRRORS[orientation]}, "
                          "and a mirror image is no camera's view (its pose would be a mirror's): set its "
                          "orientation to 1 to use its pixels as the camera stored them, or leave out the camera")
    if orientation not in _TURNS:
        return camera
    A, words = _TURNS[orientation]
    quarter = A[0, 0] == 0
    stored = stored_size(orientation, width, height)
    try:
        camera.for_image(*stored)
    except CameraError as exc:
        raise CameraError(f"{exc} (a camera file describes the pixels as the camera stored them: {stored[0]}x"
                          f"{stored[1]} px in this photo, shown {width}x{height} as its EXIF orientation "
                          f"{orientation} turns them)") from None
    size = np.array((camera.width, camera.height) if camera.width is not None else stored)
    F = A @ camera.K[:2, :2] @ A.T
    if F[1, 0] != 0:  # OpenCV's K has no place for the skew a quarter turn moves below the diagonal
        raise CameraError(f"this camera's skew s={camera.K[0, 1]:g} cannot be turned with a photo turned {words} by "
                          "its EXIF orientation: calibrate without skew, or set the photo's orientation to 1 to use "
                          "its pixels as the camera stored them")
    K = np.eye(3)
    K[:2, :2], K[:2, 2] = F, A @ camera.K[:2, 2] + (A == -1) @ (size - 1)
    dist = camera.dist.copy()
    dist[[3, 2]] = A @ camera.dist[[3, 2]]  # (p2, p1)
    if dist.size >= 12:
        dist[[8, 10]], dist[[9, 11]] = A @ camera.dist[[8, 10]], A @ camera.dist[[9, 11]]
    if dist.size == 14 and dist[12:].any():
        if quarter:  # the sensor's tilt, Ry(tau_y) Rx(tau_x), turned is Rx Ry: another model
            raise CameraError("a tilted-sensor camera (tau_x, tau_y) cannot be turned a quarter turn with its photo: "
                              "set the photo's EXIF orientation to 1 to use its pixels as the camera stored them")
        dist[12:] = -dist[12:]
    w, h = (int(size[1]), int(size[0])) if quarter else (int(size[0]), int(size[1]))
    sized = camera.width is not None
    return Camera(K, dist, w if sized else None, h if sized else None,
                  f"{camera.source}, turned {words} with the photo (EXIF orientation {orientation})")



def exif_camera(data: bytes, width: int, height: int) -> ExifCamera:
    """A distortion-free camera for the decoded `width` x `height` image from the EXIF of its encoded
    `data` (JPEG, PNG, WebP), or why none (`ExifCamera`).

    `width`, `height` are of the image as decoded (after EXIF orientation, which the result keeps
    for a camera file's intrinsics: `ExifCamera.camera_for`). `source` names the EXIF fields used,
    e.g. "EXIF focal length 4.2 mm (35 mm equiv 26 mm)". Centred with square pixels, the camera is
    the same however the photo was turned: its focal length is held to PLAUSIBLE_HFOV_DEG across the
    sensor's width, as the pixels are stored.
    """
    lens, orientation = read_lens_exif(data), exif_orientation(data)
    stored = stored_size(orientation, width, height)
    f = focal_px(lens, *stored) if lens is not None else None
    if f is None:
        return ExifCamera(None, ignored_focal(lens, *stored) if lens is not None else None, orientation)
    parts = [f"focal length {lens.focal_mm:.3g} mm"] if lens.focal_mm else []
    if lens.focal_35mm:
        parts.append(f"35 mm equiv {lens.focal_35mm:.3g} mm")
    source = "EXIF " + (f"{parts[0]} ({parts[1]})" if len(parts) == 2 else parts[0])
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    return ExifCamera(Camera(K, np.zeros(5), width, height, source), orientation=orientation)


def decode_with_exif(data: bytes, name: str) -> tuple[np.ndarray, ExifCamera]:
    """Encoded image bytes -> ((H, W, 3) uint8 BGR as `decode_image` gives it, what its EXIF gives for
    the camera at that decoded size). Raises ImageError naming `name`."""
    image = decode_image(data, name)
    return image, exif_camera(data, image.shape[1], image.shape[0])
