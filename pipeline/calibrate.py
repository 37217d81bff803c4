"""Camera calibration from photos of a printed chessboard (Zhang's method, via OpenCV).

Conventions: a board is `(cols, rows)` *inner* corners (a board of 10 x 7 squares has 9 x 6);
image sizes are `(width, height)` px; corner arrays are (N, 2) float image px in OpenCV's
row-major order, N = cols * rows; board points are (N, 3) metres on the board plane z = 0.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import cv2
import numpy as np

from .camera import Camera, CameraError, principal_point_problem, size_change

MIN_VIEWS = 3
# More inner corners per side than any printable board has; the detector's cost grows with them.
MAX_BOARD_SIDE = 100
# Largest chessboard square (m): printed boards have squares of a few cm, wall-sized ones 20 cm;
# beyond 1 m the number was millimetres.
MAX_SQUARE_M = 1.0
# findChessboardCornersSB cost grows with the pixel count and it finds boards just as well at
# this size; the corners are then refined at full resolution.
MAX_DETECT_SIDE = 1600
# A view whose RMS error is below this is usable whatever the others score: sub-pixel corner
# detectors are good to ~0.1 px, so a relative rule alone would flag noise on a very good set.
OUTLIER_FLOOR_PX = 0.5
# Limits past which a calibration is reported as suspect (see `Calibration.warnings`).
MAX_GOOD_RMS_PX = 1.0
MAX_FOCAL_STD = 0.01  # relative standard deviation of fx, fy
# Zhang's method needs the board tilted: seen face-on in every view, the focal length trades
# off freely against the board's distance.
MIN_MAX_TILT_DEG = 15.0


class CalibrationError(ValueError):
    """Inputs that cannot give a calibration; the message says which and why."""


@dataclass(frozen=True, eq=False)
class BoardView:
    """The chessboard as seen in one image.

    corners: (cols * rows, 2) float64 image px, or None when the board was not found.
    image_size: (width, height) px of the image it was found in.
    """

    name: str
    image_size: tuple[int, int]
    corners: np.ndarray | None

    @property
    def found(self) -> bool:
        return self.corners is not None


@dataclass(frozen=True, eq=False)
class Calibration:
    """Intrinsics fitted to the views where the board was found, and how well each view fits.

    views: every view passed in, in input order (V of them).
    errors_px: (V,) RMS reprojection error of each view in px under `camera`; NaN where the board
        was not found. Views in `excluded` were left out of the fit and are scored by their own
        pose (solvePnP) under the fitted intrinsics.
    rvecs, tvecs: (V, 3) board-to-camera Rodrigues rotation (rad) and translation (metres); NaN
        where the board was not found.
    rms_px: RMS reprojection error over all corners of the views used in the fit, px.
    intrinsics_std: (fx, fy, cx, cy) standard deviations of the estimates, px.
    """

    camera: Camera
    rms_px: float
    views: tuple[BoardView, ...]
    errors_px: np.ndarray
    rvecs: np.ndarray
    tvecs: np.ndarray
    intrinsics_std: np.ndarray
    excluded: tuple[int, ...]
    board: tuple[int, int]
    square_m: float
    fix_k3: bool

    @property
    def not_found(self) -> tuple[int, ...]:
        """Indices of the views where the board was not found."""
        return tuple(i for i, v in enumerate(self.views) if not v.found)

    @property
    def used(self) -> tuple[int, ...]:
        """Indices of the views the intrinsics were fitted to."""
        return tuple(i for i, v in enumerate(self.views) if v.found and i not in self.excluded)

    @property
    def tilts_deg(self) -> np.ndarray:
        """(V,) angle between each board's normal and the optical axis, degrees; NaN where not found."""
        tilts = np.full(len(self.views), np.nan)
        for i in np.flatnonzero(np.isfinite(self.rvecs[:, 0])):
            tilts[i] = math.degrees(math.acos(min(1.0, abs(cv2.Rodrigues(self.rvecs[i])[0][2, 2]))))
        return tilts

    @property
    def warnings(self) -> list[str]:
        """Reasons to distrust this calibration, each with what to do about it."""
        out = []
        if self.rms_px > MAX_GOOD_RMS_PX:
            out.append(f"RMS {self.rms_px:.2f} px is above {MAX_GOOD_RMS_PX:g} px: check the board is flat and sharp "
                       "in every photo and its size (inner corners, square side) is right")
        focal_std = float(np.max(self.intrinsics_std[:2] / np.diag(self.camera.K)[:2]))
        if focal_std > MAX_FOCAL_STD:
            out.append(f"the focal length is uncertain by ±{focal_std:.1%}: add photos from more viewpoints")
        max_tilt = float(np.nanmax(self.tilts_deg[list(self.used)]))
        if max_tilt < MIN_MAX_TILT_DEG:
            out.append(f"the board faces the camera in every photo (largest tilt {max_tilt:.0f}°), so the focal "
                       "length is poorly determined: add photos with the board tilted 30-45°")
        return out

    @property
    def outlier_threshold_px(self) -> float:
        """Error above which a used view is an outlier, px (see `outlier_threshold`)."""
        return outlier_threshold(self.errors_px[list(self.used)])

    @property
    def outliers(self) -> tuple[int, ...]:
        """Indices of used views whose error is far above the rest (above `outlier_threshold_px`)."""
        limit = self.outlier_threshold_px
        return tuple(i for i in self.used if self.errors_px[i] > limit)

    def to_json(self) -> dict:
        """JSON-ready summary: the camera, RMS, standard deviations of fx, fy, cx, cy and the outlier
        threshold (px), warnings, and per view (in input order) whether the board was found, its RMS
        error (px), its tilt (degrees), and whether it is an outlier or was left out of the fit."""
        outliers, tilts = set(self.outliers), self.tilts_deg
        return {
            "board": list(self.board), "square_m": self.square_m, "rms_px": self.rms_px,
            "camera": self.camera.to_json(),
            "intrinsics_std": dict(zip(("fx", "fy", "cx", "cy"), self.intrinsics_std.tolist())),
            "outlier_threshold_px": self.outlier_threshold_px, "used": len(self.used), "warnings": self.warnings,
            "views": [{"name": v.name, "found": v.found, "error_px": _finite_or_none(self.errors_px[i]),
                       "tilt_deg": _finite_or_none(tilts[i]), "outlier": i in outliers, "excluded": i in self.excluded}
                      for i, v in enumerate(self.views)],
        }


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def parse_board(text: str) -> tuple[int, int]:
    """"9x6" -> (9, 6) inner corners; CalibrationError for anything else."""
    parts = text.lower().replace("×", "x").split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise CalibrationError(f"board must be COLSxROWS inner corners, e.g. 9x6; got {text!r}")
    return check_board((int(parts[0]), int(parts[1])))


def check_board(board: tuple[int, int]) -> tuple[int, int]:
    """`board` as (cols, rows) ints; CalibrationError unless each side has 3 to MAX_BOARD_SIDE inner corners."""
    cols, rows = board
    if cols < 3 or rows < 3:
        raise CalibrationError(f"board needs at least 3x3 inner corners; got {cols}x{rows} "
                               "(count the corners where four squares meet, not the squares)")
    if cols > MAX_BOARD_SIDE or rows > MAX_BOARD_SIDE:
        raise CalibrationError(f"board sides have at most {MAX_BOARD_SIDE} inner corners; got {cols}x{rows}")
    return int(cols), int(rows)


def check_square(square_m: float) -> float:
    """`square_m` as a float; CalibrationError unless it is a positive, finite number of metres
    up to MAX_SQUARE_M."""
    if not (isinstance(square_m, (int, float)) and math.isfinite(square_m) and square_m > 0):
        raise CalibrationError(f"square size must be a positive number of metres (e.g. 0.025 for 25 mm); "
                               f"got {square_m}")
    if square_m > MAX_SQUARE_M:
        raise CalibrationError(f"square size {square_m:g} m is no chessboard's: it is in metres (0.025 for 25 mm)")
    return float(square_m)


def board_points(board: tuple[int, int], square_m: float) -> np.ndarray:
    """(cols * rows, 3) float32 corner positions in metres on the board plane, in OpenCV's order."""
    cols, rows = board
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2)
    return np.column_stack([grid * square_m, np.zeros(len(grid))]).astype(np.float32)


def chessboard_image(board: tuple[int, int], square_px: int = 100, margin_px: int | None = None) -> np.ndarray:
    """A printable board with `board` inner corners: (H, W) uint8, white margin of one square by default.

    The top-left square is black; the margin gives the detector the quiet zone it needs.
    """
    cols, rows = check_board(board)
    margin = square_px if margin_px is None else margin_px
    squares = (np.indices((rows + 1, cols + 1)).sum(axis=0) % 2).astype(np.uint8) * 255
    image = np.kron(squares, np.ones((square_px, square_px), np.uint8))
    return cv2.copyMakeBorder(image, margin, margin, margin, margin, cv2.BORDER_CONSTANT, value=255)


def find_board(gray: np.ndarray, board: tuple[int, int], name: str = "") -> BoardView:
    """Sub-pixel inner corners of a chessboard with `board` = (cols, rows) inner corners.

    The corners may be numbered from either end of the board; for calibrating one camera that
    only changes the board pose of that view.
    gray: (H, W) uint8. The board is searched for with findChessboardCornersSB, on a copy shrunk
    to MAX_DETECT_SIDE px for large images, and its corners refined at full resolution by
    cornerSubPix (as accurate as SB's CALIB_CB_ACCURACY upsampling at a twentieth of the cost).
    """
    cols, rows = check_board(board)
    h, w = gray.shape[:2]
    scale = min(1.0, MAX_DETECT_SIDE / max(w, h))
    small = gray if scale == 1.0 else cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE
    found, corners = cv2.findChessboardCornersSB(small, (cols, rows), flags=flags)
    if not found:
        return BoardView(name, (w, h), None)
    return BoardView(name, (w, h), refine_corners(gray, (corners.reshape(-1, 2) + 0.5) / scale - 0.5))


def refine_corners(gray: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(N, 2) corners moved to the nearby saddle point, (N, 2) float64 px.

    The search window reaches a third of the way to the closest neighbouring corner (the 10th
    percentile spacing, for foreshortened boards): wide enough to average out blur and noise,
    never wide enough to take in a second corner.
    """
    spacing = np.percentile(np.linalg.norm(np.diff(corners, axis=0), axis=1), 10)
    half = int(np.clip(spacing / 3, 2, 25))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
    refined = cv2.cornerSubPix(gray, corners.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1), criteria)
    return refined.reshape(-1, 2).astype(np.float64)


def outlier_threshold(errors_px: np.ndarray) -> float:
    """Error above which a view is an outlier: max(2·median, median + 3·MAD, OUTLIER_FLOOR_PX), px."""
    errors_px = np.asarray(errors_px, dtype=np.float64)
    median = float(np.median(errors_px))
    mad = float(np.median(np.abs(errors_px - median)))
    return max(2 * median, median + 3 * mad, OUTLIER_FLOOR_PX)


ADD_PHOTOS = "add photos of the board"


def too_few_boards_advice(board: tuple[int, int], found: int, photos: int) -> str:
    """What to do when the `board` ((cols, rows) inner corners), found in `found` of `photos`, is
    found in too few to calibrate. Missing from most of them (found in fewer than half), its size is
    suspect: most often it was given in squares, and then it is found in none. Found in most, its
    size is right and photos are what is missing: a set whose photos were removed one by one was
    told to check the board size once one photo without the board was among the few left."""
    if 2 * found >= photos:
        return ADD_PHOTOS
    cols, rows = board
    return (f"check the board size: it counts inner corners (where four squares meet) across x down, not squares, "
            f"so {cols}x{rows} is a board of {cols + 1}x{rows + 1} squares; and the whole board, with its white "
            "border, must be in view")


# What photos of another size than the calibration's are (`size_change`), and what to do with them.
OTHER_SIZE_ADVICE = {
    "scaled": "the same frame at another resolution (resized, or another resolution setting): retake {them} at "
              "{width}x{height} or leave {them} out (the calibrated camera is scaled to photos of that shape when "
              "it is used)",
    "turned": "the frame turned on its side (portrait and landscape photos need separate calibrations): "
              "calibrate that orientation separately or leave {them} out",
    "reframed": "another aspect (cropped, or another camera mode): calibrate that size separately or leave {them} out",
}


def reference_size(views: tuple[BoardView, ...], found: list[int]) -> tuple[int, int]:
    """The size (width, height) px most of the `found` views share (the first listed of sizes tied):
    the size a calibration of them is for, so that the odd ones out are named rather than the rest."""
    width, height = Counter(tuple(views[i].image_size) for i in found).most_common(1)[0][0]
    return width, height


def other_sizes(views: tuple[BoardView, ...], found: list[int], size: tuple[int, int]) -> dict[int, str]:
    """The `found` views of another size than `size` (width, height) px, their `reference_size`, each
    with its size and theirs: {index: "640x480, the others 1280x960"} ("most 1280x960" when a third
    size is among them). Such views make `calibrate` refuse (`size_mismatch`); {} when all are `size`."""
    w, h = size
    odd = [i for i in found if tuple(views[i].image_size) != (w, h)]
    others = "the others" if len({tuple(views[i].image_size) for i in odd}) == 1 else "most"
    return {i: f"{views[i].image_size[0]}x{views[i].image_size[1]}, {others} {w}x{h}" for i in odd}


def size_mismatch(views: tuple[BoardView, ...], found: list[int], size: tuple[int, int]) -> str | None:
    """Why the `found` views cannot be calibrated together at `size` (width, height) px: which are
    which other size, how it differs and what to do; None when all are `size`.

    A calibration holds for one image size; said once as "portrait and landscape photos need separate
    calibrations" for every other size, it misled about a photo that was merely half the size.
    """
    by_size: dict[tuple[int, ...], list[str]] = {}
    for i in found:
        by_size.setdefault(tuple(views[i].image_size), []).append(views[i].name or str(i))
    alike = len(by_size.pop(size, []))
    if not by_size:
        return None
    others = []
    for (w, h), names in by_size.items():
        one = len(names) == 1
        advice = OTHER_SIZE_ADVICE[size_change(size, (w, h))].format(
            width=size[0], height=size[1], them="it" if one else "them")
        others.append(f"{', '.join(names)} {'is' if one else 'are'} {w}x{h} px, {advice}")
    return (f"the photos must all be one size, as a calibration holds for one: {alike} of the {len(found)} with the "
            f"board are {size[0]}x{size[1]} px, but {'; and '.join(others)}")


def calibrate(views: list[BoardView], board: tuple[int, int], square_m: float,
              image_size: tuple[int, int] | None = None, exclude: tuple[int, ...] = (),
              fix_k3: bool = True) -> Calibration:
    """Fit K and distortion (k1, k2, p1, p2, k3) to the views where the board was found.

    square_m: side of one printed square in metres (sets the scale of `tvecs` only).
    image_size: (width, height) px; taken from the views when None, and every found view must match.
    exclude: indices of views to leave out of the fit (e.g. outliers).
    fix_k3: keep k3 = 0, as ROS's calibrator does by default: with 15-20 handheld views k3 mostly
        fits noise and extrapolates wildly towards the image corners.
    """
    board = check_board(board)
    square_m = check_square(square_m)
    views = tuple(views)
    if not views:  # every photo unreadable: the board was not missed, and no hint on its size helps
        raise CalibrationError("no photo to calibrate from")
    found = [i for i, v in enumerate(views) if v.found]
    if not found:
        raise CalibrationError(f"the {board[0]}x{board[1]} board was not found in any of the {len(views)} image(s); "
                               f"{too_few_boards_advice(board, 0, len(views))}")
    width, height = image_size or reference_size(views, found)
    size = (width, height)

    mismatch = size_mismatch(views, found, size)
    if mismatch:
        raise CalibrationError(mismatch)
    n_corners = board[0] * board[1]
    wrong = [views[i].name or str(i) for i in found if views[i].corners.shape != (n_corners, 2)]
    if wrong:
        raise CalibrationError(f"a {board[0]}x{board[1]} board has {n_corners} corners; these views have a different "
                               f"number: {', '.join(wrong)}")
    fit = [i for i in found if i not in exclude]
    if len(fit) < MIN_VIEWS:
        # Boards found but left out (outliers) still show its size is right: more photos are missing.
        advice = too_few_boards_advice(board, len(found), len(views)) if len(found) < MIN_VIEWS else ADD_PHOTOS
        raise CalibrationError(f"the board was found in {len(fit)} usable image(s); calibration needs at least "
                               f"{MIN_VIEWS} (15-20 recommended, tilted and spread over the frame); {advice}")
    obj = board_points(board, square_m)
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    rms, K, dist, rvecs, tvecs, std_intr, _, per_view = cv2.calibrateCameraExtended(
        [obj] * len(fit), [views[i].corners.astype(np.float32) for i in fit], tuple(int(s) for s in size),
        None, None, flags=flags)
    try:
        camera = Camera(K, dist.ravel(), int(size[0]), int(size[1]), "calibrated")
        problem = principal_point_problem(camera)
    except CameraError as exc:
        problem = str(exc)
    if problem:  # a degenerate fit, e.g. views that barely tilt the board
        raise CalibrationError(f"the fit gave no usable camera ({problem}); add views with the board tilted "
                               "and spread over the frame")

    n = len(views)
    errors, rv, tv = np.full(n, np.nan), np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    errors[fit] = per_view.ravel()
    rv[fit], tv[fit] = np.hstack(rvecs).T, np.hstack(tvecs).T
    for i in set(found) - set(fit):
        rv[i], tv[i], errors[i] = view_pose(camera, views[i].corners, obj)
    return Calibration(camera, float(rms), views, errors, rv, tv, std_intr.ravel()[:4].copy(),
                       tuple(sorted(set(exclude) & set(found))), board, float(square_m), fix_k3)


def view_pose(camera: Camera, corners: np.ndarray, obj: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Board pose (rvec (3,), tvec (3,) metres) of one view under fixed intrinsics, and its RMS error px."""
    corners = corners.astype(np.float64)
    _, rvec, tvec = cv2.solvePnP(obj, corners, camera.K, camera.dist, flags=cv2.SOLVEPNP_IPPE)
    rvec, tvec = cv2.solvePnPRefineLM(obj, corners, camera.K, camera.dist, rvec, tvec)
    projected, _ = cv2.projectPoints(obj, rvec, tvec, camera.K, camera.dist)
    rms = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - corners) ** 2, axis=1))))
    return rvec.ravel(), tvec.ravel(), rms


def drop_outliers(calibration: Calibration) -> Calibration:
    """Recalibrate without `calibration.outliers` (one round; the result may name new ones)."""
    c = calibration
    if not c.outliers:
        return c
    return calibrate(list(c.views), c.board, c.square_m, (c.camera.width, c.camera.height),
                     exclude=tuple(sorted(set(c.excluded) | set(c.outliers))), fix_k3=c.fix_k3)


def format_report(calibration: Calibration) -> str:
    """Human-readable summary: a per-view table, the intrinsics with their standard deviations, outliers."""
    c = calibration
    outliers = set(c.outliers)
    lines = [f"{'image':<32} {'board':<10} {'error px':>8}"]
    for i, view in enumerate(c.views):
        status = "found" if view.found else "not found"
        error = f"{c.errors_px[i]:8.3f}" if view.found else f"{'-':>8}"
        note = "  outlier" if i in outliers else "  dropped as an outlier, not fitted" if i in c.excluded else ""
        lines.append(f"{view.name:<32} {status:<10} {error}{note}")
    K, d, (sfx, sfy, scx, scy) = c.camera.K, c.camera.dist, c.intrinsics_std
    lines += [
        "",
        f"overall RMS {c.rms_px:.3f} px from {len(c.used)} of {len(c.views)} image(s) "
        f"({c.board[0]}x{c.board[1]} inner corners, {c.square_m * 1000:g} mm squares)",
        f"fx {K[0, 0]:.2f} ± {sfx:.2f}  fy {K[1, 1]:.2f} ± {sfy:.2f}  cx {K[0, 2]:.2f} ± {scx:.2f}  "
        f"cy {K[1, 2]:.2f} ± {scy:.2f} px  at {c.camera.width}x{c.camera.height}",
        "distortion k1 k2 p1 p2 k3: " + " ".join(f"{v:.5g}" for v in d),
    ]
    if outliers:
        names = ", ".join(f"{c.views[i].name} ({c.errors_px[i]:.2f} px)" for i in sorted(outliers))
        lines.append(f"outliers (error > {c.outlier_threshold_px:.2f} px): {names}; {outlier_advice(c)}")
    lines += [f"warning: {w}" for w in c.warnings]
    return "\n".join(lines)


def outlier_advice(calibration: Calibration, drop: str = "signpose calibrate --drop-outliers",
                   leave_out: str = "leave {them} out of the photos") -> str:
    """What to do about `calibration.outliers`, in the words of the tool at hand: `drop`, what drops
    outliers; `leave_out`, how to leave photos out ({them}: "it" or "them"). The CLI's by default;
    the page's buttons are another's (app/calibration.py), sent to it, which shows them as they come.

    Once outliers have been dropped (`drop_outliers`), the refit may flag others: they are not
    dropped in turn, since round after round would whittle down any set, so the advice is no longer
    to drop them (it sent people round in a loop)."""
    if not calibration.excluded:
        return f"retake or drop them ({drop})"
    they, them, are = ("it", "it", "is") if len(calibration.outliers) == 1 else ("they", "them", "are")
    return (f"{they} stood out only in the refit without the outliers dropped, and {are} kept: outliers are "
            "dropped once, as each refit shifts the errors and round after round would whittle the set down; "
            f"retake {them}, or {leave_out.format(them=them)} if the board is blurred or bent in {them}")
