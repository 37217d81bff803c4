"""EXIF intrinsics: JPEGs and PNGs with lens EXIF built byte by byte (and by Pillow, as a cross-check, a WebP too)."""

import io
import math
import struct
import zlib

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from signpose.pipeline.camera import Camera, CameraError, assumed_camera
from signpose.pipeline.exif import (ExifCamera, LensExif, decode_with_exif, exif_camera, focal_px, read_lens_exif,
                           turned_camera)

FOCAL, FOCAL_35, PLANE_X, PLANE_UNIT, PIXEL_X, PIXEL_Y = 0x920A, 0xA405, 0xA20E, 0xA210, 0xA002, 0xA003
SHORT, LONG, RATIONAL = 3, 4, 5


def tiff_block(tags: dict[int, tuple[int, object]], order: str = "<") -> bytes:
    """A TIFF block whose IFD0 points to an Exif IFD holding `tags`: tag -> (type, int or (num, den))."""
    exif_at = 8 + 18  # header, then IFD0 with its one entry
    data_at = exif_at + 2 + 12 * len(tags) + 4
    entries, data = b"", b""
    for tag, (kind, value) in sorted(tags.items()):
        if kind == RATIONAL:
            entries += struct.pack(order + "HHII", tag, kind, 1, data_at + len(data))
            data += struct.pack(order + "II", *value)
        elif kind == SHORT:  # left-justified in the 4-byte value field, whatever the byte order
            entries += struct.pack(order + "HHIH2x", tag, kind, 1, value)
        else:
            entries += struct.pack(order + "HHII", tag, kind, 1, value)
    header = (b"II" if order == "<" else b"MM") + struct.pack(order + "HI", 42, 8)
    ifd0 = struct.pack(order + "HHHII", 1, 0x8769, LONG, 1, exif_at) + struct.pack(order + "I", 0)
    return header + ifd0 + struct.pack(order + "H", len(tags)) + entries + struct.pack(order + "I", 0) + data


def jpeg_with_exif(tiff: bytes, width: int = 64, height: int = 48) -> bytes:
    jpeg = cv2.imencode(".jpg", np.zeros((height, width, 3), np.uint8))[1].tobytes()
    app1 = b"Exif\x00\x00" + tiff
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpeg[2:]


PHONE = {FOCAL: (RATIONAL, (42, 10)), FOCAL_35: (SHORT, 26), PIXEL_X: (LONG, 4032), PIXEL_Y: (LONG, 3024)}
# 50 mm lens on a 23.5 mm wide, 6000 px APS-C sensor; FocalPlaneXResolution in pixels per inch.
DSLR = {FOCAL: (RATIONAL, (50, 1)), FOCAL_35: (SHORT, 75), PLANE_X: (RATIONAL, (6000 * 254, 235)),
        PLANE_UNIT: (SHORT, 2), PIXEL_X: (SHORT, 6000), PIXEL_Y: (SHORT, 4000)}


@pytest.mark.parametrize("order", ["<", ">"])
def test_phone_35mm_equivalent(order):
    cam = exif_camera(jpeg_with_exif(tiff_block(PHONE, order)), 4032, 3024).camera
    # 26 mm over the 43.27 mm full-frame diagonal, times the 5040 px image diagonal.
    assert cam.K[0, 0] == pytest.approx(26 * 5040 / math.hypot(36, 24)) == cam.K[1, 1]
    assert (cam.K[0, 2], cam.K[1, 2]) == (2016, 1512) and not cam.has_distortion
    assert cam.source == "EXIF focal length 4.2 mm (35 mm equiv 26 mm)"
    hfov = math.degrees(2 * math.atan(2016 / cam.K[0, 0]))
    assert 65 < hfov < 70  # what a 26 mm-equivalent phone camera sees across its long side


@pytest.mark.parametrize("order", ["<", ">"])
def test_focal_plane_resolution_is_preferred(order):
    jpeg = jpeg_with_exif(tiff_block(DSLR, order))
    f_full = 50 * 6000 / 23.5
    assert exif_camera(jpeg, 6000, 4000).camera.K[0, 0] == pytest.approx(f_full)
    assert exif_camera(jpeg, 1500, 1000).camera.K[0, 0] == pytest.approx(f_full / 4)  # resized
    portrait = exif_camera(jpeg, 1000, 1500).camera  # rotated by EXIF orientation when decoded
    assert portrait.K[0, 0] == pytest.approx(f_full / 4) and portrait.K[0, 2] == 500


def test_focal_plane_units():
    per_mm = {**DSLR, PLANE_X: (RATIONAL, (6000 * 10, 235)), PLANE_UNIT: (SHORT, 4)}
    assert exif_camera(jpeg_with_exif(tiff_block(per_mm)), 6000, 4000).camera.K[0, 0] == pytest.approx(50 * 6000 / 23.5)
    lens = read_lens_exif(jpeg_with_exif(tiff_block(DSLR)))
    assert lens == LensExif(50.0, 75.0, pytest.approx(6000 / 23.5), (6000, 4000))


def test_only_true_focal_length_is_not_enough():
    jpeg = jpeg_with_exif(tiff_block({FOCAL: (RATIONAL, (42, 10))}))
    assert read_lens_exif(jpeg).focal_mm == pytest.approx(4.2)
    assert exif_camera(jpeg, 4032, 3024).camera is None


def test_implausible_values_are_skipped():
    bogus_plane = {**DSLR, PLANE_X: (RATIONAL, (1, 1))}  # 1 px per inch: a 0.1° field of view
    cam = exif_camera(jpeg_with_exif(tiff_block(bogus_plane)), 6000, 4000).camera
    assert cam.K[0, 0] == pytest.approx(75 * math.hypot(6000, 4000) / math.hypot(36, 24))
    assert exif_camera(jpeg_with_exif(tiff_block({FOCAL_35: (SHORT, 1)})), 640, 480).camera is None
    assert exif_camera(jpeg_with_exif(tiff_block({FOCAL: (RATIONAL, (42, 0)), FOCAL_35: (SHORT, 0)})),
                       640, 480).camera is None


@pytest.mark.parametrize("tags, ignored", [
    ({FOCAL_35: (SHORT, 65535)}, "the photo's EXIF 35 mm-equivalent focal length of 65535 mm is implausible and was "
                                 "ignored"),
    ({FOCAL_35: (SHORT, 0)}, "35 mm-equivalent focal length of 0 mm is implausible and was ignored"),
    ({FOCAL: (RATIONAL, (0, 1)), FOCAL_35: (SHORT, 65535)},
     "focal length of 0 mm and 35 mm-equivalent focal length of 65535 mm are implausible and were ignored"),
    ({**DSLR, PLANE_X: (RATIONAL, (1, 1)), FOCAL_35: (SHORT, 0)}, "focal length of 50 mm and 35 mm-equivalent"),
    ({FOCAL: (RATIONAL, (42, 10))}, None),   # a true focal length without the sensor's size: not implausible
    ({FOCAL: (RATIONAL, (0, 1)), FOCAL_35: (SHORT, 26)}, None),   # the other one is used
    ({}, None),
])
def test_an_implausible_focal_length_is_said_to_be_ignored(tags, ignored):
    exif = exif_camera(jpeg_with_exif(tiff_block(tags)), 640, 480)
    assert (exif.camera is None) == (tags.get(FOCAL_35, (0, 0))[1] != 26)
    if ignored is None:
        assert exif.ignored is None
    else:
        assert ignored in exif.ignored


def test_no_exif():
    plain = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].tobytes()
    png = cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))[1].tobytes()
    for data in (plain, png, b"", b"\xff\xd8", b"\xff\xd8\xff\xe1\x00\x08Exif\x00\x00"):
        assert read_lens_exif(data) is None and exif_camera(data, 8, 8).camera is None


def test_reads_exif_written_by_pillow():
    Image = pytest.importorskip("PIL.Image")
    from PIL import ExifTags, TiffImagePlugin

    exif = Image.Exif()
    exif_ifd = exif.get_ifd(ExifTags.IFD.Exif)
    exif_ifd[ExifTags.Base.FocalLength] = TiffImagePlugin.IFDRational(57, 10)
    exif_ifd[ExifTags.Base.FocalLengthIn35mmFilm] = 24
    buf = io.BytesIO()
    Image.new("RGB", (400, 300)).save(buf, "JPEG", exif=exif)
    cam = exif_camera(buf.getvalue(), 400, 300).camera
    assert cam.K[0, 0] == pytest.approx(24 * 500 / math.hypot(36, 24))
    assert cam.source == "EXIF focal length 5.7 mm (35 mm equiv 24 mm)"


def test_focal_px_without_pixel_dimensions_assumes_the_recorded_size():
    lens = LensExif(focal_mm=50.0, focal_35mm=None, plane_px_per_mm=6000 / 23.5, pixel_size=None)
    assert focal_px(lens, 6000, 4000) == pytest.approx(50 * 6000 / 23.5)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_arbitrary_bytes_never_raise(data):
    camera = exif_camera(b"\xff\xd8" + data, 640, 480).camera  # must not raise, whatever the bytes
    assert camera is None or camera.K[0, 0] > 0


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(st.data())
def test_corrupted_exif_never_raises(data):
    jpeg = bytearray(jpeg_with_exif(tiff_block(DSLR, data.draw(st.sampled_from(["<", ">"])))))
    exif_end = 4 + 2 + 6 + len(tiff_block(DSLR)) + 2
    for _ in range(data.draw(st.integers(1, 8))):
        jpeg[data.draw(st.integers(2, exif_end))] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(2, len(jpeg)))
    camera = exif_camera(bytes(jpeg[:cut]), 6000, 4000).camera
    assert camera is None or camera.K[0, 0] > 0


def png_with_exif(tiff: bytes, width: int = 64, height: int = 48) -> bytes:
    """A PNG with `tiff` in an eXIf chunk after IHDR, as cameras and editors that write PNG put it."""
    png = cv2.imencode(".png", np.zeros((height, width, 3), np.uint8))[1].tobytes()
    chunk = struct.pack(">I", len(tiff)) + b"eXIf" + tiff + struct.pack(">I", zlib.crc32(b"eXIf" + tiff))
    ihdr_end = 8 + 8 + 13 + 4
    return png[:ihdr_end] + chunk + png[ihdr_end:]


def webp_with_exif(width: int = 400, height: int = 300, focal_35mm: int = 24) -> bytes:
    """A WebP with an EXIF chunk holding a 35 mm-equivalent focal length, as Pillow writes it."""
    from PIL import ExifTags, Image

    exif = Image.Exif()
    exif.get_ifd(ExifTags.IFD.Exif)[ExifTags.Base.FocalLengthIn35mmFilm] = focal_35mm
    buf = io.BytesIO()
    Image.new("RGB", (width, height)).save(buf, "WEBP", exif=exif)
    return buf.getvalue()


@pytest.mark.parametrize("name", ["png", "png_with_exif_header", "webp"])
def test_exif_is_read_from_png_and_webp_too(name):
    """Only a JPEG's was read: a PNG or WebP photo with its lens in EXIF fell back to the assumed 60°."""
    if name == "webp":
        data, size = webp_with_exif(), (400, 300)
    else:  # some writers begin a PNG's eXIf with the "Exif\0\0" of a JPEG's APP1
        data = png_with_exif((b"Exif\x00\x00" if name == "png_with_exif_header" else b"") + tiff_block(PHONE))
        size = (64, 48)
    image, exif = decode_with_exif(data, name)
    assert image.shape[:2] == size[::-1]
    f_35 = 24 if name == "webp" else 26
    assert exif.camera.K[0, 0] == pytest.approx(f_35 * math.hypot(*size) / math.hypot(36, 24))
    assert exif.camera.source.startswith("EXIF ") and f"35 mm equiv {f_35} mm" in exif.camera.source


def test_a_png_or_webp_without_exif_has_none():
    png = cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))[1].tobytes()
    webp = cv2.imencode(".webp", np.zeros((8, 8, 3), np.uint8))[1].tobytes()
    for data in (png, webp, png[:20], webp[:14]):
        assert read_lens_exif(data) is None


# EXIF orientation -> (rotation taking the camera frame of the pixels as stored to that of the photo as shown,
# and the stored pixel (x, y) -> shown pixel (x, y) for a W x H image)
TURNS = {3: (np.diag([-1.0, -1, 1]), lambda x, y, w, h: (w - 1 - x, h - 1 - y)),
         6: (np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), lambda x, y, w, h: (h - 1 - y, x)),
         8: (np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]]), lambda x, y, w, h: (y, w - 1 - x))}


@pytest.mark.parametrize("orientation", TURNS)
@pytest.mark.parametrize("terms", [4, 5, 8, 12, 14])
@pytest.mark.parametrize("sized", [True, False])
def test_a_turned_camera_sees_what_the_stored_one_saw_turned(orientation, terms, sized):
    """Every distortion model OpenCV has: points the camera saw, turned with the photo, are where the turned
    camera puts them, and undistorted there they give the stored camera's rays turned (the tangential and
    thin-prism terms change sign or swap; a tilted sensor's only under a half turn)."""
    rotation, pixel = TURNS[orientation]
    rng = np.random.default_rng(terms)
    dist = rng.normal(0, 0.01, terms)
    dist[0] = -0.1
    if terms == 14 and orientation != 3:
        dist[12:] = 0
    w, h = 640, 480
    camera = Camera(np.array([[520.0, 0, 380], [0, 510, 260], [0, 0, 1]]), dist, *((w, h) if sized else (None, None)))
    shown = (h, w) if orientation != 3 else (w, h)
    turned = turned_camera(camera, orientation, *shown)
    assert (turned.width, turned.height) == (shown if sized else (None, None))
    points = np.column_stack([rng.uniform(-1, 1, 50), rng.uniform(-0.7, 0.7, 50), rng.uniform(2, 4, 50)])
    stored = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera.K, camera.dist)[0].reshape(-1, 2)
    expected = np.column_stack(pixel(stored[:, 0], stored[:, 1], w, h))
    seen = cv2.projectPoints(points @ rotation.T, np.zeros(3), np.zeros(3), turned.K, turned.dist)[0].reshape(-1, 2)
    assert np.abs(seen - expected).max() < 1e-9
    undistort = getattr(cv2, "undistortPointsIter", cv2.undistortPoints)  # 4.x names the overload with criteria
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    rays = undistort(stored[:, None], camera.K, camera.dist, R=None, P=None, criteria=criteria).reshape(-1, 2)
    turned_rays = undistort(expected[:, None], turned.K, turned.dist, R=None, P=None, criteria=criteria)
    assert np.abs(turned_rays.reshape(-1, 2) - rays @ rotation[:2, :2].T).max() < 1e-9


def test_what_no_turned_camera_can_be_is_refused_with_why():
    camera = Camera(np.array([[520.0, 0, 320], [0, 510, 240], [0, 0, 1]]), np.zeros(5), 640, 480, "file:lens.yaml")
    assert turned_camera(camera, 1, 640, 480) is camera
    for orientation in (2, 4, 5, 7):
        with pytest.raises(CameraError, match=f"EXIF orientation {orientation} shows it mirrored"):
            turned_camera(camera, orientation, 640, 480)
    skewed = Camera(camera.K + [[0, 2, 0], [0, 0, 0], [0, 0, 0]], camera.dist, 640, 480)
    assert turned_camera(skewed, 3, 640, 480).K[0, 1] == 2  # a half turn keeps it
    with pytest.raises(CameraError, match="skew s=2 cannot be turned"):
        turned_camera(skewed, 6, 480, 640)
    tilted = Camera(camera.K, np.r_[np.zeros(12), 0.01, 0], 640, 480)
    with pytest.raises(CameraError, match="tilted-sensor"):
        turned_camera(tilted, 8, 480, 640)
    # in the camera's words, with how the photo's pixels are stored: a camera for another aspect
    with pytest.raises(CameraError, match=r"another aspect than the 640x480 px .*\(a camera file describes the pixels "
                                          r"as the camera stored them: 600x480 px in this photo, shown 480x600"):
        turned_camera(camera, 6, 480, 600)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_the_assumed_field_of_view_spans_the_sensor_however_the_photo_was_turned(orientation):
    """A photo the camera stored 640x480 and its EXIF orientation shows on its side (5-8) had the 60° across its
    480 px: a focal length 3/4 of the same photo's upright, and poses 25-36 cm off at 1-1.8 m."""
    sideways = orientation >= 5
    shown = (480, 640) if sideways else (640, 480)
    camera = ExifCamera(orientation=orientation).camera_for(None, *shown, 60.0)
    f = assumed_camera(640, 480, 60.0).K[0, 0]
    assert camera.K.tolist() == [[f, 0, shown[0] / 2], [0, f, shown[1] / 2], [0, 0, 1]]
    assert ("across the photo's height, the sensor's width" in camera.source) == sideways


def exif_photo(orientation: int, focal_35mm: int) -> bytes:
    """A small JPEG whose EXIF gives `orientation` and a 35 mm-equivalent focal length, as Pillow writes them."""
    from PIL import ExifTags, Image

    exif = Image.Exif()
    exif[ExifTags.Base.Orientation] = orientation
    exif.get_ifd(ExifTags.IFD.Exif)[ExifTags.Base.FocalLengthIn35mmFilm] = focal_35mm
    buf = io.BytesIO()
    Image.new("RGB", (40, 30)).save(buf, "JPEG", exif=exif)
    return buf.getvalue()


def test_an_exif_focal_length_is_held_to_a_field_of_view_across_the_sensor_however_the_photo_was_turned():
    """360 mm equivalent is 5.5° across a 4000x3000 sensor's width, a camera's, but 4.1° across its height: shown on
    its side, the photo's field of view was taken across its height, and the focal length refused as implausible."""
    upright = exif_camera(exif_photo(1, 360), 4000, 3000).camera
    sideways = exif_camera(exif_photo(6, 360), 3000, 4000).camera
    assert upright is not None and sideways is not None
    assert sideways.K[0, 0] == upright.K[0, 0] == pytest.approx(360 * 5000 / math.hypot(36, 24))
    assert exif_camera(exif_photo(6, 500), 3000, 4000).ignored.endswith("of 500 mm is implausible and was ignored")
