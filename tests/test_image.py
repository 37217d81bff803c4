"""Decoding input images: transparency shown over white, and errors that say what is wrong."""

import io

import cv2
import numpy as np
import pytest
from PIL import Image

from pipeline.image import ImageError, decode_image

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
