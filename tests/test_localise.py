"""The camera in the map frame by one joint fit over every mapped sign in view (pipeline/localise.py)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from signpose.pipeline.library import SAMPLE_LIBRARY, load_library
from signpose.pipeline.localise import locate_in_map
from signpose.pipeline.pose import Pose, estimate_pose, rotation_error_deg
from signpose.pipeline.pose_filter import exp_so3, log_so3
from signpose.pipeline.sign_map import MappedSign, SignMap
from signpose.pipeline.synth import synthetic_camera

LIBRARY = load_library(SAMPLE_LIBRARY)
CAMERA = synthetic_camera((640, 480))
NOISE_PX = 0.5
# Two signs 2.4 m apart, the second turned 35° about the map's y (down): the camera sees both from 3-4 m.
MAP = SignMap({"security_compound": MappedSign("security_compound", np.eye(3), np.zeros(3)),
               "ministry_of_torture": MappedSign("ministry_of_torture", exp_so3(np.array([0.0, -0.6, 0.0])),
                                                 np.array([2.4, 0.1, 0.3]))})


@dataclass(frozen=True)
class Seen:
    """A sign found in an image, as a recognition gives it."""

    label: str
    corners: np.ndarray
    pose: Pose | None


def true_camera(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of a camera 3-4 m in front of the signs, X_cam = R·X_map + t, looking at their middle."""
    position = np.array([rng.uniform(0.6, 1.8), rng.uniform(-0.3, 0.3), rng.uniform(-4.0, -3.0)])
    forward = np.array([1.2, 0.05, 0.15]) - position
    forward /= np.linalg.norm(forward)
    right = np.cross([0.0, 1.0, 0.0], forward)
    right /= np.linalg.norm(right)
    R_map_cam = np.column_stack([right, np.cross(forward, right), forward]) @ exp_so3(rng.normal(0, 0.02, 3))
    return R_map_cam.T, -R_map_cam.T @ position


def seen(label: str, R: np.ndarray, t: np.ndarray, rng: np.random.Generator, sign_map: SignMap = MAP) -> Seen:
    """Sign `label` in the camera (R, t): its corners projected with noise, its pose fitted to them."""
    sign, mapped = LIBRARY[label], sign_map.signs[label]
    corners = cv2.projectPoints(mapped.to_map(sign.to_metric(sign.corners_px)), cv2.Rodrigues(R)[0], t, CAMERA.K,
                                CAMERA.dist)[0].reshape(4, 2) + rng.normal(0.0, NOISE_PX, (4, 2))
    H = cv2.getPerspectiveTransform(sign.corners_px.astype(np.float32), corners.astype(np.float32))
    pose = estimate_pose(H, sign.corners_px, corners, sign, CAMERA, corner_sigma_px=NOISE_PX)
    return Seen(label, corners, pose)


def in_map(found: Seen) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of the map in the camera from one sign's own pose and the map."""
    mapped = MAP.signs[found.label]
    R = found.pose.R @ mapped.R.T
    return R, found.pose.t - R @ mapped.position_m


def test_two_signs_locate_the_camera_better_than_either_alone_with_a_covariance_that_covers_the_error():
    rng = np.random.default_rng(3)
    errors: dict[str, list[float]] = {"joint": [], "security_compound": [], "ministry_of_torture": []}
    rotation: dict[str, list[float]] = {"joint": [], "alone": []}
    covered = []
    for _ in range(40):
        R, t = true_camera(rng)
        position = -R.T @ t
        found = [seen(label, R, t, rng) for label in MAP.signs]
        located = locate_in_map(found=found, sign_map=MAP, library=LIBRARY, camera=CAMERA)
        assert located is not None and set(located.signs_used) == set(MAP.signs)
        errors["joint"].append(float(np.linalg.norm(located.position_m - position)))
        rotation["joint"].append(rotation_error_deg(located.R, R.T))
        for f in found:
            R_f, t_f = in_map(f)
            errors[f.label].append(float(np.linalg.norm(-R_f.T @ t_f - position)))
            rotation["alone"].append(rotation_error_deg(R_f, R))
        # the true pose's offset in ROS order: position, then rotation about the map's axes (R_true = exp(δθ)·R)
        e = np.concatenate([position - located.position_m, log_so3(R.T @ located.R.T)])
        covered.append(float(e @ np.linalg.solve(located.covariance_xyz_rpy, e)) < 12.59)  # chi-square 6 dof, 95 %
    joint = np.median(errors["joint"])
    assert joint < 0.7 * min(np.median(errors["security_compound"]), np.median(errors["ministry_of_torture"]))
    assert np.median(rotation["joint"]) < np.median(rotation["alone"])
    assert np.mean(covered) >= 0.85


def test_signs_not_in_the_map_are_left_out_and_none_in_the_map_gives_none():
    rng = np.random.default_rng(4)
    R, t = true_camera(rng)
    found = [seen(label, R, t, rng) for label in MAP.signs]
    alone = SignMap({"security_compound": MAP.signs["security_compound"]})
    one = locate_in_map(found=found, sign_map=alone, library=LIBRARY, camera=CAMERA)
    assert one is not None and one.signs_used == ("security_compound",)
    # the single sign's own pose, composed with the map
    R_s, t_s = in_map(found[0])
    assert np.linalg.norm(one.position_m - (-R_s.T @ t_s)) < 1e-3
    # a sign the map lacks, far off where it is said to be, changes nothing
    stray = Seen("chief_of_security", found[1].corners + 40.0, found[1].pose)
    with_stray = locate_in_map(found=[found[0], stray], sign_map=alone, library=LIBRARY, camera=CAMERA)
    np.testing.assert_allclose(with_stray.position_m, one.position_m)
    elsewhere = SignMap({"chief_of_security": MappedSign("chief_of_security", np.eye(3), np.zeros(3))})
    assert locate_in_map(found=found, sign_map=elsewhere, library=LIBRARY, camera=CAMERA) is None
    assert locate_in_map(found=[Seen("security_compound", found[0].corners, None)], sign_map=MAP, library=LIBRARY,
                         camera=CAMERA) is None


def test_the_map_covariance_of_the_signs_adds_to_the_camera_and_the_json_is_plain():
    rng = np.random.default_rng(5)
    R, t = true_camera(rng)
    found = [seen(label, R, t, rng) for label in MAP.signs]
    certain = locate_in_map(found=found, sign_map=MAP, library=LIBRARY, camera=CAMERA)
    sigma = np.diag([0.01**2] * 3 + [math.radians(0.5) ** 2] * 3)
    loose = SignMap({k: MappedSign(k, s.R, s.position_m, sigma) for k, s in MAP.signs.items()})
    uncertain = locate_in_map(found=found, sign_map=loose, library=LIBRARY, camera=CAMERA)
    np.testing.assert_allclose(uncertain.position_m, certain.position_m)
    grown = np.diag(uncertain.covariance_xyz_rpy) - np.diag(certain.covariance_xyz_rpy)
    assert np.all(grown > 0) and grown[0] > 0.3 * 0.01**2
    document = json.loads(json.dumps(certain.to_json(), allow_nan=False))
    assert len(document["position_m"]) == 3 and len(document["orientation_wxyz"]) == 4
    assert np.array(document["covariance_xyz_rpy"]).shape == (6, 6)
    assert document["signs_used"] == list(certain.signs_used)
    w, x, y, z = document["orientation_wxyz"]
    assert pytest.approx(1.0) == w * w + x * x + y * y + z * z


def test_a_sign_that_disagrees_with_the_others_is_left_out_and_named():
    """Three signs in view, one of them moved 15 cm since the map was made: the fit leaves it out and names it,
    and locates the camera from the other two as if it were not there; with the map right, all three are used.
    Two signs that disagree are both kept, their disagreement in the covariance."""
    third = "chief_of_security"
    truth = SignMap({**MAP.signs, third: MappedSign(third, exp_so3(np.array([0.0, 0.3, 0.0])), np.array([1.2, -0.9, 0.2]))})
    stale = SignMap({**truth.signs, third: MappedSign(third, truth.signs[third].R,
                                                      truth.signs[third].position_m + [0.15, 0.0, 0.0])})
    rng = np.random.default_rng(7)
    for _ in range(5):
        R, t = true_camera(rng)
        found = [seen(label, R, t, rng, truth) for label in truth.signs]
        right = locate_in_map(found=found, sign_map=truth, library=LIBRARY, camera=CAMERA)
        assert set(right.signs_used) == set(truth.signs) and right.signs_rejected == ()
        moved = locate_in_map(found=found, sign_map=stale, library=LIBRARY, camera=CAMERA)
        assert moved.signs_rejected == (third,) and set(moved.signs_used) == set(MAP.signs)
        two = locate_in_map(found=found[:2], sign_map=truth, library=LIBRARY, camera=CAMERA)
        np.testing.assert_allclose(moved.position_m, two.position_m, atol=1e-9)
        assert moved.to_json()["signs_rejected"] == [third]
    # Two signs that disagree do not say which is wrong: both stay, the covariance grows.
    apart = SignMap({**MAP.signs, "ministry_of_torture": MappedSign("ministry_of_torture", MAP.signs["ministry_of_torture"].R,
                                                                    MAP.signs["ministry_of_torture"].position_m + 0.3)})
    found = [seen(label, R, t, rng) for label in MAP.signs]
    agreeing = locate_in_map(found=found, sign_map=MAP, library=LIBRARY, camera=CAMERA)
    one = locate_in_map(found=found, sign_map=apart, library=LIBRARY, camera=CAMERA)
    assert set(one.signs_used) == set(MAP.signs) and one.signs_rejected == ()
    assert np.trace(one.covariance_xyz_rpy[:3, :3]) > 10 * np.trace(agreeing.covariance_xyz_rpy[:3, :3])
