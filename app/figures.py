"""PNG figures of each pipeline stage for one image, and of calibration photos, drawn with OpenCV.

All figures are BGR uint8, scaled down so their longer side is at most `MAX_SIDE_PX`; line
widths and text scale with the image so they stay visible on 12-megapixel photos.
"""

from __future__ import annotations

import cv2
import numpy as np

from signpose.pipeline.calibrate import BoardView
from signpose.pipeline.camera import Camera
from signpose.pipeline.image import to_gray
from signpose.pipeline.library import Library
from signpose.pipeline.recognize import Attempt, Recognition, SignScore
from signpose.pipeline.segment import Box, Segmentation, normalize_levels, segment
from signpose.pipeline.verify import TextCheck, TextTemplate, rectify_text, text_template, text_threshold

STAGES = ("input", "gray", "mask", "blob", "crop", "matches", "inliers", "text")
# The stages drawn on the colour photo; the others need only its gray.
PHOTO_STAGES = ("input", "blob", "crop", "matches", "inliers")
MAX_SIDE_PX = 1600
# Figures of smaller images are drawn on a copy enlarged to this, each pixel a square block: on a
# 1 x 1 px image the "no sign" label covered the whole photo, which the page then showed as a
# large black square.
MIN_SIDE_PX = 320
MATCH_PANEL_HEIGHT_PX = 600
MATCH_PANEL_MAX_WIDTH_PX = 4 * MATCH_PANEL_HEIGHT_PX
# BGR
GREEN, RED, YELLOW, ORANGE, CYAN, WHITE, BLACK = (60, 200, 60), (60, 60, 230), (0, 220, 255), (0, 140, 255), \
    (230, 200, 0), (255, 255, 255), (0, 0, 0)
DIM = 0.35
# UNSEEN: a strip the text check did not see (not a gray: the photo is gray); DARK: the page's
# figure background (#1f2328).
UNSEEN, DARK = (210, 170, 140), (40, 35, 31)
# The text check's figure: figure px per template px (CHECK_WIDTH 128 -> 768 px wide), and its
# writing, about 20 px tall: some 12 px where the page shows the figure, 460 px wide.
TEXT_BLOCK_PX = 6
TEXT_CONTEXT_PX = 4  # template rows shown above and below the strips: the plaque, or what H put there instead
TEXT_FONT_SCALE, TEXT_THICKNESS = 0.9, 2
Spot = tuple[tuple[int, int], bool]  # where a label may go: (org, above) as `_band` takes them


class FigureError(LookupError):
    """A figure that cannot be drawn for this result (e.g. an unknown sign); the message says why."""


def _pen(shape: tuple[int, ...]) -> tuple[int, float]:
    """(line thickness px, font scale) readable on an image of `shape` after downscaling to MAX_SIDE_PX."""
    side = max(shape[:2])
    unit = max(1.0, side / 800)
    return max(1, round(2 * unit)), 0.6 * unit


def _band(shape: tuple[int, ...], text: str, org: tuple[int, int], above: bool = True) -> Box:
    """The black band `text` is written on in an image of `shape`: `org` (px) is its bottom-left
    corner, or with `above` False its top-left. Moved inside the image where it would stick out,
    so no label is cut off at an edge."""
    thick, scale = _pen(shape)
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    band_w, band_h = w + 2 * base, h + 2 * base
    x = max(0, min(org[0], shape[1] - band_w))
    top = max(0, min(org[1] - band_h if above else org[1], shape[0] - band_h))
    return x, top, x + band_w, top + band_h


def _write(img: np.ndarray, text: str, band: Box, color) -> None:
    """`text` on the black `band` made for it by `_band`, so it reads on any background."""
    thick, scale = _pen(img.shape)
    base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)[1]
    x0, y0, x1, y1 = band
    cv2.rectangle(img, (x0, y0), (x1, y1), BLACK, cv2.FILLED)
    cv2.putText(img, text, (x0 + base, y1 - base), cv2.FONT_HERSHEY_SIMPLEX, scale, color, thick, cv2.LINE_AA)


def _label(img: np.ndarray, text: str, org: tuple[int, int], color) -> None:
    """`text` on a black band whose bottom-left corner is `org` (px)."""
    _write(img, text, _band(img.shape, text, org), color)


def _overlap(a: Box, b: Box) -> bool:
    """Whether bands `a` and `b` share a pixel (their corners inclusive, as `_write` draws them)."""
    return a[0] <= b[2] and b[0] <= a[2] and a[1] <= b[3] and b[1] <= a[3]


def _free_band(shape: tuple[int, ...], text: str, spots: list[Spot], taken: list[Box]) -> Box:
    """The band for `text` at the first of `spots` ((org, above) as for `_band`) clear of every band
    in `taken`; when none is, the first spot moved down past the bands in its way, as far as the
    image allows. It joins `taken`."""
    bands = [_band(shape, text, org, above) for org, above in spots]
    band = next((b for b in bands if not any(_overlap(b, t) for t in taken)), bands[0])
    height = band[3] - band[1]
    while (hit := next((t for t in taken if _overlap(band, t)), None)) is not None and hit[3] + height < shape[0]:
        band = (band[0], hit[3] + 1, band[2], hit[3] + 1 + height)
    taken.append(band)
    return band


def _scaled(img: np.ndarray, scale: float) -> np.ndarray:
    """`img` resized by `scale`, at least 1 px each way: a 4000 x 1 px strip would otherwise shrink to nothing."""
    h, w = img.shape[:2]
    return cv2.resize(img, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)


def fit(img: np.ndarray, max_side: int = MAX_SIDE_PX) -> np.ndarray:
    """`img` shrunk to at most `max_side` px a side; itself when it already fits."""
    scale = max_side / max(img.shape[:2])
    return img if scale >= 1 else _scaled(img, scale)


def _enlarged(img: np.ndarray) -> tuple[np.ndarray, int]:
    """`img` enlarged by the whole factor k that brings its longer side to MIN_SIDE_PX or more (each
    pixel a k x k block, no blur), and k; `img` itself and 1 when it is that large already."""
    h, w = img.shape[:2]
    k = -(-MIN_SIDE_PX // max(h, w))
    return (img, 1) if k <= 1 else (cv2.resize(img, (w * k, h * k), interpolation=cv2.INTER_NEAREST), k)


def _at(k: int, points: np.ndarray) -> np.ndarray:
    """Image px (pixel centres at whole numbers) on a copy enlarged k times by `_enlarged`."""
    return (np.asarray(points, dtype=np.float64) + 0.5) * k - 0.5


def _bgr(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img.copy()


def _enlarged_box(box: Box, k: int) -> Box:
    """`box` (x0, y0, x1, y1) px in the image `_enlarged` `k` times."""
    x0, y0, x1, y1 = box
    return k * x0, k * y0, k * x1, k * y1


def _box(img: np.ndarray, box: Box, color, text: str | None = None) -> None:

    thick, _ = _pen(img.shape)
    x0, y0, x1, y1 = box
    cv2.rectangle(img, (x0, y0), (x1 - 1, y1 - 1), color, thick, cv2.LINE_AA)
    if text:
        _label(img, text, (x0, y0), color)  # a tab on the box's top edge


def _quad(img: np.ndarray, corners: np.ndarray, color) -> None:
    thick, _ = _pen(img.shape)
    pts = np.round(corners).astype(np.int32)
    cv2.polylines(img, [pts], True, color, thick + 1, cv2.LINE_AA)


def segmentation_of(image: np.ndarray, recognition: Recognition) -> Segmentation:
    """The result's segmentation, or (segment_mode "none") what thresholding would have given."""
    return recognition.segmentation or segment(to_gray(image), recognition.settings)


def chosen_blob(recognition: Recognition) -> int | None:
    """Index into the segmentation's blobs of the region the answer came from, if it was a blob."""
    attempt = recognition.attempt
    if attempt is None or not attempt.source.startswith("blob "):
        return None
    return int(attempt.source.split()[1]) - 1


def answer_text(recognition: Recognition) -> str | None:
    """The recognised sign and what decided it (feature inliers and margin, or the plaque's
    correlation); None without a sign."""
    best = recognition.best
    if best is not None:
        return f"{best.sign} ({best.n_inliers} inliers, margin {recognition.margin})"
    if recognition.by_plaque:
        return f"{recognition.label} (plaque, correlation {recognition.plaque.correlation:.2f})"
    return None


def draw_input(image: np.ndarray, recognition: Recognition) -> np.ndarray:
    """The photo with every searched region and the recognised sign's outline (the result's
    `corners`), each labelled where no other label is."""
    img, k = _enlarged(image)
    img = img.copy() if k == 1 else img
    thick, _ = _pen(img.shape)
    labels = []  # (text, color, spots to try in turn) for `_free_band`
    for attempt in recognition.attempts:
        color = YELLOW if attempt is recognition.attempt else ORANGE
        x0, y0, _, y1 = region = _enlarged_box(attempt.region, k)
        _box(img, region, color)
        labels.append((attempt.source, color, [((x0, y0), True), ((x0, y0), False), ((x0, y1), False)]))
    corners, answer = recognition.corners, answer_text(recognition)
    if corners is not None and answer is not None:
        corners = _at(k, corners)
        _quad(img, corners, GREEN)
        (x0, y0), (_, y1) = np.min(corners, axis=0).astype(int), np.max(corners, axis=0).astype(int)
        # First, so it gets its spot: below the outline, as its region's label is above it.
        labels.insert(0, (answer, GREEN, [((x0, y1 + 2 * thick), False), ((x0, y0 - 2 * thick), True)]))
    else:  # bottom-left, else top-right: the full frame's label is top-left
        labels.insert(0, ("no sign", RED, [((0, img.shape[0]), True), ((img.shape[1], 0), False)]))
    taken: list[Box] = []
    for text, color, spots in labels:
        _write(img, text, _free_band(img.shape, text, spots, taken), color)
    return img


def draw_gray(image: np.ndarray, recognition: Recognition) -> np.ndarray:
    """The normalised gray image the threshold applies to, as uint8 levels (through a lookup table:
    a float copy of a 12 MP photo would take 48 MB)."""
    seg = segmentation_of(image, recognition)
    levels = normalize_levels(seg.source, seg.normalization)
    return cv2.LUT(seg.source, np.round(levels * 255).astype(np.uint8))


def draw_mask(image: np.ndarray, recognition: Recognition) -> np.ndarray:
    """White where the normalised gray passes the threshold."""
    return segmentation_of(image, recognition).mask


def draw_blob(image: np.ndarray, recognition: Recognition) -> np.ndarray:
    """The photo dimmed, candidate blobs tinted: the chosen one green, the others orange, with their crops."""
    seg = segmentation_of(image, recognition)
    img = cv2.convertScaleAbs(image, alpha=DIM)  # uint8 throughout: no float copy of a large photo
    chosen = chosen_blob(recognition)
    colors = [GREEN if i == chosen else ORANGE for i in range(len(seg.blobs))]
    for blob, color in zip(seg.blobs, colors):
        # Within the blob's box, in OpenCV: over all of a 12 MP photo the figure took 270 ms.
        x0, y0, x1, y1 = blob.bbox
        pixels = cv2.compare(seg.labels[y0:y1, x0:x1], blob.label, cv2.CMP_EQ)
        photo = image[y0:y1, x0:x1]
        tinted = cv2.addWeighted(photo, 0.5, np.full_like(photo, color), 0.5, 0)
        cv2.copyTo(tinted, pixels, img[y0:y1, x0:x1])
    img, k = _enlarged(img)  # tinted first, at the labels' resolution
    for i, (blob, crop, color) in enumerate(zip(seg.blobs, seg.crops, colors)):
        _box(img, _enlarged_box(crop, k), color, f"blob {i + 1}: {blob.area} px")
    if not seg.blobs:
        _label(img, "no blob above the threshold", (10, 10), RED)
    return img


def _region(recognition: Recognition, width: int, height: int) -> tuple[Attempt | None, Box]:
    attempt = recognition.attempt
    return attempt, attempt.region if attempt is not None else (0, 0, width, height)


def draw_crop(image: np.ndarray, recognition: Recognition) -> np.ndarray:
    """The region the answer came from, with its keypoints."""
    attempt, (x0, y0, x1, y1) = _region(recognition, image.shape[1], image.shape[0])
    img, k = _enlarged(image[y0:y1, x0:x1])
    img = img.copy() if k == 1 else img
    if attempt is not None:
        thick, _ = _pen(img.shape)
        for (x, y), size in zip(_at(k, attempt.features.xy - (x0, y0)), attempt.features.size):
            cv2.circle(img, (round(x), round(y)), max(2, round(k * size / 2)), CYAN, max(1, thick // 2),
                       cv2.LINE_AA)
        _label(img, f"{attempt.source}: {len(attempt.features)} keypoints", (6, 6), CYAN)
    return img


def pick_score(recognition: Recognition, library: Library, sign_id: str | None) -> SignScore:
    """The score for `sign_id`; by default the winner, else the sign with the most inliers."""
    scores = recognition.scores
    if sign_id is None:
        if recognition.best is not None:
            return recognition.best
        if not scores:
            raise FigureError("no region was searched, so there are no matches to show")
        return recognition.attempt.leader
    for score in scores:
        if score.sign == sign_id:
            return score
    if sign_id in library.ids:
        raise FigureError(f"this result predates sign {sign_id!r}; wait for the re-run to finish")
    raise FigureError(f"sign {sign_id!r} is not in the library; choose one of {', '.join(library.ids)}")


def _panel(img: np.ndarray) -> tuple[np.ndarray, float]:
    """`img` scaled to MATCH_PANEL_HEIGHT_PX tall, but at most MATCH_PANEL_MAX_WIDTH_PX wide (a
    4000 x 1 px region would otherwise become gigabytes) and then padded to that height; and the scale."""
    h, w = img.shape[:2]
    scale = min(MATCH_PANEL_HEIGHT_PX / h, MATCH_PANEL_MAX_WIDTH_PX / w)
    out = _scaled(img, scale)
    return cv2.copyMakeBorder(out, 0, MATCH_PANEL_HEIGHT_PX - out.shape[0], 0, 0, cv2.BORDER_CONSTANT), scale


def draw_matches(image: np.ndarray, recognition: Recognition, library: Library, sign_id: str | None,
                 inliers_only: bool) -> np.ndarray:
    """Library sign left, searched region of the photo right, a line per match.

    All ratio-test matches (inliers green, outliers red), or only the inliers together with
    the sign's outline as the homography maps it.
    """
    score = pick_score(recognition, library, sign_id)
    _, (x0, y0, x1, y1) = _region(recognition, image.shape[1], image.shape[0])
    sign_img = library[score.sign].image if score.sign in library.ids else np.zeros((64, 64), np.uint8)
    left, right = _bgr(sign_img), image[y0:y1, x0:x1]
    (left, s_left), (right, s_right) = _panel(left), _panel(right)
    img = np.hstack([left, right])
    shift = np.array([left.shape[1], 0.0])
    inliers = score.estimate.inliers if score.estimate is not None else np.zeros(score.n_matches, bool)
    for src, dst, ok in zip(score.src, score.dst, inliers):
        if inliers_only and not ok:
            continue
        a = np.round(src * s_left).astype(int)
        b = np.round((dst - (x0, y0)) * s_right + shift).astype(int)
        cv2.line(img, tuple(a), tuple(b), GREEN if ok else RED, 1, cv2.LINE_AA)
    if inliers_only and score.corners is not None:
        _quad(img, (score.corners - (x0, y0)) * s_right + shift, GREEN)
    what = f"{score.n_inliers} inliers" if inliers_only else f"{score.n_matches} matches, {score.n_inliers} inliers"
    _label(img, f"{score.sign}: {what}" + (f" ({score.reason})" if score.reason else ""), (8, 8), WHITE)
    return img


def _checked(recognition: Recognition, library: Library) -> tuple[str, np.ndarray, TextCheck, str]:
    """(sign id, H, check, what it is) of the check to draw: the recognised sign's, else the first
    winner the check turned down; FigureError saying why there is none."""
    if recognition.text_check is not None:
        sign_id, H, check = recognition.label, recognition.H, recognition.text_check
        what = "the photo, read through the homography"
    elif recognition.turned_down:
        first = recognition.turned_down[0]
        sign_id, H, check = first.sign, first.H, first.text
        what = f"turned down: {first.source} read as {first.sign}"
    elif recognition.settings.min_text_correlation <= 0:
        raise FigureError(f"the text check is off (min_text_correlation {recognition.settings.min_text_correlation:g}, "
                          "as in the paper preset): set it above 0 to check the recognised sign's text")
    else:
        raise FigureError("no sign was recognised and no winner turned down for its text, so no text was checked "
                          "(the scores say why)")
    if sign_id not in library.ids:
        raise FigureError(f"sign {sign_id!r} is no longer in the library; wait for the re-run to finish")
    return sign_id, H, check, what


def _stretched(levels: np.ndarray, rows: tuple[int, int], mask: np.ndarray) -> np.ndarray:
    """(h, w) float gray `levels` as uint8, their range over the strips' `rows` where `mask` is True
    stretched to 0-255: the correlation ignores each strip's gain and offset, and a dim photo read
    as it is would show darker than its sign's template for no difference the check sees."""
    top, bottom = rows
    inside = levels[top:bottom][mask[top:bottom]]
    lo, hi = (float(inside.min()), float(inside.max())) if inside.size else (0.0, 255.0)
    return np.clip((levels - lo) * (255 / max(hi - lo, 1e-6)), 0, 255).astype(np.uint8)


def _strip_colors(check: TextCheck, min_correlation: float) -> list[tuple[int, int, int]]:
    """Per strip: GREEN when it reaches `min_correlation`, RED when not, UNSEEN when it was not seen."""
    return [UNSEEN if c is None else GREEN if c >= min_correlation else RED for c in check.strips]


def _text_panel(levels: np.ndarray, template: TextTemplate, colors: list[tuple[int, int, int]]) -> np.ndarray:
    """The strips' rows of (h, w) uint8 `levels` at the template's resolution, and TEXT_CONTEXT_PX
    rows either side dimmed (the check does not compare them), TEXT_BLOCK_PX px a template px;
    each strip outlined in its colour."""
    k, top, bottom = TEXT_BLOCK_PX, int(template.rows[0]), int(template.rows[1])
    y0, y1 = max(0, top - TEXT_CONTEXT_PX), min(levels.shape[0], bottom + TEXT_CONTEXT_PX)
    panel = _bgr(cv2.resize(levels[y0:y1], None, fx=k, fy=k, interpolation=cv2.INTER_NEAREST))
    top, bottom = (top - y0) * k, (bottom - y0) * k
    panel[:top] = panel[:top] * DIM
    panel[bottom:] = panel[bottom:] * DIM
    for x0, x1, color in zip(template.columns[:-1], template.columns[1:], colors):
        # inside its own columns, so that two neighbours' edges show side by side
        cv2.rectangle(panel, (int(x0) * k + 1, top + 1), (int(x1) * k - 2, bottom - 2), color, 2)
    return panel


def _text_band(width: int, texts: list[tuple[str, int, int, tuple[int, int, int]]]) -> np.ndarray:
    """A DARK band `width` px wide with each (text, x0, x1, colour) centred between x0 and x1 px,
    in TEXT_FONT_SCALE, or smaller where one would not fit its span (a long sign id)."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    height = cv2.getTextSize("0", font, TEXT_FONT_SCALE, TEXT_THICKNESS)[0][1]
    scale = TEXT_FONT_SCALE
    # In steps: OpenCV 5 sizes its font in whole px, so a scale a little smaller may be no narrower.
    while scale > 0.3 and any(cv2.getTextSize(text, font, scale, TEXT_THICKNESS)[0][0] > x1 - x0 - 8
                              for text, x0, x1, _ in texts):
        scale -= 0.05
    band = np.full((2 * height, width, 3), DARK, np.uint8)
    for text, x0, x1, color in texts:
        w = cv2.getTextSize(text, font, scale, TEXT_THICKNESS)[0][0]
        cv2.putText(band, text, ((x0 + x1 - w) // 2, (3 * height) // 2), font, scale, color, TEXT_THICKNESS,
                    cv2.LINE_AA)
    return band


def draw_text(gray: np.ndarray, recognition: Recognition, library: Library) -> np.ndarray:
    """The recognised sign's text check (pipeline/verify.py), else that of the first winner it
    turned down: above, the photo read at the library sign's template pixels through the final H
    (the patch the check correlates); below, the template; each strip outlined on both and its
    correlation between them, green when it reaches the result's `min_text_correlation`, red when
    not, UNSEEN and so labelled when it lies mostly outside the photo or glare washed it out; in
    red at the foot, the sides beyond which the plaque and its text go on. FigureError when there
    is no check to draw."""
    sign_id, H, check, what = _checked(recognition, library)
    sign = library[sign_id]
    template = text_template(library, sign.id)
    read = rectify_text(gray, sign, template, H, recognition.camera)
    minimum = text_threshold(sign, recognition.settings)  # the sign's own bar, or its kind's setting
    colors = _strip_colors(check, minimum)
    # black where the photo was not seen: the check leaves those pixels out
    photo = _text_panel(np.where(read.seen, _stretched(read.patch, template.rows, read.seen), 0).astype(np.uint8),
                        template, colors)
    library_sign = _text_panel(_stretched(template.image, template.rows, np.ones_like(read.seen)), template, colors)
    width, edges = photo.shape[1], [int(c) * TEXT_BLOCK_PX for c in template.columns]
    values = [("washed out" if i in check.washed else "unseen" if c is None else f"{c:.3f}", x0, x1, color)
              for i, (c, x0, x1, color) in enumerate(zip(check.strips, edges[:-1], edges[1:], colors))]
    head = _text_band(width, [(what, 0, width, WHITE)])
    judged = "the median strip passes" if check.kind == "picture" else "strips pass"
    foot = _text_band(width, [(f"library sign {sign.id}: {judged} at {minimum:g} or more", 0, width, WHITE)])
    bands = [head, photo, _text_band(width, values), library_sign, foot]
    if check.continued:
        sides = " and ".join(check.continued)
        bands.append(_text_band(width, [(f"the plaque and its text go on beyond its {sides} side", 0, width, RED)]))
    return np.vstack(bands)


def stage_figure(stage: str, image: np.ndarray, recognition: Recognition, library: Library,
                 sign_id: str | None = None) -> np.ndarray:
    """The figure for `stage` (one of STAGES) of `image`, the colour photo for PHOTO_STAGES, else
    the photo or its gray; FigureError when it cannot be drawn."""
    if stage in ("matches", "inliers"):
        img = draw_matches(image, recognition, library, sign_id, inliers_only=stage == "inliers")
    elif stage == "text":
        img = draw_text(image, recognition, library)
    else:
        draw = {"input": draw_input, "gray": draw_gray, "mask": draw_mask, "blob": draw_blob, "crop": draw_crop}
        img = draw[stage](image, recognition)
    return fit(img)


def draw_board(preview: np.ndarray, view: BoardView, board: tuple[int, int], camera: Camera | None,
               max_side: int) -> np.ndarray:
    """A calibration photo with the chessboard corners found in it, at most `max_side` px a side.

    preview: (h, w) uint8 gray copy of the photo (any size with the photo's aspect); `view` holds
    the corners in the full photo's px. With `camera`, the photo and its corners are undistorted
    by it, so the board's rows show straight.
    """
    img = _bgr(fit(preview, max_side))
    h, w = img.shape[:2]
    corners = None
    if view.found:
        # Pixel centres: full-res (x + 0.5) * scale - 0.5, as find_board scales its detections.
        scale = np.array([w / view.image_size[0], h / view.image_size[1]])
        corners = ((view.corners + 0.5) * scale - 0.5).astype(np.float32).reshape(-1, 1, 2)
    if camera is not None:
        cam, _ = camera.for_image(w, h)  # scaled to the figure; a rounding-level aspect change is harmless
        img = cv2.undistort(img, cam.K, cam.dist)
        if corners is not None:
            corners = cv2.undistortPoints(corners, cam.K, cam.dist, P=cam.K)
    if corners is None:
        _label(img, "board not found", (8, 8), RED)
    else:
        cv2.drawChessboardCorners(img, board, corners, True)
    return img


def jpeg(img: np.ndarray) -> bytes:
    # Calibration photos are photos: JPEG is a tenth of the PNG's size at no visible cost.
    return cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()


def png(img: np.ndarray) -> bytes:
    # Level 1: figures are made on demand while a person waits; size matters less than time.
    return cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].tobytes()
