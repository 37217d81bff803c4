"""Quick synthetic photos for server tests: a library sign warped onto a noisy wall, as JPEG bytes.

pipeline.synth renders realistic rooms but takes seconds per scene; these take milliseconds.
"""

from __future__ import annotations

import io
import json
import struct
import zlib

import cv2
import numpy as np
from PIL import Image

from signpose.app.workspace import SAMPLE_SCENES
from signpose.pipeline.camera import Camera, load_camera
from signpose.pipeline.library import Library, LibrarySign
from tools.render_library import render_sign
from tests.support.chessboards import pixel_rays

SIZE = (640, 480)  # (w, h) px


def wall(seed: int) -> np.ndarray:
    """(h, w) uint8 mid-gray noise: darker than any sign's white."""
    rng = np.random.default_rng(seed)
    return (rng.random((SIZE[1], SIZE[0])) * 50 + 60).astype(np.uint8)


def shaded_wall(seed: int) -> np.ndarray:
    """(h, w) float32 wall lit unevenly: its gray drifts by about 25 levels over 50 px, so each side
    of a plaque meets another contrast and blur shifts its edge by another fraction of a pixel."""
    rng = np.random.default_rng(seed)
    drift = cv2.GaussianBlur(rng.normal(0, 200, (SIZE[1], SIZE[0])).astype(np.float32), (0, 0), 15)
    return np.clip(110 + drift, 40, 180)


def sign_on_wall(sign, corners: np.ndarray, wall_seed: int, gain: float = 1.0) -> np.ndarray:
    """(h, w) uint8 `wall(wall_seed)` with `sign`'s image, times `gain`, warped onto `corners`
    (4 x 2 image points of its top-left, top-right, bottom-right, bottom-left)."""
    w, h = sign.size_px
    H = cv2.getPerspectiveTransform(np.float32([[0, 0], [w, 0], [w, h], [0, h]]), np.float32(corners))
    image = sign.image if gain == 1.0 else (sign.image * gain).astype(np.uint8)
    warped = cv2.warpPerspective(image, H, SIZE)
    inside = cv2.warpPerspective(np.full_like(sign.image, 255), H, SIZE) > 0
    return np.where(inside, warped, wall(wall_seed))


def sign_photo(library: Library, sign_id: str, seed: int = 0) -> bytes:
    """JPEG of `sign_id` seen slightly obliquely in the middle of a wall."""
    rng = np.random.default_rng(seed)
    jitter = rng.uniform(-15, 15, (4, 2))
    dst = np.float32([[170, 160], [470, 175], [460, 300], [180, 290]] + jitter)
    gray = sign_on_wall(library[sign_id], dst, seed)
    return cv2.imencode(".jpg", cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR), [cv2.IMWRITE_JPEG_QUALITY, 92])[1].tobytes()


def render_plaque(sign, corners: np.ndarray, wall, gain: float = 1.0, big: int = 4) -> np.ndarray:
    """(480, 640) float32 image of `sign`'s image times `gain` with its corners at `corners`
    (4 x 2, image px) over `wall` (a gray level, or a (480, 640) image): rendered `big` times
    larger and shrunk, so its edges are anti-aliased."""
    # library pixel i covers [i, i + 1] (its edges at 0 and w); big pixel j is image x = (j + 0.5) / big - 0.5
    H = cv2.getPerspectiveTransform(sign.corners_px.astype(np.float32),
                                    ((corners + 0.5) * big - 0.5).astype(np.float32))
    H = H @ np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])
    size = (SIZE[0] * big, SIZE[1] * big)
    plaque = cv2.warpPerspective(sign.image.astype(np.float32) * gain, H, size, flags=cv2.INTER_LINEAR)
    cover = cv2.warpPerspective(np.ones_like(sign.image, np.float32), H, size, flags=cv2.INTER_LINEAR)
    if np.ndim(wall):
        wall = cv2.resize(wall, size, interpolation=cv2.INTER_NEAREST)
    return cv2.resize(plaque + wall * (1 - cover), SIZE, interpolation=cv2.INTER_AREA)


def like_a_camera(image: np.ndarray, blur: float, seed: int) -> np.ndarray:
    """(H, W) float `image` blurred by a Gaussian of `blur` px and noised (σ 3 levels), as uint8."""
    noisy = cv2.GaussianBlur(image, (0, 0), blur) + np.random.default_rng(seed).normal(0, 3, image.shape)
    return np.clip(noisy, 0, 255).astype(np.uint8)


def plaque_of(text: str, sign_id: str = "decoy") -> LibrarySign:
    """A plaque of `text` made as the sample library's are (the same font, size and layout)."""
    return LibrarySign(sign_id, text, text, "", 0.6, 0.24, np.asarray(render_sign(text)))


# Other signs in the library's font, each sharing a word or most of its letters with one of its signs.
# وزارة التعليم differs from وزارة التعذيب only in its last letters, all in one strip (0.72-0.73 there).
DECOYS = ("رئيس الوزراء", "مكتب أمني", "وزارة الصحة", "مجمع تجاري", "وزارة الداخلية", "وزارة التعليم")
PLAQUE_AT = np.array([[200, 170], [440, 180], [436, 276], [204, 268]], float)  # a 240 px plaque, a little oblique


def decoy_image(text: str, seed: int) -> np.ndarray:
    """(480, 640) uint8 photo of a plaque of `text` at PLAQUE_AT on a shaded wall."""
    return like_a_camera(render_plaque(plaque_of(text), PLAQUE_AT, shaded_wall(seed), 0.92), 0.7, seed)


def block_sign(seed: int) -> bytes:
    """PNG of a 600 x 240 px sign of 60 x 24 random blocks: no other seed's, nor a sample sign, is
    alike (a copy of a sign the library has is refused)."""
    blocks = np.random.default_rng(seed).integers(0, 256, (24, 60), dtype=np.uint8)
    return cv2.imencode(".png", cv2.resize(blocks, (600, 240), interpolation=cv2.INTER_NEAREST))[1].tobytes()


def empty_photo(seed: int = 0) -> bytes:
    """JPEG of a wall without a sign."""
    return cv2.imencode(".jpg", wall(seed))[1].tobytes()


def with_focal_exif(jpeg: bytes, focal_35mm_mm: float) -> bytes:
    """`jpeg` re-saved with an EXIF 35 mm-equivalent focal length, as phone cameras write it."""
    exif = Image.Exif()
    exif[0x8769] = {0xA405: focal_35mm_mm}  # Exif IFD: FocalLengthIn35mmFilm
    out = io.BytesIO()
    Image.open(io.BytesIO(jpeg)).save(out, "JPEG", exif=exif, quality=95)
    return out.getvalue()


def tiny_photo() -> bytes:
    """A valid 64 x 48 px JPEG of a few hundred bytes."""
    return cv2.imencode(".jpg", np.full((48, 64), 90, np.uint8))[1].tobytes()


def png_bomb(width: int = 20_000, height: int = 20_000) -> bytes:
    """A tiny PNG whose header claims `width` x `height` px: decoding it would need gigabytes."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + \
        chunk(b"IEND", b"")


def big_photo(width: int, height: int, scene: str = "scene_002.jpg") -> bytes:
    """JPEG of a sample scene (scene_002 shows security_compound) upscaled to `width` x `height` px,
    standing in for a phone's photo."""
    image = cv2.imread(str(SAMPLE_SCENES / scene), cv2.IMREAD_COLOR)
    big = cv2.resize(image, (width, height), interpolation=cv2.INTER_CUBIC)
    return cv2.imencode(".jpg", big, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()


def scrambled_scene() -> bytes:
    """scrambled.jpg: sample scene_002 with every 37th byte inverted from byte 2000 on, as a failing copy makes.
    OpenCV decodes it mostly grey, warning only on stderr."""
    data = (SAMPLE_SCENES / "scene_002.jpg").read_bytes()
    return bytes(b ^ 0xFF if i >= 2000 and i % 37 == 0 else b for i, b in enumerate(data))


# How an iPhone's HEIC photo begins: an ftyp box, major brand "heic", compatible "mif1" and "heic".
HEIC_START = b"\x00\x00\x00\x18ftypheic\x00\x00\x00\x00mif1heic" + bytes(100)


def has(img: np.ndarray, color: tuple[int, int, int]) -> bool:
    """Whether `img` has a pixel of exactly `color` (BGR): the core of a line or letter drawn in it."""
    return bool(np.all(img == color, axis=2).any())


def corners_seen_from(sign: LibrarySign, position_m: tuple[float, float, float], hfov_deg: float = 60.0) -> np.ndarray:
    """(4, 2) image px of `sign`'s corners TL, TR, BR, BL in a SIZE image, photographed by a pinhole
    camera of `hfov_deg` standing at `position_m` in the sign frame (z < 0: in front of it) and
    looking at the sign's centre, upright."""
    forward = -np.asarray(position_m, float) / np.linalg.norm(position_m)
    right = np.cross([0.0, 1.0, 0.0], forward)   # the sign's y runs down, as the camera's does
    right /= np.linalg.norm(right)
    R = np.stack([right, np.cross(forward, right), forward])
    f = SIZE[0] / 2 / np.tan(np.radians(hfov_deg) / 2)
    K = np.array([[f, 0, SIZE[0] / 2], [0, f, SIZE[1] / 2], [0, 0, 1]])
    in_camera = (sign.to_metric(sign.corners_px) - position_m) @ R.T
    return (in_camera @ K.T)[:, :2] / in_camera[:, 2:]


def sign_seen_from(library: Library, sign_id: str, position_m: tuple[float, float, float], seed: int = 0,
                   hfov_deg: float = 60.0) -> bytes:
    """JPEG of `sign_id` on a noisy wall as `corners_seen_from` sees it (`hfov_deg`: the page's
    default assumed field of view, so the pose recognised is this one)."""
    gray = sign_on_wall(library[sign_id], corners_seen_from(library[sign_id], position_m, hfov_deg), seed)
    return cv2.imencode(".jpg", cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR), [cv2.IMWRITE_JPEG_QUALITY, 92])[1].tobytes()


def steep_plaque(sign: LibrarySign, off_axis_deg: float, distance_m: float = 1.0, seed: int = 0) -> np.ndarray:
    """(480, 640) uint8 photo of `sign` seen `off_axis_deg` off its normal from the side at `distance_m`
    (`corners_seen_from`), on a wall nearly as light as the plaque: no white blob stands out for the
    plaque fallback to read."""
    angle = np.radians(off_axis_deg)
    corners = corners_seen_from(sign, (distance_m * np.sin(angle), 0.0, -distance_m * np.cos(angle)))
    return like_a_camera(render_plaque(sign, corners, np.clip(shaded_wall(seed) + 90, 0, 255), 0.95), 0.7, seed)


# The sample scenes' camera with its principal point 60 px right of and 30 px below the centre, behind a lens
# with tangential distortion: a camera file every term of which a turned photo changes.
OFF_CENTRE = Camera(np.array([[554.2562584220408, 0, 380], [0, 554.2562584220408, 270], [0, 0, 1]]),
                    np.array([-0.08, 0.02, 0.003, -0.002, 0.0]), 640, 480, "off-centre lens")
TURNED_SCENE = "scene_002.jpg"  # security_compound, its pose in the scenes' truth.json


def lens_maps(lens: Camera, pinhole_K: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(map_x, map_y), each (h, w) float32 for `size` = (w, h) px of `lens`'s image: where each of its pixels
    reads a render by a pinhole camera with `pinhole_K` (3, 3), the px its ray meets it at (for cv2.remap)."""
    source = (pixel_rays(lens.K, lens.dist, size) @ pinhole_K.T)[..., :2].astype(np.float32)
    return source[..., 0], source[..., 1]


def through_lens(image: np.ndarray, lens: Camera, pinhole_K: np.ndarray | None = None) -> np.ndarray:
    """`image`, rendered by a pinhole camera with `pinhole_K` (3, 3) (default: `lens`'s K), as `lens` takes it,
    distortion and all (`lens_maps`), at the render's size. Near its edges the lens sees past the render:
    replicated, not black, which would be an edge beside a plaque that no camera makes."""
    h, w = image.shape[:2]
    map_x, map_y = lens_maps(lens, lens.K if pinhole_K is None else pinhole_K, (w, h))
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def turned_photos(*orientations: int) -> dict[int, bytes]:
    """JPEGs of the sample scene TURNED_SCENE as the OFF_CENTRE camera takes it, by EXIF orientation: their
    pixels are stored alike, as the sensor gave them, and the orientation turns them to be shown, as a phone
    held each way writes them (a camera file describes the pixels as stored)."""
    ideal = load_camera(SAMPLE_SCENES / "camera.yaml")  # the renders' pinhole camera
    seen = through_lens(cv2.imread(str(SAMPLE_SCENES / TURNED_SCENE)), OFF_CENTRE, ideal.K)
    out = io.BytesIO()
    Image.fromarray(seen[..., ::-1]).save(out, "JPEG", quality=95)
    return {orientation: with_orientation(out.getvalue(), orientation) for orientation in orientations}


def with_orientation(jpeg: bytes, orientation: int) -> bytes:
    """`jpeg`, its data as it is, with an EXIF APP1 giving `orientation` after its start of image."""
    exif = Image.Exif()
    exif[0x0112] = orientation
    app1 = exif.tobytes()  # "Exif\0\0" and the TIFF block
    return jpeg[:2] + b"\xff\xe1" + (len(app1) + 2).to_bytes(2, "big") + app1 + jpeg[2:]


# How near turned_scene_position a pose of TURNED_SCENE is expected: the sample scenes were drawn by a renderer
# that shrank each picture by its rim's coverage (RENDERING 1), and their truth puts the camera 7 mm from where
# the sign's edges, read in linear light, place it. A camera not turned with the photo put it 8 cm off.
TURNED_WITHIN_M = 0.01


def turned_scene_position() -> np.ndarray:
    """(3,) m: where the camera stood for TURNED_SCENE, in the sign frame (−Rᵀt of its truth)."""
    truth = json.loads((SAMPLE_SCENES / "truth.json").read_text())["images"][TURNED_SCENE]
    return -np.array(truth["R"]).T @ np.array(truth["t"])


# A 150 px sign, a little oblique, in dim_plaque_scene.
DIM_PLAQUE_AT = np.array([[230.0, 250.0], [380.0, 243.0], [383.0, 305.0], [228.0, 309.0]])


def dim_plaque_scene(sign=None, plaque_level: float = 150.0, blur: float = 1.5, exit_plaque=None, seed: int = 0) -> np.ndarray:
    """A 640 x 480 gray wall under a bright lamp (which sets the normalisation's maximum, so the
    plaques stay below the segmentation threshold), with `sign` at DIM_PLAQUE_AT and optionally a
    plaque reading EXIT at `exit_plaque` (x, y), both as bright as `plaque_level`; blurred and noised."""
    img = np.full((480, 640), 70, np.float32)
    img[20:60, 250:400] = 255
    if sign is not None:
        img = render_plaque(sign, DIM_PLAQUE_AT, img, plaque_level / 255)
    if exit_plaque is not None:
        x0, y0 = exit_plaque
        text = np.full((50, 125), plaque_level, np.uint8)
        cv2.putText(text, "EXIT", (12, 38), cv2.FONT_HERSHEY_SIMPLEX, 1.3, 25, 3)
        img[y0:y0 + 50, x0:x0 + 125] = text
    return like_a_camera(img, blur, seed)
