"""Decoding input images: transparency shown over white, and errors that say what is wrong."""

import base64
import io
import os
import re
import socket
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image, ImageOps

from signpose.pipeline.image import ImageError, decode_image, exif_orientation, read_file
from tests.support.chessboards import render_boards
from tests.support.scene_images import HEIC_START, scrambled_scene, with_orientation

# Black text on a transparent ground, as sign artwork is often drawn: the ground's colour
# values are black too (what many tools store under alpha 0).
ALPHA = np.zeros((48, 64), np.uint8)
ALPHA[16:32, 8:56] = 255
ARTWORK = {
    "RGBA": Image.fromarray(np.dstack([np.zeros((48, 64, 3), np.uint8), ALPHA]), "RGBA"),
    "LA": Image.fromarray(np.dstack([np.zeros((48, 64), np.uint8), ALPHA]), "LA"),
}


def encode(image: Image.Image, fmt: str, **options) -> bytes:
    out = io.BytesIO()
    image.save(out, fmt, **options)
    return out.getvalue()


TRANSPARENT = {
    "rgba.png": encode(ARTWORK["RGBA"], "PNG"),
    "gray_alpha.png": encode(ARTWORK["LA"], "PNG"),
    "palette.png": encode(Image.fromarray(255 - ALPHA).convert("P"), "PNG", transparency=255),
    "rgba16.png": cv2.imencode(".png", np.dstack([np.zeros((48, 64, 3), np.uint16), ALPHA.astype(np.uint16) * 257]))[1]
    .tobytes(),
    "lossless.webp": encode(ARTWORK["RGBA"], "WEBP", lossless=True),
    "lossy.webp": encode(ARTWORK["RGBA"], "WEBP", quality=90),
}


@pytest.mark.parametrize("name", TRANSPARENT)
def test_transparent_pixels_are_white(name):
    """Alpha was dropped, leaving the artwork black on black: a blank image to the library."""
    image = decode_image(TRANSPARENT[name], name)
    assert image.shape == (48, 64, 3) and image.dtype == np.uint8
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(int)
    assert np.abs(gray[ALPHA == 0] - 255).max() <= 8 and np.abs(gray[20:28, 12:52]).max() <= 8


def test_an_opaque_image_with_an_alpha_channel_keeps_its_colours():
    bgr = np.random.default_rng(0).integers(0, 256, (48, 64, 3), np.uint8)
    data = cv2.imencode(".png", np.dstack([bgr, np.full((48, 64), 255, np.uint8)]))[1].tobytes()
    assert np.array_equal(decode_image(data), bgr)


def test_floating_point_samples_are_named_not_called_damage():
    data = cv2.imencode(".tiff", np.full((48, 64, 3), 0.5, np.float32))[1].tobytes()
    with pytest.raises(ImageError) as info:
        decode_image(data, "f.tiff")
    assert str(info.value) == ("f.tiff: a TIFF of float32 samples, which signpose does not read; "
                               "export it with 8- or 16-bit integer samples")


def photo_jpeg(**options) -> bytes:
    """A small photo-like JPEG (texture and noise, so its data holds stuffed 0xFF bytes) saved by Pillow."""
    rng = np.random.default_rng(1)
    ramp = np.linspace(0, 255, 96)
    rgb = np.clip(np.dstack([ramp[None, :].repeat(64, 0), ramp[:64, None].repeat(96, 1), np.full((64, 96), 90.0)])
                  + rng.normal(0, 25, (64, 96, 3)), 0, 255).astype(np.uint8)
    image = Image.fromarray(rgb)
    mode = options.pop("mode", None)
    return encode(image.convert(mode) if mode else image, "JPEG", **options)


def with_restarts(jpeg: bytes) -> bytes:
    """`jpeg` re-encoded by OpenCV with a restart marker every MCU row (as many cameras write them)."""
    image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_RST_INTERVAL, 6])[1].tobytes()


def entropy_data(jpeg: bytes, scan: int = 0) -> slice:
    """Where the entropy-coded data of scan number `scan` (0 the first, -1 the last) lies in `jpeg`."""
    sos = [found.start() for found in re.finditer(rb"\xff\xda", jpeg)][scan]  # 0xFF in the data comes before 0x00
    start = sos + 2 + int.from_bytes(jpeg[sos + 2:sos + 4], "big")
    return slice(start, re.compile(rb"\xff[^\x00\xd0-\xd7]").search(jpeg, start).start())


SOUND_JPEGS = {
    "baseline.jpg": photo_jpeg(quality=95),
    "progressive.jpg": photo_jpeg(quality=90, progressive=True),
    "progressive_gray.jpg": photo_jpeg(mode="L", progressive=True),
    "progressive_cmyk.jpg": photo_jpeg(mode="CMYK", progressive=True),
    "progressive_opencv.jpg": cv2.imencode(".jpg", cv2.imdecode(np.frombuffer(photo_jpeg(), np.uint8), cv2.IMREAD_COLOR),
                                           [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes(),
    "progressive_restarts.jpg": cv2.imencode(".jpg", cv2.imdecode(np.frombuffer(photo_jpeg(), np.uint8), cv2.IMREAD_COLOR),
                                             [cv2.IMWRITE_JPEG_PROGRESSIVE, 1, cv2.IMWRITE_JPEG_RST_INTERVAL, 2])[1].tobytes(),
    "optimized_444.jpg": photo_jpeg(quality=95, subsampling=0, optimize=True),
    "gray.jpg": photo_jpeg(mode="L"),
    "cmyk.jpg": photo_jpeg(mode="CMYK"),
    "restarts.jpg": with_restarts(photo_jpeg(quality=95)),
    # EXIF with a JPEG thumbnail inside (its own markers, end of image included)
    "exif_thumbnail.jpg": photo_jpeg(exif=b"Exif\x00\x00II*\x00\x08\x00\x00\x00\x00\x00\x00\x00"
                                     + photo_jpeg(quality=50)),
    # a phone's second picture (depth map, gain map) after the end of the first
    "trailing_image.jpg": photo_jpeg() + photo_jpeg(quality=50),
    # fill 0xFF bytes before a marker, which the standard allows
    "fill_bytes.jpg": photo_jpeg().replace(b"\xff\xda", b"\xff\xff\xff\xda", 1),
}


@pytest.mark.parametrize("name", SOUND_JPEGS)
def test_sound_jpegs_of_every_kind_decode(name):
    data = SOUND_JPEGS[name]
    assert b"\xff\x00" in data[entropy_data(data).start:]  # what the damage check must tell from damage
    assert decode_image(data, name).shape == (64, 96, 3)


def damaged(jpeg: bytes, edit) -> bytes:
    """`jpeg` with `edit` applied to the entropy-coded data of its first scan."""
    where = entropy_data(jpeg)
    return jpeg[:where.start] + edit(jpeg[where]) + jpeg[where.stop:]


def stray_ff(data: bytes) -> bytes:
    """A data byte turned 0xFF before one that is not 0x00: it reads as a marker."""
    i = next(i for i in range(100, len(data) - 1) if data[i - 1] != 0xFF and data[i + 1] not in (0x00, 0xFF))
    return data[:i] + b"\xff" + data[i + 1:]


DAMAGED_JPEGS = {
    "scrambled.jpg": scrambled_scene(),
    # a stuffed 0x00 overwritten: the 0xFF before it then reads as a marker
    "unstuffed.jpg": damaged(SOUND_JPEGS["baseline.jpg"], lambda d: d.replace(b"\xff\x00", b"\xff\x37", 1)),
    "stray_ff.jpg": damaged(SOUND_JPEGS["optimized_444.jpg"], stray_ff),
    # a sector of zeros over a restart marker: the next one comes out of turn
    "zeroed.jpg": damaged(SOUND_JPEGS["restarts.jpg"], lambda d: d.replace(b"\xff\xd1", b"\x00\x00", 1)),
}


@pytest.mark.parametrize("name", DAMAGED_JPEGS)
def test_a_jpeg_with_damaged_image_data_is_refused_not_decoded_grey(name):
    """OpenCV decodes these (libjpeg fills what it cannot read with grey, or garbles it), warning
    only on stderr: a scrambled photo would be answered "no sign" without a word."""
    data = DAMAGED_JPEGS[name]
    assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) is not None
    with pytest.raises(ImageError) as info:
        decode_image(data, name)
    assert re.fullmatch(rf"{re.escape(name)}: damaged or truncated JPEG file \(its (image )?data is corrupt \(seen at "
                        r"byte \d+\): decoded, part of the picture would be grey or garbled\); copy or export it again",
                        str(info.value)), str(info.value)


def test_a_jpeg_cut_inside_its_image_data_says_so():
    data = SOUND_JPEGS["baseline.jpg"]
    with pytest.raises(ImageError, match=r"cut\.jpg: damaged or truncated JPEG file \(it ends inside its image data: "
                                         r"cut short\); copy or export it again"):
        decode_image(data[:len(data) * 2 // 3], "cut.jpg")


HEIF_FILES = {  # name: (bytes, what the error begins with)
    # told by content, whatever the name says
    "IMG_0001.jpg": (HEIC_START, "IMG_0001.jpg: HEIC/HEIF images are not supported: export it as JPEG (on an iPhone, "
                                 "to take JPEGs from now on: Settings > Camera > Formats > Most Compatible)"),
    "photo.heif": (b"\x00\x00\x00\x1cftypmif1\x00\x00\x00\x00mif1heixmiaf" + bytes(100),
                   "photo.heif: HEIC/HEIF images are not supported"),
    # an AVIF's brands include HEIF's mif1; some OpenCV builds decode AVIF, but not one without its image
    "photo.avif": (b"\x00\x00\x00\x20ftypavif\x00\x00\x00\x00avifmif1miafMA1B" + bytes(100),
                   "photo.avif: an AVIF image that cannot be read here (AVIF is not among the formats signpose "
                   "supports): export it as JPEG or PNG"),
    "clip.mp4": (b"\x00\x00\x00\x18ftypisom\x00\x00\x02\x00isomiso2" + bytes(100),
                 "clip.mp4: not an image file (use JPEG, PNG, TIFF, WebP, BMP or GIF)"),
}


@pytest.mark.parametrize("name", HEIF_FILES)
def test_heif_images_say_what_they_are_and_how_to_get_a_jpeg(name):
    """An iPhone's HEIC photo was called "not an image file"."""
    data, message = HEIF_FILES[name]
    with pytest.raises(ImageError) as info:
        decode_image(data, name)
    assert str(info.value).startswith(message)


def refusal(path: Path) -> str:
    """What `read_file` raises for `path`, read on a thread of its own: a read that never ends fails the test
    instead of hanging it."""
    outcome = []

    def read() -> None:
        try:
            read_file(path)
            outcome.append("read")
        except Exception as exc:  # whatever it is, the assertion shows it
            outcome.append(f"{type(exc).__name__}: {exc}")

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(10)
    assert outcome, f"reading {path} never ended"
    return outcome[0]


def test_read_file_refuses_what_is_not_a_regular_file_without_opening_it(tmp_path, monkeypatch):
    """A named pipe called photo.jpg was opened, and reading it waited for a writer forever."""
    monkeypatch.chdir(tmp_path)  # a socket's path must be short: bound by its name in this folder
    os.mkfifo("photo.jpg")
    with socket.socket(socket.AF_UNIX) as listening:
        listening.bind("socket.jpg")
        (tmp_path / "notes.txt").write_text("a file, not a folder")
        for path, kind in [(tmp_path / "photo.jpg", "is a named pipe (FIFO), not a regular file"),
                           (tmp_path / "socket.jpg", "is a socket, not a regular file"),
                           (Path(os.devnull), "is a device, not a regular file"),
                           (tmp_path, "is a directory, not a regular file"),
                           (tmp_path / "notes.txt" / "photo.jpg", "Not a directory")]:
            assert refusal(path) == f"ImageError: {path}: {kind}"


@pytest.mark.parametrize("bits", [8, 10, 12, 16])
def test_camera_data_of_any_depth_in_16_bits_keeps_its_levels(bits):
    """A mono12 or mono10 camera's frames saved as 16-bit PNG: the top 8 of 16 bits left them at
    levels 0-15 and 0-3, features found no match, and a harder scene was missed."""
    scene = cv2.imread(str(Path(__file__).parents[1] / "sample_images" / "scenes" / "scene_002.jpg"))
    if bits == 16:
        deep = scene.astype(np.uint16) * 257
    else:
        deep = scene.astype(np.uint16) << (bits - 8)
    image = decode_image(cv2.imencode(".png", deep)[1].tobytes(), f"mono{bits}.png")
    assert image.dtype == np.uint8 and np.array_equal(image, scene)


SCENE_002 = Path(__file__).parents[1] / "sample_images" / "scenes" / "scene_002.jpg"


def zeroed(data: bytes, start: int, stop: int) -> bytes:
    """`data` with zeros over bytes `start` to `stop`, as a failing card or copy leaves it."""
    return data[:start] + bytes(stop - start) + data[stop:]


def stopped_short(jpeg: bytes) -> dict[str, bytes]:
    """`jpeg`, progressive, stopped after each of its scans but the last: cut there with an end-of-image
    marker added, or zeros written over the rest up to its own (a failing card or copy). Named
    "cut_after_1", ..., "zeros_after_1" (its first scan), ...; the structure of each is sound."""
    ends = [entropy_data(jpeg, scan).stop for scan in range(jpeg.count(b"\xff\xda") - 1)]
    return {**{f"cut_after_{i + 1}": jpeg[:end] + b"\xff\xd9" for i, end in enumerate(ends)},
            **{f"zeros_after_{i + 1}": zeroed(jpeg, end, len(jpeg) - 2) for i, end in enumerate(ends)}}


def halfway_into_last_scan(jpeg: bytes) -> int:
    """Where `jpeg`'s last scan is half through its entropy-coded data."""
    last = entropy_data(jpeg, -1)
    return (last.start + last.stop) // 2


PROGRESSIVE_SCENE_002 = encode(Image.open(SCENE_002), "JPEG", quality=92, progressive=True)
STOPPED = "its scans stop before its picture is complete: cut short, or the rest overwritten"
RAN_OUT = "its image data runs out inside a scan: decoded, part of the picture is blurred or garbled"
SHORT_OF_DATA = {  # name: (bytes, why it is refused)
    **{f"{name[:-4]}_{how}.jpg": (data, STOPPED) for name in ["progressive.jpg", "progressive_gray.jpg",
                                                              "progressive_opencv.jpg"]
       for how, data in stopped_short(SOUND_JPEGS[name]).items()},
    # every scan there, the last one short of its data
    **{f"{name[:-4]}_cut_in_last_scan.jpg": (SOUND_JPEGS[name][:halfway_into_last_scan(SOUND_JPEGS[name])]
                                             + b"\xff\xd9", RAN_OUT)
       for name in ["progressive.jpg", "progressive_gray.jpg", "progressive_opencv.jpg"]},
    "progressive_zeros_in_last_scan.jpg": (zeroed(SOUND_JPEGS["progressive.jpg"],
                                                  halfway_into_last_scan(SOUND_JPEGS["progressive.jpg"]),
                                                  len(SOUND_JPEGS["progressive.jpg"]) - 2), RAN_OUT),
    # a photo cut at 97 % of its file: all but 3 % of its last scan there
    "scene_002_cut_at_97.jpg": (PROGRESSIVE_SCENE_002[:len(PROGRESSIVE_SCENE_002) * 97 // 100] + b"\xff\xd9",
                                RAN_OUT),
}


@pytest.mark.parametrize("name", SHORT_OF_DATA)
def test_a_progressive_jpeg_short_of_data_is_refused(name):
    """libjpeg decodes the scans and data there are, blurred or coarse, not grey, and says so only on stderr: a
    photo saved progressive and cut at 15 % (an end-of-image marker added, or zeros over the rest) reads at 26 dB
    and would be answered "no sign", at 25 % its pose 7 mm off. Baseline files cut so are refused as well."""
    data, why = SHORT_OF_DATA[name]
    assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) is not None
    with pytest.raises(ImageError, match=rf"^{re.escape(name)}: damaged or truncated JPEG file \({re.escape(why)}\); "
                                         r"copy or export it again$"):
        decode_image(data, name)


def cut_with_end(jpeg: bytes) -> bytes:
    """`jpeg` cut in the middle of its image data and ended there with an end-of-image marker, as a repair tool
    leaves it: its structure is sound and libjpeg runs out of data."""
    where = entropy_data(jpeg)
    return jpeg[:(where.start + where.stop) // 2] + b"\xff\xd9"


def grey_where(image: np.ndarray, *boxes: tuple[slice, slice]) -> np.ndarray:
    """`image` with each (rows, columns) box flat grey 128."""
    image = image.copy()
    for box in boxes:
        image[box] = 128
    return image


SCENE = cv2.imread(str(SCENE_002))
LETTERBOX_JPEG = cv2.imencode(".jpg", grey_where(SCENE, np.s_[:64], np.s_[-64:]))[1].tobytes()
ZEROED_JPEGS = {  # name: (bytes, the share of the picture drawn grey, in the message)
    "zeros_mid.jpg": (zeroed(SCENE_002.read_bytes(), 5000, 15000), "23"),
    "zeros_to_end.jpg": (zeroed(SCENE_002.read_bytes(), 5000, 25000), "62"),
    "zeros_early.jpg": (zeroed(SCENE_002.read_bytes(), 3000, 4000), "2.8"),
    # 98 bytes zeroed: the last two MCUs grey (their first column blended with the MCU before)
    "zeros_small.jpg": (zeroed(SCENE_002.read_bytes(), 1209, 1307), "0.17"),
    "cut_eoi_added.jpg": (SCENE_002.read_bytes()[:12960] + b"\xff\xd9", "61"),
    # turned when shown: libjpeg fills in the order the pixels are stored
    "zeros_turned.jpg": (with_orientation(zeroed(SCENE_002.read_bytes(), 5000, 25000), 6), "62"),
    "gray_8x8_mcus.jpg": (cut_with_end(photo_jpeg(mode="L", quality=95)), None),
    "444_8x8_mcus.jpg": (cut_with_end(photo_jpeg(quality=95, subsampling=0)), None),
    "422_16x8_mcus.jpg": (cut_with_end(photo_jpeg(quality=95, subsampling=1)), None),
    # grey of its own where the data runs out: a letterbox, zeroed in its picture or cut in its bottom bar
    "letterbox_zeroed.jpg": (zeroed(LETTERBOX_JPEG, 9000, 16000), "4.8"),
    "letterbox_cut.jpg": (LETTERBOX_JPEG[:-60] + b"\xff\xd9", "1.2"),
    "no_data.jpg": (SCENE_002.read_bytes()[:entropy_data(SCENE_002.read_bytes()).start] + b"\xff\xd9", "100"),
}


@pytest.mark.parametrize("name", ZEROED_JPEGS)
def test_a_jpeg_with_zeros_over_its_image_data_is_refused(name):
    """Zeros (a failing card or copy) make no marker, so the structure stays sound; libjpeg runs out
    of data and draws the rest grey, and the photo would be answered "no sign" (even 10 kB of zeros)."""
    data, share = ZEROED_JPEGS[name]
    assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) is not None
    with pytest.raises(ImageError, match=rf"{re.escape(name)}: damaged JPEG file \(its image data runs out before its "
                                         rf"end, and the last {share or '[0-9.]+'} % of its picture is drawn flat grey "
                                         r"\(128\), as libjpeg draws missing data\); copy or export it again"):
        decode_image(data, name)


GREY_PICTURES = {  # exactly 128 where libjpeg's fill would be, but of their own: what each is, (H, W[, 3]) uint8
    "letterbox.jpg": grey_where(SCENE, np.s_[:64], np.s_[-64:]),
    "pillarbox.jpg": grey_where(SCENE, np.s_[:, :80], np.s_[:, -80:]),
    "right_band.jpg": grey_where(SCENE, np.s_[:, -96:]),
    "corner_patch.jpg": grey_where(SCENE, np.s_[-100:, -120:]),
    "corner_block.jpg": grey_where(SCENE, np.s_[:8, :8]),
    # ending flat grey, as libjpeg draws missing data: refused as damaged
    "last_block.jpg": grey_where(SCENE, np.s_[-16:, -16:]),
    "bottom_band.jpg": grey_where(SCENE, np.s_[-80:]),
    "thin_top_wide_bottom.jpg": grey_where(SCENE, np.s_[:10], np.s_[-70:]),
    "all_grey.jpg": grey_where(SCENE, np.s_[:]),
    **{f"chessboard_{i}.jpg": board for i, board in enumerate(render_boards(3)[0])},  # borderValue 128 around
}


# Arithmetic-coded (SOF9), as `jpegtran -arithmetic` writes it and neither Pillow nor OpenCV can: scene_002 in gray at
# 128 x 96 px, its bottom half flat grey 128.
ARITHMETIC_GREY_BAND = base64.b64decode(
    "/9j/4AAQSkZJRgABAQAAAQABAAD/2wBDABsSFBcUERsXFhceHBsgKEIrKCUlKFE6PTBCYFVlZF9VXVtqeJmBanGQc1tdhbWGkJ6jq62rZ4C8yb"
    "qmx5moq6T/yQALCABgAIABAREA/8wABgAQEAX/2gAIAQEAAD8A/SYS6jLfx8XGqAwQOg0gqE11PT5ySBH63ru6LpyyeHKtqnS3U2gt0qa3SoAj"
    "zB3TT/W5G9uCxC/EnpvPICxQHHhV7d0jcd9E2p4l3j1E/IVKi74I/WOuNzX6qf8ALBzy2H7GSn3b2OooNJzXHeoFtzObkQk4Y5YD9RIqGgmyOk"
    "bgemXRBYDFQazogaVUdM4RfF4r5uuLjsyM9XFvXsZpcfdo9xjf4hBcVSerF+BEtJJi1dvJ6oAHyjxEFWzYzBSZXRPX3OxfKQvi38Y2BCk/tVBE"
    "4tbUB5BgWiSiUss+McGscBxfog6S6UNHbCjirOqhJZq3zKFFY2oy9JHEef0Df1uNk+vbkaRq+GHoJbfRDE1RJi1x5Ub/AHlOzuH5MIE420FL/w"
    "AXyzUAEy0cdl65dwMx6tKKMY1wBXNm5ZxFx5jexi6uSkklPHL44NMh2GXtgMDO9YqR53hKZIP8srANvW0T+1JUePWlFc52WDogN6CktspEm3Th"
    "jf8AGF7/2Q==")


def test_a_sound_arithmetic_coded_jpeg_ending_flat_grey_is_read():
    """An arithmetic decoder reads past a scan's end, counting on zero bytes there its encoder leaves out: decoded
    again with filler after its data, to see if libjpeg had run short, its last MCUs changed and it was refused."""
    assert decode_image(ARITHMETIC_GREY_BAND, "arithmetic.jpg").shape == (96, 128, 3)


@pytest.mark.parametrize("encoder", ["opencv", "pillow_444"])
@pytest.mark.parametrize("name", GREY_PICTURES)
def test_a_sound_jpeg_flat_grey_128_in_places_is_read(name, encoder):
    """A corner of 8 x 8 px exactly grey 128 was taken for libjpeg's fill: letterboxed and pillarboxed photos, and
    the project's own chessboard renders saved as JPEG, were refused as damaged (calibrate found no photo). Then
    a picture ending in flat grey 128 of its own was, unless grey reached up from there or began it: a last block
    of 128, a grey band at the bottom, a letterbox thinner at the top than an MCU (at 4:2:0), a blank picture."""
    picture = GREY_PICTURES[name]
    if encoder == "opencv":
        data = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    else:
        data = encode(Image.fromarray(picture[..., ::-1] if picture.ndim == 3 else picture), "JPEG", quality=95,
                      subsampling=0)
    assert decode_image(data, name).shape[:2] == picture.shape[:2]
    assert decode_image(with_orientation(data, 6), name).shape[:2] == picture.shape[1::-1]


# 40 x 60 px RGB, a white square top left and a red bar top right: no turn or mirror leaves it as it is.
PICTURE = np.zeros((40, 60, 3), np.uint8)
PICTURE[:10, :10] = 255
PICTURE[:5, 50:] = (255, 0, 0)


def oriented(fmt: str, mode: str, orientation: int) -> bytes:
    """PICTURE, as its pixels are stored, saved by Pillow as `fmt` in `mode` with EXIF `orientation`."""
    exif = Image.Exif()
    exif[0x0112] = orientation
    image = Image.fromarray(PICTURE).convert(mode)
    if fmt == "TIFF":  # the orientation is the TIFF's own tag
        return encode(image, fmt, exif=exif)
    lossless = {"WEBP": {"lossless": True}, "JPEG": {"quality": 100, "subsampling": 0}}.get(fmt, {})  # near enough
    return encode(image, fmt, exif=exif.tobytes(), **lossless)


@pytest.mark.parametrize("orientation", range(1, 9))
@pytest.mark.parametrize("fmt, mode", [("JPEG", "RGB"), ("PNG", "RGB"), ("PNG", "RGBA"), ("WEBP", "RGBA"),
                                       ("TIFF", "RGB")])
def test_every_format_is_turned_as_its_exif_orientation_says(fmt, mode, orientation):
    """A PNG or WebP with alpha was decoded as stored whatever its orientation (OpenCV turns none it reads with
    alpha), and which formats OpenCV turns depends on its version: the camera must be turned as the pixels were."""
    data = oriented(fmt, mode, orientation)
    # Pillow turns a TIFF as it loads it, and the others when asked
    shown = np.asarray(ImageOps.exif_transpose(Image.open(io.BytesIO(data))).convert("RGB"))[..., ::-1]
    assert exif_orientation(data) == orientation
    for image, expected in ((decode_image(data), shown), (decode_image(data, as_stored=True), PICTURE[..., ::-1])):
        assert image.shape == expected.shape and np.abs(image.astype(int) - expected).max() <= 8


def test_decoders_chatter_is_kept_off_stderr_and_other_threads_writes_are_not(capfd):
    """libjpeg warns from C on file descriptor 2 of an image signpose refuses in its own words. Decodes on four
    threads, while a fifth writes its own lines on stderr: each of those lines arrives, none of libjpeg's, and
    stderr is left where it was."""
    damaged = ZEROED_JPEGS["zeros_mid.jpg"][0]
    assert b"Corrupt JPEG data" in decoder_output(damaged)  # what is kept off

    def decode_all() -> None:
        for _ in range(20):
            with pytest.raises(ImageError):
                decode_image(damaged, "zeros_mid.jpg")
            decode_image(SOUND_JPEGS["baseline.jpg"])

    def write_lines() -> None:
        for i in range(200):
            os.write(2, f"line {i} of another thread\n".encode())

    threads = [threading.Thread(target=decode_all) for _ in range(4)] + [threading.Thread(target=write_lines)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    os.write(2, b"after\n")
    err = capfd.readouterr().err
    assert sorted(err.splitlines()) == sorted([f"line {i} of another thread" for i in range(200)] + ["after"])



def test_decodes_run_at_once_each_keeping_its_chatter_off_stderr(monkeypatch, capfd):
    """Decodes took a process-wide lock for as long as they ran, to point file descriptor 2 away and back: a
    server's batch decoded one photo at a time whatever its cores. Two decodes that each finish only once the
    other has begun both finish, and what they print on descriptor 2 stays off it."""
    both = threading.Barrier(2, timeout=5)
    imdecode = cv2.imdecode

    def meeting_decode(buf: np.ndarray, flags: int) -> np.ndarray | None:
        os.write(2, b"Corrupt JPEG data: premature end of data segment\n")
        both.wait()
        return imdecode(buf, flags)

    monkeypatch.setattr(cv2, "imdecode", meeting_decode)
    shapes = []
    threads = [threading.Thread(target=lambda: shapes.append(decode_image(SOUND_JPEGS["baseline.jpg"]).shape))
               for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(shapes) == 2
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"


def test_lines_written_while_decodes_overlap_arrive_as_each_decode_ends(monkeypatch, capfd):
    """Descriptor 2 points at the capture for as long as any decode runs, which on a busy server's threads may
    be for a whole batch: another thread's lines written meanwhile arrive as each decode ends (a line cut short,
    once it is whole or the last decode ends), not only after the last."""
    running, release = threading.Event(), threading.Event()
    imdecode = cv2.imdecode

    def held_decode(buf: np.ndarray, flags: int) -> np.ndarray | None:
        if threading.current_thread().name == "held":
            running.set()
            release.wait(5)
        return imdecode(buf, flags)

    monkeypatch.setattr(cv2, "imdecode", held_decode)
    held = threading.Thread(target=decode_image, args=(SOUND_JPEGS["baseline.jpg"],), name="held")
    held.start()
    assert running.wait(5)
    os.write(2, b"a line of another thread\nand half a")
    decode_image(SOUND_JPEGS["baseline.jpg"])  # begins and ends while the held one runs
    assert capfd.readouterr().err == "a line of another thread\n"
    release.set()
    held.join()
    assert capfd.readouterr().err == "and half a"


def test_decodes_work_with_file_descriptor_2_closed():
    """A process started with its standard descriptors closed (a daemon's `<&- 2>&-`) failed every decode:
    duplicating descriptor 2, to point it back after the decode, raised EBADF. It decodes, refusing in its own
    words what it refuses, and what the decoders print goes nowhere."""
    code = ("import os; os.close(0); os.close(2)\n"
            "from signpose.pipeline.image import ImageError, decode_image\n"
            f"data = open({str(SCENE_002)!r}, 'rb').read()\n"
            "print(decode_image(data).shape)\n"
            "try:\n"
            "    decode_image(data[:5000] + bytes(10000) + data[15000:], 'zeroed.jpg')\n"
            "except ImageError as error:\n"
            "    print(error)\n")
    run = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).parents[1], capture_output=True, text=True)
    assert run.returncode == 0 and run.stdout.startswith("(480, 640, 3)\nzeroed.jpg: damaged JPEG file"), run


def decoder_output(data: bytes) -> bytes:
    """What OpenCV's decoders print on file descriptor 2 decoding `data`, in a process of their own."""
    code = "import sys, numpy, cv2; cv2.imdecode(numpy.frombuffer(sys.stdin.buffer.read(), numpy.uint8), 1)"
    return subprocess.run([sys.executable, "-c", code], input=data, capture_output=True).stderr
