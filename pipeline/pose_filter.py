"""A constant-velocity Kalman filter on SE(3) for the camera pose relative to one sign.

The state is the camera's orientation and position in the sign frame (R_sc = Rᵀ and p = -Rᵀt,
for a pose X_cam = R·X_sign + t) with their angular and linear rates: a camera moves smoothly
through the sign's frame, whereas t (in the camera frame) swings with every turn of the head.
The orientation error is a left perturbation, R_sc = exp(φ)·R̂_sc, so the 12-dim error state is
[φ (rad), p (m), ω (rad/s), v (m/s)], all in the sign frame.

Each measurement is a `Pose` with its (6, 6) covariance over [rotation vector of R, t] (see
`pipeline.pose`), and it is compared with the state where it was measured: R = R_scᵀ and
t = -R_scᵀ·p, linearised at the predicted state (an extended Kalman filter). A sign's pose pins t
(its bearing to a fraction of a pixel, its distance to a few per cent) far better than R (the
tilt of a small or far sign, to degrees); carried into [φ, p] at the measured pose instead, the
few degrees of tilt error moved the well-pinned combination by centimetres at 7 m (second order)
against its millimetres of σ, and the filter jumped with them. Process noise is white acceleration
(angular and linear), whose densities set how quickly the filter follows a turn: the defaults
follow a step turn within two frames at 30 fps while averaging the per-frame jitter of a still
camera down.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from .pose import Pose

# White angular acceleration density, rad²/s³, and linear, m²/s³. A camera turns far more abruptly
# than its centre changes speed; on the 12 s synthetic corridor flight the linear density took the
# filtered jitter from 4.4 mm median (2.0) to 3.4 (0.05) and 3.0 (0.02), the angular one (50, 10,
# 2) changed nothing there, and a step turn of 20° is followed within two frames from 50 down to 10.
ANGULAR_ACCELERATION_DENSITY = 10.0
LINEAR_ACCELERATION_DENSITY = 0.05
# A measurement this many σ (Mahalanobis, over 6 dof) from the prediction is a new motion the
# model missed, not noise: the filter restarts from it instead of lagging behind it.
RESTART_MAHALANOBIS = 12.0
# A measurement this long (s) after the last one restarts the filter too: a constant-velocity guess
# over a longer time (a camera that saw no mapped sign for a second) is no prior, and linearised at it
# the update landed 16-25 cm off on the sample flight, the covariance saying a few centimetres. The
# tracker allows as many frames as a track outlives unseen where frames come further apart.
MAX_GAP_S = 0.5
# Without a covariance, a measurement counts with this σ: rad for rotation, m for position.
FALLBACK_SIGMA = (0.01, 0.01)
# Identities of the sizes the filter works in: read only (np.eye on each use was a tenth of an update).
_I3, _I12 = np.eye(3), np.eye(12)


def skew(v: np.ndarray) -> np.ndarray:
    """(3, 3) cross-product matrix [v]x of (3,) v."""
    x, y, z = np.asarray(v, dtype=np.float64).reshape(3).tolist()
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of rotation vector (3,) phi (rad)."""
    return cv2.Rodrigues(np.asarray(phi, dtype=np.float64).reshape(3, 1))[0]


def log_so3(R: np.ndarray) -> np.ndarray:
    """(3,) rotation vector (rad) of (3, 3) rotation R."""
    return cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].ravel()


def left_jacobian(phi: np.ndarray) -> np.ndarray:
    """(3, 3) left Jacobian of SO(3) at rotation vector phi: exp(phi + δ) ≈ exp(J_l(phi)·δ)·exp(phi)."""
    phi = np.asarray(phi, dtype=np.float64).reshape(3)
    angle = math.sqrt(float(phi @ phi))
    K = skew(phi)
    if angle < 1e-8:
        return _I3 + 0.5 * K
    # K·K = phi·phiᵀ - angle²·I
    b = (angle - math.sin(angle)) / angle**3
    return (1 - b * angle**2) * _I3 + (1 - math.cos(angle)) / angle**2 * K + b * np.outer(phi, phi)


def pose_jacobian(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(6, 6) first-order map from a pose's [rotation vector of R, t] errors to the filter's
    [φ (left perturbation of Rᵀ), p = -Rᵀt] errors."""
    # R = exp(ψ)R̂ with ψ = J_l·δrvec gives Rᵀ = R̂ᵀexp(-ψ) = exp(-R̂ᵀψ)R̂ᵀ, so φ = -R̂ᵀψ; and
    # p = -Rᵀt moves by dp = R̂ᵀ[t]x R̂ φ - R̂ᵀ dt.
    Rt = R.T
    J = np.zeros((6, 6))
    J[:3, :3] = -Rt @ left_jacobian(log_so3(R))
    J[3:, :3] = Rt @ skew(t) @ R @ J[:3, :3]
    J[3:, 3:] = -Rt
    return J


def pose_jacobian_inverse(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(6, 6) inverse of `pose_jacobian(R, t)`: the filter's [φ, p] errors back to the pose's
    [rotation vector of R, t] errors."""
    # pose_jacobian is [[A, 0], [C·A, D]] with A = -Rᵀ·J_l, C = Rᵀ[t]x R, D = -Rᵀ, whose inverse is
    # [[A⁻¹, 0], [-D⁻¹·C, D⁻¹]] = [[-J_l⁻¹·R, 0], [[t]x·R, -R]].
    J_inv = np.zeros((6, 6))
    J_inv[:3, :3] = -np.linalg.inv(left_jacobian(log_so3(R))) @ R
    J_inv[3:, :3] = skew(t) @ R
    J_inv[3:, 3:] = -R
    return J_inv


def ros_jacobian(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(6, 6) Jacobian of the camera's pose in the frame a pose (R (3, 3), t (3,) m) maps from (X_cam =
    R·X + t: a sign's, the map's), in ROS order [position (m), rotation about that frame's x, y, z (rad)],
    with respect to the pipeline's [rotation vector of R, t]: `pose_jacobian` with its two blocks of rows
    swapped."""
    jacobian = pose_jacobian(np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64).reshape(3))
    return np.vstack([jacobian[3:], jacobian[:3]])


@functools.lru_cache(maxsize=64)
def process_noise(dt: float, angular_density: float, linear_density: float) -> np.ndarray:
    """(12, 12) process noise over [φ, p, ω, v] of white angular (rad²/s³) and linear (m²/s³)
    acceleration over `dt` s. Cached: frames mostly come at one rate. Read only."""
    densities = np.diag([angular_density] * 3 + [linear_density] * 3)
    Q = np.kron(np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]), densities)
    Q.flags.writeable = False
    return Q


@dataclass
class PoseFilter:
    """Constant-velocity filter of one sign's camera pose; `update` takes each frame's measured
    `Pose` at `time_s` and returns the filtered one; for a frame without a measurement, `predict`
    moves it to the frame's time and `pose` is its guess. The first measurement starts it at rest, as
    does one `max_gap_s` after the last or `restart_mahalanobis` σ from the prediction."""

    angular_density: float = ANGULAR_ACCELERATION_DENSITY
    linear_density: float = LINEAR_ACCELERATION_DENSITY
    restart_mahalanobis: float = RESTART_MAHALANOBIS
    max_gap_s: float = MAX_GAP_S
    R_sc: np.ndarray | None = field(default=None, repr=False)  # (3, 3) camera -> sign rotation
    p: np.ndarray = field(default_factory=lambda: np.zeros(3), repr=False)  # camera centre, sign frame, m
    omega: np.ndarray = field(default_factory=lambda: np.zeros(3), repr=False)  # rad/s, sign frame
    v: np.ndarray = field(default_factory=lambda: np.zeros(3), repr=False)  # m/s, sign frame
    P: np.ndarray = field(default_factory=lambda: np.zeros((12, 12)), repr=False)
    time_s: float | None = None
    measured_s: float = -math.inf  # time of the last measurement, s

    @property
    def started(self) -> bool:
        return self.R_sc is not None

    @staticmethod
    def _measurement(pose: Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R (3, 3), t (3,), covariance (6, 6) over [ψ, t], ψ the left perturbation of R:
        R = exp(ψ)·R̂) of a measured pose."""
        R, t = np.asarray(pose.R, dtype=np.float64), np.asarray(pose.t, dtype=np.float64).reshape(3)
        cov = pose.covariance
        if cov is None or not np.all(np.isfinite(cov)):
            cov = np.diag([FALLBACK_SIGMA[0] ** 2] * 3 + [FALLBACK_SIGMA[1] ** 2] * 3)
        # exp(r + δr) = exp(J_l(r)·δr)·exp(r): the rotation vector's errors as left perturbations
        D = np.eye(6)
        D[:3, :3] = left_jacobian(log_so3(R))
        return R, t, D @ cov @ D.T

    def _observation(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R̂ (3, 3), t̂ (3,) the pose the state predicts, H (6, 12) the first-order map from the
        state's errors to [ψ, t])."""
        assert self.R_sc is not None
        R = self.R_sc.T
        t = -R @ self.p
        # R_sc = exp(φ)·R̂_sc gives R = exp(-R̂·φ)·R̂, and t = -R·p moves by [t̂]x·R̂·φ - R̂·dp.
        H = np.zeros((6, 12))
        H[:3, :3] = -R
        H[3:, :3] = skew(t) @ R
        H[3:, 3:6] = -R
        return R, t, H

    def _start(self, pose: Pose, time_s: float) -> None:
        """Start at rest at the measured `pose`, its covariance carried into [φ, p]."""
        R, t = np.asarray(pose.R, dtype=np.float64), np.asarray(pose.t, dtype=np.float64).reshape(3)
        cov = pose.covariance
        if cov is None or not np.all(np.isfinite(cov)):
            cov = np.diag([FALLBACK_SIGMA[0] ** 2] * 3 + [FALLBACK_SIGMA[1] ** 2] * 3)
        J = pose_jacobian(R, t)
        self.R_sc, self.p = R.T, -R.T @ t
        self.omega, self.v = np.zeros(3), np.zeros(3)
        self.P = np.zeros((12, 12))
        self.P[:6, :6] = J @ cov @ J.T
        # Unknown rates at the start: a turn of a few rad/s or a move of a few m/s.
        self.P[6:9, 6:9] = _I3 * 4.0
        self.P[9:, 9:] = _I3 * 1.0
        self.time_s = self.measured_s = time_s

    def predict(self, time_s: float) -> None:
        """Move the state to `time_s` (s) under constant velocity."""
        assert self.R_sc is not None and self.time_s is not None, "predict after the first update"
        dt = max(0.0, time_s - self.time_s)
        if dt == 0.0:
            return
        self.R_sc = exp_so3(self.omega * dt) @ self.R_sc
        self.p = self.p + self.v * dt
        # F·P·Fᵀ with F = [[I, dt·I], [0, I]] over [(φ, p), (ω, v)]: rows, then columns, added to.
        P = self.P.copy()
        P[:6] += dt * P[6:]
        P[:, :6] += dt * P[:, 6:]
        self.P = P + process_noise(dt, self.angular_density, self.linear_density)
        self.time_s = time_s

    def update(self, pose: Pose, time_s: float) -> Pose:
        """Fold in the measured `pose` at `time_s` (s) and return the filtered pose."""
        if self.R_sc is None or time_s - self.measured_s > self.max_gap_s:
            self._start(pose, time_s)
            return self.pose()
        R, t, cov = self._measurement(pose)
        self.predict(time_s)
        R_hat, t_hat, H = self._observation()
        innovation = np.concatenate([log_so3(R @ R_hat.T), t - t_hat])
        PH = self.P @ H.T
        S = H @ PH + cov
        try:
            # One solve for both: S⁻¹·innovation (the Mahalanobis distance) and S⁻¹·(P·Hᵀ)ᵀ (the gain, S symmetric).
            solved = np.linalg.solve(S, np.column_stack([innovation, PH.T]))
            distance = math.sqrt(max(0.0, float(innovation @ solved[:, 0])))
        except np.linalg.LinAlgError:
            solved, distance = None, math.inf
        if solved is None or distance > self.restart_mahalanobis:
            self._start(pose, time_s)
            return self.pose()
        gain = solved[:, 1:].T
        dx = gain @ innovation
        self.R_sc = exp_so3(dx[:3]) @ self.R_sc
        self.p = self.p + dx[3:6]
        self.omega = self.omega + dx[6:9]
        self.v = self.v + dx[9:12]
        I_KH = _I12 - gain @ H
        # Joseph form: stays symmetric positive definite whatever the rounding.
        self.P = I_KH @ self.P @ I_KH.T + gain @ cov @ gain.T
        # a stamp back in time is taken as no time passed, as `predict` takes it
        self.measured_s = max(self.measured_s, time_s)
        return self.pose()

    def pose(self) -> Pose:
        """The filtered pose as a `Pose` (R, t of the sign in the camera) with its (6, 6)
        covariance over [rotation vector, t], carried back from the state's [φ, p]."""
        assert self.R_sc is not None, "no pose before the first update"
        R = self.R_sc.T
        t = -R @ self.p
        J_inv = pose_jacobian_inverse(R, t)
        covariance = J_inv @ self.P[:6, :6] @ J_inv.T
        return Pose(R=R, t=t, method="filtered", reprojection_rmse_px=math.nan, ambiguous=False,
                    solution_errors=None, covariance=0.5 * (covariance + covariance.T))
