"""Camera 6-DOF pose from a sign's homography or its inlier matches.

Frames: the sign frame has its origin at the sign centre, x right, y down the sign, z into the
wall, metres. The camera frame is OpenCV's: x right, y down, z forward. A pose (R, t) maps sign
points into the camera, X_cam = R·X_sign + t, so the camera sits at -Rᵀt in the sign frame.

Distortion: every error (RMSE, IPPE solution errors, covariance) is measured in the original,
distorted image against the measured pixels, projecting with the camera's distortion. The
closed-form starts (the paper's H decomposition, IPPE) need an ideal pinhole image, so they run
on points undistorted here to 1e-10 px (OpenCV's default `undistortPoints` stops after five
iterations, which is pixels off under strong distortion). Levenberg-Marquardt refinement then
works on the measured pixels with the distortion model, where the noise actually is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .camera import Camera
from .homography import dlt_homography, normalize_scale
from .library import LibrarySign
from .settings import POSE_METHODS

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
# Sign points whose spread across their main direction is below this fraction of the spread
# along it are collinear: they determine no homography and no pose.
_MIN_SPREAD_RATIO = 1e-6
# JᵀJ with a condition number past this has no usable inverse: the pose is unconstrained along some axis.
_MAX_COVARIANCE_CONDITION = 1e12
# 1σ in px, in x and in y, of each sign corner from errors a fit's residuals cannot show because a
# whole side or region shares them (an edge's bias under blur, a homography's bias from features
# on the text), by how the corners were measured: the plaque's edges, feature inliers, or dense
# alignment (ECC; the plaque's blob too, when ECC failed). Residuals alone gave 1σ of 0.3° to far signs 6-16° off.
# Rotation errors within twice the σ reported with these, on the 640x480 and 1280x960 benchmark
# scenes, the sample datasets and 50 renders 2-12 m away: edges 98 % of 374 poses (0.05 px: 94 %),
# features 94 % of 123 (the paper preset), ECC 9 of 10.
CORNER_SIGMA_PX = {"outline": 0.1, "features": 1.0, "dense": 2.0}
# IPPE's other solution, refined, is told apart from the pose when it moves the corners by more than this many corner σ.
AMBIGUITY_CORNER_SIGMAS = 3.0
# Refined solutions closer than this (degrees) are one minimum: merged ones differed by under 0.01°, distinct ones by 5° or more.
AMBIGUITY_MIN_DEG = 1.0


class PoseError(ValueError):
    """No pose can be computed from the given points or homography; the message says why."""


@dataclass(frozen=True, eq=False)
class Pose:
    """A camera pose relative to a sign.

    `R` (3, 3) and `t` (3,) metres map sign-frame points into the camera frame.
    `reprojection_rmse_px`: root mean squared distance, in image px, between the measured points
    and the sign points projected with this pose and the camera's distortion. The measured
    points are the feature inliers, or for a pose from the plaque's outline its edge points
    (distance across their side); after ECC alone they are a grid through the aligned
    homography, which the pose fits almost exactly.
    `solution_errors`: (best, second) RMSE px of IPPE's two planar solutions, each refined by
    Levenberg-Marquardt, whichever method produced the pose (None only for poses built
    elsewhere). `ambiguous`: the other solution is a different pose the measurements cannot rule
    out (see `estimate_pose`).
    `covariance`: (6, 6) over [rotation vector (rad, 3), translation (m, 3)], the fit's own plus
    what `CORNER_SIGMA_PX` adds (`corner_covariance`), or None.
    """

    R: np.ndarray
    t: np.ndarray
    method: str
    reprojection_rmse_px: float
    ambiguous: bool
    solution_errors: tuple[float, float] | None
    covariance: np.ndarray | None

    @property
    def camera_position(self) -> np.ndarray:
        """(3,) camera centre in the sign frame, metres (`camera_position`)."""
        return camera_position(self.R, self.t)

    @property
    def quaternion_wxyz(self) -> np.ndarray:
        """(4,) unit quaternion (w, x, y, z), w >= 0, of R (sign frame -> camera frame)."""
        return quaternion_wxyz(self.R)

    @property
    def euler_deg(self) -> dict[str, float]:
        """R as yaw, pitch, roll in degrees with R = Rz(yaw)·Ry(pitch)·Rx(roll) (see `euler_zyx_deg`)."""
        yaw, pitch, roll = euler_zyx_deg(self.R)
        return {"yaw": yaw, "pitch": pitch, "roll": roll}

    def to_json(self) -> dict:
        """Plain-Python, JSON-safe summary; non-finite numbers become None."""
        return {
            "R": _json_numbers(self.R),
            "t": _json_numbers(self.t),
            "camera_position": _json_numbers(self.camera_position),
            "quaternion_wxyz": _json_numbers(self.quaternion_wxyz),
            "euler_deg": {k: _json_numbers(v) for k, v in self.euler_deg.items()},
            "reprojection_rmse_px": _json_numbers(self.reprojection_rmse_px),
            "ambiguous": bool(self.ambiguous),
            "covariance": None if self.covariance is None else _json_numbers(self.covariance),
        }


def _json_numbers(x):
    """A number or (nested) array as plain floats / nested lists, with NaN and ±inf as None."""
    if np.ndim(x) == 0:
        value = float(x)
        return value if math.isfinite(value) else None
    return [_json_numbers(v) for v in x]


def camera_position(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(3,) m: the centre of the camera of pose (R (3, 3), t (3,) m), X_cam = R·X_sign + t, in the sign frame: -Rᵀt."""
    return -np.asarray(R, dtype=np.float64).T @ np.asarray(t, dtype=np.float64).reshape(3)


def rotation_error_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Geodesic angle in degrees between two (3, 3) rotations: the angle of R_aᵀ·R_b.

    Uses atan2(sin, cos) of the relative rotation, accurate at small and large angles alike
    (arccos of the trace loses half the digits near zero).
    """
    D = np.asarray(R_a, dtype=np.float64).T @ np.asarray(R_b, dtype=np.float64)
    sin = 0.5 * np.linalg.norm([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]])
    cos = 0.5 * (np.trace(D) - 1.0)
    return math.degrees(math.atan2(sin, cos))


def quaternion_wxyz(R: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion (w, x, y, z) of the (3, 3) rotation R, sign chosen so w >= 0."""
    rvec = cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].ravel()
    angle = float(np.linalg.norm(rvec))
    if angle == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * rvec / angle])


def rotation_from_quaternion_wxyz(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of the unit quaternion q (4,) = (w, x, y, z); the inverse of `quaternion_wxyz`."""
    w, x, y, z = (float(v) for v in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def rotation_from_euler_zyx_deg(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """(3, 3) rotation Rz(yaw)·Ry(pitch)·Rx(roll), angles in degrees; the inverse of `euler_zyx_deg`."""
    (cy, sy), (cp, sp), (cr, sr) = ((math.cos(a), math.sin(a)) for a in map(math.radians, (yaw, pitch, roll)))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def euler_zyx_deg(R: np.ndarray) -> tuple[float, float, float]:
    """(yaw, pitch, roll) in degrees with R = Rz(yaw)·Ry(pitch)·Rx(roll); pitch in [-90, 90].

    At gimbal lock (pitch = ±90°) only yaw ∓ roll is defined; roll is reported as 0.
    """
    R = np.asarray(R, dtype=np.float64)
    cos_pitch = math.hypot(R[0, 0], R[1, 0])
    pitch = math.atan2(-R[2, 0], cos_pitch)
    if cos_pitch < 1e-9:
        yaw, roll = math.atan2(-R[0, 1], R[1, 1]), 0.0
    else:
        yaw, roll = math.atan2(R[1, 0], R[0, 0]), math.atan2(R[2, 1], R[2, 2])
    return math.degrees(yaw), math.degrees(pitch), math.degrees(roll)


def _with_cross(c1: np.ndarray, c2: np.ndarray) -> np.ndarray:
    """(3, 3) matrix with columns c1, c2 (3,) and c1 × c2: np.cross written out, since on one
    pair of 3-vectors its axis handling costs several times the arithmetic."""
    (a0, a1, a2), (b0, b1, b2) = c1.tolist(), c2.tolist()
    return np.array([[a0, b0, a1 * b2 - a2 * b1], [a1, b1, a2 * b0 - a0 * b2], [a2, b2, a0 * b1 - a1 * b0]])


def _nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation (det +1) closest to (3, 3) M in Frobenius norm (polar decomposition by SVD)."""
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def pose_from_homography(H_metric: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Decompose a sign-plane homography into (R (3, 3), t (3,) metres), as in the paper / AprilTag.

    H_metric (3, 3) maps sign-plane metres (X, Y, 1) to image px; K (3, 3) is the camera matrix.
    K⁻¹H = s·[r1 r2 t]: |s| is the geometric mean of the first two column norms (splitting the
    disagreement between them evenly), its sign puts the sign in front of the camera (t_z > 0),
    and [r1 r2 r1×r2] is projected onto the nearest rotation.
    """
    M = np.linalg.solve(np.asarray(K, dtype=np.float64), np.asarray(H_metric, dtype=np.float64))
    scale = math.sqrt(np.linalg.norm(M[:, 0]) * np.linalg.norm(M[:, 1]))
    if not (math.isfinite(scale) and scale > 0):
        raise PoseError("homography is degenerate: it collapses the sign plane")
    M = M / math.copysign(scale, M[2, 2])
    r1, r2, t = M[:, 0], M[:, 1], M[:, 2]
    return _nearest_rotation(_with_cross(r1, r2)), t


def homography_from_pose(R: np.ndarray, t: np.ndarray, K: np.ndarray, sign: LibrarySign) -> np.ndarray:
    """(3, 3) homography library px -> image px (no distortion) of `sign` seen with pose (R, t).

    H = K·[r1 r2 t]·sign.pixel_to_metric, scaled to H[2, 2] = 1.
    """
    R = np.asarray(R, dtype=np.float64)
    P = np.column_stack([R[:, 0], R[:, 1], np.asarray(t, dtype=np.float64).ravel()])
    return normalize_scale(np.asarray(K, dtype=np.float64) @ P @ sign.pixel_to_metric)


def undistort_pixels(pts: np.ndarray, camera: Camera) -> np.ndarray:
    """(N, 2) measured image px -> (N, 2) px of an ideal pinhole camera with the same K.

    Iterates to 1e-10 px (see the module docstring); returns the points unchanged without distortion.
    """
    pts = np.ascontiguousarray(pts, dtype=np.float64).reshape(-1, 1, 2)
    if not camera.has_distortion:
        return pts.reshape(-1, 2)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x names the overload taking criteria
        out = cv2.undistortPointsIter(pts, camera.K, camera.dist, None, camera.K, _UNDISTORT_CRITERIA)
    else:
        out = cv2.undistortPoints(pts, camera.K, camera.dist, None, None, camera.K, _UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)


def distort_pixels(pts: np.ndarray, camera: Camera) -> np.ndarray:
    """(N, 2) px of an ideal pinhole camera with the same K -> (N, 2) image px as the camera
    measures them, with its distortion: the inverse of `undistort_pixels`."""
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    if not camera.has_distortion:
        return pts
    rays = np.column_stack([pts, np.ones(len(pts))]) @ np.linalg.inv(camera.K).T
    zero = np.zeros(3)
    return cv2.projectPoints(rays, zero, zero, camera.K, camera.dist)[0].reshape(-1, 2)


def ideal_patch(gray: np.ndarray, box: tuple[int, int, int, int], camera: Camera) -> np.ndarray:
    """The (y1 - y0, x1 - x0) uint8 patch over `box` (x0, y0, x1, y1) of the image an ideal
    pinhole camera with `camera`'s K would take: each px sampled from (H, W) uint8 `gray` where
    the lens puts it (`distort_pixels`), bilinearly; replicated beyond the frame."""
    x0, y0, x1, y1 = box
    u, v = np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64))
    seen = distort_pixels(np.column_stack([u.ravel(), v.ravel()]), camera).astype(np.float32)
    shape = (y1 - y0, x1 - x0)
    return cv2.remap(gray, seen[:, 0].reshape(shape), seen[:, 1].reshape(shape), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def _project(R: np.ndarray, t: np.ndarray, obj: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Project (N, 3) sign points with pose (R, t) and distortion: (N, 2) px and the (2N, 6)
    Jacobian of the stacked (u, v) per point with respect to [rotation vector, t]."""
    rvec = cv2.Rodrigues(R)[0]
    img, jac = cv2.projectPoints(obj, rvec, np.asarray(t, dtype=np.float64).reshape(3, 1), camera.K, camera.dist)
    return img.reshape(-1, 2), jac[:, :6]


def _rmse(residuals: np.ndarray) -> float:
    """Root mean squared length of (N, 2) residual vectors."""
    return float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))


def _reprojection_rmse(R: np.ndarray, t: np.ndarray, obj: np.ndarray, measured_px: np.ndarray, camera: Camera) -> float:
    """`_rmse` of (N, 3) sign points projected with (R, t) against their (N, 2) measured px."""
    return _rmse(_project(R, t, obj, camera)[0] - measured_px)


def _covariance(residuals: np.ndarray, jacobian: np.ndarray) -> np.ndarray | None:
    """(6, 6) covariance σ²(JᵀJ)⁻¹ with σ² = SSE / (2N - 6), from (N, 2) residuals px and the
    (2N, 6) Jacobian; None when there are no degrees of freedom left or JᵀJ is singular."""
    dof = residuals.size - 6
    if dof <= 0:
        return None
    return _scaled_inverse(jacobian.T @ jacobian, float(np.sum(residuals**2)) / dof)


def _scaled_inverse(JtJ: np.ndarray, sigma_sq: float) -> np.ndarray | None:
    """σ²(JᵀJ)⁻¹, or None when JᵀJ (6, 6) is singular."""
    if np.linalg.cond(JtJ) > _MAX_COVARIANCE_CONDITION:
        return None
    return sigma_sq * np.linalg.inv(JtJ)


def corner_covariance(R: np.ndarray, t: np.ndarray, sign: LibrarySign, camera: Camera,
                      sigma_px: float) -> np.ndarray | None:
    """(6, 6) covariance over [rotation vector (rad), translation (m)] of a pose (R, t) whose sign
    corners are each off by `sigma_px` in x and in y independently: σ²(JᵀJ)⁻¹ with J the (8, 6)
    Jacobian of the four projected corners. None when JᵀJ is singular."""
    _, jacobian = _project(R, t, sign.to_metric(sign.corners_px), camera)
    return _scaled_inverse(jacobian.T @ jacobian, sigma_px**2)


def with_corner_floor(covariance: np.ndarray | None, R: np.ndarray, t: np.ndarray, sign: LibrarySign,
                      camera: Camera, sigma_px: float) -> np.ndarray | None:
    """A fit's `covariance` (6, 6) plus `corner_covariance`: the errors its residuals show and those
    they cannot, which are independent. None stays None (nothing measured)."""
    if covariance is None or sigma_px == 0:
        return covariance
    floor = corner_covariance(R, t, sign, camera, sigma_px)
    return covariance if floor is None else covariance + floor


def _in_front(R: np.ndarray, t: np.ndarray, obj: np.ndarray) -> bool:
    """All (N, 3) sign points have positive depth in the camera."""
    return bool(np.all(obj @ R[2] + t[2] > 0))


def _comparable(best: float, second: float, ratio: float) -> bool:
    """best / second > ratio, with equal errors (both zero included) counting as comparable."""
    return best == second or best > ratio * second


def _ambiguous(best: tuple[np.ndarray, np.ndarray], other: tuple[np.ndarray, np.ndarray], obj: np.ndarray,
               solution_errors: tuple[float, float], ratio: float, sign: LibrarySign, camera: Camera,
               corner_sigma_px: float) -> bool:
    """Whether `other`, IPPE's second planar solution refined, is a second pose the measurements
    cannot rule out: it puts the (N, 3) sign points `obj` in front of the camera too; it is another
    minimum, at least AMBIGUITY_MIN_DEG from `best` (near frontal views both solutions refine to
    one); and it explains the points nearly as well (`_comparable` solution errors) or moves the
    sign's corners by less than AMBIGUITY_CORNER_SIGMAS × `corner_sigma_px` (RMS), so that errors a
    side shares could be the whole difference (small far signs, whose points' residuals tell the
    two apart by hundredths of a pixel)."""
    if not (_in_front(*best, obj) and _in_front(*other, obj)):
        return False
    if rotation_error_deg(best[0], other[0]) < AMBIGUITY_MIN_DEG:
        return False
    corners = sign.to_metric(sign.corners_px)
    moved = _rmse(_project(*best, corners, camera)[0] - _project(*other, corners, camera)[0])
    return _comparable(*solution_errors, ratio) or moved < AMBIGUITY_CORNER_SIGMAS * corner_sigma_px


def _check_spread(obj: np.ndarray) -> None:
    """Raise PoseError unless the (N, 3) z = 0 sign points span the plane (not all on one line)."""
    spread = np.linalg.svd(obj[:, :2] - obj[:, :2].mean(axis=0), compute_uv=False)
    if not spread[-1] > _MIN_SPREAD_RATIO * spread[0]:
        raise PoseError("the inlier points lie on a line: they do not determine a pose")


def _rotation_onto_ray(v: np.ndarray) -> np.ndarray:
    """(3, 3) rotation turning the optical axis onto the ray through normalised image point v (2,)."""
    ray = np.append(v, 1.0) / math.hypot(np.linalg.norm(v), 1.0)
    axis = np.array([-ray[1], ray[0], 0.0])  # optical axis × ray
    sin = float(np.linalg.norm(axis))
    if sin == 0.0:
        return np.eye(3)
    return cv2.Rodrigues(axis / sin * math.atan2(sin, ray[2]))[0]


def _ippe_rotations(J: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IPPE's two plane rotations (Collins & Bartoli 2014) from the Jacobian J (2, 2) of the
    plane -> normalised-image homography at the plane origin, which it maps to v (2,).

    The rotation's third-row entries b = ±√(1 - (σ2/σ1)²)·(A's second right singular vector) come
    from the SVD of A = σ1·R̃ and are never NaN; the textbook √(1 - |R̃ column|²) goes negative by
    rounding near fronto-parallel views.
    """
    Rv = _rotation_onto_ray(v)
    B = np.hstack([np.eye(2), -v[:, None]]) @ Rv[:, :2]
    A = np.linalg.solve(B, J)
    _, sigma, Vt = np.linalg.svd(A)
    R22 = A / sigma[0]
    b = math.sqrt(max(0.0, 1.0 - (sigma[1] / sigma[0]) ** 2)) * Vt[1]
    c1, c2 = np.append(R22[:, 0], b[0]), np.append(R22[:, 1], b[1])
    flip = np.array([1.0, 1.0, -1.0])
    return Rv @ _with_cross(c1, c2), Rv @ _with_cross(c1 * flip, c2 * flip)


def _translation_given_rotation(R: np.ndarray, plane: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """(3,) t minimising the algebraic error of (N, 2) plane points (m, z = 0) seen along (N, 2)
    normalised image rays under rotation R: (R p + t) × (ray, 1) = 0, two rows per point."""
    q = plane @ R[:, :2].T
    n = len(plane)
    A = np.zeros((2 * n, 3))
    A[0::2, 0] = A[1::2, 1] = 1.0
    A[0::2, 2], A[1::2, 2] = -rays[:, 0], -rays[:, 1]
    rhs = np.empty(2 * n)
    rhs[0::2] = rays[:, 0] * q[:, 2] - q[:, 0]
    rhs[1::2] = rays[:, 1] * q[:, 2] - q[:, 1]
    return np.linalg.lstsq(A, rhs, rcond=None)[0]


def _ippe_solutions(obj: np.ndarray, ideal_px: np.ndarray, K: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """IPPE's two planar poses [(R, t), (R, t)] for (N >= 4, 3) z = 0 sign points seen at (N, 2) ideal px.

    The same decomposition as `cv2.solvePnPGeneric(..., SOLVEPNP_IPPE)`, done here because
    OpenCV's returns NaN for fronto-parallel views of exact correspondences, and a wrong rotation
    when the rotation is a half-turn (a camera rolled exactly 180°): both common in synthetic scenes.
    """
    centroid = obj.mean(axis=0)
    plane = obj[:, :2] - centroid[:2]
    rays = (np.column_stack([ideal_px, np.ones(len(ideal_px))]) @ np.linalg.inv(K).T)[:, :2]
    H = dlt_homography(plane, rays)  # H[2, 2] = 1: the centroid maps to (v, 1)
    v = H[:2, 2]
    J = H[:2, :2] - np.outer(v, H[2, :2])
    solutions = []
    for R in _ippe_rotations(J, v):
        t_centred = _translation_given_rotation(R, plane, rays)
        solutions.append((R, t_centred - R @ centroid))
    return solutions


def _refine_lm(R: np.ndarray, t: np.ndarray, obj: np.ndarray, measured_px: np.ndarray,
               camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on the distorted reprojection error, starting from (R, t)."""
    rvec, tvec = cv2.solvePnPRefineLM(obj, measured_px, camera.K, camera.dist, cv2.Rodrigues(R)[0],
                                      t.reshape(3, 1).copy())
    return cv2.Rodrigues(rvec)[0], tvec.ravel()


def _paper_pose(H: np.ndarray, src_px: np.ndarray, ideal_px: np.ndarray, sign: LibrarySign,
                camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Decompose the sign's homography; under distortion H is refitted on the undistorted points
    first, since the given H was fitted to distorted pixels and is no plane-to-pinhole map."""
    H_ideal = dlt_homography(src_px, ideal_px) if camera.has_distortion else H
    return pose_from_homography(H_ideal @ np.linalg.inv(sign.pixel_to_metric), camera.K)


def _correspondences(H: np.ndarray, src_px: np.ndarray, dst_px: np.ndarray,
                     sign: LibrarySign) -> tuple[np.ndarray, np.ndarray, bool]:
    """(src (N, 2), dst (N, 2), measured): the inliers, or with fewer than 4 of them the sign's
    corners mapped through H (`measured` False: residuals then say nothing about the noise)."""
    src_px = np.ascontiguousarray(src_px, dtype=np.float64).reshape(-1, 2)
    dst_px = np.ascontiguousarray(dst_px, dtype=np.float64).reshape(-1, 2)
    if len(src_px) != len(dst_px):
        raise ValueError(f"src_px and dst_px must have the same length; got {len(src_px)} and {len(dst_px)}")
    if len(src_px) >= 4:
        return src_px, dst_px, True
    corners = sign.corners_px
    return corners, cv2.perspectiveTransform(corners.reshape(-1, 1, 2), H).reshape(-1, 2), False


def estimate_pose(H: np.ndarray, src_px: np.ndarray, dst_px: np.ndarray, sign: LibrarySign, camera: Camera,
                  method: str = "ippe_lm", ambiguity_ratio: float = 0.8,
                  corner_sigma_px: float = 0.0, with_covariance: bool = True) -> Pose:
    """Camera pose relative to `sign` from its homography and inlier matches.

    H (3, 3): library px -> image px. src_px (N, 2): library px of the inliers; dst_px (N, 2):
    their measured (distorted) image px. With fewer than 4 inliers the sign's corners mapped
    through H stand in for them, and the covariance is None.

    method: "paper" decomposes H (`pose_from_homography`); "ippe" takes the better of IPPE's two
    planar solutions as they are; "ippe_lm" refines both by Levenberg-Marquardt and takes the
    better refined one. Both are refined for every method: the pose is `ambiguous` when the other refined
    one is a different pose the points cannot rule out (`_ambiguous`: best / second RMSE >
    `ambiguity_ratio`, or corners within the noise; typical for small, near-frontal signs).
    The covariance linearises the reprojection at the returned pose (see `_covariance`) and adds
    errors of `corner_sigma_px` at the corners, which the residuals cannot show (`with_corner_floor`;
    0: the fit's own alone; `recognize` passes CORNER_SIGMA_PX by how the points were measured);
    for "paper", whose pose does not minimise reprojection error, it is an approximation.
    `with_covariance` False leaves it None, for a caller that measures it from other points
    (`recognize`, from a refined outline's edge points, as the grid fitted then is exact by construction).

    Raises PoseError when the points or H admit no pose.
    """
    if method not in POSE_METHODS:
        raise ValueError(f"unknown pose method {method!r}; choose from {', '.join(POSE_METHODS)}")
    src_px, dst_px, measured = _correspondences(H, src_px, dst_px, sign)
    obj = sign.to_metric(src_px)
    ideal_px = undistort_pixels(dst_px, camera)

    _check_spread(obj)
    # Each solution refined to its own minimum: near frontal views IPPE's two lie a few degrees
    # either side of the one minimum both refine to, fitting equally badly (0.8 px on an exact grid).
    solutions = _ippe_solutions(obj, ideal_px, camera.K)
    refined = [_refine_lm(R_s, t_s, obj, dst_px, camera) for R_s, t_s in solutions]
    errors = [_reprojection_rmse(R_s, t_s, obj, dst_px, camera) for R_s, t_s in refined]
    order = np.argsort(errors)
    best, other = refined[order[0]], refined[order[1]]
    solution_errors = (errors[order[0]], errors[order[1]])

    if method == "paper":
        R, t = _paper_pose(H, src_px, ideal_px, sign, camera)
    elif method == "ippe":
        R, t = min(solutions, key=lambda s: _reprojection_rmse(s[0], s[1], obj, dst_px, camera))

    else:
        R, t = best

    projected, jacobian = _project(R, t, obj, camera)
    residuals = projected - dst_px
    return Pose(
        R=R, t=t, method=method, reprojection_rmse_px=_rmse(residuals),
        ambiguous=_ambiguous(best, other, obj, solution_errors, ambiguity_ratio, sign, camera, corner_sigma_px),
        solution_errors=solution_errors,
        covariance=with_corner_floor(_covariance(residuals, jacobian) if measured else None, R, t, sign, camera,
                                     corner_sigma_px) if with_covariance else None,
    )


def pose_near(R: np.ndarray, t: np.ndarray, src_px: np.ndarray, dst_px: np.ndarray, sign: LibrarySign,
              camera: Camera, corner_sigma_px: float = 0.0, *, with_covariance: bool = True) -> Pose:
    """The pose of `sign` fitted to (N >= 4, 2) library px `src_px` seen at (N, 2) image px `dst_px`
    by Levenberg-Marquardt from the start (R (3, 3), t (3,) m), with its covariance as `estimate_pose`
    gives it (None without `with_covariance`: for a caller that measures it otherwise).

    For a sign followed from frame to frame: starting from the previous frame's pose keeps the
    planar solution it had, so the two-fold ambiguity is settled by continuity, not decided again
    on each frame's points. `solution_errors` is None and `ambiguous` False: the other solution
    is not looked at.

    Raises PoseError when the points admit no pose.
    """
    src_px = np.ascontiguousarray(src_px, dtype=np.float64).reshape(-1, 2)
    dst_px = np.ascontiguousarray(dst_px, dtype=np.float64).reshape(-1, 2)
    if len(src_px) < 4 or len(src_px) != len(dst_px):
        raise PoseError(f"a pose needs 4 or more correspondences; got {len(src_px)} and {len(dst_px)} points")
    obj = sign.to_metric(src_px)
    _check_spread(obj)
    R, t = _refine_lm(np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64), obj, dst_px, camera)
    if not _in_front(R, t, obj):
        raise PoseError("the refined pose puts the sign behind the camera")
    if not with_covariance:
        return Pose(R=R, t=t, method="tracked", reprojection_rmse_px=_reprojection_rmse(R, t, obj, dst_px, camera),
                    ambiguous=False, solution_errors=None, covariance=None)
    projected, jacobian = _project(R, t, obj, camera)
    residuals = projected - dst_px
    return Pose(R=R, t=t, method="tracked", reprojection_rmse_px=_rmse(residuals), ambiguous=False,
                solution_errors=None,
                covariance=with_corner_floor(_covariance(residuals, jacobian), R, t, sign, camera, corner_sigma_px))
