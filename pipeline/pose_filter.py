"""A constant-velocity Kalman filter on SE(3) for the camera pose relative to one sign.

The state is the camera's orientation and position in the sign frame (R_sc = Rᵀ and p = -Rᵀt,
for a pose X_cam = R·X_sign + t) with their angular and linear rates: a camera moves smoothly
through the sign's frame, whereas t (in the camera frame) swings with every turn of the head.
The orientation error is a left perturbation, R_sc = exp(φ)·R̂_sc, so the 12-dim error state is
[φ (rad), p (m), ω (rad/s), v (m/s)], all in the sign frame.

Each measurement is a `Pose` with its (6, 6) covariance over [rotation vector of R, t] (see
`pipeline.pose`); it is carried into [φ, p] to first order. Process noise is white acceleration
(angular and linear), whose densities set how quickly the filter follows a turn: the defaults
follow a step turn within two frames at 30 fps while averaging the per-frame jitter of a still
camera down.
"""

from __future__ import annotations

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
# Without a covariance, a measurement counts with this σ: rad for rotation, m for position.
FALLBACK_SIGMA = (0.01, 0.01)


def skew(v: np.ndarray) -> np.ndarray:
    """(3, 3) cross-product matrix [v]x of (3,) v."""
    x, y, z = (float(a) for a in v)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of rotation vector (3,) phi (rad)."""
    return cv2.Rodrigues(np.asarray(phi, dtype=np.float64).reshape(3, 1))[0]


def log_so3(R: np.ndarray) -> np.ndarray:
    """(3,) rotation vector (rad) of (3, 3) rotation R."""
    return cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].ravel()


def left_jacobian(phi: np.ndarray) -> np.ndarray:
    """(3, 3) left Jacobian of SO(3) at rotation vector phi: exp(phi + δ) ≈ exp(J_l(phi)·δ)·exp(phi)."""
    angle = float(np.linalg.norm(phi))
    K = skew(phi)
    if angle < 1e-8:
        return np.eye(3) + 0.5 * K
    return (np.eye(3) + (1 - math.cos(angle)) / angle**2 * K
            + (angle - math.sin(angle)) / angle**3 * K @ K)


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


def ros_jacobian(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(6, 6) Jacobian of the camera's pose in the frame a pose (R (3, 3), t (3,) m) maps from (X_cam =
    R·X + t: a sign's, the map's), in ROS order [position (m), rotation about that frame's x, y, z (rad)],
    with respect to the pipeline's [rotation vector of R, t]: `pose_jacobian` with its two blocks of rows
    swapped."""
    jacobian = pose_jacobian(np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64).reshape(3))
    return np.vstack([jacobian[3:], jacobian[:3]])


@dataclass
class PoseFilter:
    """Constant-velocity filter of one sign's camera pose; `update` takes each frame's measured
    `Pose` at `time_s` and returns the filtered one, `predict_pose` the filter's guess for a
    frame without a measurement. The first measurement starts it at rest."""

    angular_density: float = ANGULAR_ACCELERATION_DENSITY
    linear_density: float = LINEAR_ACCELERATION_DENSITY
    restart_mahalanobis: float = RESTART_MAHALANOBIS
    R_sc: np.ndarray | None = field(default=None, repr=False)  # (3, 3) camera -> sign rotation
    p: np.ndarray = field(default_factory=lambda: np.zeros(3), repr=False)  # camera centre, sign frame, m
    omega: np.ndarray = field(default_factory=lambda: np.zeros(3), repr=False)  # rad/s, sign frame
    v: np.ndarray = field(default_factory=lambda: np.zeros(3), repr=False)  # m/s, sign frame
    P: np.ndarray = field(default_factory=lambda: np.zeros((12, 12)), repr=False)
    time_s: float | None = None

    @property
    def started(self) -> bool:
        return self.R_sc is not None

    def _measurement(self, pose: Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R_sc (3, 3), p (3,), covariance (6, 6) over [φ, p]) of a measured pose."""
        R, t = np.asarray(pose.R, dtype=np.float64), np.asarray(pose.t, dtype=np.float64).reshape(3)
        cov = pose.covariance
        if cov is None or not np.all(np.isfinite(cov)):
            cov = np.diag([FALLBACK_SIGMA[0] ** 2] * 3 + [FALLBACK_SIGMA[1] ** 2] * 3)
        J = pose_jacobian(R, t)
        return R.T, -R.T @ t, J @ cov @ J.T

    def _start(self, R_sc: np.ndarray, p: np.ndarray, cov: np.ndarray, time_s: float) -> None:
        self.R_sc, self.p = R_sc, p
        self.omega, self.v = np.zeros(3), np.zeros(3)
        self.P = np.zeros((12, 12))
        self.P[:6, :6] = cov
        # Unknown rates at the start: a turn of a few rad/s or a move of a few m/s.
        self.P[6:9, 6:9] = np.eye(3) * 4.0
        self.P[9:, 9:] = np.eye(3) * 1.0
        self.time_s = time_s

    def predict(self, time_s: float) -> None:
        """Move the state to `time_s` (s) under constant velocity."""
        assert self.R_sc is not None and self.time_s is not None, "predict after the first update"
        dt = max(0.0, time_s - self.time_s)
        if dt == 0.0:
            return
        self.R_sc = exp_so3(self.omega * dt) @ self.R_sc
        self.p = self.p + self.v * dt
        F = np.eye(12)
        F[0:3, 6:9] = F[3:6, 9:12] = np.eye(3) * dt
        Q = np.zeros((12, 12))
        for block, q in ((slice(0, 3), self.angular_density), (slice(3, 6), self.linear_density)):
            rate = slice(block.start + 6, block.stop + 6)
            Q[block, block] = np.eye(3) * q * dt**3 / 3
            Q[block, rate] = Q[rate, block] = np.eye(3) * q * dt**2 / 2
            Q[rate, rate] = np.eye(3) * q * dt
        self.P = F @ self.P @ F.T + Q
        self.time_s = time_s

    def update(self, pose: Pose, time_s: float) -> Pose:
        """Fold in the measured `pose` at `time_s` (s) and return the filtered pose."""
        R_sc, p, cov = self._measurement(pose)
        if self.R_sc is None:
            self._start(R_sc, p, cov, time_s)
            return self.pose()
        self.predict(time_s)
        innovation = np.concatenate([log_so3(R_sc @ self.R_sc.T), p - self.p])
        S = self.P[:6, :6] + cov
        try:
            distance = math.sqrt(max(0.0, float(innovation @ np.linalg.solve(S, innovation))))
        except np.linalg.LinAlgError:
            distance = math.inf
        if distance > self.restart_mahalanobis:
            self._start(R_sc, p, cov, time_s)
            return self.pose()
        gain = self.P[:, :6] @ np.linalg.inv(S)
        dx = gain @ innovation
        self.R_sc = exp_so3(dx[:3]) @ self.R_sc
        self.p = self.p + dx[3:6]
        self.omega = self.omega + dx[6:9]
        self.v = self.v + dx[9:12]
        I_KH = np.eye(12)
        I_KH[:, :6] -= gain
        # Joseph form: stays symmetric positive definite whatever the rounding.
        self.P = I_KH @ self.P @ I_KH.T + gain @ cov @ gain.T
        return self.pose()

    def pose(self) -> Pose:
        """The filtered pose as a `Pose` (R, t of the sign in the camera) with its (6, 6)
        covariance over [rotation vector, t], carried back from the state's [φ, p]."""
        assert self.R_sc is not None, "no pose before the first update"
        R = self.R_sc.T
        t = -R @ self.p
        J_inv = np.linalg.inv(pose_jacobian(R, t))
        covariance = J_inv @ self.P[:6, :6] @ J_inv.T
        return Pose(R=R, t=t, method="filtered", reprojection_rmse_px=math.nan, ambiguous=False,
                    solution_errors=None, covariance=0.5 * (covariance + covariance.T))
