"""The camera located in the map frame from every mapped sign in view, by one joint fit.

Each sign in view contributes its four corners as the image measured them (TL, TR, BR, BL, image
px: what a recognition and a tracked sign both keep), placed in the map through the map file
(X_map = R_sign·X_sign + position). One Levenberg-Marquardt fit over all of them finds the camera
pose in the map frame, X_cam = R·X_map + t: signs at different places pin down together what one
sign alone leaves loose (its distance against its tilt, a flipped planar solution).

A sign's corners count with one σ (px) of its own, the σ at which they would give its pose's
covariance: σ² = (det Σ · det JᵀJ)^(1/6), J the (8, 6) Jacobian of its projected corners, Σ its
pose's (6, 6) covariance (the fit's residuals and the corner floor, `pipeline.pose`). So an
outlined sign 2 m away outweighs a feature-matched one at 8 m as their own fits say it should.
The covariance is σ-whitened Gauss-Newton's (JᵀJ)⁻¹ scaled, as `pipeline.pose` scales a fit's, by
the residuals: here by χ²/dof when signs disagree beyond their σ (never below 1, since a sign's
four corners alone fit a pose nearly exactly), plus what each sign's map covariance moves the
camera by.

A sign that disagrees with the others (moved since the survey, a wrong recognition) is left out.
The fit's whitened squared residual, each sign's corners counting its σ and its map covariance,
is tested against the 99.9 % point of chi-square with 8N - 6 dof (N signs, three or more); beyond
it, the sign whose removal leaves the others fitting best is dropped, and the test repeated down
to two signs. Two signs that disagree do not say which is wrong: both stay, and their
disagreement grows the covariance. The dropped signs are named in `signs_rejected`. (Each sign is fitted over the others, not predicted by them: one sign alone
fixes its tilt against its distance too loosely, and a planar flip too often, to predict another.)
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from .camera import Camera
from .library import Library
from .pose import Pose, _json_numbers, _project, _rmse, _scaled_inverse, quaternion_wxyz
from .pose_filter import pose_jacobian, ros_jacobian, skew
from .sign_map import SignMap

MAX_ITERATIONS = 50
# A step smaller than this (rad and m) ends the fit: far below a pose's 1σ.
STEP_TOLERANCE = 1e-10


class SignInView(Protocol):
    """A sign found in an image: a `Recognition`, a tracker's `SignObservation`."""

    @property
    def label(self) -> str | None: ...

    @property
    def corners(self) -> np.ndarray | None: ...

    @property
    def pose(self) -> Pose | None: ...


@dataclass(frozen=True, eq=False)
class CameraInMap:
    """The camera in the map frame: `pose` is the map's pose in the camera as `pipeline.pose` writes a
    sign's (X_cam = R·X_map + t, covariance over [rotation vector of R, t]; `reprojection_rmse_px` over
    every corner used), `signs_used` the mapped signs it was fitted to, `signs_rejected` the mapped
    signs in view left out as disagreeing with them."""

    pose: Pose
    signs_used: tuple[str, ...]
    signs_rejected: tuple[str, ...] = ()

    @property
    def R(self) -> np.ndarray:
        """(3, 3) camera orientation in the map: X_map = R·X_cam + position_m."""
        return self.pose.R.T

    @property
    def position_m(self) -> np.ndarray:
        """(3,) camera centre in the map frame, metres."""
        return self.pose.camera_position

    @property
    def covariance_xyz_rpy(self) -> np.ndarray | None:
        """(6, 6) covariance in ROS order: position x, y, z (m²), rotation about the map's x, y, z (rad²),
        the orientation perturbed as exp([δθ]×)·R; None when the fit has none."""
        if self.pose.covariance is None:
            return None
        J = ros_jacobian(self.pose.R, self.pose.t)
        covariance = J @ self.pose.covariance @ J.T
        return 0.5 * (covariance + covariance.T)

    @property
    def reprojection_rmse_px(self) -> float:
        return self.pose.reprojection_rmse_px

    def to_json(self) -> dict:
        """{"position_m", "orientation_wxyz", "covariance_xyz_rpy" (6x6 or null), "signs_used",
        "signs_rejected", "reprojection_rmse_px"}; non-finite numbers as null."""
        covariance = self.covariance_xyz_rpy
        return {"position_m": _json_numbers(self.position_m), "orientation_wxyz": _json_numbers(quaternion_wxyz(self.R)),
                "covariance_xyz_rpy": None if covariance is None else _json_numbers(covariance),
                "signs_used": list(self.signs_used), "signs_rejected": list(self.signs_rejected),
                "reprojection_rmse_px": _json_numbers(self.reprojection_rmse_px)}


@dataclass(frozen=True, eq=False)
class _SignPoints:
    """One mapped sign's corners: (4, 3) map points, (4, 2) measured image px, their σ (px), the sign's
    pose composed with the map (R, t: X_cam = R·X_map + t) as a start, and its map covariance."""

    sign_id: str
    points: np.ndarray
    measured: np.ndarray
    sigma_px: float
    start: tuple[np.ndarray, np.ndarray]
    certainty: float
    map_position: np.ndarray
    map_covariance: np.ndarray | None


def _corner_sigma(pose: Pose, corners_sign: np.ndarray, camera: Camera) -> float | None:
    """The σ (px) at which (4, 3) sign-frame corners give `pose`'s covariance (geometric mean over
    its six directions); None without a usable covariance."""
    covariance = pose.covariance
    if covariance is None or not np.all(np.isfinite(covariance)):
        return None
    _, J = _project(pose.R, pose.t, corners_sign, camera)
    sign_det, log_det = np.linalg.slogdet(covariance @ (J.T @ J))
    return math.exp(log_det / 12) if sign_det > 0 else None


def _sign_points(found: SignInView, sign_map: SignMap, library: Library, camera: Camera) -> _SignPoints | None:
    """What `found` gives the fit, None when it is not a mapped library sign with corners and a pose with covariance."""
    label, corners, pose = found.label, found.corners, found.pose
    if label is None or label not in sign_map.signs or label not in library.ids or corners is None or pose is None:
        return None
    sign, mapped = library[label], sign_map.signs[label]
    corners_sign = sign.to_metric(sign.corners_px)
    sigma = _corner_sigma(pose, corners_sign, camera)
    if sigma is None:
        return None
    R = pose.R @ mapped.R.T  # X_cam = R_cs·R_msᵀ·(X_map - p_ms) + t_cs
    to_position = pose_jacobian(pose.R, pose.t)[3:]  # the camera position's rows
    position_block = to_position @ pose.covariance @ to_position.T
    return _SignPoints(label, mapped.to_map(corners_sign), np.asarray(corners, dtype=np.float64).reshape(4, 2),
                       sigma, (R, pose.t - R @ mapped.position_m), float(np.trace(position_block)),
                       mapped.position_m, mapped.covariance)


def _fit(R: np.ndarray, t: np.ndarray, points: np.ndarray, measured: np.ndarray, weights: np.ndarray,
         camera: Camera) -> tuple[np.ndarray, np.ndarray, float]:
    """Levenberg-Marquardt on the weighted reprojection error of (N, 3) map points against (N, 2) px,
    weights (N,) = 1/σ, from (R, t): (R, t, the weighted sum of squares)."""
    rvec, t = cv2.Rodrigues(R)[0].ravel(), np.asarray(t, dtype=np.float64).copy()
    w2 = np.repeat(weights, 2)[:, None]

    def cost(rv: np.ndarray, tv: np.ndarray) -> float:
        return float(np.sum(((_project(cv2.Rodrigues(rv)[0], tv, points, camera)[0] - measured) * weights[:, None]) ** 2))

    current, damping = cost(rvec, t), 1e-3
    for _ in range(MAX_ITERATIONS):
        projected, J = _project(cv2.Rodrigues(rvec)[0], t, points, camera)
        Jw, r = J * w2, ((projected - measured) * weights[:, None]).ravel()
        A, g = Jw.T @ Jw, Jw.T @ r
        while True:
            step = np.linalg.solve(A + damping * np.diag(np.diag(A)), -g)
            trial = cost(rvec + step[:3], t + step[3:])
            if trial <= current:
                rvec, t, current, damping = rvec + step[:3], t + step[3:], trial, damping / 10
                break
            damping *= 10
            if damping > 1e10:
                return cv2.Rodrigues(rvec)[0], t, current
        if np.linalg.norm(step) < STEP_TOLERANCE:
            break
    return cv2.Rodrigues(rvec)[0], t, current


def locate_in_map(*, found: Iterable[SignInView], sign_map: SignMap, library: Library,
                  camera: Camera) -> CameraInMap | None:
    """The camera in `sign_map`'s frame from the signs `found` in one image (`camera`: its intrinsics,
    scaled to the image), or None when none of them is a mapped sign with corners and a pose with
    covariance. Signs not in the map are left out, and signs that disagree with the others (see the
    module's docstring) are left out and named.

    The fit starts from each sign's own pose composed with the map, the most certain first, and
    keeps the best end: a flipped planar pose of one sign does not decide where it ends."""
    signs: list[_SignPoints] = []
    # One measurement per sign, its most certain: a sign reported twice counts once.
    for sign in sorted(filter(None, (_sign_points(f, sign_map, library, camera) for f in found)),
                       key=lambda s: s.certainty):
        if all(s.sign_id != sign.sign_id for s in signs):
            signs.append(sign)
    if not signs:
        return None
    rejected: list[str] = []
    pose = _joint_fit(signs, camera)
    # Two signs that disagree do not say which is wrong: both stay, and the covariance grows.
    while len(signs) > 2 and _chi2(signs, pose, camera) > _chi2_limit(8 * len(signs) - 6):
        rest = [signs[:i] + signs[i + 1:] for i in range(len(signs))]
        fits = [_joint_fit(r, camera) for r in rest]
        worst = int(np.argmin([_chi2(r, f, camera) for r, f in zip(rest, fits)]))
        rejected.append(signs[worst].sign_id)
        signs, pose = rest[worst], fits[worst]
    return CameraInMap(pose, tuple(s.sign_id for s in signs), tuple(rejected))


def _joint_fit(signs: list[_SignPoints], camera: Camera) -> Pose:
    """The map's pose in the camera fitted over `signs` (one or more), with its covariance (None:
    singular), from each one's start, keeping the end with the least cost."""
    points = np.concatenate([s.points for s in signs])
    measured = np.concatenate([s.measured for s in signs])
    weights = np.repeat([1.0 / s.sigma_px for s in signs], 4)
    R, t, chi2 = min((_fit(*s.start, points, measured, weights, camera) for s in signs), key=lambda fit: fit[2])
    projected, J = _project(R, t, points, camera)
    Jw = J * np.repeat(weights, 2)[:, None]
    dof = 2 * len(points) - 6
    covariance = _scaled_inverse(Jw.T @ Jw, max(1.0, chi2 / dof))
    if covariance is not None:
        covariance = covariance + _map_covariance(signs, R, J, Jw, weights)
    return Pose(R=R, t=t, method="map", reprojection_rmse_px=_rmse(projected - measured), ambiguous=False,
                solution_errors=None, covariance=covariance)


def _chi2(signs: list[_SignPoints], pose: Pose, camera: Camera) -> float:
    """Whitened squared residual of the signs' corners at `pose` (the map's in the camera), each sign's
    corners counting its σ and what its map covariance moves them by."""
    total = 0.0
    for sign in signs:
        projected, J = _project(pose.R, pose.t, sign.points, camera)
        residual = (sign.measured - projected).ravel()
        spread = np.eye(8) * sign.sigma_px**2
        if sign.map_covariance is not None:
            moved = _map_jacobian(sign, pose.R, J)
            spread += moved @ sign.map_covariance @ moved.T
        total += float(residual @ np.linalg.solve(spread, residual))
    return total


def _chi2_limit(dof: int) -> float:
    """The 99.9 % point of chi-square with `dof` degrees of freedom (Wilson-Hilferty, within 1 % from 10 dof)."""
    z, k = 3.0902, 2.0 / (9.0 * dof)
    return dof * (1.0 - k + z * math.sqrt(k)) ** 3


def _map_jacobian(sign: _SignPoints, R: np.ndarray, J: np.ndarray) -> np.ndarray:
    """(8, 6) d px of `sign`'s four corners / d [δp, δθ] of its map pose (ROS order, about the map's
    axes): a sign so moved moves its corners by δp - [X - p]×·δθ. J (8, 6): their projection
    Jacobian at the camera (R, t), its t columns d px / d X_cam."""
    moved = np.vstack([np.hstack([np.eye(3), -skew(X - sign.map_position)]) for X in sign.points])  # (12, 6)
    return np.vstack([J[2 * k:2 * k + 2, 3:] @ R @ moved[3 * k:3 * k + 3] for k in range(4)])


def _map_covariance(signs: list[_SignPoints], R: np.ndarray, J: np.ndarray, Jw: np.ndarray,
                    weights: np.ndarray) -> np.ndarray:
    """(6, 6) covariance over [rotation vector, t] the signs' map covariances add: a sign moved by
    [δp, δθ] moves its corners (`_map_jacobian`), and the fit's solution by -(JᵀJ)⁻¹Jᵀ of what that
    moves the whitened residuals (J (2N, 6) projection Jacobian, Jw whitened)."""
    gain = np.linalg.solve(Jw.T @ Jw, Jw.T)
    added = np.zeros((6, 6))
    for i, sign in enumerate(signs):
        if sign.map_covariance is None:
            continue
        rows = slice(8 * i, 8 * i + 8)
        A = gain[:, rows] @ (_map_jacobian(sign, R, J[rows]) * np.repeat(weights[4 * i:4 * i + 4], 2)[:, None])
        added += A @ sign.map_covariance @ A.T
    return added
