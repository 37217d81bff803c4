"""Photos of a printed chessboard rendered under known intrinsics and lens distortion, for the
calibration tests (pipeline and API).

Conventions as in pipeline/calibrate.py: sizes are (width, height) px, board poses are
board-to-camera (Rodrigues rvec in rad, tvec in metres), board points metres on z = 0.
"""

from __future__ import annotations

import cv2
import numpy as np

from signpose.pipeline.calibrate import board_points, chessboard_image

SIZE = (640, 480)
K_TRUE = np.array([[520.0, 0, 318.0], [0, 515.0, 243.0], [0, 0, 1]])
DIST_TRUE = np.array([-0.12, 0.05, 0.001, -0.0005, 0.0])
BOARD = (9, 6)
SQUARE_M = 0.03
TEXTURE_SQUARE_PX = 40
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)


def board_poses(n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """n (rvec (3,), tvec (3,) m) board poses, 0.35-0.55 m away, tilted up to ~30° and spread over the frame."""
    rng = np.random.default_rng(seed)
    centre = np.array([(BOARD[0] - 1) / 2, (BOARD[1] - 1) / 2, 0]) * SQUARE_M
    poses = []
    for _ in range(n):
        rvec = np.concatenate([rng.uniform(-0.5, 0.5, 2), rng.uniform(-0.3, 0.3, 1)])
        offset = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.06, 0.06), rng.uniform(0.35, 0.55)])
        poses.append((rvec, offset - cv2.Rodrigues(rvec)[0] @ centre))
    return poses


def pixel_rays(K: np.ndarray, dist: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) homogeneous normalised ray of every pixel centre of the distorted image."""
    w, h = size
    pixels = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1)
    undistort = getattr(cv2, "undistortPointsIter", cv2.undistortPoints)  # 4.x names the overload with criteria
    xy = undistort(pixels.reshape(-1, 1, 2), K, dist, R=None, P=None, criteria=_UNDISTORT_CRITERIA)
    return np.concatenate([xy.reshape(h, w, 2), np.ones((h, w, 1))], axis=-1)


def render_board(rays: np.ndarray, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """(H, W) uint8 image of the printed board at pose (rvec, tvec), with the lens distortion baked into `rays`."""
    R = cv2.Rodrigues(rvec)[0]
    plane_to_rays = np.column_stack([R[:, 0], R[:, 1], tvec])  # board (X, Y, 1) metres -> ray
    p = rays @ np.linalg.inv(plane_to_rays).T
    xy = p[..., :2] / p[..., 2:]
    # Texture pixel centres are integers, so inner corner (0, 0) sits half a pixel before the edge of square 1.
    texture_px = xy * (TEXTURE_SQUARE_PX / SQUARE_M) + 2 * TEXTURE_SQUARE_PX - 0.5
    texture = chessboard_image(BOARD, TEXTURE_SQUARE_PX)
    image = cv2.remap(texture, texture_px[..., 0].astype(np.float32), texture_px[..., 1].astype(np.float32),
                      cv2.INTER_LINEAR, borderValue=128)
    return cv2.GaussianBlur(image, (0, 0), 0.7)  # a lens is never perfectly sharp


def render_boards(n: int, seed: int = 0) -> tuple[list[np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
    """n board photos ((H, W) uint8, through K_TRUE and DIST_TRUE) and their true poses."""
    rays = pixel_rays(K_TRUE, DIST_TRUE, SIZE)
    poses = board_poses(n, seed)
    return [render_board(rays, r, t) for r, t in poses], poses


def projected_corners(rvec, tvec, K=K_TRUE, dist=DIST_TRUE) -> np.ndarray:
    """(N, 2) px where the board's inner corners land at pose (rvec, tvec)."""
    img, _ = cv2.projectPoints(board_points(BOARD, SQUARE_M), rvec, tvec, K, dist)
    return img.reshape(-1, 2)


def shaky_board(image: np.ndarray, seed: int = 5) -> np.ndarray:
    """A board photo ((H, W) uint8) stretched by 3 % in x, with noise: the board is found, but its
    corners fit no camera the other photos agree on (an outlier)."""
    rng = np.random.default_rng(seed)
    warped = cv2.resize(image, None, fx=1.03, fy=1.0)[:, :image.shape[1]]
    return np.clip(warped + rng.normal(0, 2, warped.shape), 0, 255).astype(np.uint8)
