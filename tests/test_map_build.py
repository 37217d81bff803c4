"""The sign map's pose graph (pipeline/map_build.py), the synthetic surveys and `signpose map build`."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import types
from pathlib import Path

import gtsam
import numpy as np
import pytest

from signpose.app.cli import main
from signpose.app.responses import map_out
from signpose.app.sign_maps import open_sign_maps
from signpose.app.state import StateDir
from signpose.pipeline.library import load_library
from signpose.pipeline.map_build import (CHI2_REJECT, SHARED_SHARE, DisconnectedSurvey, MapBuildError, Observation, build_map,
                                         gtsam_covariance, ros_covariance, sign_groups)
from signpose.pipeline.pose_filter import exp_so3, log_so3
from signpose.pipeline.sign_map import MappedSign, SignMap, load_sign_map, read_sign_map
from signpose.pipeline.synth import synthetic_camera
from signpose.pipeline.synth_survey import write_survey

ROOT = Path(__file__).resolve().parents[1]
SURVEY = ROOT / "sample_images" / "surveys" / "room"

# Three signs: two on one wall 3 m apart, one round the corner (turned 90° about y).
SIGNS = {"a": (np.eye(3), np.zeros(3)),
         "b": (exp_so3(np.array([0.0, 0.02, 0.01])), np.array([3.0, 0.1, 0.0])),
         "c": (exp_so3(np.array([0.0, math.pi / 2, 0.0])), np.array([4.5, -0.2, -1.5]))}
SIGMA_ROT, SIGMA_T = math.radians(0.1), 0.002


def cameras(n: int = 12, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """(R_map_cam, position) of `n` cameras across the room from the signs, roughly facing them."""
    rng = np.random.default_rng(seed)
    return [(exp_so3(rng.normal(0.0, 0.15, 3)), np.array([rng.uniform(0.0, 4.0), rng.uniform(-0.3, 0.3), -4.0]))
            for _ in range(n)]


def seen(i: int, sign: str) -> bool:
    """Which camera sees which sign: a only in the first half, c only in the second, b in all."""
    return not ((sign == "a" and i >= 7) or (sign == "c" and i < 5))


def survey(rng: np.random.Generator, signs=SIGNS, cams=None, correlated: bool = False) -> list[Observation]:
    """Noisy observations of `signs` from `cams`: each sign seen by every photo off by one error of its own
    (SHARED_SHARE of an observation's covariance, in the sign's frame, as GTSAM perturbs a pose), then each observation by noise drawn
    from its covariance."""
    covariance = np.diag([SIGMA_ROT**2] * 3 + [SIGMA_T**2] * 3)
    if correlated:  # rotation and translation errors that go together, as a pose fit's do
        covariance[0, 4] = covariance[4, 0] = 0.6 * SIGMA_ROT * SIGMA_T
    observations = []
    shared = {sign_id: rng.multivariate_normal(np.zeros(6), SHARED_SHARE**2 * covariance) for sign_id in signs}
    for i, (R_c, p_c) in enumerate(cams or cameras()):
        for sign_id, (R_true, p_true) in signs.items():
            if not seen(i, sign_id):
                continue
            R_s, p_s = R_true @ exp_so3(shared[sign_id][:3]), p_true + R_true @ shared[sign_id][3:]
            R, t = R_c.T @ R_s, R_c.T @ (p_s - p_c)  # X_cam = R·X_sign + t
            e = rng.multivariate_normal(np.zeros(6), covariance)
            observations.append(Observation(f"img{i}", sign_id, exp_so3(log_so3(R) + e[:3]), t + e[3:], covariance))
    return observations


def error(sign: MappedSign, R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The true pose's offset from `sign` in the map file's order: [δp, δθ], R = exp(δθ)·R_sign."""
    return np.concatenate([p - sign.position_m, log_so3(R @ sign.R.T)])


def test_the_pose_graph_recovers_hand_made_signs_with_a_covariance_that_covers_the_error():
    rng = np.random.default_rng(1)
    squared = []
    for _ in range(25):
        build = build_map(survey(rng, correlated=True))
        assert list(build.sign_map.signs) == ["a", "b", "c"]
        assert build.reports["a"].fixed == "anchor"
        np.testing.assert_allclose(build.sign_map.signs["a"].position_m, 0.0, atol=1e-9)
        for sign_id in "bc":
            e = error(build.sign_map.signs[sign_id], *SIGNS[sign_id])
            assert np.linalg.norm(e[:3]) < 0.03 and math.degrees(np.linalg.norm(e[3:])) < 1.0
            covariance = build.sign_map.signs[sign_id].covariance
            assert np.allclose(covariance, covariance.T) and np.linalg.eigvalsh(covariance).min() > 0
            squared.append(float(e @ np.linalg.solve(covariance, e)))
    # The whitened squared error of a right covariance is chi-square with 6 dof: mean 6. A covariance
    # in the wrong order or about the wrong axes is off by orders of magnitude.
    assert 4.5 < np.mean(squared) < 8.0
    assert np.mean(np.array(squared) < 12.6) > 0.85  # chi-square 6 dof, 95 %
    b = build.reports["b"]
    assert b.images == 12 and b.seen_with == {"a": 7, "c": 7}
    assert 0 < b.sigma_position_mm < 10 and 0 < b.sigma_rotation_deg < 0.5


def test_covariances_move_into_gtsams_tangent_and_out_to_the_map_files_order():
    rng = np.random.default_rng(2)
    R, t = exp_so3(np.array([0.4, -1.1, 0.7])), np.array([0.3, -0.2, 2.5])
    T = gtsam.Pose3(gtsam.Rot3(R), t)
    # A pose's errors over [rotation vector, t] seen as GTSAM's right perturbation T·Exp(ξ).
    covariance = np.diag([1e-6] * 3 + [4e-6] * 3)
    xi = [gtsam.Pose3.Logmap(T.between(gtsam.Pose3(gtsam.Rot3(exp_so3(log_so3(R) + d[:3])), t + d[3:])))
          for d in rng.multivariate_normal(np.zeros(6), covariance, 4000)]
    np.testing.assert_allclose(np.cov(np.array(xi).T), gtsam_covariance(R, covariance), atol=1.5e-7)
    # GTSAM's [ω, v] at T as the map file's [δp, δθ]: position and a rotation about the map axes on the left.
    tangent = np.diag([1e-6, 2e-6, 3e-6, 4e-6, 5e-6, 6e-6])
    offsets = []
    for d in rng.multivariate_normal(np.zeros(6), tangent, 4000):
        moved = T.compose(gtsam.Pose3.Expmap(d))
        offsets.append(np.concatenate([moved.translation() - t, log_so3(moved.rotation().matrix() @ R.T)]))
    np.testing.assert_allclose(np.cov(np.array(offsets).T), ros_covariance(R, tangent), atol=2e-7)


def test_a_survey_in_two_unlinked_groups_is_refused_naming_both():
    rng = np.random.default_rng(3)
    far = {"d": (np.eye(3), np.array([20.0, 0.0, 0.0])), "e": (np.eye(3), np.array([22.0, 0.0, 0.0]))}
    other_room = [Observation("other" + o.image, o.sign_id, o.R, o.t, o.covariance)
                  for o in survey(rng, far, [(R, p + [19.0, 0, 0]) for R, p in cameras(6, seed=4)])]
    observations = survey(rng) + other_room
    assert sign_groups(observations) == [["a", "b", "c"], ["d", "e"]]
    with pytest.raises(DisconnectedSurvey, match=r"2 groups.*\{a, b, c\}; \{d, e\}") as caught:
        build_map(observations)
    assert caught.value.groups == [["d", "e"]]
    # A known pose in each group places both.
    truth = {**SIGNS, **far}
    known = SignMap({s: MappedSign(s, *truth[s]) for s in ("a", "d")})
    build = build_map(observations, known=known)
    assert set(build.sign_map.signs) == set("abcde")
    assert np.linalg.norm(build.sign_map.signs["e"].position_m - far["e"][1]) < 0.02


def test_two_known_signs_fix_the_map_frame_and_keep_their_poses():
    rng = np.random.default_rng(5)
    # The building's frame: the signs' room turned 30° about the vertical and moved.
    R_w = exp_so3(np.array([0.0, math.radians(30), 0.0]))
    p_w = np.array([10.0, -1.0, 5.0])
    in_building = {s: (R_w @ R, R_w @ p + p_w) for s, (R, p) in SIGNS.items()}
    taped = np.diag([1e-6] * 3 + [1e-6] * 3)  # 1 mm and 1 mrad
    lobby = MappedSign("lobby", np.eye(3), np.array([30.0, 0.0, 0.0]))  # known, not in the survey
    known = SignMap({"a": MappedSign("a", *in_building["a"], covariance=taped),
                     "c": MappedSign("c", *in_building["c"]), "lobby": lobby}, frame="building")
    build = build_map(survey(rng), known=known)
    assert build.sign_map.frame == "building"
    assert build.reports["lobby"].images == 0 and build.reports["lobby"].fixed == "known"
    np.testing.assert_allclose(build.sign_map.signs["lobby"].position_m, lobby.position_m, atol=1e-9)
    assert build.reports["a"].fixed == build.reports["c"].fixed == "known" and build.reports["b"].fixed is None
    np.testing.assert_allclose(build.sign_map.signs["c"].position_m, in_building["c"][1], atol=1e-4)
    e = error(build.sign_map.signs["b"], *in_building["b"])
    assert np.linalg.norm(e[:3]) < 0.015 and math.degrees(np.linalg.norm(e[3:])) < 0.5
    # A known sign held by its covariance keeps about it; without one it is held tightly.
    assert build.sign_map.signs["a"].covariance[0, 0] <= 1e-6 * 1.01
    assert build.sign_map.signs["c"].covariance[0, 0] < 1e-10


def test_an_inconsistent_observation_is_rejected_and_listed():
    rng = np.random.default_rng(6)
    observations = survey(rng)
    good = build_map(observations)
    # img3's view of b turned 8° and 15 cm off: a wrong planar solution, a mismatched sign.
    bad = next(i for i, o in enumerate(observations) if o.image == "img3" and o.sign_id == "b")
    o = observations[bad]
    observations[bad] = Observation(o.image, o.sign_id, exp_so3(np.array([0.0, math.radians(8), 0.0])) @ o.R,
                                    o.t + [0.15, 0.0, 0.0], o.covariance)
    build = build_map(observations)
    assert [(r.observation.image, r.observation.sign_id) for r in build.rejected] == [("img3", "b")]
    assert build.rejected[0].chi2 > CHI2_REJECT
    assert build.reports["b"].rejected == 1 and build.reports["b"].images == 11
    for sign_id in "bc":
        assert np.linalg.norm(build.sign_map.signs[sign_id].position_m - good.sign_map.signs[sign_id].position_m) < 0.005


def test_a_map_built_in_the_server_keeps_its_report_across_a_restart(tmp_path):
    """After a restart the server held a built map's signs without how the survey saw them (images,
    signs seen with, what was rejected): the report is kept in the state beside the map, and left out
    once the map file no longer is the one built."""
    observations = survey(np.random.default_rng(6))
    bad = next(i for i, o in enumerate(observations) if o.image == "img3" and o.sign_id == "b")
    o = observations[bad]
    observations[bad] = Observation(o.image, o.sign_id, o.R, o.t + [0.15, 0.0, 0.0], o.covariance)
    workspace = types.SimpleNamespace(state=StateDir(tmp_path), library=types.SimpleNamespace(ids=list(SIGNS)),
                                      config=types.SimpleNamespace(map_file=None), publish=lambda *_: None)
    held = open_sign_maps(workspace).hold_build(build_map(observations), "built from 12 photo(s) and 0 flight(s)",
                                                {"img3": "IMG_0003.jpg"}, ["blurred.jpg could not be run"])
    assert held.report is not None and ("IMG_0003.jpg", "b") in [r[:2] for r in held.report.rejected]

    again = open_sign_maps(workspace).held
    assert again is not None and again.source == "built from 12 photo(s) and 0 flight(s), kept from the last run"
    said = {"rejected": True, "unmapped": True, "warnings": True, "signs": {"__all__": {"id", "fixed", "images", "seen_with"}}}
    assert map_out(again).model_dump(include=said) == map_out(held).model_dump(include=said)
    assert "1 observation(s) rejected as inconsistent" in again.yaml()   # the download carries the report too

    with workspace.state.map_path.open("a") as f:
        f.write("# edited by hand\n")
    edited = open_sign_maps(workspace).held
    assert edited is not None and edited.report is None and edited.source == "map.yaml kept from the last run"
    assert map_out(edited).signs[1].images is None


def test_no_sign_and_an_anchor_not_seen_are_refused():
    with pytest.raises(MapBuildError, match="no sign was seen"):
        build_map([])
    with pytest.raises(MapBuildError, match="anchor 'z' is not among the signs the survey saw: a, b, c"):
        build_map(survey(np.random.default_rng(7)), anchor="z")
    with pytest.raises(DisconnectedSurvey, match=r"none of the known signs \(z\) was seen"):
        build_map(survey(np.random.default_rng(7)), known=SignMap({"z": MappedSign("z", np.eye(3), np.zeros(3))}))


def test_a_generated_survey_has_four_signs_on_two_walls_seen_in_pairs_with_its_truth(tmp_path):
    library = load_library(SURVEY / "library")
    room = write_survey(tmp_path, library, synthetic_camera(), labels=[s.id for s in library.signs][:5],
                        n_photos=8, seed=3)
    assert len(room.signs) == 5 and len({s.wall for s in room.signs}) >= 2
    gaps = [np.linalg.norm(a.centre - b.centre) for a, b in zip(room.signs, room.signs[1:])]
    assert min(gaps) > 1.4 and max(gaps) < 8.0
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert len(truth["photos"]) == 8 and sum(len(p["signs"]) >= 2 for p in truth["photos"]) >= 4
    assert truth["photos"][0]["signs"] == [room.signs[0].label]
    assert all((tmp_path / p["image"]).is_file() for p in truth["photos"])
    truth_map = load_sign_map(tmp_path / "truth_map.yaml", [s.id for s in library.signs])
    np.testing.assert_allclose(truth_map.signs[room.signs[0].label].position_m, 0.0)


def run_map_build(*args, capsys) -> tuple[int, str, str]:
    code = main(["map", "build", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
def test_map_build_maps_the_sample_survey_and_the_map_loads_back(tmp_path, capsys):
    code, out, err = run_map_build(SURVEY, "-o", tmp_path / "map.yaml", capsys=capsys)
    assert code == 0, err
    assert "observations of 6 sign(s)" in err and "wrote 6 signs" in err
    built = load_sign_map(tmp_path / "map.yaml", [s.id for s in load_library(SURVEY / "library").signs])
    truth = load_sign_map(SURVEY / "truth_map.yaml")
    assert list(built.signs)[0] == "security_compound"  # the first photo's sign, the truth's origin
    assert "anchor" in out.splitlines()[1]
    for sign_id, sign in truth.signs.items():
        e = error(built.signs[sign_id], sign.R, sign.position_m)
        covariance = built.signs[sign_id].covariance
        sigma_position, sigma_rotation = (math.sqrt(np.linalg.eigvalsh(covariance[i:i + 3, i:i + 3]).max())
                                          for i in (0, 3))
        # Plaques 70-200 px wide, chained round three walls: the far end is some centimetres off (and
        # says so); bench/map.py measures the accuracy on larger surveys.
        assert np.linalg.norm(e[:3]) < max(5 * sigma_position, 0.01) and np.linalg.norm(e[:3]) < 0.2, sign_id
        assert np.linalg.norm(e[3:]) < max(5 * sigma_rotation, math.radians(0.3)), sign_id
    text = (tmp_path / "map.yaml").read_text()
    assert "# fixed (anchor); seen in" in text and "1-sigma" in text
    # -o -: the map on stdout, the report on stderr.
    code, out, err = run_map_build(*(SURVEY / f"photo_{i:03d}.jpg" for i in range(4)), "-o", "-", capsys=capsys)
    assert code == 0 and "security_compound" in err
    assert set(read_sign_map(out.encode(), "stdout").signs) <= set(truth.signs)


@pytest.mark.slow
def test_map_build_refuses_a_disconnected_survey_and_a_bad_anchor(tmp_path, capsys):
    truth = json.loads((SURVEY / "truth.json").read_text())
    photos = tmp_path / "photos"
    photos.mkdir()
    # The back wall's first two signs apart from the front wall's two: no photo links them.
    groups = ({"security_compound", "ministry_of_torture"}, {"directors_office", "emergency_exit"})
    for photo in truth["photos"]:
        if any(set(photo["signs"]) <= g for g in groups):
            shutil.copy(SURVEY / photo["image"], photos)
    for name in ("camera.yaml", "library"):
        (shutil.copytree if name == "library" else shutil.copy)(SURVEY / name, photos / name)
    code, out, err = run_map_build(photos, "-o", tmp_path / "map.yaml", capsys=capsys)
    lines = err.strip().splitlines()
    assert code == 1 and lines[-1].startswith("signpose map build: error: the survey's signs form 2 groups")
    assert "ministry_of_torture, security_compound" in lines[-1] and "directors_office, emergency_exit" in lines[-1]
    assert not (tmp_path / "map.yaml").exists()
    code, _, err = run_map_build(SURVEY / "photo_000.jpg", "-o", tmp_path / "map.yaml", "--anchor", "lobby",
                                 capsys=capsys)
    assert code == 2 and "signpose map build: error: --anchor 'lobby' is not a sign of the library" in err
    code, _, err = run_map_build(SURVEY / "photo_000.jpg", "-o", tmp_path / "map.yaml", "--anchor", "archives",
                                 capsys=capsys)
    assert code == 1 and "the anchor 'archives' is not among the signs the survey saw: security_compound" in err
    code, _, err = run_map_build(SURVEY, "-o", tmp_path / "map.yaml", "--anchor", "archives", "--known",
                                 SURVEY / "truth_map.yaml", capsys=capsys)
    assert code == 2 and "give --anchor or --known, not both" in err
    # A photo given twice is one view: counted once and said, not taken for two independent ones.
    photo = SURVEY / "photo_002.jpg"
    code, _, err = run_map_build(photo, photo, "-o", tmp_path / "twice.yaml", "--anchor", "security_compound",
                                 capsys=capsys)
    assert "1 photo(s) or flight(s) given more than once, each used once" in err and "1 images and frames" in err


def test_map_build_is_a_subcommand_with_its_help():
    run = subprocess.run([sys.executable, "-m", "signpose.app.cli", "map", "build", "--help"], capture_output=True,
                         text=True, cwd=ROOT)
    assert run.returncode == 0 and "--anchor SIGN_ID" in run.stdout and "--known MAP" in run.stdout


@pytest.mark.slow
def test_map_build_maps_the_signs_a_flight_sees_together(tmp_path, capsys):
    flight = ROOT / "sample_images" / "flights" / "corridor"
    code, out, err = run_map_build(flight / "flight.mp4", "-o", tmp_path / "map.yaml", "--anchor", "security_compound",
                                   capsys=capsys)
    assert code == 0, err
    built = load_sign_map(tmp_path / "map.yaml")
    # On the corridor wall: chief_of_security 2.6 m along x and 0.1 m up from security_compound.
    # Off the wall (z) by the anchor's tilt, which its 0.6 m plaque, seen from 1-4 m, gives to a degree
    # or two: 2.6 m along, a 12 cm lever.
    offset = built.signs["chief_of_security"].position_m - [2.6, 0.1, 0.0]
    assert np.all(np.abs(offset) < [0.05, 0.05, 0.2]), offset
    assert "security_compound (" in out.splitlines()[2]  # seen with it, on the frames that link them
